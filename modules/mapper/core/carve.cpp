/* carve: see carve.h. */
#include "carve.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "voxel_hash.h"

namespace {
struct Count {
    int64_t visit_start, last_hit;   /* utime: the present visit's first hit, the last hit */
    uint32_t hits;
    uint32_t passes;           /* passes outside the visits: before the first, between, after the last */
    uint32_t passes_since_hit; /* passes since the last hit: inside the visit if the next hit continues it */
    float longest_s;           /* the longest visit that ended */
    float ground_z;    /* band cells: the ground model's height at the cell's centre */
    int32_t raised;    /* band cells: the cell of its points higher than raise_m over the ground, or -1 */
    uint8_t protect;   /* in the band over the ground: never carved */
    uint8_t visits;    /* spans of hits kept apart by more than revisit_s (up to 255), in the drive of drive */
    uint8_t occupied;  /* the cell's eighths (x, y, z halves; bit x + 2y + 4z) that hold its points */
    uint8_t drive;     /* the drive the counts below are of (pb_carve_set_drive) */
    uint8_t drive_passes;  /* passes in that drive (saturating) */
    uint8_t drive_flags;   /* bit 0: hit in that drive; bit 1: an earlier drive passed it min_passes_empty
                            * times and never hit it; bit 2: an earlier drive hit it on more than
                            * max_visits visits; bits 3-7: the earlier drives that hit it (saturating) */
};

/* The counts of a cell last touched in an earlier drive, carried into drive d: what that
 * drive said kept in drive_flags, its visits and passes of its own started afresh. */
inline void roll_to(Count &n, uint8_t d, const pb_carve_config_t &cfg)
{
    if (n.drive == d) return;
    if (!(n.drive_flags & 1) && n.drive_passes >= cfg.min_passes_empty) n.drive_flags |= 2;
    if (n.visits > cfg.max_visits) n.drive_flags |= 4;
    if ((n.drive_flags & 1) && (n.drive_flags >> 3) < 31) n.drive_flags += 8;
    if (n.hits) n.longest_s = std::max(n.longest_s, (float)((double)(n.last_hit - n.visit_start) * 1e-6));
    n.drive_flags &= (uint8_t)~1u;
    n.visits = 0;
    n.drive_passes = 0;
    n.drive = d;
}

/* The eighth of the cell whose lowest corner is lo (half its edge: half_m) that p falls in, as a bit. */
inline uint8_t eighth_bit(const double p[3], const double lo[3], double half_m)
{
    int b = 0;
    for (int a = 0; a < 3; a++) b |= (p[a] >= lo[a] + half_m) << a;
    return (uint8_t)(1u << b);
}
}  // namespace

struct pb_carve {
    pb_carve_config_t cfg;
    double inv;
    pb_loc::VoxelHash index;
    uint8_t drive = 0;                 /* the drive the rays now come from */
    std::vector<Count> counts;
    std::vector<int32_t> point_cell;   /* per map point, its cell (-1: outside the key range) */
    int64_t lo[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, hi[3] = {INT64_MIN, INT64_MIN, INT64_MIN};   /* cells' extent */
    /* a bit per cell of the extent, set where the map has points: a ray's walk crosses mostly
     * empty cells, and a bit is cheaper to test than the index (none when the extent is too large) */
    pb_loc::VoxelBits occupied;

    bool maybe_occupied(const int64_t v[3]) const   /* v within the extent */
    {
        return occupied.words.empty() || occupied.has(v[0], v[1], v[2]);
    }
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
            c->counts.push_back(Count{0, 0, 0, 0, 0, 0.0f, protect ? (float)g : 0.0f, -1, protect, 0, 0, 0, 0, 0});
        }
        /* a band cell's points clear of the ground are judged apart: a car's sill over the road */
        Count &n = c->counts[(size_t)k];
        if (n.protect && p[2] > n.ground_z + c->cfg.raise_m) {
            if (n.raised < 0) {
                n.raised = (int32_t)c->counts.size();
                c->counts.push_back(Count{0, 0, 0, 0, 0, 0.0f, 0.0f, -1, 0, 0, 0, 0, 0, 0});
            }
            k = c->counts[(size_t)k].raised;
        }
        c->point_cell[i] = k;
        /* the eighth of the cell it lies in */
        const double pd[3] = {p[0], p[1], p[2]};
        const double lo[3] = {std::floor(p[0] * c->inv) * c->cfg.cell_m, std::floor(p[1] * c->inv) * c->cfg.cell_m,
                              std::floor(p[2] * c->inv) * c->cfg.cell_m};
        c->counts[(size_t)k].occupied |= eighth_bit(pd, lo, c->cfg.cell_m / 2);
    }
    /* the occupied cells' bits, when the extent is at most 2^26 cells (8 MB) */
    if (!c->counts.empty() && c->occupied.cover(c->lo, c->hi, (int64_t)1 << 26))
        c->index.for_each([&](uint64_t key, int32_t) { c->occupied.set(key); });
    return c;
}

void pb_carve_destroy(pb_carve_t *c) { delete c; }

/* The eighths of cell v that the ray o + u t (u unit) crosses for t in [t0, t1], as bits. */
static uint8_t eighths_crossed(const pb_carve_t *c, const int64_t v[3], const double o[3], const double u[3], double t0,
                               double t1)
{
    const double half = c->cfg.cell_m / 2;
    double lo[3], p[3], q[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = (double)v[a] * c->cfg.cell_m;
        p[a] = o[a] + u[a] * t0;
        q[a] = o[a] + u[a] * t1;
    }
    /* the segment crosses each of the three mid-planes at most once: an eighth is crossed
     * where a piece between two crossings (in order) has its middle */
    double cuts[5] = {t0, t1, t1, t1, t1};
    int n = 1;
    for (int a = 0; a < 3; a++) {
        double mid = lo[a] + half;
        if ((p[a] - mid) * (q[a] - mid) < 0) {
            double t = t0 + (mid - p[a]) / u[a];
            int i = n++;
            for (; i > 1 && cuts[i - 1] > t; i--) cuts[i] = cuts[i - 1];   /* kept in order */
            cuts[i] = t;
        }
    }
    cuts[n] = t1;
    uint8_t m = 0;
    for (int i = 0; i < n; i++) {
        double t = 0.5 * (cuts[i] + cuts[i + 1]), x[3] = {o[0] + u[0] * t, o[1] + u[1] * t, o[2] + u[2] * t};
        m |= eighth_bit(x, lo, half);
    }
    return m;
}

void pb_carve_ray(pb_carve_t *c, int64_t utime, const double o[3], const double e[3])
{
    double d[3] = {e[0] - o[0], e[1] - o[1], e[2] - o[2]};
    double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len > 1e-6)) return;
    /* a return beyond max_range_m is no hit, but the beam was free up to there */
    const bool beyond = len > c->cfg.max_range_m;
    uint64_t key;
    if (!beyond && pb_loc::voxel_key_of(e[0], e[1], e[2], c->inv, &key)) {
        int32_t k = c->index.find(key);
        if (k >= 0 && c->counts[(size_t)k].raised >= 0 && e[2] > c->counts[(size_t)k].ground_z + c->cfg.raise_m)
            k = c->counts[(size_t)k].raised;
        if (k >= 0) {
            Count &n = c->counts[(size_t)k];
            roll_to(n, c->drive, c->cfg);
            n.drive_flags |= 1;
            if (n.hits == 0 || utime - n.last_hit > (int64_t)(c->cfg.revisit_s * 1e6)) {   /* a new visit */
                if (n.hits) n.longest_s = std::max(n.longest_s, (float)((double)(n.last_hit - n.visit_start) * 1e-6));
                n.passes += n.passes_since_hit;
                n.visit_start = utime;
                n.visits += n.visits < 255;
            }
            n.hits++;
            n.last_hit = utime;
            n.passes_since_hit = 0;
        }
    }
    /* the cells the ray crosses up to end_margin_m before its end, in order (a 3-D DDA) */
    const double stop = beyond ? c->cfg.max_range_m : len - c->cfg.end_margin_m;
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
    const double u3[3] = {d[0] / len, d[1] / len, d[2] / len};
    int64_t v[3], step[3];
    double tmax[3], tdelta[3];
    for (int a = 0; a < 3; a++) {
        double u = u3[a], x = o[a] * c->inv;
        v[a] = pb_floor_i64(x);
        step[a] = u > 0 ? 1 : -1;
        tdelta[a] = u != 0 ? c->cfg.cell_m / std::fabs(u) : INFINITY;
        double frac = u > 0 ? (double)(v[a] + 1) - x : x - (double)v[a];
        tmax[a] = u != 0 ? frac * c->cfg.cell_m / std::fabs(u) : INFINITY;
    }
    /* the walk leaves the cells' box once and for all (each axis moves one way): checked on
     * the axis that steps; `outside` counts the axes on which the cell is not in the box */
    auto out_on = [&](int b) { return v[b] < c->lo[b] || v[b] > c->hi[b]; };
    int outside = 0;
    for (int b = 0; b < 3; b++) {
        if (step[b] > 0 ? v[b] > c->hi[b] : v[b] < c->lo[b]) return;
        outside += out_on(b);
    }
    double t_in = 0;
    for (;;) {
        int a = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
        if (!outside && c->maybe_occupied(v) && pb_loc::voxel_key(v[0], v[1], v[2], &key)) {
            int32_t k = c->index.find(key);
            const double t_out = std::min(tmax[a], stop);
            if (k >= 0 && c->counts[(size_t)k].raised >= 0) {
                /* the raised part is passed when the ray stays clear of the ground through the cell */
                double zlow = o[2] + d[2] / len * (d[2] < 0 ? t_out : t_in);
                if (zlow > c->counts[(size_t)k].ground_z + c->cfg.raise_m) k = c->counts[(size_t)k].raised;
            }
            /* a pass through the cell's empty part (beside a wall, over a roof's edge) is none */
            if (k >= 0 && (eighths_crossed(c, v, o, u3, t_in, t_out) & c->counts[(size_t)k].occupied)) {
                Count &n = c->counts[(size_t)k];
                roll_to(n, c->drive, c->cfg);
                (n.hits ? n.passes_since_hit : n.passes)++;
                n.drive_passes += n.drive_passes < 255;
            }
        }
        if (tmax[a] > stop) break;
        t_in = tmax[a];
        outside -= out_on(a);
        v[a] += step[a];
        if (step[a] > 0 ? v[a] > c->hi[a] : v[a] < c->lo[a]) return;
        outside += out_on(a);
        tmax[a] += tdelta[a];
    }
}

/* A cell whose hits tell of road users passing by: visits no longer than limit_s, few enough of them. */
static bool passing(const pb_carve_config_t &cfg, const Count &n, double limit_s)
{
    const double longest_s = n.hits ? std::max((double)n.longest_s, (double)(n.last_hit - n.visit_start) * 1e-6) : 0;
    return !n.protect && n.visits <= cfg.max_visits && !(n.drive_flags & 4) && longest_s <= limit_s;
}

/* Passes enough outside the visits: min_passes for each drive that hit the cell (one drive
 * that never hit it was enough for the rest; see empty). */
static bool passed(const Count &n, int min_passes)
{
    const uint32_t drives_hit = (uint32_t)(n.drive_flags >> 3) + (n.drive_flags & 1);
    return n.passes + n.passes_since_hit >= (uint32_t)min_passes * std::max(1u, drives_hit);
}

/* Empty in a drive: passed min_passes_empty times in it and never hit in it (several drives:
 * what the others saw there was parked, then gone). */
static bool empty(const pb_carve_config_t &cfg, const Count &n)
{
    return !n.protect && ((n.drive_flags & 2) || (!(n.drive_flags & 1) && n.drive_passes >= cfg.min_passes_empty));
}

/* Step 1: the cells seen through often enough outside their visits (more often after a
 * longer visit: several road users one after the other). */
static std::vector<uint8_t> gone_cells(const pb_carve_t *c)
{
    std::vector<uint8_t> gone(c->counts.size(), 0);
    for (size_t k = 0; k < c->counts.size(); k++) {
        const Count &n = c->counts[k];
        gone[k] = (passing(c->cfg, n, c->cfg.transient_s) && passed(n, c->cfg.min_passes)) ||
                  (passing(c->cfg, n, c->cfg.long_visit_s) && passed(n, c->cfg.min_passes_long)) || empty(c->cfg, n);
    }
    return gone;
}

/* Each cell's key (a raised part has its cell's). */
static std::vector<uint64_t> cell_keys(const pb_carve_t *c)
{
    std::vector<uint64_t> key(c->counts.size(), 0);
    c->index.for_each([&](uint64_t kk, int32_t v) {
        key[(size_t)v] = kk;
        if (c->counts[(size_t)v].raised >= 0) key[(size_t)c->counts[(size_t)v].raised] = kk;
    });
    return key;
}

void pb_carve_gone(const pb_carve_t *c, std::vector<uint64_t> *keys)
{
    const std::vector<uint8_t> gone = gone_cells(c);
    const std::vector<uint64_t> key = cell_keys(c);
    for (size_t k = 0; k < gone.size(); k++)
        if (gone[k]) keys->push_back(key[k]);
}

size_t pb_carve_keep(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, std::vector<uint8_t> *keep)
{
    const pb_carve_config_t &cfg = c->cfg;
    const size_t ncells = c->counts.size();
    // 1. the cells seen through often enough outside their visits
    const std::vector<uint8_t> gone = gone_cells(c);
    // 2. the cells seen through less often (or never: the sample is sparse), or hit over a
    //    longer visit but seen through min_passes times, lying among such cells (here, or in
    //    the other parts' gone_keys): the rest of the same body
    const std::vector<uint64_t> key = cell_keys(c);
    auto neighbour_gone = [&](uint64_t nk) {
        if (gone_keys) return std::binary_search(gone_keys->begin(), gone_keys->end(), nk);
        int32_t j = c->index.find(nk);
        if (j < 0) return false;
        int32_t r = c->counts[(size_t)j].raised;
        return gone[(size_t)j] || (r >= 0 && gone[(size_t)r]);
    };
    std::vector<uint8_t> grown(gone);
    for (size_t k = 0; k < ncells; k++) {
        const Count &n = c->counts[k];
        if (gone[k] || !(passing(cfg, n, cfg.transient_s) || (passing(cfg, n, cfg.long_visit_s) && passed(n, cfg.min_passes))))
            continue;
        int64_t v[3];
        pb_loc::voxel_unkey(key[k], &v[0], &v[1], &v[2]);
        int around = 0;
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++)
                for (int dz = -1; dz <= 1; dz++) {
                    uint64_t nk;
                    if ((dx | dy | dz) == 0 || !pb_loc::voxel_key(v[0] + dx, v[1] + dy, v[2] + dz, &nk)) continue;
                    around += neighbour_gone(nk);
                }
        grown[k] = around >= cfg.carved_beside;
    }
    // 3. their points
    keep->assign(c->point_cell.size(), 1);
    size_t carved = 0;
    for (size_t i = 0; i < c->point_cell.size(); i++) {
        int32_t k = c->point_cell[i];
        if (k >= 0 && grown[(size_t)k]) {
            (*keep)[i] = 0;
            carved++;
        }
    }
    return carved;
}

void pb_carve_set_drive(pb_carve_t *c, int drive) { c->drive = (uint8_t)std::min(std::max(drive, 0), 255); }

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
