/* places: Scan-Context-like place recognition in the prior map (see places.h). */
#include "places.h"
#include "pb_split.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <unordered_map>

namespace pb_loc {

namespace {

const double kColumn = 1.0;   /* the map is summarised in 1 m columns */

struct column_t {
    float ground = NAN;       /* the ground's height (NaN: none seen, filled from neighbours) */
    float height = 0;         /* highest structure above the ground, clipped */
    bool has_ground = false;  /* ground seen in this very column */
    bool low = false;         /* structure below car height here: no place */
};

} // namespace

/* Columns are held in square blocks of kBlock x kBlock, only where the map has cells
 * (and, while building, around them): memory follows the map, not its bounding box. */
static const float kKeyScale = 65535;   /* a place's ring key is stored in 1/kKeyScale */
static const int kBlock = 16;   /* >= 8: the ground fill reaches 8 columns (fill_ground) */

static uint64_t block_id(int bx, int by) { return ((uint64_t)(uint32_t)bx << 32) | (uint32_t)by; }

struct places {
    places_config_t cfg;
    int W = 0, H = 0;                  /* the columns of the map's bounding box */
    double lo[2] = { 0, 0 };
    std::unordered_map<uint64_t, size_t> block_at;   /* blocks with structure: id -> index */
    std::vector<std::array<int32_t, 2>> block_xy;    /* per block: bx, by */
    std::vector<float> height;         /* per block, kBlock^2 columns: highest structure above the ground */
    /* per place, 52 bytes (one every metre of free ground: 121,082 on the default site):
     * its ring key in 1/65535 (full descriptors on demand; in 1/255 the true place
     * ranked lower on MulRan), column and ground height */
    std::vector<std::array<uint16_t, PLACE_RINGS>> ring_key;
    std::vector<std::array<int32_t, 2>> spot_col;
    std::vector<float> spot_z;
    int reach = 0;                     /* the polar grid reaches this many columns */
    std::vector<int16_t> bin_of;       /* its bin (ring * PLACE_SECTORS + sector, -1 none) per
                                        * column offset, (2 reach + 1)^2 row by row */
};

/* The descriptor of the place at column (ix, iy): the highest column of each bin. Block by
 * block, each looked up once (a query describes thousands of places). */
static void describe_column(const places_t *p, int ix, int iy, place_desc_t *d)
{
    float *h = &d->h[0][0];
    std::fill(h, h + PLACE_RINGS * PLACE_SECTORS, 0.f);
    const int R = p->reach, side = 2 * R + 1;
    for (int by = std::max(0, (iy - R) / kBlock); by <= (iy + R) / kBlock; by++)
        for (int bx = std::max(0, (ix - R) / kBlock); bx <= (ix + R) / kBlock; bx++) {
            auto it = p->block_at.find(block_id(bx, by));
            if (it == p->block_at.end()) continue;
            const float *col = &p->height[it->second * kBlock * kBlock];
            const int x0 = std::max(bx * kBlock, ix - R), x1 = std::min(bx * kBlock + kBlock - 1, ix + R);
            const int y0 = std::max(by * kBlock, iy - R), y1 = std::min(by * kBlock + kBlock - 1, iy + R);
            for (int y = y0; y <= y1; y++) {
                const float *row = col + (y - by * kBlock) * kBlock - bx * kBlock;   /* row[x]: column x */
                const int16_t *bin = &p->bin_of[(size_t)(y - iy + R) * side + R - ix];   /* bin[x] */
                for (int x = x0; x <= x1; x++)
                    if (bin[x] >= 0 && row[x] > h[bin[x]]) h[bin[x]] = row[x];
            }
        }
}

static int sector_of(double dx, double dy)
{
    int s = (int)std::floor((std::atan2(dy, dx) + M_PI) / (2 * M_PI) * PLACE_SECTORS);
    return std::min(std::max(s, 0), PLACE_SECTORS - 1);
}

/* Bins behind the first tall one along each sector are unknown; then the ring key: the
 * mean height of the known bins of each ring, over clip_m. */
static void finish(const places_config_t &cfg, place_desc_t *d)
{
    for (int s = 0; s < PLACE_SECTORS; s++) {
        bool hidden = false;
        for (int r = 0; r < PLACE_RINGS; r++) {
            if (hidden) d->h[r][s] = -1;
            else if (d->h[r][s] >= cfg.tall_m) hidden = true;
        }
    }
    double ring_sum[PLACE_RINGS] = {};
    int ring_n[PLACE_RINGS] = {};
    for (int r = 0; r < PLACE_RINGS; r++)
        for (int s = 0; s < PLACE_SECTORS; s++) {
            if (d->h[r][s] < 0) continue;
            ring_sum[r] += d->h[r][s];
            ring_n[r]++;
        }
    for (int r = 0; r < PLACE_RINGS; r++) d->ring_key[r] = ring_n[r] ? (float)(ring_sum[r] / (ring_n[r] * cfg.clip_m)) : 0.f;
}

/* The polar grid of a place as a table of column offsets. */
static void make_offsets(places_t *p)
{
    const int R = (int)std::ceil(PLACE_RINGS * p->cfg.ring_m / kColumn), side = 2 * R + 1;
    p->reach = R;
    p->bin_of.assign((size_t)side * side, -1);
    for (int dy = -R; dy <= R; dy++)
        for (int dx = -R; dx <= R; dx++) {
            double r = std::hypot(dx, dy) * kColumn;
            int ring = (int)(r / p->cfg.ring_m);
            if (ring >= PLACE_RINGS || r < 1e-9) continue;
            p->bin_of[(size_t)(dy + R) * side + dx + R] = (int16_t)(ring * PLACE_SECTORS + sector_of(dx, dy));
        }
}

struct places_builder {
    places_config_t cfg;
    double lo[2] = { HUGE_VAL, HUGE_VAL }, hi[2] = { -HUGE_VAL, -HUGE_VAL };
    int W = 0, H = 0;
    bool filled = false;
    std::unordered_map<uint64_t, size_t> block_at;   /* id -> index */
    std::vector<std::array<int32_t, 2>> block_xy;
    std::vector<column_t> col;                       /* per block, kBlock^2 */

    /* the column of a cell (clamped into the grid as the extent was taken) */
    void column_of(const float *q, int *ix, int *iy) const
    {
        *ix = std::min(W - 1, (int)((q[0] - lo[0]) / kColumn));
        *iy = std::min(H - 1, (int)((q[1] - lo[1]) / kColumn));
    }
    column_t *at(int ix, int iy, bool make)
    {
        if (ix < 0 || iy < 0 || ix >= W || iy >= H) return nullptr;
        uint64_t id = block_id(ix / kBlock, iy / kBlock);
        auto it = block_at.find(id);
        if (it == block_at.end()) {
            if (!make) return nullptr;
            it = block_at.emplace(id, block_xy.size()).first;
            block_xy.push_back({ ix / kBlock, iy / kBlock });
            col.resize(col.size() + kBlock * kBlock);
        }
        return &col[it->second * kBlock * kBlock + (iy % kBlock) * kBlock + ix % kBlock];
    }
    float ground_at(int ix, int iy)
    {
        column_t *c = at(ix, iy, false);
        return c ? c->ground : NAN;
    }
};

places_builder_t *places_builder_new(const places_config_t &cfg)
{
    places_builder_t *b = new places_builder_t();
    b->cfg = cfg;
    return b;
}

void places_builder_extent(places_builder_t *b, const float *xyz, size_t n)
{
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < 2; a++) {
            b->lo[a] = std::min(b->lo[a], (double)xyz[3 * i + a]);
            b->hi[a] = std::max(b->hi[a], (double)xyz[3 * i + a]);
        }
}

void places_builder_ground(places_builder_t *b, const float *xyz, const uint8_t *ground, size_t n)
{
    if (b->W == 0 && b->lo[0] <= b->hi[0]) {
        b->W = (int)((b->hi[0] - b->lo[0]) / kColumn) + 1;
        b->H = (int)((b->hi[1] - b->lo[1]) / kColumn) + 1;
    }
    for (size_t i = 0; i < n; i++) {
        if (!ground[i]) continue;
        int ix, iy;
        b->column_of(xyz + 3 * i, &ix, &iy);
        column_t *c = b->at(ix, iy, true);
        if (!c) continue;
        if (!c->has_ground || xyz[3 * i + 2] < c->ground) c->ground = xyz[3 * i + 2];
        c->has_ground = true;
    }
}

/* Columns without ground (under buildings, foliage): from the neighbours, 8 passes. A
 * column further than 8 from any ground gets none, so the blocks next to those with
 * ground hold every column that can get one. */
static void fill_ground(places_builder_t *b)
{
    b->filled = true;
    size_t with_ground = b->block_xy.size();
    for (size_t k = 0; k < with_ground; k++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++)
                b->at((b->block_xy[k][0] + dx) * kBlock, (b->block_xy[k][1] + dy) * kBlock, true);
    const size_t B2 = kBlock * kBlock;
    std::vector<float> fill(b->col.size());
    for (int pass = 0; pass < 8; pass++) {
        for (size_t k = 0; k < b->block_xy.size(); k++)
            for (size_t j = 0; j < B2; j++) {
                fill[k * B2 + j] = NAN;
                if (!std::isnan(b->col[k * B2 + j].ground)) continue;
                int ix = b->block_xy[k][0] * kBlock + (int)(j % kBlock), iy = b->block_xy[k][1] * kBlock + (int)(j / kBlock);
                double s = 0;
                int m = 0;
                for (int dy = -1; dy <= 1; dy++)
                    for (int dx = -1; dx <= 1; dx++) {
                        float g = b->ground_at(ix + dx, iy + dy);
                        if (std::isnan(g)) continue;
                        s += g;
                        m++;
                    }
                if (m) fill[k * B2 + j] = (float)(s / m);
            }
        for (size_t i = 0; i < b->col.size(); i++) if (std::isnan(b->col[i].ground)) b->col[i].ground = fill[i];
    }
}

void places_builder_structure(places_builder_t *b, const float *xyz, const uint8_t *ground, size_t n)
{
    if (!b->filled) fill_ground(b);
    for (size_t i = 0; i < n; i++) {
        if (ground[i]) continue;
        int ix, iy;
        b->column_of(xyz + 3 * i, &ix, &iy);
        column_t *c = b->at(ix, iy, false);
        if (!c || std::isnan(c->ground)) continue;
        double h = xyz[3 * i + 2] - c->ground;
        if (h >= 0.3 && h < b->cfg.car_clearance_m) c->low = true;
        if (h >= b->cfg.min_height_m) c->height = std::max(c->height, (float)std::min(h, b->cfg.clip_m));
    }
}

places_t *places_builder_finish(places_builder_t *b)
{
    std::unique_ptr<places_builder_t> own(b);
    if (!b->filled) fill_ground(b);
    const places_config_t &cfg = b->cfg;
    const size_t B2 = kBlock * kBlock;
    places_t *p = new places();
    p->cfg = cfg;
    p->W = b->W; p->H = b->H; p->lo[0] = b->lo[0]; p->lo[1] = b->lo[1];
    /* 1. the blocks with structure, in (by, bx) order */
    std::vector<size_t> order(b->block_xy.size());
    for (size_t k = 0; k < order.size(); k++) order[k] = k;
    std::sort(order.begin(), order.end(), [&](size_t u, size_t v) {
        return std::make_pair(b->block_xy[u][1], b->block_xy[u][0]) < std::make_pair(b->block_xy[v][1], b->block_xy[v][0]);
    });
    for (size_t k : order) {
        bool any = false;
        for (size_t j = 0; j < B2 && !any; j++) any = b->col[k * B2 + j].height > 0;
        if (!any) continue;
        p->block_at[block_id(b->block_xy[k][0], b->block_xy[k][1])] = p->block_xy.size();
        p->block_xy.push_back(b->block_xy[k]);
        for (size_t j = 0; j < B2; j++) p->height.push_back(b->col[k * B2 + j].height);
    }
    /* 2. the polar grid as column offsets (no trigonometry per place) */
    make_offsets(p);
    /* 3. a place at every free ground spot of a place_step grid, in row order; only its
     *    ring key is kept (the full descriptor is rebuilt from the columns for the shortlist) */
    int step = std::max(1, (int)std::lround(cfg.place_step_m / kColumn));
    std::vector<std::array<int32_t, 2>> spots;
    for (size_t k : order)
        for (size_t j = 0; j < B2; j++) {
            const column_t &c = b->col[k * B2 + j];
            int ix = b->block_xy[k][0] * kBlock + (int)(j % kBlock), iy = b->block_xy[k][1] * kBlock + (int)(j / kBlock);
            if (c.has_ground && !c.low && ix % step == 0 && iy % step == 0) spots.push_back({ iy, ix });
        }
    std::sort(spots.begin(), spots.end());
    p->ring_key.resize(spots.size());
    p->spot_col.resize(spots.size());
    p->spot_z.resize(spots.size());
    pb_split2(spots.size(), [&](size_t i0, size_t i1) {   /* each place its own */
        place_desc_t d;
        for (size_t i = i0; i < i1; i++) {
            int ix = spots[i][1], iy = spots[i][0];
            describe_column(p, ix, iy, &d);
            finish(cfg, &d);
            for (int r = 0; r < PLACE_RINGS; r++)
                p->ring_key[i][r] = (uint16_t)std::lround(std::min(1.f, std::max(0.f, d.ring_key[r])) * kKeyScale);
            p->spot_col[i] = { ix, iy };
            p->spot_z[i] = b->at(ix, iy, false)->ground;
        }
    });
    if (p->spot_z.empty()) { delete p; return nullptr; }
    return p;
}

void places_builder_destroy(places_builder_t *b) { delete b; }

places_t *places_build(const pb_regmap_t *map, const places_config_t &cfg)
{
    std::vector<float> xyz;
    std::vector<uint8_t> ground;
    pb_regmap_cells(map, &xyz, &ground);
    places_builder_t *b = places_builder_new(cfg);
    places_builder_extent(b, xyz.data(), ground.size());
    places_builder_ground(b, xyz.data(), ground.data(), ground.size());
    places_builder_structure(b, xyz.data(), ground.data(), ground.size());
    return places_builder_finish(b);
}

void places_destroy(places_t *p) { delete p; }

/* Serialised form (little-endian): "PBPLACE4" (4: places every metre, 52 bytes each; 3
 * held 112 bytes a place, 2 every column
 * of the bounding box), f64 ring_m, place_step_m, min_height_m, tall_m, clip_m,
 * car_clearance_m, i32 shortlist (the writer's; a query setting since 6 Dec 2026, not
 * read), W, H, u32 places, f64 lo[2], u32 blocks, then per block
 * i32 bx, by, f32 height[16 * 16] (row by row), then per place i32 ix, iy, f32 z (the
 * ground's height), u16 ring_key[PLACE_RINGS] (in 1/65535). */
static const char kPlacesMagic[8] = { 'P', 'B', 'P', 'L', 'A', 'C', 'E', '4' };
static const size_t kPlacesHeader = 8 + 6 * 8 + 4 * 4 + 2 * 8 + 4, kPlaceBytes = 8 + 4 + 2 * PLACE_RINGS,
                    kBlockBytes = 8 + 4 * kBlock * kBlock;

template <class T> static void put_le(std::vector<uint8_t> *o, T v)
{
    const uint8_t *b = (const uint8_t *)&v;
    o->insert(o->end(), b, b + sizeof v);
}
template <class T> static T get_le(const uint8_t *p) { T v; std::memcpy(&v, p, sizeof v); return v; }

void places_encode(const places_t *p, std::vector<uint8_t> *out)
{
    out->clear();
    out->reserve(kPlacesHeader + kBlockBytes * p->block_xy.size() + kPlaceBytes * p->spot_z.size());
    out->resize(sizeof kPlacesMagic);
    std::memcpy(out->data(), kPlacesMagic, sizeof kPlacesMagic);
    const places_config_t &c = p->cfg;
    for (double v : { c.ring_m, c.place_step_m, c.min_height_m, c.tall_m, c.clip_m, c.car_clearance_m }) put_le(out, v);
    put_le<int32_t>(out, c.shortlist);
    put_le<int32_t>(out, p->W);
    put_le<int32_t>(out, p->H);
    put_le<uint32_t>(out, (uint32_t)p->spot_z.size());
    put_le(out, p->lo[0]);
    put_le(out, p->lo[1]);
    put_le<uint32_t>(out, (uint32_t)p->block_xy.size());
    for (size_t k = 0; k < p->block_xy.size(); k++) {
        put_le<int32_t>(out, p->block_xy[k][0]);
        put_le<int32_t>(out, p->block_xy[k][1]);
        for (size_t j = 0; j < (size_t)kBlock * kBlock; j++) put_le(out, p->height[k * kBlock * kBlock + j]);
    }
    for (size_t i = 0; i < p->spot_z.size(); i++) {
        put_le<int32_t>(out, p->spot_col[i][0]);
        put_le<int32_t>(out, p->spot_col[i][1]);
        put_le(out, p->spot_z[i]);
        for (uint16_t k : p->ring_key[i]) put_le(out, k);
    }
}

places_t *places_decode(const uint8_t *b, size_t n, char *msg, size_t msg_len)
{
    if (n >= 8 && std::memcmp(b, kPlacesMagic, 7) == 0 && b[7] != kPlacesMagic[7]) {
        snprintf(msg, msg_len, "byte 0: place descriptors of another version (PBPLACE%c, this localizer reads "
                 "PBPLACE4): rebuild the site's map.tiles with map-tiles", b[7]);
        return nullptr;
    }
    if (n < kPlacesHeader || std::memcmp(b, kPlacesMagic, 8) != 0) {
        snprintf(msg, msg_len, "byte 0: not place descriptors (no PBPLACE4 header)");
        return nullptr;
    }
    places_config_t c;
    double *cd[6] = { &c.ring_m, &c.place_step_m, &c.min_height_m, &c.tall_m, &c.clip_m, &c.car_clearance_m };
    for (int i = 0; i < 6; i++) *cd[i] = get_le<double>(b + 8 + 8 * i);
    int32_t written_shortlist = get_le<int32_t>(b + 56);   /* the query's own setting is used */
    int32_t W = get_le<int32_t>(b + 60), H = get_le<int32_t>(b + 64);
    uint32_t np = get_le<uint32_t>(b + 68);
    double lo[2] = { get_le<double>(b + 72), get_le<double>(b + 80) };
    uint32_t nb = get_le<uint32_t>(b + 88);
    bool ok = c.ring_m >= 0.5 && c.ring_m <= 100 && written_shortlist >= 1 && written_shortlist <= 100000 && c.clip_m > 0 &&
              c.clip_m < 1000 && std::isfinite(c.min_height_m) && std::isfinite(c.tall_m) && W > 0 && H > 0 &&
              W <= 1000000000 && H <= 1000000000 &&   /* column + ring offsets stay within int */
              std::isfinite(lo[0]) && std::isfinite(lo[1]) &&
              (uint64_t)n == kPlacesHeader + (uint64_t)kBlockBytes * nb + (uint64_t)kPlaceBytes * np;
    if (!ok) {
        snprintf(msg, msg_len, "byte 8: bad place header (ring %g m, %d x %d columns, %u blocks, %u places, %zu bytes)",
                 c.ring_m, W, H, nb, np, n);
        return nullptr;
    }
    std::unique_ptr<places_t> p(new places());
    p->cfg = c;
    p->W = W; p->H = H; p->lo[0] = lo[0]; p->lo[1] = lo[1];
    const uint8_t *q = b + kPlacesHeader;
    p->height.resize((size_t)nb * kBlock * kBlock);
    for (size_t k = 0; k < nb; k++, q += kBlockBytes) {
        int32_t bx = get_le<int32_t>(q), by = get_le<int32_t>(q + 4);
        bool good = bx >= 0 && by >= 0 && bx <= (W - 1) / kBlock && by <= (H - 1) / kBlock &&
                    p->block_at.emplace(block_id(bx, by), k).second;
        for (size_t j = 0; j < (size_t)kBlock * kBlock; j++) {
            float h = get_le<float>(q + 8 + 4 * j);
            good &= std::isfinite(h);
            p->height[k * kBlock * kBlock + j] = h;
        }
        if (!good) {
            snprintf(msg, msg_len, "byte %zu: block %zu of column heights is damaged", (size_t)(q - b), k);
            return nullptr;
        }
        p->block_xy.push_back({ bx, by });
    }
    p->spot_z.resize(np);
    p->spot_col.resize(np);
    p->ring_key.resize(np);
    for (size_t i = 0; i < np; i++, q += kPlaceBytes) {
        p->spot_col[i] = { get_le<int32_t>(q), get_le<int32_t>(q + 4) };
        p->spot_z[i] = get_le<float>(q + 8);
        for (int r = 0; r < PLACE_RINGS; r++) p->ring_key[i][r] = get_le<uint16_t>(q + 12 + 2 * r);
        bool good = p->spot_col[i][0] >= 0 && p->spot_col[i][0] < W && p->spot_col[i][1] >= 0 && p->spot_col[i][1] < H &&
                    std::isfinite(p->spot_z[i]);
        if (!good) {
            snprintf(msg, msg_len, "byte %zu: place %zu is damaged", (size_t)(q - b), i);
            return nullptr;
        }
    }
    if (np == 0) {
        snprintf(msg, msg_len, "byte 68: no places");
        return nullptr;
    }
    make_offsets(p.get());
    return p.release();
}
size_t places_count(const places_t *p) { return p ? p->spot_z.size() : 0; }

void places_describe(const places_t *p, const float *xyz, size_t n, place_desc_t *d)
{
    places_describe(p->cfg, xyz, n, d);
}

void places_describe(const places_config_t &cfg, const float *xyz, size_t n, place_desc_t *d)
{
    /* heights above the ground around each bin, as the map's are, not above the car's
     * base plane: on a grade or a crest that plane is metres off the ground 40 m away */
    static const float NONE = 1e9f;
    float lo[PLACE_RINGS][PLACE_SECTORS], hi[PLACE_RINGS][PLACE_SECTORS];
    for (int r = 0; r < PLACE_RINGS; r++)
        for (int s = 0; s < PLACE_SECTORS; s++) { lo[r][s] = NONE; hi[r][s] = -NONE; }
    for (size_t i = 0; i < n; i++) {
        double x = xyz[3 * i], y = xyz[3 * i + 1];
        float z = xyz[3 * i + 2];
        int ring = (int)(std::hypot(x, y) / cfg.ring_m);
        if (ring >= PLACE_RINGS) continue;
        int s = sector_of(x, y);
        lo[ring][s] = std::min(lo[ring][s], z);
        hi[ring][s] = std::max(hi[ring][s], z);
    }
    for (int r = 0; r < PLACE_RINGS; r++)
        for (int s = 0; s < PLACE_SECTORS; s++) {
            /* a bin with no return is unknown (beyond range, hidden by a car), not free */
            d->h[r][s] = -1;
            if (hi[r][s] == -NONE) continue;
            d->h[r][s] = 0;
            /* the ground is the lowest return nearby (a wall or a bush may hide it in this
             * very bin) that lies where a road of up to 10 % grade can be; with none, the
             * base plane stands in */
            float ground = NONE;
            for (int dr = -1; dr <= 1; dr++)
                for (int ds = -2; ds <= 2; ds++) {
                    int rr = r + dr, ss = (s + ds + PLACE_SECTORS) % PLACE_SECTORS;
                    if (rr < 0 || rr >= PLACE_RINGS || lo[rr][ss] == NONE) continue;
                    if (std::fabs(lo[rr][ss]) <= 0.5 + 0.1 * (rr + 0.5) * cfg.ring_m) ground = std::min(ground, lo[rr][ss]);
                }
            if (ground == NONE) ground = 0;
            double h = hi[r][s] - ground;
            if (h >= cfg.min_height_m) d->h[r][s] = (float)std::min(h, cfg.clip_m);
        }
    finish(cfg, d);
}

/* A descriptor in whole centimetres (-1 unknown), each ring held twice over so that
 * sector s + shift needs no wrap: the comparison under every shift runs on integers in
 * plain loops, which the compiler vectorises (and integer sums do not depend on order). */
struct cm_desc_t {
    int16_t h[PLACE_RINGS][2 * PLACE_SECTORS];
};

static void to_cm(const place_desc_t &d, cm_desc_t *c)
{
    for (int r = 0; r < PLACE_RINGS; r++)
        for (int s = 0; s < PLACE_SECTORS; s++)
            c->h[r][s] = c->h[r][s + PLACE_SECTORS] = d.h[r][s] < 0 ? -1 : (int16_t)std::lround(d.h[r][s] * 100);
}

/* Mean height difference over bins known on both sides, sweep sector s against map
 * sector s + shift, under every shift; the best, 1 when too few bins are comparable
 * under any; *shift gets its shift (the lowest of equals). Every shift, not a few that
 * a coarser key proposes: on MulRan's tree-lined roads the mean height per sector named
 * a wrong turn at the true place, which then ranked beyond the 300th (odd split, 48.5 s). */
static double compare_shifts(const places_config_t &cfg, const cm_desc_t &a, const cm_desc_t &m, int *shift)
{
    double best = 1.0;
    *shift = 0;
    for (int sh = 0; sh < PLACE_SECTORS; sh++) {
        int32_t sum = 0, k = 0;
        for (int r = 0; r < PLACE_RINGS; r++) {
            const int16_t *x = a.h[r], *y = m.h[r] + sh;
            for (int i = 0; i < PLACE_SECTORS; i++) {
                int32_t known = (x[i] >= 0) & (y[i] >= 0);
                int32_t d = x[i] - y[i];
                sum += known * (d < 0 ? -d : d);
                k += known;
            }
        }
        if (k < PLACE_RINGS * PLACE_SECTORS / 10) continue;
        double c = sum / (k * cfg.clip_m * 100);
        if (c < best) { best = c; *shift = sh; }
    }
    return best;
}

double places_compare(const places_config_t &cfg, const place_desc_t &a, const place_desc_t &b, double *yaw)
{
    cm_desc_t ca, cb;
    to_cm(a, &ca);
    to_cm(b, &cb);
    int sh;
    double d = compare_shifts(cfg, ca, cb, &sh);
    *yaw = sh * 2 * M_PI / PLACE_SECTORS;
    return d;
}

void places_query(const places_t *p, const place_desc_t &d, int k, std::vector<place_match_t> *out)
{
    out->clear();
    size_t n = p->spot_z.size();
    float key[PLACE_RINGS];   /* the sweep's ring key in the places' units */
    for (int r = 0; r < PLACE_RINGS; r++) key[r] = d.ring_key[r] * kKeyScale;
    /* 1. shortlist by the ring key (rotation invariant) */
    std::vector<std::pair<double, size_t>> rk(n);
    for (size_t i = 0; i < n; i++) {
        double s = 0;
        for (int r = 0; r < PLACE_RINGS; r++) s += std::fabs(key[r] - p->ring_key[i][r]);
        rk[i] = { s, i };
    }
    size_t m = std::min(n, (size_t)std::max(k, p->cfg.shortlist));
    std::partial_sort(rk.begin(), rk.begin() + m, rk.end());
    /* 2. the full descriptors under every sector shift, each place on its own (two threads) */
    cm_desc_t cd;
    to_cm(d, &cd);
    out->resize(m);
    pb_split2(m, [&](size_t j0, size_t j1) {
        place_desc_t pd;
        cm_desc_t cp;
        for (size_t j = j0; j < j1; j++) {
            const auto &c = p->spot_col[rk[j].second];
            describe_column(p, c[0], c[1], &pd);
            finish(p->cfg, &pd);
            to_cm(pd, &cp);
            int sh;
            place_match_t &pm = (*out)[j];
            pm = { p->lo[0] + (c[0] + 0.5) * kColumn, p->lo[1] + (c[1] + 0.5) * kColumn, p->spot_z[rk[j].second], 0, 0 };
            pm.distance = compare_shifts(p->cfg, cd, cp, &sh);
            pm.yaw = sh * 2 * M_PI / PLACE_SECTORS;
        }
    }, 256);
    std::stable_sort(out->begin(), out->end(), [](const place_match_t &a, const place_match_t &b) {
        return a.distance < b.distance;
    });
    /* a place's neighbours are the same place to a search around it */
    std::vector<place_match_t> kept;
    for (const place_match_t &q : *out) {
        bool near = false;
        for (const place_match_t &o : kept) near |= std::hypot(q.x - o.x, q.y - o.y) < p->cfg.separation_m;
        if (!near) kept.push_back(q);
        if ((int)kept.size() >= k) break;
    }
    out->swap(kept);
}

} // namespace pb_loc
