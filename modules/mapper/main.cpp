// mapper: a recorded drive (LCM log) -> a whole site, by LiDAR odometry, loop closure,
// GNSS anchoring and carving what moved (docs/mapper.md). This file: the options and the
// steps in order; the shell's parts are listed in mapper.h, the logic is in core/.
#include <chrono>
#include <filesystem>
#include <deque>
#include <malloc.h>
#include <sys/stat.h>

#include "mapper.h"
#include "pb_clock.h"
#include "pb_opt.h"
#include "portobello_lidar_scan_t.h"

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
        "the log has them (else the last step's motion; the sweeps of the first metre, aligned\n"
        "to the standing car's own view, are aligned again to the view from 3 m on), then\n"
        "every return within 60 m of the\n"
        "LiDAR is placed with the pose at its own time (farther ones are left out and counted:\n"
        "what moved is carved out by rays and views that reach 60 m, so nothing farther could be\n"
        "checked). Each voxel keeps when it was first and last hit (a carved one hit within 1 s\n"
        "moved through). Then the drive is read once more: the returns at the road under what\n"
        "moved, while it was there (a tyre's lowest 0.3 m), are taken out of the road's voxels; a\n"
        "voxel left standing alone over the road where something moved goes too.\n"
        
        "Where the drive passes a place again, the sweep is matched to the earlier pass's map\n"
        "and the poses are solved again with these loops (Ceres pose graph).\n"
        "Writes SITE_DIR/map.pcd (binary PCD, one point per voxel), SITE_DIR/trajectory.tum\n"
        "(base in map at the middle of each sweep, after loop closure; TUM: t x y z qx qy qz qw),\n"
        "SITE_DIR/odometry.tum (the same before loop closure), SITE_DIR/ground.yaml (+ .pgm or .blocks, the\n"
        "ground model), SITE_DIR/map.tiles (the map prepared for the localizer), report.json and\n"
        "SITE_DIR/report.png (top-down: map grey, trajectory before loop closure orange and after\n"
        "blue, loops green, GNSS fixes red, points carved as moving objects magenta, those that\n"
        "went as objects the views saw through violet; north up\n"
        "when geo-referenced). With\n"
        "GNSS_FIX in the log, the map is moved onto the fixes (east-north-up at the first 3-D\n"
        "fix) and SITE_DIR/site.yaml holds that geo-reference; a trajectory that stays farther\n"
        "from the fixes than their reported accuracy (a drift) is bent onto them (one drive);\n"
        "a receiver clock more than 0.3 s off the LiDAR's is measured from when the fixes\n"
        "arrive, said on stderr and in report.json, and taken out of the fix times;\n"
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
        "stderr and in report.json) and the run starts over. The later steps checkpoint too\n"
        "(poses.bin after the loops and anchoring, carved.bin after the map and carving, with\n"
        "map-tiles.tmp/): a run resumes after the last one done. A finished run removes them all.\n"
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
    auto lap_at = wall0;   /* step k's wall time: since the last step ended */
    auto lap = [&](int k) {
        const auto now = std::chrono::steady_clock::now();
        R.wall_s[k] = std::chrono::duration<double>(now - lap_at).count();
        lap_at = now;
    };
    pb_err_t err;
    int rc = pb_vehicle_load(vehicle, &R.veh, &err);
    pb_reg_config_default(&R.reg);
    R.reg.line_along_view = 0.3;   /* the odometry's local map saw each pole from the sweeps behind */
    for (int a = 0; a < 3; a++) R.reg.view_xyz[a] = R.veh.base_from_lidar.t[a];
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
    // the sweeps counted, for the progress bars (every drive's first: a bad log fails early),
    // and the first one's columns, which set the odometry's cell
    for (Run *D : R.drives) {
        if (rc == 0)
            rc = pb_log_read_track(D->log_path, nullptr, nullptr, R.scan_ch,
                                   [](const pb_event_t *ev, void *u, pb_err_t *) {
                                       Run *d = (Run *)u;
                                       portobello_lidar_scan_t s;
                                       /* (one that does not decode is the odometry pass's error to name) */
                                       if (d->total++ == 0 && portobello_lidar_scan_t_decode(ev->data, 0, ev->datalen, &s) >= 0) {
                                           if (s.npixels > 0) d->sweep_cols = s.cols;
                                           portobello_lidar_scan_t_decode_cleanup(&s);
                                       }
                                       return 0;
                                   }, D, &err);
        if (rc == 0 && D->total == 0) rc = pb_err_set(&err, "%s: no %s in the log", D->log_path, R.scan_ch);
        D->odom_cfg.cell_m = pb_odom_cell_m(D->sweep_cols);
    }
    for (Run *D : R.drives) {
        // a checkpoint of an interrupted run of this log resumed
        if (rc == 0) rc = checkpoint_ids(D, &err);
        if (rc == 0 && !R.poses_path) rc = checkpoint_read(D, &err);
        // 1. odometry; a keyframe every 2 m (or the poses given)
        if (rc == 0) rc = R.poses_path ? read_poses(D, &err) : pass_odometry(D, &err);
        if (D->kf_file) std::fclose(D->kf_file);
        D->kf_file = nullptr;
        pb_odom_destroy(D->odom);   /* restored but not used (an error before the pass) */
        D->odom = nullptr;
    }
    cpu_ms[1] = pb_clock_process_cpu_ms();
    lap(0);
    // what an interrupted run had done after the odometry (1: the loops and anchoring, 2: the
    // map and the carving too)
    int done = 0;
    if (rc == 0) rc = stage_read(&R, &done, &err);
    if (done >= 1) reset_peak_rss();   /* the steps done before keep their peaks */
    if (done < 1) {
        R.peak_mb[0] = peak_rss_mb();
        reset_peak_rss();
        // 2. loop closure over the keyframes
        if (rc == 0 && !R.poses_path) rc = close_loops(&R, &err);
        // 3. GNSS anchoring
        if (rc == 0) rc = anchor(&R, &err);
        R.peak_mb[1] = peak_rss_mb();
        reset_peak_rss();
        if (rc == 0) rc = stage_write_poses(&R, &err);
    }
    cpu_ms[2] = pb_clock_process_cpu_ms();
    lap(1);
    if (done < 2) {
        // 4. the map with the final poses
        if (rc == 0) rc = pass_map(&R, &err);
        R.peak_mb[2] = peak_rss_mb();
        reset_peak_rss();
        lap(2);
        // 5. the ground model, and what moved carved out with it
        pb_ground_t *ground = rc == 0 ? make_ground(&R, &err) : nullptr;
        if (rc == 0) rc = pass_carve(&R, ground, &err);
        pb_ground_destroy(ground);
        for (Run *D : R.drives) pb_pose_track_destroy(D->track);
        R.peak_mb[3] = peak_rss_mb();
        reset_peak_rss();
        if (rc == 0) rc = stage_write_carved(&R, &err);
        lap(3);
    }
    // 6. the site's other files, the report
    if (rc == 0) rc = write_site(&R, &err);
    cpu_ms[3] = pb_clock_process_cpu_ms();
    R.peak_mb[4] = peak_rss_mb();
    lap(4);
    if (rc == 0)
        rc = write_report(R, cpu_ms, std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count(), &err);
    if (rc != 0) {
        std::fprintf(stderr, "mapper: %s\n", err.msg);
        return 1;
    }
    for (Run *D : R.drives)   /* done: nothing to resume */
        for (const std::string &f : {D->work("checkpoint"), D->work("checkpoint") + ".tmp", D->work("keyframes")})
            std::remove(f.c_str());
    for (const char *f : {"poses.bin", "carved.bin"}) std::remove(R.path(f).c_str());
    std::error_code ec;
    std::filesystem::remove_all(R.tiles_dir, ec);
    return 0;
}

