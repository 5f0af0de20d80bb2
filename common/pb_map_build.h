/* pb_map_build: assembling a prior point-cloud map from scans and poses.
 *
 * Used by tools/build-map (scans and poses from an LCM log) and
 * tools/import-scans (scans and poses from files), and by the mapper. C-callable;
 * implemented in C++ (link libpb_common_cxx.a).
 *
 *  - pb_pose_track_t: a time-ordered list of poses (map <- frame) that
 *    interpolates linearly in position and by slerp in orientation.
 *  - pb_map_builder_t: accumulates points transformed into `map` and reduces
 *    them on the fly to one point per voxel (the centroid of xyz and the mean
 *    intensity of every point that fell in it, the same result as
 *    pcl::VoxelGrid over all points). Streaming keeps memory proportional to
 *    the occupied voxels, not to the points, and 64-bit voxel keys avoid
 *    VoxelGrid's int overflow on large extents.
 *
 * Ownership: each _create returns an object the caller frees with the matching
 * _destroy (NULL is a no-op). Inputs are copied; no pointer is kept. */
#ifndef PB_MAP_BUILD_H
#define PB_MAP_BUILD_H

#include <stdint.h>
#include "pb_err.h"
#include "pb_math.h"
#include "pb_scan.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---------------------------------------------------------------- pose track */
typedef struct pb_pose_track pb_pose_track_t;

pb_pose_track_t *pb_pose_track_create(void);
void pb_pose_track_destroy(pb_pose_track_t *t);

/* Adds a pose valid at utime (any order; kept sorted, stable for equal times). A track being
 * added to must not be read; a track no longer added to may be read by several threads at once. */
void pb_pose_track_add(pb_pose_track_t *t, int64_t utime, const pb_transform_t *pose);
int pb_pose_track_count(const pb_pose_track_t *t);
/* First and last pose time; returns 0, or -1 if the track is empty. */
int pb_pose_track_span(const pb_pose_track_t *t, int64_t *first, int64_t *last);

/* Pose at utime, interpolated between the two poses that bracket it (an exact
 * hit needs no neighbour). Returns 1 with *out set, 0 if utime is outside the
 * track (no extrapolation). */
int pb_pose_track_at(const pb_pose_track_t *t, int64_t utime, pb_transform_t *out);

/* ---------------------------------------------------------------- map builder */
typedef struct pb_map_builder pb_map_builder_t;

/* voxel_m > 0: one point per voxel of that edge (metres).
 * voxel_m <= 0: every point is kept (no reduction). */
pb_map_builder_t *pb_map_builder_create(double voxel_m, pb_err_t *err);
void pb_map_builder_destroy(pb_map_builder_t *b);

/* Adds points of one scan, all moved by the same map <- lidar transform. Points at
 * exactly (0, 0, 0) in the lidar frame are no-return markers and are skipped (here and
 * in pb_map_builder_add_timed).
 * Returns 0, or -1 if a point falls outside the voxel key range (+-2^20 voxels). */
int pb_map_builder_add(pb_map_builder_t *b, const pb_points_t *pts,
                       const pb_transform_t *map_from_lidar, pb_err_t *err);

/* Adds points of one scan, each moved by its own time's pose:
 *   map <- lidar(t_i) = track(scan_utime + offset_us[i]) * base_from_lidar
 * (base_from_lidar NULL = identity, i.e. the track holds lidar poses).
 * The scan is added only if the track brackets every point's time.
 * Returns 1 if added, 0 if skipped for lack of bracketing poses, -1 on error. */
int pb_map_builder_add_timed(pb_map_builder_t *b, const pb_points_t *pts, int64_t scan_utime,
                             const pb_pose_track_t *track, const pb_transform_t *base_from_lidar,
                             pb_err_t *err);

/* The points of one scan placed as pb_map_builder_add_timed places them (each with its own
 * time's pose; no-return markers and points beyond the max range left out): their x y z in
 * map into xyz (room for 3 * pts->n), their index in pts into index (NULL: not wanted), the
 * points beyond the max range into *beyond (NULL: not wanted). Returns how many, or -1 when
 * the track does not bracket the scan (add_timed skips it). */
int pb_map_builder_place_timed(const pb_map_builder_t *b, const pb_points_t *pts, int64_t scan_utime,
                               const pb_pose_track_t *track, const pb_transform_t *base_from_lidar,
                               double *xyz, int32_t *index, int64_t *beyond);

/* pb_map_builder_add_timed's second half: adds the n points pb_map_builder_place_timed placed
 * from pts (xyz, index, beyond as it gave them; index must be given), so that the next scan can
 * be placed on another thread while one is added. The same map as add_timed, byte for byte.
 * Returns 0, or -1 if a point falls outside the voxel key range. */
int pb_map_builder_add_placed(pb_map_builder_t *b, const pb_points_t *pts, const double *xyz, const int32_t *index,
                              int n, int64_t beyond, pb_err_t *err);
/* The key of the voxel of edge voxel_m that holds (x, y, z), as a builder keys it (its
 * pb_map_voxel_t.key); 0, or -1 outside the key range. Its lowest corner: pb_map_voxel_corner. */
int pb_map_voxel_key(double voxel_m, double x, double y, double z, uint64_t *key);
void pb_map_voxel_corner(double voxel_m, uint64_t key, double corner[3]);

int64_t pb_map_builder_points_in(const pb_map_builder_t *b);   /* points added */
/* The stamp the points added from now on leave in their voxels (pb_map_voxel_t.first, .last;
 * 0 until set): the mapper stamps each sweep's number, to know when a voxel was hit without
 * reading the drive again. */
void pb_map_builder_stamp(pb_map_builder_t *b, uint32_t stamp);
/* Points farther than max_m from the sensor (their frame's origin) left out of the map from
 * now on, and counted (pb_map_builder_points_beyond); max_m <= 0: none left out (the default). */
void pb_map_builder_set_max_range(pb_map_builder_t *b, double max_m);
int64_t pb_map_builder_points_beyond(const pb_map_builder_t *b);
int64_t pb_map_builder_size(const pb_map_builder_t *b);        /* points in the map */
/* Extent of the map's points; returns 0, or -1 if empty. */
int pb_map_builder_bounds(const pb_map_builder_t *b, double min[3], double max[3]);

/* Paging a large map out of memory and back (the mapper keeps only the tiles around the
 * car). A builder made tiled holds its voxels per square tile of tile_voxels voxels a side
 * (x, y; tile = floor(voxel index / tile_voxels)); a tile can be taken out whole and put
 * back later as it was: the voxels, their sums and pb_map_builder_write_pcd's order are
 * those of a builder that was never paged. A point that falls in a tile not held starts
 * that tile afresh: the caller puts a tile back before points can reach it. */
typedef struct {
    uint64_t key;
    float sx, sy, sz, si;   /* sums of the points' offsets from the voxel's min corner, of intensities */
    uint32_t n, seq;        /* points; the order the voxel was made in (0, 1, ...) */
    uint32_t first, last;   /* the least and the greatest stamp of its points (pb_map_builder_stamp) */
} pb_map_voxel_t;

pb_map_builder_t *pb_map_builder_create_tiled(double voxel_m, int tile_voxels, pb_err_t *err);
/* The tiles held, (tx, ty) pairs into xy (room for max); returns how many are held. */
int pb_map_builder_tiles(const pb_map_builder_t *b, int32_t *xy, int max);
/* Voxels in tile (tx, ty) (0 when not held). */
int64_t pb_map_builder_tile_size(const pb_map_builder_t *b, int32_t tx, int32_t ty);
/* Moves tile (tx, ty)'s voxels into out (room for pb_map_builder_tile_size), in the order
 * they were made; the tile is then not held. */
void pb_map_builder_tile_take(pb_map_builder_t *b, int32_t tx, int32_t ty, pb_map_voxel_t *out);
/* Puts voxels taken before back (a tile not held). Returns 0, or -1 (a voxel held already, out of memory). */
int pb_map_builder_put(pb_map_builder_t *b, const pb_map_voxel_t *v, size_t n, pb_err_t *err);
/* The voxel's point as the PCD holds it: the centroid and the mean intensity. */
void pb_map_voxel_point(const pb_map_builder_t *b, const pb_map_voxel_t *v, float out[4]);

/* Writes the map as binary PCD (fields x y z intensity, float32), creating the
 * parent directory if it is missing. Returns 0, or -1 (empty map, I/O error). */
int pb_map_builder_write_pcd(const pb_map_builder_t *b, const char *path, pb_err_t *err);

/* Writes n points (x y z intensity, 4 floats each) as binary PCD, the same file
 * pb_map_builder_write_pcd (and PCL for pcl::PointXYZI) writes, a part at a time:
 * fill(user, first, count, xyzi, err) puts points first .. first + count - 1 into xyzi and
 * returns 0, or -1 with err set (the file is then removed). Returns 0, or -1 (I/O error,
 * err names the file). */
int pb_pcd_write_xyzi_from(const char *path, int64_t n,
                           int (*fill)(void *user, int64_t first, int64_t count, float *xyzi, pb_err_t *err),
                           void *user, pb_err_t *err);

#ifdef __cplusplus
}
#endif
#endif
