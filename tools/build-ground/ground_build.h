/* The ground model from a prior map (pure: no I/O).
 *
 * Per cell, the lowest map point; a cell is ground when that point lies at most
 * `step_m` + `grade` x `window_m` above the lowest one within window_m (a kerb or a
 * slope passes; the roof or the side of a parked car or a wall above the ground
 * does not), then a 3x3 median of the ground cells removes single outliers and
 * cells up to fill_m from ground take the mean of their known neighbours (the road
 * under a parked car). Everything else stays unknown.
 *
 * Memory: every grid is a pb_ground_t, held in blocks where the map has points (and the
 * filling reaches): it follows the map's points, not its extent.
 *
 * Ownership: gb_build returns a pb_ground_t the caller destroys. */
#ifndef GROUND_BUILD_H
#define GROUND_BUILD_H

#include <stddef.h>
#include "pb_ground.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    double cell_m;      /* grid spacing (default 0.25) */
    double window_m;    /* radius of the lowest-point window (default 1.0) */
    double step_m;      /* a kerb or step allowed above the window's lowest point (default 0.18) */
    double grade;       /* slope allowed across the window (default 0.12) */
    double fill_m;      /* holes filled this far from ground (default 2.5) */
} gb_config_t;

void gb_config_default(gb_config_t *c);
/* points: n x (x, y, z) floats, stride floats apart. NULL if n == 0 or out of memory.
 * *nground counts ground cells before filling. */
pb_ground_t *gb_build(const float *points, size_t n, size_t stride, const gb_config_t *c, size_t *nground);

/* The same from a map given in parts (a map too large to hold at once): the extent of all
 * its points first (gb_bounds over every part), then every part added (points outside
 * those bounds are dropped), then finished; the result is gb_build's on the whole map. Ownership: gb_begin returns an object that
 * gb_finish frees (NULL: no finite point, or out of memory). */
typedef struct gb_accum gb_accum_t;
void gb_bounds(const float *points, size_t n, size_t stride, double lo[2], double hi[2]);   /* start lo +inf, hi -inf */
gb_accum_t *gb_begin(const double lo[2], const double hi[2], const gb_config_t *c);
void gb_add(gb_accum_t *a, const float *points, size_t n, size_t stride);
pb_ground_t *gb_finish(gb_accum_t *a, size_t *nground);

#ifdef __cplusplus
}
#endif
#endif
