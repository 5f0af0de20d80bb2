// mapper, step 6: the site's files (map.pcd from the kept tiles, the trajectories, map.tiles,
// site.yaml) and report.json (mapper.h).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <malloc.h>
#include "mapper.h"
#include "carve.h"
#include "map_source.h"
#include <cjson/cJSON.h>

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

static const char *kPeakStep[] = {"odometry", "loops", "map", "carve", "site"};

static const char *kStatusName[] = {"first", "tracked", "searched", "weak", "predicted", "from_previous"};

static double pct(std::vector<double> v, double p)
{
    if (v.empty()) return NAN;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, (size_t)std::floor(p * (double)(v.size() - 1) + 0.5))];
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
int write_site(Run *R, pb_err_t *err)
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
    if (rc != 0) return -1;   /* the map's tiles stay for a restart (carved.bin) until the end */
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

/* The poses the trajectory is judged at: the first, then each one at least half a second
 * after the one before (closer ones' noise would pass for acceleration or speed). */
static std::vector<const SweepPose *> half_second_marks(const std::vector<SweepPose> &traj)
{
    const int64_t kGapUs = 500000;
    std::vector<const SweepPose *> at;
    for (const SweepPose &s : traj)
        if (at.empty() || s.utime - at.back()->utime >= kGapUs) at.push_back(&s);
    return at;
}

/* Where the odometry (or the poses given) implies a horizontal acceleration no car makes (over
 * 5 m/s^2, the bound the MulRan reference is judged by), between half-second marks: the times
 * (s after the first pose) of the middle poses that break it; *checked the accelerations
 * computed, *max_mps2 the largest. An odometry lost by jumps shows many of these, a right one
 * none or a few; one that slides smoothly along a featureless road shows none. */
static std::vector<double> implausible_steps(const std::vector<SweepPose> &traj, int *checked, double *max_mps2)
{
    const double kLimitMps2 = 5.0;
    const std::vector<const SweepPose *> at = half_second_marks(traj);
    std::vector<double> bad;
    *checked = 0;
    *max_mps2 = 0;
    for (size_t i = 2; i < at.size(); i++) {
        const double t0 = at[i - 2]->utime * 1e-6, t1 = at[i - 1]->utime * 1e-6, t2 = at[i]->utime * 1e-6;
        const Eigen::Vector2d v1 = (at[i - 1]->odometry.translation() - at[i - 2]->odometry.translation()).head<2>() / (t1 - t0),
                              v2 = (at[i]->odometry.translation() - at[i - 1]->odometry.translation()).head<2>() / (t2 - t1);
        const double a = (v2 - v1).norm() / (0.5 * (t2 - t0));
        (*checked)++;
        *max_mps2 = std::max(*max_mps2, a);
        if (a > kLimitMps2) bad.push_back((at[i - 1]->utime - traj.front().utime) * 1e-6);
    }
    return bad;
}

/* Where the car measured its own speed (VEHICLE_SPEED, the sweeps' predictions), whether the
 * odometry went as fast: between half-second marks, the odometry's speed along the ground
 * against the mean measured speed of the sweeps after the first mark up to the second, by
 * magnitude (a wheel speed may be unsigned). A step is off when they differ by more than 1 m/s
 * and a fifth of the measured speed (wheel speeds err by a few percent). An odometry held where
 * the car stood while it drove (sparse rings among porous trees: docs/mapper.md, "Not yet")
 * passes the acceleration test above; the car's speed tells. *checked the steps compared,
 * *max_mps the largest difference; returns the steps off. */
static int speed_disagreements(const std::vector<SweepPose> &traj, int *checked, double *max_mps)
{
    const std::vector<const SweepPose *> at = half_second_marks(traj);
    *checked = 0;
    *max_mps = 0;
    int off = 0;
    for (size_t i = 1; i < at.size(); i++) {
        double sum = 0;
        int n = 0;
        for (const SweepPose *k = at[i - 1] + 1; k <= at[i]; k++)
            if (std::isfinite(k->measured_mps)) { sum += std::fabs(k->measured_mps); n++; }
        if (n != at[i] - at[i - 1]) continue;   /* every sweep of the step measured */
        const double measured = sum / n;
        const double odo = (at[i]->odometry.translation() - at[i - 1]->odometry.translation()).head<2>().norm() /
                           ((at[i]->utime - at[i - 1]->utime) * 1e-6);
        const double d = std::fabs(odo - measured);
        (*checked)++;
        *max_mps = std::max(*max_mps, d);
        off += d > 1.0 && d > 0.2 * measured;
    }
    return off;
}

/* report.json (cJSON: names and messages escaped) and the summary line. */
int write_report(const Run &R, const double cpu_ms[4], double wall_s, pb_err_t *err)
{
    long by_status[6] = {}, by_motion[3] = {}, sparse = 0;
    const int64_t sparse_gap_us = (int64_t)(pb_odom_config_t{}.sparse_gap_s * 1e6);
    double path_m = 0;
    std::vector<double> ms, inl;
    for (size_t i = 0; i < R.traj.size(); i++) {
        const SweepPose &s = R.traj[i];
        if (s.status != kGiven) by_status[s.status]++;
        if (s.motion != kGiven) by_motion[s.motion]++;
        if (i > 0) path_m += (s.pose.translation() - R.traj[i - 1].pose.translation()).norm();
        if (i > 0 && s.utime - R.traj[i - 1].utime > sparse_gap_us) sparse++;
        ms.push_back(s.cpu_ms);
        if (std::isfinite(s.inlier_fraction)) inl.push_back(s.inlier_fraction);
    }
    const double span_s = (R.traj.back().utime - R.traj.front().utime) * 1e-6;
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "log", R.log_path);
    cJSON_AddStringToObject(j, "poses_given", R.poses_path ? R.poses_path : "");
    cJSON_AddNumberToObject(j, "scans", (double)R.traj.size());
    cJSON_AddNumberToObject(j, "scans_in_log", (double)R.total);
    cJSON_AddNumberToObject(j, "sweep_columns", R.sweep_cols);
    cJSON_AddNumberToObject(j, "odometry_cell_m", R.odom_cfg.cell_m);
    cJSON_AddNumberToObject(j, "empty_scans", (double)R.empty);
    cJSON_AddNumberToObject(j, "out_of_order_scans", (double)R.out_of_order);
    /* (from_previous: sparse sweeps placed by the sweep before alone, odometry.h) */
    for (int k = 0; k < 6; k++) cJSON_AddNumberToObject(j, (std::string("scans_") + kStatusName[k]).c_str(), (double)by_status[k]);
    /* what each sweep's prediction came from: dead reckoning on VEHICLE_SPEED and IMU, the
     * last step's motion (LiDAR alone), or nothing (the first sweep, after a gap) */
    cJSON_AddNumberToObject(j, "scans_motion_measured", (double)by_motion[PB_ODOM_MOTION_MEASURED]);
    cJSON_AddNumberToObject(j, "scans_motion_constant", (double)by_motion[PB_ODOM_MOTION_CONSTANT]);
    cJSON_AddNumberToObject(j, "scans_motion_none", (double)by_motion[PB_ODOM_MOTION_NONE]);
    /* sweeps far apart (a dataset's keyframes, dropped sweeps): the odometry's sparse path
     * (odometry.h), which holds less well than on a live 10 Hz drive */
    cJSON_AddNumberToObject(j, "scans_sparse", (double)sparse);
    int accel_checked = 0;
    double accel_max = 0;
    const std::vector<double> implausible = implausible_steps(R.traj, &accel_checked, &accel_max);
    cJSON_AddNumberToObject(j, "odometry_accel_checked", accel_checked);
    cJSON_AddNumberToObject(j, "odometry_accel_max_mps2", accel_max);
    cJSON *bad = cJSON_AddArrayToObject(j, "odometry_implausible_at_s");
    for (double t : implausible) cJSON_AddItemToArray(bad, cJSON_CreateNumber(t));
    int speed_checked = 0;
    double speed_max = 0;
    const int speed_off = speed_disagreements(R.traj, &speed_checked, &speed_max);
    cJSON_AddNumberToObject(j, "odometry_speed_checked", speed_checked);
    cJSON_AddNumberToObject(j, "odometry_speed_off", speed_off);
    cJSON_AddNumberToObject(j, "odometry_speed_diff_max_mps", speed_max);
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
    /* the receiver's clock against the LiDAR's, taken out of the fix times (the first drive's) */
    cJSON_AddNumberToObject(j, "gnss_clock_offset_s", R.gnss_clock_offset_us * 1e-6);
    cJSON_AddNumberToObject(j, "gnss_clock_lags", R.gnss_clock_lags);
    cJSON_AddNumberToObject(j, "gnss_fixes_used", R.anchor.used);
    cJSON_AddNumberToObject(j, "gnss_fixes_gated", R.anchor.gated);
    cJSON_AddNumberToObject(j, "gnss_fixes_rejected", R.anchor.rejected);
    cJSON_AddNumberToObject(j, "gnss_resid_median_m", R.anchor.resid_median_m);
    cJSON_AddNumberToObject(j, "gnss_resid_p90_m", R.anchor.resid_p90_m);
    cJSON_AddNumberToObject(j, "gnss_resid_max_m", R.anchor.resid_max_m);
    cJSON_AddBoolToObject(j, "gnss_held", R.hold.held);   /* pb_anchor_hold: the drift bent onto the fixes */
    cJSON_AddNumberToObject(j, "gnss_drift_ratio", R.hold.ratio);
    cJSON_AddNumberToObject(j, "gnss_held_fixes", R.hold.fixes);
    cJSON_AddNumberToObject(j, "gnss_held_links", R.hold.links);   /* places the loops joined, kept joined */
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
    /* restart inside the later steps: the last step done before ("loops", "carve"; "" none) */
    cJSON_AddStringToObject(j, "resumed_after_step", R.resumed_after.c_str());
    cJSON_AddStringToObject(j, "stage_checkpoint_refused", R.stage_refused.c_str());
    cJSON *peak = cJSON_AddObjectToObject(j, "peak_rss_mb");
    double peak_all = 0;
    for (int k = 0; k < 5; k++) {
        cJSON_AddNumberToObject(peak, kPeakStep[k], std::round(R.peak_mb[k]));
        peak_all = std::max(peak_all, R.peak_mb[k]);
    }
    cJSON_AddNumberToObject(peak, "all", std::round(peak_all));
    /* where the wall time went (the loops step holds the anchoring; carve the ground model) */
    cJSON *steps = cJSON_AddObjectToObject(j, "wall_s_steps");
    for (int k = 0; k < 5; k++) cJSON_AddNumberToObject(steps, kPeakStep[k], std::round(R.wall_s[k] * 100) / 100);
    cJSON_AddStringToObject(j, "picture", "report.png");
    cJSON_AddNumberToObject(j, "picture_m_per_px", R.m_per_px);
    cJSON_AddNumberToObject(j, "map_points", (double)R.map_points);
    cJSON_AddNumberToObject(j, "map_range_m", pb_carve_config_t{}.max_range_m);
    cJSON_AddNumberToObject(j, "map_returns_beyond_range", (double)R.beyond_range);
    cJSON_AddNumberToObject(j, "map_points_carved", (double)R.carved);
    cJSON_AddNumberToObject(j, "map_points_carved_seen_through", (double)R.carved_groups);
    cJSON_AddNumberToObject(j, "under_moving_returns_taken", (double)R.under_returns);
    cJSON_AddNumberToObject(j, "under_moving_points_moved", (double)R.under_moved);
    cJSON_AddNumberToObject(j, "under_moving_points_gone", (double)R.under_gone);
    cJSON_AddNumberToObject(j, "under_sweeps_read", (double)R.under_sweeps);
    cJSON_AddNumberToObject(j, "carving_views", (double)R.views);
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
        cJSON_AddNumberToObject(o, "gnss_clock_offset_s", D->gnss_clock_offset_us * 1e-6);
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
    if (!R.quiet && !R.poses_path && 2 * sparse > (long)R.traj.size())
        std::fprintf(stderr, "mapper: warning: %ld of %zu sweeps came more than %.1f s after the one before (keyframes, "
                     "or a LiDAR dropping sweeps): the odometry holds less well on sweeps this far apart "
                     "(docs/mapper.md, \"Keyframe logs\")\n", sparse, R.traj.size(), sparse_gap_us * 1e-6);
    if (!R.quiet && 10 * implausible.size() > (size_t)accel_checked)
        std::fprintf(stderr, "mapper: warning: the %s imply more than 5 m/s^2, which no car does, at %zu of %d "
                     "half-second steps (the first %.1f s after the start): %s there, and the map with it "
                     "(report.json: odometry_implausible_at_s)\n", R.poses_path ? "poses given" : "odometry's poses",
                     implausible.size(), accel_checked, implausible.front(),
                     R.poses_path ? "they are likely wrong" : "it is likely lost");
    if (!R.quiet && 10 * speed_off > speed_checked)
        std::fprintf(stderr, "mapper: warning: the odometry's speed differs from the car's own (VEHICLE_SPEED) by more "
                     "than 1 m/s and a fifth at %d of %d half-second steps (up to %.1f m/s): it is likely lost, and "
                     "the map with it (report.json: odometry_speed_off)\n", speed_off, speed_checked, speed_max);
    if (!R.quiet && R.poses_path)
        std::fprintf(stderr, "mapper: %zu poses of %s over %.1f m in %.1f s of drive; %zu map points (%zu carved: moved; "
                     "%ld returns beyond %.0f m left out); %.1f s wall\n", R.traj.size(), R.poses_path, path_m, span_s,
                     R.map_points, R.carved, R.beyond_range, pb_carve_config_t{}.max_range_m, wall_s);
    else if (!R.quiet)
        std::fprintf(stderr,
                     "mapper: %zu sweeps over %.1f m in %.1f s of drive (tracked %ld, searched %ld, weak %ld, "
                     "predicted %ld); %d loop(s) of %d tried, largest correction %.2f m; odometry %.2f ms CPU per sweep "
                     "(mean, every thread), %zu map points (%zu carved: moved; %ld returns beyond %.0f m left out); %.1f s wall\n",
                     R.traj.size(), path_m, span_s, by_status[PB_ODOM_TRACKED], by_status[PB_ODOM_SEARCHED],
                     by_status[PB_ODOM_WEAK], by_status[PB_ODOM_PREDICTED], R.loops.verified, R.loops.candidates,
                     R.loops.max_change_m, (cpu_ms[1] - cpu_ms[0]) / (double)R.traj.size(), R.map_points, R.carved,
                     R.beyond_range, pb_carve_config_t{}.max_range_m, wall_s);
    return 0;
}
