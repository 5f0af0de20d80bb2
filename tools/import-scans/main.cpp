// import-scans: a folder of KITTI .bin / PCD scans plus a poses file -> an LCM
// log of LIDAR_SCAN (point form) + GROUND_TRUTH (the LiDAR pose in `map`), and
// optionally the prior map assembled from them.
//
// Scan k goes with pose k and time k; when the counts differ the minimum is
// imported and a warning names both counts (MulRan keyframe folders, e.g., hold
// one pose fewer than scans). Poses with their own times (TUM, or a time and a
// 3x4, as MulRan's global_pose.csv) at other instants than the scans' --times are
// interpolated at each scan's time instead (ground truth from an INS at 100 Hz).
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "pb_err.h"
#include "pb_log.h"
#include "pb_map_build.h"
#include "pb_opt.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "pose_files.h"
#include "scan_files.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"

namespace fs = std::filesystem;

// Times without --times or TUM stamps: 10 Hz from 2020-01-01T00:00:00Z.
static const int64_t DEFAULT_EPOCH_US = 1577836800LL * 1000000LL;
static const int64_t DEFAULT_PERIOD_US = 100000;

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: import-scans --scans DIR --poses FILE [--calib FILE] [--times FILE] --out LOG.lcm\n"
        "                    [--vehicle FILE] [--map-out MAP.pcd] [--voxel 0.15] [--every N [--first K]]\n"
        "                    [--sensor NAME] [--quiet]\n"
        "\n"
        "Imports the scans of DIR (KITTI .bin float32 x y z i, or .pcd with fields x y z and\n"
        "optionally intensity, t [ns] or time [s], ring) in file-name order. Scan k goes with\n"
        "pose k (and time k), unless the poses carry times of their own at other instants than\n"
        "--times: then each scan takes the pose interpolated at its time (linear, slerp), and a\n"
        "scan outside the poses' span or in a gap of more than 1 s between two of them is left\n"
        "out (counted). Writes per scan, at the same utime, GROUND_TRUTH (pose_t, source\n"
        "GROUND_TRUTH: the LiDAR pose in map, or the base pose with --vehicle) and LIDAR_SCAN (point form; ring 255 and offset 0\n"
        "when the file has none). Non-finite points are dropped and counted.\n"
        "  --poses FILE   KITTI (12 numbers a line: 3x4 row-major), TUM (8: t x y z qx qy qz qw)\n"
        "                 or timed KITTI (13: t and the 3x4, as MulRan's global_pose.csv),\n"
        "                 detected by the column count; spaces or commas between numbers; '#'\n"
        "                 lines are comments; times must increase. A time is seconds (up to 12\n"
        "                 integer digits and any decimals), or an integer of 16 digits\n"
        "                 (microseconds) or 19 (nanoseconds)\n"
        "  --calib FILE   KITTI calib with a Tr: line (velo -> cam). KITTI poses are camera poses;\n"
        "                 the LiDAR pose is then Tr^-1 * P * Tr, i.e. the map frame is the LiDAR\n"
        "                 frame at the first pose (z up), not the camera's (y down)\n"
        "  --vehicle FILE the poses are still LiDAR poses, but GROUND_TRUTH then carries the base\n"
        "                 pose (map <- lidar composed with lidar <- base from the vehicle file)\n"
        "  --times FILE   one UNIX time a line (e.g. MulRan times.txt); 'names': each scan's file\n"
        "                 name is its time (MulRan's Ouster/*.bin, in nanoseconds); else the poses'\n"
        "                 times; else 10 Hz from 2020-01-01T00:00:00Z\n"
        "  --map-out MAP  also assemble the prior map (binary PCD, x y z intensity) with voxel\n"
        "                 --voxel metres (default 0.15; 0 keeps every point). A folder holding\n"
        "                 only this file as map.pcd is a loadable site\n"
        "  --every N      import every Nth scan only (default 1)\n"
        "  --first K      ... from scan K on (0-based, default 0): --every 2 builds a map from the\n"
        "                 even scans, --every 2 --first 1 gives the odd ones to localize in it\n"
        "  --bin-fields L the float32 fields of a .bin point, in order (default x,y,z,i: KITTI,\n"
        "                 MulRan): names x y z i ring t (seconds after the scan's time) and _ (a\n"
        "                 field to skip), e.g. x,y,z,i,ring (nuScenes). The first scan is checked:\n"
        "                 read with the wrong point size, neighbours in the file jump apart, and\n"
        "                 that is an error naming the size that fits\n"
        "  --spin cw|ccw  scans without point times are raw sweeps of a LiDAR spinning this way\n"
        "                 seen from above (Velodyne and Ouster: cw): each point's time from its\n"
        "                 azimuth. Without it such scans are taken as motion-compensated (KITTI's\n"
        "                 odometry scans are), every point at the scan's time\n"
        "  --seam-deg D   with --spin: the azimuth (degrees, from the scan's x toward y) where a\n"
        "                 sweep starts, at the scan's time. Default: a scan in firing order (as\n"
        "                 sensors and KITTI-style .bin write them) starts at its first point; its\n"
        "                 points must turn the way --spin says, else it is an error\n"
        "  --sweep-ms MS  with --spin: the time of one turn (default 100, 10 Hz)\n"
        "  --sensor NAME  LIDAR_SCAN sensor name (default \"imported\"); the sensor string written is\n"
        "                 VEHICLE:NAME with --vehicle (the vehicle file's name), else lidar:NAME, so a\n"
        "                 module run with another vehicle file can tell and refuse the log\n"
        "If the numbers of scans, poses and times differ, the first min(...) are imported and a\n"
        "warning names the counts. Errors name FILE:LINE (text files) or FILE: byte N (.bin).\n");
}

// ---------------------------------------------------------------- main

static int bin_fields_option(const char *prog, const char *arg, void *var)
{
    pb_err_t err;
    if (parse_bin_fields(arg, static_cast<BinLayout *>(var), &err) == 0) return 0;
    std::fprintf(stderr, "%s: --bin-fields: %s\n", prog, err.msg);
    return -1;
}

static std::string lower_ext(const fs::path &p)
{
    std::string e = p.extension().string();
    for (auto &ch : e) ch = char(std::tolower((unsigned char)ch));
    return e;
}

// ---------------------------------------------------------------- main

// ---------------------------------------------------------------- poses at the scans' times

// A gap between two poses longer than this holds no ground truth for a scan inside it.
static const int64_t MAX_POSE_GAP_US = 1000000;

// Whether the poses' times are the scans' (the same count, each within half a millisecond).
static bool same_instants(const std::vector<int64_t> &pose_times, const std::vector<int64_t> &scan_times)
{
    if (pose_times.size() != scan_times.size()) return false;
    for (size_t k = 0; k < pose_times.size(); k++)
        if (std::llabs(pose_times[k] - scan_times[k]) > 500) return false;
    return true;
}

static pb_transform_t transform_of(const Eigen::Isometry3d &T)
{
    Eigen::Quaterniond q(T.linear());
    return {{T.translation().x(), T.translation().y(), T.translation().z()}, {q.w(), q.x(), q.y(), q.z()}};
}

// The poses at their times, for pb_pose_track_at; the caller destroys it.
static pb_pose_track_t *track_of(const std::vector<Eigen::Isometry3d> &poses, const std::vector<int64_t> &times)
{
    pb_pose_track_t *track = pb_pose_track_create();
    for (size_t k = 0; k < poses.size() && k < times.size(); k++) {
        pb_transform_t x = transform_of(poses[k]);
        pb_pose_track_add(track, times[k], &x);
    }
    return track;
}

// Replaces *poses (timed, increasing; track holds them) by one pose per scan:
// interpolated at the scan's time; scans with no pose there (before the first, after
// the last, or in a gap of more than MAX_POSE_GAP_US) are dropped from *files and
// *times, and counted in a warning. Returns 0, or -1 after an error message when no
// scan is left.
static int pair_by_time(const char *poses_path, const pb_pose_track_t *track, std::vector<fs::path> *files,
                        std::vector<int64_t> *times, std::vector<Eigen::Isometry3d> *poses,
                        const std::vector<int64_t> &pose_times)
{
    size_t n = std::min(files->size(), times->size());
    if (files->size() != times->size())
        std::fprintf(stderr, "import-scans: warning: %zu scans but %zu times: pairing the first %zu with the poses\n",
                     files->size(), times->size(), n);
    std::vector<fs::path> kept_files;
    std::vector<int64_t> kept_times;
    std::vector<Eigen::Isometry3d> kept_poses;
    size_t before = 0, after = 0, gap = 0;
    for (size_t k = 0; k < n; k++) {
        int64_t t = (*times)[k];
        auto hi = std::lower_bound(pose_times.begin(), pose_times.end(), t);
        pb_transform_t x;
        if (hi == pose_times.begin() && (hi == pose_times.end() || *hi != t)) { before++; continue; }
        if (hi == pose_times.end()) { after++; continue; }
        if (*hi != t && *hi - *(hi - 1) > MAX_POSE_GAP_US) { gap++; continue; }
        if (!pb_pose_track_at(track, t, &x)) { after++; continue; }
        Eigen::Isometry3d P = Eigen::Isometry3d::Identity();
        P.linear() = Eigen::Quaterniond(x.q[0], x.q[1], x.q[2], x.q[3]).normalized().toRotationMatrix();
        P.translation() = Eigen::Vector3d(x.t[0], x.t[1], x.t[2]);
        kept_files.push_back((*files)[k]);
        kept_times.push_back(t);
        kept_poses.push_back(P);
    }
    if (before + after + gap)
        std::fprintf(stderr, "import-scans: warning: %zu of %zu scans have no pose at their time in %s (%zu before its "
                     "first, %zu after its last, %zu in gaps over %.1f s): left out\n", before + after + gap, n,
                     poses_path, before, after, gap, MAX_POSE_GAP_US * 1e-6);
    if (kept_files.empty()) {
        std::fprintf(stderr, "import-scans: no scan time lies within the poses of %s (scans %.6f-%.6f s, poses "
                     "%.6f-%.6f s): are both UNIX times?\n", poses_path, n ? (*times)[0] * 1e-6 : 0.0,
                     n ? (*times)[n - 1] * 1e-6 : 0.0, pose_times.front() * 1e-6, pose_times.back() * 1e-6);
        return -1;
    }
    files->swap(kept_files);
    times->swap(kept_times);
    poses->swap(kept_poses);
    return 0;
}

int main(int argc, char **argv)
{
    const char *scans_dir = nullptr, *poses_path = nullptr, *calib_path = nullptr, *times_path = nullptr;
    const char *out_path = nullptr, *map_path = nullptr, *sensor = "imported", *vehicle_path = nullptr;
    double voxel = 0.15, seam_deg = NAN, sweep_ms = 100;
    long every = 1, first = 0;
    int quiet = 0, spin = 0;
    BinLayout layout;
    static const char *const spins[] = {"none", "cw", "ccw"};
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("scans", &scans_dir), PB_OPT_REQUIRED("poses", &poses_path), PB_OPT_STRING("calib", &calib_path),
        PB_OPT_STRING("times", &times_path), PB_OPT_REQUIRED("out", &out_path), PB_OPT_STRING("map-out", &map_path),
        PB_OPT_STRING("sensor", &sensor), PB_OPT_STRING("vehicle", &vehicle_path), PB_OPT_DOUBLE("voxel", &voxel, 0, 1000),
        PB_OPT_LONG("every", &every, 1, 1000000), PB_OPT_LONG("first", &first, 0, 1000000000),
        PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_CALL("bin-fields", bin_fields_option, &layout), PB_OPT_CHOICE("spin", &spin, spins, 3),
        PB_OPT_DOUBLE("seam-deg", &seam_deg, -360, 360), PB_OPT_DOUBLE("sweep-ms", &sweep_ms, 1, 1000), PB_OPT_END,
    };
    int parsed = pb_opt_parse("import-scans", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    auto t0 = std::chrono::steady_clock::now();
    pb_err_t err;

    // Scan files in name order.
    std::vector<fs::path> files;
    try {
        for (const auto &e : fs::directory_iterator(scans_dir)) {
            std::string ext = lower_ext(e.path());
            if (e.is_regular_file() && (ext == ".bin" || ext == ".pcd")) files.push_back(e.path());
        }
    } catch (const std::exception &e) {
        std::fprintf(stderr, "import-scans: %s: %s\n", scans_dir, e.what());
        return 1;
    }
    std::sort(files.begin(), files.end(),
              [](const fs::path &a, const fs::path &b) { return a.filename().string() < b.filename().string(); });
    if (files.empty()) {
        std::fprintf(stderr, "import-scans: %s: no .bin or .pcd scans\n", scans_dir);
        return 1;
    }

    std::vector<Eigen::Isometry3d> poses;
    std::vector<int64_t> pose_times, times;
    PoseFormat fmt = FMT_NONE;
    if (read_poses(poses_path, poses, pose_times, &fmt, &err) != 0) {
        std::fprintf(stderr, "import-scans: %s\n", err.msg);
        return 1;
    }
    if (calib_path) {
        Eigen::Isometry3d Tr;
        if (read_calib_tr(calib_path, &Tr, &err) != 0) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            return 1;
        }
        Eigen::Isometry3d Tri = Tr.inverse();
        for (auto &P : poses) P = Tri * P * Tr;
    }
    const char *time_src;
    if (times_path && std::strcmp(times_path, "names") == 0) {
        for (const fs::path &f : files) {
            int64_t us;
            if (parse_time_us(f.stem().string(), &us) != 0) {
                std::fprintf(stderr, "import-scans: --times names: %s: the name is not a time (seconds, or an integer "
                             "of 16 digits for microseconds or 19 for nanoseconds)\n", f.c_str());
                return 1;
            }
            times.push_back(us);
        }
        time_src = "the scans' names";
    } else if (times_path) {
        if (read_times(times_path, times, &err) != 0) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            return 1;
        }
        time_src = times_path;
    } else if (!pose_times.empty()) {
        times = pose_times;
        time_src = "the poses";
    } else {
        time_src = "10 Hz from 2020-01-01T00:00:00Z";
    }

    // Poses at other instants than the scans: each scan takes the pose at its own time
    // (and the map's points theirs, from the same track).
    pb_pose_track_t *track = nullptr;
    if (times_path && !pose_times.empty() && !same_instants(pose_times, times)) {
        track = track_of(poses, pose_times);
        if (pair_by_time(poses_path, track, &files, &times, &poses, pose_times) != 0) {
            pb_pose_track_destroy(track);
            return 1;
        }
    }
    size_t n = std::min(files.size(), poses.size());
    if (!times.empty()) n = std::min(n, times.size());
    if (files.size() != poses.size())
        std::fprintf(stderr, "import-scans: warning: %zu scans in %s but %zu poses in %s: importing the first %zu\n",
                     files.size(), scans_dir, poses.size(), poses_path, n);
    if (times_path && times.size() != files.size())
        std::fprintf(stderr, "import-scans: warning: %zu scans in %s but %zu times in %s: importing the first %zu\n",
                     files.size(), scans_dir, times.size(), times_path, n);
    if (times.empty())
        for (size_t k = 0; k < n; k++) times.push_back(DEFAULT_EPOCH_US + int64_t(k) * DEFAULT_PERIOD_US);

    // GROUND_TRUTH is the LiDAR pose unless a vehicle file gives base <- lidar.
    Eigen::Isometry3d lidar_from_base = Eigen::Isometry3d::Identity();
    // The scans say which frame their GROUND_TRUTH is in: "VEHICLE:SENSOR" (the base of
    // that vehicle file) or "lidar:SENSOR" (the LiDAR itself); the localizer refuses a
    // log whose vehicle is not its own instead of matching in the wrong frame.
    std::string frame = "lidar";
    if (vehicle_path) {
        pb_vehicle_t veh;
        if (pb_vehicle_load(vehicle_path, &veh, &err) != 0) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            return 1;
        }
        const pb_transform_t &b = veh.base_from_lidar;
        Eigen::Isometry3d base_from_lidar = Eigen::Isometry3d::Identity();
        base_from_lidar.linear() = Eigen::Quaterniond(b.q[0], b.q[1], b.q[2], b.q[3]).toRotationMatrix();
        base_from_lidar.translation() = Eigen::Vector3d(b.t[0], b.t[1], b.t[2]);
        lidar_from_base = base_from_lidar.inverse();
        frame = veh.name;
    }
    const std::string sensor_tag = frame + ":" + sensor;
    std::vector<Eigen::Isometry3d> gt_poses;
    for (const auto &P : poses) gt_poses.push_back(P * lidar_from_base);

    // The imported subset (every Nth from the first), with its times and poses.
    std::vector<size_t> pick;
    for (size_t k = size_t(first); k < n; k += size_t(every)) pick.push_back(k);
    if (pick.empty()) {
        std::fprintf(stderr, "import-scans: no scan to import: %zu scans pair with poses and times, and --first is %ld\n",
                     n, first);
        return 1;
    }
    for (size_t j = 1; j < pick.size(); j++)
        if (times[pick[j]] <= times[pick[j - 1]]) {
            std::fprintf(stderr, "import-scans: warning: times from %s do not increase at scan %zu (%s)\n", time_src,
                         pick[j], files[pick[j]].filename().c_str());
            break;
        }

    pb_map_builder_t *map = nullptr;
    if (map_path) {
        map = pb_map_builder_create(voxel, &err);
        if (!map) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            return 1;
        }
        if (!track) {   /* the imported poses at the scans' times */
            std::vector<Eigen::Isometry3d> at;
            std::vector<int64_t> t;
            for (size_t k : pick) { at.push_back(poses[k]); t.push_back(times[k]); }
            track = track_of(at, t);
        }
    }
    pb_log_t *log = pb_log_open_write(out_path, &err);
    if (!log) {
        std::fprintf(stderr, "import-scans: %s\n", err.msg);
        return 1;
    }

    pb_progress_t prog;
    pb_progress_start(&prog, "import-scans", int64_t(pick.size()), quiet);
    Scan s;
    std::vector<uint8_t> buf;
    long total_points = 0, total_dropped = 0, timed_fallback = 0, untimed = 0, spun_but_timed = 0;
    int status = 0;
    for (size_t j = 0; j < pick.size() && status == 0; j++) {
        size_t k = pick[j];
        pb_progress_update(&prog, int64_t(j));
        const std::string path = files[k].string();
        s.clear();
        int rc = lower_ext(files[k]) == ".bin" ? read_bin(path, layout, j == 0, s, &err) : read_pcd(path, s, &err);
        if (rc != 0) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            status = 1;
            break;
        }
        int np = int(s.x.size());
        total_points += np;
        total_dropped += s.dropped;
        if (s.has_time && spin) spun_but_timed++;
        else if (spin && times_from_azimuth(path, s, spin == 2, seam_deg * M_PI / 180, sweep_ms * 1000, &err) != 0) {
            std::fprintf(stderr, "import-scans: %s\n", err.msg);
            status = 1;
            break;
        }
        if (!s.has_time) {
            untimed++;
            s.offset_us.assign(size_t(np), 0);
        }
        if (!s.has_ring) s.ring.assign(size_t(np), 255);
        int64_t utime = times[k];

        // GROUND_TRUTH: the LiDAR (or base) pose; velocities by finite differences over the imported subset.
        const Eigen::Isometry3d &P = gt_poses[k];
        Eigen::Quaterniond q(P.linear());
        q.normalize();
        portobello_pose_t gt;
        std::memset(&gt, 0, sizeof gt);
        gt.utime = utime;
        for (int a = 0; a < 3; a++) gt.position[a] = P.translation()[a];
        gt.orientation[0] = q.w(); gt.orientation[1] = q.x(); gt.orientation[2] = q.y(); gt.orientation[3] = q.z();
        if (pick.size() > 1) {
            size_t ja = j > 0 ? j - 1 : j, jb = j + 1 < pick.size() ? j + 1 : j;
            const Eigen::Isometry3d &A = gt_poses[pick[ja]], &B = gt_poses[pick[jb]];
            double dt = double(times[pick[jb]] - times[pick[ja]]) * 1e-6;
            if (dt > 0) {
                Eigen::Vector3d v = (B.translation() - A.translation()) / dt;
                Eigen::AngleAxisd w(Eigen::Quaterniond(A.linear()).conjugate() * Eigen::Quaterniond(B.linear()));
                Eigen::Vector3d om = w.axis() * w.angle() / dt;   // in the body frame
                for (int a = 0; a < 3; a++) { gt.velocity[a] = v[a]; gt.angular_velocity[a] = om[a]; }
            }
        }
        gt.status = PORTOBELLO_POSE_T_STATUS_TRACKING;
        gt.source = PORTOBELLO_POSE_T_SOURCE_GROUND_TRUTH;
        gt.match_score = NAN;

        portobello_lidar_scan_t m;
        std::memset(&m, 0, sizeof m);
        double ident[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
        m.utime = utime;
        m.sensor = const_cast<char *>(sensor_tag.c_str());
        m.seq = int32_t(k);
        std::memcpy(m.lidar_from_beam, ident, sizeof ident);
        m.npoints = np;
        m.x = s.x.data(); m.y = s.y.data(); m.z = s.z.data(); m.intensity = s.intensity.data();
        m.point_offset_us = s.offset_us.data();
        m.ring = s.ring.data();

        int ngt = portobello_pose_t_encoded_size(&gt);
        int nsc = portobello_lidar_scan_t_encoded_size(&m);
        buf.resize(size_t(std::max(ngt, nsc)));
        if (portobello_pose_t_encode(buf.data(), 0, ngt, &gt) < 0 ||
            pb_log_write(log, utime, "GROUND_TRUTH", buf.data(), ngt, &err) != 0 ||
            portobello_lidar_scan_t_encode(buf.data(), 0, nsc, &m) < 0 ||
            pb_log_write(log, utime, "LIDAR_SCAN", buf.data(), nsc, &err) != 0) {
            std::fprintf(stderr, "import-scans: %s: %s\n", out_path, err.msg);
            status = 1;
            break;
        }

        if (map && np > 0) {
            pb_points_t pts = {np, np, s.x.data(), s.y.data(), s.z.data(), s.intensity.data(), s.offset_us.data(),
                               s.ring.data()};
            // the points are the LiDAR's: placed with the LiDAR pose (P is the base's with --vehicle)
            const Eigen::Isometry3d &L = poses[k];
            pb_transform_t x = transform_of(L);
            int r = s.has_time ? pb_map_builder_add_timed(map, &pts, utime, track, nullptr, &err) : 0;
            if (r == 0) {   // no per-point time, or times beyond the poses: the scan's own pose
                if (s.has_time) timed_fallback++;
                r = pb_map_builder_add(map, &pts, &x, &err) == 0 ? 1 : -1;
            }
            if (r < 0) {
                std::fprintf(stderr, "import-scans: %s: %s\n", path.c_str(), err.msg);
                status = 1;
            }
        }
    }
    if (status == 0) pb_progress_finish(&prog);
    else if (prog.tty && !quiet) std::fputc('\n', stderr);
    if (pb_log_close(log, &err) != 0) {
        std::fprintf(stderr, "import-scans: %s\n", err.msg);
        status = 1;
    }
    if (status == 0 && map && pb_map_builder_write_pcd(map, map_path, &err) != 0) {
        std::fprintf(stderr, "import-scans: %s\n", err.msg);
        status = 1;
    }
    if (total_dropped)
        std::fprintf(stderr, "import-scans: %ld non-finite points dropped\n", total_dropped);
    if (untimed)
        std::fprintf(stderr, "import-scans: %ld scans have no point times: imported as motion-compensated sweeps (every "
                     "point at the scan's time); raw sweeps of a spinning LiDAR need --spin (see --help)\n", untimed);
    if (spun_but_timed)
        std::fprintf(stderr, "import-scans: %ld scans carry point times of their own: --spin not used for them\n",
                     spun_but_timed);
    if (timed_fallback)
        std::fprintf(stderr, "import-scans: %ld scans had point times beyond the poses: placed with their scan pose\n",
                     timed_fallback);
    if (status == 0 && !quiet) {
        double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        std::fprintf(stderr, "import-scans: %zu scans (%s poses, times from %s), %ld points -> %s", pick.size(),
                     format_name(fmt), time_src, total_points, out_path);
        if (map)
            std::fprintf(stderr, "; map %lld points (voxel %.3f m) -> %s", (long long)pb_map_builder_size(map), voxel,
                         map_path);
        std::fprintf(stderr, " in %.2f s\n", dt);
    }
    pb_map_builder_destroy(map);
    pb_pose_track_destroy(track);
    return status;
}
