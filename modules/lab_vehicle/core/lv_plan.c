/* Speed planning of one leg of the lab drive (see lv_plan.h). */
#include "lv_plan.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "pb_profile.h"

#define PLAN_DS 0.25        /* m, grid of the speed plan */

int lv_leg_plan(lv_leg_t *leg, const pb_route_t *r, const pb_speed_profile_t *p, double d0, double length,
                pb_err_t *err)
{
    memset(leg, 0, sizeof *leg);
    if (!(length > 0) || !isfinite(length) || length > 1e7)
        return pb_err_set(err, "leg of %g m: expected a positive length", length);
    int N = (int)ceil(length / PLAN_DS) + 1;
    if (N < 3) N = 3;
    double ds = length / (N - 1);       /* the grid ends exactly on the target */
    double *kap = malloc(N * sizeof *kap), *vmax = malloc(N * sizeof *vmax);
    if (!kap || !vmax) { free(kap); free(vmax); return pb_err_set(err, "out of memory"); }
    for (int i = 0; i < N; i++) {
        pb_route_point_t rp;
        pb_route_eval(r, d0 + i * ds, &rp);
        kap[i] = fabs(rp.kappa);
    }
    /* Smoothing moves each speed change up to half a window (0.5 s) in time, i.e. up
     * to cruise * 0.5 m along the road (plus the lag of the smoothed motion): take
     * the sharpest curvature within that reach so the smoothed car keeps lat_accel. */
    int reach = (int)ceil(p->cruise * (LV_BOX_S + 0.25) / ds);
    for (int i = 0; i < N; i++) {
        double k = 0;
        for (int j = i - reach; j <= i + reach; j++) {
            double kj;
            if (j >= 0 && j < N) kj = kap[j];
            else {
                pb_route_point_t rp;
                pb_route_eval(r, d0 + j * ds, &rp);
                kj = fabs(rp.kappa);
            }
            if (kj > k) k = kj;
        }
        /* 0.2 % below the limit: curvature peaks between grid points */
        vmax[i] = k > 1e-9 ? fmin(p->cruise, sqrt(0.998 * p->lat_accel / k)) : p->cruise;
    }
    vmax[0] = vmax[N - 1] = 0;
    for (int i = 1; i < N; i++) vmax[i] = fmin(vmax[i], sqrt(vmax[i - 1] * vmax[i - 1] + 2 * p->accel * ds));
    for (int i = N - 2; i >= 0; i--) vmax[i] = fmin(vmax[i], sqrt(vmax[i + 1] * vmax[i + 1] + 2 * p->decel * ds));

    /* Knots (t, v), v linear in t between them (constant acceleration per grid step).
     * Rest pads of half the smoothed window (2 * (w-1)/2 samples) at both ends keep
     * the smoothed car at rest before t = 0 and after t_end. */
    int w = (int)(LV_BOX_S / LV_PLAN_DT) | 1;
    double pad = (w - 1) * LV_PLAN_DT;
    double *kt = malloc((N + 2) * sizeof *kt), *kv = malloc((N + 2) * sizeof *kv);
    int nk = 0;
    kt[nk] = 0; kv[nk++] = 0;
    double t = pad;
    kt[nk] = t; kv[nk++] = 0;
    for (int i = 1; i < N; i++) {
        double vs = vmax[i - 1] + vmax[i];
        t += 2 * ds / vs;               /* vs > 0: only the ends are at rest */
        kt[nk] = t; kv[nk++] = vmax[i];
    }
    t += pad;
    kt[nk] = t; kv[nk++] = 0;
    int n = (int)ceil(t / LV_PLAN_DT - 1e-9) + 1;
    leg->v = malloc(n * sizeof *leg->v);
    leg->s = malloc(n * sizeof *leg->s);
    pb_profile_sample(kt, kv, nk, LV_PLAN_DT, n, leg->v);
    pb_profile_smooth(leg->v, n, w);
    pb_profile_smooth(leg->v, n, w);
    leg->v[0] = leg->v[n - 1] = 0;      /* rest by construction; drop rounding dust */
    leg->s[0] = 0;
    for (int k = 1; k < n; k++) leg->s[k] = leg->s[k - 1] + 0.5 * (leg->v[k - 1] + leg->v[k]) * LV_PLAN_DT;
    /* The sampled profile covers the leg to O(dt^2); rescale so it ends exactly on it. */
    double scale = length / leg->s[n - 1];
    for (int k = 0; k < n; k++) { leg->v[k] *= scale; leg->s[k] *= scale; }
    leg->s[n - 1] = length;
    leg->d0 = d0;
    leg->length = length;
    leg->dt = LV_PLAN_DT;
    leg->n = n;
    leg->t_end = (n - 1) * LV_PLAN_DT;
    free(kap); free(vmax); free(kt); free(kv);
    return 0;
}

void lv_leg_free(lv_leg_t *leg)
{
    free(leg->v); free(leg->s);
    leg->v = leg->s = NULL;
    leg->n = 0;
}

void lv_leg_eval(const lv_leg_t *leg, double t, double *s, double *v, double *a)
{
    if (t <= 0) { *s = 0; *v = 0; *a = 0; return; }
    if (t >= leg->t_end) { *s = leg->length; *v = 0; *a = 0; return; }
    int k = (int)(t / leg->dt);
    if (k > leg->n - 2) k = leg->n - 2;
    double tau = t - k * leg->dt;
    /* v linear within a step, s its exact integral (s' = v holds exactly). */
    double ak = (leg->v[k + 1] - leg->v[k]) / leg->dt;
    *v = leg->v[k] + ak * tau;
    *s = leg->s[k] + leg->v[k] * tau + 0.5 * ak * tau * tau;
    /* Reported acceleration: nodal central differences, interpolated (continuous). */
    int k0 = k > 0 ? k - 1 : 0, k2 = k + 2 < leg->n ? k + 2 : leg->n - 1;
    double a0 = (leg->v[k + 1] - leg->v[k0]) / ((k + 1 - k0) * leg->dt);
    double a1 = (leg->v[k2] - leg->v[k]) / ((k2 - k) * leg->dt);
    *a = a0 + (a1 - a0) * (tau / leg->dt);
}
