/* The localizer pipeline (see localizer.h). */
#include "localizer_impl.h"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <deque>

namespace pb_loc {

void event(outputs_t *out, const char *counter, const char *fmt, ...)
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
    pb_clock_offset_init(&L->gnss_clock, cfg.gnss_clock_tol_us);
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

void localizer_set_pager(localizer_t *L, localizer_pager_fn pager, void *user)
{
    L->pager = pager;
    L->pager_user = user;
}

void localizer_set_places(localizer_t *L, places_t *places)
{
    places_destroy(L->places);
    L->places = places;
    L->places_failed = false;
}

void localizer_destroy(localizer_t *L)
{
    if (L) places_destroy(L->places);
    delete L;
}

/* Starts afresh (a clock step or a log gap): everything known about motion and time is
 * dropped; the last pose becomes a prior for the next sweep when the car cannot have
 * moved far (a clock step, not a gap). */
static void restart(localizer_t *L, bool keep_pose, outputs_t *out, const char *why)
{
    bool had = L->pred.initialized && keep_pose;
    Eigen::Isometry3d last = had ? filter_base_pose(&L->pred) : Eigen::Isometry3d::Identity();
    localizer_config_t cfg = L->cfg;
    cfg.has_initial_pose = false;
    extrinsics_t ex = L->ex;
    const pb_regmap_t *map = L->map;
    bool has_geo = L->has_geo;
    pb_georef_t geo = L->geo;
    int status = L->status;
    places_t *places = L->places;
    localizer_pager_fn pager = L->pager;
    void *pager_user = L->pager_user;
    *L = localizer();
    L->places = places;
    L->pager = pager;
    L->pager_user = pager_user;
    L->cfg = cfg; L->ex = ex; L->map = map; L->has_geo = has_geo; L->geo = geo;
    pb_clock_offset_init(&L->gnss_clock, cfg.gnss_clock_tol_us);
    filter_create(&L->kf, cfg.filter, ex.base_from_imu);
    L->pred = L->kf;
    L->status = status;
    if (had) { L->has_hint = true; L->hint = last; L->hint_t = 0; }
    set_status(L, ST_INITIALIZING, out, why);
}

/* The sensors' clock stepped back by `step` (an NTP or GNSS time sync on the car) while
 * the car went on moving: every time the core holds moves back with it, so the state is
 * continuous in the new clock. No search and no restart: POSE_PREDICTED goes on at its
 * rate, and the next sweep is matched against the prediction as after a LiDAR gap
 * (degraded until a match is accepted). GNSS keeps its own clock: its offset to the
 * sensors is measured afresh. */
static void rebase_clock(localizer_t *L, int64_t step, outputs_t *out, const char *why)
{
    auto back = [step](int64_t &t) { if (t != 0) t -= step; };
    back(L->kf.utime); back(L->pred.utime);
    for (input_ev_t &e : L->buf) e.t -= step;
    back(L->newest_t); back(L->last_imu_t); back(L->last_speed_t); back(L->last_scan_t);
    back(L->last_pose_out_t); back(L->last_pred_out_t); back(L->pend_utime); back(L->pend_t_ref);
    back(L->cand_t); back(L->hint_t); back(L->last_match_t); back(L->prev_pose_t); back(L->last_structure_t);
    back(L->verified_t); back(L->held_t);
    L->gnss_res.clear();
    pb_clock_offset_forget(&L->gnss_clock);
    L->has_fix = false;
    if (L->status == ST_TRACKING) set_status(L, ST_DEGRADED, out, why);
}

/* A time far behind the newest input (the clock stepped back) or far after it (a gap in
 * the log): carry the state over to the new clock, or start again, rather than drop
 * everything as out of order or dead-reckon across. `expected` is the time this input
 * would have had without a step (its channel's last time plus its last interval). */
static void check_clock(localizer_t *L, int64_t t, int64_t expected, const char *channel, outputs_t *out)
{
    /* one stray old message is out of order, not a clock step: the step is taken when
     * cfg.time_jump_inputs successive inputs agree on the earlier time */
    bool behind = L->newest_t != 0 && L->newest_t - t > L->cfg.time_jump_us;
    if (!behind) {
        L->jump_count = 0;
    } else if (L->jump_count == 0 || std::llabs(t - L->jump_last_t) > L->cfg.time_jump_us) {
        L->jump_count = 1;
        L->jump_last_t = t;
        L->jump_step = (expected != 0 ? expected : L->newest_t) - t;
    } else {
        L->jump_count++;
        L->jump_last_t = std::max(L->jump_last_t, t);
    }
    if (behind && L->jump_count >= L->cfg.time_jump_inputs) {
        L->jump_count = 0;
        char why[160];
        if (L->pred.initialized && (L->status == ST_TRACKING || L->status == ST_DEGRADED)) {
            snprintf(why, sizeof why, "%s: time stepped back %.3f s; the pose carries over to the new clock", channel,
                     L->jump_step * 1e-6);
            event(out, "time_jump", "%s", why);
            rebase_clock(L, L->jump_step, out, why);
        } else {
            snprintf(why, sizeof why, "%s: time stepped back %.1f s; starting again from the last pose", channel,
                     (L->newest_t - t) * 1e-6);
            event(out, "time_jump", "%s", why);
            restart(L, true, out, why);
        }
    } else if (L->newest_t != 0 && t - L->newest_t > L->cfg.reinit_gap_us) {
        char why[160];
        snprintf(why, sizeof why, "%s: no input for %.1f s; starting again", channel, (t - L->newest_t) * 1e-6);
        event(out, "log_gap", "%s", why);
        restart(L, false, out, why);
    }
    if (t > L->newest_t) L->newest_t = t;
}

bool imu_fresh(const localizer_t *L, int64_t t)
{
    return L->last_imu_t != 0 && t - L->last_imu_t <= L->cfg.imu_timeout_us && t >= L->last_imu_t - 1000000;
}

double newest_speed(const localizer_t *L, int64_t t)
{
    for (auto it = L->buf.rbegin(); it != L->buf.rend(); ++it)
        if (it->kind == EV_SPEED) return std::llabs(t - it->t) <= L->cfg.speed_timeout_us ? it->speed : NAN;
    return NAN;
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
            /* many cars report the speed's magnitude only (Toyota wheel speeds): when the
             * scan matches clearly move backwards, so does the car */
            double v = !L->speed_signed && e.speed >= 0 && L->match_fwd_mps < -L->cfg.reverse_detect_mps ? -e.speed
                                                                                                   : e.speed;
            filter_update_speed(f, v);
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
    const double b2 = L->cfg.pose_bias_sigma_m * L->cfg.pose_bias_sigma_m;
    p.covariance(0, 0) += b2;
    p.covariance(1, 1) += b2;
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
    /* no estimate: a covariance that says so (never a certain identity) */
    p.covariance.setZero();
    p.covariance.diagonal() << UNKNOWN_POS_VAR, UNKNOWN_POS_VAR, UNKNOWN_POS_VAR, UNKNOWN_ROT_VAR, UNKNOWN_ROT_VAR,
        UNKNOWN_ROT_VAR;
    p.status = L->status;
    p.source = SRC_LOCALIZER;
    p.match_score = NAN;
    out->poses.push_back(p);
    L->last_pose_out_t = t;
}

void set_status(localizer_t *L, int s, outputs_t *out, const char *why)
{
    if (s == L->status) return;
    char c[64];
    snprintf(c, sizeof c, "to_%s", localizer_status_name(s));
    event(out, c, "%s -> %s: %s", localizer_status_name(L->status), localizer_status_name(s), why);
    L->status = s;
}

/* Rebuilds pred from kf and the inputs after it. */
void rebuild_pred(localizer_t *L)
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
    /* dead reckoning is no pose for long: lost by time, relocalised when the scans return */
    if (t - L->last_scan_t > L->cfg.lidar_lost_us && L->status != ST_LOST) {
        char why[96];
        snprintf(why, sizeof why, "no LiDAR for %.1f s (limit %.1f s)", (t - L->last_scan_t) * 1e-6,
                 L->cfg.lidar_lost_us * 1e-6);
        event(out, "lidar_outage", "LIDAR_SCAN: %s", why);
        L->candidate = false;
        set_status(L, ST_LOST, out, why);
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
    check_clock(L, utime, L->last_imu_t + L->imu_dt, "IMU", out);
    if (utime <= L->last_imu_t) {
        if (utime == L->last_imu_t) event(out, "imu_duplicate");
        else event(out, "imu_out_of_order", "IMU: sample %lld us older than the last one dropped",
                   (long long)(L->last_imu_t - utime));
        return;
    }
    if (L->last_imu_t != 0 && utime - L->last_imu_t > L->cfg.imu_gap_us)
        event(out, "imu_gap", "IMU: gap of %.0f ms before %lld", (utime - L->last_imu_t) * 1e-3, (long long)utime);
    L->imu_dt = L->last_imu_t != 0 ? utime - L->last_imu_t : 0;
    L->last_imu_t = utime;
    if (L->pred.initialized && L->stood && L->imu_dt > 0 && L->imu_dt < L->cfg.imu_gap_us) {
        /* the direction of a departure: the IMU's forward acceleration (gravity and bias
         * taken out with the filter's attitude) integrated since the car last stood (only
         * then: on a start while moving it would be the change of speed, and braking
         * would read as reversing) */
        const Eigen::Matrix3d R = L->pred.q.toRotationMatrix();
        Vec3 a = R * (accel - L->pred.ba) - Vec3(0, 0, L->cfg.filter.gravity);
        Vec3 fwd = R * (L->ex.base_from_imu.linear().transpose() * Vec3::UnitX());
        L->depart_v += a.dot(fwd) * (L->imu_dt * 1e-6);
        if (L->depart_dir == 0 && std::fabs(L->depart_v) > L->cfg.depart_detect_mps) L->depart_dir = L->depart_v > 0 ? 1 : -1;
    }
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
    check_clock(L, utime, L->last_speed_t + L->speed_dt, "VEHICLE_SPEED", out);
    if (utime <= L->last_speed_t) {
        event(out, utime == L->last_speed_t ? "speed_duplicate" : "speed_out_of_order");
        return;
    }
    L->speed_dt = L->last_speed_t != 0 ? utime - L->last_speed_t : 0;
    L->last_speed_t = utime;
    /* an unsigned speed takes the direction the IMU saw at the departure */
    if (speed_mps < 0) L->speed_signed = true;
    if (std::fabs(speed_mps) < L->cfg.standstill_mps) { L->depart_v = 0; L->depart_dir = 0; L->stood = true; }
    if (!L->speed_signed && L->depart_dir < 0) speed_mps = -speed_mps;
    input_ev_t e;
    e.t = utime; e.kind = EV_SPEED; e.speed = speed_mps; e.accel.setZero(); e.gyro.setZero();
    /* keep the buffer in time order (IMU and CAN interleave within a few ms) */
    auto it = L->buf.end();
    while (it != L->buf.begin() && std::prev(it)->t > utime) --it;
    bool at_end = it == L->buf.end();
    L->buf.insert(it, e);
    if (!L->kf.initialized) {
        while (!L->buf.empty() && L->buf.front().t < utime - 1000000) L->buf.pop_front();
        return;
    }
    if (utime <= L->kf.utime) return;
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

Eigen::Isometry3d imu_pose(const filter_t &f)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = f.q.toRotationMatrix();
    T.translation() = f.p;
    return T;
}

/* Neither a fresh IMU nor a recent CAN speed: motion comes from the matches alone. */
static bool lidar_alone(const localizer_t *L, int64_t t)
{
    return !imu_fresh(L, t) && (L->last_speed_t == 0 || t - L->last_speed_t > L->cfg.speed_timeout_us);
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


/* A run of sweeps whose matches agree with the motion but fit too little of the map's
 * structure: a wrong pose, or a scene that changed since the map (parked cars that came or
 * went where little else stands: the right pose fits 10-27 %, its neighbours 6-19 %). A
 * wrong pose has a place near it that fits better (a pose slid along the road, a kidnap);
 * a changed scene does not. Searched when the run would make the pose LOST, and again every
 * hold_recheck_us while it lasts; never held longer than lidar_lost_us after the last
 * verified sweep. True: the pose is held (its matches update the filter). */
static bool scene_changed(localizer_t *L, const Eigen::Isometry3d &pose, double si, int64_t t, outputs_t *out)
{
    if (L->verified_t == 0 || t - L->verified_t > L->cfg.lidar_lost_us) return false;
    if (L->held_t != 0 && t - L->held_t < L->cfg.hold_recheck_us) {
        event(out, "match_structure_held");
        return true;
    }
    if (L->held_t == 0 && (L->reject_count + 1 < L->cfg.rejects_to_lost || L->structure_run + 1 < L->cfg.rejects_to_lost))
        return false;
    pb_reg_result_t r;
    double fit;
    const double radius = L->cfg.hold_search_m;
    bool found = search_seeds(L, { pose }, radius, L->cfg.hold_search_yaw_deg * M_PI / 180, false, &r, &fit, nullptr);
    double away = found ? (r.pose.translation() - pose.translation()).head<2>().norm() : 0;
    if (found && (fit >= L->cfg.min_structure_inliers ||
                  (fit >= L->cfg.structure_peak_floor && fit >= L->cfg.structure_peak_ratio * si))) {
        event(out, "match_structure_elsewhere", "%.0f%% of the structure fits %.1f m from the pose, %.0f%% at it: the pose "
              "is wrong", 100 * fit, away, 100 * si);
        L->held_t = 0;
        L->reject_count = std::max(L->reject_count, L->cfg.rejects_to_lost - 1);   /* LOST with this sweep */
        return false;
    }
    L->held_t = t;
    char why[300];
    snprintf(why, sizeof why, "only %.0f%% of the structure above the ground fits the map, and no place within %.0f m fits "
             "better (best %.0f%%): the scene changed since the map, the pose is held", 100 * si, radius,
             100 * std::max(fit, 0.0));
    event(out, "match_structure_held", "%s", why);
    if (L->status == ST_TRACKING) set_status(L, ST_DEGRADED, out, why);
    return true;
}

static void update_lidar_only_motion(localizer_t *L, int64_t t)
{
    /* the forward speed between successive accepted matches: the direction of travel that
     * an unsigned CAN speed lacks */
    Eigen::Isometry3d base = filter_base_pose(&L->kf);
    if (L->last_match_t != 0 && t > L->last_match_t && t - L->last_match_t < 500000)
        L->match_fwd_mps = (base.linear().transpose() * (base.translation() - L->last_match_pose.translation())).x() /
                           ((t - L->last_match_t) * 1e-6);
    L->last_match_pose = base;
    L->last_match_t = t;
    /* the speed sweeps are deskewed with: smoothed over the first sweeps after a start,
     * when the filter's speed is still metres per second off (see deskew_smooth) */
    Vec3 vb = filter_body_velocity(&L->kf);
    if (!L->deskew_vel_ok) L->deskew_vel_n = 0;
    double a = L->deskew_vel_n < L->cfg.deskew_smooth_sweeps ? L->cfg.deskew_smooth : 0.0;
    L->deskew_vel = L->deskew_vel_ok ? Vec3(a * L->deskew_vel + (1 - a) * vb) : vb;
    L->deskew_vel_ok = true;
    L->deskew_vel_n++;
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

/* The second match of a candidate whose speed was unknown: velocity and turn rate from the
 * two matched poses, the filter restarted at the second. */
static void restart_from_two_matches(localizer_t *L, filter_t *f, const Eigen::Isometry3d &pose, int64_t t)
{
    double dt = (t - L->cand_t) * 1e-6;
    Vec3 v = (pose.translation() - L->cand_pose.translation()) / dt;
    Vec3 omega = f->omega;
    if (!imu_fresh(L, t)) {
        Eigen::AngleAxisd aa(L->cand_pose.linear().transpose() * pose.linear());
        omega = L->ex.base_from_imu.linear().transpose() * (aa.axis() * aa.angle() / dt);
        /* the chord of a constant turn: the velocity at its end is turned by half the turn
         * further, and the arc is longer than the chord by (a/2)/sin(a/2) */
        double half = 0.5 * aa.angle();
        if (half > 1e-6 && half < M_PI / 2)
            v = Eigen::AngleAxisd(half, L->cand_pose.linear() * aa.axis()) * v * (half / std::sin(half));
    }
    /* the speed is the difference of two matches (each good to a few cm): the mean over
     * their interval, so the speed now differs from it by what the car's acceleration
     * changed in half that interval (keyframes seconds apart: metres per second) */
    filter_reset(f, t, pose, v, omega, 0.1, 1 * M_PI / 180, std::max({ 0.1, 0.1 / dt, f->cfg.cv_accel_noise * dt / 2 }));
    L->deskew_vel_ok = false;
    L->cand_vel_unknown = false;
}

/* The prediction's horizontal position standard deviation (base), metres. */
static double prediction_sigma_m(const filter_t &prior)
{
    Mat6 P = filter_base_covariance(&prior);
    return std::sqrt(std::max(P(0, 0), P(1, 1)));
}

/* A match whose structure does not fit the map while tracking, or while verifying a
 * candidate whose motion was unknown at its start (LiDAR alone: its speed comes from two
 * matches), and any verifying sweep whose prediction is unsure by a metre: the
 * prediction may be off by more than one registration pulls in (a turn between sparse
 * sweeps). Searched again around it, as far as its covariance says;
 * true with the result when that fits and agrees with the prediction (the motion gate). */
static bool research(localizer_t *L, const filter_t &prior, const Eigen::Isometry3d &guess, pb_reg_result_t *res,
                     double *si)
{
    Mat6 P = filter_base_covariance(&prior);
    double radius = std::min(3 * prediction_sigma_m(prior), 4.0);
    double yaw = std::min(3 * std::sqrt(P(5, 5)), 20 * M_PI / 180);
    if (radius < 1.0 && yaw < 5 * M_PI / 180) return false;   /* a sure prediction: one registration pulls it in */
    pb_reg_result_t r;
    double fit;
    if (!search_seeds(L, { guess }, std::max(radius, 1.0), std::max(yaw, 5 * M_PI / 180), false,
                      &r, &fit, nullptr) ||
        fit < L->cfg.min_structure_inliers)
        return false;
    Eigen::Matrix<double, 6, 1> d;
    double chi2 = filter_pose_innovation(&prior, r.pose, floored(L, r.covariance), &d);
    if (chi2 > L->cfg.gate_chi2 && (d.head<3>().norm() > L->cfg.gate_min_m || d.tail<3>().norm() > 2 * M_PI / 180))
        return false;
    *res = r;
    *si = fit;
    return true;
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
    d = scan_diag_t{ t_ref, L->status, false, false, NAN, NAN, NAN, NAN, NAN };

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
        L->init_inliers = L->init_structure = NAN;
        bool found = try_initialize(L, t_ref, out);
        d.inlier_fraction = L->init_inliers;
        d.structure_inliers = L->init_structure;
        if (found) {
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
    /* the speed (base) the sweep is deskewed with, for the verification below */
    Vec3 swept = filter_body_velocity(&prior);
    if (L->deskew_vel_ok && L->deskew_vel_n < L->cfg.deskew_smooth_sweeps && lidar_alone(L, t_ref)) {
        swept = L->deskew_vel;
        /* the sweep's motion at the smoothed speed (the prior keeps the filter's) */
        filter_t kept = L->kf;
        Eigen::Isometry3d b = filter_base_pose(&L->kf);
        L->kf.v += b.linear() * L->deskew_vel - filter_base_velocity(&L->kf);
        predict_to(L, t_ref);
        L->kf = kept;
    }
    deskew_points(L, utime, pts, t_ref);
    pb_err_t err;
    pb_reg_result_t res;
    Eigen::Isometry3d guess = filter_base_pose(&prior);
    /* a candidate whose speed is not known yet (no CAN, GNSS or earlier track: a moving
     * start from a prior or a search): the car may have moved as far along its axis as a
     * car can since (sweeps may be sparse: skipped while searching, or keyframes), either
     * way (reversing, or a LiDAR mounted facing backwards) */
    bool free_motion = L->candidate && L->cand_vel_unknown;
    double along_fit = -1, along_rival = -1;   /* the match's structure fit and a far place's as good (sparse sweeps) */
    double reach = free_motion ? motion_reach_m(L, (t_ref - L->cand_t) * 1e-6) : 0;
    bool degenerate = false;   /* the match is not used along `weak` ... */
    bool detected = false;     /* ... because this sweep does not fix it (else: one did lately) */
    Vec3 weak = Vec3::Zero();
    int rc;
    if (reach > 1.0) {
        double step;
        std::vector<Eigen::Isometry3d> seeds = motion_seeds(L, guess, (t_ref - L->cand_t) * 1e-6, &step);
        double fit, rival;
        rc = search_seeds(L, seeds, std::max(1.5, 0.75 * step), 5 * M_PI / 180, false, &res, &fit, &rival)
                 ? res.status : PB_REG_FEW_POINTS;
        if (rc == PB_REG_FEW_POINTS) { res.points_matched = 0; res.points_used = int(L->xyz.size() / 3); }
        /* sparse sweeps reach tens of metres along a road: a place that another one as far
         * along fits about as well does not say how far the car went (MulRan keyframes: a
         * right place, then one 34 m along a straight road 2.6 s later) */
        else if (ambiguous(L, fit, rival)) { along_fit = fit; along_rival = rival; }
    } else {
        pb_reg_config_t reg = L->cfg.reg;
        reg.prior_sigma_m = prediction_sigma_m(prior);
        /* LiDAR alone the prediction is the last matches' motion: the match is held near it
         * where the sweep hardly fixes the pose (a street of porous crowns: a match that
         * wandered 0.2 m along the road became a speed error and the next prediction worse).
         * With IMU or CAN the filter's own fusion does that, and a prior here would count
         * the prediction twice (porous street, IMU + CAN: p99 0.049 -> 0.060 m) */
        if (lidar_alone(L, t_ref))
            rc = pb_reg_align_prior(L->map, L->xyz.data(), L->xyz.size() / 3, guess, filter_base_covariance(&prior), &reg,
                                    &res, &err);
        else
            rc = pb_reg_align(L->map, L->xyz.data(), L->xyz.size() / 3, guess, &reg, &res, &err);
        /* a tunnel or a road between long walls: the match is not used along it (the motion
         * carries the position there, and its uncertainty grows) */
        if (rc >= 0 && rc != PB_REG_FEW_POINTS && match_degenerate(L, res, &weak)) {
            detected = true;
            event(out, "match_degenerate", "the sweep does not fix the position along %.0f deg (walls longer than the "
                  "LiDAR reaches: a tunnel, a bridge, a cutting): the motion carries it there",
                  std::atan2(weak.y(), weak.x()) * 180 / M_PI);
            if (++L->weak_run >= L->cfg.degenerate_enter_sweeps) {
                L->weak_dir = weak;
                L->weak_clear = 0;
            }
        } else if (rc >= 0) {
            L->weak_run = 0;
        }
        if (rc >= 0 && L->weak_dir.squaredNorm() > 0) {
            degenerate = true;
            weak = L->weak_dir;
        }
        if (degenerate) {
            const double s2 = L->cfg.degenerate_sigma_m * L->cfg.degenerate_sigma_m;
            res.covariance.topLeftCorner<3, 3>() += weak * weak.transpose() * s2;
        }
    }
    bool accept = false;
    double structure_miss = NAN;   /* the structure fit of a match that failed only that test ... */
    Mat6 miss_cov = Mat6::Identity();   /* ... and that match's covariance */
    const char *why = nullptr;
    char whybuf[1200];
    if (rc < 0) {
        snprintf(whybuf, sizeof whybuf, "registration: %s", err.msg);
        why = whybuf;
        event(out, "match_error", "%s", whybuf);
    } else if (rc == PB_REG_FEW_POINTS) {
        why = "too few points matched the map";
        event(out, "match_few_points", "LIDAR_SCAN: %d of %d points matched the map", res.points_matched, res.points_used);
    } else if (along_rival >= 0) {
        snprintf(whybuf, sizeof whybuf, "how far the car went is not known: a place more than %.0f m from the match "
                 "fits %.0f%% of the structure, the match %.0f%%", L->cfg.rival_m, 100 * along_rival, 100 * along_fit);
        why = whybuf;
        event(out, "match_ambiguous", "%s", whybuf);
    } else {
        /* a candidate's verifying sweep whose prediction is less sure than one
         * registration pulls in (sweeps seconds apart): the match is the best fit within
         * the prediction's spread, not the minimum nearest to it (MulRan keyframes: 1.6 m
         * along a road that hardly fixes the pose along it, or no fit after a turn) */
        pb_reg_result_t r2;
        double si2;
        bool searched = L->candidate && !free_motion && 3 * prediction_sigma_m(prior) >= 1.0;
        if (searched && research(L, prior, guess, &r2, &si2)) {
            double si1 = res.inlier_fraction >= L->cfg.min_inlier_fraction ? structure_inliers(L, res.pose) : -1;
            if (si2 > (std::isfinite(si1) ? si1 : -1)) {
                res = r2;
                event(out, "match_researched", "candidate's match: a better fit found around the prediction");
            }
        }
        d.matched = true;
        d.inlier_fraction = res.inlier_fraction;
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
        } else if (!free_motion && chi2 > L->cfg.gate_chi2 &&
                   (step > L->cfg.gate_min_m || r.tail<3>().norm() > 2 * M_PI / 180)) {
            snprintf(whybuf, sizeof whybuf, "match %.2f m / %.1f deg from the prediction (chi2 %.0f)", step,
                     r.tail<3>().norm() * 180 / M_PI, chi2);
            why = whybuf;
            event(out, "match_inconsistent", "%s", whybuf);
        } else {
            double si = structure_inliers(L, res.pose);
            /* a place from the global search is verified only by sweeps whose structure can
             * be judged: the ground alone fits anywhere */
            bool unjudged = L->candidate && L->cand_global && !std::isfinite(si);
            bool fits = !unjudged && structure_fits(L, res.pose, si, out);
            /* a place from the global search is verified by sweeps that fit where its
             * motion puts them: searched for around there, a street whose trees repeat
             * fits at a wrong place too (seen 192 m off on the porous street). Only
             * sweeps a second or more apart (keyframes) leave the motion that unsure. */
            /* (not again when it was searched around the prediction above: the same search) */
            bool may_research = !searched &&
                                (!L->candidate || (L->cand_no_speed && (!L->cand_global || L->scan_dt >= 1000000)));
            if (!fits && !free_motion && may_research && research(L, prior, guess, &res, &si)) {
                fits = true;   /* research() takes only a pose that fits outright */
                cov = floored(L, res.covariance);
                d.inlier_fraction = res.inlier_fraction;
                d.score = res.score;
                event(out, "match_researched", "match off the map's structure: found again around the prediction");
            }
            d.structure_inliers = si;
            if (unjudged && !fits) {
                why = "too little structure above the ground to verify a place found without a prior";
                event(out, "match_structure_unjudged", "%s", why);
            } else if (!fits) {
                snprintf(whybuf, sizeof whybuf, "only %.0f%% of the structure above the ground fits the map (need %.0f%%)",
                         100 * si, 100 * L->cfg.min_structure_inliers);
                why = whybuf;
                structure_miss = si;
                miss_cov = cov;
                event(out, "match_structure_mismatch", "%s", whybuf);
            } else {
                accept = true;
                if (free_motion) restart_from_two_matches(L, &prior, res.pose, t_ref);
                else if (degenerate) filter_update_pose_except(&prior, res.pose, cov, weak);
                else filter_update_pose(&prior, res.pose, cov);
                if (!detected && L->weak_dir.squaredNorm() > 0 && ++L->weak_clear >= L->cfg.degenerate_clear_sweeps)
                    L->weak_dir.setZero();
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
    /* a tracked pose whose matches fit too little of the structure: held when no place
     * near fits better (the scene changed, not the pose) */
    bool held = std::isfinite(structure_miss) && !L->candidate &&
                (L->status == ST_TRACKING || L->status == ST_DEGRADED) && scene_changed(L, res.pose, structure_miss, t_ref, out);
    if (held) {
        filter_update_pose(&L->kf, res.pose, miss_cov);
        update_lidar_only_motion(L, t_ref);
        L->reject_count = 0;
        L->structure_run = 0;
    } else if (accept) {
        update_lidar_only_motion(L, t_ref);
        L->reject_count = 0;
        L->held_t = 0;
        L->verified_t = t_ref;
        L->structure_run = 0;
        if (L->candidate) {
            double dv = (filter_body_velocity(&L->kf) - swept).norm();
            double skew = dv * (t_ref - utime) * 1e-6 / 2;
            if (skew > L->cfg.verify_deskew_m) {
                event(out, "verify_deskew", "sweep deskewed with a speed %.1f m/s off its match (%.2f m over the sweep); "
                      "verification waits", dv, skew);
            } else if (degenerate || detected) {
                /* a place along a tunnel fits as well as any other */
                event(out, "verify_degenerate", "the sweep does not fix the position along the road; verification waits");
            } else if (++L->verify_count >= L->cfg.verify_scans) {
                L->candidate = false;
                set_status(L, ST_TRACKING, out, "pose verified");
            }
        } else if (degenerate && prediction_sigma_m(L->kf) > L->cfg.degenerate_lost_m) {
            /* not known along the road: where the walls end, a match from here would take the
             * exit's structure for wherever the prediction has got to; relocalised instead */
            snprintf(whybuf, sizeof whybuf, "the LiDAR does not fix the position along the road (a tunnel, long "
                     "walls), and the motion alone knows it to %.1f m (sd)", prediction_sigma_m(L->kf));
            set_status(L, ST_LOST, out, whybuf);
        } else if (degenerate && prediction_sigma_m(L->kf) > L->cfg.degenerate_degraded_m) {
            if (L->status == ST_TRACKING) {
                snprintf(whybuf, sizeof whybuf, "the LiDAR does not fix the position along the road (a tunnel, long "
                         "walls): from the motion alone, sd %.1f m", prediction_sigma_m(L->kf));
                set_status(L, ST_DEGRADED, out, whybuf);
            }
        } else if (L->status != ST_TRACKING && L->status != ST_LOST) {
            set_status(L, ST_TRACKING, out, was_gap ? "LiDAR back" : "match accepted");
        }
    } else {
        ++L->reject_count;
        L->structure_run = std::isfinite(structure_miss) ? L->structure_run + 1 : 0;
        if (L->candidate && structure_miss >= L->cfg.structure_peak_floor &&
            L->cand_holds < L->cfg.verify_scans - 1) {
            ++L->cand_holds;
            event(out, "candidate_held", "candidate kept through a sweep that neither verifies nor drops it: %s",
                  why ? why : "?");
        } else if (L->candidate) {
            /* a candidate that fails is dropped: search again on the next sweep, around
             * where it would be now when it came from a prior with tries left and the
             * car's speed unknown (then its motion, not the place, may have failed it;
             * otherwise the global search follows, as it did) */
            L->candidate = false;
            if (L->cand_retry_hint && L->hint_tries < L->cfg.hint_retries) {
                L->has_hint = true;
                L->hint = filter_base_pose(&L->kf);
                L->hint_t = L->cand_vel_unknown ? L->cand_t : t_ref;   /* unknown speed: it has not moved on */
                L->hint_body_vel = L->cand_vel_unknown ? Vec3::Zero() : filter_body_velocity(&L->kf);
            }
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
    check_clock(L, t_ref, L->last_scan_t + L->scan_dt, "LIDAR_SCAN", out);
    if (L->last_scan_t != 0 && t_ref <= L->last_scan_t) {
        if (t_ref == L->last_scan_t) event(out, "scan_duplicate", "LIDAR_SCAN: sweep at %lld repeated, dropped", (long long)utime);
        else event(out, "scan_out_of_order", "LIDAR_SCAN: sweep %.0f ms older than the last one dropped",
                   (L->last_scan_t - t_ref) * 1e-3);
        return;
    }
    L->scan_dt = L->last_scan_t != 0 ? t_ref - L->last_scan_t : 0;
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

void localizer_gnss(localizer_t *L, const gnss_in_t &raw, outputs_t *out)
{
    if (!L->has_geo) return;
    if (raw.fix_type < 2 || !std::isfinite(raw.lat_deg) || !std::isfinite(raw.lon_deg) || !std::isfinite(raw.alt_m)) {
        event(out, "gnss_no_fix");
        return;
    }
    if (L->has_fix && raw.utime <= L->fix_raw_utime) {
        event(out, raw.utime == L->fix_raw_utime ? "gnss_duplicate" : "gnss_out_of_order");
        return;
    }
    L->fix_raw_utime = raw.utime;
    /* the receiver's clock may be off the other sensors' by seconds: measured and taken out */
    gnss_in_t fx = raw;
    fx.utime -= gnss_clock_offset(L, raw.utime, out);
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

} // namespace pb_loc
