/* under: see under.h. */
#include "under.h"

#include <algorithm>
#include <climits>
#include <cmath>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "pb_map_build.h"

namespace {
/* A one-hash bit filter in front of a hash set: nearly every return of a sweep lies in no
 * watched column, and a bit says so for less than a lookup costs. The 128 KB stay in cache;
 * the localizer's open-addressing VoxelHash alone, tried in place of filter and sets, missed
 * it: a read of the hills 0.3 -> 0.5 s, the same map. */
struct KeyBits {
    std::vector<uint64_t> bits = std::vector<uint64_t>(1u << 14);   /* 2^20 bits, 128 KB */
    static uint32_t slot(uint64_t key) { return (uint32_t)((key * 0x9E3779B97F4A7C15ull) >> 44); }
    void add(uint64_t key) { bits[slot(key) >> 6] |= 1ull << (slot(key) & 63); }
    void clear(uint64_t key) { bits[slot(key) >> 6] &= ~(1ull << (slot(key) & 63)); }
    bool may_hold(uint64_t key) const { return bits[slot(key) >> 6] >> (slot(key) & 63) & 1; }
};

struct Taken {
    double s[4];   /* the returns' offsets from the voxel's lowest corner (x y z), intensities */
    uint32_t n;
};
}  // namespace

struct pb_under {
    pb_under_config_t cfg;
    double voxel_m, inv_col;
    int reach;                            /* columns a body marks on each side of its own */
    const pb_ground_t *ground;
    /* carved voxels in the body band, and the first and last time a sweep hit them */
    std::unordered_map<uint64_t, std::pair<int64_t, int64_t>> seen;
    KeyBits watch_bits, around_bits, body_bits, taken_bits;   /* filters in front of watch, around, body and taken */
    bool settled = false;                 /* body and watch made from seen (at the first sweep) */
    std::unordered_set<uint64_t> body;    /* carved voxels that are bodies */
    std::vector<std::pair<int64_t, int64_t>> hit_spans;   /* when bodies were hit: first, last; sorted, apart */
    std::unordered_set<uint64_t> watch;   /* where a body stood: its columns and their 8 neighbours */
    std::unordered_set<uint64_t> around;  /* the columns within twice bump_reach_m of a watched one */
    std::unordered_map<uint64_t, Taken> taken;
    uint64_t returns_taken = 0;
    /* one sweep's: the returns in watched columns, the columns a body marked */
    std::vector<size_t> near;
    std::unordered_set<uint64_t> marked;
    std::unordered_set<uint64_t> under;   /* the columns within reach of a marked one ... */
    KeyBits under_bits;                   /* ... and their filter (cleared key by key) */
    struct Beam { int32_t column; float elevation, range; size_t k; };   /* a near return's beam */
    std::vector<Beam> beams;
    std::vector<uint8_t> done;   /* per near return: judged by step 2 */
    /* the one-look voxels (pb_under_look): (a voxel beside one, its number), sorted on the
     * first support, and a filter in front of it (17 pairs, 272 bytes a look: 2 MB for the
     * loop's 8,357, about 33 MB for an hour's drive) */
    std::vector<std::pair<uint64_t, int>> look_beside;
    bool look_sorted = true;
    KeyBits look_bits;
    std::vector<uint8_t> look_supported;

    int64_t col(double v) const { return (int64_t)std::floor(v * inv_col); }
    static uint64_t column_key(int64_t cx, int64_t cy) { return (uint64_t)cx << 32 | (uint32_t)cy; }
    static uint64_t column_moved(uint64_t c, int dx, int dy) { return column_key((int32_t)(c >> 32) + dx, (int32_t)(uint32_t)c + dy); }
    uint64_t column(double x, double y) const { return column_key(col(x), col(y)); }   /* (x, y)'s column */
    /* the height of (x, y, z) over the ground; false where the model has none */
    bool height(double x, double y, double z, double *h) const
    {
        double g;
        if (!ground || pb_ground_height(ground, x, y, &g) != 0) return false;
        *h = z - g;
        return true;
    }
};

pb_under_t *pb_under_create(const float *carved, size_t n, size_t stride, const int64_t *hit, double voxel_m,
                            const pb_ground_t *ground, const pb_under_config_t *cfg)
{
    pb_under_t *u = new pb_under();
    if (cfg) u->cfg = *cfg;
    u->voxel_m = voxel_m;
    u->inv_col = 1.0 / u->cfg.column_m;
    u->reach = (int)std::lround(u->cfg.reach_m / u->cfg.column_m);
    u->ground = ground;
    for (size_t i = 0; i < n; i++) {
        const float *p = carved + i * stride;
        double h;
        uint64_t key;
        if (!u->height(p[0], p[1], p[2], &h) || h < u->cfg.body_min_m || h > u->cfg.body_max_m ||
            pb_map_voxel_key(voxel_m, p[0], p[1], p[2], &key) != 0)
            continue;
        auto &span = u->seen.emplace(key, std::make_pair(INT64_MAX, INT64_MIN)).first->second;
        if (!hit) continue;
        span.first = std::min(span.first, hit[2 * i]);
        span.second = std::max(span.second, hit[2 * i + 1]);
    }
    return u;
}

/* The bodies: carved voxels whose returns all came within body_span_s (a voxel hit over a
 * longer time is something that stands there and that the carving took, such as foliage it
 * saw through), and where they stood. A carved voxel no sweep hit is none. */
static void settle(pb_under_t *u)
{
    u->settled = true;
    const int64_t span_us = (int64_t)std::llround(u->cfg.body_span_s * 1e6);
    for (const auto &kv : u->seen) {
        if (kv.second.first > kv.second.second || kv.second.second - kv.second.first > span_us) continue;
        u->body.insert(kv.first);
        u->hit_spans.push_back(kv.second);
        u->body_bits.add(kv.first);
        double c[3];
        pb_map_voxel_corner(u->voxel_m, kv.first, c);
        const int64_t cx = u->col(c[0] + u->voxel_m / 2), cy = u->col(c[1] + u->voxel_m / 2);
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++) {
                u->watch.insert(pb_under::column_key(cx + dx, cy + dy));
                u->watch_bits.add(pb_under::column_key(cx + dx, cy + dy));
            }
    }
    u->seen.clear();
    std::sort(u->hit_spans.begin(), u->hit_spans.end());
    size_t m = 0;   /* overlapping spans merged */
    for (const auto &h : u->hit_spans) {
        if (m > 0 && h.first <= u->hit_spans[m - 1].second) u->hit_spans[m - 1].second = std::max(u->hit_spans[m - 1].second, h.second);
        else u->hit_spans[m++] = h;
    }
    u->hit_spans.resize(m);
    /* a bump may lie up to bump_reach_m from a watched column, and its test looks as far again */
    const int r = 1 + (int)std::ceil(2 * u->cfg.bump_reach_m * u->inv_col);
    for (uint64_t c : u->watch)
        for (int dx = -r; dx <= r; dx++)
            for (int dy = -r; dy <= r; dy++) {
                const uint64_t k = pb_under::column_moved(c, dx, dy);
                if (u->around.insert(k).second) u->around_bits.add(k);
            }
}

void pb_under_destroy(pb_under_t *u) { delete u; }

int pb_under_busy(pb_under_t *u, int64_t t)
{
    if (!u->settled) settle(u);
    /* the last span that starts at or before t */
    auto it = std::upper_bound(u->hit_spans.begin(), u->hit_spans.end(), std::make_pair(t, INT64_MAX));
    return it != u->hit_spans.begin() && std::prev(it)->second >= t;
}

void pb_under_sweep(pb_under_t *u, const double *xyz, size_t n, const pb_points_t *pts, const int32_t *index)
{
    auto of = [&](size_t i) { return index ? (size_t)index[i] : i; };   /* return i's index in pts */
    if (!u->settled) settle(u);
    if (u->body.empty()) return;
    // 1. the returns where a body stood at some time; the columns where one fell in a body now
    u->near.clear();
    u->marked.clear();
    for (size_t i = 0; i < n; i++) {
        const double *p = xyz + 3 * i;
        const uint64_t c = u->column(p[0], p[1]);
        if (!u->watch_bits.may_hold(c) || !u->watch.count(c)) continue;
        u->near.push_back(i);
        uint64_t key;
        if (pb_map_voxel_key(u->voxel_m, p[0], p[1], p[2], &key) == 0 && u->body_bits.may_hold(key) && u->body.count(key))
            u->marked.insert(c);
    }
    if (u->marked.empty()) return;
    /* the columns within reach of a marked one: one look-up a return, not one per column in reach */
    for (uint64_t c : u->under) u->under_bits.clear(c);
    u->under.clear();
    for (uint64_t c : u->marked)
        for (int dx = -u->reach; dx <= u->reach; dx++)
            for (int dy = -u->reach; dy <= u->reach; dy++) {
                const uint64_t k = pb_under::column_moved(c, dx, dy);
                if (u->under.insert(k).second) u->under_bits.add(k);
            }
    // 2. of those, the low ones within reach of a marked column taken out of their voxels
    std::vector<uint8_t> &done = u->done;
    done.assign(u->near.size(), 0);
    auto take = [&](size_t i) {
        const double *p = xyz + 3 * i;
        double h;
        uint64_t key;
        if (!u->height(p[0], p[1], p[2], &h) || h > u->cfg.return_max_m ||
            pb_map_voxel_key(u->voxel_m, p[0], p[1], p[2], &key) != 0 || (u->body_bits.may_hold(key) && u->body.count(key)))
            return;
        double corner[3];
        pb_map_voxel_corner(u->voxel_m, key, corner);
        Taken &t = u->taken.emplace(key, Taken{{0, 0, 0, 0}, 0}).first->second;
        u->taken_bits.add(key);
        for (int a = 0; a < 3; a++) t.s[a] += p[a] - corner[a];
        t.s[3] += pts && pts->intensity ? pts->intensity[of(i)] : 0.0f;
        t.n++;
        u->returns_taken++;
    };
    for (size_t k = 0; k < u->near.size(); k++) {
        const double *p = xyz + 3 * u->near[k];
        const uint64_t c = u->column(p[0], p[1]);
        if (u->under_bits.may_hold(c) && u->under.count(c)) { take(u->near[k]); done[k] = 1; }
    }
    // 3. the sweep's columns known: a low return whose beam above ended in a body, nearer or
    // a little farther (a wheel's bottom; what a beam under a nearer car's body met)
    if (!pts || !pts->offset_us) return;
    const int32_t *column = pts->offset_us;
    for (int i = 1, run = 1; i < pts->n; i++) {
        run = column[i] == column[i - 1] ? run + 1 : 1;
        if (run > 256) return;
    }
    using Beam = pb_under::Beam;
    std::vector<Beam> &beams = u->beams;
    beams.clear();
    for (size_t k = 0; k < u->near.size(); k++) {
        const size_t i = of(u->near[k]);
        const float rxy = std::hypot(pts->x[i], pts->y[i]);
        beams.push_back({column[i], std::atan2(pts->z[i], rxy), std::sqrt(rxy * rxy + pts->z[i] * pts->z[i]), k});
    }
    std::sort(beams.begin(), beams.end(), [](const Beam &a, const Beam &b) {
        return a.column != b.column ? a.column < b.column : a.elevation != b.elevation ? a.elevation < b.elevation : a.k < b.k;
    });
    for (size_t b = 0; b + 1 < beams.size(); b++) {
        const Beam &low = beams[b], &above = beams[b + 1];
        if (done[low.k] || above.column != low.column || above.range > low.range + u->cfg.above_beyond_m) continue;
        const double *q = xyz + 3 * u->near[above.k];
        uint64_t key;
        if (pb_map_voxel_key(u->voxel_m, q[0], q[1], q[2], &key) == 0 && u->body_bits.may_hold(key) && u->body.count(key))
            take(u->near[low.k]);
    }
}

uint32_t pb_under_adjust(const pb_under_t *u, float p[4], uint32_t n)
{
    uint64_t key;
    if (pb_map_voxel_key(u->voxel_m, p[0], p[1], p[2], &key) != 0 || !u->taken_bits.may_hold(key)) return n;
    auto it = u->taken.find(key);
    if (it == u->taken.end()) return n;
    double h;
    /* on the ground: the road itself; higher than the road's band: what stands there (a kerb's
     * or a bush's base beside a car), which the taking of its lowest returns would lift */
    if (!u->height(p[0], p[1], p[2], &h) || h <= u->cfg.lifted_m || h > u->cfg.road_max_m) return n;
    const Taken &t = it->second;
    if (t.n >= n) return 0;
    double corner[3];
    pb_map_voxel_corner(u->voxel_m, key, corner);
    const uint32_t left = n - t.n;
    for (int a = 0; a < 3; a++) p[a] = (float)(corner[a] + (((double)p[a] - corner[a]) * n - t.s[a]) / left);
    p[3] = (float)(((double)p[3] * n - t.s[3]) / left);
    return left;
}

int pb_under_near(const pb_under_t *u, const float p[3])
{
    const uint64_t c = u->column(p[0], p[1]);
    return u->around_bits.may_hold(c) && u->around.count(c);
}

size_t pb_under_bumps(const pb_under_t *u, const float *xyz, size_t n, size_t stride, uint8_t *gone)
{
    // 1. the points' heights over the ground, and the points sorted by bump_reach_m cells
    const double reach = u->cfg.bump_reach_m, join = 2 * u->voxel_m;
    std::vector<double> h(n, NAN);
    std::vector<std::pair<uint64_t, uint32_t>> by_cell(n);
    auto cell_of = [&](double v) { return (int64_t)std::floor(v / reach); };
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + i * stride;
        u->height(p[0], p[1], p[2], &h[i]);
        by_cell[i] = {pb_under::column_key(cell_of(p[0]), cell_of(p[1])), (uint32_t)i};
    }
    std::sort(by_cell.begin(), by_cell.end());
    auto within = [&](size_t i, double r, const auto &f) {   /* f(j) for every other point within r (x-y) */
        const float *p = xyz + i * stride;
        const int64_t cx = cell_of(p[0]), cy = cell_of(p[1]);
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++) {
                const uint64_t k = pb_under::column_key(cx + dx, cy + dy);
                for (auto it = std::lower_bound(by_cell.begin(), by_cell.end(), std::make_pair(k, (uint32_t)0));
                     it != by_cell.end() && it->first == k; ++it) {
                    const float *q = xyz + (size_t)it->second * stride;
                    if (it->second != i && (q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]) <= r * r) f(it->second);
                }
            }
    };
    // 2. the points within bump_reach_m of where a body stood (a wheel stands at its body's
    //    corner, and the body's voxels carved are those the map held), in the band; those
    //    within two voxels joined in patches
    const int rc = (int)std::ceil(reach * u->inv_col);
    auto near_watch = [&](double x, double y) {
        const uint64_t c = u->column(x, y);
        for (int dx = -rc; dx <= rc; dx++)
            for (int dy = -rc; dy <= rc; dy++) {
                const uint64_t k = pb_under::column_moved(c, dx, dy);
                if (u->watch_bits.may_hold(k) && u->watch.count(k)) return true;
            }
        return false;
    };
    std::vector<uint32_t> patch(n, UINT32_MAX);   /* a candidate's link toward its patch's root */
    auto root = [&](uint32_t i) {
        while (patch[i] != i) i = patch[i] = patch[patch[i]];
        return i;
    };
    std::vector<uint32_t> cand;
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + i * stride;
        if (h[i] >= u->cfg.bump_m && h[i] <= u->cfg.return_max_m && near_watch(p[0], p[1]))
            patch[i] = (uint32_t)i, cand.push_back((uint32_t)i);
    }
    for (uint32_t i : cand)
        within(i, join, [&](uint32_t j) {
            if (patch[j] != UINT32_MAX) patch[root(j)] = root(i);
        });
    // 3. a patch no wider than bump_reach_m goes when each of its points stands bump_m over
    // every other point within reach, and those fill bump_fill of the voxel columns there
    struct Patch { float lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY}; bool bump = true; };
    std::unordered_map<uint32_t, Patch> patches;
    const double columns = M_PI * reach * reach / (u->voxel_m * u->voxel_m);
    for (uint32_t i : cand) {
        Patch &P = patches[root(i)];
        const float *p = xyz + (size_t)i * stride;
        for (int a = 0; a < 2; a++) P.lo[a] = std::min(P.lo[a], p[a]), P.hi[a] = std::max(P.hi[a], p[a]);
        if (!P.bump) continue;
        int neighbours = 0;
        within(i, reach, [&](uint32_t j) {
            neighbours++;
            /* a neighbour of the patch, or one standing bump_m lower (one without a height is not) */
            if (!(patch[j] != UINT32_MAX && root(j) == root(i)) && !(h[j] <= h[i] - u->cfg.bump_m)) P.bump = false;
        });
        if (neighbours < u->cfg.bump_fill * columns) P.bump = false;
    }
    size_t bumps = 0;
    for (size_t i = 0; i < n; i++) {
        gone[i] = 0;
        if (patch[i] == UINT32_MAX) continue;
        const Patch &P = patches[root((uint32_t)i)];
        if (P.bump && std::max(P.hi[0] - P.lo[0], P.hi[1] - P.lo[1]) <= reach) gone[i] = 1, bumps++;
    }
    return bumps;
}

void pb_under_counts(const pb_under_t *u, uint64_t *returns, uint64_t *voxels)
{
    *returns = u->returns_taken;
    *voxels = u->taken.size();
}

int pb_under_look(pb_under_t *u, const float p[3], int64_t first, int64_t last)
{
    double h;
    uint64_t key;
    if (first != last || !u->height(p[0], p[1], p[2], &h) || h <= u->cfg.lifted_m || h > u->cfg.road_max_m ||
        pb_map_voxel_key(u->voxel_m, p[0], p[1], p[2], &key) != 0)
        return -1;
    const int i = (int)u->look_supported.size();
    u->look_supported.push_back(0);
    const double c = u->voxel_m / 2;   /* the voxels beside: keyed as points at their middles */
    double corner[3];
    pb_map_voxel_corner(u->voxel_m, key, corner);
    for (int dx = -1; dx <= 1; dx++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dz = -1; dz <= 0; dz++) {
                uint64_t k;
                if ((dx || dy || dz) && pb_map_voxel_key(u->voxel_m, corner[0] + c + dx * u->voxel_m, corner[1] + c + dy * u->voxel_m,
                                                         corner[2] + c + dz * u->voxel_m, &k) == 0)
                {
                    u->look_beside.push_back({k, i});
                    u->look_bits.add(k);
                }
            }
    u->look_sorted = false;
    return i;
}

void pb_under_look_support(pb_under_t *u, const float p[3], uint32_t n, int64_t first, int64_t last)
{
    uint64_t key;
    if (u->look_beside.empty() || n < (uint32_t)u->cfg.look_returns ||
        (double)(last - first) < u->cfg.look_span_s * 1e6 || pb_map_voxel_key(u->voxel_m, p[0], p[1], p[2], &key) != 0)
        return;
    if (!u->look_bits.may_hold(key)) return;
    if (!u->look_sorted) {
        std::sort(u->look_beside.begin(), u->look_beside.end());
        u->look_sorted = true;
    }
    for (auto it = std::lower_bound(u->look_beside.begin(), u->look_beside.end(), std::make_pair(key, INT_MIN));
         it != u->look_beside.end() && it->first == key; ++it)
        u->look_supported[(size_t)it->second] = 1;
}

int pb_under_look_gone(const pb_under_t *u, int i)
{
    return i >= 0 && (size_t)i < u->look_supported.size() && u->look_supported[(size_t)i];
}
