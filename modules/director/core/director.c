/* director: the scenario runtime (see director.h). */
#include "director.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geom.h"

#define STANDSTILL_V 0.1        /* m/s: below this the car is at rest */
#define MAX_INPUTS 16
#define DELAY_RING 16
#define WALK_STRIDE_M 1.4       /* one walk-cycle of the animation */

typedef struct {
    int prev;                   /* previous raw value, -1 = unknown (start, after restore) */
    int was;                    /* the condition's value at the previous evaluation */
    int nimp;                   /* pending delayed impulses (edge conditions) */
    int64_t imp[DELAY_RING];
    int ntr;                    /* level transitions for delayed level conditions */
    int64_t tr_t[DELAY_RING];
    int tr_v[DELAY_RING];
} cond_rt_t;

typedef struct {
    int fired;
    int64_t fired_utime;
    cond_rt_t *conds;
} trig_rt_t;

typedef struct {
    double x, y, yaw, vx, vy;
    int beh, wp;
    double wait_left, wait_total;
    int holding, mark_done, colliding;
    double speed;               /* current walking speed (sync) */
    double walked;              /* m, for the walk phase */
    char anim[SC_ID_LEN];
    int anim_override;
    int64_t anim_t0;
} agent_rt_t;

struct director {
    const sc_scenario_t *sc;
    const pb_route_t *route;
    dir_vehicle_t veh;
    dir_event_fn on_event;
    void *user;
    trig_rt_t *trig;
    agent_rt_t *ag;
    int nfired;
    /* the car */
    int have_pose, stale, restored;
    int64_t t0, t_pose, t_agents;
    dir_pose_t pose, prev_pose;
    geom_shape_t foot, prev_foot;
    double car_r;               /* radius of the footprint's bounding circle */
    double speed, accel, s_base;
    double prev_speed, prev_s_base;
    int64_t still_since;        /* -1 when moving */
    double front;               /* rear axle to front bumper */
    /* the ground model (NULL: the plane z = 0) and each volume's ground height */
    const pb_ground_t *ground;
    double *vol_dz;
    /* pending participant inputs */
    int ninputs;
    struct { int64_t utime; char input[32]; } inputs[MAX_INPUTS];
};

/* ---------------------------------------------------------------- helpers */
/* Ground height at (x, y): the ground model's, else 0 (no model, or unknown there). */
static double ground_z(const director_t *d, double x, double y)
{
    double z = 0;
    if (d->ground && pb_ground_height(d->ground, x, y, &z)) z = 0;
    return z;
}

/* An event of the car at pose `at` (NULL: the latest pose); its time is the pose's. */
static void vemit(director_t *d, const dir_pose_t *at, const char *kind, const char *event_id, int agent, const char *fmt,
                  va_list ap)
{
    if (!d->on_event) return;
    dir_event_t ev;
    memset(&ev, 0, sizeof ev);
    ev.utime = at ? at->utime : d->have_pose ? d->pose.utime : d->t_agents;
    ev.kind = kind;
    snprintf(ev.event_id, sizeof ev.event_id, "%s", event_id);
    ev.vehicle = at ? *at : d->pose;
    if (agent >= 0) {
        snprintf(ev.agent_id, sizeof ev.agent_id, "%s", d->sc->agents[agent].id);
        ev.agent_pos[0] = d->ag[agent].x; ev.agent_pos[1] = d->ag[agent].y;
        ev.agent_pos[2] = ground_z(d, d->ag[agent].x, d->ag[agent].y);
    }
    vsnprintf(ev.detail, sizeof ev.detail, fmt, ap);
    d->on_event(&ev, d->user);
}

static void emit(director_t *d, const char *kind, const char *event_id, int agent, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void emit(director_t *d, const char *kind, const char *event_id, int agent, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vemit(d, NULL, kind, event_id, agent, fmt, ap);
    va_end(ap);
}

static void emit_at(director_t *d, const dir_pose_t *at, const char *kind, const char *event_id, int agent, const char *fmt, ...)
    __attribute__((format(printf, 6, 7)));
static void emit_at(director_t *d, const dir_pose_t *at, const char *kind, const char *event_id, int agent, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vemit(d, at, kind, event_id, agent, fmt, ap);
    va_end(ap);
}

/* The car's box at a pose: centre ahead of the rear axle by length/2 - rear_overhang. */
static void footprint(const director_t *d, const double pos[3], const double q[4], geom_shape_t *g)
{
    memset(g, 0, sizeof *g);
    g->kind = GEOM_BOX;
    geom_quat_to_R(q, g->R);
    double off[3] = { d->veh.length / 2 - d->veh.rear_overhang, 0, d->veh.height / 2 };
    for (int i = 0; i < 3; i++) g->c[i] = pos[i] + g->R[3 * i] * off[0] + g->R[3 * i + 1] * off[1] + g->R[3 * i + 2] * off[2];
    g->half[0] = d->veh.length / 2; g->half[1] = d->veh.width / 2; g->half[2] = d->veh.height / 2;
}

static int foot_touches_volume(const director_t *d, const geom_shape_t *foot, const sc_volume_t *v)
{
    double dx = foot->c[0] - v->bound_c[0], dy = foot->c[1] - v->bound_c[1];
    double r = d->car_r + v->bound_r;
    if (dx * dx + dy * dy > r * r) return 0;
    geom_shape_t g;
    geom_volume(&g, v);
    /* a volume's heights count from the ground at its centre */
    double dz = d->vol_dz ? d->vol_dz[v - d->sc->volumes] : 0;
    g.c[2] += dz; g.z0 += dz; g.z1 += dz;
    return geom_intersect(foot, &g);
}

static void agent_shape(const director_t *d, int i, geom_shape_t *g)
{
    const sc_agent_t *a = &d->sc->agents[i];
    if (a->shape == SC_SHAPE_CYLINDER) {
        geom_cylinder(g, d->ag[i].x, d->ag[i].y, ground_z(d, d->ag[i].x, d->ag[i].y), a->radius, a->height);
    } else {
        double c[3] = { d->ag[i].x, d->ag[i].y, ground_z(d, d->ag[i].x, d->ag[i].y) + a->size[2] / 2 };
        geom_box_yaw(g, c, d->ag[i].yaw, a->size);
    }
}

static double agent_radius(const sc_agent_t *a)
{
    return a->shape == SC_SHAPE_CYLINDER ? a->radius : 0.5 * hypot(a->size[0], a->size[1]);
}

/* Distance in the ground plane from the footprint to a point (0 inside). */
static double foot_distance(const geom_shape_t *f, const double p[2])
{
    double dx = p[0] - f->c[0], dy = p[1] - f->c[1];
    double lx = f->R[0] * dx + f->R[3] * dy, ly = f->R[1] * dx + f->R[4] * dy;
    double ex = fmax(fabs(lx) - f->half[0], 0), ey = fmax(fabs(ly) - f->half[1], 0);
    return hypot(ex, ey);
}

/* Arc length of the route nearest (x, y), searched near hint: Newton on the
 * tangential offset. Falls back to the global search when it does not settle. */
static double project_near(const pb_route_t *r, double x, double y, double hint)
{
    double s = hint;
    for (int it = 0; it < 8; it++) {
        pb_route_point_t p;
        pb_route_eval(r, s, &p);
        double along = (x - p.x) * cos(p.yaw) + (y - p.y) * sin(p.yaw);
        if (fabs(along) > 20) along = along > 0 ? 20 : -20;
        s += along;
        if (fabs(along) < 1e-4) {
            pb_route_eval(r, s, &p);
            if (hypot(p.x - x, p.y - y) > 2 * r->lane_width) return pb_route_project(r, x, y);
            s = fmod(s, r->length);
            return s < 0 ? s + r->length : s;
        }
    }
    return pb_route_project(r, x, y);
}

/* Route distance from a to b wrapped into [-L/2, L/2). */
static double route_delta(const pb_route_t *r, double a, double b)
{
    double d = fmod(b - a, r->length);
    if (d >= r->length / 2) d -= r->length;
    if (d < -r->length / 2) d += r->length;
    return d;
}

double dir_predict_arrival(double d, double v, double a, double decel, double ease)
{
    if (d <= 0.3 && v < STANDSTILL_V) return 0;
    if (d <= 0) return 0;
    if (v < 0.3) return INFINITY;           /* standing short of the line: it has not set off yet */
    /* Braking at a, the car stops within v^2 / |a| (twice the constant-deceleration
     * distance: the jerk-limited ending's bound). Well short of the line it is stopping
     * behind something (a queue, a car ahead): when it will arrive is unknown. */
    if (a < -0.2 && v * v / -a < d - 1.0) return INFINITY;
    /* Drivers (and simdrive's smoothed speed profile) ease off the brake before the
     * car comes to rest; constant deceleration misses that by `ease` seconds. In the
     * last metres the ending itself is modelled: v falling like tau^2 (jerk-limited)
     * reaches zero after 2 v / |a|, independent of where exactly the car stops. */
    if (a < -0.5 && v < 1.5) return 2 * v / -a;
    if (a < -0.2 || v * v / (2 * d) >= decel) return 2 * d / v + ease;    /* braking to the line */
    return d / v + v / (2 * decel) + ease;  /* cruise, then brake at decel */
}

/* ---------------------------------------------------------------- create */
director_t *dir_create(const sc_scenario_t *sc, const pb_route_t *route, const dir_vehicle_t *veh,
                       dir_event_fn on_event, void *user, pb_err_t *err)
{
    if (!(veh->length > 0 && veh->width > 0 && veh->height > 0 && veh->rear_overhang >= 0 && veh->rear_overhang < veh->length)) {
        pb_err_set(err, "director: vehicle dimensions are not valid");
        return NULL;
    }
    for (int i = 0; i < sc->nbehaviours; i++)
        if (sc->behaviours[i].sync && !route) {
            pb_err_set(err, "%s:%d: behaviour '%s' is synchronised to a stop line but no route was loaded", sc->path,
                       sc->behaviours[i].line, sc->behaviours[i].id);
            return NULL;
        }
    director_t *d = calloc(1, sizeof *d);
    d->sc = sc;
    d->route = route;
    d->veh = *veh;
    d->on_event = on_event;
    d->user = user;
    d->front = veh->length - veh->rear_overhang;
    d->car_r = 0.5 * hypot(veh->length, veh->width) + 0.01;
    d->trig = calloc(sc->ntriggers ? sc->ntriggers : 1, sizeof *d->trig);
    for (int i = 0; i < sc->ntriggers; i++) {
        d->trig[i].conds = calloc(sc->triggers[i].nconds, sizeof *d->trig[i].conds);
        for (int k = 0; k < sc->triggers[i].nconds; k++) d->trig[i].conds[k].prev = -1;
    }
    d->ag = calloc(sc->nagents ? sc->nagents : 1, sizeof *d->ag);
    for (int i = 0; i < sc->nagents; i++) {
        agent_rt_t *a = &d->ag[i];
        a->x = sc->agents[i].xy[0]; a->y = sc->agents[i].xy[1]; a->yaw = sc->agents[i].yaw;
        a->beh = -1;
        strcpy(a->anim, "idle");
    }
    d->still_since = -1;
    return d;
}

void dir_set_ground(director_t *d, const pb_ground_t *ground)
{
    d->ground = ground;
    free(d->vol_dz);
    d->vol_dz = NULL;
    if (!ground) return;
    d->vol_dz = calloc(d->sc->nvolumes ? d->sc->nvolumes : 1, sizeof *d->vol_dz);
    for (int i = 0; i < d->sc->nvolumes; i++)
        d->vol_dz[i] = ground_z(d, d->sc->volumes[i].bound_c[0], d->sc->volumes[i].bound_c[1]);
}

void dir_destroy(director_t *d)
{
    if (!d) return;
    free(d->vol_dz);
    for (int i = 0; i < d->sc->ntriggers; i++) free(d->trig[i].conds);
    free(d->trig);
    free(d->ag);
    free(d);
}

int dir_is_stale(const director_t *d) { return d->stale; }
int dir_has_pose(const director_t *d) { return d->have_pose; }
int64_t dir_time(const director_t *d) { return d->t_agents; }
int dir_triggers_fired(const director_t *d) { return d->nfired; }

void dir_input(director_t *d, int64_t utime, const char *input, int value)
{
    if (!value) return;     /* releases do not count */
    if (d->ninputs == MAX_INPUTS) {   /* oldest dropped: a burst of presses within one pose period */
        memmove(d->inputs, d->inputs + 1, (MAX_INPUTS - 1) * sizeof d->inputs[0]);
        d->ninputs--;
    }
    d->inputs[d->ninputs].utime = utime;
    snprintf(d->inputs[d->ninputs].input, sizeof d->inputs[0].input, "%s", input);
    d->ninputs++;
}

/* ---------------------------------------------------------------- agents */
static const char *moving_animation(const sc_agent_t *a)
{
    return strcmp(a->kind, "pedestrian") == 0 ? "walk" : "move";
}

static void set_anim(director_t *d, agent_rt_t *a, const char *name, int64_t t)
{
    if (strcmp(a->anim, name) != 0) {
        snprintf(a->anim, sizeof a->anim, "%s", name);
        a->anim_t0 = t;
    }
}

/* Seconds the car needs to reach its rest point at the behaviour's stop line. */
static double car_arrival(const director_t *d, const sc_behaviour_t *b, int64_t t, double decel)
{
    const sc_stop_t *st = &d->sc->stops[b->sync_stop];
    double target = st->s - d->front - d->sc->stop_gap_m;
    double dist = route_delta(d->route, d->s_base, target);
    if (dist < -2.0) return 0;      /* already past: hurry */
    double T = dir_predict_arrival(dist, d->speed, d->accel, decel, b->sync_ease);
    if (isfinite(T)) T -= (t - d->t_pose) * 1e-6;   /* prediction made at the last pose */
    return T < 0 ? 0 : T;
}

/* Speed for a synchronised agent: reach the mark when the car comes to rest. */
static void sync_speed(director_t *d, int i, const sc_behaviour_t *b, int64_t t)
{
    agent_rt_t *a = &d->ag[i];
    double D = 0, W = a->wait_left, x = a->x, y = a->y;
    for (int k = a->wp; k <= b->sync_mark; k++) {
        D += hypot(b->pts[k].xy[0] - x, b->pts[k].xy[1] - y);
        x = b->pts[k].xy[0]; y = b->pts[k].xy[1];
        if (k < b->sync_mark) W += b->pts[k].wait_s;
    }
    /* Holding agents set off on a late-biased prediction (the car may brake more
     * gently than sync decel): early is only repaired by waiting, late by walking faster. */
    double T = car_arrival(d, b, t, a->holding ? b->sync_decel * 0.6 : b->sync_decel);
    if (!isfinite(T)) {
        /* car standing or stopping short of the line: pause while the mark stays within
         * reach at speed_max once the car sets off (its quickest pull-up: accelerating,
         * then braking, both at sync decel), else walk on slowly */
        if (a->holding) return;
        const sc_stop_t *st = &d->sc->stops[b->sync_stop];
        double dist = route_delta(d->route, d->s_base, st->s - d->front - d->sc->stop_gap_m);
        double t_go = dist > 0 ? 2 * sqrt(dist / b->sync_decel) : 0;
        a->speed = D / b->speed_max + W < t_go ? 0 : b->speed_min;
        return;
    }
    double avail = T - W;
    double v = avail > 1e-3 ? D / avail : INFINITY;
    if (a->holding) {
        if (v < b->speed_min) return;
        a->holding = 0;
    }
    /* Early even at speed_min (the car slowed down: a lead car, a late braker): pause
     * once that would be more than 0.5 s early, and set off again at speed_min when it
     * would be 0.25 s early (the car usually comes sooner than a slow approach predicts). */
    double slack = avail - D / b->speed_min;
    if (slack > (a->speed == 0 ? 0.25 : 0.5)) { a->speed = 0; return; }
    a->speed = v < b->speed_min ? b->speed_min : v > b->speed_max ? b->speed_max : v;
}

static void advance_agent(director_t *d, int i, int64_t t_from, int64_t t_to)
{
    agent_rt_t *a = &d->ag[i];
    const sc_agent_t *sa = &d->sc->agents[i];
    double dt = (t_to - t_from) * 1e-6;
    a->vx = a->vy = 0;
    if (a->beh < 0) {
        if (!a->anim_override) set_anim(d, a, "idle", t_to);
        return;
    }
    const sc_behaviour_t *b = &d->sc->behaviours[a->beh];
    int synced = b->sync && !a->mark_done && a->wp <= b->sync_mark;
    if (synced && d->stale) { set_anim(d, a, "idle", t_to); return; }   /* held: no trustworthy car time */
    if (synced && d->have_pose) sync_speed(d, i, b, t_to);
    if (synced && (a->holding || a->speed == 0)) {   /* holding, or paused for a car stopping short */
        if (!a->anim_override) set_anim(d, a, "idle", t_to);
        return;
    }
    double moved = 0;
    while (dt > 1e-9 && a->beh >= 0) {
        if (a->wait_left > 0) {
            if (!a->anim_override) set_anim(d, a, a->wp > 0 ? b->pts[a->wp - 1].gesture : "idle", t_to);
            double w = fmin(dt, a->wait_left);
            a->wait_left -= w;
            dt -= w;
            if (a->wait_left <= 1e-9) a->wait_left = 0;
            continue;
        }
        if (a->wp >= b->npts) {     /* path done */
            a->beh = -1;
            if (!a->anim_override) set_anim(d, a, "idle", t_to);
            break;
        }
        const sc_waypoint_t *w = &b->pts[a->wp];
        double speed = (b->sync && a->wp <= b->sync_mark && !a->mark_done) ? a->speed : w->speed;
        double dx = w->xy[0] - a->x, dy = w->xy[1] - a->y, dist = hypot(dx, dy);
        double step = speed * dt;
        if (!a->anim_override) set_anim(d, a, moving_animation(sa), t_to);
        if (dist > 1e-9) a->yaw = atan2(dy, dx);
        if (step < dist) {
            a->x += dx / dist * step; a->y += dy / dist * step;
            a->vx = dx / dist * speed; a->vy = dy / dist * speed;
            moved += step;
            dt = 0;
        } else {
            a->x = w->xy[0]; a->y = w->xy[1];
            moved += dist;
            dt -= speed > 0 ? dist / speed : dt;
            if (speed > 0 && dist > 1e-9) { a->vx = dx / dist * speed; a->vy = dy / dist * speed; }
            a->wait_left = w->wait_s;
            a->wait_total = w->wait_s;
            if (b->sync && a->wp == b->sync_mark && !a->mark_done) {
                a->mark_done = 1;
                /* the exact instant within this step, for timing studies */
                double t_mark = t_to * 1e-6 - dt;
                char id[SC_ID_LEN + 8];
                snprintf(id, sizeof id, "%s/mark", b->id);
                emit(d, "mark", id, i, "reached mark %d of %s at t=%.3f s (stop line %s)", b->sync_mark, b->id,
                     t_mark - d->t0 * 1e-6, d->sc->stops[b->sync_stop].id);
            }
            a->wp++;
        }
    }
    a->walked += moved;
}

static void advance_agents(director_t *d, int64_t t)
{
    if (t <= d->t_agents) return;
    for (int i = 0; i < d->sc->nagents; i++) advance_agent(d, i, d->t_agents, t);
    d->t_agents = t;
}

void dir_tick(director_t *d, int64_t t)
{
    if (!d->have_pose) return;      /* scenario time starts with the first pose */
    advance_agents(d, t);
}

void dir_set_stale(director_t *d, int stale, int64_t utime, double age_s)
{
    if (stale == d->stale) return;
    d->stale = stale;
    if (stale) emit(d, "warning", "pose_stale", -1, "no vehicle pose for %.2f s: synchronised behaviours hold their agents", age_s);
    else emit(d, "warning", "pose_resumed", -1, "vehicle poses resumed: synchronised behaviours continue");
}

/* ---------------------------------------------------------------- actions */
/* An action of a trigger that fired at pose `at` (between the previous pose and the
 * latest one): its events carry that pose, and a behaviour it starts has walked
 * since then, so agents move alike whatever the pose rate. */
static void run_action(director_t *d, const sc_trigger_t *tr, const sc_action_t *ac, const dir_pose_t *at)
{
    const sc_scenario_t *sc = d->sc;
    char id[SC_ID_LEN * 2 + 16];
    int64_t t = at->utime;
    switch (ac->type) {
    case SC_ACT_START: {
        const sc_behaviour_t *b = &sc->behaviours[ac->behaviour];
        agent_rt_t *a = &d->ag[b->agent];
        a->beh = ac->behaviour;
        a->wp = 0; a->wait_left = 0; a->mark_done = 0; a->anim_override = 0;
        a->holding = b->sync;
        a->speed = b->sync ? b->speed_min : 0;
        snprintf(id, sizeof id, "start:%s", b->id);
        emit_at(d, at, "action", id, b->agent, "trigger %s starts behaviour %s%s", tr->id, b->id, b->sync ? " (arrival-synchronised)" : "");
        if (t < d->t_agents) advance_agent(d, b->agent, t, d->t_agents);
        break;
    }
    case SC_ACT_STOP: {
        const sc_behaviour_t *b = &sc->behaviours[ac->behaviour];
        agent_rt_t *a = &d->ag[b->agent];
        if (a->beh == ac->behaviour) { a->beh = -1; a->wait_left = 0; set_anim(d, a, "idle", t); }
        snprintf(id, sizeof id, "stop:%s", b->id);
        emit_at(d, at, "action", id, b->agent, "trigger %s stops behaviour %s", tr->id, b->id);
        break;
    }
    case SC_ACT_ANIMATE: {
        agent_rt_t *a = &d->ag[ac->agent];
        set_anim(d, a, ac->name, t);
        a->anim_override = strcmp(ac->name, "auto") != 0;
        snprintf(id, sizeof id, "animate:%s", sc->agents[ac->agent].id);
        emit_at(d, at, "action", id, ac->agent, "trigger %s sets animation %s", tr->id, ac->name);
        break;
    }
    case SC_ACT_PLACE: {
        agent_rt_t *a = &d->ag[ac->agent];
        a->x = ac->xy[0]; a->y = ac->xy[1]; a->yaw = ac->yaw;
        snprintf(id, sizeof id, "place:%s", sc->agents[ac->agent].id);
        emit_at(d, at, "action", id, ac->agent, "trigger %s places the agent at %.2f %.2f", tr->id, ac->xy[0], ac->xy[1]);
        break;
    }
    case SC_ACT_EMIT:
        snprintf(id, sizeof id, "emit:%s", ac->name);
        emit_at(d, at, "action", id, -1, "trigger %s emits %s", tr->id, ac->name);
        break;
    }
}

/* ---------------------------------------------------------------- conditions */
/* What the car-motion conditions look at: the car at a pose or between two. */
typedef struct {
    geom_shape_t foot;
    double speed, s_base;
} car_state_t;

static double stop_distance(const director_t *d, int stop, double s_base)
{   /* along the route from the front bumper to the stop line (negative once past it) */
    return route_delta(d->route, s_base + d->front, d->sc->stops[stop].s);
}

static int raw_value(director_t *d, const sc_cond_t *c, int64_t t, const car_state_t *car)
{
    switch (c->type) {
    case SC_COND_ENTER: return foot_touches_volume(d, &car->foot, &d->sc->volumes[c->volume]);
    case SC_COND_DISTANCE: {
        /* unsigned, like a distance to a point: "below 3" must not hold half a lap past the line */
        double dist = c->stop_line >= 0 ? fabs(stop_distance(d, c->stop_line, car->s_base)) : foot_distance(&car->foot, c->point);
        return c->has_below ? dist < c->below : dist > c->above;
    }
    case SC_COND_TTA: {
        double dist = c->stop_line >= 0 ? stop_distance(d, c->stop_line, car->s_base) : foot_distance(&car->foot, c->point);
        if (dist < 0) return 0;
        double tta = car->speed > STANDSTILL_V ? dist / car->speed : INFINITY;
        return tta < c->below;
    }
    case SC_COND_SPEED: return c->has_below ? car->speed < c->below : car->speed > c->above;
    case SC_COND_STANDSTILL: return d->still_since >= 0 && (t - d->still_since) * 1e-6 >= c->duration_s;
    case SC_COND_AFTER: {
        const trig_rt_t *o = &d->trig[c->after_trigger];
        return o->fired && (t - o->fired_utime) * 1e-6 >= c->after_s;
    }
    case SC_COND_INPUT:
        for (int k = 0; k < d->ninputs; k++)
            if (d->inputs[k].utime <= t && strcmp(d->inputs[k].input, c->input) == 0) return 1;
        return 0;
    case SC_COND_TIME: return (t - d->t0) * 1e-6 > c->above;
    }
    return 0;
}

/* OpenSCENARIO semantics: the edge is taken on the raw value, then the result is
 * delayed by delay_s. An edge needs a known previous value, so nothing rises on
 * the first pose (or the first after a restore). t_raw: when the raw value took
 * its current value (<= t); delays count from it. *onset: when the result
 * became true. */
static int cond_delayed(const sc_cond_t *c, cond_rt_t *cr, int raw, int64_t t_raw, int64_t t, int64_t *onset)
{
    int v;
    if (c->edge == SC_EDGE_NONE) v = raw;
    else if (cr->prev < 0) v = 0;
    else if (c->edge == SC_EDGE_RISING) v = raw && !cr->prev;
    else if (c->edge == SC_EDGE_FALLING) v = !raw && cr->prev;
    else v = raw != cr->prev;
    cr->prev = raw;
    *onset = t_raw;
    if (c->delay_s <= 0) return v;
    int64_t delay = (int64_t)llround(c->delay_s * 1e6);
    if (c->edge != SC_EDGE_NONE) {
        if (v && cr->nimp < DELAY_RING) cr->imp[cr->nimp++] = t_raw;
        if (cr->nimp && cr->imp[0] + delay <= t) {
            *onset = cr->imp[0] + delay;
            memmove(cr->imp, cr->imp + 1, (cr->nimp - 1) * sizeof cr->imp[0]);
            cr->nimp--;
            return 1;
        }
        return 0;
    }
    int last = cr->ntr ? cr->tr_v[cr->ntr - 1] : 0;
    if (v != last) {
        if (cr->ntr == DELAY_RING) {
            memmove(cr->tr_t, cr->tr_t + 1, (DELAY_RING - 1) * sizeof cr->tr_t[0]);
            memmove(cr->tr_v, cr->tr_v + 1, (DELAY_RING - 1) * sizeof cr->tr_v[0]);
            cr->ntr--;
        }
        cr->tr_t[cr->ntr] = t_raw; cr->tr_v[cr->ntr] = v; cr->ntr++;
    }
    int out = 0, k = 0;
    while (k < cr->ntr && cr->tr_t[k] + delay <= t) out = cr->tr_v[k++];
    if (k > 0) *onset = cr->tr_t[k - 1] + delay;
    if (k > 1) {   /* keep the newest transition already in effect */
        memmove(cr->tr_t, cr->tr_t + k - 1, (cr->ntr - k + 1) * sizeof cr->tr_t[0]);
        memmove(cr->tr_v, cr->tr_v + k - 1, (cr->ntr - k + 1) * sizeof cr->tr_v[0]);
        cr->ntr -= k - 1;
    }
    return out;
}

/* The condition's value now; *onset as above, INT64_MIN when a level already held at
 * the previous evaluation (an edge is a new event each time). */
static int cond_value(const sc_cond_t *c, cond_rt_t *cr, int raw, int64_t t_raw, int64_t t, int64_t *onset)
{
    int out = cond_delayed(c, cr, raw, t_raw, t, onset);
    if (out && cr->was && c->edge == SC_EDGE_NONE) *onset = INT64_MIN;
    cr->was = out;
    return out;
}

/* The car at fraction f (0..1) of the way from the previous pose to the latest:
 * position, velocity, speed and route position linear, orientation by normalised
 * quaternion blend (poses are close: at most jump_m apart). */
static void car_between(const director_t *d, double f, dir_pose_t *p, car_state_t *car)
{
    const dir_pose_t *a = &d->prev_pose, *b = &d->pose;
    double dot = 0, n = 0;
    for (int i = 0; i < 4; i++) dot += a->q[i] * b->q[i];
    p->utime = a->utime + llround(f * (double)(b->utime - a->utime));
    for (int i = 0; i < 3; i++) {
        p->pos[i] = a->pos[i] + f * (b->pos[i] - a->pos[i]);
        p->vel[i] = a->vel[i] + f * (b->vel[i] - a->vel[i]);
    }
    for (int i = 0; i < 4; i++) {
        p->q[i] = (1 - f) * a->q[i] + f * (dot < 0 ? -b->q[i] : b->q[i]);
        n += p->q[i] * p->q[i];
    }
    for (int i = 0; i < 4; i++) p->q[i] /= sqrt(n);
    footprint(d, p->pos, p->q, &car->foot);
    car->speed = d->prev_speed + f * (d->speed - d->prev_speed);
    car->s_base = d->route ? d->prev_s_base + f * route_delta(d->route, d->prev_s_base, d->s_base) : 0;
}

/* When, since the previous pose, a condition's raw value became `raw`: a car
 * condition by bisection on the motion between the two poses (12 halvings: a 1 m
 * step to 0.25 mm), a condition of time from its own clock. Within the two poses. */
static int64_t raw_change_time(director_t *d, const sc_cond_t *c, int raw, int64_t t)
{
    int64_t t0 = d->prev_pose.utime, on = t;
    switch (c->type) {
    case SC_COND_ENTER: case SC_COND_DISTANCE: case SC_COND_TTA: case SC_COND_SPEED: {
        double lo = 0, hi = 1;
        for (int it = 0; it < 12; it++) {
            double mid = (lo + hi) / 2;
            dir_pose_t p;
            car_state_t car;
            car_between(d, mid, &p, &car);
            if (raw_value(d, c, t, &car) == raw) hi = mid; else lo = mid;
        }
        on = t0 + llround(hi * (double)(t - t0));
        break;
    }
    case SC_COND_STANDSTILL:
        if (raw) on = d->still_since + llround(c->duration_s * 1e6);
        break;
    case SC_COND_AFTER:
        if (raw) on = d->trig[c->after_trigger].fired_utime + llround(c->after_s * 1e6);
        break;
    case SC_COND_TIME:
        if (raw) on = d->t0 + llround(c->above * 1e6);
        break;
    case SC_COND_INPUT:
        for (int k = 0; raw && k < d->ninputs; k++)
            if (d->inputs[k].utime <= t && strcmp(d->inputs[k].input, c->input) == 0 && d->inputs[k].utime < on)
                on = d->inputs[k].utime;
        break;
    }
    return on < t0 ? t0 : on > t ? t : on;
}

/* After a jump: did the straight line between the two poses sweep the footprint through v? */
static int swept_through(const director_t *d, const sc_volume_t *v, double jump)
{
    /* broad phase: segment of footprint centres against the bounding circle */
    double ax = d->prev_foot.c[0], ay = d->prev_foot.c[1], bx = d->foot.c[0], by = d->foot.c[1];
    double ex = bx - ax, ey = by - ay, L2 = ex * ex + ey * ey;
    double u = L2 > 0 ? ((v->bound_c[0] - ax) * ex + (v->bound_c[1] - ay) * ey) / L2 : 0;
    u = u < 0 ? 0 : u > 1 ? 1 : u;
    if (hypot(ax + u * ex - v->bound_c[0], ay + u * ey - v->bound_c[1]) > d->car_r + v->bound_r) return 0;
    int n = (int)ceil(jump / 0.25);
    if (n > 40000) n = 40000;
    for (int k = 1; k < n; k++) {
        dir_pose_t p;
        car_state_t car;
        car_between(d, (double)k / n, &p, &car);
        if (foot_touches_volume(d, &car.foot, v)) return 1;
    }
    return 0;
}

/* Triggers fire at the instant their conditions were met, interpolated between the
 * previous pose and this one (not at the pose that shows it: at 10 m/s a 10 Hz
 * POSE would place a trigger up to 1 m late, differently on each platform). The
 * event is still published now, at this pose, carrying that earlier instant. */
static void eval_triggers(director_t *d, int64_t t, int first, int jumped, double jump)
{
    const sc_scenario_t *sc = d->sc;
    car_state_t now = { .foot = d->foot, .speed = d->speed, .s_base = d->s_base };
    for (int ti = 0; ti < sc->ntriggers; ti++) {
        trig_rt_t *tr = &d->trig[ti];
        if (tr->fired) continue;
        const sc_trigger_t *st = &sc->triggers[ti];
        int group_ok[64];
        int64_t group_on[64];   /* when the group's last condition became true */
        int ng = st->ngroups < 64 ? st->ngroups : 64;
        for (int g = 0; g < ng; g++) { group_ok[g] = 1; group_on[g] = INT64_MIN; }
        for (int k = 0; k < st->nconds; k++) {
            const sc_cond_t *c = &st->conds[k];
            cond_rt_t *cr = &tr->conds[k];
            int raw = raw_value(d, c, t, &now);
            if (c->type == SC_COND_ENTER && jumped && !raw && cr->prev == 0 && swept_through(d, &sc->volumes[c->volume], jump)) {
                char id[SC_ID_LEN * 2 + 8];
                snprintf(id, sizeof id, "pose_jump:%s", st->id);
                emit(d, "warning", id, -1, "pose jumped %.1f m across volume %s (trigger %s): %s", jump,
                     sc->volumes[c->volume].id, st->id, sc->on_jump == SC_JUMP_FIRE ? "counted as entered (on_pose_jump: fire)" : "not counted as entered (on_pose_jump: skip)");
                if (sc->on_jump == SC_JUMP_FIRE) raw = 1;
            }
            /* across a jump the motion between the poses is unknown: the change counts at this pose */
            int64_t t_raw = !first && !jumped && cr->prev >= 0 && raw != cr->prev ? raw_change_time(d, c, raw, t) : t, on;
            int v = cond_value(c, cr, raw, t_raw, t, &on);
            if (c->group >= ng) continue;
            if (!v) group_ok[c->group] = 0;
            else if (on > group_on[c->group]) group_on[c->group] = on;
        }
        /* the trigger fired when its first group was complete */
        int64_t t_fire = INT64_MAX;
        for (int g = 0; g < ng; g++)
            if (group_ok[g] && group_on[g] < t_fire) t_fire = group_on[g];
        if (t_fire == INT64_MAX) continue;
        int64_t t_prev = first ? t : d->prev_pose.utime;
        if (jumped || t_fire > t) t_fire = t;
        if (t_fire < t_prev) t_fire = t_prev;
        dir_pose_t at = d->pose;
        if (t_fire < t) {
            car_state_t car;
            car_between(d, (double)(t_fire - t_prev) / (double)(t - t_prev), &at, &car);
            at.utime = t_fire;
        }
        tr->fired = 1;
        tr->fired_utime = t_fire;
        d->nfired++;
        emit_at(d, &at, "trigger", st->id, -1, "conditions met %.3f s (%.2f m) before the pose that showed them",
                (t - t_fire) * 1e-6, hypot(d->pose.pos[0] - at.pos[0], d->pose.pos[1] - at.pos[1]));
        for (int a = 0; a < st->nactions; a++) run_action(d, st, &st->actions[a], &at);
    }
}

static void check_collisions(director_t *d)
{
    for (int i = 0; i < d->sc->nagents; i++) {
        agent_rt_t *a = &d->ag[i];
        double dx = a->x - d->foot.c[0], dy = a->y - d->foot.c[1], r = d->car_r + agent_radius(&d->sc->agents[i]);
        int hit = 0;
        if (dx * dx + dy * dy <= r * r) {
            geom_shape_t g;
            agent_shape(d, i, &g);
            hit = geom_intersect(&d->foot, &g);
        }
        if (hit && !a->colliding) {
            char id[SC_ID_LEN + 16];
            snprintf(id, sizeof id, "collision:%s", d->sc->agents[i].id);
            emit(d, "collision", id, i, "virtual collision: car footprint touches %s %s at %.2f m/s", d->sc->agents[i].kind,
                 d->sc->agents[i].id, d->speed);
        }
        a->colliding = hit;
    }
}

/* ---------------------------------------------------------------- the step */
int dir_pose(director_t *d, const dir_pose_t *p, pb_err_t *err)
{
    for (int i = 0; i < 3; i++)
        if (!isfinite(p->pos[i]) || !isfinite(p->vel[i])) return pb_err_set(err, "pose at %lld is not finite", (long long)p->utime);
    for (int i = 0; i < 4; i++)
        if (!isfinite(p->q[i])) return pb_err_set(err, "pose at %lld is not finite", (long long)p->utime);
    if (d->have_pose && p->utime <= d->t_pose)
        return pb_err_set(err, "pose at %lld is not newer than the previous one (%lld)", (long long)p->utime, (long long)d->t_pose);
    int first = !d->have_pose;
    int64_t t = p->utime;
    if (first) { if (!d->restored) d->t0 = t; d->t_agents = t; }
    else advance_agents(d, t);   /* agents up to this instant with the previous car state */
    d->prev_pose = d->pose;
    d->prev_foot = d->foot;
    d->pose = *p;
    footprint(d, p->pos, p->q, &d->foot);
    double step = first ? 0 : hypot(p->pos[0] - d->prev_pose.pos[0], p->pos[1] - d->prev_pose.pos[1]);
    int jumped = !first && step > d->sc->jump_m;
    double v = hypot(p->vel[0], p->vel[1]);
    if (!first) {
        double dt = (t - d->t_pose) * 1e-6;
        double a = (v - d->speed) / dt;
        double k = dt / (dt + 0.2);     /* 0.2 s smoothing of the measured acceleration */
        d->accel = jumped ? 0 : d->accel + k * (a - d->accel);
    }
    d->prev_speed = first ? v : d->speed;
    d->speed = v;
    /* at rest since the speed fell below STANDSTILL_V, interpolated between the poses */
    if (v < STANDSTILL_V) {
        if (d->still_since < 0)
            d->still_since = first || jumped || d->prev_speed < STANDSTILL_V
                                 ? t : d->t_pose + llround((d->prev_speed - STANDSTILL_V) / (d->prev_speed - v) * (double)(t - d->t_pose));
    } else {
        d->still_since = -1;
    }
    d->prev_s_base = d->s_base;
    if (d->route) d->s_base = (first || jumped) ? pb_route_project(d->route, p->pos[0], p->pos[1])
                                                : project_near(d->route, p->pos[0], p->pos[1], d->s_base);
    d->t_pose = t;
    d->have_pose = 1;
    if (jumped) emit(d, "warning", "pose_jump", -1, "vehicle pose jumped %.2f m in %.3f s", step, (t - d->prev_pose.utime) * 1e-6);
    if (first) d->prev_s_base = d->s_base;
    eval_triggers(d, t, first, jumped, step);
    /* inputs are consumed at the pose that evaluated them */
    int keep = 0;
    for (int k = 0; k < d->ninputs; k++)
        if (d->inputs[k].utime > t) d->inputs[keep++] = d->inputs[k];
    d->ninputs = keep;
    /* a behaviour started now begins from this instant */
    if (d->t_agents < t) d->t_agents = t;
    check_collisions(d);
    return 0;
}

int dir_agents(const director_t *d, dir_agent_out_t *out)
{
    const sc_scenario_t *sc = d->sc;
    for (int i = 0; i < sc->nagents; i++) {
        const agent_rt_t *a = &d->ag[i];
        dir_agent_out_t *o = &out[i];
        o->id = sc->agents[i].id; o->kind = sc->agents[i].kind; o->model = sc->agents[i].model;
        /* feet on the ground; the vertical speed follows the ground along the walk */
        o->pos[0] = a->x; o->pos[1] = a->y; o->pos[2] = ground_z(d, a->x, a->y);
        o->yaw = a->yaw;
        o->vel[0] = a->vx; o->vel[1] = a->vy;
        o->vel[2] = (ground_z(d, a->x + 0.1 * a->vx, a->y + 0.1 * a->vy) - o->pos[2]) / 0.1;
        o->animation = a->anim;
        if (!strcmp(a->anim, "walk") || !strcmp(a->anim, "move")) o->phase = (float)fmod(a->walked / WALK_STRIDE_M, 1.0);
        else if (a->wait_total > 0 && a->wait_left > 0) o->phase = (float)(1 - a->wait_left / a->wait_total);
        else o->phase = 0;
        double dist = d->have_pose ? hypot(a->x - d->pose.pos[0], a->y - d->pose.pos[1]) : INFINITY;
        o->distance_m = d->have_pose ? (float)dist : -1.0f;
        o->in_range = d->have_pose && dist <= sc->render_distance_m;
    }
    return sc->nagents;
}

/* ---------------------------------------------------------------- recovery */
int dir_state_write(const director_t *d, char *buf, size_t cap)
{
    size_t n = 0;
#define OUT(...) do { int w = snprintf(buf + n, n < cap ? cap - n : 0, __VA_ARGS__); if (w < 0 || n + w >= cap) return -1; n += w; } while (0)
    OUT("portobello-director-state 1\nscenario %s\nt0 %lld\ntime %lld\n", d->sc->id, (long long)d->t0, (long long)d->t_agents);
    for (int i = 0; i < d->sc->ntriggers; i++)
        if (d->trig[i].fired) OUT("fired %s %lld\n", d->sc->triggers[i].id, (long long)d->trig[i].fired_utime);
    for (int i = 0; i < d->sc->nagents; i++) {
        const agent_rt_t *a = &d->ag[i];
        OUT("agent %s %.17g %.17g %.17g %s %d %.17g %.17g %d %d %.17g %.17g %s %d\n", d->sc->agents[i].id, a->x, a->y, a->yaw,
            a->beh >= 0 ? d->sc->behaviours[a->beh].id : "-", a->wp, a->wait_left, a->wait_total, a->holding, a->mark_done,
            a->speed, a->walked, a->anim, a->anim_override);
    }
#undef OUT
    return (int)n;
}

int dir_state_read(director_t *d, const char *text, pb_err_t *err)
{
    const char *p = text;
    int lineno = 0, version = 0;
    char line[512];
    while (*p) {
        const char *e = strchr(p, '\n');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        lineno++;
        if (len >= sizeof line) return pb_err_set(err, "state line %d: too long", lineno);
        memcpy(line, p, len);
        line[len] = 0;
        p = e ? e + 1 : p + len;
        char a0[64], id[SC_ID_LEN + 1], beh[SC_ID_LEN + 1], anim[SC_ID_LEN];
        long long v;
        if (lineno == 1) {
            if (sscanf(line, "portobello-director-state %d", &version) != 1 || version != 1)
                return pb_err_set(err, "state line 1: not a director state (version 1)");
            continue;
        }
        if (sscanf(line, "%63s", a0) != 1) continue;
        if (!strcmp(a0, "scenario")) {
            if (sscanf(line, "scenario %48s", id) != 1 || strcmp(id, d->sc->id) != 0)
                return pb_err_set(err, "state line %d: the state is of scenario '%s', not '%s'", lineno, id, d->sc->id);
        } else if (!strcmp(a0, "t0")) {
            if (sscanf(line, "t0 %lld", &v) != 1) return pb_err_set(err, "state line %d: bad t0", lineno);
            d->t0 = v;
        } else if (!strcmp(a0, "time")) {
            if (sscanf(line, "time %lld", &v) != 1) return pb_err_set(err, "state line %d: bad time", lineno);
            d->t_agents = v;
        } else if (!strcmp(a0, "fired")) {
            if (sscanf(line, "fired %48s %lld", id, &v) != 2) return pb_err_set(err, "state line %d: bad fired line", lineno);
            int ti = sc_find_trigger(d->sc, id);
            if (ti < 0) return pb_err_set(err, "state line %d: unknown trigger '%s'", lineno, id);
            if (!d->trig[ti].fired) d->nfired++;
            d->trig[ti].fired = 1;
            d->trig[ti].fired_utime = v;
        } else if (!strcmp(a0, "agent")) {
            agent_rt_t a;
            memset(&a, 0, sizeof a);
            if (sscanf(line, "agent %48s %lf %lf %lf %48s %d %lf %lf %d %d %lf %lf %47s %d", id, &a.x, &a.y, &a.yaw, beh, &a.wp,
                       &a.wait_left, &a.wait_total, &a.holding, &a.mark_done, &a.speed, &a.walked, anim, &a.anim_override) != 14)
                return pb_err_set(err, "state line %d: bad agent line", lineno);
            int ai = sc_find_agent(d->sc, id);
            if (ai < 0) return pb_err_set(err, "state line %d: unknown agent '%s'", lineno, id);
            a.beh = strcmp(beh, "-") ? sc_find_behaviour(d->sc, beh) : -1;
            if (strcmp(beh, "-") && a.beh < 0) return pb_err_set(err, "state line %d: unknown behaviour '%s'", lineno, beh);
            if (a.beh >= 0 && (a.wp < 0 || a.wp > d->sc->behaviours[a.beh].npts)) return pb_err_set(err, "state line %d: waypoint out of range", lineno);
            if (!isfinite(a.x) || !isfinite(a.y) || !isfinite(a.yaw)) return pb_err_set(err, "state line %d: not finite", lineno);
            snprintf(a.anim, sizeof a.anim, "%s", anim);
            d->ag[ai] = a;
        } else {
            return pb_err_set(err, "state line %d: unknown record '%s'", lineno, a0);
        }
    }
    if (version != 1) return pb_err_set(err, "state: empty");
    d->restored = 1;
    return 0;
}
