/* map_tiles: the prior map cut into square tiles of prepared cells, so the
 * localizer holds only the tiles around the car and pages as it moves (maps of
 * any size, memory bounded by the load radius, not by the map).
 *
 * At map build time (tools/map-tiles, `make` for the default site, the mapper's
 * last step) the map is prepared tile by tile: each tile's cells (planes and lines
 * of the fine and the coarse level, each fitted to its 3x3x3 neighbourhood) are
 * fitted from the tile's points and a margin of one voxel of either level from the
 * adjacent tiles, so each cell sees its whole neighbourhood, as in a whole-map
 * preparation: the file is byte for byte the one pb_tiles_encode writes from the
 * whole map, and memory follows a tile, not the map. A tile loaded at run time
 * therefore holds exactly the cells a whole-map load would have there: where the
 * loaded tiles cover the scan, registration gives bit-identical poses with and
 * without paging.
 *
 * Each tile also holds its rough cells (fine voxels of structure that fits no plane
 * or line: trees, bushes, fences) with their Gaussians: registration's target where
 * no plane or line is near, and map evidence for the structure test. The place descriptors of the whole map (core/places, for a
 * start with no prior) are stored once after the tiles: they are small (held
 * sparsely, in the blocks of columns that have map cells) and a global search needs
 * all of them.
 *
 * File (little-endian, written and read by this code only):
 *   header, 192 bytes: "PBTILES1", u32 version (4; 3 had rough cells without
 *     their Gaussians, 2 dense place descriptors: both refused), u32 tiles, f64 voxel_m,
 *     coarse_voxel_m, planarity_max, tile_m, i32 min_points, i32 0,
 *     i64 map points, fine cells, coarse cells, f64 min[3], max[3],
 *     (128) u64 source bytes, u32 source CRC-32, u32 0 (the map.pcd it was
 *     prepared from), u64 places offset, u64 places bytes, 32 bytes 0
 *   tile table, 32 bytes a tile: i32 tx, ty (tile = floor(x / tile_m)),
 *     u64 byte offset, u32 fine cells, u32 coarse cells, u32 rough cells, u32 0
 *   a tile: its fine cells then its coarse cells, 48 bytes each: u64 voxel
 *     key, f32 mean[3], u1[3], u2[3], u8 kind (1 plane, 2 line), 3 bytes 0;
 *     then its rough cells, 48 bytes each: u64 voxel key, f32 mean[3], f32 w[6]
 *     (C^-1/2's upper triangle; w[0] = 0: too few points for a target), 4 bytes 0
 *   places: the bytes of places_encode (core/places.h)
 *
 * Pure: reading is through a callback the caller provides (the shell does the
 * file I/O); no clocks.
 * Ownership: pb_tiles_open returns a pager the caller frees with
 * pb_tiles_destroy; it owns the map pb_tiles_map returns (valid until then; its
 * contents change only inside pb_tiles_page, never behind the caller's back).
 * Errors: -1 / NULL with pb_err_t naming the file and the byte offset. */
#ifndef PB_LOC_MAP_TILES_H
#define PB_LOC_MAP_TILES_H

#include <stddef.h>
#include <stdint.h>
#include <vector>
#include "pb_err.h"
#include "regmap.h"

typedef struct {
    double load_radius_m;   /* tiles within this horizontal distance of the car are loaded (default 120) */
    double keep_radius_m;   /* loaded tiles are dropped beyond this (hysteresis; default 160) */
} pb_tiles_config_t;

void pb_tiles_config_default(pb_tiles_config_t *cfg);

/* The map file the tiles were prepared from: a tile file that does not match the
 * site's map.pcd must not be used. */
typedef struct {
    uint64_t bytes;
    uint32_t crc32;
} pb_tiles_source_t;

/* Encodes a whole prepared map into the tile file format (out is replaced).
 * tile_m must be a whole multiple of both voxel sizes of the map. places: the
 * place descriptors' bytes (may be empty: no global search with this file). */
int pb_tiles_encode(const pb_regmap_t *map, double tile_m, const pb_tiles_source_t &source,
                    const std::vector<uint8_t> &places, std::vector<uint8_t> *out, pb_err_t *err);

/* The tiled preparation (maps larger than memory; the shell streams the points and
 * holds them per tile on disk):
 * 1. every point goes to the tiles pb_tiles_point_tiles names: its own and, within one
 *    voxel of either level of a border, the adjacent ones (their margin);
 * 2. each tile is prepared from the points sent to it, in the map's order
 *    (pb_tiles_prepare_tile): its cells are those a whole-map preparation has there, in
 *    the same order; a tile with no cells is left out of the file;
 * 3. pb_tiles_encode_head writes the header and the tile table (rows in (tx, ty) order)
 *    that go before the tiles' bytes, which are followed by the place descriptors.
 * The result is byte for byte pb_tiles_encode's of the whole map. */
typedef struct {
    int32_t tx, ty;
    uint32_t fine, coarse, rough;   /* cells of the tile */
} pb_tiles_row_t;

/* The tiles (at most 9, written to out) whose preparation needs point p. Returns how
 * many (0: no voxel holds it; it still counts in the map's points and extent). */
int pb_tiles_point_tiles(const pb_regmap_config_t *cfg, double tile_m, const float p[3], int32_t out[9][2]);

/* Prepares tile (tx, ty) from the n points (xyz interleaved, the map's order) sent to it:
 * appends its bytes to out, sets *row (counts 0: no cells), and appends its fine cells
 * and rough cells as points to place_xyz / place_ground (as pb_regmap_cells gives them,
 * for places_builder). Returns 0, or -1 (bad tile edge, out of memory; err set). */
int pb_tiles_prepare_tile(const pb_regmap_config_t *cfg, double tile_m, int32_t tx, int32_t ty, const float *xyz,
                          size_t n, pb_tiles_row_t *row, std::vector<uint8_t> *out, std::vector<float> *place_xyz,
                          std::vector<uint8_t> *place_ground, pb_err_t *err);

/* The header and tile table (out replaced) of a file whose rows' tiles follow in the
 * rows' order, then places_bytes of place descriptors. info: the map's points, extent,
 * fine cells (cells) and coarse cells (coarse_cells). Returns 0 or -1 (bad tile edge). */
int pb_tiles_encode_head(const pb_regmap_config_t *cfg, double tile_m, const pb_regmap_info_t &info,
                         const std::vector<pb_tiles_row_t> &rows, const pb_tiles_source_t &source,
                         uint64_t places_bytes, std::vector<uint8_t> *out, pb_err_t *err);

/* Reads len bytes at offset into buf; returns 0, or -1 when they cannot all be read. */
typedef int (*pb_tiles_read_fn)(void *user, uint64_t offset, void *buf, size_t len);

typedef struct pb_tiles pb_tiles_t;

/* Reads and checks the header and the tile table (file_size bytes in all);
 * name is used in messages. Nothing is loaded until pb_tiles_page. */
pb_tiles_t *pb_tiles_open(pb_tiles_read_fn read, void *user, uint64_t file_size, const char *name,
                          const pb_tiles_config_t *cfg, pb_err_t *err);
void pb_tiles_destroy(pb_tiles_t *t);

/* The map file the tiles were prepared from (from the header). */
pb_tiles_source_t pb_tiles_source(const pb_tiles_t *t);

/* Reads the stored place descriptors' bytes (out replaced; empty when the file has
 * none). Returns 0, or -1 when they cannot be read. */
int pb_tiles_read_places(const pb_tiles_t *t, std::vector<uint8_t> *out, pb_err_t *err);

/* The paged map (empty until the first pb_tiles_page). */
const pb_regmap_t *pb_tiles_map(const pb_tiles_t *t);

/* Brings the loaded tiles to those around map (x, y): loads every tile within
 * load_radius_m, drops those beyond keep_radius_m. Returns the number of tiles
 * loaded plus dropped (0: nothing changed, cheap), or -1 when a tile cannot be
 * read or is corrupt (err set; the tiles that could be read are in use and the
 * bad one is tried again at the next call). */
int pb_tiles_page(pb_tiles_t *t, double x, double y, pb_err_t *err);

typedef struct {
    int tiles_total, tiles_loaded;
    int64_t fine_cells, coarse_cells, rough_cells;   /* loaded */
    int64_t loads, drops;               /* tiles, since open */
    double tile_m;
} pb_tiles_stats_t;
void pb_tiles_stats(const pb_tiles_t *t, pb_tiles_stats_t *st);

#endif
