/* map_source: the localizer's prior map from a site folder, whole or paged.
 *
 * With paged = true, SITE/map.tiles (tools/map-tiles; built by `make` for the
 * default site) is paged: only the tiles around the car are held
 * (core/map_tiles). Otherwise SITE/map.pcd is loaded whole, as before. The
 * tile format does not carry the rough-structure cells yet, and place
 * descriptors built from a paged map see only the loaded tiles: opt-in. A map.tiles older than map.pcd is
 * an error naming both (it would localize in yesterday's map).
 *
 * Shell code (file I/O). Ownership: map_source_open returns an object freed
 * with map_source_close; map_source_map's pointer is valid until then. */
#ifndef LOC_MAP_SOURCE_H
#define LOC_MAP_SOURCE_H

#include <string>
#include "core/map_tiles.h"
#include "core/regmap.h"

typedef struct map_source map_source_t;

/* site: the folder; cfg NULL = default radii (ignored for a whole map). */
map_source_t *map_source_open(const std::string &site, bool paged, const pb_tiles_config_t *cfg, pb_err_t *err);
void map_source_close(map_source_t *s);
const pb_regmap_t *map_source_map(const map_source_t *s);
/* 1 when paged (map.tiles), 0 when whole. */
int map_source_paged(const map_source_t *s);
/* The file in use (map.tiles or map.pcd), for messages. */
const char *map_source_path(const map_source_t *s);
/* Pages around map (x, y); a no-op for a whole map. Returns as pb_tiles_page. */
int map_source_page(map_source_t *s, double x, double y, pb_err_t *err);
void map_source_stats(const map_source_t *s, pb_tiles_stats_t *st);

#endif
