// build-map: LIDAR_SCAN + a pose channel of an LCM log -> a voxelised prior map (binary PCD).
//
// Every point is moved by the pose at its own time (scan utime + its offset), so
// the sweep's motion is undone; the pose is interpolated between the two
// logged poses that bracket it. Scans without bracketing poses are skipped and
// counted. Two passes over the log: poses first (small), then scans.
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "pb_err.h"
#include "pb_log.h"
#include "pb_map_build.h"
#include "pb_opt.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_pose_t.h"

static void usage(FILE *f)
{
    std::fprintf(f,
        "usage: build-map --log LOG.lcm --out MAP.pcd [--voxel 0.15] [--pose-channel GROUND_TRUTH]\n"
        "                 [--scan-channel LIDAR_SCAN] [--vehicle FILE] [--every N] [--quiet]\n"
        "\n"
        "Assembles the LIDAR_SCAN sweeps of LOG into one point cloud in `map` and writes it\n"
        "as binary PCD (x y z intensity), one point per voxel (centroid, mean intensity).\n"
        "  --pose-channel C  portobello.pose_t messages, base in map (default GROUND_TRUTH);\n"
        "                    each point uses the pose at scan utime + its offset, linear in\n"
        "                    position and slerp in orientation\n"
        "  --vehicle FILE    vehicle file giving base <- lidar (sensors: lidar: xyz, rpy_deg);\n"
        "                    without it the poses are taken as LiDAR poses\n"
        "  --voxel M         voxel edge in metres (default 0.15; 0 keeps every point)\n"
        "  --every N         use every Nth scan only (default 1)\n"
        "Scans whose points are not all bracketed by poses are skipped and counted.\n"
        "Exit 1 on error, or if no scan could be used.\n");
}

int main(int argc, char **argv)
{
    const char *log_path = nullptr, *out_path = nullptr, *vehicle = nullptr;
    const char *pose_ch = "GROUND_TRUTH", *scan_ch = "LIDAR_SCAN";
    double voxel = 0.15;
    long every = 1;
    int quiet = 0;
    const pb_opt_t opts[] = {
        PB_OPT_REQUIRED("log", &log_path), PB_OPT_REQUIRED("out", &out_path), PB_OPT_STRING("vehicle", &vehicle),
        PB_OPT_STRING("pose-channel", &pose_ch), PB_OPT_STRING("scan-channel", &scan_ch),
        PB_OPT_DOUBLE("voxel", &voxel, 0, 1000), PB_OPT_LONG("every", &every, 1, 1000000), PB_OPT_FLAG("quiet", &quiet, 1),
        PB_OPT_END,
    };
    int parsed = pb_opt_parse("build-map", opts, usage, 0, argc, argv);
    if (parsed >= 0) return parsed;
    auto t0 = std::chrono::steady_clock::now();
    pb_err_t err;

    pb_transform_t base_from_lidar = {{0, 0, 0}, {1, 0, 0, 0}};
    if (vehicle) {
        pb_vehicle_t veh;
        if (pb_vehicle_load(vehicle, &veh, &err) != 0) {
            std::fprintf(stderr, "build-map: %s\n", err.msg);
            return 1;
        }
        base_from_lidar = veh.base_from_lidar;
    }

    // Pass 1: poses, and the number of scans (for the progress bar).
    struct Pass1 { pb_pose_track_t *track; long nscans; } pass1 = { pb_pose_track_create(), 0 };
    auto on_pose = [](const portobello_pose_t *p, const pb_transform_t *T, void *u) {
        pb_pose_track_add(((Pass1 *)u)->track, p->utime, T);
    };
    auto on_scan = [](const pb_event_t *, void *u, pb_err_t *) { ((Pass1 *)u)->nscans++; return 0; };
    if (pb_log_read_track(log_path, pose_ch, on_pose, scan_ch, on_scan, &pass1, &err)) {
        std::fprintf(stderr, "build-map: %s\n", err.msg);
        return 1;
    }
    pb_pose_track_t *track = pass1.track;
    long nscans_total = pass1.nscans;
    if (pb_pose_track_count(track) == 0) {
        std::fprintf(stderr, "build-map: %s: no %s poses\n", log_path, pose_ch);
        return 1;
    }

    // Pass 2: scans.
    pb_map_builder_t *map = pb_map_builder_create(voxel, &err);
    pb_log_t *log = map ? pb_log_open_read(log_path, &err) : nullptr;
    if (!log) {
        std::fprintf(stderr, "build-map: %s\n", err.msg);
        return 1;
    }
    pb_points_t pts;
    std::memset(&pts, 0, sizeof pts);
    pb_progress_t prog;
    pb_progress_start(&prog, "build-map", nscans_total, quiet);
    long seen = 0, used = 0, skipped = 0, empty = 0;
    int status = 0;
    pb_event_t ev;
    int rc;
    while ((rc = pb_log_next(log, &ev, &err)) == 1) {
        if (std::strcmp(ev.channel, scan_ch) != 0) continue;
        pb_progress_update(&prog, seen);
        long idx = seen++;
        if (idx % every) continue;
        portobello_lidar_scan_t s;
        if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) {
            std::fprintf(stderr, "build-map: %s: byte %lld: cannot decode %s as lidar_scan_t\n", log_path,
                         (long long)ev.offset, ev.channel);
            status = 1;
            break;
        }
        int n = pb_scan_points(&s, &pts, &err);
        int64_t utime = s.utime;
        portobello_lidar_scan_t_decode_cleanup(&s);
        if (n < 0) {
            std::fprintf(stderr, "build-map: %s: byte %lld: %s\n", log_path, (long long)ev.offset, err.msg);
            status = 1;
            break;
        }
        if (n == 0) { empty++; continue; }
        int r = pb_map_builder_add_timed(map, &pts, utime, track, vehicle ? &base_from_lidar : nullptr, &err);
        if (r < 0) {
            std::fprintf(stderr, "build-map: scan at utime %lld: %s\n", (long long)utime, err.msg);
            status = 1;
            break;
        }
        if (r == 0) skipped++;
        else used++;
    }
    if (rc < 0) {
        std::fprintf(stderr, "build-map: %s\n", err.msg);
        status = 1;
    }
    if (status == 0) pb_progress_finish(&prog);
    else if (prog.tty && !quiet) std::fputc('\n', stderr);
    pb_log_close(log, nullptr);
    pb_points_free(&pts);

    if (status == 0 && used == 0) {
        std::fprintf(stderr, "build-map: no usable scan (%ld on %s, %ld without bracketing %s poses, %ld empty)\n",
                     seen, scan_ch, skipped, pose_ch, empty);
        status = 1;
    }
    if (status == 0 && pb_map_builder_write_pcd(map, out_path, &err) != 0) {
        std::fprintf(stderr, "build-map: %s\n", err.msg);
        status = 1;
    }
    if (status == 0) {
        double mn[3], mx[3];
        pb_map_builder_bounds(map, mn, mx);
        double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (skipped)
            std::fprintf(stderr, "build-map: warning: %ld scans skipped: no bracketing %s poses\n", skipped, pose_ch);
        if (!quiet)
            std::fprintf(stderr,
                         "build-map: %ld of %ld scans used (every %ld; %ld skipped, %ld empty), %lld points -> "
                         "%lld map points (voxel %.3f m), extent [%.1f %.1f %.1f]..[%.1f %.1f %.1f] m, "
                         "%s written in %.2f s\n",
                         used, seen, every, skipped, empty, (long long)pb_map_builder_points_in(map),
                         (long long)pb_map_builder_size(map), voxel, mn[0], mn[1], mn[2], mx[0], mx[1], mx[2],
                         out_path, dt);
    }
    pb_map_builder_destroy(map);
    pb_pose_track_destroy(track);
    return status;
}
