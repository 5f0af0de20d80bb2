/* anchor: see anchor.h. */
#include "anchor.h"

#include <algorithm>
#include <cmath>
#include <ceres/ceres.h>

#include "pose_graph.h"

using Vec3 = Eigen::Vector3d;

/* The weighted rigid transform dst <- src (Umeyama, no scale). */
static Eigen::Isometry3d fit_rigid(const std::vector<Vec3> &src, const std::vector<Vec3> &dst, const std::vector<double> &w)
{
    double wsum = 0;
    Vec3 ms = Vec3::Zero(), md = Vec3::Zero();
    for (size_t i = 0; i < src.size(); i++) { ms += w[i] * src[i]; md += w[i] * dst[i]; wsum += w[i]; }
    ms /= wsum;
    md /= wsum;
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < src.size(); i++) S += w[i] * (dst[i] - md) * (src[i] - ms).transpose();
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0) D(2, 2) = -1;   /* a rotation, not a reflection */
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = svd.matrixU() * D * svd.matrixV().transpose();
    T.translation() = md - T.linear() * ms;
    return T;
}

static double quantile(std::vector<double> v, double q)
{
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, (size_t)std::floor(q * (double)(v.size() - 1) + 0.5))];
}

static bool gated_in(const pb_anchor_obs_t &o, const pb_anchor_config_t &cfg)
{
    return o.fix_3d && o.h_acc_m > 0 && o.h_acc_m <= cfg.max_h_acc_m && o.antenna_map.allFinite() && o.fix_enu.allFinite();
}

int pb_anchor_fit(const std::vector<pb_anchor_obs_t> &obs, const pb_anchor_config_t *cfg_in, pb_anchor_result_t *r,
                  pb_err_t *err)
{
    const pb_anchor_config_t cfg = cfg_in ? *cfg_in : pb_anchor_config_t{};
    *r = pb_anchor_result_t{};
    r->enu_from_map = Eigen::Isometry3d::Identity();
    if (obs.empty()) return pb_err_set(err, "anchoring: no GNSS fix"), -1;

    // 1. the gate
    std::vector<size_t> use;
    for (size_t i = 0; i < obs.size(); i++) {
        if (gated_in(obs[i], cfg))
            use.push_back(i);
        else
            r->gated++;
    }
    for (;;) {
        // 4. enough fixes, spread far enough to fix the heading?
        r->used = (int)use.size();
        if ((int)use.size() < cfg.min_fixes) {
            r->why = "too few usable GNSS fixes (3-D, accuracy within the gate)";
            return 0;
        }
        r->extent_m = 0;
        for (size_t a = 0; a < use.size(); a += std::max<size_t>(1, use.size() / 200))
            for (size_t b = a + 1; b < use.size(); b++)
                r->extent_m = std::max(r->extent_m, (obs[use[a]].antenna_map - obs[use[b]].antenna_map).norm());
        if (r->extent_m < cfg.min_extent_m) {
            r->why = "the drive's GNSS fixes span too little ground to fix the map's heading";
            return 0;
        }
        // 2. the fit
        std::vector<Vec3> src, dst;
        std::vector<double> w;
        for (size_t i : use) {
            src.push_back(obs[i].antenna_map);
            dst.push_back(obs[i].fix_enu);
            w.push_back(1.0 / (obs[i].h_acc_m * obs[i].h_acc_m));
        }
        r->enu_from_map = fit_rigid(src, dst, w);
        std::vector<double> d(use.size());
        for (size_t k = 0; k < use.size(); k++) d[k] = (r->enu_from_map * src[k] - dst[k]).norm();
        r->resid_median_m = quantile(d, 0.5);
        r->resid_p90_m = quantile(d, 0.9);
        r->resid_max_m = *std::max_element(d.begin(), d.end());
        // 3. outliers out, and fit again
        double gate = std::max(cfg.min_reject_m, cfg.reject_sigmas * r->resid_median_m);
        std::vector<size_t> kept;
        for (size_t k = 0; k < use.size(); k++)
            if (d[k] <= gate) kept.push_back(use[k]);
        if (kept.size() == use.size()) break;
        r->rejected += (int)(use.size() - kept.size());
        use.swap(kept);
    }
    r->anchored = 1;
    r->why = "";
    return 0;
}

/* A fix's antenna position (seen from its node: d, in the node's frame) against the fix, per
 * axis in sigmas (horizontal sigma_h, vertical sigma_v). Parameters: the node's q (x y z w), t. */
struct FixError {
    Vec3 d, fix;
    double sigma_h, sigma_v;

    template <class T>
    bool operator()(const T *q_p, const T *t_p, T *res) const
    {
        Eigen::Map<const Eigen::Quaternion<T>> q(q_p);
        Eigen::Map<const Eigen::Matrix<T, 3, 1>> t(t_p);
        Eigen::Matrix<T, 3, 1> e = q * d.cast<T>() + t - fix.cast<T>();
        res[0] = e[0] / T(sigma_h);
        res[1] = e[1] / T(sigma_h);
        res[2] = e[2] / T(sigma_v);
        return true;
    }
};

/* The pose at time t between the poses around it (utime in order, t within their span). */
static Eigen::Isometry3d pose_at(const std::vector<int64_t> &utime, const std::vector<Eigen::Isometry3d> &poses, int64_t t)
{
    size_t b = (size_t)(std::upper_bound(utime.begin(), utime.end(), t) - utime.begin());
    b = std::min(std::max<size_t>(b, 1), utime.size() - 1);
    const size_t a = b - 1;
    const double u = std::min(1.0, std::max(0.0, double(t - utime[a]) / double(utime[b] - utime[a])));
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::Quaterniond(poses[a].linear()).slerp(u, Eigen::Quaterniond(poses[b].linear())).toRotationMatrix();
    T.translation() = (1 - u) * poses[a].translation() + u * poses[b].translation();
    return T;
}

/* A fix in the graph: on node k, the antenna at d in the node's frame. */
struct HeldFix {
    size_t k;
    Vec3 d, fix;
    double sigma_h;
};

/* The graph's nodes: a pose every node_spacing_m of each drive's path (all drives' in one
 * list, drive after drive). */
struct HeldNodes {
    std::vector<Eigen::Isometry3d> before;
    std::vector<size_t> first;                  /* per drive: its first node */
    std::vector<std::vector<size_t>> sweep;     /* per drive: each node's sweep */
    std::vector<std::vector<int64_t>> utime;    /* per drive: each node's time */

    /* Drive d's node at or before time t (its first for earlier times). */
    size_t at(size_t d, int64_t t) const
    {
        const std::vector<int64_t> &u = utime[d];
        size_t k = (size_t)(std::upper_bound(u.begin(), u.end(), t) - u.begin());
        return first[d] + (k ? k - 1 : 0);
    }
};

/* Steps 2-4's least squares: nodes joined by their drive's steps with step_scale times the
 * configured freedom, the links and the fixes; solved into *solved. The fixes' p90 distance
 * from the antenna at the solution into *resid_p90. Returns 0, or -1 with err. */
static int solve_hold(const HeldNodes &N, const std::vector<std::pair<size_t, size_t>> &links,
                      const std::vector<HeldFix> &fixes, const pb_anchor_hold_config_t &cfg, double step_scale,
                      std::vector<Eigen::Isometry3d> *solved, double *resid_p90, int *iterations, pb_err_t *err)
{
    const std::vector<Eigen::Isometry3d> &before = N.before;
    pb_pose_graph g(before);
    const double deg = M_PI / 180;
    for (size_t d = 0; d < N.first.size(); d++)
        for (size_t k = N.first[d]; k + 1 < N.first[d] + N.sweep[d].size(); k++) {
            Eigen::Isometry3d rel = before[k].inverse() * before[k + 1];
            double sm = step_scale * cfg.step_sigma_m * std::max(1.0, rel.translation().norm());
            g.add_edge(k, k + 1, rel, pb_sqrt_info(sm, step_scale * cfg.step_sigma_deg * deg));
        }
    for (const auto &l : links)
        g.add_edge(l.first, l.second, before[l.first].inverse() * before[l.second],
                   pb_sqrt_info(cfg.link_sigma_m, cfg.link_sigma_deg * deg));
    ceres::CauchyLoss loss(cfg.loss_sigmas);
    for (const HeldFix &f : fixes)
        g.problem.AddResidualBlock(new ceres::AutoDiffCostFunction<FixError, 3, 4, 3>(
                                       new FixError{f.d, f.fix, f.sigma_h, 1.5 * f.sigma_h}),
                                   &loss, g.q[f.k].data(), g.t[f.k].data());
    if (g.solve("GNSS hold", iterations, err) != 0) return -1;
    *solved = g.poses();
    std::vector<double> d;
    for (const HeldFix &f : fixes) d.push_back(((*solved)[f.k] * f.d - f.fix).norm());
    *resid_p90 = d.empty() ? 0 : quantile(d, 0.9);
    return 0;
}

int pb_anchor_hold(std::vector<pb_anchor_drive_t> *drives, const std::vector<pb_anchor_link_t> &links_in,
                   const pb_anchor_result_t &fit, const Vec3 &antenna, const pb_anchor_hold_config_t *cfg_in,
                   pb_anchor_hold_result_t *r, pb_err_t *err)
{
    const pb_anchor_hold_config_t cfg = cfg_in ? *cfg_in : pb_anchor_hold_config_t{};
    const pb_anchor_config_t gate{};
    *r = pb_anchor_hold_result_t{};
    std::vector<pb_anchor_drive_t> &D = *drives;
    if (!fit.anchored) return 0;
    for (const pb_anchor_drive_t &dr : D)
        if (dr.poses.size() < 2 || dr.poses.size() != dr.utime.size()) return 0;

    // 1. do the trajectories disagree with the fixes beyond what they say they err?
    std::vector<double> acc;
    for (const pb_anchor_drive_t &dr : D)
        for (const pb_anchor_obs_t &o : dr.obs)
            if (gated_in(o, gate)) acc.push_back(o.h_acc_m);
    if (acc.empty()) return 0;
    const double h_acc = quantile(acc, 0.5);
    r->ratio = fit.resid_p90_m / h_acc;
    if (!(r->ratio > cfg.inconsistent_ratio)) return 0;

    // 2. nodes every node_spacing_m of each drive's path; the links between their nodes
    HeldNodes N;
    for (const pb_anchor_drive_t &dr : D) {
        const std::vector<Eigen::Isometry3d> &P = dr.poses;
        N.first.push_back(N.before.size());
        N.sweep.emplace_back();
        N.utime.emplace_back();
        double since = 0;
        for (size_t i = 0; i < P.size(); i++) {
            if (i) since += (P[i].translation() - P[i - 1].translation()).norm();
            if (i && since < cfg.node_spacing_m && i + 1 < P.size()) continue;
            N.sweep.back().push_back(i);
            N.utime.back().push_back(dr.utime[i]);
            N.before.push_back(P[i]);
            since = 0;
        }
    }
    auto within = [&](int d, int64_t t) {
        return d >= 0 && (size_t)d < D.size() && t >= D[(size_t)d].utime.front() && t <= D[(size_t)d].utime.back();
    };
    std::vector<std::pair<size_t, size_t>> links;
    for (const pb_anchor_link_t &l : links_in) {
        if (!within(l.a_drive, l.a_utime) || !within(l.b_drive, l.b_utime)) continue;
        const size_t a = N.at((size_t)l.a_drive, l.a_utime), b = N.at((size_t)l.b_drive, l.b_utime);
        if (a != b) links.push_back({a, b});
    }

    // 3. the fixes, one per fix_every_s at most, on the antenna seen from the node before
    std::vector<HeldFix> fixes;
    for (size_t d = 0; d < D.size(); d++) {
        const pb_anchor_drive_t &dr = D[d];
        int64_t last = INT64_MIN;
        for (const pb_anchor_obs_t &o : dr.obs) {
            if (!gated_in(o, gate) || !within((int)d, o.utime)) continue;
            if (last != INT64_MIN && double(o.utime - last) < cfg.fix_every_s * 1e6) continue;
            last = o.utime;
            const size_t k = N.at(d, o.utime);
            /* h_acc: the horizontal RMS of two axes */
            fixes.push_back({k, N.before[k].inverse() * (pose_at(dr.utime, dr.poses, o.utime) * antenna), o.fix_enu,
                             o.h_acc_m / std::sqrt(2.0)});
        }
    }

    // 4. solve; while the fixes still disagree as much, the steps are given more freedom (the
    //    odometry drifted more than its sigmas say); every pose moved with its nodes
    std::vector<Eigen::Isometry3d> solved;
    double scale = 1, p90 = 0;
    for (int round = 0; round < cfg.max_rounds; round++, scale *= 3) {
        if (solve_hold(N, links, fixes, cfg, scale, &solved, &p90, &r->iterations, err) != 0) return -1;
        if (!(p90 / h_acc > cfg.inconsistent_ratio)) break;
    }
    for (size_t d = 0; d < D.size(); d++) {
        const size_t n = N.sweep[d].size(), k0 = N.first[d];
        std::vector<Eigen::Isometry3d> before(N.before.begin() + (long)k0, N.before.begin() + (long)(k0 + n)),
            after(solved.begin() + (long)k0, solved.begin() + (long)(k0 + n)), moved = D[d].poses;
        pb_pose_graph_apply(N.utime[d], before, after, D[d].utime, &moved);
        for (size_t i = 0; i < moved.size(); i++)
            r->max_change_m = std::max(r->max_change_m, (moved[i].translation() - D[d].poses[i].translation()).norm());
        D[d].poses.swap(moved);
    }
    r->held = 1;
    r->nodes = (int)N.before.size();
    r->fixes = (int)fixes.size();
    r->links = (int)links.size();
    r->step_scale = scale;
    r->resid_p90_m = p90;
    return 0;
}
