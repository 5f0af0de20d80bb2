// mapper, steps 1-3: the sweeps' poses by odometry (or --poses), loop closure and GNSS
// anchoring (mapper.h; the logic in core/odometry, loops, anchor, pose_graph).
#include <cmath>
#include "mapper.h"
#include "pb_clock.h"
#include "pb_clock_offset.h"
#include "pose_graph.h"
#include "portobello_gnss_fix_t.h"
#include "portobello_imu_t.h"
#include "portobello_lidar_scan_t.h"
#include "portobello_vehicle_speed_t.h"

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

/* For each GNSS_FIX of the log, its time minus the end of the newest sweep on scan_ch that
 * came before it. One more read of the log, only for logs with fixes. */
static int read_fix_lags(const char *log_path, const char *scan_ch, std::vector<int64_t> *lags, pb_err_t *err)
{
    pb_log_t *log = pb_log_open_read(log_path, err);
    if (!log) return -1;
    pb_event_t ev;
    int rc;
    int64_t newest_end = INT64_MIN;
    while ((rc = pb_log_next(log, &ev, err)) == 1) {
        if (std::strcmp(ev.channel, scan_ch) == 0) {
            portobello_lidar_scan_t s;
            if (portobello_lidar_scan_t_decode(ev.data, 0, ev.datalen, &s) < 0) continue;   /* the odometry said so */
            int64_t last = 0;   /* the sweep's last return, after its time */
            for (int c = 0; c < s.cols; c++) last = std::max<int64_t>(last, s.col_offset_us[c]);
            for (int i = 0; i < s.npoints; i++) last = std::max<int64_t>(last, s.point_offset_us[i]);
            newest_end = std::max(newest_end, s.utime + last);
            portobello_lidar_scan_t_decode_cleanup(&s);
        } else if (std::strcmp(ev.channel, "GNSS_FIX") == 0 && newest_end != INT64_MIN) {
            portobello_gnss_fix_t f;
            if (portobello_gnss_fix_t_decode(ev.data, 0, ev.datalen, &f) < 0) continue;   /* not a fix: not used */
            lags->push_back(f.utime - newest_end);
            portobello_gnss_fix_t_decode_cleanup(&f);
        }
    }
    pb_log_close(log, nullptr);
    return rc < 0 ? -1 : 0;   /* err names the log and the byte */
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


/* --poses: the trajectory from a TUM file (t x y z qx qy qz qw: base in map, t in seconds
 * ascending; '#' comments), no odometry and no loops: the map, the ground and the carving
 * are made with these poses (an INS or RTK trajectory, another SLAM's). Errors name the
 * file and line. */
int read_poses(Run *R, pb_err_t *err)
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
        R->traj.push_back({utime, T, T, kGiven, kGiven, NAN, 0, -1, NAN});
    }
    std::fclose(f);
    if (rc == 0 && R->traj.size() < 2)
        rc = pb_err_set(err, "%s: %zu pose(s); a map needs two or more", R->poses_path, R->traj.size());
    return rc;
}

/* Pass 1: odometry over every sweep; a keyframe every kKeyframeSpacingM; a checkpoint
 * every R->checkpoint_every sweeps and at the end. Resumes where R's checkpoint left off. */
int pass_odometry(Run *R, pb_err_t *err)
{
    const std::string kf_path = R->work("keyframes");
    R->kf_file = std::fopen(kf_path.c_str(), R->resumed_from ? "ab" : "wb");
    if (!R->kf_file) return pb_err_set(err, "%s: cannot write: %s", kf_path.c_str(), std::strerror(errno)), -1;
    if (R->odometry_done) return 0;
    pb_odom_t *odom = R->odom ? R->odom : pb_odom_create(&R->odom_cfg, &R->reg);
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
            for (size_t c = 0; c < r.n_corrected; c++)   /* the start's sweeps aligned again */
                for (size_t i = R->traj.size(); i-- > 0;)
                    if (R->traj[i].utime == r.corrected[c].utime) {
                        R->traj[i].pose = R->traj[i].odometry = r.corrected[c].pose;
                        break;
                    }
            std::vector<pb_keyframe_t> &kf = R->kf;
            if (kf.empty() || (r.pose.translation() - kf.back().pose.translation()).norm() >= kKeyframeSpacingM) {
                kf.push_back({r.utime, r.pose, {}});
                const std::vector<float> &sw = pb_odom_last_sweep(odom);
                pb_reg_downsample(sw.data(), sw.size() / 3, &kf_reduce, &kf.back().xyz);
            }
            R->traj.push_back({r.utime, r.pose, r.pose, r.status, r.motion, r.inlier_fraction,
                               pb_clock_thread_cpu_ms() - c0, (int)kf.size() - 1,
                               r.motion == PB_ODOM_MOTION_MEASURED ? r.v_base.x() : NAN});
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
int close_loops(Run *R, pb_err_t *err)
{
    std::vector<pb_keyframe_t> kf;   /* every drive's, one drive after the other, without their points */
    struct Files {
        std::vector<std::string> path;
        std::vector<FILE *> f;
        ~Files() { for (FILE *x : f) if (x) std::fclose(x); }
    } files;
    for (Run *D : R->drives) {
        const std::string kf_path = D->work("keyframes");
        if (!read_keyframes(kf_path, D->kf.size(), D->kf_bytes, false, &D->kf))
            return pb_err_set(err, "%s: cannot read the keyframes back", kf_path.c_str()), -1;
        for (pb_keyframe_t &k : D->kf) {
            k.drive = D->drive;
            kf.push_back(k);
        }
        files.path.push_back(kf_path);
        files.f.push_back(std::fopen(kf_path.c_str(), "rb"));
        if (!files.f.back()) return pb_err_set(err, "%s: cannot open: %s", kf_path.c_str(), std::strerror(errno)), -1;
    }
    // the points read back from keyframes.bin as the loops need them (an hour of drive's
    // keyframes would be most of a gigabyte)
    const pb_keyframe_points_t points = {
        [](void *u, const pb_keyframe_t &k, std::vector<float> *xyz, pb_err_t *e) {
            const Files &fs = *(const Files *)u;
            return keyframe_points(fs.f[(size_t)k.drive], fs.path[(size_t)k.drive], k.points_key, xyz, e);
        },
        &files};
    std::vector<Eigen::Isometry3d> solved;
    if (kf.size() >= 2) {
        pb_loops_config_t lcfg;
        lcfg.reg = R->reg;
        if (pb_loops_close(kf, &lcfg, &solved, &R->loops, err, &points) != 0) return -1;
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
int anchor(Run *R, pb_err_t *err)
{
    std::vector<Run *> placed;
    for (Run *D : R->drives)
        if (D->placement.placed) placed.push_back(D);
    std::vector<std::vector<portobello_gnss_fix_t>> fixes(placed.size());
    for (size_t d = 0; d < placed.size(); d++) {
        Run *D = placed[d];
        if (read_fixes(D->log_path, &fixes[d], err) != 0) return -1;
        std::vector<int64_t> lags;
        if (!fixes[d].empty() && read_fix_lags(D->log_path, D->scan_ch, &lags, err) != 0) return -1;
        D->gnss_clock_lags = (int)lags.size();
        /* the receiver's clock against the sweeps' over the whole drive (pb_clock_offset.h): as
         * stamped, a fix would be taken for where the car was seconds later, and the map moved
         * and bent along its path by speed x offset */
        D->gnss_clock_offset_us = pb_clock_offset_median(lags.data(), lags.size(), PB_CLOCK_OFFSET_TOL_US);
        for (auto &f : fixes[d]) f.utime -= D->gnss_clock_offset_us;
        if (D->gnss_clock_offset_us && !R->quiet)
            std::fprintf(stderr, "mapper: %s: the GNSS receiver's clock is %+.2f s off the LiDAR's (median of %zu fixes); "
                         "fix times corrected by that\n", D->log_path, D->gnss_clock_offset_us * 1e-6, lags.size());
    }
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
    // a drift the fixes see beyond their own errors bent out (pb_anchor_hold: every placed
    // drive on its fixes, the places the loops joined kept joined), then fitted again
    std::vector<pb_anchor_drive_t> held(placed.size());
    std::vector<int> index(R->drives.size(), -1);   /* drive -> its place in held */
    for (size_t d = 0; d < placed.size(); d++) {
        index[(size_t)placed[d]->drive] = (int)d;
        for (const SweepPose &sp : placed[d]->traj) { held[d].utime.push_back(sp.utime); held[d].poses.push_back(sp.pose); }
        held[d].obs = observe_fixes(fixes[d], placed[d]->traj, R->veh, R->georef);
    }
    std::vector<pb_anchor_link_t> links;
    for (const auto &l : R->loop_times)
        if (index[(size_t)l.first.first] >= 0 && index[(size_t)l.second.first] >= 0)
            links.push_back({index[(size_t)l.first.first], l.first.second, index[(size_t)l.second.first], l.second.second});
    const Eigen::Vector3d lever(R->veh.base_from_gnss.t[0], R->veh.base_from_gnss.t[1], R->veh.base_from_gnss.t[2]);
    if (pb_anchor_hold(&held, links, R->anchor, lever, nullptr, &R->hold, err) != 0) return -1;
    if (R->hold.held) {
        for (size_t d = 0; d < placed.size(); d++)
            for (size_t i = 0; i < held[d].poses.size(); i++) placed[d]->traj[i].pose = held[d].poses[i];
        observe();
        if (pb_anchor_fit(obs, nullptr, &R->anchor, err) != 0) return -1;
        for (Run *D : placed)
            for (SweepPose &sp : D->traj) sp.pose = R->anchor.enu_from_map * sp.pose;
    }
    for (const pb_anchor_obs_t &o : obs) R->layers.fixes.push_back(o.fix_enu);
    return 0;
}
