/* loops: see loops.h. */
#include "loops.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <ceres/ceres.h>

#include "registration.h"
#include "regmap.h"

using Vec3 = Eigen::Vector3d;

namespace {

/* The relative pose b in a's frame against a measured one: translation error in a's frame
 * and twice the vector part of the rotation error quaternion (small angles: the angle),
 * weighted by the edge's square-root information. */
struct RelativePoseError {
    Vec3 t_ab;
    Eigen::Quaterniond q_ab;
    Eigen::Matrix<double, 6, 6> sqrt_info;

    template <class T>
    bool operator()(const T *qa_p, const T *ta_p, const T *qb_p, const T *tb_p, T *res) const
    {
        Eigen::Map<const Eigen::Quaternion<T>> qa(qa_p), qb(qb_p);
        Eigen::Map<const Eigen::Matrix<T, 3, 1>> ta(ta_p), tb(tb_p);
        Eigen::Quaternion<T> qa_inv = qa.conjugate();
        Eigen::Matrix<T, 3, 1> t_est = qa_inv * (tb - ta);
        Eigen::Quaternion<T> dq = q_ab.template cast<T>().conjugate() * (qa_inv * qb);
        Eigen::Map<Eigen::Matrix<T, 6, 1>> r(res);
        r.template head<3>() = t_est - t_ab.template cast<T>();
        r.template tail<3>() = T(2.0) * dq.vec();
        r.applyOnTheLeft(sqrt_info.template cast<T>());
        return true;
    }
};

Eigen::Matrix<double, 6, 6> sqrt_info_of(double sigma_m, double sigma_rad)
{
    Eigen::Matrix<double, 6, 1> d;
    d << Vec3::Constant(1 / sigma_m), Vec3::Constant(1 / sigma_rad);
    return d.asDiagonal();
}

}  // namespace

struct Loop {
    size_t i, j;
    Eigen::Isometry3d rel;   /* keyframe j in keyframe i's frame, from the match */
};

/* Least squares over the odometry edges and the loops, the first keyframe fixed. */
static int solve(const std::vector<pb_keyframe_t> &kf, const std::vector<Loop> &loops, const pb_loops_config_t &cfg,
                 std::vector<Eigen::Isometry3d> *out, int *iterations, pb_err_t *err)
{
    const size_t n = kf.size();
    std::vector<std::array<double, 4>> q(n);
    std::vector<std::array<double, 3>> t(n);
    for (size_t k = 0; k < n; k++) {
        Eigen::Quaterniond qq(kf[k].pose.linear());
        q[k] = {qq.x(), qq.y(), qq.z(), qq.w()};
        Vec3 tt = kf[k].pose.translation();
        t[k] = {tt.x(), tt.y(), tt.z()};
    }
    ceres::Problem::Options popt;
    popt.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(popt);
    ceres::EigenQuaternionManifold quat;
    auto add_edge = [&](size_t a, size_t b, const Eigen::Isometry3d &rel, const Eigen::Matrix<double, 6, 6> &si) {
        auto *f = new ceres::AutoDiffCostFunction<RelativePoseError, 6, 4, 3, 4, 3>(
            new RelativePoseError{rel.translation(), Eigen::Quaterniond(rel.linear()), si});
        problem.AddResidualBlock(f, nullptr, q[a].data(), t[a].data(), q[b].data(), t[b].data());
    };
    const double deg = M_PI / 180;
    for (size_t k = 0; k + 1 < n; k++) {
        Eigen::Isometry3d rel = kf[k].pose.inverse() * kf[k + 1].pose;
        double sm = cfg.odom_sigma_m * std::max(1.0, rel.translation().norm());
        add_edge(k, k + 1, rel, sqrt_info_of(sm, cfg.odom_sigma_deg * deg));
    }
    for (const Loop &l : loops) add_edge(l.i, l.j, l.rel, sqrt_info_of(cfg.loop_sigma_m, cfg.loop_sigma_deg * deg));
    for (size_t k = 0; k < n; k++) problem.SetManifold(q[k].data(), &quat);
    problem.SetParameterBlockConstant(q[0].data());
    problem.SetParameterBlockConstant(t[0].data());
    ceres::Solver::Options sopt;
    sopt.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    sopt.num_threads = 1;
    sopt.max_num_iterations = 100;
    sopt.logging_type = ceres::SILENT;
    ceres::Solver::Summary sum;
    ceres::Solve(sopt, &problem, &sum);
    if (!sum.IsSolutionUsable())
        return pb_err_set(err, "loop closure: the pose graph did not solve: %s", sum.message.c_str()), -1;
    *iterations += (int)sum.iterations.size();
    for (size_t k = 0; k < n; k++) {
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        T.linear() = Eigen::Quaterniond(q[k][3], q[k][0], q[k][1], q[k][2]).normalized().toRotationMatrix();
        T.translation() = Vec3(t[k][0], t[k][1], t[k][2]);
        (*out)[k] = T;
    }
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

    // 1-2. candidates, verified against the earlier pass's map
    std::vector<Loop> loops;
    pb_reg_config_t rcfg;
    pb_reg_config_default(&rcfg);
    size_t last_tried = 0;
    for (size_t j = 1; j < n; j++) {
        if (kf[j].xyz.empty() || (last_tried && j - last_tried < 5)) continue;
        size_t best = n;
        double best_d = cfg.search_radius_m;
        for (size_t i = 0; i < j && s[j] - s[i] >= cfg.min_separation_m; i++) {
            double d = (kf[i].pose.translation() - kf[j].pose.translation()).norm();
            if (d < best_d) { best_d = d; best = i; }
        }
        if (best == n) continue;
        last_tried = j;
        rep->candidates++;
        const size_t i = best;
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
        if (!m) { rep->rejected++; continue; }
        pb_reg_result_t r;
        int rc = pb_reg_align(m, kf[j].xyz.data(), kf[j].xyz.size() / 3, kf[j].pose, &rcfg, &r, &e);
        const double allowed = cfg.max_correction_m + cfg.max_drift * (s[j] - s[i]);
        /* judged on the structure above the ground: the ground fits a pose metres off */
        if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers)) {
            pb_reg_result_t g;
            rc = pb_reg_align_global(m, kf[j].xyz.data(), kf[j].xyz.size() / 3, kf[j].pose, allowed,
                                     cfg.search_yaw_deg * M_PI / 180, &rcfg, &g, &e);
            r = g;
        }
        pb_regmap_destroy(m);
        double moved = (r.pose.translation() - kf[j].pose.translation()).norm();
        if (rc < 0 || rc == PB_REG_FEW_POINTS || !(r.upright_inlier_fraction >= cfg.min_inliers) || moved > allowed) {
            rep->rejected++;
            continue;
        }
        loops.push_back({i, j, kf[i].pose.inverse() * r.pose});
        rep->loops.push_back({(int)i, (int)j});
        rep->verified++;
    }
    if (loops.empty()) return 0;

    // 3. the pose graph, solved; a loop that disagrees with the rest after the solve is
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
        loops.erase(loops.begin() + (long)worst);
        rep->loops.erase(rep->loops.begin() + (long)worst);
        if (loops.empty()) {
            for (size_t k = 0; k < n; k++) (*out)[k] = kf[k].pose;
            break;
        }
    }
    rep->verified = (int)loops.size();
    for (size_t k = 0; k < n; k++)
        rep->max_change_m = std::max(rep->max_change_m, ((*out)[k].translation() - kf[k].pose.translation()).norm());
    return 0;
}
