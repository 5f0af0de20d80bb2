// mapper: a recorded drive (LCM log) -> a whole site, by LiDAR odometry, loop closure,
// GNSS anchoring and carving what moved (docs/mapper.md). The shell: options, the log's
// three passes, the files; the logic is in core/ (odometry, loops, anchor, carve).
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <map>
#include <string>
#include <sys/stat.h>
#include <vector>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include "anchor.h"
#include "carve.h"
#include "loops.h"
#include "odometry.h"
#include "pb_clock.h"
#include "pb_err.h"
#include "pb_geo.h"
#include "pb_log.h"
#include "pb_map_build.h"
#include "pb_opt.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "picture.h"
#include "ground_build.h"
#include "map_source.h"
#include "pb_ground.h"
#include "portobello_gnss_fix_t.h"
#include "portobello_imu_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_vehicle_speed_t.h"
#include <cjson/cJSON.h>

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: mapper --log DRIVE.lcm --out SITE_DIR [--vehicle FILE] [--voxel 0.15]\n"
        "              [--scan-channel LIDAR_SCAN] [--quiet]\n"
        "\n"
        "Builds a prior map from a recorded drive by LiDAR odometry: every sweep is\n"
        "registered to a rolling local map of the sweeps before it (the localizer's\n"
        "registration), predicted by dead reckoning on VEHICLE_SPEED and the IMU's gyro when\n"
        "the log has them (else the last step's motion), then every point is placed with the\n"
        "pose at its own time.\n"
        
        "Where the drive passes a place again, the sweep is matched to the earlier pass's map\n"
        "and the poses are solved again with these loops (Ceres pose graph).\n"
        "Writes SITE_DIR/map.pcd (binary PCD, one point per voxel), SITE_DIR/trajectory.tum\n"
        "(base in map at the middle of each sweep, after loop closure; TUM: t x y z qx qy qz qw),\n"
        "SITE_DIR/odometry.tum (the same before loop closure), SITE_DIR/ground.yaml (+ .pgm, the\n"
        "ground model), SITE_DIR/map.tiles (the map prepared for the localizer), report.json and\n"
        "SITE_DIR/report.png (top-down: map grey, trajectory before loop closure orange and after\n"
        "blue, loops green, GNSS fixes red, points carved as moving objects magenta; north up\n"
        "when geo-referenced). With\n"
        "GNSS_FIX in the log, the map is moved onto the fixes (east-north-up at the first 3-D\n"
        "fix) and SITE_DIR/site.yaml holds that geo-reference; without, the map stays in the\n"
        "first sweep's frame and no site.yaml is written.\n"
        "  --vehicle FILE      base <- lidar (default vehicles/prius2017.yaml; scans imported from\n"
        "                      a dataset with their poses in the LiDAR frame: vehicles/lidar_mast.yaml)\n"
        "  --voxel M           map.pcd voxel edge, metres (default 0.15)\n"
        "  --scan-channel C    (default LIDAR_SCAN)\n"
        "  --quiet             no progress bar, no summary\n"
        "Exit 1 on error (unreadable or damaged log, no sweep, unwritable SITE_DIR).\n");
}

struct SweepPose {
    int64_t utime;
    Eigen::Isometry3d pose;      /* the odometry's; after loop closure, corrected */
    Eigen::Isometry3d odometry;
    int status, motion;          /* PB_ODOM_* and PB_ODOM_MOTION_* */
    double inlier_fraction, cpu_ms;
    int keyframe;                /* index of the last keyframe at or before it */
};

/* Keyframes for loop closure every this much path; their points kept at this voxel (about
 * 40 KB a keyframe on the simulated OS1-64). */
static const double kKeyframeSpacingM = 2.0;
static const double kKeyframeVoxelM = 0.5;

static pb_transform_t to_transform(const Eigen::Isometry3d &T)
{
    pb_transform_t t;
    pb_reg_to_transform(T, &t);
    return t;
}

/* Every sweep's pose moved by its keyframes' corrections (new * old^-1), interpolated in
 * time between the keyframe before it and the one after. */
static void apply_corrections(std::vector<SweepPose> *traj, const std::vector<pb_keyframe_t> &kf,
                              const std::vector<Eigen::Isometry3d> &solved)
{
    std::vector<Eigen::Isometry3d> C(kf.size());
    for (size_t k = 0; k < kf.size(); k++) C[k] = solved[k] * kf[k].pose.inverse();
    for (SweepPose &s : *traj) {
        size_t a = (size_t)s.keyframe, b = std::min(a + 1, kf.size() - 1);
        double u = b > a ? double(s.utime - kf[a].utime) / double(kf[b].utime - kf[a].utime) : 0;
        u = std::min(1.0, std::max(0.0, u));
        Eigen::Isometry3d Ci = Eigen::Isometry3d::Identity();
        Ci.linear() = Eigen::Quaterniond(C[a].linear()).slerp(u, Eigen::Quaterniond(C[b].linear())).toRotationMatrix();
        Ci.translation() = (1 - u) * C[a].translation() + u * C[b].translation();
        s.pose = Ci * s.odometry;
    }
}

/* The GNSS_FIX of the log against the trajectory (pb_anchor_fit). No fix at all: not
 * anchored (result->why says so), not an error. */
static int anchor_to_gnss(const char *log_path, const std::vector<SweepPose> &traj, const pb_vehicle_t &veh,
                          pb_anchor_result_t *result, pb_georef_t *georef, std::vector<Eigen::Vector3d> *fixes_enu,
                          pb_err_t *err)
{
    struct Fixes { std::vector<portobello_gnss_fix_t> v; int undecodable; } fixes = {{}, 0};
    auto on_fix = [](const pb_event_t *ev, void *u, pb_err_t *) {
        Fixes *f = (Fixes *)u;
        portobello_gnss_fix_t m;
        if (portobello_gnss_fix_t_decode(ev->data, 0, ev->datalen, &m) < 0) { f->undecodable++; return 0; }
        f->v.push_back(m);
        portobello_gnss_fix_t_decode_cleanup(&m);
        return 0;
    };
    if (pb_log_read_track(log_path, nullptr, nullptr, "GNSS_FIX", on_fix, &fixes, err)) return -1;
    *result = pb_anchor_result_t{};
    result->why = "no GNSS_FIX in the log";
    const portobello_gnss_fix_t *origin = nullptr;
    for (const auto &f : fixes.v)
        if (f.fix_type >= PORTOBELLO_GNSS_FIX_T_FIX_3D && f.fix_type != PORTOBELLO_GNSS_FIX_T_FIX_TIME_ONLY) { origin = &f; break; }
    if (!origin) {
        if (!fixes.v.empty()) result->why = "no 3-D GNSS fix in the log";
        return 0;
    }
    *georef = pb_georef_t{origin->lat_deg, origin->lon_deg, origin->alt_m, 0};
    pb_pose_track_t *track = pb_pose_track_create();
    for (const SweepPose &s : traj) {
        pb_transform_t t = to_transform(s.pose);
        pb_pose_track_add(track, s.utime, &t);
    }
    const Eigen::Vector3d lever(veh.base_from_gnss.t[0], veh.base_from_gnss.t[1], veh.base_from_gnss.t[2]);
    std::vector<pb_anchor_obs_t> obs;
    for (const auto &f : fixes.v) {
        pb_transform_t t;
        if (!pb_pose_track_at(track, f.utime, &t)) continue;   /* before the first sweep or after the last */
        pb_anchor_obs_t o;
        o.antenna_map = pb_reg_from_transform(&t) * lever;
        double enu[3];
        pb_geo_wgs84_to_map(georef, f.lat_deg, f.lon_deg, f.alt_m, enu);
        o.fix_enu = Eigen::Vector3d(enu[0], enu[1], enu[2]);
        fixes_enu->push_back(o.fix_enu);
        o.h_acc_m = f.h_acc_m;
        o.fix_3d = f.fix_type >= PORTOBELLO_GNSS_FIX_T_FIX_3D && f.fix_type != PORTOBELLO_GNSS_FIX_T_FIX_TIME_ONLY;
        obs.push_back(o);
    }
    pb_pose_track_destroy(track);
    if (obs.empty()) {
        result->why = "no GNSS fix within the drive's sweeps";
        return 0;
    }
    return pb_anchor_fit(obs, nullptr, result, err);
}

static int write_site_yaml(const char *path, const char *name, const char *log_path, const pb_georef_t &g, double voxel)
{
    std::string quoted;   /* the folder's name as a YAML double-quoted scalar */
    for (const char *c = name; *c; c++) {
        if (*c == '"' || *c == '\\') quoted += '\\';
        quoted += *c;
    }
    FILE *f = std::fopen(path, "w");
    if (!f) return -1;
    std::fprintf(f,
                 "# Written by build/bin/mapper from %s (docs/mapper.md).\n"
                 "name: \"%s\"\n"
                 "description: prior map built by the mapper from a recorded drive\n"
                 "# map frame: east-north-up at the drive's first 3-D GNSS fix (ellipsoid height)\n"
                 "georef:\n"
                 "  lat0_deg: %.9f\n"
                 "  lon0_deg: %.9f\n"
                 "  alt0_m: %.3f\n"
                 "  yaw_deg: 0.0\n"
                 "map:\n"
                 "  file: map.pcd\n"
                 "  frame: map\n"
                 "  voxel_m: %.3f\n",
                 log_path, quoted.c_str(), g.lat0_deg, g.lon0_deg, g.alt0_m, voxel);
    return std::fclose(f) == 0 ? 0 : -1;
}

static int write_tum(const char *path, const std::vector<SweepPose> &traj, bool odometry)
{
    FILE *f = std::fopen(path, "w");
    if (!f) return -1;
    for (const SweepPose &s : traj) {
        const Eigen::Isometry3d &T = odometry ? s.odometry : s.pose;
        Eigen::Quaterniond q(T.linear());
        const Eigen::Vector3d &p = T.translation();
        std::fprintf(f, "%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", s.utime * 1e-6, p.x(), p.y(), p.z(), q.x(), q.y(),
                     q.z(), q.w());
    }
    return std::fclose(f) == 0 ? 0 : -1;
}

static const char *kStatusName[] = {"first", "tracked", "searched", "weak", "predicted"};

static double pct(std::vector<double> v, double p)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, (size_t)std::floor(p * (double)(v.size() - 1) + 0.5))];
}

/* The car's own body in base (xmin, ymin, zmin, xmax, ymax, zmax), 10 cm larger than the
 * vehicle file's box, as the localizer's: returns from it (a roof the mount lets beams reach)
 * would be mapped along the whole drive. */
struct BodyBox {
    double b[6];
    explicit BodyBox(const pb_vehicle_t &v)
        : b{-v.rear_overhang - 0.1, -v.width / 2 - 0.1, -0.1, v.length - v.rear_overhang + 0.1, v.width / 2 + 0.1, v.height + 0.1} {}
    bool has(const Eigen::Vector3d &p) const
    {
        return p.x() >= b[0] && p.y() >= b[1] && p.z() >= b[2] && p.x() <= b[3] && p.y() <= b[4] && p.z() <= b[5];
    }
};

/* Every LIDAR_SCAN of the log in turn, without the points on the car's own body:
 * fn(utime, points in base, the same points in the lidar frame, event) returns 0 or -1;
 * other (if given) sees every other event first, in log order, and returns 0 or -1. */
using OtherFn = std::function<int(const pb_event_t &, pb_err_t *)>;
template <class F>
static int for_each_sweep(const char *log_path, const char *scan_ch, const pb_vehicle_t &veh, long every,
                          pb_progress_t *prog, F fn, long *empty, pb_err_t *err, const OtherFn &other = nullptr)
{
    const Eigen::Isometry3d base_from_lidar = pb_reg_from_transform(&veh.base_from_lidar);
    const BodyBox body(veh);
    pb_log_t *log = pb_log_open_read(log_path, err);
    if (!log) return -1;
    pb_points_t pts;
    std::memset(&pts, 0, sizeof pts);
    std::vector<float> xyz;
    pb_event_t ev;
    int rc, status = 0;
    long seen = 0;
    while ((rc = pb_log_next(log, &ev, err)) == 1) {
        if (std::strcmp(ev.channel, scan_ch) != 0) {
            if (other && other(ev, err) != 0) {
                pb_err_prefix(err, "%s: byte %lld: ", log_path, (long long)ev.offset);
                status = -1;
                break;
            }
            continue;
        }
        if (prog) pb_progress_update(prog, seen);
        if (seen++ % every) continue;
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) {
            pb_err_set(err, "%s: byte %lld: %s does not decode as lidar_scan_t", log_path, (long long)ev.offset,
                       ev.channel);
            status = -1;
            break;
        }
        int n = pb_scan_points(&s, &pts, err);
        int64_t utime = s.utime;
        portobello_lidar_scan_t_decode_cleanup(&s);
        if (n < 0) {
            pb_err_prefix(err, "%s: byte %lld: ", log_path, (long long)ev.offset);
            status = -1;
            break;
        }
        xyz.resize(3 * (size_t)n);
        int kept = 0;
        for (int i = 0; i < n; i++) {
            Eigen::Vector3d p = base_from_lidar * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
            if (body.has(p)) continue;
            xyz[3 * kept] = (float)p.x(); xyz[3 * kept + 1] = (float)p.y(); xyz[3 * kept + 2] = (float)p.z();
            pts.x[kept] = pts.x[i]; pts.y[kept] = pts.y[i]; pts.z[kept] = pts.z[i];
            pts.intensity[kept] = pts.intensity[i];
            pts.offset_us[kept] = pts.offset_us[i];
            pts.ring[kept] = pts.ring[i];
            kept++;
        }
        pts.n = kept;
        xyz.resize(3 * (size_t)kept);
        if (kept == 0) { (*empty)++; continue; }
        if (fn(utime, xyz, pts, ev, err) != 0) {
            pb_err_prefix(err, "%s: byte %lld: ", log_path, (long long)ev.offset);
            status = -1;
            break;
        }
    }
    if (rc < 0) status = -1;
    pb_log_close(log, nullptr);
    pb_points_free(&pts);
    return status;
}

/* One run: the options, and what each step hands the next. */
struct Run {
    const char *log_path, *out_dir, *scan_ch;
    double voxel;
    int quiet;
    pb_vehicle_t veh;
    long total = 0, empty = 0, out_of_order = 0;
    long by_motion[3] = {0, 0, 0};   /* sweeps predicted by PB_ODOM_MOTION_* */
    std::vector<SweepPose> traj;
    std::vector<pb_keyframe_t> kf;
    pb_loops_report_t loops = {};
    std::vector<std::pair<int64_t, int64_t>> loop_times;   /* kept loops: (earlier, later) keyframe utime */
    pb_anchor_result_t anchor = {};
    pb_georef_t georef = {};
    pb_picture_layers_t layers;
    pb_pose_track_t *track = nullptr;
    long placed = 0, unplaced = 0;
    pcl::PointCloud<pcl::PointXYZI> cloud;   /* the map, read back after pass 2 */
    std::string ground_why;                  /* empty: ground.yaml written */
    size_t carved = 0;
    double m_per_px = 0;
    std::string path(const char *name) const { return std::string(out_dir) + "/" + name; }
};

/* The car's own motion from the log: VEHICLE_SPEED (signed speed) and IMU (gyro, rotated
 * into base), gathered between sweeps for the odometry's dead reckoning. */
struct MotionSamples {
    Eigen::Matrix3d base_from_imu;
    std::vector<pb_odom_speed_t> speed;
    std::vector<pb_odom_rate_t> rate;

    int add(const pb_event_t &ev, pb_err_t *err)
    {
        if (std::strcmp(ev.channel, "VEHICLE_SPEED") == 0) {
            portobello_vehicle_speed_t m;
            if (portobello_vehicle_speed_t_decode(ev.data, 0, ev.datalen, &m) < 0)
                return pb_err_set(err, "%s does not decode as vehicle_speed_t", ev.channel), -1;
            if (std::isfinite(m.speed_mps)) speed.push_back({m.utime, m.speed_mps});
            portobello_vehicle_speed_t_decode_cleanup(&m);
        } else if (std::strcmp(ev.channel, "IMU") == 0) {
            portobello_imu_t m;
            if (portobello_imu_t_decode(ev.data, 0, ev.datalen, &m) < 0)
                return pb_err_set(err, "%s does not decode as imu_t", ev.channel), -1;
            Eigen::Vector3d w = base_from_imu * Eigen::Vector3d(m.gyro[0], m.gyro[1], m.gyro[2]);
            if (w.allFinite()) rate.push_back({m.utime, {w.x(), w.y(), w.z()}});
            portobello_imu_t_decode_cleanup(&m);
        }
        return 0;
    }
    /* Samples out of time order (two sources merged badly) are left out, not fatal. */
    pb_odom_motion_t take(int64_t last_speed, int64_t last_rate)
    {
        drop_unordered(&speed, last_speed);
        drop_unordered(&rate, last_rate);
        return {speed.data(), speed.size(), rate.data(), rate.size()};
    }
    template <class S>
    static void drop_unordered(std::vector<S> *v, int64_t last)
    {
        size_t k = 0;
        for (const S &x : *v)
            if (x.utime >= last) (*v)[k++] = x, last = x.utime;
        v->resize(k);
    }
};

/* Pass 1: odometry over every sweep; a keyframe every kKeyframeSpacingM. */
static int pass_odometry(Run *R, pb_err_t *err)
{
    pb_odom_t *odom = pb_odom_create(nullptr, nullptr);
    pb_reg_config_t kf_reduce;
    pb_reg_config_default(&kf_reduce);
    kf_reduce.target_points = 0;
    kf_reduce.scan_voxel_m = kKeyframeVoxelM;
    int64_t last_scan_utime = 0;
    R->traj.reserve((size_t)R->total);
    pb_progress_t prog;
    pb_progress_start(&prog, "mapper: odometry", R->total, R->quiet);
    MotionSamples ms;
    ms.base_from_imu = pb_reg_from_transform(&R->veh.base_from_imu).linear();
    int64_t last_speed = INT64_MIN, last_rate = INT64_MIN;
    int rc = for_each_sweep(R->log_path, R->scan_ch, R->veh, 1, &prog,
        [&](int64_t utime, const std::vector<float> &xyz, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            if (!R->traj.empty() && utime <= last_scan_utime) { R->out_of_order++; return 0; }
            last_scan_utime = utime;
            double c0 = pb_clock_thread_cpu_ms();
            pb_odom_result_t r;
            pb_odom_motion_t motion = ms.take(last_speed, last_rate);
            if (!ms.speed.empty()) last_speed = ms.speed.back().utime;
            if (!ms.rate.empty()) last_rate = ms.rate.back().utime;
            int ok = pb_odom_add(odom, utime, xyz.data(), pts.offset_us, xyz.size() / 3, &motion, &r, e);
            ms.speed.clear();
            ms.rate.clear();
            if (ok != 0) return -1;
            R->by_motion[r.motion]++;
            std::vector<pb_keyframe_t> &kf = R->kf;
            if (kf.empty() || (r.pose.translation() - kf.back().pose.translation()).norm() >= kKeyframeSpacingM) {
                kf.push_back({r.utime, r.pose, {}});
                const std::vector<float> &sw = pb_odom_last_sweep(odom);
                pb_reg_downsample(sw.data(), sw.size() / 3, &kf_reduce, &kf.back().xyz);
            }
            R->traj.push_back({r.utime, r.pose, r.pose, r.status, r.motion, r.inlier_fraction,
                               pb_clock_thread_cpu_ms() - c0, (int)kf.size() - 1});
            return 0;
        }, &R->empty, err, [&](const pb_event_t &ev, pb_err_t *e) { return ms.add(ev, e); });
    pb_odom_destroy(odom);
    if (rc != 0) {
        if (prog.tty && !R->quiet) std::fputc('\n', stderr);
        return -1;
    }
    pb_progress_finish(&prog);
    if (R->traj.size() < 2)
        return pb_err_set(err, "%s: %zu usable sweep(s) on %s; a map needs two or more", R->log_path, R->traj.size(),
                          R->scan_ch), -1;
    return 0;
}

/* The keyframes' poses solved again with the loops found; the sweeps moved with them. */
static int close_loops(Run *R, pb_err_t *err)
{
    std::vector<Eigen::Isometry3d> solved;
    if (R->kf.size() >= 2) {
        if (pb_loops_close(R->kf, nullptr, &solved, &R->loops, err) != 0) return -1;
        apply_corrections(&R->traj, R->kf, solved);
    }
    for (const auto &l : R->loops.loops)
        R->loop_times.push_back({R->kf[(size_t)l.first].utime, R->kf[(size_t)l.second].utime});
    R->kf.clear();
    R->kf.shrink_to_fit();
    return 0;
}

/* GNSS anchoring: the trajectory (and so the map) moved onto the fixes, in the
 * east-north-up frame at the first 3-D fix, which becomes the site's geo-reference. */
static int anchor(Run *R, pb_err_t *err)
{
    if (anchor_to_gnss(R->log_path, R->traj, R->veh, &R->anchor, &R->georef, &R->layers.fixes, err) != 0) return -1;
    if (R->anchor.anchored) {
        for (SweepPose &sp : R->traj) {
            sp.pose = R->anchor.enu_from_map * sp.pose;
            sp.odometry = R->anchor.enu_from_map * sp.odometry;
        }
    } else {
        R->layers.fixes.clear();   /* in no frame of this map */
        if (!R->quiet)
            std::fprintf(stderr, "mapper: warning: the map is not geo-referenced (%s); it stays in the first pose's frame\n",
                         R->anchor.why);
    }
    return 0;
}

/* Pass 2: the map, every point with the pose at its time, written and read back. The poses
 * are at the sweeps' middles: the track is carried on by the first and last steps' motion
 * to cover the first sweep's first half and the last one's second half. */
static int pass_map(Run *R, pb_err_t *err)
{
    const std::vector<SweepPose> &traj = R->traj;
    R->track = pb_pose_track_create();
    for (const SweepPose &s : traj) {
        pb_transform_t t = to_transform(s.pose);
        pb_pose_track_add(R->track, s.utime, &t);
    }
    for (int end = 0; end < 2; end++) {
        const SweepPose &a = end ? traj[traj.size() - 2] : traj[1], &b = end ? traj.back() : traj[0];
        pb_transform_t t = to_transform(b.pose * (a.pose.inverse() * b.pose));
        pb_pose_track_add(R->track, b.utime + (b.utime - a.utime), &t);
    }
    pb_map_builder_t *map = pb_map_builder_create(R->voxel, err);
    if (!map) return -1;
    long empty = 0;
    pb_progress_t prog;
    pb_progress_start(&prog, "mapper: map", R->total, R->quiet);
    int rc = for_each_sweep(R->log_path, R->scan_ch, R->veh, 1, &prog,
        [&](int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            int r = pb_map_builder_add_timed(map, &pts, utime, R->track, &R->veh.base_from_lidar, e);
            if (r < 0) return -1;
            (r ? R->placed : R->unplaced)++;
            return 0;
        }, &empty, err);
    if (rc == 0) pb_progress_finish(&prog);
    const std::string map_path = R->path("map.pcd");
    if (rc == 0) rc = pb_map_builder_write_pcd(map, map_path.c_str(), err);
    pb_map_builder_destroy(map);
    if (rc != 0) return -1;
    if (pcl::io::loadPCDFile(map_path, R->cloud) < 0) return pb_err_set(err, "%s: cannot read it back", map_path.c_str()), -1;
    return 0;
}

/* The ground model (tools/build-ground's core) from the map; a site without one is still a
 * site for the localizer: say why, go on. Kept for the carving. */
static pb_ground_t *make_ground(Run *R, pb_err_t *err)
{
    gb_config_t gcfg;
    gb_config_default(&gcfg);
    size_t nground = 0;
    pb_ground_t *ground = gb_build(R->cloud.empty() ? nullptr : &R->cloud.points[0].x, R->cloud.size(),
                                   sizeof(pcl::PointXYZI) / sizeof(float), &gcfg, &nground);
    const std::string ground_path = R->path("ground.yaml");
    if (!ground) R->ground_why = "no ground in the map";
    else if (pb_ground_save(ground, ground_path.c_str(), err) != 0) R->ground_why = err->msg;
    if (!R->ground_why.empty()) {
        std::remove(ground_path.c_str());
        std::fprintf(stderr, "mapper: warning: no ground model written: %s\n", R->ground_why.c_str());
    }
    return ground;
}

/* Pass 3: what moved is carved out of the map (core/carve.h), on a sample of the rays
 * (every 4th sweep, every 13th point: 13 is prime to the beam count, so every beam takes
 * its turn); the band over the ground model is spared. map.pcd is written again. */
static int pass_carve(Run *R, const pb_ground_t *ground, pb_err_t *err)
{
    pb_carve_t *carve = pb_carve_create(&R->cloud.points[0].x, R->cloud.size(), sizeof(pcl::PointXYZI) / sizeof(float),
                                        ground, nullptr);
    const Eigen::Isometry3d bl = pb_reg_from_transform(&R->veh.base_from_lidar);
    long empty = 0;
    pb_progress_t prog;
    pb_progress_start(&prog, "mapper: carve", R->total, R->quiet);
    int rc = for_each_sweep(R->log_path, R->scan_ch, R->veh, 4, &prog,
        [&](int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *) {
            int32_t cached = INT32_MIN;
            Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
            bool have = false;
            for (int i = 0; i < pts.n; i += 13) {
                if (pts.offset_us[i] != cached) {   /* a column's points share their time */
                    cached = pts.offset_us[i];
                    pb_transform_t t;
                    have = pb_pose_track_at(R->track, utime + cached, &t);
                    if (have) T = pb_reg_from_transform(&t) * bl;
                }
                if (!have) continue;
                Eigen::Vector3d o = T.translation(), e = T * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
                pb_carve_ray(carve, utime + cached, o.data(), e.data());
            }
            return 0;
        }, &empty, err);
    std::vector<uint8_t> keep;
    if (rc == 0) {
        pb_progress_finish(&prog);
        R->carved = pb_carve_keep(carve, &keep);
    }
    pb_carve_destroy(carve);
    if (rc != 0) return -1;
    pcl::PointCloud<pcl::PointXYZI> kept;
    kept.reserve(R->cloud.size() - R->carved);
    for (size_t i = 0; i < R->cloud.size(); i++) {
        const pcl::PointXYZI &q = R->cloud.points[i];
        if (keep[i]) kept.push_back(q);
        else R->layers.removed.insert(R->layers.removed.end(), {q.x, q.y, q.z});
    }
    R->cloud.swap(kept);
    const std::string map_path = R->path("map.pcd"), tmp = map_path + ".tmp";
    if (pcl::io::savePCDFileBinary(tmp, R->cloud) < 0 || std::rename(tmp.c_str(), map_path.c_str()) != 0) {
        std::remove(tmp.c_str());
        return pb_err_set(err, "%s: cannot write", map_path.c_str()), -1;
    }
    return 0;
}

/* The trajectories, the tiles the localizer pages (its map_source, from the map as
 * written), the picture and site.yaml. */
static int write_site(Run *R, pb_err_t *err)
{
    if (write_tum(R->path("trajectory.tum").c_str(), R->traj, false) != 0 ||
        write_tum(R->path("odometry.tum").c_str(), R->traj, true) != 0)
        return pb_err_set(err, "%s: cannot write the trajectories: %s", R->out_dir, std::strerror(errno)), -1;
    if (map_source_write_tiles(R->path("map.pcd").c_str(), R->path("map.tiles").c_str(), MAP_SOURCE_TILE_M, nullptr,
                               nullptr, nullptr, err) != 0)
        return -1;
    std::map<int64_t, Eigen::Vector3d> at;
    for (const SweepPose &sp : R->traj) {
        R->layers.before.push_back(sp.odometry.translation());
        R->layers.after.push_back(sp.pose.translation());
        at[sp.utime] = sp.pose.translation();
    }
    for (const auto &lt : R->loop_times)
        if (at.count(lt.first) && at.count(lt.second)) R->layers.loops.push_back({at[lt.first], at[lt.second]});
    if (pb_picture_write(R->cloud.empty() ? nullptr : &R->cloud.points[0].x, R->cloud.size(),
                         sizeof(pcl::PointXYZI) / sizeof(float), &R->layers, R->path("report.png").c_str(), &R->m_per_px,
                         err) != 0)
        return -1;
    const std::string site_path = R->path("site.yaml");
    if (!R->anchor.anchored) {
        std::remove(site_path.c_str());   /* one from an earlier run would geo-reference this map wrongly */
        return 0;
    }
    std::string name = R->out_dir;
    while (name.size() > 1 && name.back() == '/') name.pop_back();
    name = name.substr(name.find_last_of('/') + 1);
    if (write_site_yaml(site_path.c_str(), name.c_str(), R->log_path, R->georef, R->voxel) != 0)
        return pb_err_set(err, "%s: cannot write: %s", site_path.c_str(), std::strerror(errno)), -1;
    return 0;
}

/* report.json (cJSON: names and messages escaped) and the summary line. */
static int write_report(const Run &R, const double cpu_ms[4], double wall_s, pb_err_t *err)
{
    long by_status[5] = {};
    double path_m = 0;
    std::vector<double> ms, inl;
    for (size_t i = 0; i < R.traj.size(); i++) {
        const SweepPose &s = R.traj[i];
        by_status[s.status]++;
        if (i > 0) path_m += (s.pose.translation() - R.traj[i - 1].pose.translation()).norm();
        ms.push_back(s.cpu_ms);
        if (std::isfinite(s.inlier_fraction)) inl.push_back(s.inlier_fraction);
    }
    const double span_s = (R.traj.back().utime - R.traj.front().utime) * 1e-6;
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "log", R.log_path);
    cJSON_AddNumberToObject(j, "scans", (double)R.traj.size());
    cJSON_AddNumberToObject(j, "scans_in_log", (double)R.total);
    cJSON_AddNumberToObject(j, "empty_scans", (double)R.empty);
    cJSON_AddNumberToObject(j, "out_of_order_scans", (double)R.out_of_order);
    for (int k = 0; k < 5; k++) cJSON_AddNumberToObject(j, (std::string("scans_") + kStatusName[k]).c_str(), (double)by_status[k]);
    /* what each sweep's prediction came from: dead reckoning on VEHICLE_SPEED and IMU, the
     * last step's motion (LiDAR alone), or nothing (the first sweep, after a gap) */
    cJSON_AddNumberToObject(j, "scans_motion_measured", (double)R.by_motion[PB_ODOM_MOTION_MEASURED]);
    cJSON_AddNumberToObject(j, "scans_motion_constant", (double)R.by_motion[PB_ODOM_MOTION_CONSTANT]);
    cJSON_AddNumberToObject(j, "scans_motion_none", (double)R.by_motion[PB_ODOM_MOTION_NONE]);
    cJSON_AddNumberToObject(j, "loop_candidates", R.loops.candidates);
    cJSON_AddNumberToObject(j, "loop_candidates_by_place", R.loops.place_candidates);
    cJSON_AddNumberToObject(j, "loops", R.loops.verified);
    cJSON_AddNumberToObject(j, "loops_by_position", R.loops.verified - R.loops.place_loops);
    cJSON_AddNumberToObject(j, "loops_by_place", R.loops.place_loops);
    cJSON_AddNumberToObject(j, "loops_rejected", R.loops.rejected);
    cJSON_AddNumberToObject(j, "loops_dropped", R.loops.dropped);
    cJSON_AddNumberToObject(j, "loop_correction_max_m", R.loops.max_change_m);
    cJSON_AddBoolToObject(j, "ground_model", R.ground_why.empty());
    cJSON_AddStringToObject(j, "ground_model_why_not", R.ground_why.c_str());
    cJSON_AddBoolToObject(j, "geo_referenced", R.anchor.anchored);
    cJSON_AddStringToObject(j, "geo_reference_why_not", R.anchor.anchored ? "" : R.anchor.why);
    cJSON_AddNumberToObject(j, "gnss_fixes_used", R.anchor.used);
    cJSON_AddNumberToObject(j, "gnss_fixes_gated", R.anchor.gated);
    cJSON_AddNumberToObject(j, "gnss_fixes_rejected", R.anchor.rejected);
    cJSON_AddNumberToObject(j, "gnss_resid_median_m", R.anchor.resid_median_m);
    cJSON_AddNumberToObject(j, "gnss_resid_p90_m", R.anchor.resid_p90_m);
    cJSON_AddNumberToObject(j, "gnss_resid_max_m", R.anchor.resid_max_m);
    cJSON_AddNumberToObject(j, "inlier_fraction_median", inl.empty() ? 0 : pct(inl, 0.5));
    cJSON_AddNumberToObject(j, "inlier_fraction_p01", inl.empty() ? 0 : pct(inl, 0.01));
    cJSON_AddNumberToObject(j, "path_m", path_m);
    cJSON_AddNumberToObject(j, "drive_s", span_s);
    cJSON_AddNumberToObject(j, "cpu_ms_per_scan_median", pct(ms, 0.5));
    cJSON_AddNumberToObject(j, "cpu_ms_per_scan_p99", pct(ms, 0.99));
    cJSON_AddNumberToObject(j, "cpu_s_odometry", (cpu_ms[1] - cpu_ms[0]) / 1e3);
    cJSON_AddNumberToObject(j, "cpu_s_loops", (cpu_ms[2] - cpu_ms[1]) / 1e3);
    cJSON_AddNumberToObject(j, "cpu_s_map", (cpu_ms[3] - cpu_ms[2]) / 1e3);
    cJSON_AddNumberToObject(j, "wall_s", wall_s);
    cJSON_AddStringToObject(j, "picture", "report.png");
    cJSON_AddNumberToObject(j, "picture_m_per_px", R.m_per_px);
    cJSON_AddNumberToObject(j, "map_points", (double)R.cloud.size());
    cJSON_AddNumberToObject(j, "map_points_carved", (double)R.carved);
    cJSON_AddNumberToObject(j, "map_voxel_m", R.voxel);
    cJSON_AddNumberToObject(j, "scans_placed", (double)R.placed);
    cJSON_AddNumberToObject(j, "scans_unplaced", (double)R.unplaced);
    char *text = cJSON_Print(j);
    cJSON_Delete(j);
    const std::string rep_path = R.path("report.json");
    FILE *f = text ? std::fopen(rep_path.c_str(), "w") : nullptr;
    bool ok = f && std::fputs(text, f) >= 0 && std::fputc('\n', f) != EOF;
    if (f) ok &= std::fclose(f) == 0;
    cJSON_free(text);
    if (!ok) return pb_err_set(err, "%s: cannot write", rep_path.c_str()), -1;
    if (!R.quiet)
        std::fprintf(stderr,
                     "mapper: %zu sweeps over %.1f m in %.1f s of drive (tracked %ld, searched %ld, weak %ld, "
                     "predicted %ld); %d loop(s) of %d tried, largest correction %.2f m; odometry %.2f ms per sweep "
                     "(median CPU), %zu map points (%zu carved: moved); %.1f s wall\n",
                     R.traj.size(), path_m, span_s, by_status[PB_ODOM_TRACKED], by_status[PB_ODOM_SEARCHED],
                     by_status[PB_ODOM_WEAK], by_status[PB_ODOM_PREDICTED], R.loops.verified, R.loops.candidates,
                     R.loops.max_change_m, pct(ms, 0.5), R.cloud.size(), R.carved, wall_s);
    return 0;
}

int main(int argc, char **argv)
{
    Run R;
    R.log_path = nullptr;
    R.out_dir = nullptr;
    R.scan_ch = "LIDAR_SCAN";
    R.voxel = 0.15;
    R.quiet = 0;
    const char *vehicle = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &R.log_path), PB_OPT_REQUIRED("out", &R.out_dir), PB_OPT_STRING("vehicle", &vehicle),
        PB_OPT_STRING("scan-channel", &R.scan_ch), PB_OPT_DOUBLE("voxel", &R.voxel, 0.01, 10),
        PB_OPT_FLAG("quiet", &R.quiet, 1), PB_OPT_END,
    };
    int parsed = pb_opt_parse("mapper", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    const auto wall0 = std::chrono::steady_clock::now();
    double cpu_ms[4] = {pb_clock_process_cpu_ms(), 0, 0, 0};
    pb_err_t err;
    int rc = pb_vehicle_load(vehicle, &R.veh, &err);
    if (rc == 0 && mkdir(R.out_dir, 0777) != 0 && errno != EEXIST)
        rc = pb_err_set(&err, "%s: cannot create: %s", R.out_dir, std::strerror(errno));
    // the sweeps counted, for the progress bars
    if (rc == 0)
        rc = pb_log_read_track(R.log_path, nullptr, nullptr, R.scan_ch,
                               [](const pb_event_t *, void *u, pb_err_t *) { (*(long *)u)++; return 0; }, &R.total, &err);
    if (rc == 0 && R.total == 0) rc = pb_err_set(&err, "%s: no %s in the log", R.log_path, R.scan_ch);
    // 1. odometry; a keyframe every 2 m
    if (rc == 0) rc = pass_odometry(&R, &err);
    cpu_ms[1] = pb_clock_process_cpu_ms();
    // 2. loop closure over the keyframes
    if (rc == 0) rc = close_loops(&R, &err);
    // 3. GNSS anchoring
    if (rc == 0) rc = anchor(&R, &err);
    cpu_ms[2] = pb_clock_process_cpu_ms();
    // 4. the map with the final poses
    if (rc == 0) rc = pass_map(&R, &err);
    // 5. the ground model, and what moved carved out with it
    pb_ground_t *ground = rc == 0 ? make_ground(&R, &err) : nullptr;
    if (rc == 0) rc = pass_carve(&R, ground, &err);
    pb_ground_destroy(ground);
    pb_pose_track_destroy(R.track);
    // 6. the site's other files, the report
    if (rc == 0) rc = write_site(&R, &err);
    cpu_ms[3] = pb_clock_process_cpu_ms();
    if (rc == 0)
        rc = write_report(R, cpu_ms, std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count(), &err);
    if (rc != 0) {
        std::fprintf(stderr, "mapper: %s\n", err.msg);
        return 1;
    }
    return 0;
}
