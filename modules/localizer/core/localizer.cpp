/* The localizer pipeline (see localizer.h). */
#include "localizer.h"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <deque>

namespace loc {

enum { EV_IMU = 0, EV_SPEED = 1 };

struct input_ev_t {
    int64_t t;
    int kind;
    Vec3 accel, gyro;   /* EV_IMU, raw (imu frame) */
    double speed;       /* EV_SPEED */
};

struct gnss_res_t {
    int64_t t;
    Eigen::Vector2d r;  /* fix minus predicted antenna position, map xy */
    double h_acc;
};

struct pose_sample_t {
    int64_t t;
    Eigen::Isometry3d map_from_imu;
};

struct localizer {
    localizer_config_t cfg;
    extrinsics_t ex;
    const pb_regmap_t *map;
    bool has_geo;
    pb_georef_t geo;

    filter_t kf;       /* committed: at the last sweep (or the last commit of old inputs) */
    filter_t pred;     /* kf moved forward by every input since */
    std::deque<input_ev_t> buf;
    Vec3 last_accel = Vec3::Zero(), last_gyro = Vec3::Zero();

    int64_t last_imu_t = 0, last_speed_t = 0, last_scan_t = 0, last_pose_out_t = 0, last_pred_out_t = 0;
    int status = ST_INITIALIZING;
    bool candidate = false;     /* kf holds a pose still being verified */
    int verify_count = 0, reject_count = 0;
    bool lidar_gap_reported = false;

    bool has_hint = false;
    Eigen::Isometry3d hint;
    int64_t hint_t = 0;
    Vec3 hint_body_vel = Vec3::Zero();   /* velocity in base before the hint, carried over */

    bool has_fix = false;
    gnss_in_t fix;
    Vec3 fix_map = Vec3::Zero();
    std::deque<gnss_res_t> gnss_res;

    /* LiDAR-only turn rate from successive poses */
    bool has_prev_pose = false;
    Eigen::Isometry3d prev_pose;
    int64_t prev_pose_t = 0;

    double last_structure = NAN;       /* the last structure fit >= cfg.structure_trust, and its time */
    int64_t last_structure_t = 0;
    std::vector<float> xyz, above;
    /* a sweep waiting for the IMU to reach its end */
    bool has_pending = false;
    int64_t pend_utime = 0, pend_t_ref = 0;
    std::vector<float> pend_x, pend_y, pend_z;
    std::vector<int32_t> pend_off;
    std::vector<pose_sample_t> samples;
};

static void event(outputs_t *out, const char *counter, const char *fmt = nullptr, ...)
    __attribute__((format(printf, 3, 4)));
static void event(outputs_t *out, const char *counter, const char *fmt, ...)
{
    event_t e;
    e.counter = counter;
    if (fmt) {
        char buf[512];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(buf, sizeof buf, fmt, ap);
        va_end(ap);
        e.message = buf;
    }
    out->events.push_back(e);
}

const char *localizer_status_name(int s)
{
    switch (s) {
    case ST_INITIALIZING: return "initializing";
    case ST_TRACKING: return "tracking";
    case ST_DEGRADED: return "degraded";
    case ST_LOST: return "lost";
    }
    return "?";
}

int localizer_status(const localizer_t *L) { return L->status; }

localizer_t *localizer_create(const localizer_config_t &cfg, const extrinsics_t &ex, const pb_regmap_t *map,
                              const pb_georef_t *geo)
{
    localizer_t *L = new localizer();
    L->cfg = cfg;
    L->ex = ex;
    L->map = map;
    L->has_geo = geo != nullptr;
    if (geo) L->geo = *geo;
    filter_create(&L->kf, cfg.filter, ex.base_from_imu);
    L->pred = L->kf;
    if (cfg.has_initial_pose) {
        const double *ip = cfg.initial_pose;
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        T.linear() = (Eigen::AngleAxisd(ip[5], Vec3::UnitZ()) * Eigen::AngleAxisd(ip[4], Vec3::UnitY()) *
                      Eigen::AngleAxisd(ip[3], Vec3::UnitX())).toRotationMatrix();
        T.translation() = Vec3(ip[0], ip[1], ip[2]);
        L->has_hint = true;
        L->hint = T;
        L->hint_t = 0;   /* valid at the first sweep */
    }
    return L;
}

void localizer_destroy(localizer_t *L) { delete L; }

static bool imu_fresh(const localizer_t *L, int64_t t)
{
    return L->last_imu_t != 0 && t - L->last_imu_t <= L->cfg.imu_timeout_us && t >= L->last_imu_t - 1000000;
}

/* Applies one buffered input to a filter (IMU predict or speed update). */
static void apply_input(const localizer_t *L, filter_t *f, const input_ev_t &e)
{
    if (e.kind == EV_IMU) {
        if (f->initialized && e.t - f->utime > L->cfg.imu_timeout_us) filter_predict_cv(f, e.t);
        filter_predict_imu(f, e.t, e.accel, e.gyro);
    } else if (e.kind == EV_SPEED) {
        if (f->initialized) {
            if (e.t > f->utime && !imu_fresh(L, e.t)) filter_predict_cv(f, e.t);
            filter_update_speed(f, e.speed);
        }
    }
}

static pose_out_t make_pose(const localizer_t *L, const filter_t &f, int64_t t, bool predicted, double score)
{
    pose_out_t p;
    p.predicted = predicted;
    p.utime = t;
    p.map_from_base = filter_base_pose(&f);
    p.velocity = filter_base_velocity(&f);
    p.angular_velocity = filter_base_rate(&f);
    p.covariance = filter_base_covariance(&f);
    p.status = L->status;
    p.source = predicted ? SRC_PREDICTED : SRC_LOCALIZER;
    p.match_score = score;
    return p;
}

static void emit_unknown_pose(localizer_t *L, int64_t t, outputs_t *out)
{
    pose_out_t p;
    p.predicted = false;
    p.utime = t;
    p.map_from_base = Eigen::Isometry3d::Identity();
    p.velocity.setZero();
    p.angular_velocity.setZero();
    p.covariance.setZero();   /* all zero: unknown */
    p.status = L->status;
    p.source = SRC_LOCALIZER;
    p.match_score = NAN;
    out->poses.push_back(p);
    L->last_pose_out_t = t;
}

static void set_status(localizer_t *L, int s, outputs_t *out, const char *why)
{
    if (s == L->status) return;
    char c[64];
    snprintf(c, sizeof c, "to_%s", localizer_status_name(s));
    event(out, c, "%s -> %s: %s", localizer_status_name(L->status), localizer_status_name(s), why);
    L->status = s;
}

/* Rebuilds pred from kf and the inputs after it. */
static void rebuild_pred(localizer_t *L)
{
    L->pred = L->kf;
    for (const input_ev_t &e : L->buf)
        if (e.t > L->kf.utime) apply_input(L, &L->pred, e);
}

/* Moves kf forward over inputs older than t_limit (while no sweep commits them). */
static void commit_until(localizer_t *L, int64_t t_limit)
{
    while (!L->buf.empty() && L->buf.front().t <= t_limit) {
        if (L->buf.front().t > L->kf.utime) apply_input(L, &L->kf, L->buf.front());
        L->buf.pop_front();
    }
}

static void maybe_gap_pose(localizer_t *L, int64_t t, outputs_t *out)
{
    if (!L->pred.initialized || L->last_scan_t == 0) return;
    if (t - L->last_scan_t <= L->cfg.lidar_timeout_us) return;
    if (!L->lidar_gap_reported) {
        L->lidar_gap_reported = true;
        event(out, "lidar_gap", "LIDAR_SCAN: none for %.0f ms; POSE from IMU/CAN prediction",
              (t - L->last_scan_t) * 1e-3);
        if (L->status == ST_TRACKING) set_status(L, ST_DEGRADED, out, "no LiDAR");
    }
    if (t - L->last_pose_out_t >= L->cfg.gap_pose_period_us) {
        filter_t f = L->pred;
        if (t > f.utime) filter_predict_cv(&f, t);
        out->poses.push_back(make_pose(L, f, t, false, NAN));
        L->last_pose_out_t = t;
    }
}

static void process_pending(localizer_t *L, outputs_t *out);

void localizer_imu(localizer_t *L, int64_t utime, const Vec3 &accel, const Vec3 &gyro, outputs_t *out)
{
    if (!accel.allFinite() || !gyro.allFinite()) {
        event(out, "imu_nonfinite", "IMU: non-finite sample at %lld dropped", (long long)utime);
        return;
    }
    if (utime <= L->last_imu_t) {
        if (utime == L->last_imu_t) event(out, "imu_duplicate");
        else event(out, "imu_out_of_order", "IMU: sample %lld us older than the last one dropped",
                   (long long)(L->last_imu_t - utime));
        return;
    }
    if (L->last_imu_t != 0 && utime - L->last_imu_t > L->cfg.imu_gap_us)
        event(out, "imu_gap", "IMU: gap of %.0f ms before %lld", (utime - L->last_imu_t) * 1e-3, (long long)utime);
    L->last_imu_t = utime;
    L->last_accel = accel;
    L->last_gyro = gyro;
    input_ev_t e;
    e.t = utime; e.kind = EV_IMU; e.accel = accel; e.gyro = gyro; e.speed = 0;
    L->buf.push_back(e);
    if (!L->kf.initialized) {
        /* keep only a short history before the first pose */
        while (!L->buf.empty() && L->buf.front().t < utime - 1000000) L->buf.pop_front();
        filter_predict_imu(&L->kf, utime, accel, gyro);   /* records the rates */
        if (L->has_pending && utime >= L->pend_t_ref) process_pending(L, out);
        return;
    }
    if (utime - L->kf.utime > 2000000) { commit_until(L, utime - 1000000); rebuild_pred(L); }
    else apply_input(L, &L->pred, e);
    if (L->has_pending && utime >= L->pend_t_ref) process_pending(L, out);
    if (!L->pred.initialized) return;
    out->poses.push_back(make_pose(L, L->pred, utime, true, NAN));
    L->last_pred_out_t = utime;
    maybe_gap_pose(L, utime, out);
}

void localizer_speed(localizer_t *L, int64_t utime, double speed_mps, outputs_t *out)
{
    if (!std::isfinite(speed_mps) || std::fabs(speed_mps) > 100) {
        event(out, "speed_invalid", "VEHICLE_SPEED: %g m/s at %lld dropped", speed_mps, (long long)utime);
        return;
    }
    if (utime <= L->last_speed_t) {
        event(out, utime == L->last_speed_t ? "speed_duplicate" : "speed_out_of_order");
        return;
    }
    L->last_speed_t = utime;
    input_ev_t e;
    e.t = utime; e.kind = EV_SPEED; e.speed = speed_mps; e.accel.setZero(); e.gyro.setZero();
    /* keep the buffer in time order (IMU and CAN interleave within a few ms) */
    auto it = L->buf.end();
    while (it != L->buf.begin() && std::prev(it)->t > utime) --it;
    bool at_end = it == L->buf.end();
    L->buf.insert(it, e);
    if (!L->kf.initialized || utime <= L->kf.utime) return;
    if (at_end) apply_input(L, &L->pred, e);
    else rebuild_pred(L);
    if (!imu_fresh(L, utime)) maybe_gap_pose(L, utime, out);
}

static Eigen::Isometry3d interp(const std::vector<pose_sample_t> &s, int64_t t)
{
    if (t <= s.front().t) return s.front().map_from_imu;
    if (t >= s.back().t) return s.back().map_from_imu;
    size_t lo = 0, hi = s.size() - 1;
    while (hi - lo > 1) {
        size_t mid = (lo + hi) / 2;
        if (s[mid].t <= t) lo = mid; else hi = mid;
    }
    double a = double(t - s[lo].t) / double(s[hi].t - s[lo].t);
    Eigen::Quaterniond q0(s[lo].map_from_imu.rotation()), q1(s[hi].map_from_imu.rotation());
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = q0.slerp(a, q1).toRotationMatrix();
    T.translation() = (1 - a) * s[lo].map_from_imu.translation() + a * s[hi].map_from_imu.translation();
    return T;
}

static Eigen::Isometry3d imu_pose(const filter_t &f)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = f.q.toRotationMatrix();
    T.translation() = f.p;
    return T;
}

/* Predicts kf to t_ref over the buffered inputs, recording poses for deskewing. */
static filter_t predict_to(localizer_t *L, int64_t t_ref)
{
    filter_t f = L->kf;
    L->samples.clear();
    L->samples.push_back({ f.utime, imu_pose(f) });
    for (const input_ev_t &e : L->buf) {
        if (e.t <= f.utime) continue;
        if (e.t > t_ref) break;
        apply_input(L, &f, e);
        if (e.kind == EV_IMU) L->samples.push_back({ f.utime, imu_pose(f) });
    }
    if (t_ref > f.utime) {
        if (imu_fresh(L, t_ref) && L->last_imu_t >= f.utime) filter_predict_imu(&f, t_ref, L->last_accel, L->last_gyro);
        else filter_predict_cv(&f, t_ref);
    }
    L->samples.push_back({ f.utime, imu_pose(f) });
    return f;
}

/* Points of the sweep into base at t_ref, each moved by the motion between its time and t_ref. */
static void deskew_points(localizer_t *L, int64_t utime, const pb_points_t *pts, int64_t t_ref)
{
    L->xyz.resize(size_t(pts->n) * 3);
    const Eigen::Isometry3d imu_from_lidar = L->ex.base_from_imu.inverse() * L->ex.base_from_lidar;
    const Eigen::Isometry3d ref_inv = L->samples.back().map_from_imu.inverse();
    int32_t cur_off = INT32_MIN;
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    size_t k = 0;
    for (int i = 0; i < pts->n; i++) {
        if (pts->offset_us[i] != cur_off) {
            cur_off = pts->offset_us[i];
            T = L->ex.base_from_imu * ref_inv * interp(L->samples, utime + cur_off) * imu_from_lidar;
        }
        Vec3 p = T * Vec3(pts->x[i], pts->y[i], pts->z[i]);
        if (!p.allFinite()) continue;
        L->xyz[k++] = float(p.x());
        L->xyz[k++] = float(p.y());
        L->xyz[k++] = float(p.z());
    }
    L->xyz.resize(k);
}

static Vec3 antenna_map(const localizer_t *L, const Eigen::Isometry3d &map_from_base)
{
    return map_from_base * L->ex.base_from_gnss.translation();
}

static bool fix_fresh(const localizer_t *L, int64_t t)
{
    return L->has_fix && std::llabs(t - L->fix.utime) < 500000;
}

static double gnss_gate(const localizer_t *L, double h_acc)
{
    double g = L->cfg.gnss_gate_k * (std::isfinite(h_acc) ? h_acc : 0.0);
    return g > L->cfg.gnss_gate_min_m ? g : L->cfg.gnss_gate_min_m;
}

/* Distance of a pose's antenna from the latest fix, extrapolated by the pose's velocity. */
static double candidate_gnss_residual(const localizer_t *L, const Eigen::Isometry3d &pose, const Vec3 &vel, int64_t t)
{
    if (!fix_fresh(L, t)) return NAN;
    Vec3 a = antenna_map(L, pose) + vel * ((L->fix.utime - t) * 1e-6);
    return std::hypot(L->fix_map.x() - a.x(), L->fix_map.y() - a.y());
}

/* Structure test (see localizer.h): share of above-ground points on the map's surfaces
 * at pose, or NaN when the sweep has too little structure to judge. */
static double structure_inliers(localizer_t *L, const Eigen::Isometry3d &pose)
{
    L->above.clear();
    size_t n = L->xyz.size() / 3, stride = n > 8000 ? n / 4000 : 1;   /* a sample is enough to judge */
    for (size_t i = 0; i + 2 < L->xyz.size(); i += 3 * stride)
        if (L->xyz[i + 2] > L->cfg.structure_min_z_m) {
            L->above.push_back(L->xyz[i]);
            L->above.push_back(L->xyz[i + 1]);
            L->above.push_back(L->xyz[i + 2]);
        }
    if (L->above.size() / 3 < size_t(L->cfg.structure_min_points)) return NAN;
    pb_reg_config_t c = L->cfg.reg;
    c.max_iterations = 0;   /* evaluate at the pose, do not move it */
    c.coarse_iterations = 0;
    pb_reg_result_t r;
    pb_err_t err;
    if (pb_reg_align(L->map, L->above.data(), L->above.size() / 3, pose, &c, &r, &err) < 0) return NAN;
    if (r.points_used < L->cfg.structure_min_points / 3) return NAN;
    return r.inlier_fraction;
}

static Mat6 floored(const localizer_t *L, const Mat6 &c)
{
    Mat6 m = c;
    if (!m.allFinite()) m = Mat6::Identity() * 1e-2;
    double ft = L->cfg.pose_sigma_floor_m, fr = L->cfg.pose_sigma_floor_rad;
    for (int i = 0; i < 3; i++) m(i, i) += ft * ft;
    for (int i = 3; i < 6; i++) m(i, i) += fr * fr;
    return m;
}

/* Start-up or relocalisation on this sweep: returns true with kf reset at a candidate. */
static bool try_initialize(localizer_t *L, int64_t t_ref, outputs_t *out)
{
    pb_err_t err;
    pb_reg_result_t res;
    Eigen::Isometry3d seed = Eigen::Isometry3d::Identity();
    double radius = 0, yaw_range = 0;
    Vec3 vel = Vec3::Zero();
    const char *how = nullptr;
    Vec3 omega = L->kf.initialized ? L->pred.omega : L->kf.omega;
    if (L->has_hint) {
        seed = L->hint;
        vel = seed.linear() * L->hint_body_vel;
        if (vel.isZero() && fix_fresh(L, t_ref) && L->fix.speed_mps > 0.5) {
            double yaw_enu = M_PI / 2 - L->fix.heading_deg * M_PI / 180;
            double yaw = yaw_enu - L->geo.yaw_deg * M_PI / 180;
            vel = Vec3(std::cos(yaw), std::sin(yaw), 0) * L->fix.speed_mps;
        }
        /* the hint is for its own time; the car moved on since */
        if (L->hint_t != 0 && t_ref > L->hint_t && t_ref - L->hint_t < 2000000)
            seed.translation() += vel * ((t_ref - L->hint_t) * 1e-6);
        L->has_hint = false;
        how = "initial pose";
        int rc = pb_reg_align(L->map, L->xyz.data(), L->xyz.size() / 3, seed, &L->cfg.reg, &res, &err);
        if (rc < 0) { event(out, "init_failed", "initial pose: %s", err.msg); return false; }
    } else if (fix_fresh(L, t_ref) && L->has_geo) {
        const gnss_in_t &fx = L->fix;
        double yaw = 0;
        if (fx.speed_mps > L->cfg.gnss_init_speed_mps && fx.heading_acc_deg < L->cfg.gnss_init_heading_acc_deg) {
            /* course over ground, clockwise from north, to map yaw (CCW from map +x) */
            double yaw_enu = M_PI / 2 - fx.heading_deg * M_PI / 180;
            yaw = pb_wrap_angle(yaw_enu - L->geo.yaw_deg * M_PI / 180);
            yaw_range = std::max(3 * fx.heading_acc_deg * M_PI / 180, 10 * M_PI / 180);
            double c = std::cos(yaw), s = std::sin(yaw);
            vel = Vec3(c, s, 0) * fx.speed_mps;
            how = "GNSS position and course";
        } else {
            if (L->pred.initialized) yaw = std::atan2(L->pred.q.toRotationMatrix()(1, 0), L->pred.q.toRotationMatrix()(0, 0));
            yaw_range = M_PI;
            how = "GNSS position and yaw search";
            if (fx.speed_mps > 0.5) {
                double ye = M_PI / 2 - fx.heading_deg * M_PI / 180 - L->geo.yaw_deg * M_PI / 180;
                vel = Vec3(std::cos(ye), std::sin(ye), 0) * fx.speed_mps;
            }
        }
        seed.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
        Vec3 ant = L->ex.base_from_gnss.translation();
        Vec3 base = L->fix_map + vel * ((t_ref - fx.utime) * 1e-6) - seed.linear() * ant;
        /* height: GNSS altitude is the least accurate axis; the map's ground decides in the match */
        seed.translation() = base;
        radius = std::max(L->cfg.gnss_search_radius_m, 2 * (std::isfinite(fx.h_acc_m) ? fx.h_acc_m : 2.0));
        int rc = pb_reg_align_global(L->map, L->xyz.data(), L->xyz.size() / 3, seed, radius, yaw_range,
                                     L->cfg.search_pos_step_m, L->cfg.search_yaw_step_deg * M_PI / 180,
                                     &L->cfg.reg, &res, &err);
        if (rc < 0) { event(out, "init_failed", "GNSS start: %s", err.msg); return false; }
    } else if (L->status == ST_LOST && L->pred.initialized) {
        /* no GNSS: look around the dead-reckoned pose */
        seed = filter_base_pose(&L->pred);
        vel = filter_base_velocity(&L->pred);
        how = "dead-reckoned pose search";
        int rc = pb_reg_align_global(L->map, L->xyz.data(), L->xyz.size() / 3, seed, 3.0, 20 * M_PI / 180,
                                     L->cfg.search_pos_step_m, L->cfg.search_yaw_step_deg * M_PI / 180,
                                     &L->cfg.reg, &res, &err);
        if (rc < 0) { event(out, "init_failed", "relocalisation: %s", err.msg); return false; }
    } else {
        return false;
    }
    if (res.status == PB_REG_FEW_POINTS || res.inlier_fraction < L->cfg.min_inlier_fraction) {
        event(out, "init_rejected", "%s: best match explains %.0f%% of the sweep (need %.0f%%)", how,
              100 * res.inlier_fraction, 100 * L->cfg.min_inlier_fraction);
        return false;
    }
    double si = structure_inliers(L, res.pose);
    if (std::isfinite(si) && si < L->cfg.min_structure_inliers) {
        event(out, "init_rejected_structure", "%s: only %.0f%% of the structure above the ground fits the map (need %.0f%%)",
              how, 100 * si, 100 * L->cfg.min_structure_inliers);
        if (L->status != ST_LOST && (L->kf.initialized || how[0] == 'i'))
            set_status(L, ST_LOST, out, "pose does not fit the map's structure");
        return false;
    }
    double gr = candidate_gnss_residual(L, res.pose, vel, t_ref);
    if (std::isfinite(gr) && gr > gnss_gate(L, L->fix.h_acc_m)) {
        event(out, "init_rejected_gnss", "%s: candidate is %.1f m from the GNSS fix", how, gr);
        /* a pose we were given (INITIAL_POSE) or had is contradicted: say so, then relocalise from GNSS */
        if (L->status != ST_LOST && (L->kf.initialized || how[0] == 'i'))
            set_status(L, ST_LOST, out, "pose disagrees with GNSS");
        return false;
    }
    Eigen::Isometry3d pose = res.pose;
    if (L->pred.initialized && vel.isZero()) vel = filter_base_velocity(&L->pred);
    /* omega: the rates of the newest IMU sample (or the LiDAR-only estimate) */
    filter_reset(&L->kf, t_ref, pose, vel, omega, 0.3, 2 * M_PI / 180, 1.0);
    while (!L->buf.empty() && L->buf.front().t <= t_ref) L->buf.pop_front();
    rebuild_pred(L);
    L->candidate = true;
    L->verify_count = 1;
    L->reject_count = 0;
    L->gnss_res.clear();
    L->has_prev_pose = false;
    event(out, "init_candidate", "%s: candidate at (%.1f, %.1f) yaw %.1f deg, inliers %.0f%%", how,
          pose.translation().x(), pose.translation().y(),
          std::atan2(pose.linear()(1, 0), pose.linear()(0, 0)) * 180 / M_PI, 100 * res.inlier_fraction);
    return true;
}

void localizer_initial_pose(localizer_t *L, int64_t utime, const Eigen::Isometry3d &T, outputs_t *out)
{
    if (!T.matrix().allFinite()) {
        event(out, "initial_pose_invalid", "INITIAL_POSE: non-finite pose ignored");
        return;
    }
    event(out, "initial_pose", "INITIAL_POSE at (%.1f, %.1f): verifying", T.translation().x(), T.translation().y());
    L->has_hint = true;
    L->hint = T;
    L->hint_t = utime;
    L->hint_body_vel = L->pred.initialized ? Vec3(filter_base_pose(&L->pred).linear().transpose() * filter_base_velocity(&L->pred))
                                           : Vec3::Zero();
    /* the current track (if any) keeps running on prediction until the hint is verified,
     * so a wrong hint can fall back on it */
    L->candidate = false;
    set_status(L, ST_INITIALIZING, out, "INITIAL_POSE received");
}

static void update_lidar_only_motion(localizer_t *L, int64_t t)
{
    Eigen::Isometry3d cur = imu_pose(L->kf);
    if (L->has_prev_pose && t > L->prev_pose_t && !imu_fresh(L, t)) {
        double dt = (t - L->prev_pose_t) * 1e-6;
        if (dt < 0.5) {
            Eigen::Quaterniond dq(L->prev_pose.rotation().transpose() * cur.rotation());
            Eigen::AngleAxisd aa(dq);
            Vec3 w = aa.axis() * aa.angle() / dt;
            L->kf.omega = 0.5 * L->kf.omega + 0.5 * w;
        }
    }
    L->has_prev_pose = true;
    L->prev_pose = cur;
    L->prev_pose_t = t;
}

/* Matches one complete sweep (t_ref: its end) and updates the state machine. */
static void process_scan(localizer_t *L, int64_t utime, int64_t t_ref, const pb_points_t *pts, outputs_t *out)
{
    if (L->kf.initialized && t_ref <= L->kf.utime) {
        event(out, "scan_out_of_order", "LIDAR_SCAN: sweep older than the filter state dropped");
        return;
    }
    bool was_gap = L->lidar_gap_reported;
    L->lidar_gap_reported = false;
    out->has_scan_diag = true;
    scan_diag_t &d = out->scan_diag;
    d = scan_diag_t{ t_ref, L->status, false, false, NAN, NAN, NAN, NAN, NAN, NAN };

    if (pts->n < L->cfg.min_scan_points) {
        event(out, pts->n == 0 ? "scan_empty" : "scan_few_points", "LIDAR_SCAN: %d valid points (need %d); not matched",
              pts->n, L->cfg.min_scan_points);
        if (L->kf.initialized) {
            L->kf = predict_to(L, t_ref);
            while (!L->buf.empty() && L->buf.front().t <= t_ref) L->buf.pop_front();
            rebuild_pred(L);
            if (L->status == ST_TRACKING) set_status(L, ST_DEGRADED, out, "sweep without points");
            out->poses.push_back(make_pose(L, L->kf, t_ref, false, NAN));
            L->last_pose_out_t = t_ref;
        } else {
            emit_unknown_pose(L, t_ref, out);
        }
        d.status = L->status;
        return;
    }

    if (!L->kf.initialized || (L->status == ST_LOST && !L->candidate) || L->has_hint) {
        if (L->kf.initialized) {
            L->kf = predict_to(L, t_ref);   /* dead reckoning goes on while lost */
            while (!L->buf.empty() && L->buf.front().t <= t_ref) L->buf.pop_front();
            rebuild_pred(L);
        } else {
            /* no motion known yet: the sweep is used as measured */
            L->samples.clear();
            L->samples.push_back({ t_ref, Eigen::Isometry3d::Identity() });
        }
        deskew_points(L, utime, pts, t_ref);
        if (try_initialize(L, t_ref, out)) {
            d.matched = true;
            out->poses.push_back(make_pose(L, L->kf, t_ref, false, NAN));
        } else if (L->kf.initialized) {
            out->poses.push_back(make_pose(L, L->kf, t_ref, false, NAN));
        } else {
            emit_unknown_pose(L, t_ref, out);
        }
        L->last_pose_out_t = t_ref;
        d.status = L->status;
        return;
    }

    filter_t prior = predict_to(L, t_ref);
    deskew_points(L, utime, pts, t_ref);
    pb_err_t err;
    pb_reg_result_t res;
    Eigen::Isometry3d guess = filter_base_pose(&prior);
    int rc = pb_reg_align(L->map, L->xyz.data(), L->xyz.size() / 3, guess, &L->cfg.reg, &res, &err);
    bool accept = false;
    const char *why = nullptr;
    char whybuf[1200];
    if (rc < 0) {
        snprintf(whybuf, sizeof whybuf, "registration: %s", err.msg);
        why = whybuf;
        event(out, "match_error", "%s", whybuf);
    } else if (rc == PB_REG_FEW_POINTS) {
        why = "too few points matched the map";
        event(out, "match_few_points", "LIDAR_SCAN: %d of %d points matched the map", res.points_matched, res.points_used);
    } else {
        d.matched = true;
        d.inlier_fraction = res.inlier_fraction;
        d.reg_ms = res.time_ms;
        d.score = res.score;
        Mat6 cov = floored(L, res.covariance);
        Eigen::Matrix<double, 6, 1> r;
        double chi2 = filter_pose_innovation(&prior, res.pose, cov, &r);
        d.innovation_chi2 = chi2;
        double step = r.head<3>().norm();
        if (res.inlier_fraction < L->cfg.min_inlier_fraction) {
            snprintf(whybuf, sizeof whybuf, "match explains %.0f%% of the sweep (need %.0f%%)", 100 * res.inlier_fraction,
                     100 * L->cfg.min_inlier_fraction);
            why = whybuf;
            event(out, "match_low_inliers", "%s", whybuf);
        } else if (chi2 > L->cfg.gate_chi2 && (step > L->cfg.gate_min_m || r.tail<3>().norm() > 2 * M_PI / 180)) {
            snprintf(whybuf, sizeof whybuf, "match %.2f m / %.1f deg from the prediction (chi2 %.0f)", step,
                     r.tail<3>().norm() * 180 / M_PI, chi2);
            why = whybuf;
            event(out, "match_inconsistent", "%s", whybuf);
        } else {
            double si = structure_inliers(L, res.pose);
            d.structure_inliers = si;
            if (std::isfinite(si) && si < L->cfg.min_structure_inliers) {
                snprintf(whybuf, sizeof whybuf, "only %.0f%% of the structure above the ground fits the map (need %.0f%%)",
                         100 * si, 100 * L->cfg.min_structure_inliers);
                why = whybuf;
                event(out, "match_structure_mismatch", "%s", whybuf);
            } else {
                accept = true;
                filter_update_pose(&prior, res.pose, cov);
                if (std::isfinite(si) && si >= L->cfg.structure_trust) {
                    L->last_structure = si;
                    L->last_structure_t = t_ref;
                }
            }
        }
        if (accept && L->candidate) {
            double gr = candidate_gnss_residual(L, filter_base_pose(&prior), filter_base_velocity(&prior), t_ref);
            d.gnss_residual_m = gr;
            if (std::isfinite(gr) && gr > gnss_gate(L, L->fix.h_acc_m)) {
                accept = false;
                snprintf(whybuf, sizeof whybuf, "pose is %.1f m from GNSS (gate %.1f m)", gr, gnss_gate(L, L->fix.h_acc_m));
                why = whybuf;
                event(out, "gnss_disagrees", "%s", whybuf);
                L->candidate = false;
                set_status(L, ST_LOST, out, whybuf);
            }
        }
    }
    L->kf = prior;
    while (!L->buf.empty() && L->buf.front().t <= t_ref) L->buf.pop_front();
    if (accept) {
        update_lidar_only_motion(L, t_ref);
        L->reject_count = 0;
        if (L->candidate) {
            if (++L->verify_count >= L->cfg.verify_scans) {
                L->candidate = false;
                set_status(L, ST_TRACKING, out, "pose verified");
            }
        } else if (L->status != ST_TRACKING && L->status != ST_LOST) {
            set_status(L, ST_TRACKING, out, was_gap ? "LiDAR back" : "match accepted");
        }
    } else {
        ++L->reject_count;
        if (L->candidate) {
            /* a candidate that fails is dropped: search again on the next sweep */
            L->candidate = false;
            if (L->status == ST_INITIALIZING) { L->kf.initialized = false; L->pred.initialized = false; }
            event(out, "candidate_dropped", "candidate pose dropped: %s", why ? why : "?");
        } else if (L->status == ST_LOST) {
            /* stays lost; relocalisation runs on the next sweep */
        } else if (L->reject_count >= L->cfg.rejects_to_lost) {
            set_status(L, ST_LOST, out, why ? why : "matches rejected");
        } else if (L->status == ST_TRACKING) {
            set_status(L, ST_DEGRADED, out, why ? why : "match rejected");
        }
    }
    d.accepted = accept;
    rebuild_pred(L);
    if (L->kf.initialized) {
        out->poses.push_back(make_pose(L, L->kf, t_ref, false, d.matched ? res.score : NAN));
    } else {
        emit_unknown_pose(L, t_ref, out);
    }
    L->last_pose_out_t = t_ref;
    d.status = L->status;
}

static void process_pending(localizer_t *L, outputs_t *out)
{
    if (!L->has_pending) return;
    L->has_pending = false;
    pb_points_t v = {};
    v.n = v.cap = int(L->pend_off.size());
    v.x = L->pend_x.data(); v.y = L->pend_y.data(); v.z = L->pend_z.data();
    v.offset_us = L->pend_off.data();
    process_scan(L, L->pend_utime, L->pend_t_ref, &v, out);
}

void localizer_scan(localizer_t *L, int64_t utime, const pb_points_t *pts, outputs_t *out)
{
    int32_t max_off = 0;
    for (int i = 0; i < pts->n; i++) if (pts->offset_us[i] > max_off) max_off = pts->offset_us[i];
    int64_t t_ref = utime + max_off;
    if (max_off > 1000000) {
        event(out, "scan_invalid", "LIDAR_SCAN: point times span %.1f s (more than a sweep); dropped", max_off * 1e-6);
        return;
    }
    if (L->last_scan_t != 0 && t_ref <= L->last_scan_t) {
        if (t_ref == L->last_scan_t) event(out, "scan_duplicate", "LIDAR_SCAN: sweep at %lld repeated, dropped", (long long)utime);
        else event(out, "scan_out_of_order", "LIDAR_SCAN: sweep %.0f ms older than the last one dropped",
                   (L->last_scan_t - t_ref) * 1e-3);
        return;
    }
    L->last_scan_t = t_ref;
    process_pending(L, out);
    /* A sweep published before its last point was measured (simdrive stamps the log
     * event at the sweep start) waits for the IMU to cover it, so that deskewing and
     * the prediction use measured motion, not an extrapolation. */
    if (L->last_imu_t != 0 && L->last_imu_t < t_ref && utime - L->last_imu_t < L->cfg.imu_timeout_us) {
        L->has_pending = true;
        L->pend_utime = utime;
        L->pend_t_ref = t_ref;
        L->pend_x.assign(pts->x, pts->x + pts->n);
        L->pend_y.assign(pts->y, pts->y + pts->n);
        L->pend_z.assign(pts->z, pts->z + pts->n);
        L->pend_off.assign(pts->offset_us, pts->offset_us + pts->n);
        return;
    }
    process_scan(L, utime, t_ref, pts, out);
}

void localizer_gnss(localizer_t *L, const gnss_in_t &fx, outputs_t *out)
{
    if (!L->has_geo) return;
    if (fx.fix_type < 2 || !std::isfinite(fx.lat_deg) || !std::isfinite(fx.lon_deg) || !std::isfinite(fx.alt_m)) {
        event(out, "gnss_no_fix");
        return;
    }
    if (L->has_fix && fx.utime <= L->fix.utime) {
        event(out, fx.utime == L->fix.utime ? "gnss_duplicate" : "gnss_out_of_order");
        return;
    }
    double xyz[3];
    pb_geo_wgs84_to_map(&L->geo, fx.lat_deg, fx.lon_deg, fx.alt_m, xyz);
    L->fix = fx;
    L->fix_map = Vec3(xyz[0], xyz[1], xyz[2]);
    L->has_fix = true;
    if (!L->pred.initialized || L->candidate || (L->status != ST_TRACKING && L->status != ST_DEGRADED)) return;
    /* divergence test: the pose's antenna against a window of fixes */
    Eigen::Isometry3d pose = filter_base_pose(&L->pred);
    Vec3 a = antenna_map(L, pose) + filter_base_velocity(&L->pred) * ((fx.utime - L->pred.utime) * 1e-6);
    L->gnss_res.push_back({ fx.utime, Eigen::Vector2d(xyz[0] - a.x(), xyz[1] - a.y()), fx.h_acc_m });
    while (!L->gnss_res.empty() && L->gnss_res.front().t < fx.utime - L->cfg.gnss_window_us) L->gnss_res.pop_front();
    if (L->gnss_res.size() < 3) return;
    Eigen::Vector2d m = Eigen::Vector2d::Zero();
    double hacc = 0;
    for (const gnss_res_t &g : L->gnss_res) { m += g.r; hacc += std::isfinite(g.h_acc) ? g.h_acc : 0; }
    m /= double(L->gnss_res.size());
    hacc /= double(L->gnss_res.size());
    double gate = gnss_gate(L, hacc);
    if (m.norm() > gate && L->status == ST_TRACKING && L->last_structure_t != 0 &&
        fx.utime - L->last_structure_t < 1000000) {
        event(out, "gnss_outlier", "GNSS_FIX: %.1f m from the pose over %zu fixes while the map fits (%.0f%% of the "
              "structure); GNSS not trusted", m.norm(), L->gnss_res.size(), 100 * L->last_structure);
        L->gnss_res.clear();
        return;
    }
    if (m.norm() > gate) {
        char why[160];
        snprintf(why, sizeof why, "pose is %.1f m from GNSS over %zu fixes (gate %.1f m)", m.norm(), L->gnss_res.size(), gate);
        event(out, "gnss_disagrees", "%s", why);
        set_status(L, ST_LOST, out, why);
        L->gnss_res.clear();
    }
}

void localizer_finish(localizer_t *L, outputs_t *out) { process_pending(L, out); }

void localizer_tick(localizer_t *L, int64_t now, outputs_t *out)
{
    /* the IMU stopped before the sweep's end: match it with what there is */
    if (L->has_pending && now > L->pend_t_ref && now - L->last_imu_t > L->cfg.imu_timeout_us) process_pending(L, out);
    if (!L->pred.initialized || imu_fresh(L, now) || now <= L->pred.utime) return;
    if (now - L->last_pred_out_t < L->cfg.predict_period_us) return;
    filter_t f = L->pred;
    if (now > f.utime) filter_predict_cv(&f, now);
    out->poses.push_back(make_pose(L, f, now, true, NAN));
    L->last_pred_out_t = now;
    maybe_gap_pose(L, now, out);
}

} // namespace loc
