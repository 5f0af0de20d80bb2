/* libFuzzer target: a map tile file (modules/localizer/core/map_tiles) and the place
 * descriptors stored in it (core/places) from arbitrary bytes: open, page at a few
 * places, read and decode the descriptors, query them; and the descriptors' decoder
 * on the bytes alone. Errors are expected; crashes and undefined behaviour are not.
 * fuzz-sources: modules/localizer/core/map_tiles.cpp modules/localizer/core/regmap.cpp modules/localizer/core/places.cpp modules/localizer/core/window_search.cpp common/pb_err.c common/pb_pcd.c
 * fuzz-libs: -Wno-deprecated -Imodules/localizer/core -I/usr/include/pcl-1.13 -I/usr/include/eigen3 -lpcl_io -lpcl_common */
#include <cstdint>
#include <cstring>
#include <vector>

#include "map_tiles.h"
#include "places.h"

struct Bytes { const uint8_t *p; size_t n; };

static int mem_read(void *user, uint64_t off, void *buf, size_t len)
{
    const Bytes *b = (const Bytes *)user;
    if (off > b->n || len > b->n - off) return -1;
    std::memcpy(buf, b->p + off, len);
    return 0;
}

static void query(const pb_loc::places_t *p)
{
    float scan[9] = { 3, 1, 2, -5, 4, 3, 10, -2, 1 };
    pb_loc::place_desc_t d;
    pb_loc::places_describe(p, scan, 3, &d);
    std::vector<pb_loc::place_match_t> m;
    pb_loc::places_query(p, d, 4, &m);
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    Bytes b = { data, size };
    pb_err_t err;
    pb_tiles_t *t = pb_tiles_open(mem_read, &b, size, "fuzz.tiles", nullptr, &err);
    if (t) {
        const double at[4][2] = { { 0, 0 }, { 100, 50 }, { -300, 20 }, { 0, 0 } };
        for (const auto &xy : at) pb_tiles_page(t, xy[0], xy[1], &err);
        std::vector<uint8_t> pb;
        if (pb_tiles_read_places(t, &pb, &err) == 0 && !pb.empty()) {
            char msg[200];
            pb_loc::places_t *p = pb_loc::places_decode(pb.data(), pb.size(), msg, sizeof msg);
            if (p) query(p);
            pb_loc::places_destroy(p);
        }
        pb_tiles_destroy(t);
    }
    char msg[200];
    pb_loc::places_t *p = pb_loc::places_decode(data, size, msg, sizeof msg);
    if (p) query(p);
    pb_loc::places_destroy(p);
    return 0;
}
