/* director: runs a scenario against the vehicle's pose (shell around core/director.c).
 *   director --site SITE_DIR --scenario FILE [--replay IN.lcm --out OUT.lcm]
 * POSE (or --pose-channel) + PARTICIPANT_INPUT in; AGENTS (--rate Hz) and
 * SCENARIO_EVENT out; STATUS heartbeat. See docs/director.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "core/director.h"
#include "core/agents_msg.h"
#include "pb_bus.h"
#include "pb_opt.h"
#include "pb_route.h"
#include "pb_signal.h"
#include "pb_site.h"
#include "pb_status.h"
#include "pb_vehicle.h"
#include "portobello_agents_t.h"
#include "portobello_participant_input_t.h"
#include "portobello_pose_t.h"
#include "portobello_scenario_event_t.h"
#include "portobello_status_t.h"
#include "core/scenario.h"

typedef struct {
    pb_bus_t *bus;
    pb_status_t *status;
    director_t *dir;
    sc_scenario_t sc;
    const char *pose_channel, *state_path;
    double stale_s;
    int64_t period_us;
    int64_t last_pose_recv, last_pose_utime, started;
    int64_t last_state_write;
    int have_pose, state_dirty, warned_missing;
    dir_agent_out_t *out;
    portobello_agent_t *agents;
} app_t;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: director --site SITE_DIR --scenario FILE [--replay IN.lcm --out OUT.lcm] [options]\n"
            "Runs a study scenario (docs/scenarios.md) against the vehicle's pose: fires its triggers\n"
            "when the car's footprint and motion meet their conditions, moves its agents, reports\n"
            "virtual collisions. Subscribes POSE (or --pose-channel) and PARTICIPANT_INPUT; publishes\n"
            "AGENTS, SCENARIO_EVENT and STATUS.\n"
            "  --site DIR          site folder (site.yaml, route.yaml)\n"
            "  --scenario FILE     scenario file; a bare name is looked up in SITE_DIR/scenarios/\n"
            "  --vehicle FILE      vehicle file for the car's box (default %s/vehicles/prius2017.yaml)\n"
            "  --pose-channel CH   vehicle pose channel (default POSE; GROUND_TRUTH for simdrive logs)\n"
            "  --rate HZ           AGENTS rate, 30 to 90 (default 60)\n"
            "  --stale-s S         POSE older than this holds synchronised agents (default 0.5)\n"
            "  --state FILE        recovery file: read at start if present, rewritten on every\n"
            "                      trigger and once a second (a restart fires no trigger twice)\n"
            "  --replay IN.lcm     read a log (time from the log) ...\n"
            "  --out OUT.lcm       ... and write what the director publishes here\n"
            "  --lcm-url URL       live bus (default $LCM_DEFAULT_URL or %s)\n"
            "  --check             load and validate everything, then exit (0 = ready)\n"
            "  -h, --help          this text\n",
            PB_SOURCE_DIR, PB_DEFAULT_LCM_URL);
}

static void write_state(app_t *a)
{
    if (!a->state_path) return;
    static char buf[1 << 20];
    int n = dir_state_write(a->dir, buf, sizeof buf);
    if (n < 0) { pb_status_error(a->status, "state: larger than 1 MB, not written"); return; }
    char tmp[1100];
    snprintf(tmp, sizeof tmp, "%s.tmp", a->state_path);
    FILE *f = fopen(tmp, "w");
    if (!f || fwrite(buf, 1, n, f) != (size_t)n || fflush(f) != 0 || fsync(fileno(f)) != 0) {
        pb_status_count(a->status, "state_write_failed", 1);
        pb_status_error(a->status, "%s: %s", tmp, strerror(errno));
        if (f) fclose(f);
        return;
    }
    fclose(f);
    if (rename(tmp, a->state_path) != 0) {
        pb_status_count(a->status, "state_write_failed", 1);
        pb_status_error(a->status, "%s: %s", a->state_path, strerror(errno));
    }
    a->state_dirty = 0;
}

static void on_event(const dir_event_t *ev, void *user)
{
    app_t *a = user;
    portobello_scenario_event_t m;
    memset(&m, 0, sizeof m);
    m.utime = ev->utime;
    m.scenario = a->sc.id;
    m.kind = (char *)ev->kind;
    m.event_id = (char *)ev->event_id;
    m.agent_id = (char *)ev->agent_id;
    m.vehicle.utime = ev->vehicle.utime;
    memcpy(m.vehicle.position, ev->vehicle.pos, sizeof m.vehicle.position);
    memcpy(m.vehicle.orientation, ev->vehicle.q, sizeof m.vehicle.orientation);
    memcpy(m.vehicle.velocity, ev->vehicle.vel, sizeof m.vehicle.velocity);
    m.vehicle.status = PORTOBELLO_POSE_T_STATUS_TRACKING;
    m.vehicle.match_score = NAN;
    memcpy(m.agent_position, ev->agent_pos, sizeof m.agent_position);
    m.detail = (char *)ev->detail;
    pb_err_t err;
    if (PB_PUBLISH(a->bus, "SCENARIO_EVENT", portobello_scenario_event_t, &m, &err))
        pb_status_error(a->status, "SCENARIO_EVENT: %s", err.msg);
    char counter[32];
    snprintf(counter, sizeof counter, "events_%s", ev->kind);
    pb_status_count(a->status, counter, 1);
    if (!strcmp(ev->kind, "warning")) pb_status_error(a->status, "%s: %s", ev->event_id, ev->detail);
    if (!strcmp(ev->kind, "trigger") || !strcmp(ev->kind, "mark")) a->state_dirty = 1;
}

static void on_pose(const pb_msg_t *msg, void *user)
{
    app_t *a = user;
    portobello_pose_t p;
    if (PB_STATUS_DECODE(a->status, msg, portobello_pose_t, &p, "undecodable_pose")) return;
    if (p.status == PORTOBELLO_POSE_T_STATUS_LOST || p.status == PORTOBELLO_POSE_T_STATUS_INITIALIZING) {
        pb_status_count(a->status, "pose_not_tracking", 1);
        return;     /* not a usable pose: it does not refresh the staleness clock either */
    }
    dir_pose_t dp = { .utime = p.utime };
    memcpy(dp.pos, p.position, sizeof dp.pos);
    memcpy(dp.q, p.orientation, sizeof dp.q);
    memcpy(dp.vel, p.velocity, sizeof dp.vel);
    pb_err_t err;
    if (dir_is_stale(a->dir)) dir_set_stale(a->dir, 0, p.utime, 0);
    if (dir_pose(a->dir, &dp, &err)) {
        pb_status_count(a->status, "rejected_pose", 1);
        pb_status_error(a->status, "%s: %s", msg->channel, err.msg);
        return;
    }
    pb_status_count(a->status, "poses", 1);
    a->last_pose_recv = msg->recv_utime;
    a->last_pose_utime = p.utime;
    a->have_pose = 1;
    if (a->state_dirty) write_state(a);
}

static void on_input(const pb_msg_t *msg, void *user)
{
    app_t *a = user;
    portobello_participant_input_t in;
    if (PB_STATUS_DECODE(a->status, msg, portobello_participant_input_t, &in, "undecodable_input")) return;
    dir_input(a->dir, in.utime, in.input, in.value);
    pb_status_count(a->status, "inputs", 1);
    portobello_participant_input_t_decode_cleanup(&in);
}

/* AGENTS at the configured rate; between poses the agents move on message time
 * extrapolated from the last pose. Also the POSE watchdog. */
static void on_timer(int64_t now, void *user)
{
    app_t *a = user;
    if (!a->started) a->started = now;
    if (!a->have_pose) {
        if (!a->warned_missing && (now - a->started) * 1e-6 > a->stale_s) {
            pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_DEGRADED);
            pb_status_error(a->status, "no %s yet: agents wait for the vehicle pose", a->pose_channel);
            a->warned_missing = 1;
        }
        return;
    }
    double age = (now - a->last_pose_recv) * 1e-6;
    if (age > a->stale_s && !dir_is_stale(a->dir)) {
        dir_set_stale(a->dir, 1, a->last_pose_utime, age);
        pb_status_count(a->status, "pose_stale", 1);
        pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_DEGRADED);
        pb_status_error(a->status, "%s stale for %.2f s: synchronised agents held", a->pose_channel, age);
    } else if (!dir_is_stale(a->dir)) {
        pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_OK);
    }
    int64_t t = a->last_pose_utime + (now - a->last_pose_recv);
    dir_tick(a->dir, t);
    int n = dir_agents(a->dir, a->out);
    dir_agents_to_msg(a->out, n, a->agents);
    portobello_agents_t m = { .utime = dir_time(a->dir), .scenario = a->sc.id, .nagents = n, .agents = a->agents };
    pb_err_t err;
    if (PB_PUBLISH(a->bus, "AGENTS", portobello_agents_t, &m, &err)) pb_status_error(a->status, "AGENTS: %s", err.msg);
    if (a->state_path && (a->state_dirty || now - a->last_state_write >= 1000000)) {
        write_state(a);
        a->last_state_write = now;
    }
}

static int file_exists(const char *p)
{
    struct stat st;
    return stat(p, &st) == 0 && S_ISREG(st.st_mode);
}

int main(int argc, char **argv)
{
    const char *url = NULL, *in = NULL, *out = NULL, *site_dir = NULL, *scenario = NULL;
    const char *vehicle_path = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    app_t a = { .pose_channel = "POSE", .stale_s = 0.5 };
    double rate = 60;
    int check_only = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("site", &site_dir), PB_OPT_REQUIRED("scenario", &scenario),
        PB_OPT_STRING("vehicle", &vehicle_path), PB_OPT_STRING("pose-channel", &a.pose_channel),
        PB_OPT_DOUBLE("rate", &rate, 30, 90), PB_OPT_DOUBLE("stale-s", &a.stale_s, 0.05, 60),
        PB_OPT_STRING("state", &a.state_path), PB_OPT_STRING("replay", &in), PB_OPT_STRING("out", &out),
        PB_OPT_STRING("lcm-url", &url), PB_OPT_FLAG("check", &check_only, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("director", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if ((in != NULL) != (out != NULL)) { fprintf(stderr, "director: --replay and --out go together\n"); return 2; }

    /* Everything is loaded and checked before the bus opens: nothing starts half-configured. */
    pb_err_t err;
    pb_site_t site;
    pb_route_t route;
    pb_vehicle_t veh;
    if (pb_site_load(site_dir, &site, &err)) { fprintf(stderr, "director: %s\n", err.msg); return 1; }
    if (pb_route_load(site.route_path, &route, &err)) { fprintf(stderr, "director: %s\n", err.msg); return 1; }
    if (pb_vehicle_load(vehicle_path, &veh, &err)) { fprintf(stderr, "director: %s\n", err.msg); pb_route_free(&route); return 1; }
    char sc_path[2200];
    if (!strchr(scenario, '/') && !file_exists(scenario))
        snprintf(sc_path, sizeof sc_path, "%s/scenarios/%s%s", site_dir, scenario, strstr(scenario, ".yaml") ? "" : ".yaml");
    else
        snprintf(sc_path, sizeof sc_path, "%s", scenario);
    if (sc_load(sc_path, &route, &a.sc, &err)) { fprintf(stderr, "director: %s\n", err.msg); pb_route_free(&route); return 1; }
    dir_vehicle_t dv = { veh.length, veh.width, veh.height, veh.rear_overhang };
    a.dir = dir_create(&a.sc, &route, &dv, on_event, &a, &err);
    if (!a.dir) { fprintf(stderr, "director: %s\n", err.msg); sc_free(&a.sc); pb_route_free(&route); return 1; }
    /* the ground model: agents stand on it, volume heights count from it */
    pb_ground_t *ground = NULL;
    if (file_exists(site.ground_path)) {
        ground = pb_ground_load(site.ground_path, &err);
        if (!ground) { fprintf(stderr, "director: %s\n", err.msg); dir_destroy(a.dir); sc_free(&a.sc); pb_route_free(&route); return 1; }
        dir_set_ground(a.dir, ground);
    } else {
        fprintf(stderr, "director: warning: %s: no ground model (make builds it); the ground is taken as z = 0\n",
                site.ground_path);
    }
    if (a.state_path && file_exists(a.state_path)) {
        FILE *f = fopen(a.state_path, "r");
        static char buf[1 << 20];
        size_t n = f ? fread(buf, 1, sizeof buf - 1, f) : 0;
        if (f) fclose(f);
        buf[n] = 0;
        if (!f || dir_state_read(a.dir, buf, &err)) {
            fprintf(stderr, "director: %s: %s\n", a.state_path, f ? err.msg : strerror(errno));
            dir_destroy(a.dir); pb_ground_destroy(ground); sc_free(&a.sc); pb_route_free(&route);
            return 1;
        }
        fprintf(stderr, "director: recovered %d fired trigger(s) from %s\n", dir_triggers_fired(a.dir), a.state_path);
    }
    if (check_only) {
        printf("%s: scenario %s: %d volumes, %d agents, %d behaviours, %d triggers: ok\n", sc_path, a.sc.id, a.sc.nvolumes,
               a.sc.nagents, a.sc.nbehaviours, a.sc.ntriggers);
        dir_destroy(a.dir); pb_ground_destroy(ground); sc_free(&a.sc); pb_route_free(&route);
        return 0;
    }
    a.out = calloc(a.sc.nagents + 1, sizeof *a.out);
    a.agents = calloc(a.sc.nagents + 1, sizeof *a.agents);
    a.bus = in ? pb_bus_create_replay(in, out, &err) : pb_bus_create_live(url, &err);
    if (!a.bus) { fprintf(stderr, "director: %s\n", err.msg); return 1; }
    pb_signal_install();
    a.status = pb_status_create(a.bus, "director", 1000000);
    pb_status_set_state(a.status, PORTOBELLO_STATUS_T_STATE_STARTING);
    a.period_us = (int64_t)llround(1e6 / rate);
    pb_bus_subscribe(a.bus, a.pose_channel, on_pose, &a);
    pb_bus_subscribe(a.bus, "PARTICIPANT_INPUT", on_input, &a);
    pb_bus_add_timer(a.bus, a.period_us, on_timer, &a);
    if (!in) fprintf(stderr, "director: scenario %s on %s, pose from %s\n", a.sc.id, pb_lcm_url(url), a.pose_channel);

    int rc = pb_bus_run(a.bus, &err);
    write_state(&a);
    pb_status_finish(a.status, rc ? err.msg : NULL);
    if (in) fprintf(stderr, "director: %d of %d triggers fired\n", dir_triggers_fired(a.dir), a.sc.ntriggers);
    pb_status_destroy(a.status);
    pb_bus_destroy(a.bus);
    dir_destroy(a.dir);
    pb_ground_destroy(ground);
    free(a.out); free(a.agents);
    sc_free(&a.sc);
    pb_route_free(&route);
    return rc == 0 ? 0 : 1;
}
