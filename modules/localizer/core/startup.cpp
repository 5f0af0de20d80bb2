/* Start-up and relocalisation: which pose to try on this sweep, and whether the match there
 * may become a candidate (see localizer.h, docs/localizer.md "Start-up"). */
#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#include "localizer_impl.h"
#include "places.h"

namespace pb_loc {

/* how far along its axis a car of unknown speed is looked for (the seeds of motion_seeds) */
static const double REACH_CAP_M = 40.0;

/* Where to search on this sweep, and why. */
struct start_t {
    Eigen::Isometry3d seed = Eigen::Isometry3d::Identity();
    double radius = 0, yaw_range = 0;
    Vec3 vel = Vec3::Zero();
    bool vel_known = false;
    const char *how = nullptr;
    std::vector<Eigen::Isometry3d> seeds;   /* instead of seed: where a car of unknown speed may be */
};

/* The base on the map's ground at (x, y): a start's height (and a GNSS height, MSL or
 * ellipsoidal, metres off) never decides it. Keeps z when the map has no ground there. */
static void put_on_ground(const localizer_t *L, Eigen::Isometry3d *T, double search_m)
{
    double gz;
    Vec3 t = T->translation();
    if (pb_regmap_ground_z(L->map, t.x(), t.y(), t.z(), search_m, 0, &gz)) T->translation().z() = gz;
}

static Vec3 course_velocity(const localizer_t *L, const gnss_in_t &fx)
{
    /* course over ground, clockwise from north, to map yaw (CCW from map +x) */
    double yaw = M_PI / 2 - fx.heading_deg * M_PI / 180 - L->geo.yaw_deg * M_PI / 180;
    return Vec3(std::cos(yaw), std::sin(yaw), 0) * fx.speed_mps;
}

/* Chooses the start for this sweep: an initial pose (a prior: searched within
 * cfg.hint_radius_m / hint_yaw_deg), a GNSS fix, or the dead-reckoned pose when lost.
 * Returns false when there is none (the caller then searches the whole map). */
static bool choose_start(localizer_t *L, int64_t t_ref, start_t *s)
{
    /* a prior of unknown speed older than the seeds along its axis reach (sweeps seconds
     * apart: MulRan's keyframes on a bridge, 3 s and 36 m on from a place that could not
     * be told from its neighbours) no longer says where the car is: searched as with none */
    if (L->has_hint && L->hint_t != 0 && t_ref > L->hint_t) {
        double dt = (t_ref - L->hint_t) * 1e-6;
        if ((L->hint_body_vel.isZero() || dt >= 2.0) && L->cfg.max_speed_mps * dt > REACH_CAP_M) L->has_hint = false;
    }
    if (L->has_hint) {
        s->seed = L->hint;
        s->vel = s->seed.linear() * L->hint_body_vel;
        if (s->vel.isZero() && fix_fresh(L, t_ref) && L->fix.speed_mps > 0.5) s->vel = course_velocity(L, L->fix);
        if (L->hint_t == 0) L->hint_t = t_ref;   /* --initial-pose: valid at the first sweep */
        /* the hint is for its own time; the car moved on since. Its speed says where
         * to for a short while only (in 2 s a car brakes by 10 m/s or turns by 35
         * degrees): older, the car is somewhere along its axis (the seeds below) */
        double dt = t_ref > L->hint_t ? (t_ref - L->hint_t) * 1e-6 : 0;
        if (dt >= 2.0) s->vel = Vec3::Zero();
        s->seed.translation() += s->vel * dt;
        s->vel_known = !s->vel.isZero();
        /* a start that fails is tried again on later sweeps, unless a track runs to fall back on */
        if (L->kf.initialized || ++L->hint_tries >= L->cfg.hint_retries) L->has_hint = false;
        put_on_ground(L, &s->seed, 10.0);
        s->radius = L->cfg.hint_radius_m;
        s->yaw_range = L->cfg.hint_yaw_deg * M_PI / 180;
        s->how = "initial pose";
        /* a prior for a moving car of unknown speed, tried again later (its first sweeps
         * did not fit, or a candidate from it failed): the car is somewhere along its axis
         * by now, not within the prior's disc */
        if (!s->vel_known && motion_reach_m(L, dt) > s->radius) {
            double step;
            s->seeds = motion_seeds(L, s->seed, dt, &step);
            s->radius = std::max(1.5, 0.75 * step);
        }
        return true;
    }
    if (fix_fresh(L, t_ref) && L->has_geo) {
        const gnss_in_t &fx = L->fix;
        double yaw = 0;
        if (fx.speed_mps > L->cfg.gnss_init_speed_mps && fx.heading_acc_deg < L->cfg.gnss_init_heading_acc_deg) {
            s->vel = course_velocity(L, fx);
            yaw = std::atan2(s->vel.y(), s->vel.x());
            s->yaw_range = std::max(3 * fx.heading_acc_deg * M_PI / 180, 10 * M_PI / 180);
            s->how = "GNSS position and course";
        } else {
            if (L->pred.initialized) yaw = std::atan2(L->pred.q.toRotationMatrix()(1, 0), L->pred.q.toRotationMatrix()(0, 0));
            s->yaw_range = M_PI;
            s->how = "GNSS position and yaw search";
            if (fx.speed_mps > 0.5) s->vel = course_velocity(L, fx);
        }
        s->vel_known = std::isfinite(fx.speed_mps);   /* under 0.5 m/s: at rest */
        s->seed.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
        Vec3 ant = L->ex.base_from_gnss.translation();
        s->seed.translation() = L->fix_map + s->vel * ((t_ref - fx.utime) * 1e-6) - s->seed.linear() * ant;
        put_on_ground(L, &s->seed, 60.0);
        s->radius = std::max(L->cfg.gnss_search_radius_m, 2 * (std::isfinite(fx.h_acc_m) ? fx.h_acc_m : 2.0));
        return true;
    }
    if (L->status == ST_LOST && L->pred.initialized && L->lost_searches++ < L->cfg.lost_searches) {
        /* no GNSS: look around the dead-reckoned pose, as far as its covariance says */
        s->seed = filter_base_pose(&L->pred);
        s->vel = filter_base_velocity(&L->pred);
        s->vel_known = true;
        Mat6 P = filter_base_covariance(&L->pred);
        double sd = std::sqrt(std::max(P(0, 0), P(1, 1)));
        s->radius = std::min(std::max(3.0, 3 * sd), L->cfg.lost_search_max_m);
        s->yaw_range = std::min(std::max(20 * M_PI / 180, 3 * std::sqrt(P(5, 5))), M_PI);
        s->how = "dead-reckoned pose search";
        return true;
    }
    return false;
}

/* Where a car whose speed is not known may be dt_s after it was at `from`: seeds along
 * arcs either way along its axis (reversing, or a LiDAR mounted facing backwards), as far
 * as max_speed * dt (at most 40 m), turning by up to max_yaw_rate * dt (at most 60
 * degrees), 10 degrees apart. *step: their spacing along the arcs (search each about
 * 0.75 * step around). At most ~40 seeds (a few hundred ms: live, the sweeps keep
 * coming), so a longer gap spaces them wider. */
double motion_reach_m(const localizer_t *L, double dt_s) { return std::min(L->cfg.max_speed_mps * dt_s, REACH_CAP_M); }

std::vector<Eigen::Isometry3d> motion_seeds(const localizer_t *L, const Eigen::Isometry3d &from, double dt_s,
                                            double *step)
{
    double reach = motion_reach_m(L, dt_s);
    double turn = std::min(L->cfg.max_yaw_rate_dps * dt_s, 60.0) * M_PI / 180;
    int nturn = int(std::floor(turn / (10 * M_PI / 180)));
    *step = std::max(2.0, 2 * reach * (2 * nturn + 1) / 40.0);
    std::vector<Eigen::Isometry3d> seeds;
    for (int k = -nturn; k <= nturn; k++)
        for (double along = -std::floor(reach / *step) * *step; along <= reach + 1e-9; along += *step) {
            if (k != 0 && std::fabs(along) < 1e-9) continue;   /* no distance, no turn */
            double phi = k * 10 * M_PI / 180, sgn = along < 0 ? -1 : 1;
            /* an arc of length |along| turning by phi: its chord, at half the turn */
            double chord = std::fabs(phi) > 1e-9 ? 2 * std::fabs(along) / std::fabs(phi) * std::sin(std::fabs(phi) / 2)
                                                 : std::fabs(along);
            Eigen::AngleAxisd half(sgn * phi / 2, Vec3::UnitZ()), full(sgn * phi, Vec3::UnitZ());
            Eigen::Isometry3d T = from;
            T.translation() += (half * from.linear().col(0)) * (sgn * chord);
            T.linear() = full * from.linear();
            seeds.push_back(T);
        }
    return seeds;
}

/* (localizer_impl.h) */
bool ambiguous(const localizer_t *L, double fit, double rival)
{
    return fit >= L->cfg.min_structure_inliers && rival > L->cfg.rival_ratio * fit;
}

/* The best of several seeds: each searched within radius / yaw_range by registration,
 * kept when the map explains enough of the sweep, ranked by the structure fit (the
 * inlier share alone favours the ground, which fits almost anywhere on a road).
 * page: ask the pager for the map around each seed first (seeds far apart).
 * *rival: the best fit of a result more than cfg.rival_m or cfg.rival_yaw_deg from the
 * best one (-1: none). */
bool search_seeds(localizer_t *L, const std::vector<Eigen::Isometry3d> &seeds, double radius, double yaw_range,
                  bool page, pb_reg_result_t *res, double *fit, double *rival)
{
    bool have = false;
    *fit = -1;
    std::vector<std::pair<double, Eigen::Isometry3d>> found;
    for (const Eigen::Isometry3d &seed : seeds) {
        if (page && L->pager) L->pager(L->pager_user, seed.translation().x(), seed.translation().y());
        pb_reg_result_t r;
        pb_err_t err;
        if (pb_reg_align_global(L->map, L->xyz.data(), L->xyz.size() / 3, seed, radius, yaw_range, &L->cfg.reg, &r,
                                &err) < 0 ||
            r.status == PB_REG_FEW_POINTS || r.inlier_fraction < L->cfg.min_inlier_fraction)
            continue;
        double si = structure_inliers(L, r.pose);
        double f = std::isfinite(si) ? si : 0.0;
        found.push_back({ f, r.pose });
        if (f > *fit) { *fit = f; *res = r; have = true; }
    }
    if (rival) {
        *rival = -1;
        for (const auto &o : found) {
            if (!have) break;
            Eigen::Isometry3d D = res->pose.inverse() * o.second;
            double dyaw = std::fabs(std::atan2(D.linear()(1, 0), D.linear()(0, 0)));
            if (D.translation().head<2>().norm() > L->cfg.rival_m || dyaw > L->cfg.rival_yaw_deg * M_PI / 180)
                *rival = std::max(*rival, o.first);
        }
    }
    if (have && page && L->pager) L->pager(L->pager_user, res->pose.translation().x(), res->pose.translation().y());
    return have;
}

/* No prior at all: the places most like this sweep (places.h), each verified by a small
 * registration search; returns the one whose structure fits the map best. Every sweep
 * tries the best-ranked places, so a place that fits as well as the one taken is among
 * those tried (a sweep trying ranks 17-32 took a road the wrong way round, 44 m off, on
 * MulRan). searching_s: how long this search has run (sweep time). */
bool global_search(localizer_t *L, double searching_s, pb_reg_result_t *res, outputs_t *out)
{
    if (!L->places && !L->places_failed && L->pager) {
        /* a paged map holds only the tiles around one place: descriptors built from it
         * would search there alone */
        event(out, "no_start", "no pose: waiting for INITIAL_POSE or a GNSS fix (the map tiles carry no place "
              "descriptors for a global search: rebuild them with map-tiles)");
        return false;
    }
    if (!L->places && !L->places_failed) {
        places_config_t pc;
        L->places = places_build(L->map, pc);
        L->places_failed = !L->places;
        if (L->places) event(out, "places_built", "global search: %zu places described in the map", places_count(L->places));
    }
    if (!L->places) {
        event(out, "no_start", "no pose: waiting for INITIAL_POSE or a GNSS fix (the map has no ground to search)");
        return false;
    }
    place_desc_t d;
    places_describe(L->places, L->xyz.data(), L->xyz.size() / 3, &d);
    std::vector<place_match_t> pm;
    places_query(L->places, d, L->cfg.global_candidates, &pm);
    std::vector<Eigen::Isometry3d> seeds;
    for (size_t i = 0; i < pm.size(); i++) {
        Eigen::Isometry3d seed = Eigen::Isometry3d::Identity();
        seed.linear() = Eigen::AngleAxisd(pm[i].yaw, Vec3::UnitZ()).toRotationMatrix();
        seed.translation() = Vec3(pm[i].x, pm[i].y, pm[i].z);
        seeds.push_back(seed);
    }
    double fit, rival;
    if (!search_seeds(L, seeds, 2.0, 12 * M_PI / 180, true, res, &fit, &rival)) {
        event(out, "no_start", "no pose: no INITIAL_POSE or GNSS fix, and none of %zu likely places in the map fits "
              "this sweep; still searching", seeds.size());
        return false;
    }
    /* the ground fits almost anywhere: a sweep with too little above it to judge the structure
     * (the car in an open place) cannot tell places apart (a street without buildings or
     * trees: the car stopped, a place 540 m off was taken on the ground alone) */
    if (!std::isfinite(structure_inliers(L, res->pose))) {
        event(out, "global_no_structure", "global search: too little structure above the ground to tell places "
              "apart; still searching");
        return false;
    }
    /* a road whose sides repeat (rows of trees, fences) fits the sweep along itself too,
     * and the place descriptor may not have proposed the true spot: probe the place's own
     * axis as rivals (MulRan: a place 24 m along the road from the truth was taken) */
    if (fit >= L->cfg.min_structure_inliers && rival <= L->cfg.rival_ratio * fit) {
        Vec3 ax = res->pose.linear().col(0);
        ax.z() = 0;
        ax.normalize();
        std::vector<Eigen::Isometry3d> along;
        for (double a : { -30.0, -20.0, -10.0, 10.0, 20.0, 30.0 }) {
            Eigen::Isometry3d seed = res->pose;
            seed.translation() += a * ax;
            along.push_back(seed);
        }
        pb_reg_result_t r2;
        double f2;
        if (search_seeds(L, along, 2.0, 4 * M_PI / 180, true, &r2, &f2, nullptr) &&
            (r2.pose.translation() - res->pose.translation()).head<2>().norm() > L->cfg.rival_m)
            rival = std::max(rival, f2);
        if (L->pager) L->pager(L->pager_user, res->pose.translation().x(), res->pose.translation().y());
    }
    /* rows of trees, parallel carriageways, a road alike both ways: a place that another
     * one far from it (or the other way round) fits about as well is not known yet */
    if (ambiguous(L, fit, rival)) {
        event(out, "global_ambiguous", "global search: two places %.0f+ m or %.0f+ deg apart fit this sweep alike "
              "(%.0f%% and %.0f%% of the structure); still searching", L->cfg.rival_m, L->cfg.rival_yaw_deg, 100 * fit,
              100 * rival);
        return false;
    }
    /* a look-alike fits a street of trees so-so (porous street: 0.6-0.7 at places 100-280
     * m along it, the truth 0.97 but not among the best-ranked places of some sweeps):
     * when the next sweep comes soon, wait for a place that fits surely (the next sweep's best).
     * Not with sweeps a second or more apart (keyframes), nor before the rate is known:
     * MulRan's true places fit 0.7-0.9, and a keyframe's wait took starts past 5 s */
    if (fit < L->cfg.global_sure_fit && L->scan_dt > 0 &&
        searching_s + L->scan_dt * 1e-6 <= L->cfg.global_patience_s) {
        event(out, "global_unsure", "global search: the best place fits %.0f%% of the structure; looking for one that "
              "fits %.0f%% for up to %.1f s", 100 * fit, 100 * L->cfg.global_sure_fit, L->cfg.global_patience_s);
        return false;
    }
    return true;
}

bool try_initialize(localizer_t *L, int64_t t_ref, outputs_t *out)
{
    pb_err_t err;
    pb_reg_result_t res;
    start_t s;
    Vec3 omega = L->kf.initialized ? L->pred.omega : L->kf.omega;
    if (choose_start(L, t_ref, &s) && !s.seeds.empty()) {
        double fit, rival;
        if (!search_seeds(L, s.seeds, s.radius, s.yaw_range, false, &res, &fit, &rival)) {
            event(out, "init_rejected", "%s: no match along the car's axis (where it may be %.1f s after the prior) "
                  "explains %.0f%% of the sweep", s.how, (t_ref - L->hint_t) * 1e-6, 100 * L->cfg.min_inlier_fraction);
            return false;
        }
        /* seeds metres apart along a road whose trees repeat: as in the global search */
        if (ambiguous(L, fit, rival)) {
            event(out, "init_ambiguous", "%s: two places %.0f+ m apart along the car's axis fit this sweep alike "
                  "(%.0f%% and %.0f%% of the structure); still searching", s.how, L->cfg.rival_m, 100 * fit, 100 * rival);
            return false;
        }
    } else if (s.how) {
        int rc = pb_reg_align_global(L->map, L->xyz.data(), L->xyz.size() / 3, s.seed, s.radius, s.yaw_range,
                                     &L->cfg.reg, &res, &err);
        if (rc < 0) { event(out, "init_failed", "%s: %s", s.how, err.msg); return false; }
    } else if (L->cfg.global_search) {
        s.how = "global search";
        if (!L->global_since || t_ref < L->global_since) L->global_since = t_ref;   /* (a clock stepped back) */
        if (!global_search(L, (t_ref - L->global_since) * 1e-6, &res, out)) return false;
    } else {
        event(out, "no_start", "no pose: waiting for INITIAL_POSE or a GNSS fix");
        return false;
    }
    const char *how = s.how;
    L->init_inliers = res.inlier_fraction;
    L->init_structure = NAN;
    if (res.status == PB_REG_FEW_POINTS || res.inlier_fraction < L->cfg.min_inlier_fraction) {
        event(out, "init_rejected", "%s: best match explains %.0f%% of the sweep (need %.0f%%)", how,
              100 * res.inlier_fraction, 100 * L->cfg.min_inlier_fraction);
        return false;
    }
    double si = structure_inliers(L, res.pose);
    L->init_structure = si;
    if (!structure_fits(L, res.pose, si, out)) {
        event(out, "init_rejected_structure", "%s: only %.0f%% of the structure above the ground fits the map (need %.0f%%)",
              how, 100 * si, 100 * L->cfg.min_structure_inliers);
        if (L->status != ST_LOST && L->kf.initialized)
            set_status(L, ST_LOST, out, "pose does not fit the map's structure");
        return false;
    }
    double gr = candidate_gnss_residual(L, res.pose, s.vel, t_ref);
    if (std::isfinite(gr) && gr > gnss_gate(L, L->fix.h_acc_m)) {
        event(out, "init_rejected_gnss", "%s: candidate is %.1f m from the GNSS fix", how, gr);
        /* a pose we had is contradicted: say so, then relocalise from GNSS */
        if (L->status != ST_LOST && L->kf.initialized) set_status(L, ST_LOST, out, "pose disagrees with GNSS");
        return false;
    }
    Eigen::Isometry3d pose = res.pose;
    double speed = newest_speed(L, t_ref);
    if (!s.vel_known && std::isfinite(speed)) {
        s.vel = pose.linear().col(0) * speed;   /* CAN speed along the matched heading */
        s.vel_known = true;
    }
    if (L->pred.initialized && !s.vel_known) { s.vel = filter_base_velocity(&L->pred); s.vel_known = true; }
    /* omega: the rates of the newest IMU sample (or the LiDAR-only estimate) */
    filter_reset(&L->kf, t_ref, pose, s.vel, omega, 0.3, 2 * M_PI / 180, 1.0);
    L->deskew_vel_ok = false;
    while (!L->buf.empty() && L->buf.front().t <= t_ref) L->buf.pop_front();
    rebuild_pred(L);
    L->candidate = true;
    L->weak_dir.setZero();   /* a new pose: what the sweeps before it did not fix is no longer known */
    L->weak_run = L->weak_clear = 0;
    L->global_since = 0;
    L->lost_searches = 0;
    L->cand_vel_unknown = !s.vel_known;
    L->cand_pose = pose;
    L->cand_t = t_ref;
    L->verify_count = 1;
    L->cand_holds = 0;
    L->reject_count = 0;
    L->gnss_res.clear();
    L->has_prev_pose = false;
    /* the direction of travel from matches starts afresh: the step from an earlier
     * (wrong or old) pose to this one is no motion of the car */
    L->last_match_t = 0;
    L->match_fwd_mps = 0;
    L->cand_no_speed = !s.vel_known;
    L->cand_global = s.how && std::strcmp(s.how, "global search") == 0;
    L->cand_retry_hint = s.how && std::strcmp(s.how, "initial pose") == 0 && !s.vel_known;
    L->has_hint = false;
    event(out, "init_candidate", "%s: candidate at (%.1f, %.1f, %.1f) yaw %.1f deg, inliers %.0f%%%s", how,
          pose.translation().x(), pose.translation().y(), pose.translation().z(),
          std::atan2(pose.linear()(1, 0), pose.linear()(0, 0)) * 180 / M_PI, 100 * res.inlier_fraction,
          s.vel_known ? "" : ", speed unknown");
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
    L->hint_tries = 0;
    L->hint_body_vel = L->pred.initialized ? filter_body_velocity(&L->pred) : Vec3::Zero();
    /* the current track (if any) keeps running on prediction until the hint is verified,
     * so a wrong hint can fall back on it */
    L->candidate = false;
    set_status(L, ST_INITIALIZING, out, "INITIAL_POSE received");
}

} // namespace pb_loc
