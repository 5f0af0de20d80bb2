/* carve: removes what moved from the mapper's map. A place the LiDAR saw through before or
 * after the moment it was hit was empty then: what the map holds there (a car that drove by,
 * a pedestrian) was there only for a moment. Each sampled ray of the drive counts a hit in the
 * cell it ended in and a pass in every occupied cell it crossed on the way. Only the passes
 * outside the span of a cell's hits count (before its first hit, after its last): a cell
 * passed through at least `min_passes` times so, and hit only within `transient_s`, is
 * carved: its map points go. A cell the sampled rays never hit has no span: all its passes
 * count (its points came from rays left out of the sample).
 * Passes outside the span tell a car that drove by (seen through after it left) from a
 * wall seen edge-on (its grazing rays pass through its cells while it is hit), and a static
 * thing hit by few sampled rays from one that was there for a moment. The first version
 * (all passes against five times the hits, the whole ground band spared) left 37 times as
 * many points on moving objects of the simulated loop and carved more of the static world.
 *
 * Cells are `cell_m` cubes over the map's points. What a ray crosses near its end is not
 * counted (the end's own cell, and `end_margin_m` before it: the beam's footprint and the
 * pose's error there). Cells within `ground_band_m` above the ground model are never carved
 * (grazing rays run along the road for metres before they hit it), but their points higher
 * than `raise_m` over the ground (at the cell's centre) are judged apart, as a cell of their
 * own: hits that end there and passes of rays that stay higher through the cell (a car's
 * sill over the road; it shared its cell with the road, hit all drive long). What stood still
 * through the drive (parked cars, a pedestrian waiting at a crossing) stays: one drive cannot
 * tell it from the world. Several drives of the course can: a cell passed through at least
 * `min_passes` times in one drive and not hit in it was empty that day, and what the other
 * drives saw there (a car parked then gone) is carved too (pb_carve_next_drive between them). A cell's span of
 * hits is then each drive's own: a cell hit only briefly in every drive that hit it, and passed
 * through outside those spans min_passes times in all, is carved too.
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
    double raise_m = 0.1;      /* a band cell's points higher over the ground than this are judged apart */
    int min_passes = 12;       /* passes outside the span the cell was hit in */
    double max_range_m = 60;   /* rays are cut here: farther, beams are wide and poses' errors grow */
    double transient_s = 2;    /* a cell hit over a longer span than this was there, not passing by */
} pb_carve_config_t;

typedef struct pb_carve pb_carve_t;

/* The cells of n map points (x, y, z floats, stride floats apart); ground NULL = none. */
pb_carve_t *pb_carve_create(const float *xyz, size_t n, size_t stride, const pb_ground_t *ground,
                            const pb_carve_config_t *cfg);
void pb_carve_destroy(pb_carve_t *c);

/* One ray of a sweep at utime, from the sensor's origin to its return, both in the map frame. */
void pb_carve_ray(pb_carve_t *c, int64_t utime, const double origin[3], const double end[3]);

/* The rays that follow are of the next drive (their utimes must not overlap the last's). */
void pb_carve_next_drive(pb_carve_t *c);

/* Per map point (as given to create): 1 keep, 0 carved. Returns the number carved. */
size_t pb_carve_keep(const pb_carve_t *c, std::vector<uint8_t> *keep);

#endif
