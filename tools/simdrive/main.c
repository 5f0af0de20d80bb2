/* simdrive: a simulated study site and drive, deterministic for a seed.
 * The shell: options, file loading, the time-ordered event loop and the log. */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "actors.h"
#include "pb_arg.h"
#include "pb_opt.h"
#include "pb_ground.h"
#include "can.h"
#include "gnss.h"
#include "imu.h"
#include "lidar.h"
#include "occlusion_truth.h"
#include "body.h"
#include "pb_log.h"
#include "pb_progress.h"
#include "rng.h"
#include "score.h"
#include "pb_route.h"
#include "pb_site.h"
#include "trajectory.h"
#include "pb_vehicle.h"
#include "world.h"
#include "portobello_can_frame_t.h"
#include "portobello_imu_t.h"
#include "portobello_pose_t.h"

#ifndef PB_SOURCE_DIR
#define PB_SOURCE_DIR "."
#endif

/* 2024-05-01T14:00:00Z: a fixed epoch, so a seed gives the same log every time. */
#define UTIME0 1714572000000000LL
#define GT_PERIOD_US 10000
#define GNSS_PERIOD_US 100000
#define MAPPING_LIDAR_PERIOD_US 500000
#define CAN_JITTER_US 300
#define TYRE_CIRCUMFERENCE_M 1.99   /* 195/65 R15 */
#define GRID_CELL_M 4.0

static void usage(FILE *f)
{
    fprintf(f,
        "usage: simdrive --out DIR [--seed N] [--duration S] [--speed-profile cautious|normal|aggressive]\n"
        "                [--site SITE_DIR] [--vehicle FILE] [--mapping] [--no-lidar] [--quiet]\n"
        "                [--scenario FILE [--head]]\n"
        "                [--driver-spread F] [--without GROUPS] [--with GROUPS] [--dwell S]...\n"
        "                [--reverse M] [--foliage-depth M]\n"
        "       simdrive --terrain-out GROUND.yaml [--site SITE_DIR]\n"
        "\n"
        "Simulates a drive around a site's route and writes DIR/drive.lcm (LCM log) and\n"
        "DIR/ground_truth.tum (base pose at 100 Hz: t x y z qx qy qz qw, t in seconds).\n"
        "The same seed gives the same log; seeds change sensor noise and biases, stop\n"
        "dwell times and traffic phase.\n"
        "\n"
        "Channels: LIDAR_SCAN (OS1-64 range image, 10 Hz), IMU (vehicle rate), CAN_FRAME\n"
        "(Prius 0x0AA WHEEL_SPEEDS ~83 Hz, 0x0B4 SPEED ~41.7 Hz, both magnitudes; 0x3BC\n"
        "GEAR_PACKET 1 Hz and at every shift), GNSS_FIX (10 Hz),\n"
        "GROUND_TRUTH (base in map, 100 Hz).\n"
        "\n"
        "  --out DIR             output folder (created)\n"
        "  --seed N              random seed (default 1)\n"
        "  --duration S          seconds to simulate (default 60; laps repeat)\n"
        "  --speed-profile P     cautious, normal (default) or aggressive (route.yaml)\n"
        "  --site DIR            site folder (default %s/maps/default)\n"
        "  --vehicle FILE        vehicle file (default %s/vehicles/prius2017.yaml)\n"
        "  --mapping             the mapping day: mapping-day objects, no traffic, exactly\n"
        "                        one lap (ignores --duration), LiDAR keyframes at 2 Hz\n"
        "  --driver-spread F     a human driver: cruise speed, braking point and deceleration\n"
        "                        vary by up to +-F (e.g. 0.2) from stop to stop, per seed\n"
        "                        (default 0: the planner's own speed curve)\n"
        "  --without G1,G2       leave out these object groups of world.yaml (the drive day's\n"
        "                        changes, e.g. fence,bus: each switchable)\n"
        "  --with G1,G2          switch on road users and returns that are off by default:\n"
        "                        lead (a lead car in the car's lane, world.yaml lead_car:; the\n"
        "                        car follows it and stops behind it), crossing (cars crossing at\n"
        "                        junctions), pedestrians (people on sidewalks and crosswalks;\n"
        "                        both world.yaml crossers:, yielding to the car), roof (LiDAR\n"
        "                        returns from the car's own body, where the mount lets beams\n"
        "                        reach it); not with --mapping\n"
        "  --no-lidar            skip LIDAR_SCAN (fast drives for IMU, CAN and GNSS studies)\n"
        "  --lidar-from S        LIDAR_SCAN only from S seconds into the drive on (a LiDAR\n"
        "                        that starts with the car already moving); those sweeps are\n"
        "                        the whole drive's, byte for byte\n"
        "  --scenario FILE       stage the scenario's agents (the director's core on ground\n"
        "                        truth): AGENTS (~33 Hz) and OCCLUSION_TRUTH at every sweep end\n"
        "                        (analytic visibility of each body sample from the eye);\n"
        "                        a bare name is looked up in SITE_DIR/scenarios/\n"
        "  --head                also simulate the participant's head: HEAD_POSE (100 Hz),\n"
        "                        the truth's eye; without it the eye is the vehicle's seat\n"
        "  --dwell S             rest S s (1.5 to 3600) at the next stop met, instead of the\n"
        "                        seed's 2-3 s (repeatable: the 1st, 2nd... stop; a participant\n"
        "                        who presses proceed, as study-synth does)\n"
        "  --reverse M           at the first stop met, shift to R, back M metres (1 to 500)\n"
        "                        along the route at 2.5 m/s, shift to D and drive back to\n"
        "                        the stop line (a reversing manoeuvre; deterministic)\n"
        "  --foliage-depth M     foliage as a LiDAR sees it: a beam into a canopy (class\n"
        "                        foliage) stops at a random depth of mean M metres, or goes\n"
        "                        through; new at every sweep (default 0: solid spheres)\n"
        "  --quiet               no progress bar\n"
        "  --terrain-out FILE    write the site's true ground (the terrain's drivable and\n"
        "                        walkable cells; others unknown) as a ground model and exit\n"
        "  --surface-distance FILE  FILE: points (float32 x y z, the site's frame; a map to\n"
        "                        score): print, as one JSON line, how far they lie from the\n"
        "                        drive day's static world (ground and objects; --mapping: the\n"
        "                        mapping day's), and how many lie on the drive's road users,\n"
        "                        and exit. Give the drive's own --seed, --duration,\n"
        "                        --speed-profile, --with, --driver-spread, --dwell, --reverse:\n"
        "                        they decide where the road users were. A point is on a moving\n"
        "                        object (on_moving) when it lies farther than 0.05 m from the\n"
        "                        static world, within 0.2 m of a road user's box as the LiDAR\n"
        "                        saw it at some sweep (traffic; lead car, crossing cars,\n"
        "                        pedestrians when on), nearer to that box than to the static\n"
        "                        world, and not under the ground (what stands on it has\n"
        "                        nothing there); on_own_body: the same with the car's own body\n"
        "                        box (with roof returns on). beyond_0.5_*: the points farther\n"
        "                        than 0.5 m sorted into on_moving, on_own_body and other\n"
        "  --surface-labels FILE with --surface-distance: write one byte per point, in the\n"
        "                        points' order: 0 within 0.05 m of the static world, 1 farther,\n"
        "                        2 on a moving object, 3 on the car's own body\n"
        "  --help                this text\n",
        PB_SOURCE_DIR, PB_SOURCE_DIR);
}

static int mkdir_p(const char *path)
{
    char buf[1024];
    snprintf(buf, sizeof buf, "%s", path);
    for (char *p = buf + 1; *p; p++)
        if (*p == '/') {
            *p = 0;
            if (mkdir(buf, 0777) && errno != EEXIST) return -1;
            *p = '/';
        }
    if (mkdir(buf, 0777) && errno != EEXIST) return -1;
    return 0;
}

static double st_dist_or_zero(const trajectory_t *tr, double t)
{
    traj_state_t st;
    traj_eval(tr, t, &st);
    return st.dist;
}

/* The true ground as a ground model (pb_ground): what tools/build-ground is measured against. */
static int write_terrain(const terrain_t *T, const char *path, pb_err_t *err)
{
    if (!T->enabled) return pb_err_set(err, "--terrain-out: the site has no terrain (its ground is the plane z = 0)");
    pb_ground_t *g = terrain_ground(T, 1);
    int rc = pb_ground_save(g, path, err);
    pb_ground_destroy(g);
    return rc;
}

enum { S_GT, S_IMU, S_LIDAR, S_GNSS, S_CAN_WS, S_CAN_SPD, S_TRUTH, S_CAN_GEAR, S_COUNT };

/* --dwell S, repeatable: the 1st, 2nd, ... stop's dwell */
typedef struct { double s[256]; int n; } dwells_t;

static int add_dwell(const char *prog, const char *arg, void *var)
{
    dwells_t *d = var;
    if (d->n == (int)(sizeof d->s / sizeof *d->s)) {
        fprintf(stderr, "%s: --dwell: at most %d stops\n", prog, d->n);
        return -1;
    }
    if (pb_arg_double(prog, "dwell", arg, 1.5, 3600, &d->s[d->n])) return -1;
    d->n++;
    return 0;
}

int main(int argc, char **argv)
{
    const char *out_dir = NULL, *site_dir = PB_SOURCE_DIR "/maps/default";
    const char *veh_path = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    long seed = 1;
    double duration = 60;
    int mapping = 0, quiet = 0, no_lidar = 0, head = 0, prof = PB_PROFILE_NORMAL;
    dwells_t dwells = { .n = 0 };
    const char *scenario = NULL;
    const char *terrain_out = NULL, *without_arg = "", *with = "", *surface_points = NULL, *surface_labels = NULL;
    double driver_spread = 0, reverse_m = 0, foliage_depth = 0, lidar_from = 0;
    const pb_opt_t opts[] = {
        PB_OPT_STRING("out", &out_dir), PB_OPT_LONG("seed", &seed, 0, LONG_MAX),
        PB_OPT_DOUBLE("duration", &duration, 0.001, 24 * 3600),
        PB_OPT_CHOICE("speed-profile", &prof, pb_profile_names, PB_PROFILE_COUNT), PB_OPT_STRING("site", &site_dir),
        PB_OPT_STRING("vehicle", &veh_path), PB_OPT_FLAG("mapping", &mapping, 1), PB_OPT_STRING("terrain-out", &terrain_out),
        PB_OPT_DOUBLE("driver-spread", &driver_spread, 0, 0.5), PB_OPT_STRING("without", &without_arg),
        PB_OPT_STRING("with", &with), PB_OPT_FLAG("no-lidar", &no_lidar, 1), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_STRING("scenario", &scenario), PB_OPT_FLAG("head", &head, 1), PB_OPT_CALL("dwell", add_dwell, &dwells),
        PB_OPT_DOUBLE("reverse", &reverse_m, 1, 500), PB_OPT_STRING("surface-distance", &surface_points),
        PB_OPT_STRING("surface-labels", &surface_labels),
        PB_OPT_DOUBLE("foliage-depth", &foliage_depth, 0, 20), PB_OPT_DOUBLE("lidar-from", &lidar_from, 0, 24 * 3600),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("simdrive", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    if (surface_labels && !surface_points) { fprintf(stderr, "simdrive: --surface-labels needs --surface-distance\n"); return 2; }
    if (!out_dir && !terrain_out && !surface_points) { fprintf(stderr, "simdrive: --out DIR is required (see --help)\n"); return 2; }
    char without[256];
    snprintf(without, sizeof without, "%s", without_arg);

    pb_err_t err = { "" };
    pb_vehicle_t veh;
    pb_site_t site;
    pb_route_t route;
    world_t world;
    if (pb_vehicle_load(veh_path, &veh, &err) || pb_site_load(site_dir, &site, &err) ||
        pb_route_load(site.route_path, &route, &err)) {
        fprintf(stderr, "simdrive: %s\n", err.msg);
        return 1;
    }
    if (world_load(site.world_path, &route, &world, &err)) {
        fprintf(stderr, "simdrive: %s\n", err.msg);
        pb_route_free(&route);
        return 1;
    }
    if (terrain_out) {
        int rc = write_terrain(&world.terrain, terrain_out, &err);
        if (rc) fprintf(stderr, "simdrive: %s\n", err.msg);
        world_free(&world);
        pb_route_free(&route);
        return rc ? 1 : 0;
    }
    for (char *save = NULL, *g = strtok_r(without, ",", &save); g; g = strtok_r(NULL, ",", &save))
        if (world_group_off(&world, g, &err)) {
            fprintf(stderr, "simdrive: %s\n", err.msg);
            world_free(&world);
            pb_route_free(&route);
            return 2;
        }
    if (with[0] && (mapping || actors_switch_on(world.actors, with, &err))) {
        fprintf(stderr, "simdrive: %s\n", mapping ? "--with: the mapping day has no traffic" : err.msg);
        world_free(&world);
        pb_route_free(&route);
        return 2;
    }
    world_build_grid(&world, mapping ? DAY_MAP : DAY_DRIVE, GRID_CELL_M);
    world.foliage_depth_m = foliage_depth;
    sim_occ_t *occ = NULL;
    if (scenario) {
        char sc_path[1200];
        if (!strchr(scenario, '/'))
            snprintf(sc_path, sizeof sc_path, "%s/scenarios/%s%s", site_dir, scenario, strstr(scenario, ".yaml") ? "" : ".yaml");
        else
            snprintf(sc_path, sizeof sc_path, "%s", scenario);
        occ = sim_occ_create(sc_path, &route, &veh, &world, head, seed, &err);
        if (!occ) { fprintf(stderr, "simdrive: %s\n", err.msg); return 1; }
    }

    /* The base origin (rear axle) halts so that the front bumper is 0.5 m behind the line. */
    double stop_offset = (veh.length - veh.rear_overhang) + 0.5;
    trajectory_t traj;
    traj_driver_t driver = { mapping ? 0 : driver_spread, dwells.s, dwells.n, mapping ? 0 : reverse_m, 0 };
    if (traj_plan(&traj, &route, &route.profiles[prof], mapping ? 0 : duration, stop_offset, &driver, seed, &err)) {
        fprintf(stderr, "simdrive: %s\n", err.msg);
        return 1;
    }
    if (world.actors->on & ACT_LEAD) {     /* behind a lead car: its speed, not the planner's */
        double front = veh.length - veh.rear_overhang;
        if (actors_plan_follow(world.actors, &traj, &route, &route.profiles[prof], duration, front, stop_offset, &driver,
                               seed, &err)) {
            fprintf(stderr, "simdrive: %s\n", err.msg);
            return 1;
        }
    }
    actors_schedule(world.actors, &route, &traj, &veh, duration, seed);
    if (mapping) duration = traj.t_end;
    body_model_t body = { .terrain = &world.terrain, .traj = &traj, .veh = &veh };
    body_model_init(&body);
    if (surface_points) {   /* the drive planned as above: its road users are the drive's */
        score_drive_t sd = { &world, &route, &body, &veh, duration, (uint64_t)seed, !mapping };
        int rc = score_surface_distance(&sd, surface_points, surface_labels, &err);
        if (rc) fprintf(stderr, "simdrive: %s\n", err.msg);
        sim_occ_destroy(occ);
        body_model_free(&body);
        traj_free(&traj);
        world_free(&world);
        pb_route_free(&route);
        return rc ? 1 : 0;
    }
    int64_t end_us = (int64_t)llround(duration * 1e6);

    if (mkdir_p(out_dir)) { fprintf(stderr, "simdrive: %s: cannot create: %s\n", out_dir, strerror(errno)); return 1; }
    char path[1200];
    snprintf(path, sizeof path, "%s/drive.lcm", out_dir);
    pb_log_out_t out = { 0 };
    out.log = pb_log_open_write(path, &err);
    if (!out.log) { fprintf(stderr, "simdrive: %s\n", err.msg); return 1; }
    snprintf(path, sizeof path, "%s/ground_truth.tum", out_dir);
    FILE *tum = fopen(path, "w");
    if (!tum) { fprintf(stderr, "simdrive: %s: %s\n", path, strerror(errno)); return 1; }

    /* sensors */
    lidar_model_t lm;
    lidar_model_os1_64(&lm);
    lidar_sim_t ls = { .world = &world, .route = &route, .traj = &traj, .body = &body, .veh = &veh, .model = &lm,
                       .seed = seed, .traffic = !mapping };
    lidar_sim_init(&ls);
    double *body_range = NULL;
    if (world.actors->on & ACT_ROOF) {
        body_range = malloc(LIDAR_ROWS * LIDAR_COLS * sizeof *body_range);
        actors_body_ranges(&veh, lm.alt, lm.az, lm.origin_m, LIDAR_ROWS, LIDAR_COLS, body_range);
        ls.body_range = body_range;
        ls.body_cls = world.actors->body_cls;
    }
    imu_sim_t imu;
    imu_sim_init(&imu, &veh, seed);
    gnss_sim_t gnss;
    gnss_sim_init(&gnss, &veh, seed, GNSS_PERIOD_US * 1e-6);

    static int32_t range_mm[LIDAR_ROWS * LIDAR_COLS], col_off[LIDAR_COLS];
    static uint8_t refl[LIDAR_ROWS * LIDAR_COLS];
    static float alt[LIDAR_ROWS], az[LIDAR_ROWS];
    portobello_lidar_scan_t scan = { 0 };
    scan.sensor = veh.lidar_model;
    scan.range_mm = range_mm; scan.reflectivity = refl; scan.col_offset_us = col_off;
    scan.beam_altitude_rad = alt; scan.beam_azimuth_rad = az;
    int16_t no_sig[1];
    scan.signal = no_sig; scan.near_ir = no_sig;

    /* Streams: period, phase; CAN frames carry a small receive-time jitter. */
    const int64_t period[S_COUNT] = { GT_PERIOD_US, (int64_t)llround(1e6 / veh.imu_rate_hz),
                                      mapping ? MAPPING_LIDAR_PERIOD_US : LIDAR_PERIOD_US, GNSS_PERIOD_US,
                                      CAN_WHEEL_SPEEDS_PERIOD_US, CAN_SPEED_PERIOD_US, LIDAR_PERIOD_US,
                                      CAN_GEAR_TICK_US };
    /* OCCLUSION_TRUTH at the end of each sweep (its last column) */
    const int64_t phase[S_COUNT] = { 0, 0, 0, 0, 2000, 5000, lm.col_off_us[LIDAR_COLS - 1], 7000 };
    int gear_sent = -1;     /* the gear of the last GEAR_PACKET (sent at 1 Hz and at every shift) */
    int64_t k[S_COUNT] = { 0 };
    /* --lidar-from: start at the first sweep that begins then (a sweep's noise is drawn from
     * its own index, so it is the whole drive's); --no-lidar: from the drive's end */
    const int64_t lidar_from_us = no_lidar ? end_us : (int64_t)llround(lidar_from * 1e6);
    if (lidar_from_us > phase[S_LIDAR])
        k[S_LIDAR] = (lidar_from_us - phase[S_LIDAR] + period[S_LIDAR] - 1) / period[S_LIDAR];
    int64_t counts[S_COUNT] = { 0 };
    pb_progress_t prog;
    pb_progress_start(&prog, "simdrive", end_us, quiet);
    for (;;) {
        int best = -1;
        int64_t tb = 0;
        for (int s = 0; s < S_COUNT; s++) {
            int64_t t = phase[s] + k[s] * period[s];
            if (s == S_CAN_WS || s == S_CAN_SPD || s == S_CAN_GEAR)
                t += (int64_t)llround((rng_uniform(seed, RNG_CAN_JITTER, (uint64_t)s, (uint64_t)k[s]) - 0.5) * 2 * CAN_JITTER_US);
            if (s == S_TRUTH && (!occ || mapping)) continue;
            if (t < end_us && (best < 0 || t < tb)) { best = s; tb = t; }
        }
        if (best < 0 || out.failed) break;
        int64_t utime = UTIME0 + tb;
        double t = tb * 1e-6;
        body_state_t b;
        if (best == S_LIDAR) traj_eval(&traj, t, &b.st);
        else body_eval(&body, t, &b);
        const traj_state_t st = b.st;
        switch (best) {
        case S_GT: {
            portobello_pose_t p = { 0 };
            p.utime = utime;
            for (int i = 0; i < 3; i++) {
                p.position[i] = b.p[i];
                p.velocity[i] = b.v[i];
                p.angular_velocity[i] = b.w[i];
            }
            memcpy(p.orientation, b.q, sizeof b.q);
            p.status = PORTOBELLO_POSE_T_STATUS_TRACKING;
            p.source = PORTOBELLO_POSE_T_SOURCE_GROUND_TRUTH;
            p.match_score = NAN;
            PB_LOG_WRITE_MSG(&out, "GROUND_TRUTH", portobello_pose_t, &p);
            if (k[best] % 50 == 0) pb_progress_update(&prog, tb);
            if (occ) sim_occ_pose(occ, &b, utime, &out);
            fprintf(tum, "%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", utime * 1e-6, p.position[0], p.position[1],
                    p.position[2], p.orientation[1], p.orientation[2], p.orientation[3], p.orientation[0]);
            break;
        }
        case S_IMU: {
            portobello_imu_t m = { 0 };
            m.utime = utime;
            m.sensor = "sim";
            imu_measure(&imu, &body, t, seed, (uint64_t)k[best], m.accel, m.gyro);
            PB_LOG_WRITE_MSG(&out, "IMU", portobello_imu_t, &m);
            break;
        }
        case S_TRUTH:
            sim_occ_truth(occ, &b, utime, &out);
            break;
        case S_LIDAR:
            lidar_simulate(&ls, (int32_t)k[best], t, utime, &scan);
            PB_LOG_WRITE_MSG(&out, "LIDAR_SCAN", portobello_lidar_scan_t, &scan);
            break;
        case S_GNSS: {
            portobello_gnss_fix_t fix = { 0 };
            gnss_step(&gnss, &veh, &site.geo, site.geoid_height_m, &b, seed, utime, &fix);
            PB_LOG_WRITE_MSG(&out, "GNSS_FIX", portobello_gnss_fix_t, &fix);
            break;
        }
        case S_CAN_GEAR: {
            int gear = t >= traj.reverse_t0 && t < traj.reverse_t1 ? CAN_GEAR_R : CAN_GEAR_D;
            if (gear == gear_sent && k[best] % (CAN_GEAR_PERIOD_US / CAN_GEAR_TICK_US) != 0) break;
            gear_sent = gear;
            uint8_t data[8];
            portobello_can_frame_t f = { 0 };
            f.utime = utime;
            f.len = 8;
            f.data = data;
            f.id = CAN_ID_GEAR;
            can_encode_gear(gear, data);
            PB_LOG_WRITE_MSG(&out, "CAN_FRAME", portobello_can_frame_t, &f);
            break;
        }
        case S_CAN_WS:
        case S_CAN_SPD: {
            uint8_t data[8];
            portobello_can_frame_t f = { 0 };
            f.utime = utime;
            f.bus = 0;
            f.len = 8;
            f.data = data;
            /* the wheels roll the 3-D path: on a grade it is longer than the plan's map arc */
            traj_state_t sw = st;
            double vh = hypot(b.v[0], b.v[1]);
            if (vh > 1e-6) { double k3 = hypot(vh, b.v[2]) / vh; sw.v *= k3; sw.omega *= k3; }
            if (best == S_CAN_WS) {
                double fl, fr, rl, rr;
                can_wheel_speeds_kmh(&veh, &sw, &fl, &fr, &rl, &rr);
                can_encode_wheel_speeds(fl, fr, rl, rr, data);
                f.id = CAN_ID_WHEEL_SPEEDS;
            } else {
                uint8_t enc = (uint8_t)((int64_t)floor(st.dist / TYRE_CIRCUMFERENCE_M) & 0xFF);
                can_encode_speed(fabs(sw.v) * 3.6, enc, data);   /* a magnitude, as the car sends it */
                f.id = CAN_ID_SPEED;
            }
            PB_LOG_WRITE_MSG(&out, "CAN_FRAME", portobello_can_frame_t, &f);
            break;
        }
        }
        counts[best]++;
        k[best]++;
    }
    pb_progress_finish(&prog);
    int rc = 0;
    if (out.failed) { fprintf(stderr, "simdrive: %s\n", out.err.msg); rc = 1; }
    if (pb_log_close(out.log, &err)) { fprintf(stderr, "simdrive: %s\n", err.msg); rc = 1; }
    if (fclose(tum)) { fprintf(stderr, "simdrive: ground_truth.tum: %s\n", strerror(errno)); rc = 1; }
    if (!quiet && !rc)
        fprintf(stderr, "simdrive: %s, %.1f s, %.0f m, %d stops planned: %lld scans, %lld imu, %lld can, %lld gnss, %lld gt -> %s\n",
                site.name, duration, st_dist_or_zero(&traj, duration), traj.stops_made,
                (long long)counts[S_LIDAR], (long long)counts[S_IMU],
                (long long)(counts[S_CAN_WS] + counts[S_CAN_SPD] + counts[S_CAN_GEAR]), (long long)counts[S_GNSS],
                (long long)counts[S_GT], out_dir);
    lidar_sim_free(&ls);
    free(body_range);
    sim_occ_destroy(occ);
    body_model_free(&body);
    free(out.buf);
    traj_free(&traj);
    world_free(&world);
    pb_route_free(&route);
    return rc;
}
