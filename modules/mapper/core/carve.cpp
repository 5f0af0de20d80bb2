/* carve: see carve.h. */
#include "carve.h"

#include <algorithm>
#include <cmath>

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
    uint8_t drive_passes;   /* passes in the drive now (saturating) */
    uint8_t drive;     /* bit 0: hit in the drive now; bit 1: a drive passed it min_passes times, no hit;
                        * bit 2: an earlier drive hit it over more than transient_s; bits 3-7: the
                        * earlier drives that hit it (saturating) */
};

/* Whether the drive now passed the cell often enough without hitting it. */
static bool empty_in_drive(const Count &n, int min_passes) { return !(n.drive & 1) && n.drive_passes >= min_passes; }
}  // namespace

struct pb_carve {
    pb_carve_config_t cfg;
    double inv;
    pb_loc::VoxelHash index;
    std::vector<Count> counts;
    std::vector<int32_t> point_cell;   /* per map point, its cell (-1: outside the key range) */
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
        if (!pb_loc::voxel_key_of(p[0], p[1], p[2], c->inv, &key)) continue;
        bool fresh;
        int32_t k = c->index.insert(key, (int32_t)c->counts.size(), &fresh);
        if (fresh) {
            /* the ground under the cell's centre */
            double g, cx = (std::floor(p[0] * c->inv) + 0.5) * c->cfg.cell_m, cy = (std::floor(p[1] * c->inv) + 0.5) * c->cfg.cell_m;
            uint8_t protect = ground && pb_ground_height(ground, cx, cy, &g) == 0 &&
                              std::floor(p[2] * c->inv) * c->cfg.cell_m <= g + c->cfg.ground_band_m;
            c->counts.push_back(Count{0, 0, 0, 0, 0, protect ? (float)g : 0.0f, -1, protect, 0, 0});
        }
        /* a band cell's points clear of the ground are judged apart: a car's sill over the road */
        Count &n = c->counts[(size_t)k];
        if (n.protect && p[2] > n.ground_z + c->cfg.raise_m) {
            if (n.raised < 0) {
                n.raised = (int32_t)c->counts.size();
                c->counts.push_back(Count{0, 0, 0, 0, 0, 0.0f, -1, 0, 0, 0});
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
            n.drive |= 1;
        }
    }
    /* the cells the ray crosses up to end_margin_m before its end, in order (a 3-D DDA) */
    const double stop = len - c->cfg.end_margin_m;
    if (stop <= 0) return;
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
        if (pb_loc::voxel_key(v[0], v[1], v[2], &key)) {
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
                if (n.drive_passes < 255) n.drive_passes++;
            }
        }
        if (tmax[a] > stop) break;
        t_in = tmax[a];
        v[a] += step[a];
        tmax[a] += tdelta[a];
    }
}

void pb_carve_next_drive(pb_carve_t *c)
{
    for (Count &n : c->counts) {
        if (empty_in_drive(n, c->cfg.min_passes)) n.drive |= 2;
        if (n.hits && n.last_hit - n.first_hit > (int64_t)(c->cfg.transient_s * 1e6)) n.drive |= 4;
        /* the span of hits is each drive's own (two drives meeting the same bus an hour apart
         * are two short spans); the passes outside it add up */
        n.passes_before += n.passes_after;
        n.passes_after = 0;
        if (n.hits && n.drive >> 3 < 31) n.drive += 8;
        n.hits = 0;
        n.drive &= ~1;
        n.drive_passes = 0;
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
        /* seen through outside a short span of hits (min_passes for each drive that hit it),
         * or empty in one of several drives (with one drive, a cell it never hit: carved by
         * the first rule too) */
        const uint32_t drives_hit = (uint32_t)(n.drive >> 3) + (n.hits > 0);
        const bool moved = n.passes_before + n.passes_after >= (uint32_t)c->cfg.min_passes * std::max(1u, drives_hit) &&
                           n.last_hit - n.first_hit <= (int64_t)(c->cfg.transient_s * 1e6) && !(n.drive & 4);
        if (!n.protect && (moved || (n.drive & 2) || empty_in_drive(n, c->cfg.min_passes))) {
            (*keep)[i] = 0;
            carved++;
        }
    }
    return carved;
}
