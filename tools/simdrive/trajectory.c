/* Speed planning and time parametrisation of the drive. */
#include "trajectory.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "pb_profile.h"
#include "rng.h"

#define PLAN_DS 0.05        /* m, grid of the speed plan: a stop lands on it, so within 2.5 cm of its line */
#define PROFILE_DT 0.002    /* s, grid of the time profile */
#define BOX_S 0.5           /* s, width of each of the two box filters (a 1 s triangle) */

/* One plan over `laps` laps into tr (v, s, n, t_end). */
static void plan_laps(trajectory_t *tr, const pb_route_t *r, const pb_speed_profile_t *p, int laps, int end_at_rest,
                     double stop_offset, const traj_driver_t *driver, uint64_t seed)
{
    static const traj_driver_t planner = { 0 };
    if (!driver) driver = &planner;
    const double spread = driver->spread;
    int met = 0;
    double S = laps * r->length;
    int N = (int)ceil(S / PLAN_DS) + 1;
    double ds = S / (N - 1);
    double *vmax = malloc(N * sizeof *vmax), *dwell = calloc(N, sizeof *dwell);
    /* the driver's factors of the leg each grid point belongs to (the leg ends at the next stop) */
    double *fc = malloc(N * sizeof *fc), *fd = malloc(N * sizeof *fd), *fb = malloc(N * sizeof *fb);
    {
        int nleg = 0;
        for (int i = 0; i < N; i++) {
            double s = i * ds, u[3] = { 0.5, 0.5, 0.5 };
            /* leg index: stops passed so far (over all laps) */
            while (1) {
                int lap = nleg / (r->nstops ? r->nstops : 1), k = r->nstops ? nleg % r->nstops : 0;
                if (!r->nstops || lap >= laps) break;
                if (lap * r->length + r->stops[k].s - stop_offset >= s) break;
                nleg++;
            }
            if (spread > 0)
                for (int j = 0; j < 3; j++) u[j] = rng_uniform(seed, RNG_DRIVER, (uint64_t)nleg, (uint64_t)j);
            fc[i] = 1 + spread * (2 * u[0] - 1);
            fd[i] = 1 + spread * (2 * u[1] - 1);
            fb[i] = 1 + spread * (2 * u[2] - 1);
        }
    }
    for (int i = 0; i < N; i++) {
        pb_route_point_t rp;
        pb_route_eval(r, i * ds, &rp);
        double k = fabs(rp.kappa), cruise = p->cruise * fc[i];
        vmax[i] = k > 1e-9 ? fmin(cruise, sqrt(p->lat_accel / k)) : cruise;
    }
    for (int lap = 0; lap < laps; lap++)
        for (int k = 0; k < r->nstops; k++) {
            double s = lap * r->length + r->stops[k].s - stop_offset;
            if (s < 1.0 || s > S - 1.0) continue;   /* not behind the start, not past the end */
            int i = (int)lround(s / ds);
            double u = rng_uniform(seed, RNG_DWELL, (uint64_t)lap, (uint64_t)k);
            vmax[i] = 0;
            dwell[i] = met < driver->ndwells ? driver->dwells[met] : r->dwell_s[0] + u * (r->dwell_s[1] - r->dwell_s[0]);
            met++;
        }
    vmax[0] = 0;
    if (end_at_rest) vmax[N - 1] = 0;
    /* forward (acceleration) and backward (deceleration) passes */
    for (int i = 1; i < N; i++) vmax[i] = fmin(vmax[i], sqrt(vmax[i - 1] * vmax[i - 1] + 2 * p->accel * ds));
    if (spread <= 0) {
        for (int i = N - 2; i >= 0; i--) vmax[i] = fmin(vmax[i], sqrt(vmax[i + 1] * vmax[i + 1] + 2 * p->decel * ds));
    } else {
        /* Two-phase braking into each stop (traj_driver_t): the main phase at decel * fd
         * ends at half the leg's cruise speed; the final phase spans the rest of the
         * braking distance b * v^2 / (2 decel) (at least 15 % of it) at whatever
         * deceleration stops the car there. Away from stops, the profile's decel. */
        double x_stop = 0;      /* distance to the next point at rest, walking back */
        for (int i = N - 2; i >= 0; i--) {
            x_stop = vmax[i + 1] == 0 && dwell[i + 1] > 0 ? ds : x_stop + ds;
            double vc = p->cruise * fc[i], a1 = p->decel * fd[i];
            double D0 = vc * vc / (2 * p->decel), R = fmax(fb[i] * D0 - 0.75 * vc * vc / (2 * a1), 0.15 * D0);
            double a2 = 0.25 * vc * vc / (2 * R);
            double a = x_stop <= R ? a2 : a1;
            vmax[i] = fmin(vmax[i], sqrt(vmax[i + 1] * vmax[i + 1] + 2 * a * ds));
        }
    }

    /* Knots (t, v): constant acceleration between grid points, so v is linear in t. */
    double *kt = malloc((2 * N + 13) * sizeof *kt), *kv = malloc((2 * N + 13) * sizeof *kv);
    int nk = 0, stops = 0, reversed = driver->reverse_m <= 0;
    double t = 0;
    tr->reverse_t0 = tr->reverse_t1 = 0;
    for (int i = 0; i < N; i++) {
        if (i > 0) {
            double vs = vmax[i - 1] + vmax[i];
            t += vs > 1e-9 ? 2 * ds / vs : 0;
        }
        kt[nk] = t; kv[nk++] = vmax[i];
        if (i > 0 && dwell[i] > 0 && !reversed && t >= driver->reverse_after_s && i * ds >= driver->reverse_m + 5) {
            /* the reversing manoeuvre: rests of 2 s (longer than the smoothing window, so
             * the car is exactly at rest while the gear changes), back reverse_m, forward
             * reverse_m to the stop line again */
            const double vr = TRAJ_REVERSE_MPS, ta = vr / TRAJ_REVERSE_ACCEL;
            const double tc = fmax(driver->reverse_m - vr * ta, 0) / vr;
            reversed = 1;
            for (int dir = -1; dir <= 1; dir += 2) {
                t += 2.0;
                kt[nk] = t; kv[nk++] = 0;
                if (dir < 0) tr->reverse_t0 = t - 1.0;
                else tr->reverse_t1 = t - 1.0;
                t += ta; kt[nk] = t; kv[nk++] = dir * vr;
                t += tc; kt[nk] = t; kv[nk++] = dir * vr;
                t += ta; kt[nk] = t; kv[nk++] = 0;
            }
        }
        if (dwell[i] > 0 || i == 0) {
            double d = i == 0 ? 1.0 : dwell[i];   /* 1 s at rest before moving off */
            if (i) stops++;
            t += d;
            kt[nk] = t; kv[nk++] = 0;
        }
    }
    if (end_at_rest) {      /* rest beyond the smoothing window: the car ends exactly at the start point */
        t += 2 * BOX_S + 0.5;
        kt[nk] = t; kv[nk++] = 0;
    }
    int n = (int)(t / PROFILE_DT) + 1;
    free(tr->v); free(tr->s);
    tr->v = malloc(n * sizeof *tr->v);
    tr->s = malloc(n * sizeof *tr->s);
    tr->n = n;
    tr->dt = PROFILE_DT;
    tr->stops_made = stops;
    pb_profile_sample(kt, kv, nk, PROFILE_DT, n, tr->v);
    /* Two box filters = a triangular window: acceleration becomes continuous and jerk
     * bounded by (accel + decel) / BOX_S. Dwells (>= 2 s) outlast the 1 s window, so
     * the car still comes to rest exactly where planned. */
    int w = (int)(BOX_S / PROFILE_DT) | 1;
    pb_profile_smooth(tr->v, n, w);
    pb_profile_smooth(tr->v, n, w);
    tr->s[0] = 0;
    for (int k = 1; k < n; k++) tr->s[k] = tr->s[k - 1] + 0.5 * (tr->v[k - 1] + tr->v[k]) * PROFILE_DT;
    tr->t_end = (n - 1) * PROFILE_DT;
    free(vmax); free(dwell); free(kt); free(kv); free(fc); free(fd); free(fb);
}

int traj_plan(trajectory_t *tr, const pb_route_t *r, const pb_speed_profile_t *p, double duration,
              double stop_offset_m, const traj_driver_t *driver, uint64_t seed, pb_err_t *err)
{
    memset(tr, 0, sizeof *tr);
    tr->route = r;
    if (duration <= 0) {
        plan_laps(tr, r, p, 1, 1, stop_offset_m, driver, seed);
        return 0;
    }
    /* Enough laps to cover the duration plus the smoothing window at the end. */
    for (int laps = 1; laps < 10000; laps++) {
        plan_laps(tr, r, p, laps, 0, stop_offset_m, driver, seed);
        if (tr->t_end > duration + 2 * BOX_S + 1.0) {
            tr->t_end = duration + 2 * BOX_S;   /* the tail feels the unconstrained end; keep it out */
            return 0;
        }
        if (tr->t_end < 1.0) break;
        laps = (int)fmax(laps, ceil(laps * (duration + 10) / tr->t_end) - 1);
    }
    traj_free(tr);
    return pb_err_set(err, "cannot plan a drive of %.0f s", duration);
}

void traj_free(trajectory_t *tr)
{
    free(tr->v); free(tr->s);
    tr->v = tr->s = NULL;
}

void traj_eval(const trajectory_t *tr, double t, traj_state_t *st)
{
    if (t < 0) t = 0;
    double kf = t / tr->dt;
    int k = (int)kf;
    if (k > tr->n - 2) k = tr->n - 2;
    double tau = t - k * tr->dt;
    /* v linear within a step (a constant), s its exact integral: s' = v holds exactly. */
    double ak = (tr->v[k + 1] - tr->v[k]) / tr->dt;
    double v = tr->v[k] + ak * tau;
    double s = tr->s[k] + tr->v[k] * tau + 0.5 * ak * tau * tau;
    /* Reported acceleration: nodal central differences, interpolated, so it is continuous. */
    int k0 = k > 0 ? k - 1 : 0, k2 = k + 2 < tr->n ? k + 2 : tr->n - 1;
    double a0 = (tr->v[k + 1] - tr->v[k0]) / ((k + 1 - k0) * tr->dt);
    double a1 = (tr->v[k2] - tr->v[k]) / ((k2 - k) * tr->dt);
    double a = a0 + (a1 - a0) * (tau / tr->dt);
    pb_route_point_t rp;
    pb_route_eval(tr->route, s, &rp);
    st->t = t;
    st->dist = s;
    st->v = v;
    st->a = a;
    st->x = rp.x; st->y = rp.y; st->yaw = rp.yaw;
    st->kappa = rp.kappa;
    st->omega = rp.kappa * v;
    st->alpha = rp.dkappa * v * v + rp.kappa * a;
}
