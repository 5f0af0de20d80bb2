// map-tiles: a site's prior map (map.pcd) -> map.tiles, the prepared map cut into
// square tiles that the localizer pages in around the car (modules/localizer/core/map_tiles.h).
#include <cstdio>
#include <string>
#include <vector>

#include "map_source.h"
#include "pb_err.h"
#include "pb_opt.h"

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: map-tiles --map SITE/map.pcd --out SITE/map.tiles [--tile 32] [--quiet]\n"
        "\n"
        "Prepares the map (planes and lines at 0.5 m and 2 m, and the rough cells of structure\n"
        "that fits neither) into square tiles of --tile metres, followed by the place\n"
        "descriptors of the whole map (for a start with no prior) and the size and CRC-32 of\n"
        "map.pcd (tiles of another map are refused). It works a tile at a time (each with a\n"
        "margin of its neighbours' points, held on disk beside OUT meanwhile): its memory is a\n"
        "tile and the place descriptors, not the map; the file is the whole-map preparation's.\n"
        "The localizer pages the tiles: only those within 120 m of the car are held, so memory\n"
        "does not grow with the map.\n"
        "The output is written to OUT.tmp and renamed, so a failed run leaves no half file.\n"
        "  --tile M   tile edge in metres, a multiple of 2 (default 32)\n"
        "  --quiet    no summary line\n");
}

int main(int argc, char **argv)
{
    const char *map_path = nullptr, *out_path = nullptr;
    double tile = 32;
    bool quiet = false;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("map", &map_path), PB_OPT_REQUIRED("out", &out_path), PB_OPT_DOUBLE("tile", &tile, 2, 10000),
        PB_OPT_BOOL("quiet", &quiet, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("map-tiles", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    pb_err_t err;
    pb_regmap_info_t info;
    size_t places = 0, bytes = 0;
    if (map_source_write_tiles(map_path, out_path, tile, &info, &places, &bytes, &err) != 0) {
        std::fprintf(stderr, "map-tiles: %s\n", err.msg);
        return 1;
    }
    if (!quiet)
        std::printf("map-tiles: %s: %lld points -> %lld fine + %lld coarse cells in %.0f m tiles, %zu places, %s "
                    "(%.1f MB)\n", map_path, (long long)info.points, (long long)info.cells, (long long)info.coarse_cells,
                    tile, places, out_path, bytes / 1e6);
    return 0;
}
