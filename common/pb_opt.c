#include "pb_opt.h"

#include <getopt.h>
#include <string.h>

#include "pb_arg.h"

#define MAX_OPTS 64
#define HELP (-2)   /* index of --help */

static int takes_argument(pb_opt_kind_t k)
{
    return k != PB_OPT_K_FLAG && k != PB_OPT_K_BOOL;
}

static int choose(const char *prog, const pb_opt_t *o, const char *arg)
{
    for (int i = 0; i < o->llo; i++)
        if (!strcmp(arg, o->words[i])) { *(int *)o->var = i; return 0; }
    fprintf(stderr, "%s: --%s: expected ", prog, o->name);
    for (int i = 0; i < o->llo; i++)
        fprintf(stderr, "%s%s", i == 0 ? "" : i == o->llo - 1 ? " or " : ", ", o->words[i]);
    fprintf(stderr, ", got '%s'\n", arg);
    return -1;
}

/* Stores one option's value; 0, or -1 after a message. */
static int apply(const char *prog, const pb_opt_t *o, const char *arg)
{
    long v;
    double d;
    switch (o->kind) {
    case PB_OPT_K_STRING:
    case PB_OPT_K_REQUIRED: *(const char **)o->var = arg; return 0;
    case PB_OPT_K_LONG: return pb_arg_long(prog, o->name, arg, o->llo, o->lhi, (long *)o->var);
    case PB_OPT_K_INT:
        if (pb_arg_long(prog, o->name, arg, o->llo, o->lhi, &v)) return -1;
        *(int *)o->var = (int)v;
        return 0;
    case PB_OPT_K_DOUBLE: return pb_arg_double(prog, o->name, arg, o->dlo, o->dhi, (double *)o->var);
    case PB_OPT_K_MICROS:
        if (pb_arg_double(prog, o->name, arg, o->dlo, o->dhi, &d)) return -1;
        *(int64_t *)o->var = (int64_t)(d * o->llo);
        return 0;
    case PB_OPT_K_FLAG: *(int *)o->var = (int)o->llo; return 0;
    case PB_OPT_K_BOOL: *(bool *)o->var = o->llo != 0; return 0;
    case PB_OPT_K_CHOICE: return choose(prog, o, arg);
    case PB_OPT_K_CALL: return o->fn(prog, arg, o->var);
    default: return -1;
    }
}

/* "PROG: --A, --B and --C are required" when one of them is missing; 0 or -1. */
static int check_required(const char *prog, const pb_opt_t *opts, int n)
{
    int missing = 0, nreq = 0, k = 0;
    for (int i = 0; i < n; i++)
        if (opts[i].kind == PB_OPT_K_REQUIRED) {
            nreq++;
            missing |= *(const char **)opts[i].var == NULL;
        }
    if (!missing) return 0;
    fprintf(stderr, "%s: ", prog);
    for (int i = 0; i < n; i++) {
        if (opts[i].kind != PB_OPT_K_REQUIRED) continue;
        k++;
        fprintf(stderr, "%s--%s", k == 1 ? "" : k == nreq ? " and " : ", ", opts[i].name);
    }
    fprintf(stderr, " %s required\n", nreq == 1 ? "is" : "are");
    return -1;
}

int pb_opt_parse(const char *prog, const pb_opt_t *opts, void (*usage)(FILE *), int flags, int argc, char **argv)
{
    struct option lo[MAX_OPTS + 2];
    char shorts[2 * MAX_OPTS + 3], *s = shorts;
    int n = 0;
    if (flags & PB_OPT_IN_ORDER) *s++ = '+';
    for (; opts[n].name; n++) {
        if (n == MAX_OPTS) {
            fprintf(stderr, "%s: more than %d options in the table\n", prog, MAX_OPTS);
            return 2;
        }
        int has_arg = takes_argument(opts[n].kind) ? required_argument : no_argument;
        lo[n] = (struct option){ opts[n].name, has_arg, NULL, 256 + n };
        if (opts[n].letter) {
            *s++ = opts[n].letter;
            if (has_arg) *s++ = ':';
        }
    }
    lo[n] = (struct option){ "help", no_argument, NULL, 'h' };
    lo[n + 1] = (struct option){ NULL, 0, NULL, 0 };
    *s++ = 'h';
    *s = 0;

    optind = 0;   /* glibc: start afresh (a test parses several command lines) */
    int c;
    while ((c = getopt_long(argc, argv, shorts, lo, NULL)) != -1) {
        int i = c >= 256 ? c - 256 : c == 'h' ? HELP : -1;
        for (int k = 0; i == -1 && c != '?' && k < n; k++)
            if (opts[k].letter == c) i = k;
        if (i == HELP) { usage(stdout); return 0; }
        if (i < 0) { usage(stderr); return 2; }
        if (apply(prog, &opts[i], optarg)) return 2;
    }
    if (!(flags & (PB_OPT_ARGS | PB_OPT_IN_ORDER)) && optind < argc) {
        fprintf(stderr, "%s: unexpected argument '%s'\n", prog, argv[optind]);
        usage(stderr);
        return 2;
    }
    if (check_required(prog, opts, n)) { usage(stderr); return 2; }
    return -1;
}
