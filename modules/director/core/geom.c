/* geom: support functions for libccd. */
#include "geom.h"

#include <ccd/ccd.h>
#include <math.h>
#include <string.h>

void geom_quat_to_R(const double q[4], double R[9])
{
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    double w = 1, x = 0, y = 0, z = 0;
    if (n > 1e-12 && isfinite(n)) { w = q[0] / n; x = q[1] / n; y = q[2] / n; z = q[3] / n; }
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z);     R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);     R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);     R[7] = 2 * (y * z + w * x);     R[8] = 1 - 2 * (x * x + y * y);
}

void geom_box_yaw(geom_shape_t *g, const double c[3], double yaw, const double size[3])
{
    memset(g, 0, sizeof *g);
    g->kind = GEOM_BOX;
    memcpy(g->c, c, sizeof g->c);
    double cy = cos(yaw), sy = sin(yaw);
    double R[9] = { cy, -sy, 0, sy, cy, 0, 0, 0, 1 };
    memcpy(g->R, R, sizeof R);
    for (int i = 0; i < 3; i++) g->half[i] = size[i] / 2;
}

void geom_cylinder(geom_shape_t *g, double x, double y, double z0, double radius, double height)
{
    memset(g, 0, sizeof *g);
    g->kind = GEOM_CYLINDER;
    g->c[0] = x; g->c[1] = y; g->c[2] = z0 + height / 2;
    g->R[0] = g->R[4] = g->R[8] = 1;
    g->half[0] = radius; g->half[2] = height / 2;
}

void geom_prism(geom_shape_t *g, const double (*pts)[2], int npts, double z0, double z1)
{
    memset(g, 0, sizeof *g);
    g->kind = GEOM_PRISM;
    g->pts = pts;
    g->npts = npts;
    g->z0 = z0; g->z1 = z1;
    for (int i = 0; i < npts; i++) { g->c[0] += pts[i][0] / npts; g->c[1] += pts[i][1] / npts; }
    g->c[2] = (z0 + z1) / 2;
    g->R[0] = g->R[4] = g->R[8] = 1;
}

static void support(const void *obj, const ccd_vec3_t *dir, ccd_vec3_t *out)
{
    const geom_shape_t *g = obj;
    const double *d = dir->v, *R = g->R;
    if (g->kind == GEOM_PRISM) {
        int best = 0;
        double bd = -INFINITY;
        for (int i = 0; i < g->npts; i++) {
            double v = g->pts[i][0] * d[0] + g->pts[i][1] * d[1];
            if (v > bd) { bd = v; best = i; }
        }
        out->v[0] = g->pts[best][0]; out->v[1] = g->pts[best][1];
        out->v[2] = d[2] >= 0 ? g->z1 : g->z0;
        return;
    }
    /* direction in the shape's frame: R^T d */
    double l[3] = { R[0] * d[0] + R[3] * d[1] + R[6] * d[2], R[1] * d[0] + R[4] * d[1] + R[7] * d[2],
                    R[2] * d[0] + R[5] * d[1] + R[8] * d[2] };
    double p[3];
    if (g->kind == GEOM_BOX) {
        for (int i = 0; i < 3; i++) p[i] = l[i] >= 0 ? g->half[i] : -g->half[i];
    } else {
        double h = hypot(l[0], l[1]);
        p[0] = h > 1e-12 ? g->half[0] * l[0] / h : 0;
        p[1] = h > 1e-12 ? g->half[0] * l[1] / h : 0;
        p[2] = l[2] >= 0 ? g->half[2] : -g->half[2];
    }
    for (int i = 0; i < 3; i++) out->v[i] = g->c[i] + R[3 * i] * p[0] + R[3 * i + 1] * p[1] + R[3 * i + 2] * p[2];
}

int geom_intersect(const geom_shape_t *a, const geom_shape_t *b)
{
    ccd_t ccd;
    CCD_INIT(&ccd);
    ccd.support1 = support;
    ccd.support2 = support;
    ccd.max_iterations = 100;
    return ccdGJKIntersect(a, b, &ccd) ? 1 : 0;
}

void geom_volume(geom_shape_t *g, const sc_volume_t *v)
{
    if (v->type == SC_VOL_BOX) {
        double c[3] = { v->center[0], v->center[1], (v->z[0] + v->z[1]) / 2 };
        geom_box_yaw(g, c, v->yaw, v->size);
    } else if (v->type == SC_VOL_CYLINDER) {
        geom_cylinder(g, v->center[0], v->center[1], v->z[0], v->radius, v->z[1] - v->z[0]);
    } else {
        geom_prism(g, (const double(*)[2])v->pts, v->npts, v->z[0], v->z[1]);
    }
}
