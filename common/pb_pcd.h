/* pb_pcd: a PCD file's header checked before PCL reads it. PCL's reader trusts the
 * header: a file that is not a PCD, or one whose header promises more than the file
 * holds, can crash it. pb_pcd_check refuses those with a message naming the file and
 * the line or byte; what it passes, PCL reads or rejects without crashing (the fuzz
 * target fuzz_import_scans holds it to that). */
#ifndef PB_PCD_H
#define PB_PCD_H

#include <stdint.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    int64_t points;        /* POINTS (= WIDTH x HEIGHT) */
    int fields;            /* FIELDS */
    int record_bytes;      /* bytes a point: sum of SIZE x COUNT */
    int64_t data_at;       /* byte where the data begins */
    char data[24];         /* "ascii", "binary" or "binary_compressed" */
} pb_pcd_header_t;

/* Reads and checks path's header: the keywords in order up to DATA, FIELDS with as
 * many SIZE (1, 2, 4 or 8), TYPE (I, U or F; F of size 4 or 8) and COUNT (1 to 4096;
 * all 1 when absent), WIDTH x HEIGHT = POINTS, a known DATA form, and data enough for
 * the points (binary: POINTS records; binary_compressed: its two sizes, the compressed
 * bytes within the file, the uncompressed POINTS records). Fills *h (may be NULL).
 * Returns 0, or -1 with err "PATH:LINE: ..." or "PATH: byte N: ...". */
int pb_pcd_check(const char *path, pb_pcd_header_t *h, pb_err_t *err);

#ifdef __cplusplus
}
#endif
#endif
