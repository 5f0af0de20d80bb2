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

/* Valid points only (no-return pixels, non-finite points and point-form points at
 * exactly (0, 0, 0), the no-return marker of organized Velodyne clouds, are skipped).
 * Returns the number of points, or -1 if the scan is inconsistent (array sizes
 * that do not match rows/cols), with err naming the field. */
int pb_scan_points(const portobello_lidar_scan_t *scan, pb_points_t *out, pb_err_t *err);
void pb_points_free(pb_points_t *pts);

/* The angles between neighbouring beams of a sweep: *ring_gap_rad, the largest gap in
 * elevation between neighbouring rings, and *col_gap_rad, between neighbouring columns.
 * Range image: exact (beam_altitude_rad; 2 pi / cols). Point form with ring indices
 * (pts from pb_scan_points of the same scan): estimated, each ring's elevation the median
 * of its points', the column gap 2 pi over the most points on one ring. Returns 1 with
 * both set, 0 (both untouched) if the scan does not say (point form without rings, fewer than two rings). */
int pb_scan_beam_gaps(const portobello_lidar_scan_t *scan, const pb_points_t *pts, double *ring_gap_rad,
                      double *col_gap_rad);

#ifdef __cplusplus
}
#endif
#endif
