/* loops: see loops.h. */
#include "loops.h"

#include <algorithm>
#include <array>
#include <deque>
#include <functional>
#include <map>
#include <tuple>
#include <unordered_map>
#include <cmath>
#include <ceres/ceres.h>

#include "places.h"
#include "pose_graph.h"
#include "registration.h"
#include "regmap.h"

using Vec3 = Eigen::Vector3d;

struct Loop {
    size_t i, j;
    Eigen::Isometry3d rel;   /* keyframe j in keyframe i's frame, from the match */
    bool by_place;           /* found by the descriptor, not by position */
};

/* Keyframes compared in full per try after the ring key (rotation invariant) */
static const size_t kPlaceShortlist = 100;

/* The keyframes' points (kf[k].xyz, or read through a pb_keyframe_points_t), their place
 * descriptors and whether they have any, by keyframe (drive, utime: the copies made for the
 * placed drives find theirs too). The descriptors are made once, reading every keyframe in
 * turn; the points are read again when a submap or a match needs them, through a cache of
 * the last kCached (consecutive candidates' submaps overlap). */
class Points {
public:
    bool failed = false;
    pb_err_t err;

    Points(const std::vector<pb_keyframe_t> &kf, const pb_keyframe_points_t *src) : kf_(kf), src_(src)
    {
        pb_loc::places_config_t pcfg;
        desc_.resize(kf.size());
        has_.resize(kf.size());
        for (size_t k = 0; k < kf.size(); k++) {
            id_[{kf[k].drive, kf[k].utime}] = k;
            const std::vector<float> &xyz = read(k);
            has_[k] = !xyz.empty();
            pb_loc::places_describe(pcfg, xyz.data(), xyz.size() / 3, &desc_[k]);
        }
    }
    bool has(const pb_keyframe_t &k) const { return has_[id(k)]; }
    const pb_loc::place_desc_t &desc(const pb_keyframe_t &k) const { return desc_[id(k)]; }
    /* k's points; valid until the next call */
    const std::vector<float> &get(const pb_keyframe_t &k)
    {
        const size_t i = id(k);
        if (!src_) return kf_[i].xyz;
        auto it = cache_.find(i);
        if (it != cache_.end()) return it->second;
        return read(i);
    }

private:
    static const size_t kCached = 128;
    const std::vector<pb_keyframe_t> &kf_;
    const pb_keyframe_points_t *src_;
    std::map<std::pair<int, int64_t>, size_t> id_;
    std::vector<pb_loc::place_desc_t> desc_;
    std::vector<char> has_;
    std::unordered_map<size_t, std::vector<float>> cache_;
    std::deque<size_t> order_;   /* cached, oldest first */
    const std::vector<float> none_;

    size_t id(const pb_keyframe_t &k) const { return id_.at({k.drive, k.utime}); }
    const std::vector<float> &read(size_t i)
    {
        if (!src_) return kf_[i].xyz;
        if (failed) return none_;
        if (order_.size() == kCached) {
            cache_.erase(order_.front());
            order_.pop_front();
        }
        std::vector<float> &xyz = cache_[i];
        order_.push_back(i);
        if (src_->read(src_->user, kf_[i], &xyz, &err) != 0) {
            failed = true;
            xyz.clear();
        }
        return xyz;
    }
};

/* Whether pose (map <- base) for keyframe j is a correction of its odometry pose that the
 * odometry can have drifted since keyframe i: at most max_correction_m + share of the path
 * between (+ slack_m) and max_correction_deg + max_drift_deg per 100 m (+ slack_deg). */
static bool within_drift(const std::vector<pb_keyframe_t> &kf, const std::vector<double> &s, const pb_loops_config_t &cfg,
                         size_t i, size_t j, const Eigen::Isometry3d &pose, double share, double slack_m, double slack_deg)
{
    const double path = s[j] - s[i];
    double moved = (pose.translation() - kf[j].pose.translation()).norm();
    double turned = Eigen::AngleAxisd(kf[j].pose.linear().transpose() * pose.linear()).angle() * 180 / M_PI;
    return moved <= cfg.max_correction_m + share * path + slack_m &&
           turned <= cfg.max_correction_deg + cfg.max_drift_deg * path / 100 + slack_deg;
}

/* Whether loops a and b agree: round the cycle from a's earlier keyframe to b's (by the
 * odometry), over b's loop, back from b's later keyframe to a's (by the odometry) and back
 * over a's loop, one comes back to the start within what the odometry can have drifted
 * over its two legs (loop edges are centimetres; a look-alike place is metres off). */
static bool consistent(const std::vector<pb_keyframe_t> &kf, const std::vector<double> &s, const pb_loops_config_t &cfg,
                       const Loop &a, const Loop &b)
{
    Eigen::Isometry3d e = a.rel.inverse() * (kf[a.i].pose.inverse() * kf[b.i].pose) * b.rel *
                          (kf[b.j].pose.inverse() * kf[a.j].pose);
    const double legs = std::fabs(s[a.i] - s[b.i]) + std::fabs(s[a.j] - s[b.j]);
    return e.translation().norm() <= cfg.max_correction_m + cfg.max_drift * legs &&
           Eigen::AngleAxisd(e.linear()).angle() * 180 / M_PI <= cfg.max_correction_deg + cfg.max_drift_deg * legs / 100;
}

/* The map of the stored keyframes before end of keyframe i's drive within submap_radius_m
 * of path around it, at least min_separation_m of path behind s_from (map frame). */
static std::vector<float> submap(Points &P, const std::vector<pb_keyframe_t> &kf, const std::vector<double> &s,
                                 const pb_loops_config_t &cfg, size_t i, size_t end, double s_from)
{
    std::vector<float> sub;
    for (size_t k = 0; k < end; k++) {
        if (!P.has(kf[k]) || kf[k].drive != kf[i].drive || std::fabs(s[k] - s[i]) > cfg.submap_radius_m ||
            s_from - s[k] < cfg.min_separation_m)
            continue;
        const std::vector<float> &xyz = P.get(kf[k]);
        for (size_t q = 0; q + 2 < xyz.size(); q += 3) {
            Vec3 p = kf[k].pose * Vec3(xyz[q], xyz[q + 1], xyz[q + 2]);
            sub.insert(sub.end(), {(float)p.x(), (float)p.y(), (float)p.z()});
        }
    }
    return sub;
}

/* Points xyz (base) registered to the map sub from seed, searched for within radius_m when
 * that does not fit; true with *pose when the structure fits. */
static bool match(const std::vector<float> &sub, const std::vector<float> &pts, const Eigen::Isometry3d &seed,
                  double radius_m, const pb_loops_config_t &cfg, Eigen::Isometry3d *pose)
{
    pb_reg_config_t rcfg = cfg.reg;
    pb_err_t e;
    pb_regmap_t *m = pb_regmap_from_points(sub.data(), sub.size() / 3, nullptr, &e);
    if (!m) return false;
    pb_reg_result_t r;
    const float *xyz = pts.data();
    const size_t n = pts.size() / 3;
    int rc = pb_reg_align(m, xyz, n, seed, &rcfg, &r, &e);
    /* judged on the structure above the ground: the ground fits a pose metres off */
    if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers))
        rc = pb_reg_align_global(m, xyz, n, seed, radius_m, cfg.search_yaw_deg * M_PI / 180, &rcfg, &r, &e);
    pb_regmap_destroy(m);
    if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers)) return false;
    *pose = r.pose;
    return true;
}

/* Step 2 for one candidate: keyframe j's points registered to the earlier pass's map
 * around keyframe i from seed, searched for within radius_m when that does not fit; true
 * with *pose when the structure fits and the correction is within the drift allowed. */
static bool verify(Points &P, const std::vector<pb_keyframe_t> &kf, const std::vector<double> &s,
                   const pb_loops_config_t &cfg, size_t i, size_t j, const Eigen::Isometry3d &seed, double radius_m,
                   double drift_share, Eigen::Isometry3d *pose)
{
    Eigen::Isometry3d r;
    const std::vector<float> sub = submap(P, kf, s, cfg, i, j, s[j]);
    if (!match(sub, P.get(kf[j]), seed, radius_m, cfg, &r)) return false;
    if (!within_drift(kf, s, cfg, i, j, r, drift_share, 0, 0)) return false;
    *pose = r;
    return true;
}

/* The keyframes kf[0, end) most alike a place of descriptor dj, among those with points for
 * which keep(i) holds: a ring-key shortlist (rotation invariant) compared in full, kept when
 * within place_max_distance and fits(i, yaw); (distance, keyframe, yaw), nearest first. */
template <class Keep, class Fits>
static std::vector<std::tuple<double, size_t, double>> most_alike(Points &P, const std::vector<pb_keyframe_t> &kf,
                                                                  size_t end, const pb_loc::place_desc_t &dj,
                                                                  const pb_loops_config_t &cfg, Keep keep, Fits fits)
{
    pb_loc::places_config_t pcfg;
    std::vector<std::pair<double, size_t>> rk;
    for (size_t i = 0; i < end; i++) {
        if (!P.has(kf[i]) || !keep(i)) continue;
        const pb_loc::place_desc_t &di = P.desc(kf[i]);
        double d = 0;
        for (int r = 0; r < pb_loc::PLACE_RINGS; r++) d += std::fabs(dj.ring_key[r] - di.ring_key[r]);
        rk.push_back({d, i});
    }
    const size_t m = std::min(rk.size(), kPlaceShortlist);
    std::partial_sort(rk.begin(), rk.begin() + (long)m, rk.end());
    std::vector<std::tuple<double, size_t, double>> alike;
    for (size_t q = 0; q < m; q++) {
        const size_t i = rk[q].second;
        double yaw, d = pb_loc::places_compare(pcfg, dj, P.desc(kf[i]), &yaw);
        if (d <= cfg.place_max_distance && fits(i, yaw)) alike.push_back({d, i, yaw});
    }
    std::sort(alike.begin(), alike.end());
    return alike;
}

/* Least squares over the odometry edges and the loops, the first keyframe fixed. */
static int solve(const std::vector<pb_keyframe_t> &kf, const std::vector<Loop> &loops, const pb_loops_config_t &cfg,
                 std::vector<Eigen::Isometry3d> *out, int *iterations, pb_err_t *err)
{
    std::vector<Eigen::Isometry3d> start;
    for (const pb_keyframe_t &k : kf) start.push_back(k.pose);
    pb_pose_graph g(start);
    const double deg = M_PI / 180;
    for (size_t k = 0; k + 1 < kf.size(); k++) {
        if (kf[k + 1].drive != kf[k].drive) continue;   /* two drives: no odometry between them */
        Eigen::Isometry3d rel = kf[k].pose.inverse() * kf[k + 1].pose;
        double sm = cfg.odom_sigma_m * std::max(1.0, rel.translation().norm());
        g.add_edge(k, k + 1, rel, pb_sqrt_info(sm, cfg.odom_sigma_deg * deg));
    }
    for (const Loop &l : loops) g.add_edge(l.i, l.j, l.rel, pb_sqrt_info(cfg.loop_sigma_m, cfg.loop_sigma_deg * deg));
    g.problem.SetParameterBlockConstant(g.q[0].data());
    g.problem.SetParameterBlockConstant(g.t[0].data());
    if (g.solve("loop closure", iterations, err) != 0) return -1;
    *out = g.poses();
    return 0;
}

/* The path length at each keyframe (the drives' paths one after the other). */
static std::vector<double> path_at(const std::vector<pb_keyframe_t> &kf)
{
    std::vector<double> s(kf.size(), 0);
    for (size_t k = 1; k < kf.size(); k++)
        s[k] = s[k - 1] + (kf[k].drive != kf[k - 1].drive ? 0 : (kf[k].pose.translation() - kf[k - 1].pose.translation()).norm());
    return s;
}

/* Steps 1-4 over the keyframes (placed drives one after the other), with the loops given
 * (step 0's) besides those found. */
static int close_placed(Points &P, const std::vector<pb_keyframe_t> &kf, const pb_loops_config_t &cfg,
                        std::vector<Loop> loops, std::vector<Eigen::Isometry3d> *out, pb_loops_report_t *rep,
                        pb_err_t *err)
{
    const size_t n = kf.size();
    for (const Loop &l : loops) rep->loops.push_back({(int)l.i, (int)l.j});
    out->resize(n);
    for (size_t k = 0; k < n; k++) (*out)[k] = kf[k].pose;
    const std::vector<double> s = path_at(kf);

    // 1-2. candidates by position and by place (the localizer's Scan-Context-like
    //      descriptor), each verified against the earlier pass's map
    size_t last_position = 0, last_place = 0;   /* the last keyframes that tried */
    for (size_t j = 1; j < n; j++) {
        if (!P.has(kf[j])) continue;
        const pb_loc::place_desc_t &dj = P.desc(kf[j]);
        size_t behind = 0;   /* keyframes [0, behind) are far enough behind (an earlier drive's: all) */
        while (behind < j && (kf[behind].drive != kf[j].drive || s[j] - s[behind] >= cfg.min_separation_m)) behind++;
        if (behind == 0) continue;
        /* a. the nearest by the odometry's positions */
        struct Candidate { size_t i; bool by_place; double yaw; };
        std::vector<Candidate> cand;
        size_t best = n;
        double best_d = cfg.search_radius_m;
        for (size_t i = 0; i < behind; i++) {
            double d = (kf[i].pose.translation() - kf[j].pose.translation()).norm();
            if (d < best_d) { best_d = d; best = i; }
        }
        if (best < n && (!last_position || j - last_position >= (size_t)cfg.try_every)) {
            cand.push_back({best, false, 0});
            last_position = j;
        }
        /* b. the most alike by the descriptor (a ring-key shortlist compared in full) that
         *    the odometry can have drifted from (a cheap test before the registration), the
         *    best distinct places, not the position candidate's */
        if (!last_place || j - last_place >= (size_t)cfg.try_every) {
            last_place = j;
            const auto alike = most_alike(P, kf, behind, dj, cfg,
                [&](size_t i) {   /* the position part of the drift bound already (yaw below) */
                    const double reach = cfg.max_correction_m + cfg.place_max_drift * (s[j] - s[i]) + cfg.place_search_m;
                    return (kf[i].pose.translation() - kf[j].pose.translation()).norm() <= reach;
                },
                [&](size_t i, double yaw) {
                    Eigen::Isometry3d at_i = kf[i].pose * Eigen::AngleAxisd(yaw, Vec3::UnitZ());
                    return within_drift(kf, s, cfg, i, j, at_i, cfg.place_max_drift, cfg.place_search_m, cfg.search_yaw_deg);
                });
            int from_place = 0;
            for (const auto &[d, i, yaw] : alike) {
                if (from_place >= cfg.place_candidates) break;
                bool distinct = best == n || std::fabs(s[best] - s[i]) > cfg.submap_radius_m;
                for (const Candidate &c : cand) distinct &= std::fabs(s[c.i] - s[i]) > cfg.submap_radius_m;
                if (!distinct) continue;
                cand.push_back({i, true, yaw});
                from_place++;
            }
        }
        for (const auto &[i, by_place, yaw] : cand) {
            rep->candidates++;
            rep->place_candidates += by_place;
            Eigen::Isometry3d seed = kf[j].pose, pose;
            double radius = cfg.max_correction_m + cfg.max_drift * (s[j] - s[i]);
            if (by_place) {
                /* the earlier keyframe turned by the descriptor's yaw: where j is if it is the same place */
                seed = kf[i].pose * Eigen::AngleAxisd(yaw, Vec3::UnitZ());
                radius = cfg.place_search_m;
            }
            if (!verify(P, kf, s, cfg, i, j, seed, radius, by_place ? cfg.place_max_drift : cfg.max_drift, &pose)) {
                rep->rejected++;
                rep->refused.push_back({(int)i, (int)j});
                continue;
            }
            loops.push_back({i, j, kf[i].pose.inverse() * pose, by_place});
            rep->loops.push_back({(int)i, (int)j});
        }
    }
    if (P.failed) return *err = P.err, -1;
    // 3. the loops that agree with each other pairwise (the largest such set, greedily from
    //    the loop that agrees with the most); a loop by place needs another loop to agree
    //    with (one look-alike place alone would bend the whole map)
    const size_t L = loops.size();
    std::vector<std::vector<char>> agree(L, std::vector<char>(L, 1));
    std::vector<std::tuple<int, double, size_t>> order;   /* -partners, correction (ties: the nearer the odometry), loop */
    for (size_t a = 0; a < L; a++) {
        int partners = 0;
        for (size_t b = 0; b < L; b++)
            if (b != a) partners += agree[a][b] = consistent(kf, s, cfg, loops[a], loops[b]);
        double moved = ((kf[loops[a].i].pose * loops[a].rel).translation() - kf[loops[a].j].pose.translation()).norm();
        order.push_back({-partners, moved, a});
    }
    std::sort(order.begin(), order.end());
    std::vector<size_t> kept;
    for (const auto &[minus_partners, moved, a] : order) {
        bool ok = true;
        for (size_t k : kept) ok &= agree[a][k] && agree[k][a];
        if (ok) kept.push_back(a);
    }
    if (kept.size() == 1 && loops[kept[0]].by_place) kept.clear();
    std::sort(kept.begin(), kept.end());
    std::vector<Loop> agreeing;
    std::vector<std::pair<int, int>> agreeing_ij;
    for (size_t a = 0, k = 0; a < L; a++) {
        if (k < kept.size() && kept[k] == a) {
            agreeing.push_back(loops[a]);
            agreeing_ij.push_back(rep->loops[a]);
            k++;
        } else {
            rep->dropped++;
            rep->refused.push_back(rep->loops[a]);
        }
    }
    loops.swap(agreeing);
    rep->loops.swap(agreeing_ij);
    if (loops.empty()) return 0;

    // 4. the pose graph, solved; a loop that disagrees with the rest after the solve is
    //    dropped and the graph solved again
    for (;;) {
        if (solve(kf, loops, cfg, out, &rep->iterations, err) != 0) return -1;
        size_t worst = loops.size();
        double worst_m = cfg.loop_reject_m;
        for (size_t l = 0; l < loops.size(); l++) {
            Eigen::Isometry3d e = loops[l].rel.inverse() * ((*out)[loops[l].i].inverse() * (*out)[loops[l].j]);
            double m = e.translation().norm();
            if (m > worst_m) { worst_m = m; worst = l; }
        }
        if (worst == loops.size()) break;
        rep->dropped++;
        rep->refused.push_back(rep->loops[worst]);
        loops.erase(loops.begin() + (long)worst);
        rep->loops.erase(rep->loops.begin() + (long)worst);
        if (loops.empty()) {
            for (size_t k = 0; k < n; k++) (*out)[k] = kf[k].pose;
            break;
        }
    }
    rep->verified = (int)loops.size();
    for (const Loop &l : loops) rep->place_loops += l.by_place;
    for (size_t k = 0; k < n; k++)
        rep->max_change_m = std::max(rep->max_change_m, ((*out)[k].translation() - kf[k].pose.translation()).norm());
    return 0;
}

/* Step 0 for one drive (its keyframes kf[b, e), in its own odometry frame): placed in the
 * map of the keyframes placed before it (placed, path ps), by the first verified match of
 * its places to theirs that a second one, at least submap_radius_m of its path further on,
 * agrees with. true with *placement (map <- its frame) and the two matches (i in placed, j
 * in kf, rel unset; *poses their j's poses in the map). */
static bool place(Points &P, const std::vector<pb_keyframe_t> &placed, const std::vector<double> &ps,
                  const std::vector<pb_keyframe_t> &kf, size_t b, size_t e, const pb_loops_config_t &cfg,
                  pb_drive_report_t *dr, Eigen::Isometry3d *placement, std::vector<Loop> *two,
                  std::vector<Eigen::Isometry3d> *poses)
{
    struct Match { size_t i, j; double sj; Eigen::Isometry3d pose; };
    std::vector<Match> found;
    double sj = 0;   /* path along the drive */
    size_t last = e;
    for (size_t j = b; j < e; j++) {
        if (j > b) sj += (kf[j].pose.translation() - kf[j - 1].pose.translation()).norm();
        if (!P.has(kf[j]) || (last < e && j - last < (size_t)cfg.try_every)) continue;
        last = j;
        const pb_loc::place_desc_t &dj = P.desc(kf[j]);
        /* the most alike places (a ring-key shortlist compared in full), distinct ones */
        const auto alike = most_alike(P, placed, placed.size(), dj, cfg, [](size_t) { return true; },
                                      [](size_t, double) { return true; });
        std::vector<size_t> tried;
        for (const auto &[d, i, yaw] : alike) {
            if ((int)tried.size() >= cfg.place_candidates) break;
            bool distinct = true;
            for (size_t t : tried) distinct &= placed[t].drive != placed[i].drive || std::fabs(ps[t] - ps[i]) > cfg.submap_radius_m;
            if (!distinct) continue;
            tried.push_back(i);
            dr->tried++;
            Eigen::Isometry3d pose;
            const std::vector<float> sub = submap(P, placed, ps, cfg, i, placed.size(), INFINITY);
            if (!match(sub, P.get(kf[j]), placed[i].pose * Eigen::AngleAxisd(yaw, Vec3::UnitZ()), cfg.place_search_m,
                       cfg, &pose))
                continue;
            dr->matched++;
            /* agreement with an earlier match far enough back: the placement it gives puts
             * this keyframe where this match does, within the drift of the two paths */
            for (const Match &a : found) {
                if (sj - a.sj < cfg.submap_radius_m) continue;
                const Eigen::Isometry3d T = a.pose * kf[a.j].pose.inverse();
                const Eigen::Isometry3d err = pose.inverse() * T * kf[j].pose;
                const double legs = (sj - a.sj) + (placed[a.i].drive == placed[i].drive ? std::fabs(ps[i] - ps[a.i]) : 0);
                if (err.translation().norm() <= cfg.max_correction_m + cfg.max_drift * legs &&
                    Eigen::AngleAxisd(err.linear()).angle() * 180 / M_PI <=
                        cfg.max_correction_deg + cfg.max_drift_deg * legs / 100) {
                    *placement = T;
                    *two = {{a.i, a.j, {}, true}, {i, j, {}, true}};
                    *poses = {a.pose, pose};
                    return true;
                }
            }
            found.push_back({i, j, sj, pose});
        }
    }
    dr->why = dr->matched ? "no two matches to the earlier drives agree" : "no place of the earlier drives matched";
    return false;
}

int pb_loops_close(const std::vector<pb_keyframe_t> &kf, const pb_loops_config_t *cfg_in,
                   std::vector<Eigen::Isometry3d> *out, pb_loops_report_t *rep, pb_err_t *err,
                   const pb_keyframe_points_t *points)
{
    const pb_loops_config_t cfg = cfg_in ? *cfg_in : pb_loops_config_t{};
    const size_t n = kf.size();
    *rep = pb_loops_report_t{};
    if (n < 2) return pb_err_set(err, "loop closure: %zu keyframe(s), two or more needed", n), -1;
    std::vector<size_t> begin = {0};   /* each drive's first keyframe, and n */
    for (size_t k = 0; k < n; k++) {
        if (k == 0 ? kf[k].drive != 0 : kf[k].drive != kf[k - 1].drive && kf[k].drive != kf[k - 1].drive + 1)
            return pb_err_set(err, "loop closure: keyframe %zu is of drive %d (drives 0, 1, ... in order)", k, kf[k].drive), -1;
        if (k > 0 && kf[k].drive != kf[k - 1].drive) begin.push_back(k);
    }
    begin.push_back(n);
    const size_t nd = begin.size() - 1;
    Points P(kf, points);
    if (P.failed) return *err = P.err, -1;
    const pb_drive_report_t first = {true, "", 0, 0, 0, Eigen::Isometry3d::Identity()};
    if (nd == 1) {
        rep->drives = {first};
        return close_placed(P, kf, cfg, {}, out, rep, err);
    }
    std::vector<const char *> excluded(nd, nullptr);   /* why a drive is left out */
    for (;;) {
        // 0. each later drive placed in the map of those before it
        std::vector<pb_drive_report_t> drives(nd, pb_drive_report_t{false, "", 0, 0, 0, Eigen::Isometry3d::Identity()});
        drives[0] = first;
        std::vector<pb_keyframe_t> placed(kf.begin(), kf.begin() + (long)begin[1]);
        std::vector<size_t> from(begin[1]);   /* placed's keyframe k is kf[from[k]] */
        for (size_t k = 0; k < begin[1]; k++) from[k] = k;
        std::vector<Loop> given;
        for (size_t d = 1; d < nd; d++) {
            if (excluded[d]) { drives[d].why = excluded[d]; continue; }
            Eigen::Isometry3d T;
            std::vector<Loop> two;
            std::vector<Eigen::Isometry3d> poses;
            if (!place(P, placed, path_at(placed), kf, begin[d], begin[d + 1], cfg, &drives[d], &T, &two, &poses)) {
                if (P.failed) return *err = P.err, -1;
                continue;
            }
            drives[d].placed = true;
            drives[d].placement = T;
            const size_t at = placed.size();
            for (size_t k = begin[d]; k < begin[d + 1]; k++) {
                placed.push_back(kf[k]);
                placed.back().pose = T * kf[k].pose;
                from.push_back(k);
            }
            for (size_t q = 0; q < 2; q++) {
                Loop l = two[q];
                l.j = l.j - begin[d] + at;
                l.rel = placed[l.i].pose.inverse() * poses[q];
                given.push_back(l);
            }
        }
        // 1-4. over the placed drives together
        pb_loops_report_t r{};
        std::vector<Eigen::Isometry3d> solved;
        if (close_placed(P, placed, cfg, given, &solved, &r, err) != 0) return -1;
        // every placed drive must still be joined to the first by the loops kept: else it is
        // left out and all done again (the drives placed on it may have to go too)
        std::vector<int> root(nd);
        for (size_t d = 0; d < nd; d++) root[d] = (int)d;
        std::function<int(int)> find = [&](int d) { return root[d] == d ? d : root[d] = find(root[d]); };
        for (const auto &l : r.loops) {
            int a = placed[(size_t)l.first].drive, b = placed[(size_t)l.second].drive;
            if (a == b) continue;
            drives[a].links++;
            drives[b].links++;
            root[find(a)] = find(b);
        }
        size_t cut = 0;
        for (size_t d = 1; d < nd && !cut; d++)
            if (drives[d].placed && find((int)d) != find(0)) cut = d;
        if (cut) {
            excluded[cut] = "its matches to the earlier drives disagreed with the rest of the graph";
            continue;
        }
        // back to the keyframes as given
        out->resize(n);
        for (size_t k = 0; k < n; k++) (*out)[k] = kf[k].pose;
        for (size_t k = 0; k < placed.size(); k++) (*out)[from[k]] = solved[k];
        for (auto *v : {&r.loops, &r.refused})
            for (auto &l : *v) l = {(int)from[(size_t)l.first], (int)from[(size_t)l.second]};
        *rep = r;
        rep->drives = drives;
        return 0;
    }
}
