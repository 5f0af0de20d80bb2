/* Terrain: the simulated site's true ground, a height field (world.yaml `terrain:`).
 *
 * The ground is described along the route: the road centre's height at route arc
 * length s (periodic Catmull-Rom knots: grades, crests, sags), an optional bank
 * (cross slope of the whole road, + = left side higher), a crown (both halves fall
 * towards the kerbs), a kerb step and a sloped sidewalk; beyond the sidewalk the
 * ground stays at the sidewalk's outer height. That description is sampled once
 * into a raster (`cell` metres); the bilinear interpolation of the raster IS the
 * truth the LiDAR ray-casts and the ground model is compared against. The car's
 * wheels use the smooth description itself (terrain_height_near), which agrees with
 * the raster to millimetres on the road and has no cell-edge kinks (the IMU would
 * see them as spikes).
 *
 * Ownership: terrain_load fills a caller-owned terrain_t; terrain_free releases it.
 * A site without `terrain:` has the plane z = 0 (enabled = 0; every function then
 * returns 0 heights and the plane intersection). */
#ifndef SIM_TERRAIN_H
#define SIM_TERRAIN_H

#include "pb_config.h"
#include "pb_err.h"
#include "pb_ground.h"
#include "pb_route.h"

typedef struct {
    int enabled;
    const pb_route_t *route;
    int nknots;
    double *ks, *kz, *kbank;    /* knots: arc length (m), road-centre height (m), bank (fraction) */
    double crown, centre_off, road_half, kerb, sidewalk_w, sidewalk_slope;
    /* raster */
    double x0, y0, cell;
    int nx, ny;
    float *h;                   /* nx * ny heights: h[iy * nx + ix] at (x0 + ix cell, y0 + iy cell) */
    unsigned char *walk;        /* per sample: 1 on the road, kerb or sidewalk (drivable or walkable) */
    /* maxima over coarser and coarser cells, for skipping empty space in ray casts */
    int nlevels;
    struct { double cell; int nx, ny; float *max; } lv[3];
    double hmax;
} terrain_t;

/* Reads the `terrain` mapping (node may be NULL: flat) and samples the raster over
 * the route's extent plus margin_m. 0 or -1 with FILE:LINE in err. */
int terrain_load(terrain_t *T, const pb_cfg_node_t *node, const pb_route_t *route, double margin_m, pb_err_t *err);
void terrain_free(terrain_t *T);

/* True height (raster, bilinear) at (x, y); outside the raster: the nearest edge. */
double terrain_height(const terrain_t *T, double x, double y);
/* The smooth description at (x, y), projecting onto the route near arc length s_guess. */
double terrain_height_near(const terrain_t *T, double x, double y, double s_guess);
/* 1 if (x, y) is on the road, kerb or sidewalk band (drivable or walkable). */
int terrain_walkable(const terrain_t *T, double x, double y);
/* The raster as a ground model (pb_ground, caller destroys): every sample, or with
 * walk_only the drivable and walkable band only (what a map-built model is measured
 * on). NULL without a terrain. */
pb_ground_t *terrain_ground(const terrain_t *T, int walk_only);
/* First intersection t in (0, tmax] of o + t d with the ground, or INFINITY. */
double terrain_raycast(const terrain_t *T, const double o[3], const double d[3], double tmax);

#endif
