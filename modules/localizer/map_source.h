/* map_source: the localizer's prior map from a site folder, paged in tiles.
 *
 * SITE/map.tiles (tools/map-tiles; built by `make` for the bundled sites) is paged:
 * only the tiles around the car are held (core/map_tiles), so memory follows the
 * load radius, not the map. The file also carries the rough-structure cells and the
 * place descriptors of the whole map (global search without a prior). A map.tiles
 * prepared from another map.pcd than the site's (size or CRC-32 differ) is an error
 * naming both: it would localize in yesterday's map. A site with map.pcd alone is
 * prepared at start-up into a temporary tile file (tile by tile, as map-tiles does;
 * build map.tiles once to start faster).
 *
 * Shell code (file I/O). Ownership: map_source_open returns an object freed with
 * map_source_close; map_source_map's pointer is valid until then, its contents
 * change only in map_source_page. */
#ifndef LOC_MAP_SOURCE_H
#define LOC_MAP_SOURCE_H

#include <string>
#include <vector>
#include "core/map_tiles.h"
#include "core/places.h"
#include "core/regmap.h"

typedef struct map_source map_source_t;

enum { MAP_SOURCE_TILE_M = 32 };   /* default tile edge, metres */

/* Size and CRC-32 of a map file (identifies the map.pcd a tile file was made from). */
int map_source_file_id(const char *path, pb_tiles_source_t *id, pb_err_t *err);

/* map.pcd prepared (cells, rough cells, place descriptors) and written as a tile file to
 * out_path (through out_path.tmp, renamed: a failed run leaves no half file). Tile by tile
 * (core/map_tiles.h): the points are streamed (binary PCD; other forms are read whole) and
 * held per tile in scratch files beside out_path, so memory follows a tile, not the map;
 * the file is byte for byte what a whole-map preparation gives. info (may be NULL): the
 * points, extent and cells; *places, *bytes (may be NULL): places and the file's size. */
int map_source_write_tiles(const char *pcd, const char *out_path, double tile_m, pb_regmap_info_t *info,
                           size_t *places, size_t *bytes, pb_err_t *err);

/* site: the folder; cfg NULL = default radii. */
map_source_t *map_source_open(const std::string &site, const pb_tiles_config_t *cfg, pb_err_t *err);
void map_source_close(map_source_t *s);
const pb_regmap_t *map_source_map(const map_source_t *s);
/* The file in use, for messages. */
const char *map_source_path(const map_source_t *s);
/* The stored place descriptors (caller frees with places_destroy), or NULL: with err
 * set when they are damaged, with err.msg empty when the file has none. */
pb_loc::places_t *map_source_places(const map_source_t *s, pb_err_t *err);
/* Pages around map (x, y). Returns as pb_tiles_page. */
int map_source_page(map_source_t *s, double x, double y, pb_err_t *err);
void map_source_stats(const map_source_t *s, pb_tiles_stats_t *st);

#endif
