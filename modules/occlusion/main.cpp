/* occlusion: which parts of each virtual agent real objects hide from the participant.
 *   occlusion [--replay IN.lcm --out OUT.lcm] [--pose-channel CH] [--vehicle FILE]
 * Thin shell around core/occlusion: options, vehicle file, subscribe, decode, publish
 * OCCLUSION, STATUS heartbeat, signals. */
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "core/occlusion.h"
#include "occ_message.h"
#include "pb_bus.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_status.h"
#include "pb_vehicle.h"
#include "portobello_agents_t.h"
#include "pb_clock.h"
#include "portobello_head_pose_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_occlusion_t.h"
#include "portobello_pose_t.h"
#include "portobello_status_t.h"

struct app_t {
    pb_bus_t *bus = nullptr;
    pb_status_t *status = nullptr;
    occlusion_t *occ = nullptr;
    pb_points_t pts = {};
    std::vector<occ_output_t> out;
    std::vector<occ_event_t> ev;
    FILE *stats = nullptr;
    int64_t published = 0;
    std::vector<double> integrate_ms, query_ms;
    bool degraded = false;
};

static void usage(FILE *f)
{
    fprintf(f,
            "usage: occlusion [--replay IN.lcm --out OUT.lcm] [--lcm-url URL] [--pose-channel CH]\n"
            "                 [--vehicle FILE] [--range M] [--stats FILE.csv]\n"
            "Hides virtual agents behind real objects the LiDAR sees. Keeps an OctoMap of the\n"
            "occupancy around the car (map frame, rolling window, free space cleared by each\n"
            "sweep), and for every agent of AGENTS in render range asks, for each sample point\n"
            "on its body, what lies between the participant's eye and it: OCCLUSION per sweep\n"
            "(per sample: 0 visible, 1 hidden, 2 unknown; the distance to the occluder; the\n"
            "visible fraction). The eye is HEAD_POSE (head in base) when it is fresh and\n"
            "tracking, else the vehicle file's seat (said in STATUS); a headset whose clock is\n"
            "more than 0.3 s off the car's is measured (its times against the newest POSE or\n"
            "sweep they arrive with), said in STATUS and taken out. Without a usable pose\n"
            "(lost, initializing, missing) every sample is unknown.\n"
            "Inputs: LIDAR_SCAN, POSE (or --pose-channel), HEAD_POSE, AGENTS.\n"
            "  --replay IN.lcm      run on a log as fast as the CPU allows (with --out)\n"
            "  --out OUT.lcm        where the replay writes OCCLUSION and STATUS\n"
            "  --lcm-url URL        live bus (default $LCM_DEFAULT_URL or %s)\n"
            "  --pose-channel CH    the vehicle pose (default POSE; GROUND_TRUTH for simdrive logs)\n"
            "  --vehicle FILE       extrinsics, size and seat (default %s/vehicles/prius2017.yaml)\n"
            "  --range M            occupancy and query range around the car (default 45)\n"
            "  --stats FILE.csv     one line per sweep: utime, integrate and query CPU ms, counts\n"
            "  -h, --help           this text\n",
            PB_DEFAULT_LCM_URL, PB_SOURCE_DIR);
}

/* Publishes what the core produced and reports its events. */
static void flush(app_t *a)
{
    for (const occ_event_t &e : a->ev) {
        pb_status_count(a->status, e.counter.c_str(), 1);
        if (!e.message.empty()) pb_status_error(a->status, "%s", e.message.c_str());
        if (e.counter == "eye_seat_fallback" || e.counter == "eye_lidar_fallback" || e.counter == "sweep_without_pose")
            a->degraded = true;
        if (e.counter == "eye_head" || e.counter == "pose_back") a->degraded = false;
    }
    a->ev.clear();
    for (occ_output_t &r : a->out) {
        std::vector<portobello_agent_occlusion_t> ag;
        portobello_occlusion_t m = occ_message(r, &ag);
        pb_err_t err;
        if (PB_PUBLISH(a->bus, "OCCLUSION", portobello_occlusion_t, &m, &err) != 0) {
            pb_status_count(a->status, "publish_failed", 1);
            pb_status_error(a->status, "OCCLUSION: %s", err.msg);
        }
        a->published++;
        if (r.pose_ok) {
            a->integrate_ms.push_back(r.integrate_ms);
            a->query_ms.push_back(r.query_ms);
        }
        if (a->stats)
            fprintf(a->stats, "%lld,%d,%.3f,%.3f,%d,%d,%d,%d\n", (long long)r.utime, r.pose_ok, r.integrate_ms, r.query_ms,
                    r.integrate.points, r.integrate.hit_voxels, r.integrate.cleared, r.integrate.observed_new);
    }
    a->out.clear();
    pb_status_set_state(a->status, a->degraded ? PORTOBELLO_STATUS_T_STATE_DEGRADED : PORTOBELLO_STATUS_T_STATE_OK);
}

static void on_scan(const pb_msg_t *m, void *user)
{
    app_t *a = (app_t *)user;
    pb_status_take(a->status, m, portobello_lidar_scan_t_decode, portobello_lidar_scan_t_decode_cleanup,
                   [a](const portobello_lidar_scan_t &s) {
                       if (pb_status_scan_points(a->status, &s, &a->pts) >= 0) {
                           /* the sensor's beam gaps, else the config's (64 x 1024): said in STATUS */
                           double ring_gap = 0, col_gap = 0;
                           if (!pb_scan_beam_gaps(&s, &a->pts, &ring_gap, &col_gap))
                               pb_status_count(a->status, "beam_gaps_from_config", 1);
                           occlusion_scan(a->occ, s.utime, &a->pts, ring_gap, col_gap, &a->out, &a->ev);
                       }
                       flush(a);
                   });
}

static void on_pose(const pb_msg_t *m, void *user)
{
    app_t *a = (app_t *)user;
    pb_status_take(a->status, m, portobello_pose_t_decode, portobello_pose_t_decode_cleanup, [a](const portobello_pose_t &s) {
        occ_pose_in_t p;
        p.utime = s.utime;
        memcpy(p.pos, s.position, sizeof p.pos);
        memcpy(p.q, s.orientation, sizeof p.q);
        memcpy(p.vel, s.velocity, sizeof p.vel);
        p.usable = s.status == PORTOBELLO_POSE_T_STATUS_TRACKING || s.status == PORTOBELLO_POSE_T_STATUS_DEGRADED;
        if (!p.usable) pb_status_count(a->status, "pose_not_tracking", 1);
        occlusion_pose(a->occ, &p, &a->out, &a->ev);
        flush(a);
    });
}

static void on_head(const pb_msg_t *m, void *user)
{
    app_t *a = (app_t *)user;
    pb_status_take(a->status, m, portobello_head_pose_t_decode, portobello_head_pose_t_decode_cleanup,
                   [a](const portobello_head_pose_t &s) {
                       if (!s.tracking) pb_status_count(a->status, "head_not_tracking", 1);
                       occlusion_head(a->occ, s.utime, s.position, s.tracking, &a->ev);
                   });
}

static void on_agents(const pb_msg_t *m, void *user)
{
    app_t *a = (app_t *)user;
    pb_status_take(a->status, m, portobello_agents_t_decode, portobello_agents_t_decode_cleanup, [a](const portobello_agents_t &s) {
        std::vector<occ_agent_in_t> ag(s.nagents);
        for (int i = 0; i < s.nagents; i++) {
            const portobello_agent_t &g = s.agents[i];
            occ_agent_in_t &o = ag[i];
            o.id = g.id; o.kind = g.kind;
            memcpy(o.pos, g.position, sizeof o.pos);
            memcpy(o.vel, g.velocity, sizeof o.vel);
            o.yaw = g.yaw_rad;
            o.in_render_range = g.in_render_range;
            if (!std::isfinite(o.pos[0]) || !std::isfinite(o.pos[1]) || !std::isfinite(o.pos[2])) {
                pb_status_count(a->status, "agent_not_finite", 1);
                pb_status_error(a->status, "AGENTS: agent %s has a NaN/inf position: no samples", g.id);
            }
            for (double &v : o.vel) if (!std::isfinite(v)) v = 0;
        }
        occlusion_agents(a->occ, s.utime, ag);
    });
}

static double percentile(std::vector<double> v, double q)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return v[(size_t)std::min<double>(v.size() - 1, std::ceil(q * v.size()) - 1)];
}

int main(int argc, char **argv)
{
    const char *url = nullptr, *in = nullptr, *outp = nullptr, *stats = nullptr, *pose_channel = "POSE";
    const char *vehicle = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    occ_config_t cfg;
    const pb_opt_t opts[] = {
        PB_OPT_STRING("replay", &in), PB_OPT_STRING("out", &outp), PB_OPT_STRING("lcm-url", &url),
        PB_OPT_STRING("pose-channel", &pose_channel), PB_OPT_STRING("vehicle", &vehicle),
        PB_OPT_DOUBLE("range", &cfg.range_m, 5, 50), PB_OPT_STRING("stats", &stats), PB_OPT_END,
    };
    int parsed = pb_opt_parse("occlusion", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    cfg.window_m = cfg.range_m + 1;
    if ((in != nullptr) != (outp != nullptr)) { fprintf(stderr, "occlusion: --replay and --out go together\n"); return 2; }

    pb_err_t err;
    pb_vehicle_t veh;
    if (pb_vehicle_load(vehicle, &veh, &err) != 0) { fprintf(stderr, "occlusion: %s\n", err.msg); return 1; }
    pb_bus_t *bus = in ? pb_bus_create_replay(in, outp, &err) : pb_bus_create_live(url, &err);
    if (!bus) { fprintf(stderr, "occlusion: %s\n", err.msg); return 1; }
    app_t a;
    a.bus = bus;
    if (stats) {
        a.stats = fopen(stats, "w");
        if (!a.stats) { fprintf(stderr, "occlusion: %s: cannot write\n", stats); pb_bus_destroy(bus); return 1; }
        fprintf(a.stats, "utime,pose_ok,integrate_ms,query_ms,points,hit_voxels,cleared,observed_new\n");
    }
    occlusion_vehicle_t ov = {};
    ov.base_from_lidar = veh.base_from_lidar;
    memcpy(ov.seat_eye, veh.seat_eye_xyz, sizeof ov.seat_eye);
    ov.has_seat_eye = veh.has_seat_eye;
    ov.length = veh.length; ov.width = veh.width; ov.height = veh.height; ov.rear_overhang = veh.rear_overhang;
    a.occ = occlusion_create(&cfg, &ov);
    occlusion_set_clock(a.occ, pb_clock_thread_cpu_ms);
    a.status = pb_status_create(bus, "occlusion", 1000000);
    if (!veh.has_seat_eye) pb_status_error(a.status, "%s: no seat.eye_xyz: without HEAD_POSE the eye is the LiDAR", vehicle);
    pb_signal_install();
    pb_bus_subscribe(bus, "LIDAR_SCAN", on_scan, &a);
    pb_bus_subscribe(bus, pose_channel, on_pose, &a);
    pb_bus_subscribe(bus, "HEAD_POSE", on_head, &a);
    pb_bus_subscribe(bus, "AGENTS", on_agents, &a);
    if (!in) fprintf(stderr, "occlusion: listening on %s\n", pb_lcm_url(url));

    int rc = pb_bus_run(bus, &err);
    occlusion_finish(a.occ, &a.out, &a.ev);
    flush(&a);
    pb_status_finish(a.status, rc ? err.msg : NULL);
    int64_t leaves, bytes;
    occ_map_size(occlusion_map(a.occ), &leaves, &bytes);
    fprintf(stderr, "occlusion: %lld OCCLUSION, integrate p50 %.1f ms p99 %.1f ms, query p50 %.2f ms, map %lld leaves %.1f MB\n",
            (long long)a.published, percentile(a.integrate_ms, 0.5), percentile(a.integrate_ms, 0.99),
            percentile(a.query_ms, 0.5), (long long)leaves, bytes / 1e6);
    if (a.stats) fclose(a.stats);
    pb_status_destroy(a.status);
    occlusion_destroy(a.occ);
    pb_points_free(&a.pts);
    pb_bus_destroy(bus);
    return rc == 0 ? 0 : 1;
}
