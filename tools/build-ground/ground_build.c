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

/* The grids are pb_ground_t's: blocks of corners held where a cell has a value, so each
 * step's memory follows the map's points, not its extent; a step works a block at a time
 * with the corners around it it needs from its neighbours (the same model as one grid). */
#define B PB_GROUND_BLOCK

struct gb_accum {
    gb_config_t c;
    pb_ground_t *zmin;  /* the lowest point per cell, NAN: none */
    int failed;         /* out of memory */
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
    gb_accum_t *a = calloc(1, sizeof *a);
    if (!a) return NULL;
    a->c = *c;
    const double cs = c->cell_m;
    const double x0 = floor(lo[0] / cs) * cs, y0 = floor(lo[1] / cs) * cs;
    a->zmin = pb_ground_create(x0, y0, cs, (int)ceil((hi[0] - x0) / cs) + 2, (int)ceil((hi[1] - y0) / cs) + 2);
    if (!a->zmin) { free(a); return NULL; }
    return a;
}

/* 1. lowest point per cell (cells centred on the grid's corners) */
void gb_add(gb_accum_t *a, const float *pts, size_t n, size_t stride)
{
    double x0, y0, cs;
    int nx, ny;
    pb_ground_dims(a->zmin, &x0, &y0, &cs, &nx, &ny);
    for (size_t i = 0; i < n; i++) {
        const float *p = pts + i * stride;
        if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2])) continue;
        int ix = (int)lround((p[0] - x0) / cs), iy = (int)lround((p[1] - y0) / cs);
        if (ix < 0 || iy < 0 || ix >= nx || iy >= ny) continue;    /* outside the bounds given */
        float *b = pb_ground_block_make(a->zmin, ix / B, iy / B);
        if (!b) { a->failed = 1; continue; }
        float *z = &b[(size_t)(iy % B) * B + ix % B];
        if (isnan(*z) || p[2] < *z) *z = p[2];
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

static int floor_div(int v, int d)
{
    return v >= 0 ? v / d : -((-v + d - 1) / d);
}

/* Block (bx, by) of g with h corners all round from the blocks about it: (B + 2h)^2
 * floats, row-major, NAN where nothing is held or outside the grid. */
static void gather(const pb_ground_t *g, int bx, int by, int h, float *out)
{
    const int W = B + 2 * h, x_lo = bx * B - h, y_lo = by * B - h;
    for (size_t k = 0; k < (size_t)W * W; k++) out[k] = NAN;
    for (int qy = floor_div(y_lo, B); qy <= floor_div(y_lo + W - 1, B); qy++)
        for (int qx = floor_div(x_lo, B); qx <= floor_div(x_lo + W - 1, B); qx++) {
            const float *b = pb_ground_block(g, qx, qy);
            if (!b) continue;
            for (int j = 0; j < B; j++) {
                int y = qy * B + j - y_lo;
                if (y < 0 || y >= W) continue;
                for (int i = 0; i < B; i++) {
                    int x = qx * B + i - x_lo;
                    if (x >= 0 && x < W) out[(size_t)y * W + x] = b[(size_t)j * B + i];
                }
            }
        }
}

/* A block's values into out's block (made only when one is known). 0, or -1: out of memory. */
static int put_block(pb_ground_t *out, int bx, int by, const float *v)
{
    size_t k = 0;
    while (k < (size_t)B * B && isnan(v[k])) k++;
    if (k == (size_t)B * B) return 0;
    float *b = pb_ground_block_make(out, bx, by);
    if (!b) return -1;
    memcpy(b, v, (size_t)B * B * sizeof *v);
    return 0;
}

static pb_ground_t *like(const pb_ground_t *g)
{
    double x0, y0, cs;
    int nx, ny;
    pb_ground_dims(g, &x0, &y0, &cs, &nx, &ny);
    return pb_ground_create(x0, y0, cs, nx, ny);
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

pb_ground_t *gb_finish(gb_accum_t *a, size_t *nground)
{
    const gb_config_t c = a->c;
    pb_ground_t *z = a->zmin, *ground = like(z), *med = NULL, *cur = NULL, *next = NULL;
    const int failed = a->failed;
    free(a);
    double x0, y0, cs;
    int nx, ny;
    pb_ground_dims(z, &x0, &y0, &cs, &nx, &ny);
    const int r = (int)ceil(c.window_m / cs), W = B + 2 * r;
    size_t n = pb_ground_blocks(z, NULL), count = 0, nc = 0;
    int *bxy = malloc((5 * n + 1) * 2 * sizeof *bxy);   /* the blocks held; later their neighbours too */
    int64_t *cand = malloc((5 * n + 1) * sizeof *cand);
    float *buf = malloc((size_t)W * W * sizeof *buf), *row = malloc((size_t)W * B * sizeof *row),
          *v = malloc((size_t)B * B * sizeof *v);
    if (failed || !ground || !bxy || !cand || !buf || !row || !v) goto fail;
    pb_ground_blocks(z, bxy);
    /* 2. the lowest point within the window (rows, then columns, over the block and r
     * corners around it), and a cell is ground when its lowest point is near it */
    const double tol = c.step_m + c.grade * c.window_m;
    for (size_t k = 0; k < n; k++) {
        gather(z, bxy[2 * k], bxy[2 * k + 1], r, buf);
        for (int y = 0; y < W; y++)
            for (int x = 0; x < B; x++) {
                float m = INFINITY;
                for (int d = 0; d <= 2 * r; d++) m = fminf(m, buf[(size_t)y * W + x + d]);
                row[(size_t)y * B + x] = m;
            }
        for (int y = 0; y < B; y++)
            for (int x = 0; x < B; x++) {
                float m = INFINITY, zc = buf[(size_t)(y + r) * W + x + r];
                for (int d = 0; d <= 2 * r; d++) m = fminf(m, row[(size_t)(y + d) * B + x]);
                v[(size_t)y * B + x] = (!isnan(zc) && zc - m <= tol) ? zc : NAN;
                count += !isnan(v[(size_t)y * B + x]);
            }
        if (put_block(ground, bxy[2 * k], bxy[2 * k + 1], v)) goto fail;
    }
    pb_ground_destroy(z);
    z = NULL;
    /* 3. 3x3 median over ground cells (a cell keeps its own value if alone) */
    med = like(ground);
    n = pb_ground_blocks(ground, bxy);
    if (!med) goto fail;
    for (size_t k = 0; k < n; k++) {
        gather(ground, bxy[2 * k], bxy[2 * k + 1], 1, buf);
        for (int y = 0; y < B; y++)
            for (int x = 0; x < B; x++) {
                float *o = &v[(size_t)y * B + x];
                *o = buf[(size_t)(y + 1) * (B + 2) + x + 1];
                if (isnan(*o)) continue;
                float w[9];
                int m = 0;
                for (int dy = 0; dy <= 2; dy++)
                    for (int dx = 0; dx <= 2; dx++) {
                        float zz = buf[(size_t)(y + dy) * (B + 2) + x + dx];
                        if (!isnan(zz)) w[m++] = zz;
                    }
                qsort(w, m, sizeof *w, cmp_float);
                *o = m % 2 ? w[m / 2] : 0.5f * (w[m / 2 - 1] + w[m / 2]);
            }
        if (put_block(med, bxy[2 * k], bxy[2 * k + 1], v)) goto fail;
    }
    pb_ground_destroy(ground);
    ground = NULL;
    /* 4. fill holes near ground: each pass, unknown cells (not on the grid's edge) with known
     * 4-neighbours take their mean; a pass reaches one corner into the blocks about */
    cur = med;
    med = NULL;
    const int passes = (int)ceil(c.fill_m / cs);
    double bx0, by0, bcs;
    int nbx, nby;
    pb_ground_dims(cur, &bx0, &by0, &bcs, &nbx, &nby);
    nbx = (nbx + B - 1) / B; nby = (nby + B - 1) / B;
    for (int it = 0; it < passes; it++) {
        n = pb_ground_blocks(cur, NULL);
        int *nb = realloc(bxy, (2 * n + 1) * sizeof *bxy);
        int64_t *nk = realloc(cand, (5 * n + 1) * sizeof *cand);
        if (nb) bxy = nb;
        if (nk) cand = nk;
        if (!nb || !nk || !(next = like(cur))) goto fail;
        pb_ground_blocks(cur, bxy);
        nc = 0;
        for (size_t k = 0; k < n; k++) {
            static const int d[5][2] = { { 0, 0 }, { -1, 0 }, { 1, 0 }, { 0, -1 }, { 0, 1 } };
            for (int q = 0; q < 5; q++) {
                int qx = bxy[2 * k] + d[q][0], qy = bxy[2 * k + 1] + d[q][1];
                if (qx >= 0 && qy >= 0 && qx < nbx && qy < nby) cand[nc++] = (int64_t)qy * nbx + qx;
            }
        }
        qsort(cand, nc, sizeof *cand, cmp_i64);
        for (size_t k = 0; k < nc; k++) {
            if (k && cand[k] == cand[k - 1]) continue;
            const int qx = (int)(cand[k] % nbx), qy = (int)(cand[k] / nbx), Wf = B + 2;
            gather(cur, qx, qy, 1, buf);
            for (int y = 0; y < B; y++)
                for (int x = 0; x < B; x++) {
                    const float *h = &buf[(size_t)(y + 1) * Wf + x + 1];
                    const int gx = qx * B + x, gy = qy * B + y;
                    v[(size_t)y * B + x] = h[0];
                    if (!isnan(h[0]) || gx < 1 || gy < 1 || gx > nx - 2 || gy > ny - 2) continue;
                    const float nbv[4] = { h[-1], h[1], h[-Wf], h[Wf] };
                    double s = 0;
                    int m = 0;
                    for (int q = 0; q < 4; q++) if (!isnan(nbv[q])) { s += nbv[q]; m++; }
                    if (m) v[(size_t)y * B + x] = (float)(s / m);
                }
            if (put_block(next, qx, qy, v)) goto fail;
        }
        pb_ground_destroy(cur);
        cur = next;
        next = NULL;
    }
    free(bxy); free(cand); free(buf); free(row); free(v);
    if (nground) *nground = count;
    return cur;
fail:
    free(bxy); free(cand); free(buf); free(row); free(v);
    pb_ground_destroy(z); pb_ground_destroy(ground); pb_ground_destroy(med); pb_ground_destroy(cur); pb_ground_destroy(next);
    return NULL;
}
