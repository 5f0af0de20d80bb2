/* score: see score.h. */
#include "score.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "actors.h"
#include "lidar.h"
#include "pb_math.h"

#define CELL_M 1.0   /* the 2-D grid over the points off the static world */

typedef struct { int64_t key; uint32_t idx; } cell_item_t;

typedef struct {
    size_t n;
    cell_item_t *items;          /* sorted by key */
    const float *xyz;
    float *d_mover, *d_body;     /* per point, the nearest box seen */
    uint8_t *mover_cls;
} cand_t;

static int64_t cell_key(int64_t ix, int64_t iy) { return (ix << 32) ^ (iy & 0xffffffffLL); }

static int cmp_item(const void *a, const void *b)
{
    int64_t x = ((const cell_item_t *)a)->key, y = ((const cell_item_t *)b)->key;
    return (x > y) - (x < y);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static size_t lower_bound(const cell_item_t *a, size_t n, int64_t key)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (a[mid].key < key) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* Distance from p to an axis-aligned box [lo, hi] (0 inside). */
static double aabb_distance(const double p[3], const double lo[3], const double hi[3])
{
    double s = 0;
    for (int k = 0; k < 3; k++) {
        double e = fmax(fmax(lo[k] - p[k], p[k] - hi[k]), 0);
        s += e * e;
    }
    return sqrt(s);
}

/* Calls visit(cand, point index, ctx) for the candidate points within the square of
 * half side r (m) about (x, y). */
static void for_cells(const cand_t *C, double x, double y, double rx, double ry,
                      void (*visit)(const cand_t *, uint32_t, const void *), const void *ctx)
{
    int64_t x0 = pb_floor_i64((x - rx) / CELL_M), x1 = pb_floor_i64((x + rx) / CELL_M);
    int64_t y0 = pb_floor_i64((y - ry) / CELL_M), y1 = pb_floor_i64((y + ry) / CELL_M);
    for (int64_t ix = x0; ix <= x1; ix++)
        for (int64_t iy = y0; iy <= y1; iy++) {
            int64_t key = cell_key(ix, iy);
            for (size_t i = lower_bound(C->items, C->n, key); i < C->n && C->items[i].key == key; i++)
                visit(C, C->items[i].idx, ctx);
        }
}

static void visit_mover(const cand_t *C, uint32_t i, const void *ctx)
{
    const mover_t *m = ctx;
    const float *q = C->xyz + 3 * (size_t)i;
    double dx = q[0] - m->cx, dy = q[1] - m->cy;
    double p[3] = { m->c * dx + m->s * dy, -m->s * dx + m->c * dy, q[2] };
    p[2] -= m->gx * p[0] + m->gy * p[1];   /* its heights follow the road's slope */
    double lo[3] = { -m->hx, -m->hy, m->z0 }, hi[3] = { m->hx, m->hy, m->z1 };
    float d = (float)aabb_distance(p, lo, hi);
    if (d < C->d_mover[i]) { C->d_mover[i] = d; C->mover_cls[i] = m->cls; }
}

typedef struct { const body_state_t *b; const double *lo, *hi; } body_ctx_t;

static void visit_body(const cand_t *C, uint32_t i, const void *ctx)
{
    const body_ctx_t *bc = ctx;
    const float *q = C->xyz + 3 * (size_t)i;
    const double *R = bc->b->R, *t = bc->b->p;
    double v[3] = { q[0] - t[0], q[1] - t[1], q[2] - t[2] }, p[3];
    for (int k = 0; k < 3; k++) p[k] = R[k] * v[0] + R[3 + k] * v[1] + R[6 + k] * v[2];   /* base <- map */
    float d = (float)aabb_distance(p, bc->lo, bc->hi);
    if (d < C->d_body[i]) C->d_body[i] = d;
}

/* The road users through the drive, placed as the LiDAR saw them: at each sweep's start
 * and end (lidar.c interpolates between them over the sweep, heights from its start). */
static void sweep_movers(const score_drive_t *drv, const cand_t *C)
{
    const double period = LIDAR_PERIOD_US * 1e-6;
    for (int64_t k = 0; (double)k * period < drv->duration; k++) {
        double t0 = (double)k * period;
        mover_t a[WORLD_MAX_MOVERS], b[WORLD_MAX_MOVERS];
        int n = world_movers(drv->world, drv->route, t0, drv->seed, a);
        world_movers(drv->world, drv->route, t0 + period, drv->seed, b);
        for (int i = 0; i < n; i++) {
            if (a[i].z1 < -500) continue;   /* absent (actors.c buries it) */
            double move = hypot(b[i].cx - a[i].cx, b[i].cy - a[i].cy) +
                          fmax(a[i].hx, a[i].hy) * hypot(b[i].c - a[i].c, b[i].s - a[i].s);
            int steps = 1 + (int)ceil(move / SCORE_STEP_M);
            for (int j = 0; j <= steps; j++) {
                double f = (double)j / steps;
                mover_t m = a[i];
                m.cx = a[i].cx + (b[i].cx - a[i].cx) * f; m.cy = a[i].cy + (b[i].cy - a[i].cy) * f;
                m.c = a[i].c + (b[i].c - a[i].c) * f; m.s = a[i].s + (b[i].s - a[i].s) * f;
                double nrm = hypot(m.c, m.s);
                m.c /= nrm; m.s /= nrm;
                double rx = fabs(m.c) * m.hx + fabs(m.s) * m.hy + SCORE_MARGIN_M;
                double ry = fabs(m.s) * m.hx + fabs(m.c) * m.hy + SCORE_MARGIN_M;
                for_cells(C, m.cx, m.cy, rx, ry, visit_mover, &m);
            }
        }
    }
}

/* The car's own body (the vehicle file's box about base) at the same steps. */
static void sweep_body(const score_drive_t *drv, const cand_t *C)
{
    const pb_vehicle_t *v = drv->veh;
    const double lo[3] = { -v->rear_overhang, -v->width / 2, 0 }, hi[3] = { v->length - v->rear_overhang, v->width / 2, v->height };
    const double c[3] = { (lo[0] + hi[0]) / 2, 0, (lo[2] + hi[2]) / 2 };
    const double r = 0.5 * sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + v->width * v->width + v->height * v->height) + SCORE_MARGIN_M;
    const double period = LIDAR_PERIOD_US * 1e-6;
    for (int64_t k = 0; (double)k * period < drv->duration; k++) {
        double t0 = (double)k * period;
        body_state_t s0, s1;
        body_pose(drv->body, t0, &s0);
        body_pose(drv->body, t0 + period, &s1);
        int steps = 1 + (int)ceil(hypot(s1.p[0] - s0.p[0], s1.p[1] - s0.p[1]) / SCORE_STEP_M);
        for (int j = 0; j <= steps; j++) {
            body_state_t b;
            body_pose(drv->body, t0 + period * j / steps, &b);
            double x = b.p[0] + b.R[0] * c[0] + b.R[1] * c[1] + b.R[2] * c[2];
            double y = b.p[1] + b.R[3] * c[0] + b.R[4] * c[1] + b.R[5] * c[2];
            body_ctx_t bc = { &b, lo, hi };
            for_cells(C, x, y, r, r, visit_body, &bc);
        }
    }
}

static float *read_points(const char *path, size_t *n, pb_err_t *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) return pb_err_set(err, "%s: %s", path, strerror(errno)), NULL;
    fseek(f, 0, SEEK_END);
    long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    if (bytes <= 0 || bytes % 12) {
        fclose(f);
        return pb_err_set(err, "%s: %ld bytes: not float32 x y z triples", path, bytes), NULL;
    }
    *n = (size_t)bytes / 12;
    float *xyz = malloc((size_t)bytes);
    int ok = xyz && fread(xyz, 12, *n, f) == *n;
    fclose(f);
    if (!ok) {
        free(xyz);
        return pb_err_set(err, "%s: cannot read", path), NULL;
    }
    return xyz;
}

int score_surface_distance(const score_drive_t *drv, const char *path, const char *labels_path, pb_err_t *err)
{
    size_t n;
    float *xyz = read_points(path, &n, err);
    if (!xyz) return -1;
    // 1. each point's distance to the static world
    double *d = malloc(n * sizeof *d), *sorted = malloc(n * sizeof *sorted);
    cand_t C = { 0 };
    C.items = malloc(n * sizeof *C.items);
    if (!d || !sorted || !C.items) {
        free(xyz); free(d); free(sorted); free(C.items);
        return pb_err_set(err, "%s: %zu points: out of memory", path, n);
    }
    size_t w5 = 0, w10 = 0, w15 = 0, far = 0;
    for (size_t i = 0; i < n; i++) {
        double p[3] = { xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2] };
        d[i] = world_distance(drv->world, p, 5.0);
        w5 += d[i] <= 0.05;
        w10 += d[i] <= 0.10;
        w15 += d[i] <= 0.15;
        far += d[i] > 0.5;
        if (d[i] > SCORE_STATIC_M)   /* only these can lie on a mover */
            C.items[C.n++] = (cell_item_t){ cell_key(pb_floor_i64(p[0] / CELL_M), pb_floor_i64(p[1] / CELL_M)), (uint32_t)i };
    }
    // 2. the nearest road user's box and own body box of each point off the static world
    qsort(C.items, C.n, sizeof *C.items, cmp_item);
    C.xyz = xyz;
    C.d_mover = malloc(n * sizeof *C.d_mover);
    C.d_body = malloc(n * sizeof *C.d_body);
    C.mover_cls = calloc(n, 1);
    uint8_t *label = calloc(n, 1);
    if (!C.d_mover || !C.d_body || !C.mover_cls || !label) {
        free(xyz); free(d); free(sorted); free(C.items); free(C.d_mover); free(C.d_body); free(C.mover_cls); free(label);
        return pb_err_set(err, "%s: %zu points: out of memory", path, n);
    }
    for (size_t i = 0; i < n; i++) C.d_mover[i] = C.d_body[i] = INFINITY;
    int roof = drv->world->actors && (drv->world->actors->on & ACT_ROOF);
    if (drv->traffic) sweep_movers(drv, &C);
    if (drv->traffic && roof) sweep_body(drv, &C);
    // 3. the rule of score.h, and the points farther than 0.5 m sorted by it
    size_t moving = 0, body = 0, far_moving = 0, far_body = 0, by_cls[WORLD_MAX_CLASSES] = { 0 };
    for (size_t i = 0; i < n; i++) {
        /* under the ground: what stands on it has nothing there (a wheel's box bottom can lie
         * as near as the road itself to a road point placed low, and win the tie) */
        int off = d[i] > SCORE_STATIC_M && xyz[3 * i + 2] >= world_ground_z(drv->world, xyz[3 * i], xyz[3 * i + 1]);
        int on_mover = off && C.d_mover[i] <= SCORE_MARGIN_M && C.d_mover[i] < d[i];
        int on_body = !on_mover && off && C.d_body[i] <= SCORE_MARGIN_M && C.d_body[i] < d[i];
        moving += on_mover;
        body += on_body;
        far_moving += on_mover && d[i] > 0.5;
        far_body += on_body && d[i] > 0.5;
        if (on_mover && C.mover_cls[i] < WORLD_MAX_CLASSES) by_cls[C.mover_cls[i]]++;
        label[i] = on_mover ? SCORE_LABEL_MOVING : on_body ? SCORE_LABEL_OWN_BODY
                 : d[i] > SCORE_STATIC_M ? SCORE_LABEL_OFF : SCORE_LABEL_STATIC;
    }
    int rc = 0;
    if (labels_path) {
        FILE *f = fopen(labels_path, "wb");
        int ok = f && fwrite(label, 1, n, f) == n;
        if (f && fclose(f)) ok = 0;
        if (!ok) rc = pb_err_set(err, "%s: cannot write the labels: %s", labels_path, strerror(errno));
    }
    memcpy(sorted, d, n * sizeof *d);
    qsort(sorted, n, sizeof *sorted, cmp_double);
    printf("{\"points\": %zu, \"median_m\": %.4f, \"p90_m\": %.4f, \"within_0.05\": %.4f, \"within_0.10\": %.4f, "
           "\"within_0.15\": %.4f, \"beyond_0.5\": %.4f, \"on_moving\": %zu, \"on_moving_share\": %.6f, "
           "\"on_moving_by_class\": {", n, sorted[n / 2], sorted[(size_t)(0.9 * (double)(n - 1))],
           (double)w5 / n, (double)w10 / n, (double)w15 / n, (double)far / n, moving, (double)moving / n);
    const char *sep = "";
    for (int c = 0; c < drv->world->nclasses; c++)
        if (by_cls[c]) {
            printf("%s\"%s\": %zu", sep, drv->world->class_name[c], by_cls[c]);
            sep = ", ";
        }
    printf("}, \"on_own_body\": %zu, \"beyond_0.5_points\": %zu, \"beyond_0.5_on_moving\": %zu, "
           "\"beyond_0.5_on_own_body\": %zu, \"beyond_0.5_other\": %zu}\n",
           body, far, far_moving, far_body, far - far_moving - far_body);
    free(xyz); free(d); free(sorted); free(C.items); free(C.d_mover); free(C.d_body); free(C.mover_cls); free(label);
    return rc;
}
