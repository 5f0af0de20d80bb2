/* carve: see carve.h. */
#include "carve.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <array>
#include <unordered_map>
#include <unordered_set>

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
    /* the views' points: those more than low_point_m over the ground (those more than
     * group_ground_m join groups, the others are judged alone), and per such point its x y z,
     * its height, and (saturating) the views that saw through it, that saw it, that hit it
     * (its bin's return at it), that saw through it after its last hit so far, and between
     * two hits */
    std::vector<uint32_t> over;
    std::vector<float> xyz, height;
    std::vector<uint8_t> through, seen, hit, since_hit, inside;
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
        double g;
        if (ground && pb_ground_height(ground, p[0], p[1], &g) == 0 && p[2] - g > c->cfg.low_point_m) {
            c->over.push_back((uint32_t)i);
            c->xyz.insert(c->xyz.end(), p, p + 3);
            c->height.push_back((float)(p[2] - g));
        }
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
    for (auto *v : {&c->through, &c->seen, &c->hit, &c->since_hit, &c->inside}) v->assign(c->over.size(), 0);
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

/* A view's range image, rows of elevation and columns of azimuth in the LiDAR's frame, sized
 * to the sweep: a row per beam gap when the returns name their beams (else square bins),
 * and about as many bins as returns, so that a sweep thinned to a keyframe (MulRan's: 14,000
 * returns) is binned as coarsely as its returns are spread. Per bin the nearest return
 * (INFINITY: none) and its height over the ground (NAN: no ground there), and the nearest in
 * the 3 x 3 bins around it when 5 or more of them returned (else 0: too little seen there to
 * see through). */
struct pb_carve_view {
    double o[3], R[9];
    double low = 0, row = 1;   /* elevation of row 0's lower edge, a row's height (rad) */
    int rows = 0, cols = 0;
    std::vector<float> near, around, height;

    /* p's direction from the origin in the LiDAR's frame: elevation, azimuth; and its range. */
    void look_at(const double p[3], double *el, double *az, double *r) const
    {
        const double d[3] = {p[0] - o[0], p[1] - o[1], p[2] - o[2]};
        double l[3];
        for (int a = 0; a < 3; a++) l[a] = R[a] * d[0] + R[3 + a] * d[1] + R[6 + a] * d[2];   /* R^T d */
        const double h = std::hypot(l[0], l[1]);
        *r = std::sqrt(h * h + l[2] * l[2]);
        *el = std::atan2(l[2], h);
        *az = std::atan2(l[1], l[0]);
    }
    /* The bin of p (false: outside the rows), and its range. */
    bool bin(const double p[3], int *row_i, int *col_i, double *r) const
    {
        double el, az;
        look_at(p, &el, &az, r);
        const int e = (int)std::floor((el - low) / row);
        if (e < 0 || e >= rows) return false;
        *row_i = e;
        *col_i = std::min(cols - 1, (int)((az + M_PI) * (cols / (2 * M_PI))));
        return true;
    }
};

pb_carve_view_t *pb_carve_view_create(const double *xyz, const uint8_t *ring, size_t n, const double origin[3],
                                      const double R[9], const pb_ground_t *ground)
{
    if (n == 0) return nullptr;
    pb_carve_view_t *v = new pb_carve_view();
    std::memcpy(v->o, origin, sizeof v->o);
    std::memcpy(v->R, R, sizeof v->R);
    // the bins: the returns' span of elevation, cut by beam gaps or into squares
    double lo = INFINITY, hi = -INFINITY;
    uint64_t beams[4] = {0, 0, 0, 0};
    for (size_t i = 0; i < n; i++) {
        double el, az, r;
        v->look_at(xyz + 3 * i, &el, &az, &r);
        if (!(r > 0.5)) continue;
        lo = std::min(lo, el);
        hi = std::max(hi, el);
        if (ring && ring[i] != 255) beams[ring[i] >> 6] |= (uint64_t)1 << (ring[i] & 63);
    }
    if (!(hi >= lo)) { delete v; return nullptr; }
    const int nbeams = __builtin_popcountll(beams[0]) + __builtin_popcountll(beams[1]) + __builtin_popcountll(beams[2]) +
                       __builtin_popcountll(beams[3]);
    const double span = std::max(hi - lo, 1e-3);
    v->row = nbeams >= 2 ? span / (nbeams - 1) : std::sqrt(span * 2 * M_PI / (double)n);
    v->rows = (int)std::floor(span / v->row) + 2;
    v->low = lo - 0.5 * v->row;
    v->cols = std::max(8, std::min(8192, (int)std::lround((double)n / v->rows)));
    const int W = v->cols, H = v->rows;
    v->near.assign((size_t)W * H, INFINITY);
    std::vector<int32_t> nearest((size_t)W * H, -1);
    for (size_t i = 0; i < n; i++) {
        int row, col;
        double r;
        if (v->bin(xyz + 3 * i, &row, &col, &r) && r > 0.5) {
            const size_t b = (size_t)row * W + col;
            if ((float)r < v->near[b]) {
                v->near[b] = (float)r;
                nearest[b] = (int32_t)i;
            }
        }
    }
    v->height.assign((size_t)W * H, NAN);
    for (size_t b = 0; ground && b < nearest.size(); b++) {
        double g;
        if (nearest[b] < 0) continue;
        const double *p = xyz + 3 * (size_t)nearest[b];
        if (pb_ground_height(ground, p[0], p[1], &g) == 0) v->height[b] = (float)(p[2] - g);
    }
    v->around.assign((size_t)W * H, 0.0f);
    for (int row = 0; row < H; row++)
        for (int col = 0; col < W; col++) {
            float m = INFINITY;
            int known = 0;
            for (int dr = -1; dr <= 1; dr++) {
                if (row + dr < 0 || row + dr >= H) continue;
                for (int dc = -1; dc <= 1; dc++) {
                    float b = v->near[(size_t)(row + dr) * W + (col + dc + W) % W];   /* azimuth wraps */
                    known += std::isfinite(b);
                    m = std::min(m, b);
                }
            }
            v->around[(size_t)row * W + col] = known >= 5 ? m : 0.0f;
        }
    return v;
}

void pb_carve_view_destroy(pb_carve_view_t *v) { delete v; }

/* View point i is too low to join groups (judged alone). */
static bool is_low(const pb_carve_t *c, size_t i) { return c->height[i] <= c->cfg.group_ground_m; }

/* A point just over the ground (lower than group_ground_m) seen through: the returns of its
 * row's bins (its own and one either side) all farther than `beyond` and come down on the
 * ground behind it, lower over the ground than its height by low_drop_m. The 3 x 3 bins
 * of a higher point would hold the road in front of it (the row below); and a beam over a
 * kerb or a raised patch ends on the surface at the point's height, which is no sign that
 * the point was gone. */
static bool low_through(const pb_carve_t *c, const pb_carve_view_t *v, int row, int col, float beyond, float height)
{
    int known = 0;
    for (int dc = -1; dc <= 1; dc++) {
        const size_t b = (size_t)row * v->cols + (col + dc + v->cols) % v->cols;   /* azimuth wraps */
        if (!std::isfinite(v->near[b])) continue;
        if (!(v->near[b] > beyond && v->height[b] < height - (float)c->cfg.low_drop_m)) return false;
        known++;
    }
    return known >= 2;
}

void pb_carve_look(pb_carve_t *c, const pb_carve_view_t *v)
{
    if (!v) return;
    const float reach = (float)c->cfg.max_range_m, o[3] = {(float)v->o[0], (float)v->o[1], (float)v->o[2]};
    float R[9];
    for (int a = 0; a < 9; a++) R[a] = (float)v->R[a];
    const float low = (float)v->low, per_row = (float)(1 / v->row), per_col = (float)(v->cols / (2 * M_PI));
    auto add = [](uint8_t &n, int k) { n = (uint8_t)std::min(255, n + k); };
    for (size_t i = 0; i < c->over.size(); i++) {
        const float d[3] = {c->xyz[3 * i] - o[0], c->xyz[3 * i + 1] - o[1], c->xyz[3 * i + 2] - o[2]};
        if (std::fabs(d[0]) > reach || std::fabs(d[1]) > reach) continue;
        const float r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if (r2 < 4 || r2 > reach * reach) continue;
        // its bin: the direction in the LiDAR's frame (R^T d), as pb_carve_view::bin but in float (every point, every view)
        float l[3];
        for (int a = 0; a < 3; a++) l[a] = R[a] * d[0] + R[3 + a] * d[1] + R[6 + a] * d[2];
        const int row = (int)std::floor((std::atan2(l[2], std::sqrt(l[0] * l[0] + l[1] * l[1])) - low) * per_row);
        if (row < 0 || row >= v->rows) continue;
        const int col = std::min(v->cols - 1, (int)((std::atan2(l[1], l[0]) + (float)M_PI) * per_col));
        const size_t b = (size_t)row * v->cols + col;
        const float r = std::sqrt(r2), margin = std::max((float)c->cfg.view_margin_m, (float)c->cfg.view_margin_share * r);
        const bool through = is_low(c, i) ? low_through(c, v, row, col, r + margin, c->height[i]) : v->around[b] > r + margin,
                   hit = !through && std::fabs(v->near[b] - r) <= margin;
        if (through) {
            add(c->through[i], 1);
            if (c->hit[i]) add(c->since_hit[i], 1);
        }
        if (through || (std::isfinite(v->near[b]) && v->near[b] > r - margin)) add(c->seen[i], 1);
        if (hit) {   /* seen through between two hits: something that stays, seen through in part (a railing, leaves) */
            add(c->inside[i], c->since_hit[i]);
            c->since_hit[i] = 0;
            add(c->hit[i], 1);
        }
    }
}

/* View point i (of over) seen through by enough views, and never between two hits. */
static bool seen_through(const pb_carve_t *c, size_t i)
{
    return c->through[i] >= c->cfg.view_min_through && 2 * c->through[i] >= c->seen[i] && c->inside[i] == 0;
}

/* View point i just over the ground, judged alone (no group): seen through by min_through
 * views or more, by three quarters of those that saw it, and hit by one at most. */
static bool low_gone(const pb_carve_t *c, size_t i, int min_through)
{
    return is_low(c, i) && c->through[i] >= min_through && 4 * c->through[i] >= 3 * c->seen[i] && c->hit[i] <= 1;
}

/* The group cell of view point i (of over); false for a point too low to join groups. */
static bool group_key(const pb_carve_t *c, size_t i, uint64_t *key)
{
    return !is_low(c, i) &&
           pb_loc::voxel_key_of(c->xyz[3 * i], c->xyz[3 * i + 1], c->xyz[3 * i + 2], 1.0 / c->cfg.group_cell_m, key);
}

void pb_carve_seeds(const pb_carve_t *c, std::vector<uint64_t> *keys)
{
    uint64_t key;
    for (size_t i = 0; i < c->over.size(); i++)
        if (seen_through(c, i) && group_key(c, i, &key)) keys->push_back(key);
}

/* The seeds' columns (x-y cells), bucketed by squares of the reach: the x-y distance from a
 * point to the nearest seed column's centre is looked up in the 3 x 3 buckets around it. */
struct pb_carve_near {
    double cell_m, reach;
    std::unordered_map<uint64_t, std::vector<std::array<double, 2>>> buckets;

    pb_carve_near(const std::vector<uint64_t> &seeds, double cell, double reach_m) : cell_m(cell), reach(reach_m)
    {
        std::vector<uint64_t> cols;   /* the seeds' columns as voxel keys at z = 0, each once */
        for (uint64_t k : seeds) {
            int64_t v[3];
            uint64_t col;
            pb_loc::voxel_unkey(k, &v[0], &v[1], &v[2]);
            if (pb_loc::voxel_key(v[0], v[1], 0, &col)) cols.push_back(col);
        }
        std::sort(cols.begin(), cols.end());
        cols.erase(std::unique(cols.begin(), cols.end()), cols.end());
        for (uint64_t col : cols) {
            int64_t v[3];
            pb_loc::voxel_unkey(col, &v[0], &v[1], &v[2]);
            const double x = ((double)v[0] + 0.5) * cell_m, y = ((double)v[1] + 0.5) * cell_m;
            uint64_t b;
            if (pb_loc::voxel_key(pb_floor_i64(x / reach), pb_floor_i64(y / reach), 0, &b)) buckets[b].push_back({x, y});
        }
    }
    /* Any seed column in the buckets that a box [lo, hi] (x-y) grown by the reach touches. */
    bool any_near(const double lo[2], const double hi[2]) const
    {
        for (int64_t bx = pb_floor_i64(lo[0] / reach) - 1; bx <= pb_floor_i64(hi[0] / reach) + 1; bx++)
            for (int64_t by = pb_floor_i64(lo[1] / reach) - 1; by <= pb_floor_i64(hi[1] / reach) + 1; by++) {
                uint64_t b;
                if (pb_loc::voxel_key(bx, by, 0, &b) && buckets.count(b)) return true;
            }
        return false;
    }
    /* The x-y distance from cell key's centre to the nearest seed column's, INFINITY beyond the reach. */
    double distance(uint64_t key) const
    {
        int64_t v[3];
        pb_loc::voxel_unkey(key, &v[0], &v[1], &v[2]);
        const double x = ((double)v[0] + 0.5) * cell_m, y = ((double)v[1] + 0.5) * cell_m;
        const int64_t bx = pb_floor_i64(x / reach), by = pb_floor_i64(y / reach);
        double best2 = INFINITY;   /* squared: std::hypot per column was a quarter of MulRan's mapper */
        for (int64_t dx = -1; dx <= 1; dx++)
            for (int64_t dy = -1; dy <= 1; dy++) {
                uint64_t b;
                if (!pb_loc::voxel_key(bx + dx, by + dy, 0, &b)) continue;
                auto it = buckets.find(b);
                if (it == buckets.end()) continue;
                for (const auto &c : it->second)
                    best2 = std::min(best2, (c[0] - x) * (c[0] - x) + (c[1] - y) * (c[1] - y));
            }
        const double best = std::sqrt(best2);
        return best <= reach ? best : INFINITY;
    }
};

pb_carve_near_t *pb_carve_near_create(const std::vector<uint64_t> &seeds, const pb_carve_config_t *cfg)
{
    pb_carve_config_t d;
    if (!cfg) cfg = &d;
    return new pb_carve_near(seeds, cfg->group_cell_m, cfg->group_reach_m);
}

void pb_carve_near_destroy(pb_carve_near_t *n) { delete n; }

/* A group cell (or group) holding no point yet. */
static pb_carve_group_cell_t empty_cell(uint64_t key, bool edge, bool carved = false)
{
    return pb_carve_group_cell_t{key, 0, 0, 0, {INFINITY, INFINITY}, {-INFINITY, -INFINITY}, INFINITY, -INFINITY, {0, 0, 0, 0, 0},
                                 (uint8_t)edge, (uint8_t)carved};
}

/* Steps 1-3 of pb_carve_keep: the cells' verdicts on the points. */
static size_t keep_by_cells(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, std::vector<uint8_t> *keep);

void pb_carve_group_cells(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, const pb_carve_near_t *seeds,
                          std::vector<pb_carve_group_cell_t> *cells)
{
    const pb_carve_config_t &cfg = c->cfg;
    if (seeds->buckets.empty() || c->counts.empty()) return;
    const pb_carve_near &near = *seeds;
    const double lo[2] = {(double)c->lo[0] * cfg.cell_m, (double)c->lo[1] * cfg.cell_m},
                 hi[2] = {(double)(c->hi[0] + 1) * cfg.cell_m, (double)(c->hi[1] + 1) * cfg.cell_m};
    if (!near.any_near(lo, hi)) return;   /* no seed within reach of this part */
    std::vector<uint8_t> keep;
    keep_by_cells(c, gone_keys, &keep);
    /* group cell -> its entry in cells (from first), or kFar: one for the kept points, one for
     * those the cells carved */
    pb_loc::VoxelHash index[2] = {pb_loc::VoxelHash(1024), pb_loc::VoxelHash(1024)};
    constexpr int32_t kFar = -2;
    const size_t first = cells->size();
    for (size_t i = 0; i < c->over.size(); i++) {
        uint64_t key;
        if (!group_key(c, i, &key)) continue;
        const bool kept = keep[c->over[i]];
        int32_t k = index[!kept].find(key);
        if (k == -1) {
            const double d = near.distance(key);
            bool fresh;
            k = index[!kept].insert(key, std::isfinite(d) ? (int32_t)(cells->size() - first) : kFar, &fresh);
            if (k != kFar) cells->push_back(empty_cell(key, d > cfg.group_reach_m - 2 * cfg.group_cell_m, !kept));
        }
        if (k == kFar) continue;
        pb_carve_group_cell_t &g = (*cells)[first + (size_t)k];
        g.n++;
        if (kept) {
            g.kept++;
            g.through += seen_through(c, i);
        }
        for (int a = 0; a < 2; a++) {
            g.lo[a] = std::min(g.lo[a], c->xyz[3 * i + a]);
            g.hi[a] = std::max(g.hi[a], c->xyz[3 * i + a]);
        }
        g.hmin = std::min(g.hmin, c->height[i]);
        g.hmax = std::max(g.hmax, c->height[i]);
        const double x = c->xyz[3 * i], y = c->xyz[3 * i + 1];
        const double m[5] = {x, y, x * x, x * y, y * y};
        for (int a = 0; a < 5; a++) g.sum[a] += m[a];
    }
}

/* The spread of a group's points across its length (x-y): the root of the smaller eigenvalue
 * of their covariance. */
static double depth(const pb_carve_group_cell_t &g)
{
    const double n = (double)g.n, mx = g.sum[0] / n, my = g.sum[1] / n;
    const double cxx = g.sum[2] / n - mx * mx, cxy = g.sum[3] / n - mx * my, cyy = g.sum[4] / n - my * my;
    const double half = 0.5 * (cxx + cyy), r = std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy);
    return std::sqrt(std::max(half - r, 0.0));
}

/* Cell or group `from` taken into `into`: their points, extents and heights together. */
static void absorb(pb_carve_group_cell_t &into, const pb_carve_group_cell_t &from)
{
    into.n += from.n;
    into.kept += from.kept;
    into.through += from.through;
    for (int a = 0; a < 2; a++) {
        into.lo[a] = std::min(into.lo[a], from.lo[a]);
        into.hi[a] = std::max(into.hi[a], from.hi[a]);
    }
    into.hmin = std::min(into.hmin, from.hmin);
    into.hmax = std::max(into.hmax, from.hmax);
    for (int a = 0; a < 5; a++) into.sum[a] += from.sum[a];
    into.edge |= from.edge;
}

/* The groups of these cells that go (their keys appended to gone, in key order). */
static void judge_groups(std::vector<pb_carve_group_cell_t> *cells, const pb_carve_config_t &cfg, std::vector<uint64_t> *gone)
{
    // one entry per cell (a cell's points may have come from two parts, or been kept and carved)
    std::sort(cells->begin(), cells->end(), [](const pb_carve_group_cell_t &x, const pb_carve_group_cell_t &y) { return x.key < y.key; });
    size_t n = 0;
    for (size_t i = 0; i < cells->size(); i++) {
        const pb_carve_group_cell_t &g = (*cells)[i];
        if (n && (*cells)[n - 1].key == g.key)
            absorb((*cells)[n - 1], g);
        else
            (*cells)[n++] = g;
    }
    cells->resize(n);
    auto through = [](const pb_carve_group_cell_t &g) { return 2 * g.through >= g.kept; };
    auto road_user = [&](const pb_carve_group_cell_t &g) {
        return !g.edge && g.n >= (uint32_t)cfg.group_min_points && (double)g.through >= cfg.group_share * (double)g.kept &&
               g.hmin <= cfg.group_foot_m && g.hmax <= cfg.group_max_height_m &&
               std::max(g.hi[0] - g.lo[0], g.hi[1] - g.lo[1]) >= cfg.group_min_width_m;
    };
    auto find = [&](uint64_t key) {
        auto it = std::lower_bound(cells->begin(), cells->end(), key,
                                   [](const pb_carve_group_cell_t &g, uint64_t k) { return g.key < k; });
        return it != cells->end() && it->key == key ? (int64_t)(it - cells->begin()) : (int64_t)-1;
    };
    std::vector<uint8_t> go(n, 0);
    std::vector<uint32_t> up(n);
    std::vector<pb_carve_group_cell_t> group(n);
    // twice: every cell, then only the cells at least half seen through (apart from what they touch)
    for (int through_only = 0; through_only < 2; through_only++) {
        // groups: touching cells joined (union-find)
        for (size_t k = 0; k < n; k++) up[k] = (uint32_t)k;
        auto root = [&](uint32_t k) {
            while (up[k] != k) k = up[k] = up[up[k]];
            return k;
        };
        for (size_t k = 0; k < n; k++) {
            if (through_only && !through((*cells)[k])) continue;
            int64_t v[3];
            pb_loc::voxel_unkey((*cells)[k].key, &v[0], &v[1], &v[2]);
            for (int dx = -1; dx <= 1; dx++)
                for (int dy = -1; dy <= 1; dy++)
                    for (int dz = -1; dz <= 1; dz++) {
                        uint64_t nk;
                        int64_t j;
                        if (!pb_loc::voxel_key(v[0] + dx, v[1] + dy, v[2] + dz, &nk) || (j = find(nk)) < 0) continue;
                        if (through_only && !through((*cells)[(size_t)j])) continue;
                        uint32_t a = root((uint32_t)k), b = root((uint32_t)j);
                        if (a != b) up[std::max(a, b)] = std::min(a, b);
                    }
        }
        // each group whole: the road users among them (seen through on their own: deep ones)
        std::fill(group.begin(), group.end(), empty_cell(0, false));
        for (size_t k = 0; k < n; k++) absorb(group[root((uint32_t)k)], (*cells)[k]);
        for (size_t k = 0; k < n; k++) {
            const pb_carve_group_cell_t &g = group[root((uint32_t)k)];
            if (road_user(g) && (!through_only || (through((*cells)[k]) && depth(g) >= cfg.group_min_depth_m))) go[k] = 1;
        }
    }
    for (size_t k = 0; k < n; k++)
        if (go[k]) gone->push_back((*cells)[k].key);   /* in key order */
}

void pb_carve_groups(std::vector<pb_carve_group_cell_t> *cells, const pb_carve_config_t *cfg_in, std::vector<uint64_t> *gone)
{
    pb_carve_config_t cfg;
    if (cfg_in) cfg = *cfg_in;
    // the groups of the kept points, then of them with the points the cells carved (a car's
    // rest beside what the rays took of it): what either takes goes
    std::vector<pb_carve_group_cell_t> kept;
    for (const pb_carve_group_cell_t &g : *cells)
        if (!g.carved) kept.push_back(g);
    judge_groups(&kept, cfg, gone);
    judge_groups(cells, cfg, gone);
    std::sort(gone->begin(), gone->end());
    gone->erase(std::unique(gone->begin(), gone->end()), gone->end());
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

static size_t keep_by_cells(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, std::vector<uint8_t> *keep)
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

size_t pb_carve_keep(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, const std::vector<uint64_t> *group_keys,
                     std::vector<uint8_t> *keep, std::vector<uint8_t> *objects)
{
    // 1-3. the cells' verdicts
    const size_t carved = keep_by_cells(c, gone_keys, keep);
    // 4. what is left over the ground, in groups with a road user's shape that views saw through
    std::vector<uint64_t> own;
    if (!group_keys) {
        std::vector<uint64_t> seeds;
        std::vector<pb_carve_group_cell_t> cells;
        pb_carve_seeds(c, &seeds);
        pb_carve_near_t *near = pb_carve_near_create(seeds, &c->cfg);
        pb_carve_group_cells(c, gone_keys, near, &cells);
        pb_carve_near_destroy(near);
        pb_carve_groups(&cells, &c->cfg, &own);
        group_keys = &own;
    }
    if (objects) objects->assign(keep->size(), 0);
    size_t by_views = 0;
    auto take = [&](size_t i) {
        (*keep)[c->over[i]] = 0;
        if (objects) (*objects)[c->over[i]] = 1;
        by_views++;
    };
    for (size_t i = 0; i < c->over.size() && !group_keys->empty(); i++) {
        uint64_t key;
        if ((*keep)[c->over[i]] && group_key(c, i, &key) && std::binary_search(group_keys->begin(), group_keys->end(), key))
            take(i);
    }
    // 5. the points just over the ground that views saw through alone (a car's sill), or as
    //    often as a body under a body that went (its wheels), unless something kept stands
    //    higher in their cell's column: they are its foot (a post's, a bush's)
    std::vector<size_t> low;
    std::unordered_map<uint64_t, float> column_top;   /* a low point's column -> the highest kept point in it */
    auto column = [&](size_t i, uint64_t *key) {
        return pb_loc::voxel_key_of(c->xyz[3 * i], c->xyz[3 * i + 1], 0.0, c->inv, key);
    };
    std::unordered_set<uint64_t> body_gone;   /* columns where a road user's body went (over group_ground_m) */
    for (size_t i = 0; i < c->over.size(); i++) {
        uint64_t key;
        if (!(*keep)[c->over[i]] && !is_low(c, i) && c->height[i] <= c->cfg.group_max_height_m && column(i, &key))
            body_gone.insert(key);
    }
    auto gone_low = [&](size_t i, uint64_t key) {   /* a body's foot needs as few views as the body */
        return low_gone(c, i, body_gone.count(key) ? c->cfg.view_min_through : c->cfg.low_min_through);
    };
    for (size_t i = 0; i < c->over.size(); i++) {
        uint64_t key;
        if ((*keep)[c->over[i]] && column(i, &key) && gone_low(i, key)) {
            low.push_back(i);
            column_top.emplace(key, -INFINITY);
        }
    }
    for (size_t i = 0; i < c->over.size() && !low.empty(); i++) {
        uint64_t key;
        if (!(*keep)[c->over[i]] || c->height[i] > c->cfg.group_max_height_m || !column(i, &key) || gone_low(i, key))
            continue;
        auto it = column_top.find(key);
        if (it != column_top.end()) it->second = std::max(it->second, c->height[i]);
    }
    for (size_t i : low) {
        uint64_t key;
        if (column(i, &key) && column_top[key] < c->height[i]) take(i);
    }
    return carved + by_views;
}

void pb_carve_set_drive(pb_carve_t *c, int drive) { c->drive = (uint8_t)std::min(std::max(drive, 0), 255); }

/* The cells' counts, then the view points' counts (through, seen, hit, since_hit, inside). */
void pb_carve_save(const pb_carve_t *c, std::vector<uint8_t> *out)
{
    const size_t cells = c->counts.size() * sizeof(Count), n = c->through.size();
    out->resize(cells + 5 * n);
    if (cells) std::memcpy(out->data(), c->counts.data(), cells);
    size_t at = cells;
    for (const auto *v : {&c->through, &c->seen, &c->hit, &c->since_hit, &c->inside}) {
        if (n) std::memcpy(out->data() + at, v->data(), n);
        at += n;
    }
}

int pb_carve_load(pb_carve_t *c, const uint8_t *data, size_t len)
{
    const size_t cells = c->counts.size() * sizeof(Count), n = c->through.size();
    if (len != cells + 5 * n) return -1;
    if (cells) std::memcpy(c->counts.data(), data, cells);
    size_t at = cells;
    for (auto *v : {&c->through, &c->seen, &c->hit, &c->since_hit, &c->inside}) {
        if (n) std::memcpy(v->data(), data + at, n);
        at += n;
    }
    return 0;
}
