/* pb_scan: a LIDAR_SCAN of either form as points in the `lidar` frame.
 *
 * Implements the range-image model documented in lcmtypes/lidar_scan_t.lcm once,
 * for every module. Ownership: pb_points_t arrays are owned by the struct and
 * freed by pb_points_free; pb_scan_points reuses their capacity. */
#ifndef PB_SCAN_H
#define PB_SCAN_H

#include <stdint.h>
#include "pb_err.h"
#include "portobello_lidar_scan_t.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    int n, cap;
    float *x, *y, *z;       /* metres, lidar frame */
    float *intensity;       /* reflectivity (range image) or intensity (point form) */
    int32_t *offset_us;     /* time after scan utime */
    uint8_t *ring;          /* beam index, 255 unknown */
} pb_points_t;

/* Valid points only (no-return pixels and non-finite points are skipped).
 * Returns the number of points, or -1 if the scan is inconsistent (array sizes
 * that do not match rows/cols), with err naming the field. */
int pb_scan_points(const portobello_lidar_scan_t *scan, pb_points_t *out, pb_err_t *err);
void pb_points_free(pb_points_t *pts);

#ifdef __cplusplus
}
#endif
#endif
