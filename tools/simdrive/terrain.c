/* Terrain: the height-field description, its raster and the ray cast. */
#include "terrain.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define EPS 1e-6
#define COARSE_M 4.0        /* cells of the maxima used to skip empty space */
#define BAND_EXTRA_M 3.0    /* sampled beyond the sidewalk, then the outer height spreads */

/* Knot j of the unwrapped periodic sequence (any integer j). */
static double knot_s(const terrain_t *T, int j, int *idx)
{
    int n = T->nknots, q = (int)floor((double)j / n);
    *idx = j - q * n;
    return T->ks[*idx] + q * T->route->length;
}

/* Periodic Hermite (Catmull-Rom slopes) through the knots: height and bank at s. */
static void profile(const terrain_t *T, double s, double *z, double *bank)
{
    const double L = T->route->length;
    int n = T->nknots;
    if (n == 1) { *z = T->kz[0]; *bank = T->kbank[0]; return; }
    s = fmod(s - T->ks[0], L);
    if (s < 0) s += L;
    s += T->ks[0];
    int i = n - 1;
    for (int k = 1; k < n; k++)
        if (T->ks[k] > s) { i = k - 1; break; }
    int im, i0, i1, i2;
    double sm = knot_s(T, i - 1, &im), s0 = knot_s(T, i, &i0), s1 = knot_s(T, i + 1, &i1), s2 = knot_s(T, i + 2, &i2);
    double h = s1 - s0, u = (s - s0) / h;
    double h00 = 2 * u * u * u - 3 * u * u + 1, h10 = u * u * u - 2 * u * u + u;
    double h01 = -2 * u * u * u + 3 * u * u, h11 = u * u * u - u * u;
    const double *v[2] = { T->kz, T->kbank };
    double out[2];
    for (int j = 0; j < 2; j++) {
        double m0 = (v[j][i1] - v[j][im]) / (s1 - sm), m1 = (v[j][i2] - v[j][i0]) / (s2 - s0);
        out[j] = h00 * v[j][i0] + h10 * h * m0 + h01 * v[j][i1] + h11 * h * m1;
    }
    *z = out[0]; *bank = out[1];
}

/* Height of the cross-section at arc length s, lateral offset d (left of the lane
 * centreline); *band = 1 on the road, kerb or sidewalk. */
static double section(const terrain_t *T, double s, double d, int *band)
{
    double z, bank;
    profile(T, s, &z, &bank);
    double e = d - T->centre_off, a = fabs(e), sg = e < 0 ? -1 : 1;
    if (a <= T->road_half) { *band = 1; return z + bank * e - T->crown * a; }
    double w = a - T->road_half;
    *band = w <= T->sidewalk_w;
    return z + (bank * sg - T->crown) * T->road_half + T->kerb + T->sidewalk_slope * fmin(w, T->sidewalk_w);
}

/* Arc length and lateral offset of (x, y), by Newton steps from s. */
static double project_near(const pb_route_t *r, double x, double y, double s, double *d)
{
    pb_route_point_t rp;
    for (int it = 0; it < 8; it++) {
        pb_route_eval(r, s, &rp);
        double c = cos(rp.yaw), sn = sin(rp.yaw), dx = x - rp.x, dy = y - rp.y;
        double along = dx * c + dy * sn, lat = -dx * sn + dy * c;
        double den = 1 - rp.kappa * lat;
        double step = along / (den > 0.2 ? den : 0.2);
        if (step > 5) step = 5;
        if (step < -5) step = -5;
        s += step;
        *d = lat;
        if (fabs(step) < 1e-12) break;      /* heights feed second differences: converge fully */
    }
    pb_route_eval(r, s, &rp);
    *d = -(x - rp.x) * sin(rp.yaw) + (y - rp.y) * cos(rp.yaw);
    return s;
}

double terrain_height_near(const terrain_t *T, double x, double y, double s_guess)
{
    if (!T->enabled) return 0;
    double d;
    double s = project_near(T->route, x, y, s_guess, &d);
    int band;
    return section(T, s, d, &band);
}

static int read_knots(terrain_t *T, const pb_cfg_node_t *prof, pb_err_t *err)
{
    int n = pb_node_count(prof);
    if (pb_node_kind(prof) != PB_NODE_LIST || n < 1)
        return pb_err_set(err, "%s:%d: terrain: profile: expected a list of [s, z] or [s, z, bank_pct]",
                          pb_node_file(prof), pb_node_line(prof));
    T->nknots = n;
    T->ks = calloc(n, sizeof *T->ks); T->kz = calloc(n, sizeof *T->kz); T->kbank = calloc(n, sizeof *T->kbank);
    for (int i = 0; i < n; i++) {
        const pb_cfg_node_t *k = pb_node_at(prof, i);
        double v[3] = { 0, 0, 0 };
        int m = pb_node_count(k);
        if (pb_node_kind(k) != PB_NODE_LIST || (m != 2 && m != 3))
            return pb_err_set(err, "%s:%d: terrain: profile: each knot is [s, z] or [s, z, bank_pct]",
                              pb_node_file(k), pb_node_line(k));
        if (pb_node_doubles(k, "profile knot", v, m, err)) return -1;
        if (v[0] < 0 || v[0] >= T->route->length || (i > 0 && v[0] <= T->ks[i - 1]))
            return pb_err_set(err, "%s:%d: terrain: profile: knot s must increase within [0, %.1f) (the route's length)",
                              pb_node_file(k), pb_node_line(k), T->route->length);
        T->ks[i] = v[0]; T->kz[i] = v[1]; T->kbank[i] = v[2] / 100;
    }
    return 0;
}

/* Samples the description into the raster: every cell corner within the band takes
 * the section at its own projection; corners beyond take the nearest band corner's
 * height (the ground stays at the sidewalk's outer height). */
static void build_raster(terrain_t *T, double margin)
{
    const pb_route_t *r = T->route;
    double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
    for (double s = 0; s < r->length; s += 1.0) {
        pb_route_point_t rp;
        pb_route_eval(r, s, &rp);
        lo[0] = fmin(lo[0], rp.x); lo[1] = fmin(lo[1], rp.y);
        hi[0] = fmax(hi[0], rp.x); hi[1] = fmax(hi[1], rp.y);
    }
    double c = T->cell;
    T->x0 = floor((lo[0] - margin) / c) * c; T->y0 = floor((lo[1] - margin) / c) * c;
    T->nx = (int)ceil((hi[0] + margin - T->x0) / c) + 1;
    T->ny = (int)ceil((hi[1] + margin - T->y0) / c) + 1;
    size_t N = (size_t)T->nx * T->ny;
    float *best = malloc(N * sizeof *best), *snear = malloc(N * sizeof *snear);
    int32_t *src = malloc(N * sizeof *src);
    T->h = malloc(N * sizeof *T->h);
    T->walk = calloc(N, 1);
    for (size_t i = 0; i < N; i++) best[i] = INFINITY;
    double W = T->road_half + T->sidewalk_w + BAND_EXTRA_M;
    for (double s = 0; s < r->length; s += c / 2) {
        pb_route_point_t rp;
        pb_route_eval(r, s, &rp);
        double nx = -sin(rp.yaw), ny = cos(rp.yaw);
        for (double e = -W; e <= W; e += c / 2) {
            double d = T->centre_off + e;
            int ix = (int)lround((rp.x + nx * d - T->x0) / c), iy = (int)lround((rp.y + ny * d - T->y0) / c);
            if (ix < 0 || iy < 0 || ix >= T->nx || iy >= T->ny) continue;
            size_t k = (size_t)iy * T->nx + ix;
            if (fabs(e) < best[k]) { best[k] = (float)fabs(e); snear[k] = (float)s; }
        }
    }
    for (size_t k = 0; k < N; k++) {
        src[k] = -1;
        if (!isfinite(best[k])) continue;
        double x = T->x0 + (double)(k % T->nx) * c, y = T->y0 + (double)(k / T->nx) * c, d;
        double s = project_near(r, x, y, snear[k], &d);
        int band;
        T->h[k] = (float)section(T, s, d, &band);
        T->walk[k] = (unsigned char)band;
        src[k] = (int32_t)k;
    }
    /* two chamfer passes carry the nearest sampled corner to the rest */
    for (int pass = 0; pass < 2; pass++) {
        int dir = pass ? -1 : 1;
        for (int iy0 = 0; iy0 < T->ny; iy0++) {
            int iy = pass ? T->ny - 1 - iy0 : iy0;
            for (int ix0 = 0; ix0 < T->nx; ix0++) {
                int ix = pass ? T->nx - 1 - ix0 : ix0;
                size_t k = (size_t)iy * T->nx + ix;
                const int nb[4][2] = { { -dir, 0 }, { 0, -dir }, { -dir, -dir }, { dir, -dir } };
                for (int q = 0; q < 4; q++) {
                    int jx = ix + nb[q][0], jy = iy + nb[q][1];
                    if (jx < 0 || jy < 0 || jx >= T->nx || jy >= T->ny) continue;
                    int32_t sj = src[(size_t)jy * T->nx + jx];
                    if (sj < 0) continue;
                    double ax = (double)(sj % T->nx) - ix, ay = (double)(sj / T->nx) - iy;
                    int32_t sk = src[k];
                    double bx = sk < 0 ? 1e9 : (double)(sk % T->nx) - ix, by = sk < 0 ? 0 : (double)(sk / T->nx) - iy;
                    if (ax * ax + ay * ay < bx * bx + by * by) src[k] = sj;
                }
            }
        }
    }
    for (size_t k = 0; k < N; k++)
        if (!isfinite(best[k])) T->h[k] = src[k] >= 0 ? T->h[src[k]] : 0;
    free(best); free(snear); free(src);
    /* maxima over 1, 4 and 16 m cells; a cell holds the corners on its edges too */
    static const int factor[3] = { 5, 20, 80 };
    T->nlevels = 3;
    T->hmax = -INFINITY;
    for (int l = 0; l < T->nlevels; l++) {
        int fct = factor[l];
        T->lv[l].cell = fct * c;
        int nx = T->lv[l].nx = (T->nx - 1) / fct + 1, ny = T->lv[l].ny = (T->ny - 1) / fct + 1;
        float *m = T->lv[l].max = malloc((size_t)nx * ny * sizeof *m);
        for (int cy = 0; cy < ny; cy++)
            for (int cx = 0; cx < nx; cx++) {
                float v = -INFINITY;
                for (int iy = cy * fct; iy <= (cy + 1) * fct && iy < T->ny; iy++)
                    for (int ix = cx * fct; ix <= (cx + 1) * fct && ix < T->nx; ix++)
                        v = fmaxf(v, T->h[(size_t)iy * T->nx + ix]);
                m[cy * nx + cx] = v;
                if (v > T->hmax) T->hmax = v;
            }
    }
}

int terrain_load(terrain_t *T, const pb_cfg_node_t *node, const pb_route_t *route, double margin_m, pb_err_t *err)
{
    memset(T, 0, sizeof *T);
    T->route = route;
    if (!node) return 0;
    struct {
        const pb_cfg_node_t *profile;
        double cell, crown_pct, centre_offset, road_half_width, kerb, sidewalk_width, sidewalk_pct;
    } o = { NULL, 0.2, 2.0, route->lane_width / 2, route->lane_width, 0.15, 3.0, 2.0 };
#define O(key, type, field, req) { key, type, offsetof(typeof(o), field), 0, req }
    const pb_cfg_field_t f[] = {
        O("profile", PB_CFG_NODE, profile, 1), O("cell", PB_CFG_DOUBLE, cell, 0),
        O("crown_pct", PB_CFG_DOUBLE, crown_pct, 0), O("centre_offset", PB_CFG_DOUBLE, centre_offset, 0),
        O("road_half_width", PB_CFG_DOUBLE, road_half_width, 0), O("kerb", PB_CFG_DOUBLE, kerb, 0),
        O("sidewalk_width", PB_CFG_DOUBLE, sidewalk_width, 0), O("sidewalk_pct", PB_CFG_DOUBLE, sidewalk_pct, 0),
        PB_CFG_END };
#undef O
    if (pb_cfg_read(node, f, &o, err)) return -1;
    if (!(o.cell >= 0.05 && o.cell <= 1.0) || o.road_half_width <= 0 || o.sidewalk_width < 0 || o.kerb < 0 || o.kerb > 1)
        return pb_err_set(err, "%s:%d: terrain: cell in [0.05, 1] m, road_half_width > 0, sidewalk_width >= 0, kerb in [0, 1] m",
                          pb_node_file(node), pb_node_line(node));
    if (read_knots(T, o.profile, err)) { terrain_free(T); return -1; }
    T->cell = o.cell;
    T->crown = o.crown_pct / 100;
    T->centre_off = o.centre_offset;
    T->road_half = o.road_half_width;
    T->kerb = o.kerb;
    T->sidewalk_w = o.sidewalk_width;
    T->sidewalk_slope = o.sidewalk_pct / 100;
    T->enabled = 1;
    build_raster(T, margin_m);
    return 0;
}

void terrain_free(terrain_t *T)
{
    free(T->ks); free(T->kz); free(T->kbank); free(T->h); free(T->walk);
    for (int l = 0; l < T->nlevels; l++) free(T->lv[l].max);
    memset(T, 0, sizeof *T);
}

static inline void cell_of(const terrain_t *T, double x, double y, int *ix, int *iy, double *u, double *v)
{
    double fx = (x - T->x0) / T->cell, fy = (y - T->y0) / T->cell;
    int i = (int)floor(fx), j = (int)floor(fy);
    if (i < 0) { i = 0; fx = 0; }
    if (j < 0) { j = 0; fy = 0; }
    if (i > T->nx - 2) { i = T->nx - 2; fx = T->nx - 1; }
    if (j > T->ny - 2) { j = T->ny - 2; fy = T->ny - 1; }
    *ix = i; *iy = j; *u = fx - i; *v = fy - j;
}

double terrain_height(const terrain_t *T, double x, double y)
{
    if (!T->enabled) return 0;
    double fx = (x - T->x0) / T->cell, fy = (y - T->y0) / T->cell;
    if (fx >= 0 && fy >= 0 && fx < T->nx - 1 && fy < T->ny - 1) {     /* the common case, without floor() */
        int i = (int)fx, j = (int)fy;
        double u = fx - i, v = fy - j;
        const float *h = T->h + (size_t)j * T->nx + i;
        return (1 - v) * ((1 - u) * h[0] + u * h[1]) + v * ((1 - u) * h[T->nx] + u * h[T->nx + 1]);
    }
    int i, j;
    double u, v;
    cell_of(T, x, y, &i, &j, &u, &v);
    const float *h = T->h + (size_t)j * T->nx + i;
    return (1 - v) * ((1 - u) * h[0] + u * h[1]) + v * ((1 - u) * h[T->nx] + u * h[T->nx + 1]);
}

int terrain_walkable(const terrain_t *T, double x, double y)
{
    if (!T->enabled) return 1;
    int i, j;
    double u, v;
    cell_of(T, x, y, &i, &j, &u, &v);
    const unsigned char *w = T->walk + (size_t)j * T->nx + i;
    return w[0] && w[1] && w[T->nx] && w[T->nx + 1];
}

static inline double above(const terrain_t *T, const double o[3], const double d[3], double t)
{
    return o[2] + t * d[2] - terrain_height(T, o[0] + t * d[0], o[1] + t * d[1]);
}

/* The first ground hit in [t0, t1], walking the cells of level l and descending
 * into those the ray passes below the maximum of; below level 0, steps of two
 * raster cells with bisection. Returns INFINITY if none. */
static double march(const terrain_t *T, int l, const double o[3], const double d[3], double t0, double t1, double step)
{
    if (l < 0) {
        double t = t0;
        while (t < t1) {
            double tn = t + step < t1 ? t + step : t1;
            if (above(T, o, d, tn) <= 0) {
                double a = t, b = tn;       /* above at a, at or below at b */
                for (int it = 0; it < 11; it++) {
                    double m = 0.5 * (a + b);
                    if (above(T, o, d, m) > 0) a = m; else b = m;
                }
                return b;
            }
            t = tn;
        }
        return INFINITY;
    }
    const double cell = T->lv[l].cell;
    const int nx = T->lv[l].nx, ny = T->lv[l].ny;
    double t = t0;
    while (t < t1) {
        double x = o[0] + t * d[0], y = o[1] + t * d[1];
        int cx = (int)floor((x - T->x0) / cell), cy = (int)floor((y - T->y0) / cell);
        if (cx < 0 || cy < 0 || cx >= nx || cy >= ny) return INFINITY;     /* off the raster */
        double te = t1;
        if (d[0] > 1e-12) { double e = (T->x0 + (cx + 1) * cell - o[0]) / d[0]; if (e < te) te = e; }
        else if (d[0] < -1e-12) { double e = (T->x0 + cx * cell - o[0]) / d[0]; if (e < te) te = e; }
        if (d[1] > 1e-12) { double e = (T->y0 + (cy + 1) * cell - o[1]) / d[1]; if (e < te) te = e; }
        else if (d[1] < -1e-12) { double e = (T->y0 + cy * cell - o[1]) / d[1]; if (e < te) te = e; }
        if (te < t) te = t;
        double za = o[2] + t * d[2], zb = o[2] + te * d[2];
        if ((za < zb ? za : zb) <= T->lv[l].max[cy * nx + cx]) {
            double hit = march(T, l - 1, o, d, t, te, step);
            if (hit < INFINITY) return hit;
        } else if (d[2] >= 0 && za > T->hmax) {
            return INFINITY;                /* above everything from here on */
        }
        t = te + 1e-7;
    }
    return INFINITY;
}

double terrain_raycast(const terrain_t *T, const double o[3], const double d[3], double tmax)
{
    if (!T->enabled) {
        if (d[2] >= -1e-12) return INFINITY;
        double t = -o[2] / d[2];
        return t > EPS && t <= tmax ? t : INFINITY;
    }
    if (above(T, o, d, 0) <= 0) return INFINITY;    /* starts under the ground */
    double dh = hypot(d[0], d[1]);
    /* fine steps of two raster cells: a feature must be narrower than that to be missed */
    double step = dh > 1e-9 ? 2 * T->cell / dh : tmax;
    double t = march(T, T->nlevels - 1, o, d, 0, tmax, step);
    return t > EPS ? t : INFINITY;
}

pb_ground_t *terrain_ground(const terrain_t *T, int walk_only)
{
    if (!T->enabled) return NULL;
    pb_ground_t *g = pb_ground_create(T->x0, T->y0, T->cell, T->nx, T->ny);
    for (int j = 0; j < T->ny; j++)
        for (int i = 0; i < T->nx; i++)
            if (!walk_only || T->walk[(size_t)j * T->nx + i]) pb_ground_set(g, i, j, T->h[(size_t)j * T->nx + i]);
    return g;
}
