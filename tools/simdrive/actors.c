/* The drive day's other road users (lead car, crossers) and the car's own body. */
#include "actors.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pb_profile.h"
#include "rng.h"

#define DT 0.002            /* s, the time step of the car-following simulation (= the trajectory's) */
#define GRID_DS 0.25        /* m, grid of the curve speed limits */
#define BOX_S 0.5           /* s, the trajectory's smoothing (as trajectory.c) */
/* Intelligent Driver Model: minimum gap, time headway, acceleration exponent */
#define IDM_S0 2.5
#define IDM_T 1.2
#define IDM_DELTA 4
#define YIELD_STEP_S 0.5
#define YIELD_MAX_S 60.0
#define ON_ROAD_M 3.0       /* a crosser this near the car's lane centreline is on its way */

static const char *const group_names[] = { "lead", "crossing", "pedestrians", "roof" };

static int find_cls(const world_t *w, const char *name, const pb_cfg_node_t *where, uint8_t *out, pb_err_t *err)
{
    for (int i = 0; i < w->nclasses; i++)
        if (!strcmp(w->class_name[i], name)) { *out = (uint8_t)i; return 0; }
    return pb_err_set(err, "%s:%d: unknown class '%s' (not under classes:)", pb_node_file(where), pb_node_line(where), name);
}

static int read_lead(actors_t *A, const world_t *w, const pb_cfg_node_t *node, pb_err_t *err)
{
    struct { char cls[24]; double size[3], z0, ro, gap, cf, spread, dwell[2]; } o =
        { "", { 0, 0, 0 }, 0.2, 1.0, 25.0, 0.85, 0.2, { 3.0, 6.0 } };
#define O(key, type, field, len, req) { key, type, offsetof(typeof(o), field), len, req }
    const pb_cfg_field_t f[] = {
        O("class", PB_CFG_STRING, cls, sizeof o.cls, 1), O("size", PB_CFG_DOUBLES, size, 3, 1),
        O("z0", PB_CFG_DOUBLE, z0, 0, 0), O("rear_overhang", PB_CFG_DOUBLE, ro, 0, 0),
        O("start_gap_m", PB_CFG_DOUBLE, gap, 0, 0), O("cruise_factor", PB_CFG_DOUBLE, cf, 0, 0),
        O("spread", PB_CFG_DOUBLE, spread, 0, 0), O("dwell_s", PB_CFG_DOUBLES, dwell, 2, 0), PB_CFG_END };
#undef O
    if (pb_cfg_read(node, f, &o, err)) return -1;
    if (o.size[0] <= 0 || o.size[1] <= 0 || o.size[2] <= 0 || o.ro < 0 || o.ro >= o.size[0] || o.gap < IDM_S0 ||
        o.cf <= 0.2 || o.cf > 1.5 || o.spread < 0 || o.spread > 0.5 || o.dwell[0] < 0.5 || o.dwell[1] < o.dwell[0])
        return pb_err_set(err, "%s:%d: lead_car: size > 0, 0 <= rear_overhang < length, start_gap_m >= %.1f, "
                          "cruise_factor in 0.2..1.5, spread in 0..0.5 and dwell_s [min, max] >= 0.5 are required",
                          pb_node_file(node), pb_node_line(node), IDM_S0);
    if (find_cls(w, o.cls, node, &A->lead_cls, err)) return -1;
    A->has_lead = 1;
    memcpy(A->lead_size, o.size, sizeof o.size);
    A->lead_z0 = o.z0; A->lead_rear_overhang = o.ro; A->lead_gap_m = o.gap;
    A->lead_cruise_factor = o.cf; A->lead_spread = o.spread;
    memcpy(A->lead_dwell, o.dwell, sizeof o.dwell);
    return 0;
}

static int read_crosser(crosser_t *c, const world_t *w, const pb_cfg_node_t *node, pb_err_t *err)
{
    struct { char kind[16], cls[24]; const pb_cfg_node_t *path; double size[3], z0, speed, period; } o =
        { "", "", NULL, { 0, 0, 0 }, 0, 0, 0 };
#define O(key, type, field, len, req) { key, type, offsetof(typeof(o), field), len, req }
    const pb_cfg_field_t f[] = {
        O("kind", PB_CFG_STRING, kind, sizeof o.kind, 1), O("class", PB_CFG_STRING, cls, sizeof o.cls, 1),
        O("path", PB_CFG_NODE, path, 0, 1), O("size", PB_CFG_DOUBLES, size, 3, 1), O("z0", PB_CFG_DOUBLE, z0, 0, 0),
        O("speed", PB_CFG_DOUBLE, speed, 0, 1), O("period_s", PB_CFG_DOUBLE, period, 0, 1), PB_CFG_END };
#undef O
    if (pb_cfg_read(node, f, &o, err)) return -1;
    const char *file = pb_node_file(node);
    int line = pb_node_line(node);
    memset(c, 0, sizeof *c);
    if (!strcmp(o.kind, "pedestrian")) c->pedestrian = 1;
    else if (strcmp(o.kind, "car")) return pb_err_set(err, "%s:%d: kind: expected car or pedestrian, got '%s'", file, line, o.kind);
    if (find_cls(w, o.cls, node, &c->cls, err)) return -1;
    c->npath = pb_node_count(o.path);
    if (pb_node_kind(o.path) != PB_NODE_LIST || c->npath < 2 || c->npath > ACTORS_MAX_PATH)
        return pb_err_set(err, "%s:%d: path: expected 2 to %d points [x, y]", file, pb_node_line(o.path), ACTORS_MAX_PATH);
    for (int i = 0; i < c->npath; i++) {
        if (pb_node_doubles(pb_node_at(o.path, i), "path point", c->path[i], 2, err)) return -1;
        if (i) c->length += hypot(c->path[i][0] - c->path[i - 1][0], c->path[i][1] - c->path[i - 1][1]);
    }
    if (o.size[0] <= 0 || o.size[1] <= 0 || o.size[2] <= 0 || o.speed <= 0 || c->length < 1.0 ||
        o.period <= c->length / o.speed)
        return pb_err_set(err, "%s:%d: crosser: size > 0, speed > 0, a path of 1 m or more and period_s longer "
                          "than one pass (%.1f s) are required", file, line, o.speed > 0 ? c->length / o.speed : 0.0);
    memcpy(c->size, o.size, sizeof o.size);
    c->z0 = o.z0; c->speed = o.speed; c->period_s = o.period;
    return 0;
}

int actors_load(actors_t *A, const world_t *w, const pb_cfg_node_t *lead, const pb_cfg_node_t *crossers, pb_err_t *err)
{
    memset(A, 0, sizeof *A);
    A->body_cls = w->ground_cls;
    for (int i = 0; i < w->nclasses; i++)
        if (!strcmp(w->class_name[i], "vehicle")) A->body_cls = (uint8_t)i;
    if (lead && read_lead(A, w, lead, err)) return -1;
    if (!crossers) return 0;
    A->ncross = pb_node_count(crossers);
    if (pb_node_kind(crossers) != PB_NODE_LIST || A->ncross > ACTORS_MAX_CROSSERS)
        return pb_err_set(err, "%s:%d: crossers: expected a list of at most %d", pb_node_file(crossers),
                          pb_node_line(crossers), ACTORS_MAX_CROSSERS);
    for (int i = 0; i < A->ncross; i++)
        if (read_crosser(&A->cross[i], w, pb_node_at(crossers, i), err)) return -1;
    return 0;
}

int actors_switch_on(actors_t *A, const char *list, pb_err_t *err)
{
    char buf[256];
    snprintf(buf, sizeof buf, "%s", list);
    for (char *save = NULL, *g = strtok_r(buf, ",", &save); g; g = strtok_r(NULL, ",", &save)) {
        int k = 0;
        while (k < 4 && strcmp(group_names[k], g)) k++;
        if (k == 4) return pb_err_set(err, "--with: no group '%s' (groups: lead, crossing, pedestrians, roof)", g);
        if (k == 0 && !A->has_lead) return pb_err_set(err, "--with lead: the world has no lead_car:");
        A->on |= 1u << k;
    }
    return 0;
}

void actors_free(actors_t *A)
{
    traj_free(&A->lead);
}

/* ---------------------------------------------------------------- car following */

typedef struct {
    double s, v, hold, dwell_left;
    int next;                   /* index of the next stop */
    int leg;                    /* stops passed */
    double fc, fd, fb;          /* this leg's driver factors (trajectory.h) */
} car_t;

typedef struct {
    const pb_speed_profile_t *p;
    double cruise;              /* the car's nominal cruise, m/s */
    double spread;
    uint64_t seed, stream;      /* driver factors and dwells */
    const traj_driver_t *drv;   /* the car's dwells (may be NULL) */
    int nstops;
    double *stop_s;             /* where the base origin rests, unwrapped */
    int *stop_lap, *stop_k;
    const pb_route_t *r;
    const double *dwell_s;      /* rest range at stops, s */
} car_cfg_t;

static void draw_leg(const car_cfg_t *c, car_t *car)
{
    double u[3] = { 0.5, 0.5, 0.5 };
    if (c->spread > 0)
        for (int j = 0; j < 3; j++) u[j] = rng_uniform(c->seed, c->stream, (uint64_t)car->leg, (uint64_t)j);
    car->fc = 1 + c->spread * (2 * u[0] - 1);
    car->fd = 1 + c->spread * (2 * u[1] - 1);
    car->fb = 1 + c->spread * (2 * u[2] - 1);
}

/* The stops of a car whose base origin rests stop_off behind each stop line, beyond s0. */
static void make_stops(car_cfg_t *c, const pb_route_t *r, double s0, double s_max, double stop_off)
{
    int laps = (int)ceil(s_max / r->length) + 1, n = 0;
    c->stop_s = malloc((laps * r->nstops + 1) * sizeof *c->stop_s);
    c->stop_lap = malloc((laps * r->nstops + 1) * sizeof *c->stop_lap);
    c->stop_k = malloc((laps * r->nstops + 1) * sizeof *c->stop_k);
    for (int lap = 0; lap < laps; lap++)
        for (int k = 0; k < r->nstops; k++) {
            double s = lap * r->length + r->stops[k].s - stop_off;
            if (s < s0 + 1.0) continue;
            c->stop_s[n] = s; c->stop_lap[n] = lap; c->stop_k[n++] = k;
        }
    c->nstops = n;
    c->r = r;
}

/* The speed from which the driver's two-phase braking (trajectory.h) stops in x metres. */
static double brake_speed(const car_cfg_t *c, const car_t *car, double x)
{
    const pb_speed_profile_t *p = c->p;
    double vc = c->cruise * car->fc, a1 = p->decel * car->fd;
    double D0 = vc * vc / (2 * p->decel), R = fmax(car->fb * D0 - 0.75 * vc * vc / (2 * a1), 0.15 * D0);
    double a2 = 0.25 * vc * vc / (2 * R);
    return x <= R ? sqrt(2 * a2 * fmax(x, 0)) : sqrt(2 * a2 * R + 2 * a1 * (x - R));
}

/* One step: free road (IDM's acceleration towards cruise, capped by the curve limits
 * and the braking curve to the next stop), plus IDM's interaction with a car ahead
 * (rear bumper at s_rear, speed v_ahead; s_rear = INFINITY: none). */
static void car_step(const car_cfg_t *c, car_t *car, const double *vcurve, int ngrid, double front, double s_rear,
                     double v_ahead, int *stops_made)
{
    const pb_speed_profile_t *p = c->p;
    if (car->hold > 0) { car->hold -= DT; car->v = 0; return; }
    if (car->dwell_left > 0) {
        car->v = 0;
        car->dwell_left -= DT;
        if (car->dwell_left <= 0) { car->next++; car->leg++; draw_leg(c, car); }
        return;
    }
    double vc = c->cruise * car->fc, v = car->v;
    double a = p->accel * (1 - pow(v / vc, IDM_DELTA));
    if (isfinite(s_rear)) {
        double gap = fmax(s_rear - (car->s + front), 0.05);
        double ss = IDM_S0 + v * IDM_T + v * (v - v_ahead) / (2 * sqrt(p->accel * p->decel));
        if (ss > 0) a -= p->accel * (ss / gap) * (ss / gap);
    }
    int gi = (int)(car->s / GRID_DS);
    double venv = vcurve[gi < ngrid ? gi : ngrid - 1];
    double x = car->next < c->nstops ? c->stop_s[car->next] - car->s : INFINITY;
    if (isfinite(x)) venv = fmin(venv, brake_speed(c, car, x));
    double vn = fmin(v + a * DT, venv);
    if (vn < 0) vn = 0;
    double sn = car->s + vn * DT;
    if (isfinite(s_rear) && sn + front > s_rear - 0.5) {    /* never into the car ahead */
        sn = fmax(car->s, s_rear - 0.5 - front);
        vn = (sn - car->s) / DT;
    }
    if (isfinite(x) && sn >= c->stop_s[car->next] - 1e-4) {     /* at the line: rest */
        sn = c->stop_s[car->next];
        vn = 0;
        int lap = c->stop_lap[car->next], k = c->stop_k[car->next];
        /* the car's dwells are the planner's (same draws); the lead car's its own */
        double u = c->stream == RNG_DRIVER ? rng_uniform(c->seed, RNG_DWELL, (uint64_t)lap, (uint64_t)k)
                                           : rng_uniform(c->seed, c->stream, (uint64_t)lap, (uint64_t)k + 1000);
        int met = *stops_made;
        car->dwell_left = c->drv && met < c->drv->ndwells ? c->drv->dwells[met]
                                                           : c->dwell_s[0] + u * (c->dwell_s[1] - c->dwell_s[0]);
        (*stops_made)++;
    }
    car->s = sn;
    car->v = vn;
}

/* v (n samples at DT) smoothed like trajectory.c, then s integrated from s0. */
static void finish(trajectory_t *tr, const pb_route_t *r, double *v, int n, double s0, double t_end, int stops)
{
    int w = (int)(BOX_S / DT) | 1;
    pb_profile_smooth(v, n, w);
    pb_profile_smooth(v, n, w);
    free(tr->v); free(tr->s);
    tr->route = r;
    tr->v = v;
    tr->s = malloc(n * sizeof *tr->s);
    tr->n = n;
    tr->dt = DT;
    tr->s[0] = s0;
    for (int k = 1; k < n; k++) tr->s[k] = tr->s[k - 1] + 0.5 * (v[k - 1] + v[k]) * DT;
    tr->t_end = t_end;
    tr->stops_made = stops;
}

int actors_plan_follow(actors_t *A, trajectory_t *ego, const pb_route_t *r, const pb_speed_profile_t *p,
                       double duration, double front_m, double stop_offset_m, const traj_driver_t *drv,
                       uint64_t seed, pb_err_t *err)
{
    if (duration <= 0) return pb_err_set(err, "--with lead: not on the mapping day");
    int n = (int)((duration + 2 * BOX_S + 1.0) / DT) + 2;
    double lead_front = A->lead_size[0] - A->lead_rear_overhang;
    double lead_s0 = front_m + A->lead_gap_m + A->lead_rear_overhang;
    double s_max = lead_s0 + p->cruise * 1.6 * (duration + 5) + 10;
    int ngrid = (int)(s_max / GRID_DS) + 2;
    /* curve limits (lateral acceleration), braked into at the profile's deceleration */
    double *vcurve = malloc(ngrid * sizeof *vcurve);
    for (int i = 0; i < ngrid; i++) {
        pb_route_point_t rp;
        pb_route_eval(r, i * GRID_DS, &rp);
        vcurve[i] = fabs(rp.kappa) > 1e-9 ? sqrt(p->lat_accel / fabs(rp.kappa)) : 1e3;
    }
    for (int i = ngrid - 2; i >= 0; i--) vcurve[i] = fmin(vcurve[i], sqrt(vcurve[i + 1] * vcurve[i + 1] + 2 * p->decel * GRID_DS));
    car_cfg_t cl = { p, p->cruise * A->lead_cruise_factor, A->lead_spread, seed, RNG_LEAD, NULL, 0, 0, 0, 0, r, A->lead_dwell };
    car_cfg_t ce = { p, p->cruise, drv ? drv->spread : 0, seed, RNG_DRIVER, drv, 0, 0, 0, 0, r, r->dwell_s };
    make_stops(&cl, r, lead_s0, s_max, lead_front + 0.5);
    make_stops(&ce, r, 0, s_max, stop_offset_m);
    car_t L = { .s = lead_s0, .hold = 1.0 }, E = { .s = 0, .hold = 1.0 };
    draw_leg(&cl, &L);
    draw_leg(&ce, &E);
    double *vl = malloc(n * sizeof *vl), *ve = malloc(n * sizeof *ve);
    int lead_stops = 0, ego_stops = 0, ego_stops_in = 0;
    for (int k = 0; k < n; k++) {
        vl[k] = L.v; ve[k] = E.v;
        if (k * DT <= duration) ego_stops_in = ego_stops;
        double rear = L.s - A->lead_rear_overhang;
        car_step(&ce, &E, vcurve, ngrid, front_m, rear, L.v, &ego_stops);
        car_step(&cl, &L, vcurve, ngrid, lead_front, INFINITY, 0, &lead_stops);
    }
    finish(&A->lead, r, vl, n, lead_s0, duration + 2 * BOX_S, lead_stops);
    traj_free(ego);
    finish(ego, r, ve, n, 0, duration + 2 * BOX_S, ego_stops_in);
    free(vcurve);
    free(cl.stop_s); free(cl.stop_lap); free(cl.stop_k);
    free(ce.stop_s); free(ce.stop_lap); free(ce.stop_k);
    return 0;
}

/* ---------------------------------------------------------------- crossers */

/* Position and heading on a crosser's path after d metres (clamped to the path). */
static void path_at(const crosser_t *c, double d, double *x, double *y, double *yaw)
{
    int i = 1;
    for (; i < c->npath; i++) {
        double l = hypot(c->path[i][0] - c->path[i - 1][0], c->path[i][1] - c->path[i - 1][1]);
        if (d <= l || i == c->npath - 1) {
            double u = l > 0 ? fmin(fmax(d / l, 0), 1) : 0;
            *x = c->path[i - 1][0] + u * (c->path[i][0] - c->path[i - 1][0]);
            *y = c->path[i - 1][1] + u * (c->path[i][1] - c->path[i - 1][1]);
            *yaw = atan2(c->path[i][1] - c->path[i - 1][1], c->path[i][0] - c->path[i - 1][0]);
            return;
        }
        d -= l;
    }
}

/* Whether a car of the route (base at route distance s_car, front / rear overhang)
 * would be on the crosser's way at route distance s_c (within margin). */
static int blocks(const pb_route_t *r, double s_car, double front, double rear, double s_c, double margin)
{
    double d = fmod(s_c - s_car, r->length);
    if (d < -r->length / 2) d += r->length;
    if (d >= r->length / 2) d -= r->length;
    return d > -rear - margin && d < front + margin;
}

void actors_schedule(actors_t *A, const pb_route_t *r, const trajectory_t *ego, const pb_vehicle_t *veh,
                     double duration, uint64_t seed)
{
    int lead_on = (A->on & ACT_LEAD) != 0;
    double front = veh->length - veh->rear_overhang;
    for (int i = 0; i < A->ncross; i++) {
        crosser_t *c = &A->cross[i];
        c->npass = 0;
        if (!(A->on & (c->pedestrian ? ACT_PEDESTRIANS : ACT_CROSSING))) continue;
        /* where along its path the crosser is on the car's lane, and the route distance there */
        int ns = (int)(c->length / 0.5) + 1;
        double *on_s = malloc(ns * sizeof *on_s);
        for (int k = 0; k < ns; k++) {
            double x, y, yaw;
            path_at(c, k * 0.5, &x, &y, &yaw);
            double s = pb_route_project(r, x, y);
            pb_route_point_t rp;
            pb_route_eval(r, s, &rp);
            on_s[k] = hypot(x - rp.x, y - rp.y) < ON_ROAD_M + c->size[1] / 2 ? s : NAN;
        }
        double pass = c->length / c->speed, margin = c->size[0] / 2 + 1.5;
        double t = rng_uniform(seed, RNG_ACTORS, (uint64_t)i, 0) * c->period_s, t_free = 0;
        while (t < duration && c->npass < ACTORS_MAX_PASSES) {
            double t0 = fmax(t, t_free);
            for (double delay = 0; delay < YIELD_MAX_S; delay += YIELD_STEP_S) {
                int clash = 0;
                for (double tau = 0; tau <= pass && !clash; tau += 0.1) {
                    int dir = c->npass & 1;
                    double d = dir ? c->length - tau * c->speed : tau * c->speed;
                    int k = (int)lround(d / 0.5);
                    if (k < 0 || k >= ns || isnan(on_s[k])) continue;
                    traj_state_t st;
                    traj_eval(ego, t0 + delay + tau, &st);
                    clash = blocks(r, st.dist, front, veh->rear_overhang, on_s[k], margin);
                    if (!clash && lead_on) {
                        traj_eval(&A->lead, t0 + delay + tau, &st);
                        clash = blocks(r, st.dist, A->lead_size[0] - A->lead_rear_overhang, A->lead_rear_overhang,
                                       on_s[k], margin);
                    }
                }
                if (!clash) { t0 += delay; if (delay > 0) A->yielded++; break; }
            }
            c->pass_t[c->npass++] = t0;
            t_free = t0 + pass + 1.0;
            t += c->period_s;
        }
        free(on_s);
    }
}

int actors_movers(const actors_t *A, const world_t *w, double t, mover_t *out, int max)
{
    int n = 0;
    if ((A->on & ACT_LEAD) && n + 5 <= max) {
        traj_state_t st;
        traj_eval(&A->lead, t, &st);
        double c = cos(st.yaw), s = sin(st.yaw), off = A->lead_size[0] / 2 - A->lead_rear_overhang;
        n += world_vehicle(w, st.x + c * off, st.y + s * off, c, s, A->lead_size, A->lead_z0, A->lead_cls, 0, out + n);
    }
    for (int i = 0; i < A->ncross && n + 5 <= max; i++) {
        const crosser_t *c = &A->cross[i];
        if (!(A->on & (c->pedestrian ? ACT_PEDESTRIANS : ACT_CROSSING))) continue;
        /* the last pass begun; before the first, a pedestrian waits at the start */
        int k = 0;
        while (k < c->npass && c->pass_t[k] <= t) k++;
        double d, x, y, yaw;
        int present = 1;
        if (k == 0) { d = 0; present = c->pedestrian; }
        else {
            double tau = t - c->pass_t[k - 1];
            double along = fmin(tau * c->speed, c->length);
            if (tau * c->speed > c->length && !c->pedestrian) present = 0;     /* a car has driven off */
            d = ((k - 1) & 1) ? c->length - along : along;
        }
        path_at(c, d, &x, &y, &yaw);
        double cy = cos(yaw), sy = sin(yaw);
        if (cy < 0 || (cy == 0 && sy < 0)) { cy = -cy; sy = -sy; }   /* a box is the same turned round */
        /* absent: buried far below the ground at the same place (the slot stays, so a
         * sweep's start and end lists pair up) */
        if (!c->pedestrian) {
            n += world_vehicle(w, x, y, cy, sy, c->size, c->z0, c->cls, !present, out + n);
            continue;
        }
        mover_t *m = &out[n++];
        m->cx = x; m->cy = y; m->c = cy; m->s = sy;
        m->hx = c->size[0] / 2; m->hy = c->size[1] / 2;
        m->gx = m->gy = 0;
        double hg = terrain_height(&w->terrain, x, y);
        m->z0 = hg + c->z0 - (present ? 0 : 1000); m->z1 = m->z0 + c->size[2];
        m->cls = c->cls;
    }
    return n;
}

/* ---------------------------------------------------------------- the car's own body */

static double ray_aabb(const double o[3], const double d[3], const double lo[3], const double hi[3])
{
    double tn = -INFINITY, tf = INFINITY;
    for (int k = 0; k < 3; k++) {
        if (fabs(d[k]) < 1e-12) {
            if (o[k] < lo[k] || o[k] > hi[k]) return INFINITY;
            continue;
        }
        double a = (lo[k] - o[k]) / d[k], b = (hi[k] - o[k]) / d[k];
        if (a > b) { double x = a; a = b; b = x; }
        tn = fmax(tn, a); tf = fmin(tf, b);
    }
    return tn <= tf && tn > 1e-6 ? tn : INFINITY;
}

void actors_body_ranges(const pb_vehicle_t *veh, const float *alt, const float *az, float origin_m, int rows,
                        int cols, double *range)
{
    /* the body as two boxes in base: the lower body bumper to bumper up to 65 % of the
     * height (bonnet, boot), and the cabin over the middle half of the length */
    double L = veh->length, W = veh->width, H = veh->height, ro = veh->rear_overhang;
    const double box[2][6] = { { -ro, -W / 2, 0, L - ro, W / 2, 0.65 * H },
                               { -ro + 0.2 * L, -W / 2 + 0.08, 0, -ro + 0.7 * L, W / 2 - 0.08, H } };
    double Rl[9];
    pb_quat_to_matrix(veh->base_from_lidar.q, Rl);
    const double *t = veh->base_from_lidar.t;
    for (int c = 0; c < cols; c++) {
        double enc = 2 * M_PI * (1.0 - (double)c / cols);
        double ol[3] = { origin_m * cos(enc), origin_m * sin(enc), 0 }, o[3];
        for (int k = 0; k < 3; k++) o[k] = Rl[3 * k] * ol[0] + Rl[3 * k + 1] * ol[1] + Rl[3 * k + 2] * ol[2] + t[k];
        for (int r = 0; r < rows; r++) {
            double th = enc + az[r], ph = alt[r];
            double dl[3] = { cos(th) * cos(ph), sin(th) * cos(ph), sin(ph) }, d[3];
            for (int k = 0; k < 3; k++) d[k] = Rl[3 * k] * dl[0] + Rl[3 * k + 1] * dl[1] + Rl[3 * k + 2] * dl[2];
            double best = INFINITY;
            for (int b = 0; b < 2; b++) best = fmin(best, ray_aabb(o, d, box[b], box[b] + 3));
            range[r * cols + c] = best;
        }
    }
}
