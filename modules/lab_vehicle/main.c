/* lab_vehicle: the in-lab twin of the study car. The shell: options, site and
 * vehicle files, the live / replay bus or the offline log writer. */
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "lab_vehicle/core/lab_vehicle.h"
#include "pb_bus.h"
#include "pb_log.h"
#include "pb_opt.h"
#include "pb_route.h"
#include "pb_signal.h"
#include "pb_site.h"
#include "pb_ground.h"
#include "pb_math.h"
#include "pb_status.h"
#include "pb_vehicle.h"
#include "portobello_agents_t.h"
#include "portobello_participant_input_t.h"
#include "portobello_pose_t.h"
#include "portobello_scenario_event_t.h"
#include "portobello_status_t.h"

#ifndef PB_SOURCE_DIR
#define PB_SOURCE_DIR "."
#endif

#define PROG "lab_vehicle"
#define TICK_US 10000                       /* POSE at 100 Hz */
#define DEFAULT_START_UTIME 1714572000000000LL  /* 2024-05-01T14:00:00Z, simdrive's epoch */

static void usage(FILE *f)
{
    fprintf(f,
        "usage: lab_vehicle [--site DIR] [--vehicle FILE] [--speed-profile P] [options]\n"
        "         live: publishes on the bus (default)\n"
        "       lab_vehicle --out LOG [--auto-proceed S] [--duration S | --laps N] [options]\n"
        "         offline: writes a whole lab drive to LOG, no bus\n"
        "       lab_vehicle --replay IN.lcm --out OUT.lcm [options]\n"
        "         replay: PARTICIPANT_INPUT and AGENTS from IN, time from IN\n"
        "\n"
        "The in-lab twin vehicle: drives the site's route with a speed profile, comes to\n"
        "rest at every stop line with the front bumper --stop-gap behind it (where\n"
        "simdrive's road car rests), announces LAB_EVENT awaiting_proceed, and departs\n"
        "once PARTICIPANT_INPUT \"proceed\" was pressed and the crosswalk ahead is clear\n"
        "of AGENTS. Publishes POSE (source LAB, status TRACKING) and GROUND_TRUTH (the\n"
        "same pose) at 100 Hz, LAB_EVENT (scenario_event_t, kind \"lab\") and STATUS.\n"
        "\n"
        "  --site DIR            site folder (default %s/maps/default)\n"
        "  --vehicle FILE        vehicle file (default %s/vehicles/prius2017.yaml)\n"
        "  --speed-profile P     cautious, normal (default) or aggressive (route.yaml)\n"
        "  --out LOG             offline: write the drive to LOG (with --replay: replay output)\n"
        "  --auto-proceed S      offline: the participant presses proceed S s after each\n"
        "                        stop (default 2.0)\n"
        "  --duration S          end after S s (offline: instead of one lap; live: exit)\n"
        "  --laps N              end at rest at the start point after N laps (offline\n"
        "                        default 1; live default 0 = drive on)\n"
        "  --start-utime US      offline: time of the first pose, us since epoch\n"
        "                        (default %lld, so runs are byte-identical)\n"
        "  --start-s M           start at rest at arc length M of the route (default 0)\n"
        "  --depart-delay S      rest at the start before moving off (default 1.0)\n"
        "  --stop-gap M          front bumper behind the stop line at rest (default 0.5)\n"
        "  --proceed-input NAME  PARTICIPANT_INPUT.input that releases the car (default proceed)\n"
        "  --crossing-margin M   the crosswalk area grows by M along the road on both sides\n"
        "                        (default 1.0), and the depth of the kerb zone where a\n"
        "                        standing agent is about to cross\n"
        "  --crossing-horizon S  an agent whose straight path enters the crosswalk within\n"
        "                        S s holds the car too (default 2.0)\n"
        "  --agents-timeout S    AGENTS older than S are stale: hold at a crossing (default 1.0)\n"
        "  --require-agents      hold at a crossing until AGENTS have been received\n"
        "  --no-ground-truth     do not publish GROUND_TRUTH\n"
        "  --keyboard            live: Enter on stdin publishes PARTICIPANT_INPUT proceed\n"
        "                        (device keyboard), for an operator or a demo\n"
        "  --replay IN.lcm       replay a log (needs --out)\n"
        "  --lcm-url URL         live bus (default $LCM_DEFAULT_URL or %s)\n"
        "  --quiet               offline: no summary line\n"
        "  -h, --help            this text\n",
        PB_SOURCE_DIR, PB_SOURCE_DIR, (long long)DEFAULT_START_UTIME, PB_DEFAULT_LCM_URL);
}

/* The site's ground model, set once by main: the twin drives on it (NULL: z = 0). */
static struct { pb_ground_t *g; double wheelbase, track; } ground;

static void fill_pose(const lv_pose_t *p, portobello_pose_t *m)
{
    memset(m, 0, sizeof *m);
    m->utime = p->utime;
    /* on the ground model: height and tilt from the ground under the four tyres, so
     * renderers get the heights the road car sees (unknown ground: level at z = 0) */
    double z = 0, roll = 0, pitch = 0;
    if (ground.g && pb_ground_car(ground.g, p->x, p->y, p->yaw, ground.wheelbase, ground.track, &z, &roll, &pitch))
        z = roll = pitch = 0;
    m->position[0] = p->x; m->position[1] = p->y; m->position[2] = z;
    pb_quat_from_rpy(roll, pitch, p->yaw, m->orientation);
    m->velocity[0] = p->v * cos(p->yaw); m->velocity[1] = p->v * sin(p->yaw);
    m->velocity[2] = -p->v * tan(pitch);
    m->angular_velocity[2] = p->omega;
    /* The twin's pose is exact by construction: 1 mm / 1 mrad standard deviations
     * (not zero, which pose_t reserves for "unknown"). */
    for (int i = 0; i < 6; i++) m->covariance[i * 7] = 1e-6;
    m->status = PORTOBELLO_POSE_T_STATUS_TRACKING;
    m->source = PORTOBELLO_POSE_T_SOURCE_LAB;
    m->match_score = NAN;
}

/* LAB_EVENT message of a core event; the strings live in *buf (the caller's). */
typedef struct { char id[32], agent[64], detail[400]; } event_strings_t;

static void fill_event(const lv_event_t *e, const portobello_pose_t *vehicle, const char *scenario,
                       portobello_scenario_event_t *m, event_strings_t *buf)
{
    memset(m, 0, sizeof *m);
    snprintf(buf->id, sizeof buf->id, "%s", e->id);
    snprintf(buf->agent, sizeof buf->agent, "%s", e->agent_id);
    /* detail: "stop_line=sl03 crosswalk=cw03: what happened" (ids only where known) */
    int n = 0;
    if (e->stop_line[0]) n += snprintf(buf->detail + n, sizeof buf->detail - n, "stop_line=%s", e->stop_line);
    if (e->crosswalk[0]) n += snprintf(buf->detail + n, sizeof buf->detail - n, " crosswalk=%s", e->crosswalk);
    snprintf(buf->detail + n, sizeof buf->detail - n, "%s%s", n && e->detail[0] ? ": " : "", e->detail);
    m->utime = e->utime;
    m->scenario = (char *)scenario;
    m->kind = "lab";
    m->event_id = buf->id;
    m->agent_id = buf->agent;
    m->vehicle = *vehicle;
    m->agent_position[0] = e->agent_xy[0];
    m->agent_position[1] = e->agent_xy[1];
    m->detail = buf->detail;
}

/* ---------------------------------------------------------------- live / replay */

typedef struct {
    lab_vehicle_t *lv;
    pb_bus_t *bus;
    pb_status_t *status;
    int ground_truth;
    int64_t end_utime;          /* 0: none (set from the first tick and --duration) */
    double duration;
    char scenario[64];
    int failed;
    int keyboard;               /* 1: Enter on stdin publishes a proceed press */
    const char *proceed_input;
    portobello_pose_t last_pose;
} app_t;

static void publish_events(app_t *a)
{
    lv_event_t e;
    while (lv_next_event(a->lv, &e)) {
        portobello_scenario_event_t m;
        event_strings_t strs;
        fill_event(&e, &a->last_pose, a->scenario, &m, &strs);
        pb_err_t err;
        if (PB_PUBLISH(a->bus, "LAB_EVENT", portobello_scenario_event_t, &m, &err))
            pb_status_error(a->status, "LAB_EVENT: %s", err.msg);
        if (!strcmp(e.id, "awaiting_proceed")) {
            pb_status_count(a->status, "stops", 1);
            pb_status_count(a->status, "awaiting_proceed", 1);   /* a gauge: 1 while waiting */
        } else if (!strcmp(e.id, "proceed")) {
            pb_status_count(a->status, "awaiting_proceed", -1);
            pb_status_count(a->status, "proceeds_accepted", 1);
        } else if (!strcmp(e.id, "crossing_occupied")) {
            pb_status_count(a->status, "holds_crossing_occupied", 1);
        } else if (!strcmp(e.id, "agents_stale") || !strcmp(e.id, "agents_missing")) {
            pb_status_count(a->status, !strcmp(e.id, "agents_stale") ? "holds_agents_stale" : "holds_agents_missing", 1);
            pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_DEGRADED);
            pb_status_error(a->status, "%s at %s: %s", e.id, e.stop_line, e.detail);
        } else if (!strcmp(e.id, "crossing_clear") || !strcmp(e.id, "departed")) {
            pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_OK);
        }
        if (!pb_bus_is_replay(a->bus))
            fprintf(stderr, PROG ": %s %s%s%s\n", e.id, e.stop_line, e.detail[0] ? ": " : "", e.detail);
    }
}

/* --keyboard: every line on stdin is a proceed press, published on the bus like a
 * wheel button's (the director sees it too; this module gets it back from LCM). */
static void poll_keyboard(app_t *a, int64_t now)
{
    struct pollfd pfd = { .fd = 0, .events = POLLIN };
    if (poll(&pfd, 1, 0) <= 0) return;
    char buf[256];
    ssize_t n = read(0, buf, sizeof buf);
    if (n <= 0) { a->keyboard = 0; return; }      /* end of input: stop polling */
    for (ssize_t i = 0; i < n; i++) {
        if (buf[i] != '\n') continue;
        portobello_participant_input_t in = { .utime = now, .input = (char *)a->proceed_input,
                                              .device = "keyboard", .value = 1 };
        pb_err_t err;
        if (PB_PUBLISH(a->bus, "PARTICIPANT_INPUT", portobello_participant_input_t, &in, &err))
            pb_status_error(a->status, "PARTICIPANT_INPUT: %s", err.msg);
    }
}

static void on_tick(int64_t now, void *user)
{
    app_t *a = user;
    if (a->failed) return;
    if (a->keyboard) poll_keyboard(a, now);
    if (a->duration > 0 && !a->end_utime) a->end_utime = now + (int64_t)llround(a->duration * 1e6);
    lv_pose_t p;
    pb_err_t err;
    if (lv_step(a->lv, now, &p, &err)) {
        a->failed = 1;
        pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_ERROR);
        pb_status_error(a->status, "%s", err.msg);
        pb_bus_stop(a->bus);
        return;
    }
    fill_pose(&p, &a->last_pose);
    if (PB_PUBLISH(a->bus, "POSE", portobello_pose_t, &a->last_pose, &err))
        pb_status_error(a->status, "POSE: %s", err.msg);
    if (a->ground_truth && PB_PUBLISH(a->bus, "GROUND_TRUTH", portobello_pose_t, &a->last_pose, &err))
        pb_status_error(a->status, "GROUND_TRUTH: %s", err.msg);
    publish_events(a);
    if (a->end_utime && now >= a->end_utime) pb_bus_stop(a->bus);
}

static void on_input(const pb_msg_t *msg, void *user)
{
    app_t *a = user;
    portobello_participant_input_t in;
    if (PB_STATUS_DECODE(a->status, msg, portobello_participant_input_t, &in, "undecodable_PARTICIPANT_INPUT")) return;
    int r = lv_on_input(a->lv, in.utime, in.input, in.value);
    if (r != LV_INPUT_ACCEPTED) {
        char name[64];
        snprintf(name, sizeof name, "inputs_ignored_%s", lv_input_results[r]);
        pb_status_count(a->status, name, 1);
        if (r == LV_INPUT_NOT_WAITING || r == LV_INPUT_EARLY)
            pb_status_error(a->status, "PARTICIPANT_INPUT \"%s\" ignored: %s", in.input,
                            r == LV_INPUT_EARLY ? "stamped before the car came to rest" : "the car is not waiting for it");
    }
    portobello_participant_input_t_decode_cleanup(&in);
    publish_events(a);
}

static void on_agents(const pb_msg_t *msg, void *user)
{
    app_t *a = user;
    portobello_agents_t m;
    if (PB_STATUS_DECODE(a->status, msg, portobello_agents_t, &m, "undecodable_AGENTS")) return;
    lv_agent_t *ag = calloc(m.nagents + 1, sizeof *ag);
    for (int i = 0; i < m.nagents; i++) {
        ag[i].id = m.agents[i].id;
        ag[i].kind = m.agents[i].kind;
        ag[i].x = m.agents[i].position[0];
        ag[i].y = m.agents[i].position[1];
        ag[i].vx = m.agents[i].velocity[0];
        ag[i].vy = m.agents[i].velocity[1];
    }
    pb_err_t err;
    /* Staleness runs on the bus clock (receive time live, log time in replay). */
    if (lv_on_agents(a->lv, pb_bus_now(a->bus), ag, m.nagents, &err)) {
        pb_status_count(a->status, "rejected_agents_nonfinite", 1);
        pb_status_error(a->status, "AGENTS: %s", err.msg);   /* no utime: printed once, not per message */
    } else {
        snprintf(a->scenario, sizeof a->scenario, "%s", m.scenario);
    }
    free(ag);
    portobello_agents_t_decode_cleanup(&m);
}

static int run_bus(lab_vehicle_t *lv, const char *url, const char *in, const char *out, int ground_truth, double duration,
                   int keyboard, const char *proceed_input)
{
    pb_err_t err;
    pb_bus_t *bus = in ? pb_bus_create_replay(in, out, &err) : pb_bus_create_live(url, &err);
    if (!bus) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    pb_signal_install();
    app_t a = { .lv = lv, .bus = bus, .ground_truth = ground_truth, .duration = duration,
                .keyboard = keyboard, .proceed_input = proceed_input };
    a.status = pb_status_create(bus, PROG, 1000000);
    pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_OK);
    pb_bus_subscribe(bus, "PARTICIPANT_INPUT", on_input, &a);
    pb_bus_subscribe(bus, "AGENTS", on_agents, &a);
    pb_bus_add_timer(bus, TICK_US, on_tick, &a);
    if (!in) fprintf(stderr, PROG ": driving on %s; POSE at 100 Hz;%s Ctrl-C stops\n", pb_lcm_url(url),
                     keyboard ? " Enter = proceed;" : "");
    int rc = pb_bus_run(bus, &err);
    if (rc || !a.failed) pb_status_finish(a.status, rc ? err.msg : NULL);
    else pb_status_publish(a.status);   /* the failure's STATUS is set */
    pb_status_destroy(a.status);
    pb_bus_destroy(bus);
    return rc || a.failed ? 1 : 0;
}

/* ---------------------------------------------------------------- offline */

static int run_offline(lab_vehicle_t *lv, const char *path, int64_t start_utime, double auto_proceed,
                       double duration, int ground_truth, int quiet)
{
    pb_err_t err;
    pb_log_out_t o = { 0 };
    o.log = pb_log_open_write(path, &err);
    if (!o.log) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    int64_t end = duration > 0 ? start_utime + (int64_t)llround(duration * 1e6) : INT64_MAX;
    int64_t press = INT64_MAX;      /* next simulated proceed press */
    int64_t nposes = 0, nstops = 0;
    double d_start = 0;
    portobello_pose_t pm;
    lv_pose_t p = { 0 };
    int rc = 0;
    for (int64_t k = 0;; k++) {
        int64_t t = start_utime + k * TICK_US;
        if (t > end) break;
        if (press <= t) {
            portobello_participant_input_t in = { .utime = press, .input = "proceed", .device = "auto_proceed", .value = 1 };
            PB_LOG_WRITE_MSG(&o, "PARTICIPANT_INPUT", portobello_participant_input_t, &in);
            lv_on_input(lv, press, in.input, in.value);
            press = INT64_MAX;
        }
        if (lv_step(lv, t, &p, &err)) { fprintf(stderr, PROG ": %s\n", err.msg); rc = 1; break; }
        if (k == 0) d_start = p.dist;
        fill_pose(&p, &pm);
        PB_LOG_WRITE_MSG(&o, "POSE", portobello_pose_t, &pm);
        if (ground_truth) PB_LOG_WRITE_MSG(&o, "GROUND_TRUTH", portobello_pose_t, &pm);
        nposes++;
        lv_event_t e;
        while (lv_next_event(lv, &e)) {
            portobello_scenario_event_t m;
            event_strings_t strs;
            fill_event(&e, &pm, "", &m, &strs);
            PB_LOG_WRITE_MSG(&o, "LAB_EVENT", portobello_scenario_event_t, &m);
            if (!strcmp(e.id, "awaiting_proceed")) {
                press = e.utime + (int64_t)llround(auto_proceed * 1e6);
                nstops++;
            }
        }
        if (o.failed || p.state == LV_STATE_FINISHED) break;
    }
    if (o.failed) { fprintf(stderr, PROG ": %s\n", o.err.msg); rc = 1; }
    if (pb_log_close(o.log, &err)) { fprintf(stderr, PROG ": %s\n", err.msg); rc = 1; }
    free(o.buf);
    if (!rc && !quiet)
        fprintf(stderr, PROG ": %.2f s, %.1f m, %lld stops, %lld poses, %s -> %s\n",
                (p.utime - start_utime) * 1e-6, p.dist - d_start, (long long)nstops, (long long)nposes,
                p.state == LV_STATE_FINISHED ? "finished at rest" : "ended at --duration", path);
    return rc;
}

/* --proceed-input: a word that fits lv_config_t.proceed_input */
static int parse_proceed_input(const char *prog, const char *arg, void *var)
{
    size_t cap = sizeof ((lv_config_t *)0)->proceed_input;
    if (!*arg || strlen(arg) >= cap) {
        fprintf(stderr, "%s: --proceed-input: expected 1 to %zu characters, got '%s'\n", prog, cap - 1, arg);
        return -1;
    }
    snprintf(var, cap, "%s", arg);
    return 0;
}

int main(int argc, char **argv)
{
    const char *site_dir = PB_SOURCE_DIR "/maps/default", *veh_path = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    const char *out = NULL, *in = NULL, *url = NULL;
    double auto_proceed = -1, duration = 0;   /* auto_proceed < 0: not given (2 s offline) */
    long laps = -1, start_utime = DEFAULT_START_UTIME;
    int ground_truth = 1, quiet = 0, keyboard = 0;
    lv_config_t cfg;
    lv_config_default(&cfg);
    const pb_opt_t opts[] = {
        PB_OPT_STRING("site", &site_dir), PB_OPT_STRING("vehicle", &veh_path), PB_OPT_CHOICE("speed-profile", &cfg.profile, pb_profile_names, PB_PROFILE_COUNT),
        PB_OPT_STRING("out", &out), PB_OPT_DOUBLE("auto-proceed", &auto_proceed, 0, 86400),
        PB_OPT_DOUBLE("duration", &duration, 0.01, 7 * 86400), PB_OPT_LONG("laps", &laps, 0, 100000),
        PB_OPT_LONG("start-utime", &start_utime, 0, LONG_MAX / 2), PB_OPT_DOUBLE("start-s", &cfg.start_s, -1e7, 1e7),
        PB_OPT_DOUBLE("depart-delay", &cfg.depart_delay_s, 0, 86400), PB_OPT_DOUBLE("stop-gap", &cfg.stop_gap_m, -2, 20),
        PB_OPT_CALL("proceed-input", parse_proceed_input, cfg.proceed_input),
        PB_OPT_DOUBLE("crossing-margin", &cfg.crossing_margin_m, 0, 100),
        PB_OPT_DOUBLE("agents-timeout", &cfg.agents_timeout_s, 0.001, 86400),
        PB_OPT_FLAG("require-agents", &cfg.require_agents, 1), PB_OPT_FLAG("no-ground-truth", &ground_truth, 0),
        PB_OPT_STRING("replay", &in), PB_OPT_STRING("lcm-url", &url), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_FLAG("keyboard", &keyboard, 1), PB_OPT_DOUBLE("crossing-horizon", &cfg.crossing_horizon_s, 0, 60),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse(PROG, opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if (in && !out) { fprintf(stderr, PROG ": --replay needs --out OUT.lcm\n"); return 2; }
    int offline = out && !in;
    if (auto_proceed >= 0 && !offline) { fprintf(stderr, PROG ": --auto-proceed is for the offline drive (--out LOG without --replay)\n"); return 2; }
    if (keyboard && (offline || in)) { fprintf(stderr, PROG ": --keyboard is for the live bus\n"); return 2; }
    if (offline && url) { fprintf(stderr, PROG ": --lcm-url has no effect offline (--out without --replay)\n"); return 2; }
    if (offline && duration > 0 && laps >= 0) { fprintf(stderr, PROG ": --duration and --laps exclude each other offline\n"); return 2; }
    if (offline && laps == 0 && duration <= 0) { fprintf(stderr, PROG ": --laps 0 offline never ends; give --duration S\n"); return 2; }
    if (auto_proceed < 0) auto_proceed = 2.0;
    cfg.laps = laps >= 0 ? (int)laps : offline && duration <= 0 ? 1 : 0;

    pb_err_t err;
    pb_vehicle_t veh;
    pb_site_t site;
    pb_route_t route;
    if (pb_vehicle_load(veh_path, &veh, &err) || pb_site_load(site_dir, &site, &err)) {
        fprintf(stderr, PROG ": %s\n", err.msg);
        return 1;
    }
    if (pb_route_load(site.route_path, &route, &err)) { fprintf(stderr, PROG ": %s\n", err.msg); return 1; }
    if (access(site.ground_path, R_OK) == 0) {
        ground.g = pb_ground_load(site.ground_path, &err);
        if (!ground.g) { fprintf(stderr, PROG ": %s\n", err.msg); pb_route_free(&route); return 1; }
        ground.wheelbase = veh.wheelbase;
        ground.track = 0.5 * (veh.track_front + veh.track_rear);
    } else {
        fprintf(stderr, PROG ": warning: %s: no ground model (make builds it); driving at z = 0\n", site.ground_path);
    }
    cfg.base_to_front_m = veh.length - veh.rear_overhang;
    lab_vehicle_t *lv = lv_create(&route, &cfg, &err);
    if (!lv) { fprintf(stderr, PROG ": %s\n", err.msg); pb_route_free(&route); return 1; }
    int rc = offline ? run_offline(lv, out, start_utime, auto_proceed, duration, ground_truth, quiet)
                     : run_bus(lv, url, in, out, ground_truth, duration, keyboard, cfg.proceed_input);
    lv_destroy(lv);
    pb_ground_destroy(ground.g);
    pb_route_free(&route);
    return rc;
}
