/* regmap: the prior map, prepared once for scan-to-map registration.
 *
 * The map's points (map frame, metres) are reduced to a voxel hash of local
 * planes: each occupied cell of edge `voxel_m` stores the centroid and normal of
 * the map points in its 3x3x3 neighbourhood (so a scan point finds its plane in
 * O(1), in its own cell, and the plane is supported by ~3x the cell size). Cells
 * whose neighbourhood is not planar (e.g. foliage, poles) keep their centroid
 * and are flagged; registration then uses them as point-to-point targets.
 * A second, coarser level (`coarse_voxel_m`) serves pb_reg_align_global.
 *
 * Loading: whole map, or only the points within `load_radius_m` (horizontal) of
 * a centre, for maps too large for memory; the caller reloads around the car
 * when pb_regmap_covers() says the car is leaving the loaded disc.
 *
 * Ownership: pb_regmap_load / pb_regmap_from_points / pb_regmap_rebuild return a map the caller
 * frees with pb_regmap_destroy (NULL is a no-op). No pointer into the inputs is
 * kept. A loaded map is read-only: several threads may align against it.
 *
 * Errors: functions that can fail return NULL or -1 and fill pb_err_t with one
 * line naming the file (missing file, unreadable/corrupt PCD, no x/y/z fields,
 * no points within the load radius). */
#ifndef PB_LOC_REGMAP_H
#define PB_LOC_REGMAP_H

#include <stddef.h>
#include <stdint.h>
#include <vector>
#include <Eigen/Core>
#include "pb_err.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double voxel_m = 0.5;         /* fine cell edge, metres */
    double coarse_voxel_m = 2.0;  /* coarse level for global alignment; 0 = none */
    int min_points = 6;           /* map points a neighbourhood needs for a plane */
    double planarity_max = 0.1;   /* smallest/middle eigenvalue ratio up to which a cell is a plane */
    double load_radius_m = 0;     /* 0 = load every point; else only within this horizontal radius */
} pb_regmap_config_t;

/* Fills *cfg with the defaults above. */
void pb_regmap_config_default(pb_regmap_config_t *cfg);

typedef struct pb_regmap pb_regmap_t;

/* Loads a PCD (ascii or binary, fields x y z [...]) in the map frame.
 * center_xy: map x, y the load disc is centred on; ignored (may be NULL) when
 * cfg->load_radius_m == 0. cfg NULL = defaults. */
pb_regmap_t *pb_regmap_load(const char *pcd_path, const pb_regmap_config_t *cfg,
                            const double center_xy[2], pb_err_t *err);

/* The finite points of a PCD file (fields x y z [...]; every data form PCL reads: ascii,
 * binary, binary_compressed) into *xyz (interleaved, replaced); *total (may be NULL) gets
 * the file's point count. 0, or -1 with err naming the file. */
int pb_pcd_read_xyz(const char *pcd_path, std::vector<float> *xyz, size_t *total, pb_err_t *err);

/* Builds from n points (xyz interleaved, map frame, metres). load_radius_m is
 * ignored. Returns NULL (err set) if n == 0 or no cell gets a target. */
pb_regmap_t *pb_regmap_from_points(const float *xyz, size_t n, const pb_regmap_config_t *cfg,
                                   pb_err_t *err);

/* As pb_regmap_from_points, for a map built again and again from mostly the same points in
 * the same order (the mapper's rolling local map): a voxel whose 3x3x3 neighbourhood holds
 * the same points as in prev keeps prev's fit, the others are fitted again. The result is
 * the same, byte for byte, as pb_regmap_from_points'. prev NULL (or built otherwise, or with
 * another config) = a build from scratch. The map returned keeps each voxel's moments for
 * the next rebuild (about 110 bytes a voxel more). prev is only read: another thread may
 * align against it meanwhile, and it may be destroyed after. */
pb_regmap_t *pb_regmap_rebuild(const pb_regmap_t *prev, const float *xyz, size_t n,
                              const pb_regmap_config_t *cfg, pb_err_t *err);

void pb_regmap_destroy(pb_regmap_t *m);

/* Information about the loaded map. */
typedef struct {
    int64_t points;          /* map points used */
    int64_t cells;           /* fine cells with a target */
    int64_t planar_cells;    /* of which planes */
    int64_t coarse_cells;
    double min[3], max[3];   /* extent of the points used, map frame */
    double center_xy[2], load_radius_m;  /* the load disc (radius 0 = everything) */
} pb_regmap_info_t;
void pb_regmap_info(const pb_regmap_t *m, pb_regmap_info_t *info);

/* 1 if the horizontal disc of radius r around (x, y) lies inside the loaded
 * disc (always 1 for a whole map), else 0: reload around the car when 0. */
int pb_regmap_covers(const pb_regmap_t *m, double x, double y, double r);

/* Height of the ground (an upward-facing plane cell of the fine level) below or near
 * (x, y): the ground cell in the vertical column at (x, y) whose plane height is nearest
 * z_hint within +-search_m, or with below_only the highest one at most z_hint (the
 * ground under a point). Returns 1 with *z set, or 0 when the column has no ground
 * (off the map, under dense foliage). */
/* The fine level as points, for place descriptors: one per cell (the centroid of a
 * target cell, the centre of a rough one), xyz interleaved, and per point 1 if it is
 * ground (an upward-facing plane), else 0. Both vectors are replaced. */
void pb_regmap_cells(const pb_regmap_t *m, std::vector<float> *xyz, std::vector<uint8_t> *ground);

int pb_regmap_ground_z(const pb_regmap_t *m, double x, double y, double z_hint, double search_m,
                       int below_only, double *z);

#endif
