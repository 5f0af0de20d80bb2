/* Ground model from a prior map: lowest points, ground test, median, fill. */
#include "ground_build.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void gb_config_default(gb_config_t *c)
{
    c->cell_m = 0.25;
    c->window_m = 1.0;
    c->step_m = 0.18;
    c->grade = 0.12;
    c->fill_m = 2.5;
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

struct gb_accum {
    gb_config_t c;
    double x0, y0;
    int nx, ny;
    float *zmin;
};

void gb_bounds(const float *pts, size_t n, size_t stride, double lo[2], double hi[2])
{
    for (size_t i = 0; i < n; i++) {
        const float *p = pts + i * stride;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) continue;
        lo[0] = fmin(lo[0], p[0]); lo[1] = fmin(lo[1], p[1]);
        hi[0] = fmax(hi[0], p[0]); hi[1] = fmax(hi[1], p[1]);
    }
}

gb_accum_t *gb_begin(const double lo[2], const double hi[2], const gb_config_t *c)
{
    if (!isfinite(lo[0])) return NULL;
    gb_accum_t *a = malloc(sizeof *a);
    if (!a) return NULL;
    a->c = *c;
    const double cs = c->cell_m;
    a->x0 = floor(lo[0] / cs) * cs;
    a->y0 = floor(lo[1] / cs) * cs;
    a->nx = (int)ceil((hi[0] - a->x0) / cs) + 2;
    a->ny = (int)ceil((hi[1] - a->y0) / cs) + 2;
    size_t N = (size_t)a->nx * a->ny;
    a->zmin = malloc(N * sizeof *a->zmin);
    if (!a->zmin) { free(a); return NULL; }
    for (size_t k = 0; k < N; k++) a->zmin[k] = INFINITY;
    return a;
}

/* 1. lowest point per cell (cells centred on the grid's corners) */
void gb_add(gb_accum_t *a, const float *pts, size_t n, size_t stride)
{
    const double cs = a->c.cell_m;
    for (size_t i = 0; i < n; i++) {
        const float *p = pts + i * stride;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) continue;
        int ix = (int)lround((p[0] - a->x0) / cs), iy = (int)lround((p[1] - a->y0) / cs);
        size_t k = (size_t)iy * a->nx + ix;
        if (p[2] < a->zmin[k]) a->zmin[k] = p[2];
    }
}

pb_ground_t *gb_build(const float *pts, size_t n, size_t stride, const gb_config_t *c, size_t *nground)
{
    if (n == 0) return NULL;
    double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
    gb_bounds(pts, n, stride, lo, hi);
    gb_accum_t *a = gb_begin(lo, hi, c);
    if (!a) return NULL;
    gb_add(a, pts, n, stride);
    return gb_finish(a, nground);
}

pb_ground_t *gb_finish(gb_accum_t *a, size_t *nground)
{
    const gb_config_t cfg = a->c, *c = &cfg;
    const double cs = c->cell_m, x0 = a->x0, y0 = a->y0;
    const int nx = a->nx, ny = a->ny;
    size_t N = (size_t)nx * ny;
    /* two grids in turn (8 bytes a cell: the grid spans the map's extent, it is what the
     * step's memory is) */
    float *g = a->zmin, *tmp = malloc(N * sizeof *tmp);
    free(a);
    /* 2. the lowest point within the window (separable: rows, then columns in place, the
     * rows above kept as they were in a ring of r + 1) */
    int r = (int)ceil(c->window_m / cs);
    float *ring = malloc((size_t)(r + 1) * nx * sizeof *ring);
    for (int y = 0; y < ny; y++)
        for (int x = 0; x < nx; x++) {
            float m = INFINITY;
            for (int d = -r; d <= r; d++) if (x + d >= 0 && x + d < nx) m = fminf(m, g[(size_t)y * nx + x + d]);
            tmp[(size_t)y * nx + x] = m;
        }
    for (int y = 0; y < ny; y++) {
        memcpy(&ring[(size_t)(y % (r + 1)) * nx], &tmp[(size_t)y * nx], (size_t)nx * sizeof *tmp);
        for (int x = 0; x < nx; x++) {
            float m = INFINITY;
            for (int d = -r; d <= r; d++) {
                int yy = y + d;
                if (yy < 0 || yy >= ny) continue;
                m = fminf(m, yy <= y ? ring[(size_t)(yy % (r + 1)) * nx + x] : tmp[(size_t)yy * nx + x]);
            }
            tmp[(size_t)y * nx + x] = m;
        }
    }
    free(ring);
    /* a cell is ground when its lowest point is near the window's (g: the lowest points, then the ground) */
    double tol = c->step_m + c->grade * c->window_m;
    size_t count = 0;
    for (size_t k = 0; k < N; k++) {
        g[k] = (isfinite(g[k]) && g[k] - tmp[k] <= tol) ? g[k] : NAN;
        count += !isnan(g[k]);
    }
    /* 3. 3x3 median over ground cells (a cell keeps its own value if alone) */
    for (int y = 0; y < ny; y++)
        for (int x = 0; x < nx; x++) {
            size_t k = (size_t)y * nx + x;
            tmp[k] = g[k];
            if (isnan(g[k])) continue;
            float v[9];
            int m = 0;
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                    int xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= nx || yy >= ny) continue;
                    float z = g[(size_t)yy * nx + xx];
                    if (!isnan(z)) v[m++] = z;
                }
            qsort(v, m, sizeof *v, cmp_float);
            tmp[k] = m % 2 ? v[m / 2] : 0.5f * (v[m / 2 - 1] + v[m / 2]);
        }
    float *t = g; g = tmp; tmp = t;
    /* 4. fill holes near ground: each pass, unknown cells with known 4-neighbours take their mean */
    int passes = (int)ceil(c->fill_m / cs);
    for (int it = 0; it < passes; it++) {
        memcpy(tmp, g, N * sizeof *g);
        for (int y = 1; y < ny - 1; y++)
            for (int x = 1; x < nx - 1; x++) {
                size_t k = (size_t)y * nx + x;
                if (!isnan(g[k])) continue;
                const size_t nb[4] = { k - 1, k + 1, k - nx, k + nx };
                double s = 0;
                int m = 0;
                for (int q = 0; q < 4; q++) if (!isnan(g[nb[q]])) { s += g[nb[q]]; m++; }
                if (m) tmp[k] = (float)(s / m);
            }
        t = g; g = tmp; tmp = t;
    }
    free(tmp);
    pb_ground_t *out = pb_ground_create(x0, y0, cs, nx, ny);
    for (int y = 0; y < ny; y++)
        for (int x = 0; x < nx; x++) pb_ground_set(out, x, y, g[(size_t)y * nx + x]);
    free(g);
    if (nground) *nground = count;
    return out;
}
