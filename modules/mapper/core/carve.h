/* carve: removes what moved from the mapper's map. A place the LiDAR saw through again and
 * again was empty most of the time: what the map holds there (a car that drove by, a
 * pedestrian) was there only for a moment. Each sampled ray of the drive counts a hit in
 * the cell it ended in and a pass in every occupied cell it crossed on the way; a cell
 * passed through more than `pass_ratio` times as often as it was hit (and at least
 * `min_passes` times), and hit only within `transient_s`, is carved: its map points go.
 * A cell the sampled rays never hit counts too (its points came from rays left out of the
 * sample); keeping those carved fewer than half as many points of passing traffic and a
 * larger share of the static world on the simulated loop.
 * The span matters: a wall seen edge-on is passed through by the rays that graze it, but
 * it is hit all the time the car drives along it; a car driving by is hit for a moment.
 *
 * Cells are `cell_m` cubes over the map's points. What a ray crosses near its end is not
 * counted (the end's own cell, and `end_margin_m` before it: the beam's footprint and the
 * pose's error there), nor cells within `ground_band_m` above the ground model (grazing rays
 * run along the road for metres before they hit it). What stood still through the drive
 * (parked cars) stays: one drive cannot tell it from the world.
 *
 * Pure: no I/O, no clock. Ownership: pb_carve_create copies what it needs; the caller
 * frees the result with pb_carve_destroy (NULL is a no-op). */
#ifndef PB_MAPPER_CARVE_H
#define PB_MAPPER_CARVE_H

#include <stddef.h>
#include <stdint.h>
#include <vector>
#include "pb_ground.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double cell_m = 0.5;
    double end_margin_m = 1.0;
    double ground_band_m = 0.4;
    double pass_ratio = 5.0;
    int min_passes = 8;
    double max_range_m = 60;   /* rays are cut here: farther, beams are wide and poses' errors grow */
    double transient_s = 3;    /* a cell hit over a longer span than this was there, not passing by */
} pb_carve_config_t;

typedef struct pb_carve pb_carve_t;

/* The cells of n map points (x, y, z floats, stride floats apart); ground NULL = none. */
pb_carve_t *pb_carve_create(const float *xyz, size_t n, size_t stride, const pb_ground_t *ground,
                            const pb_carve_config_t *cfg);
void pb_carve_destroy(pb_carve_t *c);

/* One ray of a sweep at utime, from the sensor's origin to its return, both in the map frame. */
void pb_carve_ray(pb_carve_t *c, int64_t utime, const double origin[3], const double end[3]);

/* Per map point (as given to create): 1 keep, 0 carved. Returns the number carved. */
size_t pb_carve_keep(const pb_carve_t *c, std::vector<uint8_t> *keep);

#endif
