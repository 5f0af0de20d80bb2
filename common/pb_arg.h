/* pb_arg: numeric command-line values, checked whole: "1.5x", "", "nan" and values
 * outside [lo, hi] are refused with "PROG: --OPT: expected a number in [lo, hi], got 'S'"
 * on stderr. Return 0, or -1 (the caller exits with status 2). */
#ifndef PB_ARG_H
#define PB_ARG_H

#ifdef __cplusplus
extern "C" {
#endif

int pb_arg_double(const char *prog, const char *opt, const char *s, double lo, double hi, double *out);
int pb_arg_long(const char *prog, const char *opt, const char *s, long lo, long hi, long *out);

#ifdef __cplusplus
}
#endif
#endif
