// mapper: a recorded drive (LCM log) -> a whole site, by LiDAR odometry, loop closure,
// GNSS anchoring and carving what moved (docs/mapper.md). The shell: options, the log's
// three passes, the files; the logic is in core/ (odometry, loops, anchor, carve).
#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <initializer_list>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <fcntl.h>
#include <malloc.h>
#include <sys/stat.h>
#include <unistd.h>
#include <vector>

#include "anchor.h"
#include "carve.h"
#include "loops.h"
#include "odometry.h"
#include "pose_graph.h"
#include "pb_bytes.h"
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
        "usage: mapper --log DRIVE.lcm [--log DRIVE2.lcm ...] --out SITE_DIR [--vehicle FILE] [--voxel 0.15]\n"
        "              [--poses FILE.tum]\n"
        "              [--scan-channel LIDAR_SCAN] [--checkpoint-every 100] [--tile-m 32] [--quiet]\n"
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
        "fix) and SITE_DIR/site.yaml holds that geo-reference; a trajectory that stays farther\n"
        "from the fixes than their reported accuracy (a drift) is bent onto them (one drive);\n"
        "without GNSS, the map stays in the first sweep's frame and no site.yaml is written.\n"
        "Several drives of the same course (--log repeated): each gets its own odometry, then\n"
        "each later drive is placed in the first drive's frame by matching its places to the\n"
        "earlier drives' (two matches that agree, verified by registration), one pose graph\n"
        "joins them all, the map is made from all, and what one drive saw through where another\n"
        "saw something (a car parked, then gone) is carved. A drive that cannot be placed is\n"
        "left out of the map and said so (stderr, report.json \"drives\"). The first drive's\n"
        "trajectory is trajectory.tum, drive N's trajectory.N.tum (odometry.N.tum); GNSS\n"
        "anchoring fits all placed drives' fixes; checkpoints are per drive (checkpoint.N.bin).\n"
        "Restartable: while it runs, SITE_DIR/checkpoint.bin and keyframes.bin hold the odometry\n"
        "so far; run the same command again after an interruption (Ctrl-C, power loss, a kill)\n"
        "and it resumes there, with the same result as a run without one. A checkpoint of\n"
        "another log, build of the mapper or --vehicle/--scan-channel is refused (said on\n"
        "stderr and in report.json) and the run starts over; a finished run removes both.\n"
        "  --log FILE          a recorded drive (repeat for several drives of the course; the\n"
        "                      first one's frame is the map's)\n"
        "  --vehicle FILE      base <- lidar (default vehicles/prius2017.yaml; scans imported from\n"
        "                      a dataset with their poses in the LiDAR frame: vehicles/lidar_mast.yaml)\n"
        "  --voxel M           map.pcd voxel edge, metres (default 0.15)\n"
        "  --scan-channel C    (default LIDAR_SCAN)\n"
        "  --checkpoint-every N  sweeps of odometry between checkpoints (default 100: 10 s of drive)\n"
        "  --poses FILE.tum    place the sweeps with these poses (base in map, TUM: t x y z qx qy qz\n"
        "                      qw, t in seconds; an INS or RTK trajectory, another SLAM's): no\n"
        "                      odometry and no loop closure; the map, ground, carving and report\n"
        "                      as otherwise (report.json: poses_given; scans = the poses)\n"
        "  --tile-m M          edge of the map's tiles while it is built and carved (default 32): only\n"
        "                      those within the sensor's reach are held, the others wait in\n"
        "                      SITE_DIR/map-tiles.tmp (the same map.pcd whatever the edge)\n"
        "  --quiet             no progress bar, no summary\n"
        "Exit 1 on error (unreadable or damaged log, no sweep, unwritable SITE_DIR).\n");
}

/* SweepPose.status and .motion of a pose given by --poses (not the odometry's). */
static const int kGiven = -1;

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
    std::vector<int64_t> node_utime, utime;
    std::vector<Eigen::Isometry3d> before, poses;
    for (const pb_keyframe_t &k : kf) { node_utime.push_back(k.utime); before.push_back(k.pose); }
    for (const SweepPose &s : *traj) { utime.push_back(s.utime); poses.push_back(s.odometry); }
    pb_pose_graph_apply(node_utime, before, solved, utime, &poses);
    for (size_t i = 0; i < traj->size(); i++) (*traj)[i].pose = poses[i];
}

/* The GNSS_FIX of the log (one that does not decode is not used). */
static int read_fixes(const char *log_path, std::vector<portobello_gnss_fix_t> *out, pb_err_t *err)
{
    auto on_fix = [](const pb_event_t *ev, void *u, pb_err_t *) {
        portobello_gnss_fix_t m;
        if (portobello_gnss_fix_t_decode(ev->data, 0, ev->datalen, &m) < 0) return 0;   /* not a fix: not used */
        ((std::vector<portobello_gnss_fix_t> *)u)->push_back(m);
        portobello_gnss_fix_t_decode_cleanup(&m);
        return 0;
    };
    return pb_log_read_track(log_path, nullptr, nullptr, "GNSS_FIX", on_fix, out, err);
}

static bool is_3d(const portobello_gnss_fix_t &f)
{
    return f.fix_type >= PORTOBELLO_GNSS_FIX_T_FIX_3D && f.fix_type != PORTOBELLO_GNSS_FIX_T_FIX_TIME_ONLY;
}

/* The fixes against the trajectory: where it puts the antenna at each fix's time, and the
 * fix in the east-north-up frame at georef (fixes outside the sweeps' times left out). */
static std::vector<pb_anchor_obs_t> observe_fixes(const std::vector<portobello_gnss_fix_t> &fixes,
                                                  const std::vector<SweepPose> &traj, const pb_vehicle_t &veh,
                                                  const pb_georef_t &georef)
{
    pb_pose_track_t *track = pb_pose_track_create();
    for (const SweepPose &s : traj) {
        pb_transform_t t = to_transform(s.pose);
        pb_pose_track_add(track, s.utime, &t);
    }
    const Eigen::Vector3d lever(veh.base_from_gnss.t[0], veh.base_from_gnss.t[1], veh.base_from_gnss.t[2]);
    std::vector<pb_anchor_obs_t> obs;
    for (const auto &f : fixes) {
        pb_transform_t t;
        if (!pb_pose_track_at(track, f.utime, &t)) continue;   /* before the first sweep or after the last */
        pb_anchor_obs_t o;
        o.utime = f.utime;
        o.antenna_map = pb_reg_from_transform(&t) * lever;
        double enu[3];
        pb_geo_wgs84_to_map(&georef, f.lat_deg, f.lon_deg, f.alt_m, enu);
        o.fix_enu = Eigen::Vector3d(enu[0], enu[1], enu[2]);
        o.h_acc_m = f.h_acc_m;
        o.fix_3d = is_3d(f);
        obs.push_back(o);
    }
    pb_pose_track_destroy(track);
    return obs;
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

/* Peak resident memory (VmHWM) since the last reset_peak_rss, MB; 0 where /proc has none. */
static double peak_rss_mb()
{
    FILE *f = std::fopen("/proc/self/status", "r");
    if (!f) return 0;
    char line[256];
    long kb = 0;
    while (std::fgets(line, sizeof line, f))
        if (std::sscanf(line, "VmHWM: %ld", &kb) == 1) break;
    std::fclose(f);
    return kb / 1024.0;
}

/* Starts the next step's peak from the memory held now (Linux: "5" to clear_refs), after
 * handing the heap freed by the step back (glibc keeps it, and the next step's large
 * blocks are mapped anew beside it). */
static void reset_peak_rss()
{
    malloc_trim(0);
    FILE *f = std::fopen("/proc/self/clear_refs", "w");
    if (f) { std::fputs("5", f); std::fclose(f); }
}

static const char *kPeakStep[] = {"odometry", "loops", "map", "carve", "site"};

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
    explicit BodyBox(const pb_vehicle_t &v) { pb_vehicle_body_box(&v, 0.10, b); }
    bool has(const Eigen::Vector3d &p) const
    {
        return p.x() >= b[0] && p.y() >= b[1] && p.z() >= b[2] && p.x() <= b[3] && p.y() <= b[4] && p.z() <= b[5];
    }
};

/* One event of the log as for_each_sweep's reader hands it on: a sweep decoded (its points
 * in base and in the lidar frame), another channel's event (its bytes copied), or the end. */
struct LogItem {
    enum { SWEEP, OTHER, END } kind = END;
    int64_t utime = 0;
    std::vector<float> xyz;
    pb_points_t pts = {};
    std::string channel;
    std::vector<uint8_t> data;
    pb_event_t ev = {};
    int status = 0;   /* END: 0 the log's end, -1 an error (err) */
    pb_err_t err;
    LogItem() = default;
    LogItem(const LogItem &) = delete;
    ~LogItem() { pb_points_free(&pts); }
};

/* Every LIDAR_SCAN of the log in turn after the first *seen (skipped unread), without the
 * points on the car's own body: fn(utime, points in base, the same points in the lidar
 * frame, event) returns 0 or -1; *seen counts the scans read (fn's included). other (if
 * given) sees every other event after the skipped scans, in log order, and returns 0 or -1.
 * read_ahead: the log is read and the sweeps decoded on a second thread, a few sweeps ahead
 * of fn (a pass whose own work is single-threaded: the decoding costs a fifth of the map
 * pass); fn and other run on the caller's thread, in log order, either way. */
using OtherFn = std::function<int(const pb_event_t &, pb_err_t *)>;
template <class F>
static int for_each_sweep(const char *log_path, const char *scan_ch, const pb_vehicle_t &veh, long every, long *seen,
                          pb_progress_t *prog, F fn, long *empty, pb_err_t *err, const OtherFn &other = nullptr,
                          bool read_ahead = false)
{
    pb_log_t *log = pb_log_open_read(log_path, err);
    if (!log) return -1;
    int status = 0;
    std::atomic<bool> stop(false);
    /* one item to fn or other; false once one of them failed (the rest is drained) */
    auto consume = [&](LogItem &it) {
        if (it.kind == LogItem::END) {
            if (it.status != 0 && status == 0) { *err = it.err; status = -1; }
            return false;
        }
        if (status != 0) return false;
        int r;
        if (it.kind == LogItem::OTHER) {
            it.ev.channel = it.channel.c_str();
            it.ev.data = it.data.data();
            r = other(it.ev, err);
        } else {
            r = fn(it.utime, it.xyz, it.pts, it.ev, err);
        }
        if (r != 0) {
            pb_err_prefix(err, "%s: byte %lld: ", log_path, (long long)it.ev.offset);
            status = -1;
            stop = true;   /* the reader ends at its next event */
        }
        return r == 0;
    };
    std::mutex mu;
    std::condition_variable cv;
    std::deque<std::unique_ptr<LogItem>> queue;
    /* items consumed, taken again by the reader: a sweep's arrays keep their capacity
     * (a fresh megabyte a sweep would be page faults on the hot path) */
    std::vector<std::unique_ptr<LogItem>> spare;
    const size_t kAhead = 4;
    auto take = [&] {
        std::lock_guard<std::mutex> lk(mu);
        if (spare.empty()) return std::unique_ptr<LogItem>(new LogItem);
        std::unique_ptr<LogItem> it = std::move(spare.back());
        spare.pop_back();
        return it;
    };
    auto give_back = [&](std::unique_ptr<LogItem> it) {
        std::lock_guard<std::mutex> lk(mu);
        spare.push_back(std::move(it));
    };
    auto push = [&](std::unique_ptr<LogItem> it) {
        if (!read_ahead) { consume(*it); give_back(std::move(it)); return; }
        std::unique_lock<std::mutex> lk(mu);
        cv.wait(lk, [&] { return queue.size() < kAhead || stop; });
        queue.push_back(std::move(it));
        cv.notify_all();
    };
    auto read = [&] {
        const Eigen::Isometry3d base_from_lidar = pb_reg_from_transform(&veh.base_from_lidar);
        const BodyBox body(veh);
        const long skip = *seen;
        long nread = 0;
        pb_event_t ev;
        int rc = 0;
        std::unique_ptr<LogItem> end(new LogItem);
        while (!stop && (rc = pb_log_next(log, &ev, &end->err)) == 1) {
            if (std::strcmp(ev.channel, scan_ch) != 0) {
                if (!other || nread < skip) continue;
                std::unique_ptr<LogItem> it = take();
                it->kind = LogItem::OTHER;
                it->channel = ev.channel;
                it->data.assign(ev.data, ev.data + ev.datalen);
                it->ev = ev;
                push(std::move(it));
                continue;
            }
            if (nread++ < skip) continue;
            if (prog) pb_progress_update(prog, *seen);
            if ((*seen)++ % every) continue;
            portobello_lidar_scan_t s;
            if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) {
                pb_err_set(&end->err, "%s: byte %lld: %s does not decode as lidar_scan_t", log_path,
                           (long long)ev.offset, ev.channel);
                rc = -1;
                break;
            }
            std::unique_ptr<LogItem> it = take();
            int n = pb_scan_points(&s, &it->pts, &end->err);
            it->utime = s.utime;
            portobello_lidar_scan_t_decode_cleanup(&s);
            if (n < 0) {
                pb_err_prefix(&end->err, "%s: byte %lld: ", log_path, (long long)ev.offset);
                rc = -1;
                break;
            }
            pb_points_t &pts = it->pts;
            it->xyz.resize(3 * (size_t)n);
            int kept = 0;
            for (int i = 0; i < n; i++) {
                Eigen::Vector3d p = base_from_lidar * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
                if (body.has(p)) continue;
                float *q = &it->xyz[3 * (size_t)kept];
                q[0] = (float)p.x(); q[1] = (float)p.y(); q[2] = (float)p.z();
                pts.x[kept] = pts.x[i]; pts.y[kept] = pts.y[i]; pts.z[kept] = pts.z[i];
                pts.intensity[kept] = pts.intensity[i];
                pts.offset_us[kept] = pts.offset_us[i];
                pts.ring[kept] = pts.ring[i];
                kept++;
            }
            pts.n = kept;
            it->xyz.resize(3 * (size_t)kept);
            if (kept == 0) { (*empty)++; continue; }
            it->kind = LogItem::SWEEP;
            it->ev = ev;
            it->ev.data = nullptr;   /* the sweep's bytes are not kept */
            push(std::move(it));
        }
        end->kind = LogItem::END;
        end->status = rc < 0 ? -1 : 0;
        push(std::move(end));
    };
    if (!read_ahead) {
        read();
    } else {
        std::thread reader(read);
        for (bool more = true; more;) {
            std::unique_ptr<LogItem> it;
            {
                std::unique_lock<std::mutex> lk(mu);
                cv.wait(lk, [&] { return !queue.empty(); });
                it = std::move(queue.front());
                queue.pop_front();
            }
            more = it->kind != LogItem::END;
            consume(*it);
            give_back(std::move(it));
            std::lock_guard<std::mutex> lk(mu);
            cv.notify_all();
        }
        reader.join();
    }
    pb_log_close(log, nullptr);
    return status;
}

using SweepKey = std::pair<int, int64_t>;   /* a sweep's drive and utime */

/* One run: the options, and what each step hands the next. */
struct Run {
    const char *log_path, *out_dir, *scan_ch;
    const char *poses_path = nullptr;   /* --poses: the sweeps placed with these, no odometry */
    double voxel;
    int quiet;
    int checkpoint_every;   /* sweeps between checkpoints of the odometry pass */
    pb_vehicle_t veh;
    long total = 0, empty = 0, out_of_order = 0;
    std::vector<SweepPose> traj;
    std::vector<pb_keyframe_t> kf;
    pb_loops_report_t loops = {};
    std::vector<std::pair<SweepKey, SweepKey>> loop_times;   /* kept loops: (earlier, later) keyframe */
    pb_anchor_result_t anchor = {};
    pb_anchor_hold_result_t hold = {};
    pb_georef_t georef = {};
    pb_picture_layers_t layers;
    pb_pose_track_t *track = nullptr;
    long placed = 0, unplaced = 0;
    /* the map in tiles (pass 2 -> map.pcd): their folder, their edge (--tile-m) */
    std::string tiles_dir;
    double tile_m = 32;
    size_t voxels = 0;                       /* made by pass 2 (seq 0 .. voxels - 1) */
    double ground_lo[2], ground_hi[2];       /* the map's extent, for the ground model */
    std::set<int64_t> carve_tiles;           /* the carving's tiles that hold points */
    std::vector<std::pair<int64_t, uint32_t>> kept_tiles;   /* after it: tile, seq of its next point to write */
    long tiles_held_max = 0, carve_tiles_held_max = 0, tiles_paged_out = 0, carve_tiles_paged_out = 0;
    long tiles_paged_in = 0, carve_tiles_paged_in = 0;   /* paged out, then back in */
    int64_t voxels_held_max = 0;
    size_t map_points = 0;                   /* in map.pcd */
    std::string ground_why;                  /* empty: ground.yaml written */
    size_t carved = 0;
    double m_per_px = 0;
    double peak_mb[5] = {};                  /* peak resident memory of each step (kPeakStep) */
    /* restart (checkpoint_*): what a checkpoint must match, and the odometry pass's state */
    std::string log_id, build_id, options_id;
    long resumed_from = 0;                   /* scans the checkpoint had read; 0: not resumed */
    std::string checkpoint_refused;          /* why a checkpoint found was not used */
    FILE *kf_file = nullptr;                 /* keyframes.bin, appended at each checkpoint */
    size_t kf_saved = 0;                     /* keyframes in it */
    uint64_t kf_bytes = 0;                   /* its valid length */
    pb_odom_t *odom = nullptr;               /* restored odometry (NULL: start at the first scan) */
    long seen = 0;                           /* scans read by the odometry pass */
    int64_t last_scan_utime = 0;
    bool odometry_done = false;              /* restored after the whole odometry pass */
    /* several drives (--log repeated): one Run each, the first one's also the site's */
    int drive = 0;                           /* 0, 1, ... in the order of --log */
    std::vector<Run *> drives;               /* in the first: every drive's Run, itself first */
    pb_drive_report_t placement = {true, "", 0, 0, 0, Eigen::Isometry3d::Identity()};
    std::string path(const char *name) const { return std::string(out_dir) + "/" + name; }
    std::string label(const char *what) const   /* a progress bar's */
    {
        return drive ? std::string(what) + " (drive " + std::to_string(drive + 1) + ")" : what;
    }
    /* a drive's own work file: NAME.bin for the first, NAME.N.bin for drive N */
    std::string work(const char *name) const
    {
        return drive ? path(name) + "." + std::to_string(drive + 1) + ".bin" : path(name) + ".bin";
    }
};

/* fn(D, utime, points in base, in the lidar frame, event, err) on every `every`-th sweep of
 * each placed drive D in turn, read ahead, each drive with its progress bar ("what"). */
template <class F>
static int for_each_drive_sweep(Run *R, const char *what, long every, F fn, pb_err_t *err)
{
    int rc = 0;
    for (Run *D : R->drives) {
        if (rc != 0 || !D->placement.placed) continue;
        long empty = 0, seen = 0;
        pb_progress_t prog;
        const std::string label = D->label(what);   /* the bar keeps the pointer */
        pb_progress_start(&prog, label.c_str(), D->total, R->quiet);
        rc = for_each_sweep(D->log_path, R->scan_ch, R->veh, every, &seen, &prog,
            [&](int64_t utime, const std::vector<float> &xyz, const pb_points_t &pts, const pb_event_t &ev, pb_err_t *e) {
                return fn(D, utime, xyz, pts, ev, e);
            }, &empty, err, nullptr, true);
        if (rc == 0) pb_progress_finish(&prog);
    }
    return rc;
}

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
    pb_odom_motion_t view() const { return {speed.data(), speed.size(), rate.data(), rate.size()}; }
};


/* ---- Restart after an interruption (docs/mapper.md, "Restart"). SITE_DIR/checkpoint.bin
 * holds the odometry pass so far (the sweeps' poses, the scans read, the odometry's state)
 * or, once it is over, the whole pass; the keyframes' points go to SITE_DIR/keyframes.bin,
 * appended at each checkpoint (the checkpoint says how many of its bytes are valid).
 * checkpoint.bin is written to .tmp, synced and renamed: an interruption leaves the last
 * whole one. A run that ends well removes both. */
static const char kCheckpointMagic[8] = {'P', 'B', 'M', 'A', 'P', 'C', 'K', '1'};

static void put_pose(ByteWriter &w, const Eigen::Isometry3d &T)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++) w.put(T.matrix()(r, c));
}

static Eigen::Isometry3d get_pose(ByteReader &r)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    for (int i = 0; i < 3; i++)
        for (int c = 0; c < 4; c++) T.matrix()(i, c) = r.get<double>();
    return T;
}

/* What a checkpoint must match: the log (size and its first MiB), the mapper's build (the
 * executable's size and time: another build may place the sweeps otherwise) and the options
 * the odometry depends on. */
static int checkpoint_ids(Run *R, pb_err_t *err)
{
    FILE *f = std::fopen(R->log_path, "rb");
    if (!f) return pb_err_set(err, "%s: cannot open: %s", R->log_path, std::strerror(errno)), -1;
    std::vector<uint8_t> head(1 << 20);
    head.resize(std::fread(head.data(), 1, head.size(), f));
    struct stat st;
    const bool sized = fstat(fileno(f), &st) == 0;
    std::fclose(f);
    char buf[512];
    std::snprintf(buf, sizeof buf, "log of %lld bytes, first MiB %016llx", sized ? (long long)st.st_size : -1LL,
                  (unsigned long long)pb_fnv1a64(head.data(), head.size()));
    R->log_id = buf;
    struct stat ex;
    if (stat("/proc/self/exe", &ex) != 0) ex.st_size = ex.st_mtime = -1;
    std::snprintf(buf, sizeof buf, "mapper of %lld bytes at %lld", (long long)ex.st_size, (long long)ex.st_mtime);
    R->build_id = buf;
    const pb_transform_t &bl = R->veh.base_from_lidar;
    const pb_transform_t &bi = R->veh.base_from_imu;
    const pb_vehicle_t &v = R->veh;   /* the mounts and the body box the sweeps are cut by */
    std::snprintf(buf, sizeof buf, "channel %s, base <- lidar %.17g %.17g %.17g %.17g %.17g %.17g %.17g, "
                  "base <- imu %.17g %.17g %.17g %.17g, body %.17g %.17g %.17g %.17g", R->scan_ch,
                  bl.t[0], bl.t[1], bl.t[2], bl.q[0], bl.q[1], bl.q[2], bl.q[3], bi.q[0], bi.q[1], bi.q[2], bi.q[3],
                  v.length, v.width, v.height, v.rear_overhang);
    R->options_id = buf;
    return 0;
}

/* The whole file into *out; -1 when it cannot be opened or read. */
static int read_file(const std::string &path, std::vector<uint8_t> *out)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return -1;
    out->clear();
    uint8_t chunk[1 << 16];
    size_t n;
    while ((n = std::fread(chunk, 1, sizeof chunk, f)) > 0) out->insert(out->end(), chunk, chunk + n);
    const bool ok = !std::ferror(f);
    std::fclose(f);
    return ok ? 0 : -1;
}

/* Writes the pieces one after the other to path through path.tmp, synced, renamed. */
static int write_file_synced(const std::string &path, std::initializer_list<const std::vector<uint8_t> *> pieces,
                             pb_err_t *err)
{
    const std::string tmp = path + ".tmp";
    FILE *f = std::fopen(tmp.c_str(), "wb");
    bool ok = f != nullptr;
    for (const std::vector<uint8_t> *b : pieces) ok = ok && std::fwrite(b->data(), 1, b->size(), f) == b->size();
    ok = ok && std::fflush(f) == 0 && fsync(fileno(f)) == 0;
    if (f) ok &= std::fclose(f) == 0;
    if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
        std::remove(tmp.c_str());
        return pb_err_set(err, "%s: cannot write: %s", path.c_str(), std::strerror(errno)), -1;
    }
    return 0;
}

/* keyframes.bin's first n keyframes (utime, pose, with_points: the points too) into *kf,
 * which must hold bytes bytes. false when it does not. */
static bool read_keyframes(const std::string &path, uint64_t n, uint64_t bytes, bool with_points,
                           std::vector<pb_keyframe_t> *kf)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    kf->resize(n);
    uint64_t at = 0;
    bool ok = true;
    for (pb_keyframe_t &k : *kf) {
        uint8_t head[8 + 12 * 8 + 8];
        ok = std::fread(head, 1, sizeof head, f) == sizeof head;
        if (!ok) break;
        ByteReader r{head, head + sizeof head};
        k.utime = r.get<int64_t>();
        k.pose = get_pose(r);
        const uint64_t npts = r.get<uint64_t>();
        at += sizeof head + npts * sizeof(float);
        if (!(ok = at <= bytes)) break;
        if (with_points) {
            k.xyz.resize((size_t)npts);
            ok = std::fread(k.xyz.data(), sizeof(float), k.xyz.size(), f) == k.xyz.size();
        } else {
            ok = std::fseek(f, (long)(npts * sizeof(float)), SEEK_CUR) == 0;
        }
        if (!ok) break;
    }
    std::fclose(f);
    return ok && at == bytes;
}

/* The keyframes not yet in keyframes.bin appended to it (their points then freed: read
 * back for the loops), then the checkpoint: odom the odometry in the middle of the pass,
 * NULL once the pass is over. */
static int checkpoint_write(Run *R, const pb_odom_t *odom, pb_err_t *err)
{
    std::vector<uint8_t> buf;
    ByteWriter w{&buf};
    for (; R->kf_saved < R->kf.size(); R->kf_saved++) {
        pb_keyframe_t &k = R->kf[R->kf_saved];
        w.put(k.utime);
        put_pose(w, k.pose);
        w.put_array(k.xyz.data(), k.xyz.size());
        std::vector<float>().swap(k.xyz);
    }
    if (std::fwrite(buf.data(), 1, buf.size(), R->kf_file) != buf.size() || std::fflush(R->kf_file) != 0 ||
        fsync(fileno(R->kf_file)) != 0)
        return pb_err_set(err, "%s: cannot write: %s", R->work("keyframes").c_str(), std::strerror(errno)), -1;
    R->kf_bytes += buf.size();
    buf.clear();
    for (char c : kCheckpointMagic) w.put(c);
    w.put_string(R->log_id); w.put_string(R->build_id); w.put_string(R->options_id);
    w.put((uint8_t)(odom == nullptr));
    w.put((int64_t)R->seen); w.put(R->last_scan_utime); w.put((int64_t)R->empty); w.put((int64_t)R->out_of_order);
    w.put((uint64_t)R->traj.size());
    for (const SweepPose &sp : R->traj) {
        w.put(sp.utime);
        put_pose(w, sp.odometry);
        w.put(sp.status); w.put(sp.motion); w.put(sp.inlier_fraction); w.put(sp.cpu_ms); w.put(sp.keyframe);
    }
    w.put((uint64_t)R->kf.size()); w.put(R->kf_bytes);
    std::vector<uint8_t> state, sum;   /* the state (tens of MB) written as it is, not copied */
    if (odom) pb_odom_save(odom, &state);
    w.put((uint64_t)state.size());
    ByteWriter{&sum}.put(pb_fnv1a64(state.data(), state.size(), pb_fnv1a64(buf.data(), buf.size())));
    return write_file_synced(R->work("checkpoint"), {&buf, &state, &sum}, err);
}

/* A checkpoint of this log, build and options restored into R (R->resumed_from > 0); one
 * of another (or damaged) is refused, its reason in R->checkpoint_refused and on stderr,
 * and the run starts over. Returns -1 only on an error reading a file there. */
static int checkpoint_read(Run *R, pb_err_t *err)
{
    const std::string path = R->work("checkpoint"), kf_path = R->work("keyframes");
    std::vector<uint8_t> buf;
    if (read_file(path, &buf) != 0) return 0;   /* none: a fresh start */
    ByteReader r{buf.data(), buf.data() + buf.size()};
    std::string why;
    bool magic = buf.size() >= 16;
    for (char c : kCheckpointMagic) magic &= r.get<char>() == c;
    uint64_t sum = 0;
    if (magic) std::memcpy(&sum, buf.data() + buf.size() - 8, 8);
    std::string log_id = r.get_string(), build_id = r.get_string(), options_id = r.get_string();
    if (!magic) why = "not a checkpoint of this version of the mapper";
    else if (sum != pb_fnv1a64(buf.data(), buf.size() - 8)) why = "damaged (checksum)";
    else if (log_id != R->log_id) why = "from another log (" + log_id + "; this one: " + R->log_id + ")";
    else if (build_id != R->build_id) why = "from another build of the mapper (" + build_id + "; this one: " + R->build_id + ")";
    else if (options_id != R->options_id) why = "made with other options (" + options_id + "; now: " + R->options_id + ")";
    const bool done = r.get<uint8_t>() != 0;
    const long seen = (long)r.get<int64_t>();
    R->last_scan_utime = r.get<int64_t>();
    R->empty = (long)r.get<int64_t>();
    R->out_of_order = (long)r.get<int64_t>();
    const uint64_t ntraj = r.get<uint64_t>();
    for (uint64_t i = 0; why.empty() && r.ok && i < ntraj; i++) {
        SweepPose sp;
        sp.utime = r.get<int64_t>();
        sp.pose = sp.odometry = get_pose(r);
        sp.status = r.get<int>(); sp.motion = r.get<int>(); sp.inlier_fraction = r.get<double>();
        sp.cpu_ms = r.get<double>();
        sp.keyframe = r.get<int>();
        R->traj.push_back(sp);
    }
    const uint64_t nkf = r.get<uint64_t>();
    R->kf_bytes = r.get<uint64_t>();
    std::vector<uint8_t> state;
    r.get_array(&state);
    if (why.empty() && (!r.ok || r.p != buf.data() + buf.size() - 8)) why = "damaged (truncated)";
    // the keyframes it counts, from keyframes.bin (their points stay there until the loops)
    if (why.empty() && !read_keyframes(kf_path, nkf, R->kf_bytes, false, &R->kf))
        why = "keyframes.bin does not hold the keyframes the checkpoint says";
    pb_err_t e;
    if (why.empty() && !done && !(R->odom = pb_odom_restore(state.data(), state.size(), nullptr, nullptr, &e))) why = e.msg;
    if (!why.empty()) {
        R->checkpoint_refused = why;
        R->traj.clear(); R->kf.clear();
        R->empty = R->out_of_order = 0; R->last_scan_utime = 0; R->kf_bytes = 0;
        std::fprintf(stderr, "mapper: %s: %s; starting over\n", path.c_str(), why.c_str());
        return 0;
    }
    // keyframes.bin cut to what the checkpoint counts (an interruption may have left more)
    if (truncate(kf_path.c_str(), (off_t)R->kf_bytes) != 0)
        return pb_err_set(err, "%s: cannot truncate: %s", kf_path.c_str(), std::strerror(errno)), -1;
    R->kf_saved = R->kf.size();
    R->seen = R->resumed_from = seen;
    R->odometry_done = done;
    std::fprintf(stderr, "mapper: resuming from %s: %ld of %ld scans read%s\n", path.c_str(), seen, R->total,
                 done ? ", the odometry done" : "");
    return 0;
}

/* --poses: the trajectory from a TUM file (t x y z qx qy qz qw: base in map, t in seconds
 * ascending; '#' comments), no odometry and no loops: the map, the ground and the carving
 * are made with these poses (an INS or RTK trajectory, another SLAM's). Errors name the
 * file and line. */
static int read_poses(Run *R, pb_err_t *err)
{
    FILE *f = std::fopen(R->poses_path, "r");
    if (!f) return pb_err_set(err, "%s: cannot open: %s", R->poses_path, std::strerror(errno)), -1;
    char line[1024];
    int lineno = 0, rc = 0;
    while (rc == 0 && std::fgets(line, sizeof line, f)) {
        lineno++;
        const char *p = line + std::strspn(line, " \t");
        if (*p == '#' || *p == '\n' || *p == '\r' || *p == 0) continue;
        double v[8];
        char tail[2];
        if (std::sscanf(p, "%lf %lf %lf %lf %lf %lf %lf %lf %1s", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &v[6],
                        &v[7], tail) != 8) {
            rc = pb_err_set(err, "%s:%d: expected 8 numbers (t x y z qx qy qz qw)", R->poses_path, lineno);
            break;
        }
        Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
        bool finite = true;
        for (double x : v) finite &= std::isfinite(x);
        if (!finite || std::fabs(q.norm() - 1) > 1e-3) {
            rc = pb_err_set(err, "%s:%d: not a pose (non-finite, or a quaternion of norm %.4f)", R->poses_path, lineno,
                            q.norm());
            break;
        }
        const int64_t utime = (int64_t)std::llround(v[0] * 1e6);
        if (!R->traj.empty() && utime <= R->traj.back().utime) {
            rc = pb_err_set(err, "%s:%d: time %.6f s is not after the line before's", R->poses_path, lineno, v[0]);
            break;
        }
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        T.linear() = q.normalized().toRotationMatrix();
        T.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
        R->traj.push_back({utime, T, T, kGiven, kGiven, NAN, 0, -1});
    }
    std::fclose(f);
    if (rc == 0 && R->traj.size() < 2)
        rc = pb_err_set(err, "%s: %zu pose(s); a map needs two or more", R->poses_path, R->traj.size());
    return rc;
}

/* Pass 1: odometry over every sweep; a keyframe every kKeyframeSpacingM; a checkpoint
 * every R->checkpoint_every sweeps and at the end. Resumes where R's checkpoint left off. */
static int pass_odometry(Run *R, pb_err_t *err)
{
    const std::string kf_path = R->work("keyframes");
    R->kf_file = std::fopen(kf_path.c_str(), R->resumed_from ? "ab" : "wb");
    if (!R->kf_file) return pb_err_set(err, "%s: cannot write: %s", kf_path.c_str(), std::strerror(errno)), -1;
    if (R->odometry_done) return 0;
    pb_odom_t *odom = R->odom ? R->odom : pb_odom_create(nullptr, nullptr);
    R->odom = nullptr;
    pb_reg_config_t kf_reduce;
    pb_reg_config_default(&kf_reduce);
    kf_reduce.target_points = 0;
    kf_reduce.scan_voxel_m = kKeyframeVoxelM;
    int64_t &last_scan_utime = R->last_scan_utime;
    R->traj.reserve((size_t)R->total);
    pb_progress_t prog;
    const std::string label = R->label("mapper: odometry");   /* the bar keeps the pointer */
    pb_progress_start(&prog, label.c_str(), R->total, R->quiet);
    MotionSamples ms;
    ms.base_from_imu = pb_reg_from_transform(&R->veh.base_from_imu).linear();
    int rc = for_each_sweep(R->log_path, R->scan_ch, R->veh, 1, &R->seen, &prog,
        [&](int64_t utime, const std::vector<float> &xyz, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            if (!R->traj.empty() && utime <= last_scan_utime) { R->out_of_order++; return 0; }
            last_scan_utime = utime;
            double c0 = pb_clock_thread_cpu_ms();
            pb_odom_result_t r;
            pb_odom_motion_t motion = ms.view();
            int ok = pb_odom_add(odom, utime, xyz.data(), pts.offset_us, xyz.size() / 3, &motion, &r, e);
            ms.speed.clear();
            ms.rate.clear();
            if (ok != 0) return -1;
            std::vector<pb_keyframe_t> &kf = R->kf;
            if (kf.empty() || (r.pose.translation() - kf.back().pose.translation()).norm() >= kKeyframeSpacingM) {
                kf.push_back({r.utime, r.pose, {}});
                const std::vector<float> &sw = pb_odom_last_sweep(odom);
                pb_reg_downsample(sw.data(), sw.size() / 3, &kf_reduce, &kf.back().xyz);
            }
            R->traj.push_back({r.utime, r.pose, r.pose, r.status, r.motion, r.inlier_fraction,
                               pb_clock_thread_cpu_ms() - c0, (int)kf.size() - 1});
            return R->traj.size() % (size_t)R->checkpoint_every ? 0 : checkpoint_write(R, odom, e);
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
    return checkpoint_write(R, nullptr, err);
}

/* The keyframes' poses solved again with the loops found (their points read back from
 * each drive's keyframes.bin); the later drives placed in the first one's frame, or left
 * out (said on stderr); the sweeps moved with them. */
static int close_loops(Run *R, pb_err_t *err)
{
    std::vector<pb_keyframe_t> kf;   /* every drive's, one drive after the other */
    for (Run *D : R->drives) {
        const std::string kf_path = D->work("keyframes");
        if (!read_keyframes(kf_path, D->kf.size(), D->kf_bytes, true, &D->kf))
            return pb_err_set(err, "%s: cannot read the keyframes back", kf_path.c_str()), -1;
        for (pb_keyframe_t &k : D->kf) {   /* the points move; D->kf keeps the times and poses */
            k.drive = D->drive;
            kf.push_back(std::move(k));
        }
    }
    std::vector<Eigen::Isometry3d> solved;
    if (kf.size() >= 2) {
        if (pb_loops_close(kf, nullptr, &solved, &R->loops, err) != 0) return -1;
        size_t at = 0;
        for (Run *D : R->drives) {
            const size_t nk = D->kf.size();
            D->placement = R->loops.drives[(size_t)D->drive];
            if (D->placement.placed) {
                apply_corrections(&D->traj, D->kf, {solved.begin() + (long)at, solved.begin() + (long)(at + nk)});
                if (D->drive)   /* its odometry too in the map's frame, as placed */
                    for (SweepPose &sp : D->traj) sp.odometry = D->placement.placement * sp.odometry;
            } else {
                std::fprintf(stderr, "mapper: warning: %s not placed in the map of the drives before it (%s): left "
                             "out of the map\n", D->log_path, D->placement.why);
            }
            at += nk;
        }
    }
    for (const auto &l : R->loops.loops) {
        const pb_keyframe_t &a = kf[(size_t)l.first], &b = kf[(size_t)l.second];
        R->loop_times.push_back({{a.drive, a.utime}, {b.drive, b.utime}});
    }
    for (Run *D : R->drives) {
        D->kf.clear();
        D->kf.shrink_to_fit();
    }
    return 0;
}

/* GNSS anchoring: the trajectory (and so the map) moved onto the fixes, in the
 * east-north-up frame at the first 3-D fix, which becomes the site's geo-reference. */
static int anchor(Run *R, pb_err_t *err)
{
    std::vector<Run *> placed;
    for (Run *D : R->drives)
        if (D->placement.placed) placed.push_back(D);
    std::vector<std::vector<portobello_gnss_fix_t>> fixes(placed.size());
    for (size_t d = 0; d < placed.size(); d++)
        if (read_fixes(placed[d]->log_path, &fixes[d], err) != 0) return -1;
    R->anchor = pb_anchor_result_t{};
    R->anchor.why = "no GNSS_FIX in the log";
    const portobello_gnss_fix_t *origin = nullptr;
    for (const auto &fd : fixes) {
        for (const auto &f : fd)
            if (!origin && is_3d(f)) origin = &f;
        if (!fd.empty() && !origin) R->anchor.why = "no 3-D GNSS fix in the log";
    }
    std::vector<pb_anchor_obs_t> obs;
    auto observe = [&]() {   /* every placed drive's fixes against its trajectory */
        obs.clear();
        for (size_t d = 0; d < placed.size(); d++) {
            std::vector<pb_anchor_obs_t> od = observe_fixes(fixes[d], placed[d]->traj, R->veh, R->georef);
            obs.insert(obs.end(), od.begin(), od.end());
        }
    };
    if (origin) {
        R->georef = pb_georef_t{origin->lat_deg, origin->lon_deg, origin->alt_m, 0};
        observe();
        if (obs.empty()) R->anchor.why = "no GNSS fix within the drive's sweeps";
    }
    if (!obs.empty() && pb_anchor_fit(obs, nullptr, &R->anchor, err) != 0) return -1;
    if (!R->anchor.anchored) {
        if (!R->quiet)
            std::fprintf(stderr, "mapper: warning: the map is not geo-referenced (%s); it stays in the first pose's frame\n",
                         R->anchor.why);
        return 0;
    }
    for (Run *D : R->drives)
        for (SweepPose &sp : D->traj) {
            sp.pose = R->anchor.enu_from_map * sp.pose;
            sp.odometry = R->anchor.enu_from_map * sp.odometry;
        }
    // a drift the fixes see beyond their own errors bent out (pb_anchor_hold; one drive: the
    // drives of several are held together by their loops, not yet by the fixes), fitted again
    if (placed.size() == 1) {
        for (pb_anchor_obs_t &o : obs) o.antenna_map = R->anchor.enu_from_map * o.antenna_map;
        std::vector<int64_t> utime;
        std::vector<Eigen::Isometry3d> poses;
        for (const SweepPose &sp : R->traj) { utime.push_back(sp.utime); poses.push_back(sp.pose); }
        const Eigen::Vector3d lever(R->veh.base_from_gnss.t[0], R->veh.base_from_gnss.t[1], R->veh.base_from_gnss.t[2]);
        if (pb_anchor_hold(utime, &poses, obs, R->anchor, lever, nullptr, &R->hold, err) != 0) return -1;
        if (R->hold.held) {
            for (size_t i = 0; i < poses.size(); i++) R->traj[i].pose = poses[i];
            observe();
            if (pb_anchor_fit(obs, nullptr, &R->anchor, err) != 0) return -1;
            for (SweepPose &sp : R->traj) sp.pose = R->anchor.enu_from_map * sp.pose;
        }
    }
    for (const pb_anchor_obs_t &o : obs) R->layers.fixes.push_back(o.fix_enu);
    return 0;
}

/* ---- The map in tiles (docs/mapper.md, "Memory"): pass 2 holds the tiles of voxels its
 * sweeps can reach and pages the others out to SITE_DIR/map-tiles.tmp/; the finished voxels
 * are then sorted into the carving's tiles (by its cells, so that no cell spans two), which
 * pass 3 holds while its rays can reach them, with their counts paged out and back; map.pcd
 * is assembled from the kept points in the order the voxels were made (what one builder of
 * the whole map writes). A tile is keyed tx << 32 | uint32 ty. */
static int64_t tile_key(int64_t tx, int64_t ty) { return (int64_t)((uint64_t)tx << 32 | (uint32_t)ty); }

/* Square tiles of `per` units (voxels, carving cells) a side: unit = floor(x * inv). */
struct TileGrid {
    double inv;
    int64_t per;
    int64_t of(double x) const
    {
        int64_t u = pb_floor_i64(x * inv);
        return u >= 0 ? u / per : -((-u + per - 1) / per);
    }
};

/* A point of the finished map in a tile file: the voxel's seq (the order it was made in),
 * x y z intensity. */
struct TilePoint {
    uint32_t seq;
    float p[4];
};
static_assert(sizeof(TilePoint) == 5 * sizeof(float), "TilePoint: x y z at a stride of 5 floats");

static std::string tile_path(const Run *R, char kind, int64_t key)
{
    char name[64];
    std::snprintf(name, sizeof name, "/%c_%d_%d.bin", kind, (int32_t)((uint64_t)key >> 32), (int32_t)(uint32_t)key);
    return R->tiles_dir + name;
}

template <class T>
static int tile_write(const std::string &path, const T *v, size_t n, bool append, pb_err_t *err)
{
    FILE *f = std::fopen(path.c_str(), append ? "ab" : "wb");
    bool ok = f && std::fwrite(v, sizeof(T), n, f) == n;
    if (f) ok &= std::fclose(f) == 0;
    if (!ok) return pb_err_set(err, "%s: cannot write: %s", path.c_str(), std::strerror(errno)), -1;
    return 0;
}

template <class T>
static int tile_read(const std::string &path, std::vector<T> *v, pb_err_t *err)
{
    std::vector<uint8_t> bytes;
    if (read_file(path, &bytes) != 0 || bytes.size() % sizeof(T) != 0)
        return pb_err_set(err, "%s: cannot read the tile back", path.c_str()), -1;
    v->resize(bytes.size() / sizeof(T));
    if (!bytes.empty()) std::memcpy(v->data(), bytes.data(), bytes.size());
    return 0;
}

/* The tiles of grid within reach of a sweep's points (range_m from the LiDAR, or its
 * farthest point's range when range_m < 0), into [lo, hi] (x, y): around the base's
 * positions at its first and last point's times, with the LiDAR's lever and 2 m (the path's
 * bend within a sweep). false when the track does not cover the sweep (pass 2 skips it). */
static bool sweep_reach(const Run *R, const pb_pose_track_t *track, const pb_points_t &pts, int64_t utime, double range_m,
                        const TileGrid &grid, int64_t lo[2], int64_t hi[2])
{
    int32_t omin = pts.offset_us && pts.n > 0 ? pts.offset_us[0] : 0, omax = omin;   /* as pb_map_builder_add_timed */
    double r2 = 0;
    for (int i = 0; i < pts.n; i++) {
        if (pts.offset_us) { omin = std::min(omin, pts.offset_us[i]); omax = std::max(omax, pts.offset_us[i]); }
        if (range_m < 0) r2 = std::max(r2, (double)pts.x[i] * pts.x[i] + (double)pts.y[i] * pts.y[i] + (double)pts.z[i] * pts.z[i]);
    }
    pb_transform_t a, b;
    if (!pb_pose_track_at(track, utime + omin, &a) || !pb_pose_track_at(track, utime + omax, &b)) return false;
    const double *l = R->veh.base_from_lidar.t;
    const double reach = (range_m < 0 ? std::sqrt(r2) : range_m) + std::sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) + 2;
    for (int k = 0; k < 2; k++) {
        lo[k] = grid.of(std::min(a.t[k], b.t[k]) - reach);
        hi[k] = grid.of(std::max(a.t[k], b.t[k]) + reach);
    }
    return true;
}

/* Tile k of the map's grid moved out into *vox (empty when not held). */
static void take_tile(pb_map_builder_t *map, int64_t k, std::vector<pb_map_voxel_t> *vox)
{
    const int32_t tx = (int32_t)((uint64_t)k >> 32), ty = (int32_t)(uint32_t)k;
    vox->resize((size_t)pb_map_builder_tile_size(map, tx, ty));
    pb_map_builder_tile_take(map, tx, ty, vox->data());
}

/* Every tile's finished voxels (those held by map, those paged out) as points in the
 * carving's tiles (by its cells: no cell spans two), appended to their files; the map's
 * extent for the ground model. */
static int to_carving_tiles(Run *R, pb_map_builder_t *map, std::vector<int64_t> all, const std::unordered_set<int64_t> &out,
                            pb_err_t *err)
{
    const pb_carve_config_t ccfg{};
    const TileGrid cgrid{1.0 / ccfg.cell_m, std::max<int64_t>(1, std::lround(R->tile_m / ccfg.cell_m))};
    std::sort(all.begin(), all.end());
    R->ground_lo[0] = R->ground_lo[1] = INFINITY;
    R->ground_hi[0] = R->ground_hi[1] = -INFINITY;
    std::vector<pb_map_voxel_t> vox;
    std::map<int64_t, std::vector<TilePoint>> parts;
    for (int64_t k : all) {
        if (!out.count(k)) take_tile(map, k, &vox);
        else if (tile_read(tile_path(R, 'v', k), &vox, err) != 0) return -1;
        std::remove(tile_path(R, 'v', k).c_str());
        parts.clear();
        for (const pb_map_voxel_t &v : vox) {
            TilePoint tp;
            tp.seq = v.seq;
            pb_map_voxel_point(map, &v, tp.p);
            parts[tile_key(cgrid.of(tp.p[0]), cgrid.of(tp.p[1]))].push_back(tp);
            gb_bounds(tp.p, 1, 4, R->ground_lo, R->ground_hi);
        }
        R->voxels += vox.size();
        for (const auto &pt : parts) {
            R->carve_tiles.insert(pt.first);
            if (tile_write(tile_path(R, 'p', pt.first), pt.second.data(), pt.second.size(), true, err) != 0) return -1;
        }
    }
    if (R->voxels == 0)
        return pb_err_set(err, "%s: the map has no points (no scan had bracketing poses?)", R->path("map.pcd").c_str()), -1;
    return 0;
}

/* Pass 2: the map, every point with the pose at its time, in tiles: those the sweep can
 * reach are held (paged back in when they were out), those no sweep of the last 20 reached
 * are paged out; of every drive placed, one after the other. Then the finished voxels are
 * sorted into the carving's tiles. The poses are at the sweeps' middles: the track is
 * carried on by the first and last steps' motion to cover the first sweep's first half and
 * the last one's second half. */
static int pass_map(Run *R, pb_err_t *err)
{
    for (Run *D : R->drives) {
        if (!D->placement.placed) continue;
        const std::vector<SweepPose> &traj = D->traj;
        D->track = pb_pose_track_create();
        for (const SweepPose &s : traj) {
            pb_transform_t t = to_transform(s.pose);
            pb_pose_track_add(D->track, s.utime, &t);
        }
        for (int end = 0; end < 2; end++) {
            const SweepPose &a = end ? traj[traj.size() - 2] : traj[1], &b = end ? traj.back() : traj[0];
            pb_transform_t t = to_transform(b.pose * (a.pose.inverse() * b.pose));
            pb_pose_track_add(D->track, b.utime + (b.utime - a.utime), &t);
        }
    }
    std::error_code ec;
    std::filesystem::remove_all(R->tiles_dir, ec);   /* an interrupted run's */
    if (!std::filesystem::create_directory(R->tiles_dir, ec))
        return pb_err_set(err, "%s: cannot create: %s", R->tiles_dir.c_str(), ec.message().c_str()), -1;
    const TileGrid grid{1.0 / R->voxel, std::max<int64_t>(1, std::lround(R->tile_m / R->voxel))};
    pb_map_builder_t *map = pb_map_builder_create_tiled(R->voxel, (int)grid.per, err);
    if (!map) return -1;
    std::unordered_map<int64_t, long> held;   /* tile -> the sweep that last reached it */
    std::unordered_set<int64_t> out;           /* tiles paged out */
    std::vector<pb_map_voxel_t> vox;
    std::vector<int32_t> xy;
    auto page_out = [&](int64_t k, pb_err_t *e) {
        take_tile(map, k, &vox);
        held.erase(k);
        if (vox.empty()) return 0;   /* reached, no point fell there */
        out.insert(k);
        R->tiles_paged_out++;
        return tile_write(tile_path(R, 'v', k), vox.data(), vox.size(), false, e);
    };
    long sweep = 0;
    int rc = for_each_drive_sweep(R, "mapper: map", 1,
        [&](Run *D, int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            sweep++;
            // the tiles it can reach held
            int64_t lo[2], hi[2];
            if (sweep_reach(R, D->track, pts, utime, -1, grid, lo, hi))
                for (int64_t tx = lo[0]; tx <= hi[0]; tx++)
                    for (int64_t ty = lo[1]; ty <= hi[1]; ty++) {
                        const int64_t k = tile_key(tx, ty);
                        auto it = held.find(k);
                        if (it != held.end()) { it->second = sweep; continue; }
                        held[k] = sweep;
                        if (!out.count(k)) continue;
                        if (tile_read(tile_path(R, 'v', k), &vox, e) != 0 || pb_map_builder_put(map, vox.data(), vox.size(), e) != 0)
                            return -1;
                        out.erase(k);
                        R->tiles_paged_in++;
                    }
            int r = pb_map_builder_add_timed(map, &pts, utime, D->track, &R->veh.base_from_lidar, e);
            if (r < 0) return -1;
            (r ? R->placed : R->unplaced)++;
            // a point beyond the reach would have started a paged-out tile afresh
            xy.resize(2 * (size_t)pb_map_builder_tiles(map, nullptr, 0));
            pb_map_builder_tiles(map, xy.data(), (int)(xy.size() / 2));
            for (size_t i = 0; i < xy.size(); i += 2)
                if (!held.count(tile_key(xy[i], xy[i + 1])))
                    return pb_err_set(e, "internal: a point fell in map tile (%d, %d), beyond the sweep's reach", xy[i],
                                      xy[i + 1]), -1;
            R->tiles_held_max = std::max(R->tiles_held_max, (long)(xy.size() / 2));   /* those with points */
            R->voxels_held_max = std::max(R->voxels_held_max, (int64_t)pb_map_builder_size(map));
            // the tiles no sweep of the last 20 reached paged out
            if (sweep % 10 == 0) {
                std::vector<int64_t> old;
                for (const auto &h : held)
                    if (h.second < sweep - 20) old.push_back(h.first);
                std::sort(old.begin(), old.end());
                for (int64_t k : old)
                    if (page_out(k, e) != 0) return -1;
            }
            return 0;
        }, err);
    // every tile's finished points into the carving's tiles
    std::vector<int64_t> all(out.begin(), out.end());
    for (const auto &h : held) all.push_back(h.first);
    if (rc == 0) rc = to_carving_tiles(R, map, all, out, err);
    pb_map_builder_destroy(map);
    return rc;
}

/* The ground model (tools/build-ground's core) from the map, tile by tile; a site without
 * one is still a site for the localizer: say why, go on. Kept for the carving. */
static pb_ground_t *make_ground(Run *R, pb_err_t *err)
{
    gb_config_t gcfg;
    gb_config_default(&gcfg);
    size_t nground = 0;
    gb_accum_t *acc = gb_begin(R->ground_lo, R->ground_hi, &gcfg);
    std::vector<TilePoint> pts;
    for (int64_t k : R->carve_tiles) {
        if (acc && tile_read(tile_path(R, 'p', k), &pts, err) != 0) {
            R->ground_why = err->msg;
            break;
        }
        if (acc && !pts.empty()) gb_add(acc, pts[0].p, pts.size(), sizeof(TilePoint) / sizeof(float));
    }
    pb_ground_t *ground = acc ? gb_finish(acc, &nground) : nullptr;
    if (!R->ground_why.empty()) { pb_ground_destroy(ground); ground = nullptr; }
    const std::string ground_path = R->path("ground.yaml");
    if (!ground && R->ground_why.empty()) R->ground_why = "no ground in the map";
    else if (ground && pb_ground_save(ground, ground_path.c_str(), err) != 0) R->ground_why = err->msg;
    if (!R->ground_why.empty()) {
        std::remove(ground_path.c_str());
        std::fprintf(stderr, "mapper: warning: no ground model written: %s\n", R->ground_why.c_str());
    }
    return ground;
}

/* The carving's tiles (those that hold points): each held as a pb_carve_t of its points,
 * its counts paged out to its 'c' file and back. */
struct CarveTiles {
    Run *R;
    const pb_ground_t *ground;
    pb_carve_config_t cfg;
    struct Held { pb_carve_t *carve; long last; };   /* last: the sampled sweep that last reached it */
    std::map<int64_t, Held> held;
    std::vector<TilePoint> pts;                      /* the last tile read */
    std::vector<uint8_t> bytes;

    ~CarveTiles() { for (auto &h : held) pb_carve_destroy(h.second.carve); }

    /* Tile k's carving made from its points (read into pts) and given its counts, if it
     * was paged out; NULL on error. */
    pb_carve_t *make(int64_t k, bool *was_out, pb_err_t *e)
    {
        if (tile_read(tile_path(R, 'p', k), &pts, e) != 0) return nullptr;
        if (pts.empty()) return pb_err_set(e, "%s: no point in the tile", tile_path(R, 'p', k).c_str()), nullptr;
        pb_carve_t *c = pb_carve_create(pts[0].p, pts.size(), sizeof(TilePoint) / sizeof(float), ground, &cfg);
        const std::string counts = tile_path(R, 'c', k);
        *was_out = read_file(counts, &bytes) == 0;
        if (*was_out && pb_carve_load(c, bytes.data(), bytes.size()) != 0) {
            pb_carve_destroy(c);
            return pb_err_set(e, "%s: not this tile's counts", counts.c_str()), nullptr;
        }
        return c;
    }

    /* Tile k held (paged back in if it was out); NULL on error. */
    pb_carve_t *hold(int64_t k, long sampled, pb_err_t *e)
    {
        auto it = held.find(k);
        if (it == held.end()) {
            bool was_out;
            pb_carve_t *c = make(k, &was_out, e);
            if (!c) return nullptr;
            R->carve_tiles_paged_in += was_out;
            it = held.emplace(k, Held{c, 0}).first;
        }
        it->second.last = sampled;
        return it->second.carve;
    }

    /* The tiles no sampled sweep since `since` reached: their counts paged out. */
    int page_out(long since, pb_err_t *e)
    {
        for (auto it = held.begin(); it != held.end();) {
            if (it->second.last >= since) { ++it; continue; }
            pb_carve_save(it->second.carve, &bytes);
            pb_carve_destroy(it->second.carve);
            const std::string path = tile_path(R, 'c', it->first);
            it = held.erase(it);
            R->carve_tiles_paged_out++;
            if (tile_write(path, bytes.data(), bytes.size(), false, e) != 0) return -1;
        }
        return 0;
    }

    /* Every tile's verdicts: its kept points sorted by seq (map.pcd's order) to its 'k'
     * file, the carved ones to the picture's layer. First every tile's cells carved on
     * their own counts, so that a cell on a tile's border sees its neighbours over it. */
    int finish(pb_err_t *err)
    {
        std::vector<uint64_t> gone;
        for (int64_t k : R->carve_tiles) {
            auto it = held.find(k);
            if (it != held.end()) {
                pb_carve_gone(it->second.carve, &gone);
                continue;
            }
            bool was_out;
            pb_carve_t *c = make(k, &was_out, err);
            if (!c) return -1;
            pb_carve_gone(c, &gone);
            pb_carve_destroy(c);
        }
        std::sort(gone.begin(), gone.end());
        std::vector<uint8_t> keep;
        std::vector<TilePoint> kept;
        for (int64_t k : R->carve_tiles) {
            auto it = held.find(k);
            pb_carve_t *c;
            if (it == held.end()) {
                bool was_out;
                if (!(c = make(k, &was_out, err))) return -1;
            } else {
                c = it->second.carve;
                held.erase(it);
                if (tile_read(tile_path(R, 'p', k), &pts, err) != 0) { pb_carve_destroy(c); return -1; }
            }
            R->carved += pb_carve_keep(c, &gone, &keep);
            pb_carve_destroy(c);
            kept.clear();
            for (size_t i = 0; i < pts.size(); i++) {
                if (keep[i]) kept.push_back(pts[i]);
                else R->layers.removed.insert(R->layers.removed.end(), {pts[i].p[0], pts[i].p[1], pts[i].p[2]});
            }
            std::sort(kept.begin(), kept.end(), [](const TilePoint &a, const TilePoint &b) { return a.seq < b.seq; });
            R->map_points += kept.size();
            R->kept_tiles.push_back({k, kept.empty() ? UINT32_MAX : kept[0].seq});
            if (tile_write(tile_path(R, 'k', k), kept.data(), kept.size(), false, err) != 0) return -1;
            std::remove(tile_path(R, 'p', k).c_str());
            std::remove(tile_path(R, 'c', k).c_str());
        }
        return 0;
    }
};

/* Pass 3: what moved is carved out of the map (core/carve.h), on a sample of the rays
 * (every 4th sweep, every 13th point: 13 is prime to the beam count, so every beam takes
 * its turn) of every drive placed, each an hour after the last in the carving's time (two
 * drives' clocks may overlap), with the drive's number (pb_carve_set_drive); the band over
 * the ground model is spared. A tile of the carving is held while the rays of the last 10
 * sampled sweeps could reach it (max_range_m of their origins), else its counts are paged
 * out; each ray is cast in the tiles under it. Then every tile's verdicts. */
static int pass_carve(Run *R, const pb_ground_t *ground, pb_err_t *err)
{
    CarveTiles tiles{R, ground, pb_carve_config_t{}, {}, {}, {}};
    const pb_carve_config_t &ccfg = tiles.cfg;
    const TileGrid cgrid{1.0 / ccfg.cell_m, std::max<int64_t>(1, std::lround(R->tile_m / ccfg.cell_m))};
    const Eigen::Isometry3d bl = pb_reg_from_transform(&R->veh.base_from_lidar);
    struct Ray { int64_t utime; Eigen::Vector3d o, e; };
    std::vector<Ray> rays;
    std::vector<pb_carve_t *> under;   /* the sweep's reach, row by row: the tile's carving or NULL */
    long sampled = 0;
    int drive = -1;
    const Run *now = nullptr;
    int64_t offset = 0, last = INT64_MIN;   /* drive's time + offset: the carving's */
    int rc = for_each_drive_sweep(R, "mapper: carve", 4,
        [&](Run *D, int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            if (D != now) {   /* the next drive: an hour after the last in the carving's time */
                now = D;
                drive++;
                if (last != INT64_MIN) offset = last + 3600 * (int64_t)1000000 - D->traj.front().utime;
                last = D->traj.back().utime + offset;
            }
            sampled++;
            // the sampled rays, and the extent of their origins
            rays.clear();
            double olo[2] = {INFINITY, INFINITY}, ohi[2] = {-INFINITY, -INFINITY};
            int32_t cached = INT32_MIN;
            Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
            bool have = false;
            for (int i = 0; i < pts.n; i += 13) {
                if (pts.offset_us[i] != cached) {   /* a column's points share their time */
                    cached = pts.offset_us[i];
                    pb_transform_t t;
                    have = pb_pose_track_at(D->track, utime + cached, &t);
                    if (have) T = pb_reg_from_transform(&t) * bl;
                    for (int k = 0; have && k < 2; k++) {
                        olo[k] = std::min(olo[k], T.translation()[k]);
                        ohi[k] = std::max(ohi[k], T.translation()[k]);
                    }
                }
                if (!have) continue;
                rays.push_back({utime + cached + offset, T.translation(), T * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i])});
            }
            if (rays.empty()) return 0;
            // the tiles its rays can reach held
            int64_t lo[2], hi[2];
            for (int k = 0; k < 2; k++) {
                lo[k] = cgrid.of(olo[k] - ccfg.max_range_m - 1);
                hi[k] = cgrid.of(ohi[k] + ccfg.max_range_m + 1);
            }
            const int64_t w = hi[0] - lo[0] + 1;
            under.assign((size_t)(w * (hi[1] - lo[1] + 1)), nullptr);
            for (int64_t tx = lo[0]; tx <= hi[0]; tx++)
                for (int64_t ty = lo[1]; ty <= hi[1]; ty++) {
                    const int64_t k = tile_key(tx, ty);
                    if (!R->carve_tiles.count(k)) continue;
                    pb_carve_t *c = tiles.hold(k, sampled, e);
                    if (!c) return -1;
                    pb_carve_set_drive(c, drive);
                    under[(size_t)((ty - lo[1]) * w + (tx - lo[0]))] = c;
                }
            R->carve_tiles_held_max = std::max(R->carve_tiles_held_max, (long)tiles.held.size());
            // each ray cast in the tiles under it (one longer than max_range_m counts nowhere)
            for (const Ray &r : rays) {
                const int64_t x0 = std::max(lo[0], cgrid.of(std::min(r.o.x(), r.e.x()))),
                              x1 = std::min(hi[0], cgrid.of(std::max(r.o.x(), r.e.x()))),
                              y0 = std::max(lo[1], cgrid.of(std::min(r.o.y(), r.e.y()))),
                              y1 = std::min(hi[1], cgrid.of(std::max(r.o.y(), r.e.y())));
                for (int64_t ty = y0; ty <= y1; ty++)
                    for (int64_t tx = x0; tx <= x1; tx++)
                        if (pb_carve_t *c = under[(size_t)((ty - lo[1]) * w + (tx - lo[0]))])
                            pb_carve_ray(c, r.utime, r.o.data(), r.e.data());
            }
            // the tiles no sampled sweep of the last 10 reached paged out
            return sampled % 5 == 0 ? tiles.page_out(sampled - 10, e) : 0;
        }, err);
    if (rc != 0) return -1;
    return tiles.finish(err);
}

/* map.pcd from the kept tiles, in the order of the voxels' seq: a window of seq at a time
 * gathered from the tiles that have points in it; each part drawn into the picture too. */
struct Assembly {
    Run *R = nullptr;
    pb_picture_t *pic = nullptr;
    std::vector<size_t> read;          /* per kept tile: its points taken so far */
    std::vector<float> window;         /* x y z intensity by seq - start */
    std::vector<uint8_t> has;
    std::vector<float> ready;          /* the window's points in order */
    size_t ready_at = 0;
    int64_t start = 0;                 /* the window's first seq */
    static const int64_t kWindow = int64_t(1) << 21;

    int next_window(pb_err_t *err)
    {
        const int64_t end = start + kWindow;
        window.resize(4 * (size_t)kWindow);
        has.assign((size_t)kWindow, 0);
        std::vector<TilePoint> chunk(4096);
        for (size_t t = 0; t < R->kept_tiles.size(); t++) {
            uint32_t &next = R->kept_tiles[t].second;
            if (next == UINT32_MAX || next >= end) continue;
            const std::string path = tile_path(R, 'k', R->kept_tiles[t].first);
            FILE *f = std::fopen(path.c_str(), "rb");
            if (!f || std::fseek(f, (long)(read[t] * sizeof(TilePoint)), SEEK_SET) != 0) {
                if (f) std::fclose(f);
                return pb_err_set(err, "%s: cannot read the tile back", path.c_str()), -1;
            }
            for (bool more = true; more;) {
                const size_t n = std::fread(chunk.data(), sizeof(TilePoint), chunk.size(), f);
                if (n == 0) { next = UINT32_MAX; break; }
                for (size_t i = 0; i < n; i++) {
                    if (chunk[i].seq >= end) { next = chunk[i].seq; more = false; break; }
                    std::memcpy(&window[4 * (size_t)(chunk[i].seq - start)], chunk[i].p, sizeof chunk[i].p);
                    has[(size_t)(chunk[i].seq - start)] = 1;
                    read[t]++;
                }
            }
            std::fclose(f);
        }
        ready.clear();
        ready_at = 0;
        for (size_t i = 0; i < has.size(); i++)
            if (has[i]) ready.insert(ready.end(), &window[4 * i], &window[4 * i + 4]);
        pb_picture_add(pic, ready.data(), ready.size() / 4, 4);
        start = end;
        return 0;
    }

    static int fill(void *user, int64_t, int64_t count, float *xyzi, pb_err_t *err)
    {
        Assembly *a = (Assembly *)user;
        for (int64_t done = 0; done < count;) {
            if (a->ready_at == a->ready.size()) {
                if (a->start >= (int64_t)a->R->voxels) return pb_err_set(err, "internal: the kept tiles hold fewer points than counted"), -1;
                if (a->next_window(err) != 0) return -1;
                continue;
            }
            const size_t n = std::min((size_t)(count - done), (a->ready.size() - a->ready_at) / 4);
            std::memcpy(xyzi + 4 * done, &a->ready[a->ready_at], 4 * n * sizeof(float));
            a->ready_at += 4 * n;
            done += (int64_t)n;
        }
        return 0;
    }
};

/* The trajectories, map.pcd and the picture, the tiles the localizer pages (its map_source,
 * from the map as written) and site.yaml. */
static int write_site(Run *R, pb_err_t *err)
{
    std::map<SweepKey, Eigen::Vector3d> at;
    for (Run *D : R->drives) {   /* drive N's trajectory.N.tum and odometry.N.tum */
        if (!D->placement.placed) continue;
        const std::string n = D->drive ? "." + std::to_string(D->drive + 1) : "";
        if (write_tum(R->path(("trajectory" + n + ".tum").c_str()).c_str(), D->traj, false) != 0 ||
            write_tum(R->path(("odometry" + n + ".tum").c_str()).c_str(), D->traj, true) != 0)
            return pb_err_set(err, "%s: cannot write the trajectories: %s", R->out_dir, std::strerror(errno)), -1;
        if (D->drive) {   /* the picture's lines break between drives */
            R->layers.before.push_back(Eigen::Vector3d::Constant(NAN));
            R->layers.after.push_back(Eigen::Vector3d::Constant(NAN));
        }
        for (const SweepPose &sp : D->traj) {
            R->layers.before.push_back(sp.odometry.translation());
            R->layers.after.push_back(sp.pose.translation());
            at[{D->drive, sp.utime}] = sp.pose.translation();
        }
    }
    for (const auto &lt : R->loop_times)
        if (at.count(lt.first) && at.count(lt.second)) R->layers.loops.push_back({at[lt.first], at[lt.second]});
    Assembly as{R, pb_picture_begin(&R->layers), std::vector<size_t>(R->kept_tiles.size(), 0), {}, {}, {}};
    const std::string map_path = R->path("map.pcd"), tmp = map_path + ".tmp";
    int rc = pb_pcd_write_xyzi_from(tmp.c_str(), (int64_t)R->map_points, Assembly::fill, &as, err);
    if (rc == 0 && std::rename(tmp.c_str(), map_path.c_str()) != 0)
        rc = pb_err_set(err, "%s: cannot write: %s", map_path.c_str(), std::strerror(errno));
    if (rc == 0) rc = pb_picture_write(as.pic, &R->layers, R->path("report.png").c_str(), &R->m_per_px, err);
    pb_picture_end(as.pic);
    as = Assembly{};   /* its buffers freed before the tiles are prepared */
    malloc_trim(0);
    std::error_code ec;
    std::filesystem::remove_all(R->tiles_dir, ec);
    if (rc != 0) return -1;
    if (map_source_write_tiles(map_path.c_str(), R->path("map.tiles").c_str(), MAP_SOURCE_TILE_M, nullptr,
                               nullptr, nullptr, err) != 0)
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
    long by_status[5] = {}, by_motion[3] = {};
    double path_m = 0;
    std::vector<double> ms, inl;
    for (size_t i = 0; i < R.traj.size(); i++) {
        const SweepPose &s = R.traj[i];
        if (s.status != kGiven) by_status[s.status]++;
        if (s.motion != kGiven) by_motion[s.motion]++;
        if (i > 0) path_m += (s.pose.translation() - R.traj[i - 1].pose.translation()).norm();
        ms.push_back(s.cpu_ms);
        if (std::isfinite(s.inlier_fraction)) inl.push_back(s.inlier_fraction);
    }
    const double span_s = (R.traj.back().utime - R.traj.front().utime) * 1e-6;
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "log", R.log_path);
    cJSON_AddStringToObject(j, "poses_given", R.poses_path ? R.poses_path : "");
    cJSON_AddNumberToObject(j, "scans", (double)R.traj.size());
    cJSON_AddNumberToObject(j, "scans_in_log", (double)R.total);
    cJSON_AddNumberToObject(j, "empty_scans", (double)R.empty);
    cJSON_AddNumberToObject(j, "out_of_order_scans", (double)R.out_of_order);
    for (int k = 0; k < 5; k++) cJSON_AddNumberToObject(j, (std::string("scans_") + kStatusName[k]).c_str(), (double)by_status[k]);
    /* what each sweep's prediction came from: dead reckoning on VEHICLE_SPEED and IMU, the
     * last step's motion (LiDAR alone), or nothing (the first sweep, after a gap) */
    cJSON_AddNumberToObject(j, "scans_motion_measured", (double)by_motion[PB_ODOM_MOTION_MEASURED]);
    cJSON_AddNumberToObject(j, "scans_motion_constant", (double)by_motion[PB_ODOM_MOTION_CONSTANT]);
    cJSON_AddNumberToObject(j, "scans_motion_none", (double)by_motion[PB_ODOM_MOTION_NONE]);
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
    cJSON_AddBoolToObject(j, "gnss_held", R.hold.held);   /* pb_anchor_hold: the drift bent onto the fixes */
    cJSON_AddNumberToObject(j, "gnss_drift_ratio", R.hold.ratio);
    cJSON_AddNumberToObject(j, "gnss_held_fixes", R.hold.fixes);
    cJSON_AddNumberToObject(j, "gnss_held_max_change_m", R.hold.max_change_m);
    cJSON_AddNumberToObject(j, "gnss_held_step_freedom", R.hold.step_scale);
    cJSON_AddNumberToObject(j, "gnss_held_resid_p90_m", R.hold.resid_p90_m);
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
    cJSON_AddNumberToObject(j, "resumed_from_scan", (double)R.resumed_from);
    cJSON_AddStringToObject(j, "checkpoint_refused", R.checkpoint_refused.c_str());
    cJSON *peak = cJSON_AddObjectToObject(j, "peak_rss_mb");
    double peak_all = 0;
    for (int k = 0; k < 5; k++) {
        cJSON_AddNumberToObject(peak, kPeakStep[k], std::round(R.peak_mb[k]));
        peak_all = std::max(peak_all, R.peak_mb[k]);
    }
    cJSON_AddNumberToObject(peak, "all", std::round(peak_all));
    cJSON_AddStringToObject(j, "picture", "report.png");
    cJSON_AddNumberToObject(j, "picture_m_per_px", R.m_per_px);
    cJSON_AddNumberToObject(j, "map_points", (double)R.map_points);
    cJSON_AddNumberToObject(j, "map_points_carved", (double)R.carved);
    cJSON_AddNumberToObject(j, "map_voxel_m", R.voxel);
    /* the map in tiles: how many, the most held at once (pass 2: tiles and voxels; carving) */
    cJSON_AddNumberToObject(j, "map_tile_m", R.tile_m);
    cJSON_AddNumberToObject(j, "map_voxels", (double)R.voxels);
    cJSON_AddNumberToObject(j, "map_tiles", (double)R.carve_tiles.size());
    cJSON_AddNumberToObject(j, "map_tiles_held_max", (double)R.tiles_held_max);
    cJSON_AddNumberToObject(j, "map_voxels_held_max", (double)R.voxels_held_max);
    cJSON_AddNumberToObject(j, "map_tiles_paged_out", (double)R.tiles_paged_out);
    cJSON_AddNumberToObject(j, "map_tiles_paged_in", (double)R.tiles_paged_in);
    cJSON_AddNumberToObject(j, "carve_tiles_held_max", (double)R.carve_tiles_held_max);
    cJSON_AddNumberToObject(j, "carve_tiles_paged_out", (double)R.carve_tiles_paged_out);
    cJSON_AddNumberToObject(j, "carve_tiles_paged_in", (double)R.carve_tiles_paged_in);
    cJSON_AddNumberToObject(j, "scans_placed", (double)R.placed);
    cJSON_AddNumberToObject(j, "scans_unplaced", (double)R.unplaced);
    /* per drive (the fields above are the first drive's, or of the map from all) */
    cJSON *drives = cJSON_AddArrayToObject(j, "drives");
    for (const Run *D : R.drives) {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "log", D->log_path);
        cJSON_AddNumberToObject(o, "scans", (double)D->traj.size());
        cJSON_AddBoolToObject(o, "placed", D->placement.placed);
        cJSON_AddStringToObject(o, "why_not_placed", D->placement.placed ? "" : D->placement.why);
        cJSON_AddNumberToObject(o, "place_matches_tried", D->placement.tried);
        cJSON_AddNumberToObject(o, "place_matches_verified", D->placement.matched);
        cJSON_AddNumberToObject(o, "loops_to_other_drives", D->placement.links);
        const std::string n = D->drive ? "." + std::to_string(D->drive + 1) : "";
        cJSON_AddStringToObject(o, "trajectory", D->placement.placed ? ("trajectory" + n + ".tum").c_str() : "");
        cJSON_AddNumberToObject(o, "resumed_from_scan", (double)D->resumed_from);
        cJSON_AddStringToObject(o, "checkpoint_refused", D->checkpoint_refused.c_str());
        cJSON_AddItemToArray(drives, o);
    }
    char *text = cJSON_Print(j);
    cJSON_Delete(j);
    const std::string rep_path = R.path("report.json");
    FILE *f = text ? std::fopen(rep_path.c_str(), "w") : nullptr;
    bool ok = f && std::fputs(text, f) >= 0 && std::fputc('\n', f) != EOF;
    if (f) ok &= std::fclose(f) == 0;
    cJSON_free(text);
    if (!ok) return pb_err_set(err, "%s: cannot write", rep_path.c_str()), -1;
    if (!R.quiet && R.poses_path)
        std::fprintf(stderr, "mapper: %zu poses of %s over %.1f m in %.1f s of drive; %zu map points (%zu carved: moved); "
                     "%.1f s wall\n", R.traj.size(), R.poses_path, path_m, span_s, R.map_points, R.carved, wall_s);
    else if (!R.quiet)
        std::fprintf(stderr,
                     "mapper: %zu sweeps over %.1f m in %.1f s of drive (tracked %ld, searched %ld, weak %ld, "
                     "predicted %ld); %d loop(s) of %d tried, largest correction %.2f m; odometry %.2f ms per sweep "
                     "(median CPU), %zu map points (%zu carved: moved); %.1f s wall\n",
                     R.traj.size(), path_m, span_s, by_status[PB_ODOM_TRACKED], by_status[PB_ODOM_SEARCHED],
                     by_status[PB_ODOM_WEAK], by_status[PB_ODOM_PREDICTED], R.loops.verified, R.loops.candidates,
                     R.loops.max_change_m, pct(ms, 0.5), R.map_points, R.carved, wall_s);
    return 0;
}

/* --log: one more drive. */
static int add_log(const char *, const char *arg, void *logs)
{
    ((std::vector<const char *> *)logs)->push_back(arg);
    return 0;
}

int main(int argc, char **argv)
{
    Run R;
    std::vector<const char *> logs;
    R.log_path = nullptr;
    R.out_dir = nullptr;
    R.scan_ch = "LIDAR_SCAN";
    R.voxel = 0.15;
    R.quiet = 0;
    R.checkpoint_every = 100;
    const char *vehicle = PB_SOURCE_DIR "/vehicles/prius2017.yaml";
    const pb_opt_t opts[] = {
        PB_OPT_CALL("log", add_log, &logs), PB_OPT_REQUIRED("out", &R.out_dir), PB_OPT_STRING("vehicle", &vehicle),
        PB_OPT_STRING("scan-channel", &R.scan_ch), PB_OPT_DOUBLE("voxel", &R.voxel, 0.01, 10),
        PB_OPT_FLAG("quiet", &R.quiet, 1), PB_OPT_INT("checkpoint-every", &R.checkpoint_every, 1, 1000000),
        PB_OPT_STRING("poses", &R.poses_path), PB_OPT_DOUBLE("tile-m", &R.tile_m, 1, 10000), PB_OPT_END,
    };
    int parsed = pb_opt_parse("mapper", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    R.tiles_dir = R.path("map-tiles.tmp");
    if (logs.empty() || (R.poses_path && logs.size() > 1)) {
        std::fprintf(stderr, logs.empty() ? "mapper: --log is required\n" : "mapper: --poses places one --log\n");
        usage(stderr);
        return 2;
    }
    R.log_path = logs[0];
    const auto wall0 = std::chrono::steady_clock::now();
    double cpu_ms[4] = {pb_clock_process_cpu_ms(), 0, 0, 0};
    pb_err_t err;
    int rc = pb_vehicle_load(vehicle, &R.veh, &err);
    std::deque<Run> later;   /* drives 2..n: the same options and vehicle */
    R.drives.push_back(&R);
    for (size_t k = 1; k < logs.size(); k++) {
        later.push_back(R);
        later.back().log_path = logs[k];
        later.back().drive = (int)k;
        later.back().drives.clear();
        R.drives.push_back(&later.back());
    }
    if (rc == 0 && mkdir(R.out_dir, 0777) != 0 && errno != EEXIST)
        rc = pb_err_set(&err, "%s: cannot create: %s", R.out_dir, std::strerror(errno));
    // the sweeps counted, for the progress bars (every drive's first: a bad log fails early)
    for (Run *D : R.drives) {
        if (rc == 0)
            rc = pb_log_read_track(D->log_path, nullptr, nullptr, R.scan_ch,
                                   [](const pb_event_t *, void *u, pb_err_t *) { (*(long *)u)++; return 0; }, &D->total, &err);
        if (rc == 0 && D->total == 0) rc = pb_err_set(&err, "%s: no %s in the log", D->log_path, R.scan_ch);
    }
    for (Run *D : R.drives) {
        // a checkpoint of an interrupted run of this log resumed
        if (rc == 0 && !R.poses_path) rc = checkpoint_ids(D, &err);
        if (rc == 0 && !R.poses_path) rc = checkpoint_read(D, &err);
        // 1. odometry; a keyframe every 2 m (or the poses given)
        if (rc == 0) rc = R.poses_path ? read_poses(D, &err) : pass_odometry(D, &err);
        if (D->kf_file) std::fclose(D->kf_file);
        D->kf_file = nullptr;
        pb_odom_destroy(D->odom);   /* restored but not used (an error before the pass) */
        D->odom = nullptr;
    }
    cpu_ms[1] = pb_clock_process_cpu_ms();
    R.peak_mb[0] = peak_rss_mb();
    reset_peak_rss();
    // 2. loop closure over the keyframes
    if (rc == 0 && !R.poses_path) rc = close_loops(&R, &err);
    // 3. GNSS anchoring
    if (rc == 0) rc = anchor(&R, &err);
    cpu_ms[2] = pb_clock_process_cpu_ms();
    R.peak_mb[1] = peak_rss_mb();
    reset_peak_rss();
    // 4. the map with the final poses
    if (rc == 0) rc = pass_map(&R, &err);
    R.peak_mb[2] = peak_rss_mb();
    reset_peak_rss();
    // 5. the ground model, and what moved carved out with it
    pb_ground_t *ground = rc == 0 ? make_ground(&R, &err) : nullptr;
    if (rc == 0) rc = pass_carve(&R, ground, &err);
    pb_ground_destroy(ground);
    for (Run *D : R.drives) pb_pose_track_destroy(D->track);
    R.peak_mb[3] = peak_rss_mb();
    reset_peak_rss();
    // 6. the site's other files, the report
    if (rc == 0) rc = write_site(&R, &err);
    cpu_ms[3] = pb_clock_process_cpu_ms();
    R.peak_mb[4] = peak_rss_mb();
    if (rc == 0)
        rc = write_report(R, cpu_ms, std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count(), &err);
    if (rc != 0) {
        std::fprintf(stderr, "mapper: %s\n", err.msg);
        return 1;
    }
    for (Run *D : R.drives)   /* done: nothing to resume */
        for (const std::string &f : {D->work("checkpoint"), D->work("checkpoint") + ".tmp", D->work("keyframes")})
            std::remove(f.c_str());
    return 0;
}
