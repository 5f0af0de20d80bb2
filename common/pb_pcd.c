/* pb_pcd: see pb_pcd.h. */
#include "pb_pcd.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define MAX_FIELDS 256
#define MAX_LINE 8192

/* The words of line (split in place at blanks); returns their number (at most max). */
static int split(char *line, char **w, int max)
{
    int n = 0;
    char *save = NULL;
    for (char *t = strtok_r(line, " \t\r\n", &save); t && n < max; t = strtok_r(NULL, " \t\r\n", &save)) w[n++] = t;
    return n;
}

/* A whole decimal number within [lo, hi] (no sign other than '-', no trailing text). */
static int whole(const char *s, long long lo, long long hi, long long *out)
{
    char *end;
    errno = 0;
    long long v = strtoll(s, &end, 10);
    if (errno || end == s || *end || v < lo || v > hi) return -1;
    *out = v;
    return 0;
}

static int check_header(FILE *f, long long file_bytes, const char *path, pb_pcd_header_t *h, pb_err_t *err)
{
    static const char *const order[] = {"VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT",
                                        "VIEWPOINT", "POINTS", "DATA"};
    char line[MAX_LINE], *w[MAX_FIELDS + 2];
    int nfields = -1, size[MAX_FIELDS], count[MAX_FIELDS], have_size = 0, have_type = 0, have_count = 0;
    char type[MAX_FIELDS];
    long long width = -1, height = 1, points = -1;
    int last = -1, lineno = 0;
    pb_pcd_header_t out;
    memset(&out, 0, sizeof out);
    for (;;) {
        if (!fgets(line, sizeof line, f)) {
            return pb_err_set(err, "%s:%d: no DATA line: not a PCD header", path, lineno);
        }
        lineno++;
        if (!strchr(line, '\n') && !feof(f)) {
            return pb_err_set(err, "%s:%d: a header line longer than %d bytes: not a PCD header", path, lineno, MAX_LINE - 1);
        }
        int n = split(line, w, MAX_FIELDS + 2);
        if (n == 0 || w[0][0] == '#') continue;
        int k = 0;
        while (k < 10 && strcmp(w[0], order[k]) != 0) k++;
        if (k == 10) {
            return pb_err_set(err, "%s:%d: '%.40s' is not a PCD header keyword", path, lineno, w[0]);
        }
        if (k <= last) {
            return pb_err_set(err, "%s:%d: %s out of order or twice", path, lineno, order[k]);
        }
        last = k;
        const int args = n - 1;
        if (k == 1) {
            if (args < 1 || args > MAX_FIELDS) {
                return pb_err_set(err, "%s:%d: FIELDS names %d fields (1 to %d)", path, lineno, args, MAX_FIELDS);
            }
            nfields = args;
            for (int i = 0; i < nfields; i++) size[i] = 4, count[i] = 1, type[i] = 'F';
        } else if (k >= 2 && k <= 4) {
            if (nfields < 0 || args != nfields) {
                return pb_err_set(err, "%s:%d: %s has %d values for %d fields", path, lineno, order[k], args, nfields < 0 ? 0 : nfields);
            }
            for (int i = 0; i < nfields; i++) {
                long long v;
                if (k == 2 && (whole(w[i + 1], 1, 8, &v) != 0 || (v != 1 && v != 2 && v != 4 && v != 8))) {
                    return pb_err_set(err, "%s:%d: SIZE '%.20s': 1, 2, 4 or 8 expected", path, lineno, w[i + 1]);
                }
                if (k == 2) size[i] = (int)v;
                if (k == 3) {
                    if (strlen(w[i + 1]) != 1 || !strchr("IUF", w[i + 1][0])) {
                        return pb_err_set(err, "%s:%d: TYPE '%.20s': I, U or F expected", path, lineno, w[i + 1]);
                    }
                    type[i] = w[i + 1][0];
                }
                if (k == 4) {
                    if (whole(w[i + 1], 1, 4096, &v) != 0) {
                        return pb_err_set(err, "%s:%d: COUNT '%.20s': 1 to 4096 expected", path, lineno, w[i + 1]);
                    }
                    count[i] = (int)v;
                }
            }
            have_size |= k == 2;
            have_type |= k == 3;
            have_count |= k == 4;
        } else if (k == 5 || k == 6 || k == 8) {
            long long v;
            if (args != 1 || whole(w[1], k == 8 ? 0 : 1, (long long)1 << 40, &v) != 0) {
                return pb_err_set(err, "%s:%d: %s: one whole number expected", path, lineno, order[k]);
            }
            if (k == 5) width = v;
            else if (k == 6) height = v;
            else points = v;
        } else if (k == 9) {
            if (args != 1 || (strcmp(w[1], "ascii") && strcmp(w[1], "binary") && strcmp(w[1], "binary_compressed"))) {
                return pb_err_set(err, "%s:%d: DATA: ascii, binary or binary_compressed expected", path, lineno);
            }
            snprintf(out.data, sizeof out.data, "%s", w[1]);
            break;
        }
    }
    (void)have_count;
    if (nfields < 0 || !have_size || !have_type || width < 0 || points < 0) {
        return pb_err_set(err, "%s:%d: the header lacks %s", path, lineno,
                   nfields < 0 ? "FIELDS" : !have_size ? "SIZE" : !have_type ? "TYPE" : width < 0 ? "WIDTH" : "POINTS");
    }
    if (width * height != points) {
        return pb_err_set(err, "%s:%d: WIDTH x HEIGHT (%lld x %lld) is not POINTS (%lld)", path, lineno, width, height, points);
    }
    long long record = 0;
    for (int i = 0; i < nfields; i++) {
        if (type[i] == 'F' && size[i] != 4 && size[i] != 8) {
            return pb_err_set(err, "%s: field %d: a float of %d bytes", path, i + 1, size[i]);
        }
        record += (long long)size[i] * count[i];
    }
    out.points = points;
    out.fields = nfields;
    out.record_bytes = (int)record;
    out.data_at = ftell(f);
    const long long left = file_bytes - out.data_at;
    if (strcmp(out.data, "binary") == 0 && points * record > left) {
        return pb_err_set(err, "%s: byte %lld: %lld points of %lld bytes need %lld bytes of data, the file holds %lld", path,
                   (long long)out.data_at, points, record, points * record, left);
    }
    if (strcmp(out.data, "binary_compressed") == 0) {
        unsigned char sz[8];
        if (fread(sz, 1, 8, f) != 8) {
            return pb_err_set(err, "%s: byte %lld: binary_compressed data without its two sizes", path, (long long)out.data_at);
        }
        unsigned long long packed = sz[0] | sz[1] << 8 | sz[2] << 16 | (unsigned long long)sz[3] << 24;
        unsigned long long unpacked = sz[4] | sz[5] << 8 | sz[6] << 16 | (unsigned long long)sz[7] << 24;
        if ((long long)packed > left - 8 || (long long)unpacked != points * record) {
            return pb_err_set(err, "%s: byte %lld: binary_compressed sizes %llu (packed; %lld bytes follow) and %llu "
                              "(unpacked; %lld points of %lld bytes)", path, (long long)out.data_at, packed, left - 8,
                              unpacked, points, record);
        }
    }
    /* PCL reads on after DATA while lines are blank, comments or keywords: data that
     * begins like a keyword line would be taken as header (a FIELDS of binary bytes) */
    if (fseek(f, out.data_at, SEEK_SET) != 0) return pb_err_set(err, "%s: byte %lld: cannot seek", path, (long long)out.data_at);
    for (long long at = out.data_at;;) {
        char head[16];
        int n = 0, c;
        long long start = at;
        while ((c = fgetc(f)) != EOF && c != '\n') {
            at++;
            if (n < (int)sizeof head - 1) head[n++] = (char)c;
        }
        at++;
        head[n] = 0;
        char *tok = head + strspn(head, " \t\r");
        if (*tok == '#' || (*tok == 0 && n < (int)sizeof head - 1)) {   /* PCL skips it and reads on */
            if (c == EOF) break;
            continue;
        }
        for (char *q = tok; *q; q++)
            if (*q < 32 || *q > 126) *q = '?';
        for (int k = 0; k < 10; k++)
            if (strncmp(tok, order[k], strlen(order[k])) == 0 || strncmp(tok, "COLUMNS", 7) == 0)
                return pb_err_set(err, "%s: byte %lld: the data begins like a header line ('%.9s'), which PCL would "
                                  "read as one", path, start, tok);
        break;
    }
    if (h) *h = out;
    return 0;
}

int pb_pcd_check(const char *path, pb_pcd_header_t *h, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) return pb_err_set(err, "%s: %s", path, strerror(errno));
    struct stat st;
    int rc = fstat(fileno(f), &st) != 0 ? pb_err_set(err, "%s: %s", path, strerror(errno))
                                        : check_header(f, (long long)st.st_size, path, h, err);
    fclose(f);
    return rc;
}
