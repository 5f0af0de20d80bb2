/* carve: see carve.h. */
#include "carve.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "voxel_hash.h"

namespace {
struct Count {
    uint32_t hits;
    uint32_t passes_before;   /* passes before the first hit */
    uint32_t passes_after;    /* passes since the last hit */
    int64_t first_hit, last_hit;   /* utime */
    float ground_z;    /* band cells: the ground model's height at the cell's centre */
    int32_t raised;    /* band cells: the cell of its points higher than raise_m over the ground, or -1 */
    uint8_t protect;   /* in the band over the ground: never carved */
};
}  // namespace

struct pb_carve {
    pb_carve_config_t cfg;
    double inv;
    pb_loc::VoxelHash index;
    std::vector<Count> counts;
    std::vector<int32_t> point_cell;   /* per map point, its cell (-1: outside the key range) */
    int64_t lo[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, hi[3] = {INT64_MIN, INT64_MIN, INT64_MIN};   /* cells' extent */
};

pb_carve_t *pb_carve_create(const float *xyz, size_t n, size_t stride, const pb_ground_t *ground,
                            const pb_carve_config_t *cfg)
{
    pb_carve_t *c = new pb_carve();
    if (cfg) c->cfg = *cfg;
    c->inv = 1.0 / c->cfg.cell_m;
    c->index.reset(n / 4 + 16);
    c->point_cell.assign(n, -1);
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + i * stride;
        uint64_t key;
        int64_t v[3];
        if (!pb_loc::voxel_index_of(p[0], p[1], p[2], c->inv, &v[0], &v[1], &v[2]) ||
            !pb_loc::voxel_key(v[0], v[1], v[2], &key))
            continue;
        for (int a = 0; a < 3; a++) { c->lo[a] = std::min(c->lo[a], v[a]); c->hi[a] = std::max(c->hi[a], v[a]); }
        bool fresh;
        int32_t k = c->index.insert(key, (int32_t)c->counts.size(), &fresh);
        if (fresh) {
            /* the ground under the cell's centre */
            double g, cx = (std::floor(p[0] * c->inv) + 0.5) * c->cfg.cell_m, cy = (std::floor(p[1] * c->inv) + 0.5) * c->cfg.cell_m;
            uint8_t protect = ground && pb_ground_height(ground, cx, cy, &g) == 0 &&
                              std::floor(p[2] * c->inv) * c->cfg.cell_m <= g + c->cfg.ground_band_m;
            c->counts.push_back(Count{0, 0, 0, 0, 0, protect ? (float)g : 0.0f, -1, protect});
        }
        /* a band cell's points clear of the ground are judged apart: a car's sill over the road */
        Count &n = c->counts[(size_t)k];
        if (n.protect && p[2] > n.ground_z + c->cfg.raise_m) {
            if (n.raised < 0) {
                n.raised = (int32_t)c->counts.size();
                c->counts.push_back(Count{0, 0, 0, 0, 0, 0.0f, -1, 0});
            }
            k = c->counts[(size_t)k].raised;
        }
        c->point_cell[i] = k;
    }
    return c;
}

void pb_carve_destroy(pb_carve_t *c) { delete c; }

void pb_carve_ray(pb_carve_t *c, int64_t utime, const double o[3], const double e[3])
{
    double d[3] = {e[0] - o[0], e[1] - o[1], e[2] - o[2]};
    double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len > 1e-6) || len > c->cfg.max_range_m) return;
    uint64_t key;
    if (pb_loc::voxel_key_of(e[0], e[1], e[2], c->inv, &key)) {
        int32_t k = c->index.find(key);
        if (k >= 0 && c->counts[(size_t)k].raised >= 0 && e[2] > c->counts[(size_t)k].ground_z + c->cfg.raise_m)
            k = c->counts[(size_t)k].raised;
        if (k >= 0) {
            Count &n = c->counts[(size_t)k];
            if (n.hits++ == 0) n.first_hit = utime;
            n.last_hit = utime;
            n.passes_after = 0;
        }
    }
    /* the cells the ray crosses up to end_margin_m before its end, in order (a 3-D DDA) */
    const double stop = len - c->cfg.end_margin_m;
    if (stop <= 0) return;
    /* none of them among this map's (a part's) cells: the segment misses their box grown by a cell */
    double t0 = 0, t1 = stop;
    for (int a = 0; a < 3 && t0 <= t1; a++) {
        const double blo = (double)(c->lo[a] - 1) * c->cfg.cell_m, bhi = (double)(c->hi[a] + 2) * c->cfg.cell_m;
        const double u = d[a] / len;
        if (u == 0) {
            if (o[a] < blo || o[a] > bhi) return;
            continue;
        }
        double ta = (blo - o[a]) / u, tb = (bhi - o[a]) / u;
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
    }
    if (t0 > t1) return;
    int64_t v[3], step[3];
    double tmax[3], tdelta[3];
    for (int a = 0; a < 3; a++) {
        double u = d[a] / len, x = o[a] * c->inv;
        v[a] = pb_floor_i64(x);
        step[a] = u > 0 ? 1 : -1;
        tdelta[a] = u != 0 ? c->cfg.cell_m / std::fabs(u) : INFINITY;
        double frac = u > 0 ? (double)(v[a] + 1) - x : x - (double)v[a];
        tmax[a] = u != 0 ? frac * c->cfg.cell_m / std::fabs(u) : INFINITY;
    }
    double t_in = 0;
    for (;;) {
        int a = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
        bool inside = true;   /* the walk leaves the cells' box once and for all (each axis moves one way) */
        for (int b = 0; b < 3; b++) {
            if (step[b] > 0 ? v[b] > c->hi[b] : v[b] < c->lo[b]) return;
            inside &= v[b] >= c->lo[b] && v[b] <= c->hi[b];
        }
        if (inside && pb_loc::voxel_key(v[0], v[1], v[2], &key)) {
            int32_t k = c->index.find(key);
            if (k >= 0 && c->counts[(size_t)k].raised >= 0) {
                /* the raised part is passed when the ray stays clear of the ground through the cell */
                double t_out = std::min(tmax[a], stop);
                double zlow = o[2] + d[2] / len * (d[2] < 0 ? t_out : t_in);
                if (zlow > c->counts[(size_t)k].ground_z + c->cfg.raise_m) k = c->counts[(size_t)k].raised;
            }
            if (k >= 0) {
                Count &n = c->counts[(size_t)k];
                (n.hits ? n.passes_after : n.passes_before)++;
            }
        }
        if (tmax[a] > stop) break;
        t_in = tmax[a];
        v[a] += step[a];
        tmax[a] += tdelta[a];
    }
}

size_t pb_carve_keep(const pb_carve_t *c, std::vector<uint8_t> *keep)
{
    keep->assign(c->point_cell.size(), 1);
    size_t carved = 0;
    for (size_t i = 0; i < c->point_cell.size(); i++) {
        int32_t k = c->point_cell[i];
        if (k < 0) continue;
        const Count &n = c->counts[(size_t)k];
        if (!n.protect && n.passes_before + n.passes_after >= (uint32_t)c->cfg.min_passes &&
            n.last_hit - n.first_hit <= (int64_t)(c->cfg.transient_s * 1e6)) {
            (*keep)[i] = 0;
            carved++;
        }
    }
    return carved;
}

void pb_carve_save(const pb_carve_t *c, std::vector<uint8_t> *out)
{
    out->resize(c->counts.size() * sizeof(Count));
    if (!out->empty()) std::memcpy(out->data(), c->counts.data(), out->size());
}

int pb_carve_load(pb_carve_t *c, const uint8_t *data, size_t len)
{
    if (len != c->counts.size() * sizeof(Count)) return -1;
    if (len) std::memcpy(c->counts.data(), data, len);
    return 0;
}
