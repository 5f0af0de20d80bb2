/* pb_check: a minimal check harness for the C unit tests. Each failed check
 * prints file:line and the expression; main returns pb_check_report(). */
#ifndef PB_CHECK_H
#define PB_CHECK_H

#include <math.h>
#include <stdio.h>
#include <string.h>

static int pb_checks, pb_failures;

#define CHECK(cond) do { pb_checks++; if (!(cond)) { pb_failures++; \
    fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); } } while (0)
/* CHECK in a loop over a table of cases: a failure names the case. */
#define CHECK_CASE(name, cond) do { pb_checks++; if (!(cond)) { pb_failures++; \
    fprintf(stderr, "%s:%d: case \"%s\": check failed: %s\n", __FILE__, __LINE__, (name), #cond); } } while (0)
#define CHECK_NEAR(a, b, tol) do { pb_checks++; double _a = (a), _b = (b); if (!(fabs(_a - _b) <= (tol))) { pb_failures++; \
    fprintf(stderr, "%s:%d: check failed: %s = %.9g, %s = %.9g, tolerance %g\n", __FILE__, __LINE__, #a, _a, #b, _b, (double)(tol)); } } while (0)
#define CHECK_CONTAINS(s, sub) do { pb_checks++; if (!strstr((s), (sub))) { pb_failures++; \
    fprintf(stderr, "%s:%d: check failed: \"%s\" does not contain \"%s\"\n", __FILE__, __LINE__, (s), (sub)); } } while (0)

/* CHECK that a call returned 0; a failure prints msg too (the call's error message). Its
 * value is the return code, so a test can stop there: if (CHECK_OK(load(...), err.msg)) return; */
#define CHECK_OK(rc, msg) pb_check_ok((rc), (msg), __FILE__, __LINE__)
static inline int pb_check_ok(int rc, const char *msg, const char *file, int line)
{
    pb_checks++;
    if (rc != 0) { pb_failures++; fprintf(stderr, "%s:%d: check failed: returned %d: %s\n", file, line, rc, msg); }
    return rc;
}

/* Writes text to DIR/NAME, a test's scratch file; returns its path (a static buffer,
 * valid until the next call). */
static inline const char *pb_check_write_file(const char *dir, const char *name, const char *text)
{
    static char path[256];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    if (!f) { perror(path); return path; }
    fputs(text, f);
    fclose(f);
    return path;
}

static int pb_check_report(const char *name)
{
    printf("%s: %d checks, %d failed\n", name, pb_checks, pb_failures);
    return pb_failures ? 1 : 0;
}

#endif
