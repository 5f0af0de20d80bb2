/* scenario-check core: checks of a loaded scenario against its site that the
 * loader cannot make alone (it needs the car and the route's geometry). */
#include "check.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "director/core/geom.h"

static void report(check_report_fn fn, void *user, int is_error, const char *file, int line, const char *fmt, ...)
    __attribute__((format(printf, 6, 7)));
static void report(check_report_fn fn, void *user, int is_error, const char *file, int line, const char *fmt, ...)
{
    char msg[600];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    fn(is_error, file, line, msg, user);
}

/* The car's footprint with its base origin on the route at s. */
static void foot_at(const pb_route_t *r, const check_vehicle_t *veh, double s, geom_shape_t *g)
{
    pb_route_point_t p;
    pb_route_eval(r, s, &p);
    double off = veh->length / 2 - veh->rear_overhang;
    double c[3] = { p.x + off * cos(p.yaw), p.y + off * sin(p.yaw), veh->height / 2 };
    double size[3] = { veh->length, veh->width, veh->height };
    geom_box_yaw(g, c, p.yaw, size);
}

/* Arc length (base origin) at which the footprint first touches v along one lap, or -1. */
static double first_touch(const pb_route_t *r, const check_vehicle_t *veh, const sc_volume_t *v, double *nearest)
{
    geom_shape_t gv, gf;
    geom_volume(&gv, v);
    *nearest = INFINITY;
    for (double s = 0; s < r->length; s += 0.25) {
        pb_route_point_t p;
        pb_route_eval(r, s, &p);
        double d = hypot(p.x - v->bound_c[0], p.y - v->bound_c[1]) - v->bound_r;
        if (d < *nearest) *nearest = d < 0 ? 0 : d;
        if (d > veh->length + 1) continue;
        foot_at(r, veh, s, &gf);
        if (geom_intersect(&gf, &gv)) return s;
    }
    return -1;
}

int check_scenario(const sc_scenario_t *sc, const pb_route_t *r, const check_vehicle_t *veh, check_report_fn fn, void *user)
{
    int errors = 0;
    const char *file = sc->path;
    double *touch = calloc(sc->nvolumes ? sc->nvolumes : 1, sizeof *touch);
    int *used = calloc(sc->nvolumes ? sc->nvolumes : 1, sizeof *used);
    int *started = calloc(sc->nbehaviours ? sc->nbehaviours : 1, sizeof *started);
    for (int i = 0; i < sc->ntriggers; i++) {
        const sc_trigger_t *t = &sc->triggers[i];
        for (int k = 0; k < t->nconds; k++)
            if (t->conds[k].type == SC_COND_ENTER) used[t->conds[k].volume] = 1;
        for (int k = 0; k < t->nactions; k++)
            if (t->actions[k].type == SC_ACT_START) started[t->actions[k].behaviour] = 1;
    }
    for (int i = 0; i < sc->nvolumes; i++) {
        const sc_volume_t *v = &sc->volumes[i];
        double nearest;
        touch[i] = first_touch(r, veh, v, &nearest);
        if (touch[i] < 0 && used[i]) {
            report(fn, user, 1, file, v->line, "volume '%s' is off the route: the car's footprint never touches it (%.1f m from the lane centreline)", v->id, nearest);
            errors++;
        } else if (!used[i]) {
            report(fn, user, 0, file, v->line, "volume '%s' is not used by any enter condition", v->id);
        }
    }
    for (int i = 0; i < sc->nbehaviours; i++) {
        const sc_behaviour_t *b = &sc->behaviours[i];
        if (!started[i]) report(fn, user, 0, file, b->line, "behaviour '%s' is never started by a trigger", b->id);
        if (!b->sync) continue;
        const sc_agent_t *a = &sc->agents[b->agent];
        double L = sc_path_length(b, a->xy, b->sync_mark), W = 0;
        for (int k = 0; k < b->sync_mark; k++) W += b->pts[k].wait_s;
        const sc_stop_t *st = &sc->stops[b->sync_stop];
        double rest = st->s - (veh->length - veh->rear_overhang) - sc->stop_gap_m;
        /* The earliest moment the car can be at rest: from where a trigger that
         * starts this behaviour through an enter condition fires, at the fastest
         * profile's cruise speed, then braking at its deceleration. */
        const pb_speed_profile_t *fast = &r->profiles[PB_PROFILE_AGGRESSIVE];
        for (int ti = 0; ti < sc->ntriggers; ti++) {
            const sc_trigger_t *t = &sc->triggers[ti];
            int starts = 0;
            for (int k = 0; k < t->nactions; k++) starts |= t->actions[k].type == SC_ACT_START && t->actions[k].behaviour == i;
            if (!starts) continue;
            for (int k = 0; k < t->nconds; k++) {
                if (t->conds[k].type != SC_COND_ENTER || touch[t->conds[k].volume] < 0) continue;
                double d = fmod(rest - touch[t->conds[k].volume] + 2 * r->length, r->length);
                double v = fast->cruise, tmin = d / v + v / (2 * fast->decel);
                if (v * v / (2 * fast->decel) > d) tmin = sqrt(2 * d / fast->decel);
                double need = L / b->speed_max + W;
                if (need > tmin) {
                    report(fn, user, 1, file, b->line,
                           "agent '%s' cannot reach its mark: %.1f m at most %.1f m/s (+ %.1f s waits) takes %.1f s, but the car can be at rest at %s %.1f s after trigger '%s' fires (aggressive profile)",
                           a->id, L, b->speed_max, W, need, st->id, tmin, t->id);
                    errors++;
                }
            }
        }
        if (hypot(b->pts[b->sync_mark].xy[0] - st->xy[0], b->pts[b->sync_mark].xy[1] - st->xy[1]) > 40)
            report(fn, user, 0, file, b->pts[b->sync_mark].line, "mark of '%s' is more than 40 m from stop line %s", b->id, st->id);
    }
    free(touch); free(used); free(started);
    return errors;
}
