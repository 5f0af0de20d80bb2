/* Route: reading route.yaml and the arc-length parametrised periodic cubic spline. */
#include "pb_route.h"

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "pb_config.h"

const char *const pb_profile_names[PB_PROFILE_COUNT] = { "cautious", "normal", "aggressive" };

/* 8-point Gauss-Legendre on [0,1]: arc length of a 4 m segment to ~1e-12 m. */
static const double GL_X[8] = { 0.019855071751231856, 0.10166676129318664, 0.2372337950418355, 0.4082826787521751,
                                0.5917173212478249, 0.7627662049581645, 0.8983332387068134, 0.9801449282487681 };
static const double GL_W[8] = { 0.05061426814518813, 0.11119051722668724, 0.15685332293894363, 0.18134189168918100,
                                0.18134189168918100, 0.15685332293894363, 0.11119051722668724, 0.05061426814518813 };

static double speed_at(const pb_route_t *r, int i, double t)
{
    const double *a = r->cx + 4 * i, *b = r->cy + 4 * i;
    double dx = a[1] + t * (2 * a[2] + 3 * t * a[3]);
    double dy = b[1] + t * (2 * b[2] + 3 * t * b[3]);
    return sqrt(dx * dx + dy * dy);
}

static double seg_len(const pb_route_t *r, int i, double t)
{   /* arc length of segment i from 0 to t */
    double L = 0;
    for (int k = 0; k < 8; k++) L += GL_W[k] * speed_at(r, i, t * GL_X[k]);
    return L * t;
}

/* Periodic cubic spline, chord-length parametrised (h[i] = |p[i+1] - p[i]|), so
 * unevenly spaced points do not bend the curve. Second derivatives M solve
 *   h[i-1] M[i-1] + 2 (h[i-1] + h[i]) M[i] + h[i] M[i+1] = 6 (d[i] - d[i-1]),  d[i] = (p[i+1] - p[i]) / h[i],
 * a diagonally dominant cyclic system: Gauss-Seidel converges by at least 2x per sweep.
 * Coefficients are stored for t = tau / h[i] in [0, 1]. */
static void fit_axis(int n, const double *p, const double *h, double *coef)
{
    double *M = calloc(n, sizeof *M), *d = malloc(n * sizeof *d);
    for (int i = 0; i < n; i++) d[i] = (p[(i + 1) % n] - p[i]) / h[i];
    for (int it = 0; it < 100; it++)
        for (int i = 0; i < n; i++) {
            int im = (i + n - 1) % n, ip = (i + 1) % n;
            M[i] = (6 * (d[i] - d[im]) - h[im] * M[im] - h[i] * M[ip]) / (2 * (h[im] + h[i]));
        }
    for (int i = 0; i < n; i++) {
        int ip = (i + 1) % n;
        double *c = coef + 4 * i, hi = h[i];
        c[0] = p[i];
        c[1] = (d[i] - hi * (2 * M[i] + M[ip]) / 6) * hi;
        c[2] = M[i] / 2 * hi * hi;
        c[3] = (M[ip] - M[i]) / 6 * hi * hi;
    }
    free(M);
    free(d);
}

static int cmp_stop(const void *a, const void *b)
{
    double d = ((const pb_stop_line_t *)a)->s - ((const pb_stop_line_t *)b)->s;
    return (d > 0) - (d < 0);
}

void pb_route_free(pb_route_t *r)
{
    free(r->cx); free(r->cy); free(r->seg_s); free(r->stops); free(r->cw);
    memset(r, 0, sizeof *r);
}

static int read_profiles(const pb_cfg_node_t *node, pb_route_t *r, pb_err_t *err)
{
    struct { const pb_cfg_node_t *p[PB_PROFILE_COUNT]; } pn = { { 0 } };
    pb_cfg_field_t f[PB_PROFILE_COUNT + 1];
    for (int i = 0; i < PB_PROFILE_COUNT; i++)
        f[i] = (pb_cfg_field_t){ pb_profile_names[i], PB_CFG_NODE, offsetof(typeof(pn), p) + i * sizeof(void *), 0, 1 };
    f[PB_PROFILE_COUNT] = (pb_cfg_field_t)PB_CFG_END;
    if (pb_cfg_read(node, f, &pn, err)) return -1;
    for (int i = 0; i < PB_PROFILE_COUNT; i++) {
        pb_speed_profile_t *sp = &r->profiles[i];
        const pb_cfg_field_t pf[] = {
            { "cruise", PB_CFG_DOUBLE, offsetof(pb_speed_profile_t, cruise), 0, 1 },
            { "accel", PB_CFG_DOUBLE, offsetof(pb_speed_profile_t, accel), 0, 1 },
            { "decel", PB_CFG_DOUBLE, offsetof(pb_speed_profile_t, decel), 0, 1 },
            { "lat_accel", PB_CFG_DOUBLE, offsetof(pb_speed_profile_t, lat_accel), 0, 1 }, PB_CFG_END };
        if (pb_cfg_read(pn.p[i], pf, sp, err)) return -1;
        if (sp->cruise <= 0.5 || sp->cruise > 40 || sp->accel <= 0.05 || sp->decel <= 0.05 || sp->lat_accel <= 0.05)
            return pb_err_set(err, "%s:%d: %s: cruise in 0.5..40 m/s, accel, decel, lat_accel > 0.05 m/s^2",
                              pb_node_file(pn.p[i]), pb_node_line(pn.p[i]), pb_profile_names[i]);
    }
    return 0;
}

int pb_route_load(const char *path, pb_route_t *r, pb_err_t *err)
{
    memset(r, 0, sizeof *r);
    pb_cfg_t *cfg = pb_cfg_load(path, err);
    if (!cfg) return -1;
    int rc = -1;
    struct {
        int closed; double lane_width, dwell[2];
        const pb_cfg_node_t *points, *crosswalks, *stop_lines, *profiles;
    } top = { 1, 3.5, { 2.0, 3.0 }, 0, 0, 0, 0 };
#define T(key, type, field, len, req) { key, type, offsetof(typeof(top), field), len, req }
    const pb_cfg_field_t top_f[] = {
        T("closed", PB_CFG_BOOL, closed, 0, 1), T("lane_width", PB_CFG_DOUBLE, lane_width, 0, 0),
        T("stop_dwell_s", PB_CFG_DOUBLES, dwell, 2, 0), T("points", PB_CFG_NODE, points, 0, 1),
        T("crosswalks", PB_CFG_NODE, crosswalks, 0, 0), T("stop_lines", PB_CFG_NODE, stop_lines, 0, 0),
        T("speed_profiles", PB_CFG_NODE, profiles, 0, 1), PB_CFG_END };
#undef T
    const pb_cfg_node_t *root = pb_cfg_root(cfg);
    if (pb_cfg_read(root, top_f, &top, err)) goto out;
    if (!top.closed) {
        pb_err_set(err, "%s:%d: closed: only closed loops are supported", path, pb_node_line(root));
        goto out;
    }
    if (top.dwell[0] < 0 || top.dwell[1] < top.dwell[0]) {
        pb_err_set(err, "%s: stop_dwell_s: expected [min, max] with 0 <= min <= max", path);
        goto out;
    }
    r->lane_width = top.lane_width;
    r->dwell_s[0] = top.dwell[0]; r->dwell_s[1] = top.dwell[1];
    if (pb_node_kind(top.points) != PB_NODE_LIST || pb_node_count(top.points) < 4) {
        pb_err_set(err, "%s:%d: points: expected a list of at least 4 [x, y] points", path, pb_node_line(top.points));
        goto out;
    }
    int n = r->n = pb_node_count(top.points);
    double *px = malloc(n * sizeof *px), *py = malloc(n * sizeof *py);
    for (int i = 0; i < n; i++) {
        double xy[2];
        if (pb_node_doubles(pb_node_at(top.points, i), "points", xy, 2, err)) { free(px); free(py); goto out; }
        px[i] = xy[0]; py[i] = xy[1];
    }
    r->cx = malloc(4 * n * sizeof *r->cx); r->cy = malloc(4 * n * sizeof *r->cy);
    double *h = malloc(n * sizeof *h);
    for (int i = 0; i < n; i++) {
        h[i] = hypot(px[(i + 1) % n] - px[i], py[(i + 1) % n] - py[i]);
        if (h[i] < 0.05) {
            pb_err_set(err, "%s:%d: points: point %d repeats point %d (closer than 5 cm); the loop closes by itself",
                       path, pb_node_line(pb_node_at(top.points, (i + 1) % n)), (i + 1) % n, i);
            free(px); free(py); free(h);
            goto out;
        }
    }
    fit_axis(n, px, h, r->cx);
    fit_axis(n, py, h, r->cy);
    free(px); free(py); free(h);
    r->seg_s = malloc((n + 1) * sizeof *r->seg_s);
    r->seg_s[0] = 0;
    for (int i = 0; i < n; i++) r->seg_s[i + 1] = r->seg_s[i] + seg_len(r, i, 1.0);
    r->length = r->seg_s[n];
    if (read_profiles(top.profiles, r, err)) goto out;

    if (top.crosswalks) {
        r->ncw = pb_node_count(top.crosswalks);
        r->cw = calloc(r->ncw ? r->ncw : 1, sizeof *r->cw);
        for (int i = 0; i < r->ncw; i++) {
            const pb_cfg_field_t f[] = {
                { "id", PB_CFG_STRING, offsetof(pb_crosswalk_t, id), sizeof r->cw->id, 1 },
                { "center", PB_CFG_DOUBLES, offsetof(pb_crosswalk_t, center), 2, 1 },
                { "yaw_deg", PB_CFG_DOUBLE, offsetof(pb_crosswalk_t, yaw_deg), 0, 1 },
                { "length", PB_CFG_DOUBLE, offsetof(pb_crosswalk_t, length), 0, 1 },
                { "width", PB_CFG_DOUBLE, offsetof(pb_crosswalk_t, width), 0, 1 }, PB_CFG_END };
            if (pb_cfg_read(pb_node_at(top.crosswalks, i), f, &r->cw[i], err)) goto out;
        }
    }
    if (top.stop_lines) {
        r->nstops = pb_node_count(top.stop_lines);
        r->stops = calloc(r->nstops ? r->nstops : 1, sizeof *r->stops);
        for (int i = 0; i < r->nstops; i++) {
            pb_stop_line_t *sl = &r->stops[i];
            const pb_cfg_node_t *node = pb_node_at(top.stop_lines, i);
            const pb_cfg_field_t f[] = {
                { "id", PB_CFG_STRING, offsetof(pb_stop_line_t, id), sizeof sl->id, 1 },
                { "xy", PB_CFG_DOUBLES, offsetof(pb_stop_line_t, xy), 2, 1 },
                { "yaw_deg", PB_CFG_DOUBLE, offsetof(pb_stop_line_t, yaw_deg), 0, 0 },
                { "crosswalk", PB_CFG_STRING, offsetof(pb_stop_line_t, crosswalk), sizeof sl->crosswalk, 0 },
                PB_CFG_END };
            if (pb_cfg_read(node, f, sl, err)) goto out;
            sl->s = pb_route_project(r, sl->xy[0], sl->xy[1]);
            pb_route_point_t rp;
            pb_route_eval(r, sl->s, &rp);
            if (hypot(rp.x - sl->xy[0], rp.y - sl->xy[1]) > r->lane_width) {
                pb_err_set(err, "%s:%d: stop line %s is %.1f m from the route (more than lane_width)",
                           path, pb_node_line(node), sl->id, hypot(rp.x - sl->xy[0], rp.y - sl->xy[1]));
                goto out;
            }
        }
        qsort(r->stops, r->nstops, sizeof *r->stops, cmp_stop);
    }
    rc = 0;
out:
    if (rc) pb_route_free(r);
    pb_cfg_free(cfg);
    return rc;
}

/* Segment and spline parameter of arc length s: Newton on the quadrature, so the
 * map s -> t is smooth (no table interpolation kinks in speed or yaw rate). */
static void locate(const pb_route_t *r, double s, int *seg, double *tp)
{
    s = fmod(s, r->length);
    if (s < 0) s += r->length;
    int lo = 0, hi = r->n;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (r->seg_s[mid] <= s) lo = mid; else hi = mid;
    }
    double ds = s - r->seg_s[lo], L = r->seg_s[lo + 1] - r->seg_s[lo];
    double t = ds / L;
    for (int it = 0; it < 6; it++) {
        double e = seg_len(r, lo, t) - ds;
        t -= e / speed_at(r, lo, t);
        if (fabs(e) < 1e-12) break;
    }
    *seg = lo;
    *tp = t;
}

void pb_route_eval(const pb_route_t *r, double s, pb_route_point_t *o)
{
    int i;
    double t;
    locate(r, s, &i, &t);
    const double *a = r->cx + 4 * i, *b = r->cy + 4 * i;
    double x = a[0] + t * (a[1] + t * (a[2] + t * a[3])), y = b[0] + t * (b[1] + t * (b[2] + t * b[3]));
    double x1 = a[1] + t * (2 * a[2] + 3 * t * a[3]), y1 = b[1] + t * (2 * b[2] + 3 * t * b[3]);
    double x2 = 2 * a[2] + 6 * t * a[3], y2 = 2 * b[2] + 6 * t * b[3];
    double x3 = 6 * a[3], y3 = 6 * b[3];
    double sp2 = x1 * x1 + y1 * y1, sp = sqrt(sp2);
    double cr = x1 * y2 - y1 * x2;
    o->x = x; o->y = y;
    o->yaw = atan2(y1, x1);
    o->kappa = cr / (sp2 * sp);
    /* d kappa/dt = [(x'y''' - y'x''') |p'|^2 - 3 (x'y'' - y'x'') (p'.p'')] / |p'|^5, then / |p'| for d/ds */
    double dk_dt = ((x1 * y3 - y1 * x3) * sp2 - 3 * cr * (x1 * x2 + y1 * y2)) / (sp2 * sp2 * sp);
    o->dkappa = dk_dt / sp;
}

double pb_route_project(const pb_route_t *r, double x, double y)
{
    double best = 0, bd = INFINITY;
    for (double s = 0; s < r->length; s += 1.0) {       /* coarse scan, then refine */
        pb_route_point_t p;
        pb_route_eval(r, s, &p);
        double d = hypot(p.x - x, p.y - y);
        if (d < bd) { bd = d; best = s; }
    }
    for (int it = 0; it < 20; it++) {   /* Newton on the tangential offset */
        pb_route_point_t p;
        pb_route_eval(r, best, &p);
        double along = (x - p.x) * cos(p.yaw) + (y - p.y) * sin(p.yaw);
        best += along;
        if (fabs(along) < 1e-9) break;
    }
    best = fmod(best, r->length);
    return best < 0 ? best + r->length : best;
}
