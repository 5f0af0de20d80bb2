/* Unit tests of tools/build-ground's core: the model built in blocks (gb_build, and
 * gb_begin / gb_add / gb_finish in parts) is corner for corner the model of one dense
 * grid over the whole extent, written here the plain way (the window's minimum over the
 * whole square, every cell of the extent), on a map whose features cross the blocks'
 * borders, and holds only the blocks near its points. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ground_build.h"
#include "pb_check.h"

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

/* The model as one dense grid (the reference); *nx x *ny floats, NAN unknown. */
static float *dense_build(const float *pts, size_t n, const gb_config_t *c, double *x0, double *y0, int *nx, int *ny)
{
    double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
    gb_bounds(pts, n, 3, lo, hi);
    const double cs = c->cell_m;
    *x0 = floor(lo[0] / cs) * cs;
    *y0 = floor(lo[1] / cs) * cs;
    const int w = (int)ceil((hi[0] - *x0) / cs) + 2, h = (int)ceil((hi[1] - *y0) / cs) + 2;
    *nx = w; *ny = h;
    const size_t N = (size_t)w * h;
    float *z = malloc(N * sizeof *z), *g = malloc(N * sizeof *g), *t = malloc(N * sizeof *t);
    for (size_t k = 0; k < N; k++) z[k] = INFINITY;
    for (size_t i = 0; i < n; i++) {
        const float *p = pts + 3 * i;
        size_t k = (size_t)lround((p[1] - *y0) / cs) * w + (size_t)lround((p[0] - *x0) / cs);
        if (p[2] < z[k]) z[k] = p[2];
    }
    const int r = (int)ceil(c->window_m / cs);
    const double tol = c->step_m + c->grade * c->window_m;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            float m = INFINITY, zc = z[(size_t)y * w + x];
            for (int yy = y - r; yy <= y + r; yy++)
                for (int xx = x - r; xx <= x + r; xx++)
                    if (xx >= 0 && yy >= 0 && xx < w && yy < h) m = fminf(m, z[(size_t)yy * w + xx]);
            g[(size_t)y * w + x] = isfinite(zc) && zc - m <= tol ? zc : NAN;
        }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            size_t k = (size_t)y * w + x;
            t[k] = g[k];
            if (isnan(g[k])) continue;
            float v[9];
            int m = 0;
            for (int yy = y - 1; yy <= y + 1; yy++)
                for (int xx = x - 1; xx <= x + 1; xx++)
                    if (xx >= 0 && yy >= 0 && xx < w && yy < h && !isnan(g[(size_t)yy * w + xx])) v[m++] = g[(size_t)yy * w + xx];
            qsort(v, m, sizeof *v, cmp_float);
            t[k] = m % 2 ? v[m / 2] : 0.5f * (v[m / 2 - 1] + v[m / 2]);
        }
    for (int it = 0; it < (int)ceil(c->fill_m / cs); it++) {
        memcpy(g, t, N * sizeof *g);
        for (int y = 1; y < h - 1; y++)
            for (int x = 1; x < w - 1; x++) {
                size_t k = (size_t)y * w + x;
                if (!isnan(g[k])) continue;
                const size_t nb[4] = { k - 1, k + 1, k - w, k + w };
                double s = 0;
                int m = 0;
                for (int q = 0; q < 4; q++) if (!isnan(g[nb[q]])) { s += g[nb[q]]; m++; }
                if (m) t[k] = (float)(s / m);
            }
    }
    free(z); free(g);
    return t;
}

static uint32_t rng = 12345;
static float uni(void)     /* [0, 1) */
{
    rng = rng * 1664525u + 1013904223u;
    return (float)(rng >> 8) / 16777216.0f;
}

static void add(float **p, size_t *n, size_t *cap, float x, float y, float z)
{
    if (*n == *cap) { *cap = *cap ? 2 * *cap : 4096; *p = realloc(*p, *cap * 3 * sizeof **p); }
    (*p)[3 * *n] = x; (*p)[3 * *n + 1] = y; (*p)[3 * *n + 2] = z;
    (*n)++;
}

/* A sloped, crowned road with a kerb and a raised sidewalk, a parked car (a roof over
 * a hole in the ground to fill), a wall and two drops, over several 16 m blocks; and a
 * small patch of the same far away, so the extent is mostly unknown. */
static float *make_map(size_t *n)
{
    float *p = NULL;
    size_t cap = 0;
    *n = 0;
    for (int patch = 0; patch < 2; patch++) {
        /* the far patch begins a corner past a block's border (x 304 m, y 250 m): the
         * filling reaches into blocks without points */
        const float ox = patch ? 304.3f : 0.0f, oy = patch ? 256.3f : 0.0f, len = patch ? 12.0f : 70.0f;
        for (int k = 0; k < (int)(len * 40 * 30); k++) {
            float x = ox + len * uni(), y = oy - 6 + 26 * uni(), z = 0.03f * x + 0.01f * (uni() - 0.5f);
            if (y > 12) z += 0.15f + 0.02f * (y - 12);           /* kerb, sidewalk */
            else z += 0.02f * (6 - fabsf(y - 6)) * 0.5f;          /* crown */
            if (x > 29 && x < 34.5f && y > 2 && y < 4 && !patch) z += 1.45f;   /* a car: its roof only */
            if (y > 19.5f) z += 3.0f * (uni() < 0.5f);            /* a wall and its foot */
            if (!patch && x > 48 && y < 10) z -= 0.5f;            /* drops on the blocks' borders (x 48 m, */
            if (!patch && x > 60 && y < 10) z -= 0.5f;            /* y 10 m): the windows reach across */
            add(&p, n, &cap, x, y, z);
        }
    }
    /* points exactly on block borders and corners of the grid */
    for (int k = 0; k < 200; k++) add(&p, n, &cap, 16.0f * (k % 5), -6 + 0.25f * (k / 5), 0.03f * 16.0f * (k % 5));
    return p;
}

int main(void)
{
    size_t n;
    float *pts = make_map(&n);
    gb_config_t c;
    gb_config_default(&c);
    double x0, y0;
    int nx, ny;
    float *ref = dense_build(pts, n, &c, &x0, &y0, &nx, &ny);

    size_t ng = 0;
    pb_ground_t *g = gb_build(pts, n, 3, &c, &ng);
    CHECK(g != NULL);
    if (!g) return pb_check_report("test_ground_build");
    double gx0, gy0, gcs;
    int gnx, gny;
    pb_ground_dims(g, &gx0, &gy0, &gcs, &gnx, &gny);
    CHECK(gx0 == x0 && gy0 == y0 && gcs == c.cell_m && gnx == nx && gny == ny);
    /* corner for corner: the same floats, the same unknowns */
    size_t differ = 0, known = 0, filled = 0;
    for (int y = 0; y < ny; y++)
        for (int x = 0; x < nx; x++) {
            float a = ref[(size_t)y * nx + x], b = (float)pb_ground_get(g, x, y);
            differ += !(isnan(a) ? isnan(b) : a == b);
            known += !isnan(a);
        }
    CHECK(differ == 0);
    /* the map is one that tests the steps: ground, holes filled under the car, a wall refused */
    double z;
    CHECK(known > 20000);
    CHECK(pb_ground_height(g, 31.7, 3.0, &z) == 0 && fabs(z - 0.03 * 31.7) < 0.05);   /* under the car: filled */
    filled = !isnan(pb_ground_get(g, (int)lround((31.7 - x0) / c.cell_m), (int)lround((3.0 - y0) / c.cell_m)));
    CHECK(filled == 1);
    CHECK(ng > 10000 && ng < known);
    /* held: the blocks near the two patches, a small part of the extent's */
    const size_t held = pb_ground_blocks(g, NULL), all = (size_t)((nx + 63) / 64) * ((ny + 63) / 64);
    CHECK(held >= 10 && held * 10 < all);
    printf("test_ground_build: %d x %d corners, %zu known, %zu of %zu blocks held\n", nx, ny, known, held, all);

    /* the same model from the map in parts, in another order */
    double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
    gb_bounds(pts + 3 * (n / 3), n - n / 3, 3, lo, hi);
    gb_bounds(pts, n / 3, 3, lo, hi);
    gb_accum_t *a = gb_begin(lo, hi, &c);
    CHECK(a != NULL);
    gb_add(a, pts + 3 * (n / 3), n - n / 3, 3);
    gb_add(a, pts, n / 3, 3);
    size_t ng2 = 0;
    pb_ground_t *h = gb_finish(a, &ng2);
    differ = 0;
    for (int y = 0; y < ny; y++)
        for (int x = 0; x < nx; x++) {
            double u = pb_ground_get(g, x, y), v = pb_ground_get(h, x, y);
            differ += !(isnan(u) ? isnan(v) : u == v);
        }
    CHECK(h != NULL && differ == 0 && ng2 == ng);
    pb_ground_destroy(h);
    pb_ground_destroy(g);
    free(ref);
    free(pts);
    return pb_check_report("test_ground_build");
}
