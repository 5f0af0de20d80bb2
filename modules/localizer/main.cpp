/* localizer: LiDAR localization in a site's prior map, fused with IMU and CAN speed.
 *   localizer --site SITE_DIR [--replay IN.lcm --out OUT.lcm] [--initial-pose x,y,z,r,p,y]
 * Thin shell around core/localizer (the pipeline): options, map and vehicle files,
 * subscribe, decode, publish POSE / POSE_PREDICTED, STATUS heartbeat, signals. */
#include <sys/stat.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "core/localizer.h"
#include "map_source.h"
#include "pb_bus.h"
#include "pb_clock.h"
#include "pb_opt.h"
#include "pb_signal.h"
#include "pb_site.h"
#include "pb_status.h"
#include "pb_vehicle.h"
#include "portobello_gnss_fix_t.h"
#include "portobello_imu_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"
#include "portobello_status_t.h"
#include "portobello_vehicle_speed_t.h"

using namespace pb_loc;

struct app_t {
    pb_bus_t *bus = nullptr;
    pb_status_t *status = nullptr;
    localizer_t *L = nullptr;
    outputs_t out;
    pb_points_t pts = {};
    bool use_imu = true, use_speed = true, use_gnss = true, verbose = false;
    std::vector<double> latency_ms;
    FILE *stats = nullptr;
    int64_t poses = 0, predicted = 0;
    /* message time of the newest input and the bus time it arrived at: the timer's
     * "now" in message time is input_utime + (bus now - input_bus_time), so a log played
     * live (old utimes) and a replay behave the same */
    int64_t input_utime = 0, input_bus_time = 0;
    int column_stride = 2;
    scan_diag_t diag;
    int64_t pending_utime = -1;
    double pending_prep_ms = 0;
    std::vector<int32_t> red_range, red_off;
    std::vector<uint8_t> red_refl;
    map_source_t *map = nullptr;   /* paged around the newest position (map.tiles) */
    int64_t tile_loads = 0, tile_drops = 0;   /* reported with --verbose */
    const pb_georef_t *geo = nullptr;
    std::string vehicle_name, vehicle_path;
    bool frame_error = false;
};

/* Pages the map's tiles in around map (x, y): the newest position known (a pose, a
 * GNSS fix, an initial pose, a place the global search tries). Tiles loaded and dropped
 * are counted in STATUS (map_tile_loaded, map_tile_dropped). */
static void page_map(app_t *a, double x, double y)
{
    pb_err_t err;
    int rc = map_source_page(a->map, x, y, &err);
    if (rc < 0) {
        pb_status_count(a->status, "map_tile_unreadable", 1);
        pb_status_error(a->status, "%s", err.msg);
    }
    if (rc == 0) return;
    pb_tiles_stats_t st;
    map_source_stats(a->map, &st);
    pb_status_count(a->status, "map_tile_loaded", st.loads - a->tile_loads);
    pb_status_count(a->status, "map_tile_dropped", st.drops - a->tile_drops);
    if (a->verbose)
        fprintf(stderr, "localizer: map tiles around (%.0f, %.0f): %lld loaded, %lld dropped, %d held (%lld cells)\n", x,
                y, (long long)(st.loads - a->tile_loads), (long long)(st.drops - a->tile_drops), st.tiles_loaded,
                (long long)(st.fine_cells + st.coarse_cells + st.rough_cells));
    a->tile_loads = st.loads;
    a->tile_drops = st.drops;
}

static void page_for_core(void *user, double x, double y) { page_map((app_t *)user, x, y); }

static void input_time(app_t *a, const char *channel, int64_t utime)
{
    pb_status_input_time(a->status, channel, utime);
    /* GNSS keeps its own clock (it may be seconds off; the core measures that) */
    if (strcmp(channel, "GNSS_FIX") == 0) return;
    /* newer, or much older: the sensors' clock stepped back (the core starts again) */
    if (utime > a->input_utime || utime < a->input_utime - 1000000) {
        a->input_utime = utime;
        a->input_bus_time = pb_bus_monotonic(a->bus);
    }
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: localizer [--site SITE_DIR] [--replay IN.lcm --out OUT.lcm] [--lcm-url URL]\n"
            "                 [--initial-pose x,y,z,roll,pitch,yaw] [--vehicle FILE] [--no-imu]\n"
            "                 [--no-speed] [--no-gnss] [--lidar-lost-s S] [--no-global-search]\n"
            "                 [--stats FILE.csv] [--verbose]\n"
            "Localizes the vehicle in a site's prior map (SITE_DIR/map.pcd) by matching each\n"
            "LIDAR_SCAN to the map, fused in an error-state Kalman filter with IMU and\n"
            "VEHICLE_SPEED (either may be absent: LiDAR alone works). Publishes POSE per sweep\n"
            "(status initializing / tracking / degraded / lost, covariance, match score) and\n"
            "POSE_PREDICTED at every IMU sample (200 Hz from a timer without IMU). Starts from\n"
            "INITIAL_POSE or --initial-pose (a prior: searched within 3 m and 15 degrees), GNSS_FIX\n"
            "(position, heading from course or a yaw search; a receiver clock offset is measured and\n"
            "taken out), or with neither by a global search of the whole map (place descriptors);\n"
            "until it has a pose, STATUS says why. Detects a wrong pose (structure fit, motion and\n"
            "GNSS consistency) and relocalizes; a LiDAR outage longer than --lidar-lost-s is LOST.\n"
            "  --site DIR           site folder: map.pcd and map.tiles (its paged form, from\n"
            "                       map-tiles; held only within --map-radius of the car), optional\n"
            "                       site.yaml (geo-reference for GNSS); default %s/maps/default\n"
            "  --vehicle FILE       extrinsics (default %s/vehicles/prius2017.yaml)\n"
            "  --replay IN.lcm      run on a log as fast as the CPU allows (with --out)\n"
            "  --out OUT.lcm        where the replay writes POSE, POSE_PREDICTED and STATUS\n"
            "  --lcm-url URL        live bus (default $LCM_DEFAULT_URL or %s)\n"
            "  --initial-pose P     x,y,z (m),roll,pitch,yaw (degrees) of base in map, used at the\n"
            "                       first sweep when no INITIAL_POSE / GNSS start came first\n"
            "  --no-imu, --no-speed, --no-gnss   ignore that input (tests, benchmarks)\n"
            "  --lidar-lost-s S     no LIDAR_SCAN for this long: LOST (default 10)\n"
            "  --map-radius M       hold the map's tiles within M metres of the car (default 120; SITE_DIR/\n"
            "                       map.tiles from map-tiles, else map.pcd is prepared at start-up)\n"
            "  --no-global-search   without a prior or GNSS, wait instead of searching the map\n"
            "  --stats FILE.csv     one line per sweep: utime, wall ms, status, match figures\n"
            "  --column-stride N    use every Nth column of a range-image sweep (default 2; 1 = all)\n"
            "  --verbose            print state changes to stderr\n"
            "  -h, --help           this text\n",
            PB_SOURCE_DIR, PB_SOURCE_DIR, PB_DEFAULT_LCM_URL);
}

static void to_pose_msg(const pose_out_t &p, portobello_pose_t *m)
{
    memset(m, 0, sizeof *m);
    m->utime = p.utime;
    Eigen::Quaterniond q(p.map_from_base.rotation());
    q.normalize();
    for (int i = 0; i < 3; i++) {
        m->position[i] = p.map_from_base.translation()[i];
        m->velocity[i] = p.velocity[i];
        m->angular_velocity[i] = p.angular_velocity[i];
    }
    m->orientation[0] = q.w(); m->orientation[1] = q.x(); m->orientation[2] = q.y(); m->orientation[3] = q.z();
    for (int r = 0; r < 6; r++)
        for (int c = 0; c < 6; c++) m->covariance[r * 6 + c] = p.covariance(r, c);
    m->status = (int8_t)p.status;
    m->source = (int8_t)p.source;
    m->match_score = (float)p.match_score;
}

static bool is_info(const std::string &c)
{
    return c.rfind("to_", 0) == 0 || c == "init_candidate" || c == "initial_pose" || c == "match_structure_peak";
}

/* Publishes what the core produced. t0: wall time at the start of the handler; a sweep's
 * latency is its own handler time, plus the decode time of its LIDAR_SCAN when it waited
 * for the IMU (the core matches a sweep once the IMU has reached its end). */
static void record_sweep(app_t *a, double ms);
static void flush(app_t *a, double t0 = -1)
{
    bool diag = a->out.has_scan_diag;
    scan_diag_t d = a->out.scan_diag;
    pb_err_t err;
    for (const pose_out_t &p : a->out.poses) {
        portobello_pose_t m;
        to_pose_msg(p, &m);
        const char *ch = p.predicted ? "POSE_PREDICTED" : "POSE";
        if (PB_PUBLISH(a->bus, ch, portobello_pose_t, &m, &err) != 0) {
            pb_status_count(a->status, "publish_failed", 1);
            pb_status_error(a->status, "%s: %s", ch, err.msg);
        }
        (p.predicted ? a->predicted : a->poses)++;
        /* a pose that is known (not the "unknown" covariance of a start) */
        if (!p.predicted && p.covariance(0, 0) < 1e6)
            page_map(a, p.map_from_base.translation().x(), p.map_from_base.translation().y());
    }
    for (const event_t &e : a->out.events) {
        pb_status_count(a->status, e.counter.c_str(), 1);
        if (e.message.empty()) continue;
        if (is_info(e.counter)) { if (a->verbose) fprintf(stderr, "localizer: %s\n", e.message.c_str()); }
        else pb_status_error(a->status, "%s", e.message.c_str());
    }
    int s = localizer_status(a->L);
    pb_status_set_state(a->status, s == ST_TRACKING ? PORTOBELLO_STATUS_T_STATE_OK
                                   : s == ST_INITIALIZING ? PORTOBELLO_STATUS_T_STATE_STARTING
                                                          : PORTOBELLO_STATUS_T_STATE_DEGRADED);
    a->out.clear();
    if (diag && t0 >= 0) {
        a->diag = d;
        record_sweep(a, pb_clock_monotonic_ms() - t0);
    }
}

static void record_sweep(app_t *a, double ms)
{
    const scan_diag_t &d = a->diag;
    if (d.utime == a->pending_utime) ms += a->pending_prep_ms;
    a->latency_ms.push_back(ms);
    if (a->stats)
        fprintf(a->stats, "%lld,%.3f,%d,%d,%d,%.4f,%.4f,%.4f,%.2f,%.2f\n", (long long)d.utime, ms, d.status,
                d.matched, d.accepted, d.inlier_fraction, d.structure_inliers, d.score, d.innovation_chi2,
                d.gnss_residual_m);
}

/* A sensor string "VEHICLE:NAME" (import-scans) says whose base frame the scans and
 * GROUND_TRUTH are in: another vehicle than ours is an error naming both, not a silent
 * misfit; the run stops. A plain name (drivers, simdrive) is taken as ours. */
static bool frame_matches(app_t *a, const portobello_lidar_scan_t *s)
{
    const char *colon = s->sensor ? strchr(s->sensor, ':') : nullptr;
    if (!colon) return true;
    std::string veh(s->sensor, colon - s->sensor);
    if (veh == a->vehicle_name) return true;
    pb_status_count(a->status, "frame_mismatch", 1);
    char msg[1024];
    if (veh == "lidar")
        snprintf(msg, sizeof msg, "LIDAR_SCAN sensor '%s': the scans were imported without --vehicle (GROUND_TRUTH is "
                 "the LiDAR's pose), but this run uses vehicle '%s' (%s): import them with --vehicle %s, or use "
                 "vehicles/lidar_mast.yaml for both", s->sensor, a->vehicle_name.c_str(), a->vehicle_path.c_str(),
                 a->vehicle_path.c_str());
    else
        snprintf(msg, sizeof msg, "LIDAR_SCAN sensor '%s': the scans are in the frame of vehicle '%s', but this run "
                 "uses vehicle '%s' (%s): run with the vehicle file the log was imported with",
                 s->sensor, veh.c_str(), a->vehicle_name.c_str(), a->vehicle_path.c_str());
    fprintf(stderr, "localizer: %s\n", msg);
    pb_status_set_state(a->status, PORTOBELLO_STATUS_T_STATE_ERROR);
    pb_status_error(a->status, "%s", msg);
    a->frame_error = true;
    pb_bus_stop(a->bus);
    return false;
}

/* a sweep older than this on arrival at the handler is stale while searching (one 10 Hz period and a half) */
static const int64_t kStaleScanUs = 150000;

static void on_scan(const pb_msg_t *m, void *user)
{
    app_t *a = (app_t *)user;
    double t0 = pb_clock_monotonic_ms();
    portobello_lidar_scan_t s;
    if (portobello_lidar_scan_t_decode(m->data, 0, m->len, &s) < 0) { pb_status_undecodable(a->status, "undecodable", m); return; }
    /* the sweep's time is its end: the newest measurement in it */
    int32_t last_off = 0;
    for (int i = 0; i < s.cols; i++) last_off = std::max(last_off, s.col_offset_us[i]);
    for (int i = 0; i < s.npoints; i++) last_off = std::max(last_off, s.point_offset_us[i]);
    if (last_off < 1000000) input_time(a, m->channel, s.utime + last_off);
    /* Live, without a pose, a search costs up to ~0.7 s a sweep: sweeps that waited in
     * the queue longer than a sweep period are stale, and searching on each would leave
     * the car seconds behind (and the queue holding megabytes). Search on the newest
     * instead. A replay never skips (its receive time is the event's time). */
    int st = localizer_status(a->L);
    if ((st == ST_INITIALIZING || st == ST_LOST) && pb_bus_now(a->bus) - m->recv_utime > kStaleScanUs) {
        pb_status_count(a->status, "scan_stale_skipped", 1);
        portobello_lidar_scan_t_decode_cleanup(&s);
        return;
    }
    /* every column_stride-th column of a range image: the beam model is exact for the
     * reduced image (encoder angle c/cols is unchanged), and registration keeps only
     * ~2000 voxel centroids of a sweep anyway */
    int k = a->column_stride;
    portobello_lidar_scan_t red = s;
    if (k > 1 && s.npixels > 0 && s.cols % k == 0 && s.npixels == s.rows * s.cols) {
        int cols = s.cols / k;
        a->red_range.resize((size_t)s.rows * cols);
        a->red_refl.resize((size_t)s.rows * cols);
        a->red_off.resize(cols);
        for (int r = 0; r < s.rows; r++)
            for (int c = 0; c < cols; c++) {
                a->red_range[(size_t)r * cols + c] = s.range_mm[(size_t)r * s.cols + (size_t)c * k];
                a->red_refl[(size_t)r * cols + c] = s.reflectivity[(size_t)r * s.cols + (size_t)c * k];
            }
        for (int c = 0; c < cols; c++) a->red_off[c] = s.col_offset_us[c * k];
        red.cols = cols;
        red.npixels = s.rows * cols;
        red.range_mm = a->red_range.data();
        red.reflectivity = a->red_refl.data();
        red.col_offset_us = a->red_off.data();
        red.nsignal = 0;
    }
    if (pb_status_scan_points(a->status, &red, &a->pts) < 0) a->pts.n = 0;
    int64_t utime = s.utime;
    if (!frame_matches(a, &s)) { portobello_lidar_scan_t_decode_cleanup(&s); return; }
    portobello_lidar_scan_t_decode_cleanup(&s);
    localizer_scan(a->L, utime, &a->pts, &a->out);
    if (!a->out.has_scan_diag) {
        /* waiting for the IMU: remember what this sweep cost so far */
        int32_t last = 0;
        for (int i = 0; i < a->pts.n; i++) last = std::max(last, a->pts.offset_us[i]);
        a->pending_utime = utime + last;
        a->pending_prep_ms = pb_clock_monotonic_ms() - t0;
    }
    flush(a, t0);
}

/* The handlers of small messages: pb_status_take, the input clock, and what came of the
 * message published (with its cost). */
template <typename T, typename Use>
static void take(const pb_msg_t *m, void *user, int (*decode)(const void *, int, int, T *), int (*cleanup)(T *), Use use)
{
    app_t *a = (app_t *)user;
    double t0 = pb_clock_monotonic_ms();
    auto clocked = [&](const T &s) { input_time(a, m->channel, s.utime); use(a, s); };
    if (pb_status_take(a->status, m, decode, cleanup, clocked) == 0) flush(a, t0);
}

static void on_imu(const pb_msg_t *m, void *user)
{
    take(m, user, portobello_imu_t_decode, portobello_imu_t_decode_cleanup, [](app_t *a, const portobello_imu_t &s) {
        if (a->use_imu)
            localizer_imu(a->L, s.utime, Vec3(s.accel[0], s.accel[1], s.accel[2]), Vec3(s.gyro[0], s.gyro[1], s.gyro[2]), &a->out);
    });
}

static void on_speed(const pb_msg_t *m, void *user)
{
    take(m, user, portobello_vehicle_speed_t_decode, portobello_vehicle_speed_t_decode_cleanup,
         [](app_t *a, const portobello_vehicle_speed_t &s) {
             if (a->use_speed) localizer_speed(a->L, s.utime, s.speed_mps, &a->out);
         });
}

static void on_gnss(const pb_msg_t *m, void *user)
{
    take(m, user, portobello_gnss_fix_t_decode, portobello_gnss_fix_t_decode_cleanup, [](app_t *a, const portobello_gnss_fix_t &s) {
        if (a->use_gnss) {
            gnss_in_t g;
            g.utime = s.utime; g.fix_type = s.fix_type; g.lat_deg = s.lat_deg; g.lon_deg = s.lon_deg; g.alt_m = s.alt_m;
            g.h_acc_m = s.h_acc_m; g.speed_mps = s.speed_mps; g.heading_deg = s.heading_deg; g.heading_acc_deg = s.heading_acc_deg;
            if (a->geo && s.fix_type > 0 && std::isfinite(s.lat_deg) && std::isfinite(s.lon_deg)) {
                double xyz[3];
                pb_geo_wgs84_to_map(a->geo, s.lat_deg, s.lon_deg, s.alt_m, xyz);
                int st = localizer_status(a->L);
                if (st == ST_INITIALIZING || st == ST_LOST) page_map(a, xyz[0], xyz[1]);
            }
            localizer_gnss(a->L, g, &a->out);
        }
    });
}

static void on_initial_pose(const pb_msg_t *m, void *user)
{
    take(m, user, portobello_pose_t_decode, portobello_pose_t_decode_cleanup, [](app_t *a, const portobello_pose_t &s) {
        Eigen::Quaterniond q(s.orientation[0], s.orientation[1], s.orientation[2], s.orientation[3]);
        if (!(q.norm() > 0.5 && q.norm() < 1.5)) {
            pb_status_count(a->status, "initial_pose_invalid", 1);
            pb_status_error(a->status, "INITIAL_POSE: orientation is not a unit quaternion; ignored");
        } else {
            Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
            T.linear() = q.normalized().toRotationMatrix();
            T.translation() = Vec3(s.position[0], s.position[1], s.position[2]);
            page_map(a, T.translation().x(), T.translation().y());
            localizer_initial_pose(a->L, s.utime, T, &a->out);
        }
    });
}

static void on_tick(int64_t now, void *user)
{
    app_t *a = (app_t *)user;
    if (a->input_utime == 0) return;
    double t0 = pb_clock_monotonic_ms();
    /* message time now: the newest input's time plus the monotonic time since it came */
    localizer_tick(a->L, a->input_utime + (pb_bus_monotonic(a->bus) - a->input_bus_time), &a->out);
    flush(a, t0);
}

static Eigen::Isometry3d to_iso(const pb_transform_t &t)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::Quaterniond(t.q[0], t.q[1], t.q[2], t.q[3]).normalized().toRotationMatrix();
    T.translation() = Vec3(t.t[0], t.t[1], t.t[2]);
    return T;
}

static int parse_pose(const char *s, double out[6])
{
    char *end;
    const char *p = s;
    for (int i = 0; i < 6; i++) {
        out[i] = strtod(p, &end);
        if (end == p || !std::isfinite(out[i])) return -1;
        p = end;
        if (i < 5) { if (*p != ',') return -1; p++; }
    }
    return *p == '\0' ? 0 : -1;
}

static double percentile(std::vector<double> v, double q)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    size_t i = (size_t)std::min<double>(v.size() - 1, std::ceil(q * v.size()) - 1);
    return v[i];
}

/* Fails before anything runs: publish one STATUS naming the cause (to OUT in replay). */
static int fail_start(pb_bus_t *bus, pb_status_t *st, const char *msg)
{
    fprintf(stderr, "localizer: %s\n", msg);
    if (bus) {
        pb_status_set_state(st, PORTOBELLO_STATUS_T_STATE_ERROR);
        pb_status_count(st, "start_failed", 1);
        pb_status_error(st, "%s", msg);
        pb_status_publish(st);
        pb_status_destroy(st);
        pb_bus_destroy(bus);
    }
    return 1;
}

/* --initial-pose x,y,z,roll,pitch,yaw (m, degrees) */
static int parse_initial_pose(const char *prog, const char *arg, void *var)
{
    localizer_config_t *cfg = (localizer_config_t *)var;
    if (parse_pose(arg, cfg->initial_pose) != 0) {
        fprintf(stderr, "%s: --initial-pose: expected x,y,z,roll,pitch,yaw (6 numbers), got '%s'\n", prog, arg);
        return -1;
    }
    for (int i = 3; i < 6; i++) cfg->initial_pose[i] *= M_PI / 180;
    cfg->has_initial_pose = true;
    return 0;
}

int main(int argc, char **argv)
{
    const char *url = nullptr, *in = nullptr, *outp = nullptr, *stats = nullptr;
    const char *site_arg = PB_SOURCE_DIR "/maps/default", *vehicle_arg = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    localizer_config_t cfg;
    pb_reg_config_default(&cfg.reg);
    app_t a;
    pb_tiles_config_t tiles_cfg;
    pb_tiles_config_default(&tiles_cfg);
    const pb_opt_t opts[] = {
        PB_OPT_STRING("site", &site_arg), PB_OPT_STRING("vehicle", &vehicle_arg), PB_OPT_STRING("replay", &in),
        PB_OPT_STRING("out", &outp), PB_OPT_STRING("lcm-url", &url), PB_OPT_CALL("initial-pose", parse_initial_pose, &cfg),
        PB_OPT_BOOL("no-imu", &a.use_imu, 0), PB_OPT_BOOL("no-speed", &a.use_speed, 0), PB_OPT_BOOL("no-gnss", &a.use_gnss, 0),
        PB_OPT_STRING("stats", &stats), PB_OPT_INT("column-stride", &a.column_stride, 1, 16),
        PB_OPT_BOOL("verbose", &a.verbose, 1), PB_OPT_MICROS("lidar-lost-s", &cfg.lidar_lost_us, 0.5, 3600, 1000000),
        PB_OPT_BOOL("no-global-search", &cfg.global_search, 0), PB_OPT_DOUBLE("map-radius", &tiles_cfg.load_radius_m, 90, 1e6),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("localizer", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    tiles_cfg.keep_radius_m = tiles_cfg.load_radius_m + 40;   /* hysteresis: no reload at a tile's edge */
    const std::string site = site_arg, vehicle = vehicle_arg;
    if ((in != nullptr) != (outp != nullptr)) { fprintf(stderr, "localizer: --replay and --out go together\n"); return 2; }

    pb_err_t err;
    pb_bus_t *bus = in ? pb_bus_create_replay(in, outp, &err) : pb_bus_create_live(url, &err);
    if (!bus) { fprintf(stderr, "localizer: %s\n", err.msg); return 1; }
    a.bus = bus;
    /* The heartbeat starts before the map loads (seconds): live, a supervisor sees at once
     * that the localizer is up (state STARTING). */
    a.status = pb_status_create(bus, "localizer", 1000000);

    pb_vehicle_t veh;
    if (pb_vehicle_load(vehicle.c_str(), &veh, &err) != 0) return fail_start(bus, a.status, err.msg);
    a.vehicle_name = veh.name;
    a.vehicle_path = vehicle;
    extrinsics_t ex;
    ex.base_from_lidar = to_iso(veh.base_from_lidar);
    ex.base_from_imu = to_iso(veh.base_from_imu);
    ex.base_from_gnss = to_iso(veh.base_from_gnss);
    pb_vehicle_body_box(&veh, 0.10, cfg.reg.body_box);   /* the car's own body, 10 cm margin */

    /* A site folder holding only map.pcd is enough; site.yaml adds the geo-reference. */
    struct stat sb;
    if (stat(site.c_str(), &sb) != 0 || !S_ISDIR(sb.st_mode)) {
        std::string m = site + ": site folder not found";
        return fail_start(bus, a.status, m.c_str());
    }
    pb_site_t st;
    bool has_geo = false;
    std::string site_yaml = site + "/site.yaml";
    if (stat(site_yaml.c_str(), &sb) == 0) {
        if (pb_site_load(site.c_str(), &st, &err) != 0) return fail_start(bus, a.status, err.msg);
        has_geo = true;
    } else {
        fprintf(stderr, "localizer: %s: no site.yaml, so no geo-reference: GNSS_FIX is not used\n", site.c_str());
    }
    double t0 = pb_clock_monotonic_ms();
    a.map = map_source_open(site, &tiles_cfg, &err);
    if (!a.map) return fail_start(bus, a.status, err.msg);
    const pb_regmap_t *map = map_source_map(a.map);
    if (cfg.has_initial_pose) page_map(&a, cfg.initial_pose[0], cfg.initial_pose[1]);
    /* the place descriptors of the whole map, for a start with no prior (a few MB) */
    places_t *places = cfg.global_search ? map_source_places(a.map, &err) : nullptr;
    if (cfg.global_search && !places && err.msg[0]) return fail_start(bus, a.status, err.msg);
    pb_regmap_info_t info;
    pb_regmap_info(map, &info);
    pb_tiles_stats_t ts;
    map_source_stats(a.map, &ts);
    fprintf(stderr, "localizer: map %s: %lld points in %d tiles of %.0f m, paged within %.0f m of the car; %zu places "
            "for a global search; ready in %.1f s\n", map_source_path(a.map), (long long)info.points, ts.tiles_total,
            ts.tile_m, tiles_cfg.load_radius_m, places_count(places), (pb_clock_monotonic_ms() - t0) * 1e-3);

    if (stats) {
        a.stats = fopen(stats, "w");
        if (!a.stats) { fprintf(stderr, "localizer: %s: cannot write\n", stats); map_source_close(a.map); pb_bus_destroy(bus); return 1; }
        fprintf(a.stats, "utime,wall_ms,status,matched,accepted,inlier_fraction,structure_inliers,score,innovation_chi2,gnss_residual_m\n");
    }
    a.geo = has_geo && a.use_gnss ? &st.geo : nullptr;
    a.L = localizer_create(cfg, ex, map, a.geo);
    localizer_set_pager(a.L, page_for_core, &a);
    if (places) localizer_set_places(a.L, places);
    pb_signal_install();
    pb_bus_subscribe(bus, "LIDAR_SCAN", on_scan, &a);
    pb_bus_subscribe(bus, "IMU", on_imu, &a);
    pb_bus_subscribe(bus, "VEHICLE_SPEED", on_speed, &a);
    pb_bus_subscribe(bus, "GNSS_FIX", on_gnss, &a);
    pb_bus_subscribe(bus, "INITIAL_POSE", on_initial_pose, &a);
    pb_bus_add_timer(bus, cfg.predict_period_us, on_tick, &a);
    if (!in) fprintf(stderr, "localizer: listening on %s\n", pb_lcm_url(url));

    int rc = pb_bus_run(bus, &err);
    double tf = pb_clock_monotonic_ms();
    if (!a.frame_error) {
        localizer_finish(a.L, &a.out);
        flush(&a, tf);
    }
    if (a.frame_error) {
        rc = -1;   /* the STATUS saying why is set */
        pb_status_publish(a.status);
    } else {
        pb_status_finish(a.status, rc ? err.msg : NULL);
    }
    fprintf(stderr, "localizer: %zu sweeps, %lld POSE, %lld POSE_PREDICTED, sweep latency p50 %.1f ms p99 %.1f ms, final status %s\n",
            a.latency_ms.size(), (long long)a.poses, (long long)a.predicted, percentile(a.latency_ms, 0.5),
            percentile(a.latency_ms, 0.99), localizer_status_name(localizer_status(a.L)));
    if (a.stats) fclose(a.stats);
    pb_status_destroy(a.status);
    localizer_destroy(a.L);
    pb_points_free(&a.pts);
    map_source_close(a.map);
    pb_bus_destroy(bus);
    return rc == 0 ? 0 : 1;
}
