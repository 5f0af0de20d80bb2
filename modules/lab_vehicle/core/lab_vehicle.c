/* The lab twin's core: route follower, leg planner and stop / wait state machine. */
#include "lab_vehicle.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lv_plan.h"

#define LV_MIN_LEG_M 0.5        /* a stop closer than this ahead is the one the car rests at */
#define LV_EVENT_RING 64

const char *const lv_state_names[] = { "starting", "driving", "awaiting_proceed", "awaiting_clear", "finished" };
const char *const lv_input_results[] = { "accepted", "other_input", "release", "not_waiting", "early" };

enum { HOLD_NONE, HOLD_OCCUPIED, HOLD_STALE, HOLD_MISSING };

typedef struct {
    char *id;
    int is_object;
    double x, y, vx, vy;
} agent_t;

struct lab_vehicle {
    const pb_route_t *route;
    lv_config_t cfg;
    pb_speed_profile_t prof;
    int *stop_cw;               /* crosswalk index protected by stop line k, -1 if none */
    double *stop_target;        /* base-origin rest arc length at stop k (lap 0, may be < 0) */
    double end_d;               /* unwrapped arc length where the drive ends, or INFINITY */

    int started;
    int64_t t0, now;
    lv_state_t state;
    double d, v, a;             /* unwrapped arc length, speed, acceleration */
    lv_leg_t leg;
    int64_t leg_t0;
    int leg_stop;               /* stop index at the end of the leg; -1 end of drive; -2 start point */
    int at_stop;                /* stop index the car rests at (-2: start point) */
    int64_t arrived_utime;
    int proceed_pending;
    int hold;                   /* HOLD_*: why the car is held after a proceed */
    char hold_agent[64];
    const char *hold_why;       /* how the blocker holds it (a static string) */

    agent_t *agents;
    int nagents;
    int agents_seen;
    int64_t agents_recv;

    lv_event_t ring[LV_EVENT_RING];
    int ev_head, ev_count;
};

void lv_config_default(lv_config_t *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->profile = PB_PROFILE_NORMAL;
    cfg->base_to_front_m = 4.54 - 1.04;
    cfg->stop_gap_m = 0.5;
    cfg->start_s = 0;
    cfg->depart_delay_s = 1.0;
    cfg->laps = 1;
    snprintf(cfg->proceed_input, sizeof cfg->proceed_input, "proceed");
    cfg->crossing_margin_m = 1.0;
    cfg->crossing_horizon_s = 2.0;
    cfg->agents_timeout_s = 1.0;
    cfg->require_agents = 0;
    cfg->ignore_objects = 1;
}

static int out_of(double x, double lo, double hi) { return !(x >= lo && x <= hi); }

lab_vehicle_t *lv_create(const pb_route_t *route, const lv_config_t *cfg, pb_err_t *err)
{
    if (cfg->profile < 0 || cfg->profile >= PB_PROFILE_COUNT) { pb_err_set(err, "speed profile %d unknown", cfg->profile); return NULL; }
    if (out_of(cfg->base_to_front_m, 0.1, 20)) { pb_err_set(err, "base_to_front_m %g outside [0.1, 20]", cfg->base_to_front_m); return NULL; }
    if (out_of(cfg->stop_gap_m, -2, 20)) { pb_err_set(err, "stop_gap_m %g outside [-2, 20]", cfg->stop_gap_m); return NULL; }
    if (!isfinite(cfg->start_s)) { pb_err_set(err, "start_s is not finite"); return NULL; }
    if (out_of(cfg->depart_delay_s, 0, 86400)) { pb_err_set(err, "depart_delay_s %g outside [0, 86400]", cfg->depart_delay_s); return NULL; }
    if (cfg->laps < 0) { pb_err_set(err, "laps %d is negative", cfg->laps); return NULL; }
    if (out_of(cfg->crossing_margin_m, 0, 100)) { pb_err_set(err, "crossing_margin_m %g outside [0, 100]", cfg->crossing_margin_m); return NULL; }
    if (out_of(cfg->crossing_horizon_s, 0, 60)) { pb_err_set(err, "crossing_horizon_s %g outside [0, 60]", cfg->crossing_horizon_s); return NULL; }
    if (out_of(cfg->agents_timeout_s, 0.001, 86400)) { pb_err_set(err, "agents_timeout_s %g outside [0.001, 86400]", cfg->agents_timeout_s); return NULL; }
    if (!cfg->proceed_input[0]) { pb_err_set(err, "proceed_input is empty"); return NULL; }
    const pb_speed_profile_t *p = &route->profiles[cfg->profile];
    if (!(p->cruise > 0 && p->accel > 0 && p->decel > 0 && p->lat_accel > 0)) {
        pb_err_set(err, "speed profile %s: cruise, accel, decel and lat_accel must be > 0", pb_profile_names[cfg->profile]);
        return NULL;
    }
    lab_vehicle_t *lv = calloc(1, sizeof *lv);
    lv->route = route;
    lv->cfg = *cfg;
    lv->prof = *p;
    lv->stop_cw = calloc(route->nstops + 1, sizeof *lv->stop_cw);
    lv->stop_target = calloc(route->nstops + 1, sizeof *lv->stop_target);
    for (int k = 0; k < route->nstops; k++) {
        lv->stop_cw[k] = -1;
        for (int c = 0; c < route->ncw; c++)
            if (strcmp(route->stops[k].crosswalk, route->cw[c].id) == 0) lv->stop_cw[k] = c;
        lv->stop_target[k] = route->stops[k].s - (cfg->base_to_front_m + cfg->stop_gap_m);
    }
    double L = route->length;
    lv->d = fmod(cfg->start_s, L);
    if (lv->d < 0) lv->d += L;
    lv->end_d = cfg->laps > 0 ? lv->d + cfg->laps * L : INFINITY;
    lv->state = LV_STATE_STARTING;
    lv->at_stop = -3;
    return lv;
}

static void free_agents(lab_vehicle_t *lv)
{
    for (int i = 0; i < lv->nagents; i++) free(lv->agents[i].id);
    free(lv->agents);
    lv->agents = NULL;
    lv->nagents = 0;
}

void lv_destroy(lab_vehicle_t *lv)
{
    if (!lv) return;
    lv_leg_free(&lv->leg);
    free_agents(lv);
    free(lv->stop_cw);
    free(lv->stop_target);
    free(lv);
}

lv_state_t lv_state(const lab_vehicle_t *lv) { return lv->state; }

double lv_stop_target(const lab_vehicle_t *lv, int k)
{
    return k >= 0 && k < lv->route->nstops ? lv->stop_target[k] : NAN;
}

static const char *stop_name(const lab_vehicle_t *lv, int k) { return k >= 0 ? lv->route->stops[k].id : ""; }
static const char *cw_name(const lab_vehicle_t *lv, int k)
{
    return k >= 0 && lv->stop_cw[k] >= 0 ? lv->route->cw[lv->stop_cw[k]].id : "";
}

static lv_event_t *push_event(lab_vehicle_t *lv, const char *id, int stop)
{
    if (lv->ev_count == LV_EVENT_RING) {      /* the shell drains every step; keep the newest */
        lv->ev_head = (lv->ev_head + 1) % LV_EVENT_RING;
        lv->ev_count--;
    }
    lv_event_t *ev = &lv->ring[(lv->ev_head + lv->ev_count++) % LV_EVENT_RING];
    memset(ev, 0, sizeof *ev);
    ev->utime = lv->now;
    snprintf(ev->id, sizeof ev->id, "%s", id);
    snprintf(ev->stop_line, sizeof ev->stop_line, "%s", stop_name(lv, stop));
    snprintf(ev->crosswalk, sizeof ev->crosswalk, "%s", cw_name(lv, stop));
    return ev;
}

int lv_next_event(lab_vehicle_t *lv, lv_event_t *ev)
{
    if (!lv->ev_count) return 0;
    *ev = lv->ring[lv->ev_head];
    lv->ev_head = (lv->ev_head + 1) % LV_EVENT_RING;
    lv->ev_count--;
    return 1;
}

/* The next rest point strictly ahead: a stop line, the start point (a route without
 * stop lines), or the end of the drive. */
static double next_target(const lab_vehicle_t *lv, int *stop)
{
    const pb_route_t *r = lv->route;
    double L = r->length, best = INFINITY;
    *stop = -1;
    if (r->nstops > 0) {
        double m0 = floor(lv->d / L) - 1;
        for (int m = 0; m < 4; m++)
            for (int k = 0; k < r->nstops; k++) {
                double T = lv->stop_target[k] + (m0 + m) * L;
                if (T > lv->d + LV_MIN_LEG_M && T < best) { best = T; *stop = k; }
            }
    } else {
        best = (floor(lv->d / L) + 1) * L;
        if (best <= lv->d + LV_MIN_LEG_M) best += L;
        *stop = -2;
    }
    if (lv->end_d <= best + 1e-9) { best = lv->end_d; *stop = -1; }
    return best;
}

static int depart(lab_vehicle_t *lv, int64_t t_dep, pb_err_t *err)
{
    int stop;
    double target = next_target(lv, &stop);
    if (target - lv->d < 1e-6) {        /* already at the end */
        lv->state = LV_STATE_FINISHED;
        push_event(lv, "finished", -1);
        return 0;
    }
    lv_leg_free(&lv->leg);
    if (lv_leg_plan(&lv->leg, lv->route, &lv->prof, lv->d, target - lv->d, err)) return -1;
    lv_event_t *ev = push_event(lv, "departed", lv->at_stop >= 0 ? lv->at_stop : -1);
    snprintf(ev->detail, sizeof ev->detail, "leg of %.2f m to %s, %.1f s", target - lv->d,
             stop >= 0 ? lv->route->stops[stop].id : stop == -2 ? "the start point" : "the end of the drive",
             lv->leg.t_end);
    lv->leg_t0 = t_dep;
    lv->leg_stop = stop;
    lv->state = LV_STATE_DRIVING;
    lv->hold = HOLD_NONE;
    return 0;
}

static void arrive(lab_vehicle_t *lv)
{
    lv->d = lv->leg.d0 + lv->leg.length;    /* exactly the target */
    lv->v = lv->a = 0;
    lv->arrived_utime = lv->now;
    lv->proceed_pending = 0;
    if (lv->leg_stop == -1) {
        lv->state = LV_STATE_FINISHED;
        lv_event_t *ev = push_event(lv, "finished", -1);
        snprintf(ev->detail, sizeof ev->detail, "at rest at the end of the drive (%.2f m driven)", lv->d - fmod(lv->cfg.start_s, lv->route->length));
        return;
    }
    lv->at_stop = lv->leg_stop;
    lv->state = LV_STATE_AWAIT_PROCEED;
    lv_event_t *ev = push_event(lv, "awaiting_proceed", lv->at_stop);
    if (lv->at_stop >= 0)
        snprintf(ev->detail, sizeof ev->detail, "at rest at stop line %s, front bumper %.2f m behind it; waiting for PARTICIPANT_INPUT \"%s\"",
                 lv->route->stops[lv->at_stop].id, lv->cfg.stop_gap_m, lv->cfg.proceed_input);
    else
        snprintf(ev->detail, sizeof ev->detail, "at rest at the start point; waiting for PARTICIPANT_INPUT \"%s\"", lv->cfg.proceed_input);
}

#define LV_STANDING_MPS 0.3      /* slower than this at the kerb: waiting to cross */
#define LV_PATH_STEP_S 0.05

/* Crosswalk coordinates of a map point: along the road and across it (kerb to kerb). */
static void cw_coords(const pb_crosswalk_t *cw, double x, double y, double *along, double *across)
{
    double yaw = cw->yaw_deg * M_PI / 180, dx = x - cw->center[0], dy = y - cw->center[1];
    *along = dx * cos(yaw) + dy * sin(yaw);
    *across = -dx * sin(yaw) + dy * cos(yaw);
}

static int on_crosswalk(const pb_crosswalk_t *cw, double margin, double x, double y)
{
    double along, across;
    cw_coords(cw, x, y, &along, &across);
    return fabs(along) <= cw->width / 2 + margin && fabs(across) <= cw->length / 2;
}

/* Why agent a holds the crossing: NULL if it does not. *in_s: when its path enters. */
static const char *agent_blocks(const pb_crosswalk_t *cw, const lv_config_t *cfg, const agent_t *a, double *in_s)
{
    *in_s = 0;
    if (on_crosswalk(cw, cfg->crossing_margin_m, a->x, a->y)) return "is on";
    double along, across, speed = hypot(a->vx, a->vy);
    cw_coords(cw, a->x, a->y, &along, &across);
    if (speed < LV_STANDING_MPS && fabs(along) <= cw->width / 2 + cfg->crossing_margin_m &&
        fabs(across) <= cw->length / 2 + cfg->crossing_margin_m)
        return "waits at the kerb of";
    for (double t = LV_PATH_STEP_S; t <= cfg->crossing_horizon_s + 1e-9; t += LV_PATH_STEP_S)
        if (on_crosswalk(cw, cfg->crossing_margin_m, a->x + a->vx * t, a->y + a->vy * t)) { *in_s = t; return "is heading onto"; }
    return NULL;
}

/* Why the car may not cross now (HOLD_NONE: clear); *blocker: the agent, *why: how. */
static int crossing_hold(const lab_vehicle_t *lv, const agent_t **blocker, const char **why, double *in_s)
{
    *blocker = NULL;
    *why = "";
    *in_s = 0;
    if (lv->at_stop < 0 || lv->stop_cw[lv->at_stop] < 0) return HOLD_NONE;   /* no crosswalk to check */
    if (!lv->agents_seen) return lv->cfg.require_agents ? HOLD_MISSING : HOLD_NONE;
    if (lv->now - lv->agents_recv > (int64_t)llround(lv->cfg.agents_timeout_s * 1e6)) return HOLD_STALE;
    const pb_crosswalk_t *cw = &lv->route->cw[lv->stop_cw[lv->at_stop]];
    for (int i = 0; i < lv->nagents; i++) {
        const agent_t *a = &lv->agents[i];
        if (a->is_object && lv->cfg.ignore_objects) continue;
        const char *w = agent_blocks(cw, &lv->cfg, a, in_s);
        if (w) { *blocker = a; *why = w; return HOLD_OCCUPIED; }
    }
    return HOLD_NONE;
}

static void check_and_go(lab_vehicle_t *lv, pb_err_t *err, int *rc)
{
    const agent_t *blocker;
    const char *why;
    double in_s;
    int hold = crossing_hold(lv, &blocker, &why, &in_s);
    if (hold == HOLD_NONE) {
        if (lv->hold != HOLD_NONE) push_event(lv, "crossing_clear", lv->at_stop);
        if (depart(lv, lv->now, err)) *rc = -1;
        return;
    }
    const char *bid = blocker ? blocker->id : "";
    if (hold == lv->hold && strcmp(bid, lv->hold_agent) == 0 && why == lv->hold_why) return;  /* already reported */
    lv->hold = hold;
    lv->hold_why = why;
    snprintf(lv->hold_agent, sizeof lv->hold_agent, "%s", bid);
    static const char *const ids[] = { "", "crossing_occupied", "agents_stale", "agents_missing" };
    lv_event_t *ev = push_event(lv, ids[hold], lv->at_stop);
    if (blocker) {
        snprintf(ev->agent_id, sizeof ev->agent_id, "%s", blocker->id);
        ev->agent_xy[0] = blocker->x; ev->agent_xy[1] = blocker->y;
        char when[48] = "";
        if (in_s > 0) snprintf(when, sizeof when, " (in %.2f s)", in_s);
        snprintf(ev->detail, sizeof ev->detail, "agent %s %s crosswalk %s%s; holding",
                 blocker->id, why, ev->crosswalk, when);
    } else if (hold == HOLD_STALE) {
        snprintf(ev->detail, sizeof ev->detail, "last AGENTS %.2f s ago (timeout %.2f s): cannot tell the crossing is clear; holding",
                 (lv->now - lv->agents_recv) * 1e-6, lv->cfg.agents_timeout_s);
    } else {
        snprintf(ev->detail, sizeof ev->detail, "no AGENTS received yet and agents are required; holding");
    }
    lv->state = LV_STATE_AWAIT_CLEAR;
}

int lv_step(lab_vehicle_t *lv, int64_t utime, lv_pose_t *pose, pb_err_t *err)
{
    if (!lv->started) {
        lv->started = 1;
        lv->t0 = lv->now = utime;
    }
    if (utime < lv->now) return pb_err_set(err, "time went back: %lld after %lld", (long long)utime, (long long)lv->now);
    lv->now = utime;
    int rc = 0;
    if (lv->state == LV_STATE_STARTING) {
        int64_t go = lv->t0 + (int64_t)llround(lv->cfg.depart_delay_s * 1e6);
        if (utime >= go && depart(lv, go, err)) rc = -1;
    }
    if (lv->state == LV_STATE_DRIVING) {
        double t = (utime - lv->leg_t0) * 1e-6, s;
        if (t >= lv->leg.t_end) arrive(lv);
        else {
            lv_leg_eval(&lv->leg, t, &s, &lv->v, &lv->a);
            lv->d = lv->leg.d0 + s;
        }
    }
    if (lv->state == LV_STATE_AWAIT_PROCEED && lv->proceed_pending) {
        lv->proceed_pending = 0;
        lv->state = LV_STATE_AWAIT_CLEAR;
        lv->hold = HOLD_NONE;
        lv->hold_agent[0] = 0;
    }
    if (lv->state == LV_STATE_AWAIT_CLEAR) check_and_go(lv, err, &rc);
    if (lv->state != LV_STATE_DRIVING) lv->v = lv->a = 0;

    pb_route_point_t rp;
    pb_route_eval(lv->route, lv->d, &rp);
    pose->utime = utime;
    pose->x = rp.x; pose->y = rp.y; pose->yaw = rp.yaw;
    pose->v = lv->v; pose->a = lv->a;
    pose->omega = rp.kappa * lv->v;
    pose->dist = lv->d;
    double L = lv->route->length;
    pose->route_s = fmod(lv->d, L);
    if (pose->route_s < 0) pose->route_s += L;
    pose->state = lv->state;
    return rc;
}

int lv_on_input(lab_vehicle_t *lv, int64_t utime, const char *input, int32_t value)
{
    if (!input || strcmp(input, lv->cfg.proceed_input) != 0) return LV_INPUT_OTHER;
    if (value == 0) return LV_INPUT_RELEASE;
    if (lv->state != LV_STATE_AWAIT_PROCEED || lv->proceed_pending) return LV_INPUT_NOT_WAITING;
    if (utime < lv->arrived_utime) return LV_INPUT_EARLY;
    lv->proceed_pending = 1;
    int64_t saved = lv->now;
    if (utime > lv->now) lv->now = utime;   /* stamp the event with the press */
    lv_event_t *ev = push_event(lv, "proceed", lv->at_stop);
    snprintf(ev->detail, sizeof ev->detail, "proceed pressed %.2f s after the stop", (utime - lv->arrived_utime) * 1e-6);
    lv->now = saved;
    return LV_INPUT_ACCEPTED;
}

int lv_on_agents(lab_vehicle_t *lv, int64_t recv_utime, const lv_agent_t *agents, int n, pb_err_t *err)
{
    if (n < 0) return pb_err_set(err, "negative agent count %d", n);
    for (int i = 0; i < n; i++)
        if (!isfinite(agents[i].x) || !isfinite(agents[i].y))
            return pb_err_set(err, "agent %d (%s): position is not finite", i, agents[i].id ? agents[i].id : "?");
    free_agents(lv);
    lv->agents = calloc(n + 1, sizeof *lv->agents);
    for (int i = 0; i < n; i++) {
        lv->agents[i].id = strdup(agents[i].id ? agents[i].id : "");
        lv->agents[i].is_object = agents[i].kind && strcmp(agents[i].kind, "object") == 0;
        lv->agents[i].x = agents[i].x;
        lv->agents[i].y = agents[i].y;
        lv->agents[i].vx = isfinite(agents[i].vx) ? agents[i].vx : 0;
        lv->agents[i].vy = isfinite(agents[i].vy) ? agents[i].vy : 0;
    }
    lv->nagents = n;
    lv->agents_seen = 1;
    if (recv_utime > lv->agents_recv) lv->agents_recv = recv_utime;
    return 0;
}
