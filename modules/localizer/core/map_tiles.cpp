/* map_tiles: tiled prepared map and the pager (see map_tiles.h). */
#include "map_tiles.h"
#include "regmap_impl.h"

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <string>
#include <new>
#include <unordered_map>
#include <utility>

using namespace pb_loc;

namespace {

const char kMagic[8] = {'P', 'B', 'T', 'I', 'L', 'E', 'S', '1'};
const uint32_t kVersion = 4;   /* 3: rough cells were keys alone; 2: dense place descriptors (PBPLACE2) */
const size_t kHeaderBytes = 192, kTableBytes = 32, kCellBytes = 48, kRoughBytes = 48;

/* voxels per tile edge, or 0 when tile_m is not a whole multiple of voxel */
int64_t voxels_per_tile(double tile_m, double voxel)
{
    double k = tile_m / voxel;
    int64_t n = (int64_t)std::llround(k);
    return n >= 1 && std::fabs(k - (double)n) < 1e-9 * k ? n : 0;
}

void tile_of_key(uint64_t key, int64_t per_tile, int32_t *tx, int32_t *ty)
{
    int64_t ix, iy, iz;
    voxel_unkey(key, &ix, &iy, &iz);
    *tx = (int32_t)pb_floor_div(ix, per_tile);
    *ty = (int32_t)pb_floor_div(iy, per_tile);
}

template <class T> void put(std::vector<uint8_t> *o, size_t at, T v) { std::memcpy(o->data() + at, &v, sizeof v); }
template <class T> T get(const uint8_t *p) { T v; std::memcpy(&v, p, sizeof v); return v; }

struct TileEntry {
    int32_t tx, ty;
    uint64_t offset;
    uint32_t fine, coarse, rough;
};

uint64_t tile_id(int32_t tx, int32_t ty) { return ((uint64_t)(uint32_t)tx << 32) | (uint32_t)ty; }

}  // namespace

void pb_tiles_config_default(pb_tiles_config_t *cfg)
{
    /* 120 m: the scan range (80 m) plus the start-up / relocalisation search
     * radius and the travel between two paging calls, with margin */
    cfg->load_radius_m = 120;
    cfg->keep_radius_m = 160;
}

namespace {

/* voxels per tile edge of both levels, or -1 (err set) when tile_m is not a whole
 * multiple of them; coarse: whether the map has a coarse level */
int tile_geometry(const pb_regmap_config_t *cfg, double tile_m, bool coarse, int64_t per[2], pb_err_t *err)
{
    per[0] = voxels_per_tile(tile_m, cfg->voxel_m);
    per[1] = coarse ? voxels_per_tile(tile_m, cfg->coarse_voxel_m) : 1;
    if (!(tile_m > 0) || per[0] == 0 || per[1] == 0)
        return pb_err_set(err, "tile edge %g m is not a whole multiple of the voxel sizes %g and %g m", tile_m,
                          cfg->voxel_m, cfg->coarse_voxel_m);
    return 0;
}

/* Appends one tile's bytes: the given fine then coarse cells, then its rough cells (keys of
 * the fine level's, with their Gaussians). */
void put_tile(const Level *lv[2], const std::array<std::vector<uint32_t>, 2> &cells, const std::vector<uint64_t> &rough,
              std::vector<uint8_t> *out)
{
    size_t at = out->size();
    out->resize(at + kCellBytes * (cells[0].size() + cells[1].size()) + kRoughBytes * rough.size(), 0);
    for (int l = 0; l < 2; l++)
        for (uint32_t i : cells[l]) {
            const Cell &c = lv[l]->cells[i];
            put<uint64_t>(out, at, lv[l]->keys[i]);
            std::memcpy(out->data() + at + 8, c.mean, 12);
            std::memcpy(out->data() + at + 20, c.u1, 12);
            std::memcpy(out->data() + at + 32, c.u2, 12);
            (*out)[at + 44] = c.kind;
            at += kCellBytes;
        }
    for (uint64_t key : rough) {
        const Rough &r = lv[0]->roughs[(size_t)lv[0]->rough.find(key)];
        put<uint64_t>(out, at, key);
        std::memcpy(out->data() + at + 8, r.mean, 12);
        std::memcpy(out->data() + at + 20, r.w, 24);
        at += kRoughBytes;
    }
}

}  // namespace

int pb_tiles_encode_head(const pb_regmap_config_t *cfg, double tile_m, const pb_regmap_info_t &info,
                         const std::vector<pb_tiles_row_t> &rows, const pb_tiles_source_t &source,
                         uint64_t places_bytes, std::vector<uint8_t> *out, pb_err_t *err)
{
    int64_t per[2];
    if (tile_geometry(cfg, tile_m, info.coarse_cells > 0, per, err) != 0) return -1;
    out->assign(kHeaderBytes + kTableBytes * rows.size(), 0);
    uint64_t at = out->size();
    for (const pb_tiles_row_t &r : rows) at += ((uint64_t)r.fine + r.coarse) * kCellBytes + (uint64_t)r.rough * kRoughBytes;
    std::memcpy(out->data(), kMagic, 8);
    put<uint32_t>(out, 8, kVersion);
    put<uint32_t>(out, 12, (uint32_t)rows.size());
    put<double>(out, 16, cfg->voxel_m);
    put<double>(out, 24, info.coarse_cells > 0 ? cfg->coarse_voxel_m : 0.0);
    put<double>(out, 32, cfg->planarity_max);
    put<double>(out, 40, tile_m);
    put<int32_t>(out, 48, cfg->min_points);
    put<int64_t>(out, 56, info.points);
    put<int64_t>(out, 64, info.cells);
    put<int64_t>(out, 72, info.coarse_cells);
    for (int a = 0; a < 3; a++) {
        put<double>(out, 80 + 8 * a, info.min[a]);
        put<double>(out, 104 + 8 * a, info.max[a]);
    }
    put<uint64_t>(out, 128, source.bytes);
    put<uint32_t>(out, 136, source.crc32);
    put<uint64_t>(out, 144, places_bytes ? at : 0);
    put<uint64_t>(out, 152, places_bytes);
    size_t row = kHeaderBytes;
    at = out->size();
    for (const pb_tiles_row_t &r : rows) {
        put<int32_t>(out, row, r.tx);
        put<int32_t>(out, row + 4, r.ty);
        put<uint64_t>(out, row + 8, at);
        put<uint32_t>(out, row + 16, r.fine);
        put<uint32_t>(out, row + 20, r.coarse);
        put<uint32_t>(out, row + 24, r.rough);
        row += kTableBytes;
        at += ((uint64_t)r.fine + r.coarse) * kCellBytes + (uint64_t)r.rough * kRoughBytes;
    }
    return 0;
}

int pb_tiles_encode(const pb_regmap_t *map, double tile_m, const pb_tiles_source_t &source,
                    const std::vector<uint8_t> &places, std::vector<uint8_t> *out, pb_err_t *err)
{
    const Level *lv[2] = {&map->fine, &map->coarse};
    int64_t per[2];
    if (tile_geometry(&map->cfg, tile_m, !map->coarse.cells.empty(), per, err) != 0) return -1;
    /* cells of each tile, fine then coarse, in the map's own order (deterministic);
     * then the fine rough cells, sorted by key */
    struct TileCells { std::array<std::vector<uint32_t>, 2> cells; std::vector<uint64_t> rough; };
    std::map<std::pair<int32_t, int32_t>, TileCells> tiles;
    for (int l = 0; l < 2; l++)
        for (size_t i = 0; i < lv[l]->cells.size(); i++) {
            int32_t tx, ty;
            tile_of_key(lv[l]->keys[i], per[l], &tx, &ty);
            tiles[{tx, ty}].cells[l].push_back((uint32_t)i);
        }
    map->fine.rough.for_each([&](uint64_t key, int32_t) {
        int32_t tx, ty;
        tile_of_key(key, per[0], &tx, &ty);
        tiles[{tx, ty}].rough.push_back(key);
    });
    std::vector<pb_tiles_row_t> rows;
    for (auto &t : tiles) {
        std::sort(t.second.rough.begin(), t.second.rough.end());
        rows.push_back({t.first.first, t.first.second, (uint32_t)t.second.cells[0].size(),
                        (uint32_t)t.second.cells[1].size(), (uint32_t)t.second.rough.size()});
    }
    pb_regmap_info_t info = map->info;
    info.cells = (int64_t)map->fine.cells.size();
    info.coarse_cells = (int64_t)map->coarse.cells.size();
    if (pb_tiles_encode_head(&map->cfg, tile_m, info, rows, source, places.size(), out, err) != 0) return -1;
    for (const auto &t : tiles) put_tile(lv, t.second.cells, t.second.rough, out);
    out->insert(out->end(), places.begin(), places.end());
    return 0;
}

int pb_tiles_point_tiles(const pb_regmap_config_t *cfg, double tile_m, const float p[3], int32_t out[9][2])
{
    int n = 0;
    for (int l = 0; l < 2; l++) {
        double voxel = l == 0 ? cfg->voxel_m : cfg->coarse_voxel_m;
        int64_t per = voxel > 0 ? voxels_per_tile(tile_m, voxel) : 0;
        int64_t ix, iy, iz;
        uint64_t key;
        if (per == 0 || !voxel_index_of(p[0], p[1], p[2], 1.0 / voxel, &ix, &iy, &iz) || !voxel_key(ix, iy, iz, &key))
            continue;   /* no coarse level, or a point no voxel of this level holds */
        /* the tiles of the voxel's column and its 8 neighbours, in the order of a walk over
         * them by rows (dy, then dx): one division an axis, as a neighbour is in the next tile
         * only across a border; each distinct tile once, those of the fine level first */
        const int64_t cx = pb_floor_div(ix, per), cy = pb_floor_div(iy, per);
        const int64_t rx = ix - cx * per, ry = iy - cy * per;
        int32_t xs[3], ys[3];
        int nx = 0, ny = 0;
        for (int d = -1; d <= 1; d++) {   /* non-decreasing: a repeat follows its first */
            const int32_t x = (int32_t)(cx - (d < 0 && rx == 0) + (d > 0 && rx == per - 1)),
                          y = (int32_t)(cy - (d < 0 && ry == 0) + (d > 0 && ry == per - 1));
            if (nx == 0 || xs[nx - 1] != x) xs[nx++] = x;
            if (ny == 0 || ys[ny - 1] != y) ys[ny++] = y;
        }
        const int before = n;   /* the fine level's: the coarse one's may repeat them */
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                bool seen = false;
                for (int k = 0; k < before && !seen; k++) seen = out[k][0] == xs[i] && out[k][1] == ys[j];
                if (!seen && n < 9) { out[n][0] = xs[i]; out[n][1] = ys[j]; n++; }
            }
    }
    return n;
}

int pb_tiles_prepare_tile(const pb_regmap_config_t *cfg, double tile_m, int32_t tx, int32_t ty, const float *xyz,
                          size_t n, pb_tiles_row_t *row, std::vector<uint8_t> *out, std::vector<float> *place_xyz,
                          std::vector<uint8_t> *place_ground, pb_err_t *err)
{
    int64_t per[2];
    if (tile_geometry(cfg, tile_m, cfg->coarse_voxel_m > 0, per, err) != 0) return -1;
    Level fine, coarse;
    const Level *lv[2] = {&fine, &coarse};
    std::array<std::vector<uint32_t>, 2> cells;
    std::vector<uint64_t> rough;
    try {
        /* 1. both levels over the tile and its margin: the tile's own cells get their
         *    whole neighbourhood, so the same targets as the whole map's */
        build_level(xyz, n, cfg->voxel_m, cfg, &fine);
        if (cfg->coarse_voxel_m > 0) build_level(xyz, n, cfg->coarse_voxel_m, cfg, &coarse);
        /* 2. the cells of this tile, in the order of the points (the map's order) */
        for (int l = 0; l < 2; l++)
            for (size_t i = 0; i < lv[l]->cells.size(); i++) {
                int32_t cx, cy;
                tile_of_key(lv[l]->keys[i], per[l], &cx, &cy);
                if (cx == tx && cy == ty) cells[l].push_back((uint32_t)i);
            }
        fine.rough.for_each([&](uint64_t key, int32_t) {
            int32_t cx, cy;
            tile_of_key(key, per[0], &cx, &cy);
            if (cx == tx && cy == ty) rough.push_back(key);
        });
        std::sort(rough.begin(), rough.end());
        put_tile(lv, cells, rough, out);
        /* 3. the tile's fine cells as points for the place descriptors (as pb_regmap_cells) */
        for (uint32_t i : cells[0]) {
            const Cell &c = fine.cells[i];
            place_xyz->insert(place_xyz->end(), c.mean, c.mean + 3);
            place_ground->push_back(c.ground());
        }
        for (uint64_t key : rough) {
            int64_t ix, iy, iz;
            voxel_unkey(key, &ix, &iy, &iz);
            float p[3] = {(float)((ix + 0.5) * fine.voxel), (float)((iy + 0.5) * fine.voxel), (float)((iz + 0.5) * fine.voxel)};
            place_xyz->insert(place_xyz->end(), p, p + 3);
            place_ground->push_back(0);
        }
    } catch (const std::bad_alloc &) {
        return pb_err_set(err, "out of memory preparing tile (%d, %d) from %zu points", tx, ty, n);
    }
    *row = {tx, ty, (uint32_t)cells[0].size(), (uint32_t)cells[1].size(), (uint32_t)rough.size()};
    return 0;
}

struct pb_tiles {
    pb_tiles_config_t cfg;
    pb_tiles_read_fn read;
    void *user;
    std::string name;
    uint64_t file_size;
    double tile_m;
    int64_t per_tile[2];
    std::vector<TileEntry> table;
    std::unordered_map<uint64_t, size_t> by_id;   /* tile id -> table row */
    std::vector<char> loaded;                     /* per table row */
    std::vector<uint64_t> rough;                  /* rough keys of the loaded tiles (their targets: map->fine.roughs) */
    pb_tiles_source_t source;
    uint64_t places_offset = 0, places_bytes = 0;
    int tiles_loaded = 0;
    int64_t loads = 0, drops = 0;
    pb_regmap_t *map = nullptr;
    std::vector<uint8_t> buf;                     /* one tile's bytes (reused) */
};

pb_tiles_t *pb_tiles_open(pb_tiles_read_fn read, void *user, uint64_t file_size, const char *name,
                          const pb_tiles_config_t *cfg, pb_err_t *err)
{
    uint8_t h[kHeaderBytes];
    if (file_size < kHeaderBytes || read(user, 0, h, kHeaderBytes) != 0) {
        pb_err_set(err, "%s: byte 0: shorter than the %zu-byte tile header", name, kHeaderBytes);
        return nullptr;
    }
    if (std::memcmp(h, kMagic, 8) != 0) {
        pb_err_set(err, "%s: byte 0: not a map tile file (no PBTILES1 magic)", name);
        return nullptr;
    }
    if (get<uint32_t>(h + 8) != kVersion) {
        pb_err_set(err, "%s: byte 8: tile file version %u, this localizer reads %u (rebuild it with map-tiles)", name,
                   get<uint32_t>(h + 8), kVersion);
        return nullptr;
    }
    std::unique_ptr<pb_tiles_t> t(new (std::nothrow) pb_tiles_t());
    if (!t) { pb_err_set(err, "%s: out of memory", name); return nullptr; }
    pb_tiles_config_default(&t->cfg);
    if (cfg) t->cfg = *cfg;
    t->read = read; t->user = user; t->name = name; t->file_size = file_size;
    uint32_t ntiles = get<uint32_t>(h + 12);
    pb_regmap_config_t mc;
    pb_regmap_config_default(&mc);
    mc.voxel_m = get<double>(h + 16);
    mc.coarse_voxel_m = get<double>(h + 24);
    mc.planarity_max = get<double>(h + 32);
    t->tile_m = get<double>(h + 40);
    mc.min_points = get<int32_t>(h + 48);
    t->per_tile[0] = voxels_per_tile(t->tile_m, mc.voxel_m);
    t->per_tile[1] = mc.coarse_voxel_m > 0 ? voxels_per_tile(t->tile_m, mc.coarse_voxel_m) : 1;
    if (!(mc.voxel_m > 0.01 && mc.voxel_m < 100) || !(mc.coarse_voxel_m >= 0 && mc.coarse_voxel_m < 1000) ||
        !(t->tile_m > 0 && t->tile_m < 1e5) || t->per_tile[0] == 0 || t->per_tile[1] == 0) {
        pb_err_set(err, "%s: byte 16: bad tile geometry (voxel %g m, coarse %g m, tile %g m)", name, mc.voxel_m,
                   mc.coarse_voxel_m, t->tile_m);
        return nullptr;
    }
    if ((file_size - kHeaderBytes) / kTableBytes < ntiles) {
        pb_err_set(err, "%s: byte 12: %u tiles do not fit in %" PRIu64 " bytes", name, ntiles, file_size);
        return nullptr;
    }
    /* the tile table: every tile's cells must lie inside the file */
    std::vector<uint8_t> tb((size_t)ntiles * kTableBytes);
    if (ntiles && read(user, kHeaderBytes, tb.data(), tb.size()) != 0) {
        pb_err_set(err, "%s: byte %zu: cannot read the tile table", name, kHeaderBytes);
        return nullptr;
    }
    t->table.resize(ntiles);
    for (uint32_t i = 0; i < ntiles; i++) {
        const uint8_t *r = tb.data() + (size_t)i * kTableBytes;
        TileEntry &e = t->table[i];
        e.tx = get<int32_t>(r); e.ty = get<int32_t>(r + 4);
        e.offset = get<uint64_t>(r + 8);
        e.fine = get<uint32_t>(r + 16); e.coarse = get<uint32_t>(r + 20); e.rough = get<uint32_t>(r + 24);
        uint64_t bytes = ((uint64_t)e.fine + e.coarse) * kCellBytes + (uint64_t)e.rough * kRoughBytes;
        if (e.offset < kHeaderBytes || e.offset > file_size || bytes > file_size - e.offset ||
            !t->by_id.emplace(tile_id(e.tx, e.ty), i).second) {
            pb_err_set(err, "%s: byte %zu: tile (%d, %d) is out of the file or repeated", name,
                       kHeaderBytes + (size_t)i * kTableBytes, e.tx, e.ty);
            return nullptr;
        }
    }
    t->source.bytes = get<uint64_t>(h + 128);
    t->source.crc32 = get<uint32_t>(h + 136);
    t->places_offset = get<uint64_t>(h + 144);
    t->places_bytes = get<uint64_t>(h + 152);
    if (t->places_bytes && (t->places_offset < kHeaderBytes || t->places_offset > file_size ||
                            t->places_bytes > file_size - t->places_offset)) {
        pb_err_set(err, "%s: byte 144: the place descriptors (%" PRIu64 " bytes at %" PRIu64 ") are out of the file",
                   name, t->places_bytes, t->places_offset);
        return nullptr;
    }
    t->loaded.assign(ntiles, 0);
    t->map = new (std::nothrow) pb_regmap_t();
    if (!t->map) { pb_err_set(err, "%s: out of memory", name); return nullptr; }
    t->map->cfg = mc;
    t->map->cfg.load_radius_m = t->cfg.load_radius_m;
    t->map->fine.voxel = mc.voxel_m; t->map->fine.inv_voxel = 1.0 / mc.voxel_m;
    double cv = mc.coarse_voxel_m > 0 ? mc.coarse_voxel_m : mc.voxel_m;
    t->map->coarse.voxel = cv; t->map->coarse.inv_voxel = 1.0 / cv;
    pb_regmap_info_t &info = t->map->info;
    info.points = get<int64_t>(h + 56);
    for (int a = 0; a < 3; a++) { info.min[a] = get<double>(h + 80 + 8 * a); info.max[a] = get<double>(h + 104 + 8 * a); }
    info.load_radius_m = t->cfg.load_radius_m;
    return t.release();
}

void pb_tiles_destroy(pb_tiles_t *t)
{
    if (!t) return;
    pb_regmap_destroy(t->map);
    delete t;
}

const pb_regmap_t *pb_tiles_map(const pb_tiles_t *t) { return t->map; }

pb_tiles_source_t pb_tiles_source(const pb_tiles_t *t) { return t->source; }

int pb_tiles_read_places(const pb_tiles_t *t, std::vector<uint8_t> *out, pb_err_t *err)
{
    out->clear();
    if (t->places_bytes == 0) return 0;
    try {
        out->resize((size_t)t->places_bytes);
    } catch (const std::bad_alloc &) {
        return pb_err_set(err, "%s: out of memory for %" PRIu64 " bytes of place descriptors", t->name.c_str(),
                          t->places_bytes);
    }
    if (t->read(t->user, t->places_offset, out->data(), out->size()) != 0) {
        out->clear();
        return pb_err_set(err, "%s: byte %" PRIu64 ": cannot read the place descriptors", t->name.c_str(),
                          t->places_offset);
    }
    return 0;
}

namespace {

/* horizontal distance from (x, y) to a tile's square */
double tile_distance(const pb_tiles_t *t, const TileEntry &e, double x, double y)
{
    double x0 = e.tx * t->tile_m, y0 = e.ty * t->tile_m;
    double dx = std::max({x0 - x, 0.0, x - (x0 + t->tile_m)});
    double dy = std::max({y0 - y, 0.0, y - (y0 + t->tile_m)});
    return std::hypot(dx, dy);
}

/* Drops the cells of unloaded tiles from a level, keeping the order of the rest. */
void compact(const pb_tiles_t *t, int l, Level *lv)
{
    size_t w = 0;
    for (size_t i = 0; i < lv->cells.size(); i++) {
        int32_t tx, ty;
        tile_of_key(lv->keys[i], t->per_tile[l], &tx, &ty);
        auto it = t->by_id.find(tile_id(tx, ty));
        if (it == t->by_id.end() || !t->loaded[it->second]) continue;
        lv->cells[w] = lv->cells[i];
        lv->keys[w] = lv->keys[i];
        w++;
    }
    lv->cells.resize(w);
    lv->keys.resize(w);
}

/* Drops the rough cells of unloaded tiles (keys and targets alike). */
void compact_rough(pb_tiles_t *t)
{
    std::vector<Rough> &roughs = t->map->fine.roughs;
    size_t w = 0;
    for (size_t i = 0; i < t->rough.size(); i++) {
        int32_t tx, ty;
        tile_of_key(t->rough[i], t->per_tile[0], &tx, &ty);
        auto it = t->by_id.find(tile_id(tx, ty));
        if (it == t->by_id.end() || !t->loaded[it->second]) continue;
        t->rough[w] = t->rough[i];
        roughs[w] = roughs[i];
        w++;
    }
    t->rough.resize(w);
    roughs.resize(w);
}

/* rough: the level's rough keys, the i-th of lv->roughs[i] (NULL: none) */
void reindex(Level *lv, const std::vector<uint64_t> *rough)
{
    lv->index.reset(lv->cells.size());
    bool inserted;
    for (size_t i = 0; i < lv->keys.size(); i++) lv->index.insert(lv->keys[i], (int32_t)i, &inserted);
    lv->rough.reset(rough ? rough->size() : 0);
    if (rough)
        for (size_t i = 0; i < rough->size(); i++) lv->rough.insert((*rough)[i], (int32_t)i, &inserted);
}

/* Reads one tile and appends its cells; on error nothing is appended. */
int load_tile(pb_tiles_t *t, size_t row, pb_err_t *err)
{
    const TileEntry &e = t->table[row];
    size_t n = (size_t)e.fine + e.coarse;
    t->buf.resize(n * kCellBytes + (size_t)e.rough * kRoughBytes);
    if (!t->buf.empty() && t->read(t->user, e.offset, t->buf.data(), t->buf.size()) != 0)
        return pb_err_set(err, "%s: byte %" PRIu64 ": cannot read tile (%d, %d)", t->name.c_str(), e.offset, e.tx, e.ty);
    /* check everything first, so a corrupt tile leaves the map as it was */
    for (size_t i = 0; i < n; i++) {
        const uint8_t *r = t->buf.data() + i * kCellBytes;
        int l = i < e.fine ? 0 : 1;
        int32_t tx, ty;
        tile_of_key(get<uint64_t>(r), t->per_tile[l], &tx, &ty);
        bool finite = true;
        for (int k = 0; k < 9; k++) finite &= std::isfinite(get<float>(r + 8 + 4 * k));
        uint8_t kind = r[44];
        if (tx != e.tx || ty != e.ty || !finite || (kind != CELL_PLANE && kind != CELL_LINE))
            return pb_err_set(err, "%s: byte %" PRIu64 ": corrupt cell in tile (%d, %d)", t->name.c_str(),
                              e.offset + i * kCellBytes, e.tx, e.ty);
    }
    const uint8_t *rough = t->buf.data() + n * kCellBytes;
    for (size_t i = 0; i < e.rough; i++) {
        const uint8_t *r = rough + i * kRoughBytes;
        int32_t tx, ty;
        tile_of_key(get<uint64_t>(r), t->per_tile[0], &tx, &ty);
        if (tx != e.tx || ty != e.ty)
            return pb_err_set(err, "%s: byte %" PRIu64 ": rough cell of another tile in tile (%d, %d)", t->name.c_str(),
                              e.offset + n * kCellBytes + i * kRoughBytes, e.tx, e.ty);
        bool finite = true;
        for (int k = 0; k < 9; k++) finite &= std::isfinite(get<float>(r + 8 + 4 * k));
        if (!finite || get<float>(r + 20) < 0)   /* w[0], C^-1/2's first diagonal entry: > 0, or 0 for none */
            return pb_err_set(err, "%s: byte %" PRIu64 ": corrupt rough cell in tile (%d, %d)", t->name.c_str(),
                              e.offset + n * kCellBytes + i * kRoughBytes, e.tx, e.ty);
    }
    for (size_t i = 0; i < e.rough; i++) {
        const uint8_t *r = rough + i * kRoughBytes;
        Rough g;
        std::memcpy(g.mean, r + 8, 12);
        std::memcpy(g.w, r + 20, 24);
        t->rough.push_back(get<uint64_t>(r));
        t->map->fine.roughs.push_back(g);
    }
    for (size_t i = 0; i < n; i++) {
        const uint8_t *r = t->buf.data() + i * kCellBytes;
        Level &lv = i < e.fine ? t->map->fine : t->map->coarse;
        Cell c;
        std::memcpy(c.mean, r + 8, 12);
        std::memcpy(c.u1, r + 20, 12);
        std::memcpy(c.u2, r + 32, 12);
        c.kind = r[44];
        lv.cells.push_back(c);
        lv.keys.push_back(get<uint64_t>(r));
    }
    return 0;
}

}  // namespace

int pb_tiles_page(pb_tiles_t *t, double x, double y, pb_err_t *err)
{
    /* 1. which tiles to drop and to load (only rows near the car are looked at) */
    std::vector<size_t> drop, load;
    for (size_t i = 0; i < t->table.size(); i++)
        if (t->loaded[i] && tile_distance(t, t->table[i], x, y) > t->cfg.keep_radius_m) drop.push_back(i);
    int64_t reach = (int64_t)std::ceil(t->cfg.load_radius_m / t->tile_m) + 1;
    int64_t cx = (int64_t)std::floor(x / t->tile_m), cy = (int64_t)std::floor(y / t->tile_m);
    if (!(std::isfinite(x) && std::isfinite(y) && std::fabs(x) < 1e9 && std::fabs(y) < 1e9)) {
        /* no position: nothing to load */
    } else if ((double)(2 * reach + 1) * (2 * reach + 1) > (double)t->table.size()) {
        /* a radius wider than the map: look at every tile instead of every square */
        for (size_t i = 0; i < t->table.size(); i++)
            if (!t->loaded[i] && tile_distance(t, t->table[i], x, y) <= t->cfg.load_radius_m) load.push_back(i);
    } else
        for (int64_t ty = cy - reach; ty <= cy + reach; ty++)
            for (int64_t tx = cx - reach; tx <= cx + reach; tx++) {
                auto it = t->by_id.find(tile_id((int32_t)tx, (int32_t)ty));
                if (it == t->by_id.end() || t->loaded[it->second]) continue;
                if (tile_distance(t, t->table[it->second], x, y) <= t->cfg.load_radius_m) load.push_back(it->second);
            }
    if (drop.empty() && load.empty()) return 0;
    /* 2. drop: remove their cells, keeping the order of the others */
    for (size_t i : drop) t->loaded[i] = 0;
    if (!drop.empty()) { compact(t, 0, &t->map->fine); compact(t, 1, &t->map->coarse); compact_rough(t); }
    /* 3. load: append the new tiles' cells */
    int rc = 0;
    int changed = (int)drop.size();
    for (size_t i : load) {
        if (load_tile(t, i, rc ? nullptr : err) != 0) { rc = -1; continue; }
        t->loaded[i] = 1;
        changed++;
    }
    /* 4. rebuild both hash indexes and the columns over what is loaded */
    reindex(&t->map->fine, &t->rough);
    reindex(&t->map->coarse, nullptr);
    columns_build(t->map->fine, &t->map->columns);
    t->map->columns_made = true;
    t->tiles_loaded += changed - 2 * (int)drop.size();
    t->loads += changed - (int64_t)drop.size();
    t->drops += (int64_t)drop.size();
    pb_regmap_info_t &info = t->map->info;
    info.cells = (int64_t)t->map->fine.cells.size();
    info.coarse_cells = (int64_t)t->map->coarse.cells.size();
    info.planar_cells = 0;
    for (const Cell &c : t->map->fine.cells) info.planar_cells += c.kind == CELL_PLANE;
    info.center_xy[0] = x;
    info.center_xy[1] = y;
    return rc < 0 ? -1 : changed;
}

void pb_tiles_stats(const pb_tiles_t *t, pb_tiles_stats_t *st)
{
    st->tiles_total = (int)t->table.size();
    st->tiles_loaded = t->tiles_loaded;
    st->fine_cells = (int64_t)t->map->fine.cells.size();
    st->coarse_cells = (int64_t)t->map->coarse.cells.size();
    st->rough_cells = (int64_t)t->rough.size();
    st->loads = t->loads;
    st->drops = t->drops;
    st->tile_m = t->tile_m;
}
