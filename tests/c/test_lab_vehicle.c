/* Unit tests of the lab twin's core: the leg planner and the stop / proceed /
 * crossing state machine on the default site's route. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "pb_check.h"
#include "pb_route.h"
#include "lab_vehicle/core/lab_vehicle.h"
#include "lab_vehicle/core/lv_plan.h"

#ifndef PB_SOURCE_DIR
#define PB_SOURCE_DIR "."
#endif

static void test_legs(const pb_route_t *r)
{
    const double lengths[] = { 0.6, 3.0, 30.0, 93.55, 600.0, 1500.0 };
    for (int p = 0; p < PB_PROFILE_COUNT; p++) {
        const pb_speed_profile_t *sp = &r->profiles[p];
        for (size_t i = 0; i < sizeof lengths / sizeof *lengths; i++) {
            lv_leg_t leg;
            pb_err_t err;
            CHECK(lv_leg_plan(&leg, r, sp, 40.0 + i * 7, lengths[i], &err) == 0);
            CHECK(leg.s[leg.n - 1] == lengths[i]);          /* exactly on the target */
            CHECK(leg.v[0] == 0 && leg.v[leg.n - 1] == 0);
            double s, v, a, vmax = 0, amax = 0, amin = 0, lat = 0, back = 0;
            for (int k = 1; k < leg.n; k++) {
                if (leg.s[k] < leg.s[k - 1]) back = 1;
                double acc = (leg.v[k] - leg.v[k - 1]) / leg.dt;
                if (acc > amax) amax = acc;
                if (acc < amin) amin = acc;
                if (leg.v[k] > vmax) vmax = leg.v[k];
                pb_route_point_t rp;
                pb_route_eval(r, leg.d0 + leg.s[k], &rp);
                double l = leg.v[k] * leg.v[k] * fabs(rp.kappa);
                if (l > lat) lat = l;
            }
            CHECK(!back);
            CHECK(vmax <= sp->cruise * (1 + 1e-5));      /* the end-point rescale is within 3e-6 */
            CHECK(amax <= sp->accel * 1.001);
            CHECK(amin >= -sp->decel * 1.001);
            CHECK(lat <= sp->lat_accel);
            /* rest at t <= 0 and t >= t_end; s' = v inside */
            lv_leg_eval(&leg, -1, &s, &v, &a);
            CHECK(s == 0 && v == 0);
            lv_leg_eval(&leg, leg.t_end + 5, &s, &v, &a);
            CHECK(s == lengths[i] && v == 0);
            double t = leg.t_end * 0.37, s1, s2;
            lv_leg_eval(&leg, t, &s, &v, &a);
            lv_leg_eval(&leg, t - 1e-4, &s1, &v, &a);
            lv_leg_eval(&leg, t + 1e-4, &s2, &a, &a);
            lv_leg_eval(&leg, t, &s, &v, &a);
            CHECK_NEAR((s2 - s1) / 2e-4, v, 1e-3);
            lv_leg_free(&leg);
        }
    }
    lv_leg_t leg;
    CHECK(lv_leg_plan(&leg, r, &r->profiles[0], 0, 0, NULL) == -1);
    CHECK(lv_leg_plan(&leg, r, &r->profiles[0], 0, NAN, NULL) == -1);
}

static int count_events(lab_vehicle_t *lv, const char *id, lv_event_t *last)
{
    int n = 0;
    lv_event_t e;
    while (lv_next_event(lv, &e))
        if (!strcmp(e.id, id)) { n++; if (last) *last = e; }
    return n;
}

/* Steps at 100 Hz until the state is st (or max_s pass); returns the time. */
static int64_t run_until(lab_vehicle_t *lv, int64_t *t, lv_state_t st, double max_s, lv_pose_t *p)
{
    int64_t end = *t + (int64_t)(max_s * 1e6);
    while (*t < end) {
        *t += 10000;
        CHECK(lv_step(lv, *t, p, NULL) == 0);
        if (p->state == st) return *t;
    }
    return -1;
}

static void test_state_machine(const pb_route_t *r)
{
    lv_config_t cfg;
    lv_config_default(&cfg);
    cfg.start_s = 55;
    cfg.laps = 0;
    pb_err_t err;
    lab_vehicle_t *lv = lv_create(r, &cfg, &err);
    CHECK(lv != NULL);
    lv_pose_t p;
    int64_t t = 1000000000000LL;
    CHECK(lv_step(lv, t, &p, &err) == 0);
    CHECK(p.state == LV_STATE_STARTING && p.v == 0 && p.dist == 55);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_NOT_WAITING);
    int64_t arrived = run_until(lv, &t, LV_STATE_AWAIT_PROCEED, 30, &p);
    CHECK(arrived > 0);
    /* sl01: base origin 3.50 + 0.50 m behind the line, exactly */
    CHECK_NEAR(p.dist, r->stops[0].s - 4.0, 1e-9);
    CHECK_NEAR(lv_stop_target(lv, 0), r->stops[0].s - 4.0, 1e-12);
    CHECK(p.v == 0);
    lv_event_t e;
    CHECK(count_events(lv, "awaiting_proceed", &e) == 1);
    CHECK(!strcmp(e.stop_line, "sl01") && !strcmp(e.crosswalk, "cw01"));
    /* the wrong input, a release and an early press do not release the car */
    CHECK(lv_on_input(lv, t, "horn", 1) == LV_INPUT_OTHER);
    CHECK(lv_on_input(lv, t, "proceed", 0) == LV_INPUT_RELEASE);
    CHECK(lv_on_input(lv, arrived - 1, "proceed", 1) == LV_INPUT_EARLY);
    for (int i = 0; i < 100; i++) { t += 10000; lv_step(lv, t, &p, NULL); }
    CHECK(p.state == LV_STATE_AWAIT_PROCEED && p.dist == r->stops[0].s - 4.0);
    /* a pedestrian on cw01 holds the car after proceed; an object does not */
    lv_agent_t ped = { .id = "ped1", .kind = "pedestrian", .x = r->cw[0].center[0] + 1.0, .y = r->cw[0].center[1] - 2.0 };
    lv_agent_t box = { .id = "box", .kind = "object", .x = r->cw[0].center[0], .y = r->cw[0].center[1] };
    lv_agent_t both[2] = { box, ped };
    CHECK(lv_on_agents(lv, t, both, 2, &err) == 0);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_ACCEPTED);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_NOT_WAITING);   /* one press is enough */
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    CHECK(count_events(lv, "crossing_occupied", &e) == 1);
    CHECK(!strcmp(e.agent_id, "ped1"));
    for (int i = 0; i < 50; i++) {
        t += 10000;
        CHECK(lv_on_agents(lv, t, both, 2, &err) == 0);
        lv_step(lv, t, &p, NULL);
    }
    CHECK(p.state == LV_STATE_AWAIT_CLEAR && p.v == 0);
    CHECK(count_events(lv, "crossing_occupied", NULL) == 0);   /* reported once */
    /* a non-finite agent is refused and the previous AGENTS stay */
    lv_agent_t bad = { .id = "nan", .kind = "pedestrian", .x = NAN };
    CHECK(lv_on_agents(lv, t, &bad, 1, &err) == -1);
    CHECK_CONTAINS(err.msg, "not finite");
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    /* beside the stripes, within the margin along the road: still held */
    const pb_crosswalk_t *cw = &r->cw[0];
    double cy = cos(cw->yaw_deg * M_PI / 180), sy = sin(cw->yaw_deg * M_PI / 180);
    double along = cw->width / 2 + cfg.crossing_margin_m - 0.2;
    ped.x = cw->center[0] + along * cy;
    ped.y = cw->center[1] + along * sy;
    lv_agent_t beside[2] = { box, ped };
    CHECK(lv_on_agents(lv, t, beside, 2, &err) == 0);
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    /* agent at (along, across) in cw01's frame with velocity (v_along, v_across): held? */
#define PLACE(a_, c_, va_, vc_) do { \
        ped.x = cw->center[0] + (a_) * cy - (c_) * sy; ped.y = cw->center[1] + (a_) * sy + (c_) * cy; \
        ped.vx = (va_) * cy - (vc_) * sy; ped.vy = (va_) * sy + (vc_) * cy; \
        lv_agent_t two_[2] = { box, ped }; \
        CHECK(lv_on_agents(lv, t, two_, 2, &err) == 0); \
        t += 10000; \
        lv_step(lv, t, &p, NULL); \
    } while (0)
    double kerb = cw->length / 2;
    PLACE(0.0, kerb + 0.5, 0.0, 0.0);           /* standing at the kerb: about to cross */
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    PLACE(0.0, -(kerb + 2.0), 0.0, 1.4);        /* walking onto it, there in 1.4 s */
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    lv_next_event(lv, &e);
    while (lv_next_event(lv, &e)) {}
    CHECK_CONTAINS(e.detail, "heading onto");
    PLACE(0.0, -(kerb + 4.0), 0.0, 1.4);        /* 4 m off at 1.4 m/s: not within 2 s */
    CHECK(p.state == LV_STATE_DRIVING);
    lv_destroy(lv);
    /* again to the first stop, for the sidewalk stroller */
    lv = lv_create(r, &cfg, &err);
    t = 2000000000000LL;
    CHECK(run_until(lv, &t, LV_STATE_AWAIT_PROCEED, 30, &p) > 0);
    CHECK(lv_on_agents(lv, t, NULL, 0, &err) == 0);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_ACCEPTED);
    PLACE(3.0, kerb + 0.5, -1.2, 0.0);          /* strolling along the sidewalk past the end: clear */
    CHECK(p.state == LV_STATE_DRIVING);
    CHECK(count_events(lv, "crossing_occupied", NULL) == 0);
    lv_destroy(lv);
    /* and to the first stop once more, held by the pedestrian, for the stale test */
    lv = lv_create(r, &cfg, &err);
    t = 3000000000000LL;
    CHECK(run_until(lv, &t, LV_STATE_AWAIT_PROCEED, 30, &p) > 0);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_ACCEPTED);
    PLACE(0.0, 0.0, 0.0, 0.0);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    PLACE(0.0, kerb + 5.0, 0.0, 1.0);           /* it has crossed and walks away */
    CHECK(p.state == LV_STATE_DRIVING);
    CHECK(count_events(lv, "crossing_clear", NULL) == 1);
    /* next stop: AGENTS went silent, so the car holds (stale) until they are back */
    CHECK(run_until(lv, &t, LV_STATE_AWAIT_PROCEED, 60, &p) > 0);
    CHECK_NEAR(p.dist, r->stops[1].s - 4.0, 1e-9);
    CHECK(lv_on_input(lv, t, "proceed", 1) == LV_INPUT_ACCEPTED);
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    CHECK(count_events(lv, "agents_stale", NULL) == 1);
    CHECK(lv_on_agents(lv, t, NULL, 0, &err) == 0);
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_DRIVING);
    /* time may not go back */
    CHECK(lv_step(lv, t - 1, &p, &err) == -1);
    CHECK_CONTAINS(err.msg, "time went back");
    lv_destroy(lv);

    /* require_agents: no AGENTS at all holds the car at the first crossing */
    cfg.require_agents = 1;
    lv = lv_create(r, &cfg, &err);
    t = 0;
    CHECK(run_until(lv, &t, LV_STATE_AWAIT_PROCEED, 30, &p) > 0);
    lv_on_input(lv, t, "proceed", 1);
    t += 10000;
    lv_step(lv, t, &p, NULL);
    CHECK(p.state == LV_STATE_AWAIT_CLEAR);
    CHECK(count_events(lv, "agents_missing", NULL) == 1);
    lv_destroy(lv);

    /* one lap from 0 ends at rest exactly at the start point */
    lv_config_default(&cfg);
    lv = lv_create(r, &cfg, &err);
    t = 0;
    int stops = 0;
    for (int guard = 0; guard < 100000; guard++) {
        t += 10000;
        lv_step(lv, t, &p, NULL);
        if (p.state == LV_STATE_AWAIT_PROCEED) { stops++; lv_on_input(lv, t, "proceed", 1); }
        if (p.state == LV_STATE_FINISHED) break;
    }
    CHECK(stops == r->nstops);
    CHECK(p.state == LV_STATE_FINISHED && p.v == 0);
    CHECK_NEAR(p.dist, r->length, 1e-9);
    lv_destroy(lv);

    /* bad configs */
    lv_config_default(&cfg);
    cfg.agents_timeout_s = 0;
    CHECK(lv_create(r, &cfg, &err) == NULL);
    CHECK_CONTAINS(err.msg, "agents_timeout_s");
    lv_config_default(&cfg);
    cfg.profile = 7;
    CHECK(lv_create(r, &cfg, &err) == NULL);
    lv_config_default(&cfg);
    cfg.start_s = INFINITY;
    CHECK(lv_create(r, &cfg, &err) == NULL);
}

int main(void)
{
    pb_route_t r;
    pb_err_t err;
    if (pb_route_load(PB_SOURCE_DIR "/maps/default/route.yaml", &r, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    test_legs(&r);
    test_state_machine(&r);
    pb_route_free(&r);
    return pb_check_report("test_lab_vehicle");
}
