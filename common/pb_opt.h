/* pb_opt: a program's command line from a table of its options.
 *
 * Each binary lists its long options once, with where each value goes and the range
 * a number must lie in; pb_opt_parse does the getopt_long loop every shell used to
 * write out. --help / -h is always there: usage(stdout), exit status 0. A bad option:
 * getopt's message, usage(stderr), 2. A bad value: pb_arg's message
 * ("PROG: --OPT: expected a number in [lo, hi], got 'S'"), 2. A word that is not an
 * option: "PROG: unexpected argument 'W'", usage(stderr), 2, unless the flags accept
 * arguments (then they are argv[optind] .. argv[argc - 1]). A required option
 * missing: "PROG: --A and --B are required" (every required one named), usage(stderr), 2.
 *
 *   const char *in = NULL, *channel = "POSE";
 *   long frames = 300;
 *   const pb_opt_t opts[] = {
 *       PB_OPT_REQUIRED("log", &in), PB_OPT_STRING("channel", &channel),
 *       PB_OPT_LONG("frames", &frames, 3, 1000000), PB_OPT_END,
 *   };
 *   int parsed = pb_opt_parse("prog", opts, usage, 0, argc, argv);
 *   if (parsed >= 0) return parsed;
 *
 * The table holds pointers to the caller's variables (so it is a local, not static);
 * defaults are the variables' values before the call. Options that need more than a
 * range or a word list (a repeated option, a pair of numbers) take a PB_OPT_CALL function. */
#ifndef PB_OPT_H
#define PB_OPT_H

#include <stdint.h>
#include <stdio.h>
#ifndef __cplusplus
#include <stdbool.h>
#endif

#ifdef __cplusplus
extern "C" {
#endif

typedef enum {
    PB_OPT_K_END,
    PB_OPT_K_STRING,     /* const char **: the argument itself (argv outlives the program) */
    PB_OPT_K_REQUIRED,   /* the same, and the option must be given */
    PB_OPT_K_LONG,       /* long *, within [llo, lhi] */
    PB_OPT_K_INT,        /* int *, within [llo, lhi] */
    PB_OPT_K_DOUBLE,     /* double *, finite, within [dlo, dhi] */
    PB_OPT_K_MICROS,     /* int64_t *: a number within [dlo, dhi] of a unit of llo microseconds */
    PB_OPT_K_FLAG,       /* int *, set to llo; takes no argument */
    PB_OPT_K_BOOL,       /* bool *, set to llo != 0; takes no argument */
    PB_OPT_K_CHOICE,     /* int *: the index of the argument in words[0 .. llo - 1] */
    PB_OPT_K_CALL,       /* fn(prog, argument, var) */
} pb_opt_kind_t;

/* For PB_OPT_CALL: takes the option's argument; returns 0, or -1 after printing
 * "PROG: --OPT: ..." to stderr (the program then exits with status 2). */
typedef int (*pb_opt_fn)(const char *prog, const char *arg, void *var);

typedef struct {
    const char *name;    /* long name without "--"; NULL ends the table */
    char letter;         /* also as -L, or 0 */
    pb_opt_kind_t kind;
    void *var;
    long llo, lhi;
    double dlo, dhi;
    pb_opt_fn fn;
    const char *const *words;
} pb_opt_t;

/* Flags of pb_opt_parse. */
#define PB_OPT_ARGS 1       /* words that are not options are the program's arguments */
#define PB_OPT_IN_ORDER 2   /* the same, and options end at the first of them ("+" of getopt) */

/* Parses argv against opts. Returns -1 when the program goes on, or the status to exit
 * with: 0 after --help, 2 after an error (already printed). */
int pb_opt_parse(const char *prog, const pb_opt_t *opts, void (*usage)(FILE *), int flags, int argc, char **argv);

/* Entries. The pointer's type is checked (a warning in C, an error in C++). */
#define PB_OPT_TYPED_(p, T) (1 ? (p) : (T)0)
#define PB_OPT_ENTRY(name, letter, kind, var, llo, lhi, dlo, dhi, fn) \
    { name, letter, kind, var, llo, lhi, dlo, dhi, fn, NULL }
#define PB_OPT_STRING(name, var) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_STRING, PB_OPT_TYPED_(var, const char **), 0, 0, 0, 0, NULL)
#define PB_OPT_REQUIRED(name, var) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_REQUIRED, PB_OPT_TYPED_(var, const char **), 0, 0, 0, 0, NULL)
#define PB_OPT_LONG(name, var, lo, hi) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_LONG, PB_OPT_TYPED_(var, long *), lo, hi, 0, 0, NULL)
#define PB_OPT_INT(name, var, lo, hi) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_INT, PB_OPT_TYPED_(var, int *), lo, hi, 0, 0, NULL)
#define PB_OPT_DOUBLE(name, var, lo, hi) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_DOUBLE, PB_OPT_TYPED_(var, double *), 0, 0, lo, hi, NULL)
/* A duration given in a unit of unit_us microseconds (1000: ms, 1000000: s), kept in us. */
#define PB_OPT_MICROS(name, var, lo, hi, unit_us) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_MICROS, PB_OPT_TYPED_(var, int64_t *), unit_us, 0, lo, hi, NULL)
#define PB_OPT_FLAG(name, var, value) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_FLAG, PB_OPT_TYPED_(var, int *), value, 0, 0, 0, NULL)
#define PB_OPT_BOOL(name, var, value) \
    PB_OPT_ENTRY(name, 0, PB_OPT_K_BOOL, PB_OPT_TYPED_(var, bool *), value, 0, 0, 0, NULL)
/* One of n words ("PROG: --OPT: expected A, B or C, got 'X'" otherwise). */
#define PB_OPT_CHOICE(name, var, words, n) \
    { name, 0, PB_OPT_K_CHOICE, PB_OPT_TYPED_(var, int *), n, 0, 0, 0, NULL, words }
#define PB_OPT_CALL(name, fn, var) PB_OPT_ENTRY(name, 0, PB_OPT_K_CALL, var, 0, 0, 0, 0, fn)
#define PB_OPT_END PB_OPT_ENTRY(NULL, 0, PB_OPT_K_END, NULL, 0, 0, 0, 0, NULL)

#ifdef __cplusplus
}
#endif
#endif
