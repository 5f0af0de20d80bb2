/* The site's ground model: a height grid of the drivable and walkable surface
 * (SITE/ground.yaml + ground.pgm, docs/sites.md). Built from the prior map by
 * tools/build-ground; read by the director (agents' feet, trigger volume heights)
 * and the lab twin (its pose's z, roll, pitch), so both platforms put things at
 * the same heights.
 *
 * Format: ground.yaml (origin_x, origin_y: map position of corner (0, 0); cell_m;
 * width, height: corners; z0_m, scale_m: height = z0_m + (v - 1) scale_m; file) and
 * either a 16-bit binary PGM (P5, maxval 65535, big-endian, row 0 = y origin) where
 * v = 0 is "unknown" (no ground seen there), or, for a large or mostly unknown grid (the
 * extent of a long drive), the blocked file (ground.yaml with `block` and `blocks`): only the blocks of
 * corners that hold known ground (docs/sites.md).
 *
 * Memory: the grid is held in blocks of PB_GROUND_BLOCK x PB_GROUND_BLOCK corners, made
 * when a corner in them is set known; what is unknown costs nothing but a block's
 * absence, so a model follows the ground seen, not the extent (width x height).
 *
 * Ownership: pb_ground_create / pb_ground_load return a grid the caller frees with
 * pb_ground_destroy (NULL is a no-op). */
#ifndef PB_GROUND_H
#define PB_GROUND_H

#include <stddef.h>

#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct pb_ground pb_ground_t;

/* A grid of nx x ny corners at (x0 + i cell, y0 + j cell), all unknown (nothing held).
 * NULL if cell <= 0, nx or ny < 2 or over 2^28. */
pb_ground_t *pb_ground_create(double x0, double y0, double cell, int nx, int ny);
void pb_ground_destroy(pb_ground_t *g);
void pb_ground_set(pb_ground_t *g, int ix, int iy, double z);    /* NAN: unknown */
double pb_ground_get(const pb_ground_t *g, int ix, int iy);        /* NAN if unknown or outside */
void pb_ground_dims(const pb_ground_t *g, double *x0, double *y0, double *cell, int *nx, int *ny);

/* Writes YAML_PATH and next to it (same name) the PGM (.pgm) or, when the grid has more
 * than PB_GROUND_DENSE_MAX corners or fewer than a quarter of its blocks hold a known
 * corner, the blocks (.blocks); heights are rounded to 1 mm. 0 or -1 with err (also when
 * memory ran out while the model was set: heights were dropped, so it is not written). */
#define PB_GROUND_DENSE_MAX (1L << 24)
int pb_ground_save(const pb_ground_t *g, const char *yaml_path, pb_err_t *err);
/* Reads a ground model (either file); a bad file is refused with FILE:LINE or the PGM's
 * or the blocks' byte offset. */
pb_ground_t *pb_ground_load(const char *yaml_path, pb_err_t *err);

/* Height at (x, y): bilinear over the cell's known corners (renormalised when some
 * are unknown). 0, or -1 when no corner of the cell is known (*z untouched). */
int pb_ground_height(const pb_ground_t *g, double x, double y, double *z);
/* A car standing at (x, y) with heading yaw: its base height (mean of the rear
 * contacts), roll and pitch (ZYX, rad; pitch > 0 nose down) from the ground under
 * its four tyre contacts. 0, or -1 if any contact is over unknown ground. */
int pb_ground_car(const pb_ground_t *g, double x, double y, double yaw, double wheelbase, double track,
                  double *z, double *roll, double *pitch);

/* Block by block, for code that walks the grid (tools/build-ground): block (bx, by) holds
 * corners (bx B + i, by B + j), i, j < B, row-major (j, then i); corners beyond width or
 * height stay unknown. */
#define PB_GROUND_BLOCK 64
const float *pb_ground_block(const pb_ground_t *g, int bx, int by);   /* NULL: not held (all unknown) */
/* The block, made all unknown if not held; NULL if outside the grid or out of memory. */
float *pb_ground_block_make(pb_ground_t *g, int bx, int by);
/* The number of blocks held; and when bxy is not NULL (room for 2 ints a block), which,
 * by row then column: bxy[2k] = bx, bxy[2k + 1] = by. */
size_t pb_ground_blocks(const pb_ground_t *g, int *bxy);

#ifdef __cplusplus
}
#endif
#endif
