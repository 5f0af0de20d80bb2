/* loops: see loops.h. */
#include "loops.h"

#include <algorithm>
#include <array>
#include <tuple>
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

/* Step 2 for one candidate: keyframe j's points registered to the earlier pass's map
 * around keyframe i from seed, searched for within radius_m when that does not fit; true
 * with *pose when the structure fits and the correction is within the drift allowed. */
static bool verify(const std::vector<pb_keyframe_t> &kf, const std::vector<double> &s, const pb_loops_config_t &cfg,
                   size_t i, size_t j, const Eigen::Isometry3d &seed, double radius_m, double drift_share,
                   Eigen::Isometry3d *pose)
{
    pb_reg_config_t rcfg;
    pb_reg_config_default(&rcfg);
    std::vector<float> sub;
    for (size_t k = 0; k < j; k++) {
        if (kf[k].xyz.empty() || std::fabs(s[k] - s[i]) > cfg.submap_radius_m || s[j] - s[k] < cfg.min_separation_m)
            continue;
        for (size_t q = 0; q + 2 < kf[k].xyz.size(); q += 3) {
            Vec3 p = kf[k].pose * Vec3(kf[k].xyz[q], kf[k].xyz[q + 1], kf[k].xyz[q + 2]);
            sub.insert(sub.end(), {(float)p.x(), (float)p.y(), (float)p.z()});
        }
    }
    pb_err_t e;
    pb_regmap_t *m = pb_regmap_from_points(sub.data(), sub.size() / 3, nullptr, &e);
    if (!m) return false;
    pb_reg_result_t r;
    const float *xyz = kf[j].xyz.data();
    const size_t n = kf[j].xyz.size() / 3;
    int rc = pb_reg_align(m, xyz, n, seed, &rcfg, &r, &e);
    /* judged on the structure above the ground: the ground fits a pose metres off */
    if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers))
        rc = pb_reg_align_global(m, xyz, n, seed, radius_m, cfg.search_yaw_deg * M_PI / 180, &rcfg, &r, &e);
    pb_regmap_destroy(m);
    if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers)) return false;
    if (!within_drift(kf, s, cfg, i, j, r.pose, drift_share, 0, 0)) return false;
    *pose = r.pose;
    return true;
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

int pb_loops_close(const std::vector<pb_keyframe_t> &kf, const pb_loops_config_t *cfg_in,
                   std::vector<Eigen::Isometry3d> *out, pb_loops_report_t *rep, pb_err_t *err)
{
    const pb_loops_config_t cfg = cfg_in ? *cfg_in : pb_loops_config_t{};
    const size_t n = kf.size();
    *rep = pb_loops_report_t{};
    if (n < 2) return pb_err_set(err, "loop closure: %zu keyframe(s), two or more needed", n), -1;
    out->resize(n);
    for (size_t k = 0; k < n; k++) (*out)[k] = kf[k].pose;
    std::vector<double> s(n, 0);   /* path length at each keyframe */
    for (size_t k = 1; k < n; k++) s[k] = s[k - 1] + (kf[k].pose.translation() - kf[k - 1].pose.translation()).norm();

    // 1-2. candidates by position and by place, each verified against the earlier pass's
    //      map; first every keyframe's place descriptor (the localizer's Scan-Context-like one)
    pb_loc::places_config_t pcfg;
    std::vector<pb_loc::place_desc_t> desc(n);
    for (size_t k = 0; k < n; k++) pb_loc::places_describe(pcfg, kf[k].xyz.data(), kf[k].xyz.size() / 3, &desc[k]);

    std::vector<Loop> loops;
    size_t last_position = 0, last_place = 0;   /* the last keyframes that tried */
    for (size_t j = 1; j < n; j++) {
        if (kf[j].xyz.empty()) continue;
        size_t behind = 0;   /* keyframes [0, behind) are far enough behind */
        while (behind < j && s[j] - s[behind] >= cfg.min_separation_m) behind++;
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
            std::vector<std::pair<double, size_t>> rk;
            for (size_t i = 0; i < behind; i++) {
                /* the position part of the drift bound already (yaw below) */
                const double reach = cfg.max_correction_m + cfg.place_max_drift * (s[j] - s[i]) + cfg.place_search_m;
                if (kf[i].xyz.empty() || (kf[i].pose.translation() - kf[j].pose.translation()).norm() > reach) continue;
                double d = 0;
                for (int r = 0; r < pb_loc::PLACE_RINGS; r++) d += std::fabs(desc[j].ring_key[r] - desc[i].ring_key[r]);
                rk.push_back({d, i});
            }
            size_t m = std::min(rk.size(), kPlaceShortlist);
            std::partial_sort(rk.begin(), rk.begin() + (long)m, rk.end());
            std::vector<std::tuple<double, size_t, double>> alike;   /* distance, keyframe, yaw */
            for (size_t q = 0; q < m; q++) {
                size_t i = rk[q].second;
                double yaw, d = pb_loc::places_compare(pcfg, desc[j], desc[i], &yaw);
                Eigen::Isometry3d at_i = kf[i].pose * Eigen::AngleAxisd(yaw, Vec3::UnitZ());
                if (d <= cfg.place_max_distance &&
                    within_drift(kf, s, cfg, i, j, at_i, cfg.place_max_drift, cfg.place_search_m, cfg.search_yaw_deg))
                    alike.push_back({d, i, yaw});
            }
            std::sort(alike.begin(), alike.end());
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
            if (!verify(kf, s, cfg, i, j, seed, radius, by_place ? cfg.place_max_drift : cfg.max_drift, &pose)) {
                rep->rejected++;
                rep->refused.push_back({(int)i, (int)j});
                continue;
            }
            loops.push_back({i, j, kf[i].pose.inverse() * pose, by_place});
            rep->loops.push_back({(int)i, (int)j});
        }
    }
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
