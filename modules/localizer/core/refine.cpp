/* refine: multi-scan refinement of LiDAR poses (see refine.h). */
#include "refine.h"

#include <algorithm>
#include <cmath>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include "registration.h"
#include "regmap.h"

void pb_refine_config_default(pb_refine_config_t *cfg)
{
    *cfg = pb_refine_config_t();
}

namespace {

/* The scans near scan i (not i itself), nearest first. */
std::vector<size_t> neighbours(const std::vector<Eigen::Isometry3d> &poses, size_t i, const pb_refine_config_t *cfg)
{
    std::vector<std::pair<double, size_t>> d;
    for (size_t j = 0; j < poses.size(); j++) {
        if (j == i) continue;
        double r = (poses[j].translation() - poses[i].translation()).head<2>().norm();
        if (r < cfg->neighbour_radius_m) d.push_back({r, j});
    }
    std::sort(d.begin(), d.end());
    if ((int)d.size() > cfg->max_neighbours) d.resize((size_t)cfg->max_neighbours);
    std::vector<size_t> out;
    for (auto &p : d) out.push_back(p.second);
    std::sort(out.begin(), out.end());   /* map points in scan order: deterministic */
    return out;
}

/* Registers scan i to the map of its neighbours at their poses: the pose it
 * would take and its inlier share at its current pose. */
struct Match {
    Eigen::Isometry3d pose;
    double fit_at_start;
    bool ok;
};

Match match_to_others(const std::vector<std::vector<float>> &scans, const std::vector<Eigen::Isometry3d> &poses,
                      size_t i, const pb_refine_config_t *cfg)
{
    Match m = {poses[i], NAN, false};
    std::vector<size_t> nb = neighbours(poses, i, cfg);
    if (nb.empty()) return m;
    std::vector<float> pts;
    for (size_t j : nb) {
        const std::vector<float> &s = scans[j];
        const Eigen::Matrix3f R = poses[j].linear().cast<float>();
        const Eigen::Vector3f t = poses[j].translation().cast<float>();
        for (size_t k = 0; k + 2 < s.size(); k += 3) {
            Eigen::Vector3f p = R * Eigen::Vector3f(s[k], s[k + 1], s[k + 2]) + t;
            pts.insert(pts.end(), {p.x(), p.y(), p.z()});
        }
    }
    pb_regmap_config_t mc;
    pb_regmap_config_default(&mc);
    mc.voxel_m = cfg->voxel_m;
    pb_err_t err;
    pb_regmap_t *map = pb_regmap_from_points(pts.data(), pts.size() / 3, &mc, &err);
    if (!map) return m;
    pb_reg_config_t rc;
    pb_reg_config_default(&rc);
    rc.coarse_iterations = cfg->coarse_iterations;
    rc.rough_targets = 0;   /* the others' scans at disturbed poses: a thick surface is their misalignment */
    pb_reg_result_t r;
    pb_reg_config_t ev = rc;
    ev.max_iterations = 0;
    ev.coarse_iterations = 0;
    if (pb_reg_align(map, scans[i].data(), scans[i].size() / 3, poses[i], &ev, &r, &err) >= 0)
        m.fit_at_start = r.inlier_fraction;
    int st = pb_reg_align(map, scans[i].data(), scans[i].size() / 3, poses[i], &rc, &r, &err);
    if ((st == PB_REG_OK || st == PB_REG_MAX_ITER) && r.points_used >= cfg->min_points_used) {
        m.pose = r.pose;
        m.ok = true;
    }
    pb_regmap_destroy(map);
    return m;
}

double angle_deg(const Eigen::Isometry3d &a, const Eigen::Isometry3d &b)
{
    return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() * 180 / M_PI;
}

typedef Eigen::Matrix<double, 6, 1> Vec6;
typedef Eigen::Matrix<double, 6, 6> Mat6;

/* A relative pose measured by registering scan i to the map of scan j alone
 * (no doubled structure from other scans' errors): Z ~ T_j^-1 T_i, with the
 * information W of the registration (in j's frame). */
struct Edge {
    size_t i, j;
    Eigen::Isometry3d Z;
    Mat6 W;
};

/* [t; rotation vector] of a small transform */
Vec6 vec_of(const Eigen::Isometry3d &T)
{
    Eigen::AngleAxisd aa(T.linear());
    Vec6 v;
    v.head<3>() = T.translation();
    v.tail<3>() = aa.axis() * aa.angle();
    return v;
}

/* T' = Exp(d) T with d = [dt (map); dtheta (map axes)], the registration's convention */
Eigen::Isometry3d perturb(const Eigen::Isometry3d &T, const Vec6 &d)
{
    Eigen::Isometry3d P = T;
    P.translation() += d.head<3>();
    double a = d.tail<3>().norm();
    if (a > 0) P.linear() = Eigen::AngleAxisd(a, d.tail<3>() / a).toRotationMatrix() * T.linear();
    return P;
}

/* residual of an edge at poses Ti, Tj: left error of T_j^-1 T_i against Z, in j's frame */
Vec6 edge_residual(const Edge &e, const Eigen::Isometry3d &Ti, const Eigen::Isometry3d &Tj)
{
    return vec_of(Tj.inverse() * Ti * e.Z.inverse());
}

/* Measures the edges between each scan and its neighbours (j > i) at the current poses. */
std::vector<Edge> measure_edges(const std::vector<std::vector<float>> &scans, const std::vector<pb_regmap_t *> &maps,
                                const std::vector<Eigen::Isometry3d> &poses, const pb_refine_config_t *cfg)
{
    pb_reg_config_t rc;
    pb_reg_config_default(&rc);
    rc.coarse_iterations = cfg->coarse_iterations;
    rc.rough_targets = 0;   /* one sparse scan's scattered cells are too few points for a Gaussian */
    std::vector<Edge> edges;
    for (size_t i = 0; i < poses.size(); i++)
        for (size_t j : neighbours(poses, i, cfg)) {
            if (j < i || !maps[j]) continue;
            pb_reg_result_t r;
            pb_err_t err;
            Eigen::Isometry3d guess = poses[j].inverse() * poses[i];
            int st = pb_reg_align(maps[j], scans[i].data(), scans[i].size() / 3, guess, &rc, &r, &err);
            if ((st != PB_REG_OK && st != PB_REG_MAX_ITER) || r.points_matched < cfg->min_points_used ||
                r.inlier_fraction < cfg->min_pair_inliers)
                continue;
            Mat6 C = r.covariance;
            for (int k = 0; k < 3; k++) { C(k, k) += 0.02 * 0.02; C(k + 3, k + 3) += std::pow(0.1 * M_PI / 180, 2); }
            edges.push_back({i, j, r.pose, C.inverse()});
        }
    return edges;
}

/* Least squares over all poses (Gauss-Newton, numeric Jacobians, Cauchy weights
 * on the Mahalanobis residual; the first pose holds the gauge). */
void solve_graph(const std::vector<Edge> &edges, std::vector<Eigen::Isometry3d> *poses)
{
    const size_t n = poses->size();
    for (int it = 0; it < 10; it++) {
        Eigen::MatrixXd H = Eigen::MatrixXd::Zero(6 * n, 6 * n);
        Eigen::VectorXd b = Eigen::VectorXd::Zero(6 * n);
        for (const Edge &e : edges) {
            const Eigen::Isometry3d &Ti = (*poses)[e.i], &Tj = (*poses)[e.j];
            Vec6 r0 = edge_residual(e, Ti, Tj);
            Eigen::Matrix<double, 6, 12> J;
            for (int k = 0; k < 6; k++) {
                Vec6 d = Vec6::Zero();
                d(k) = 1e-6;
                J.col(k) = (edge_residual(e, perturb(Ti, d), Tj) - r0) / 1e-6;
                J.col(6 + k) = (edge_residual(e, Ti, perturb(Tj, d)) - r0) / 1e-6;
            }
            double m2 = r0.dot(e.W * r0), w = 1.0 / (1.0 + m2 / 9.0);   /* Cauchy, scale 3 sigma */
            Eigen::Matrix<double, 12, 12> h = w * J.transpose() * e.W * J;
            Eigen::Matrix<double, 12, 1> g = w * J.transpose() * e.W * r0;
            size_t idx[2] = {6 * e.i, 6 * e.j};
            for (int a = 0; a < 2; a++) {
                b.segment<6>((Eigen::Index)idx[a]) -= g.segment<6>(6 * a);
                for (int c = 0; c < 2; c++) H.block<6, 6>((Eigen::Index)idx[a], (Eigen::Index)idx[c]) += h.block<6, 6>(6 * a, 6 * c);
            }
        }
        H.block<6, 6>(0, 0) += 1e9 * Mat6::Identity();
        H.diagonal().array() += 1e-6;
        Eigen::VectorXd dx = H.ldlt().solve(b);
        double step = 0;
        for (size_t k = 0; k < n; k++) {
            (*poses)[k] = perturb((*poses)[k], dx.segment<6>(6 * (Eigen::Index)k));
            step = std::max(step, dx.segment<3>(6 * (Eigen::Index)k).norm());
        }
        if (step < 1e-4) break;
    }
}

}  // namespace

int pb_refine_poses(const std::vector<std::vector<float>> &scans, std::vector<Eigen::Isometry3d> *poses,
                    const pb_refine_config_t *cfg_in, pb_refine_report_t *rep, void (*progress)(int, double, void *),
                    void *user, pb_err_t *err)
{
    pb_refine_config_t cfg;
    pb_refine_config_default(&cfg);
    if (cfg_in) cfg = *cfg_in;
    const size_t n = poses->size();
    if (scans.size() != n || n < 3) return pb_err_set(err, "refine: %zu scans and %zu poses (need >= 3 of each, equal)", scans.size(), n);
    const std::vector<Eigen::Isometry3d> input = *poses;
    *rep = pb_refine_report_t();
    rep->fit_before.assign(n, NAN);
    rep->fit_after.assign(n, NAN);
    /* each scan's own map, for the pairwise registrations */
    std::vector<pb_regmap_t *> maps(n, nullptr);
    pb_regmap_config_t mc;
    pb_regmap_config_default(&mc);
    mc.voxel_m = cfg.voxel_m;
    for (size_t i = 0; i < n; i++) maps[i] = pb_regmap_from_points(scans[i].data(), scans[i].size() / 3, &mc, nullptr);
    for (size_t i = 0; i < n; i++) rep->fit_before[i] = match_to_others(scans, input, i, &cfg).fit_at_start;
    Eigen::Matrix3Xd in_pos(3, n);
    for (size_t i = 0; i < n; i++) in_pos.col((Eigen::Index)i) = input[i].translation();
    for (int round = 0; round < cfg.max_rounds; round++) {
        /* 1. relative poses from pairwise registration at the current poses,
         *    then every pose from all of them at once (least squares) */
        const std::vector<Eigen::Isometry3d> prev = *poses;
        std::vector<Edge> edges = measure_edges(scans, maps, prev, &cfg);
        std::vector<Eigen::Isometry3d> &next = *poses;
        solve_graph(edges, &next);
        rep->edges = (int)edges.size();
        int kept = 0;
        std::vector<int> degree(n, 0);
        for (const Edge &e : edges) { degree[e.i]++; degree[e.j]++; }
        for (size_t i = 0; i < n; i++) kept += degree[i] == 0;
        rep->edge_resid_m.clear();
        for (const Edge &e : edges) rep->edge_resid_m.push_back(edge_residual(e, next[e.i], next[e.j]).head<3>().norm());
        /* 2. back into the input's frame: the rigid motion that best aligns the
         *    new positions with the input ones */
        Eigen::Matrix3Xd pos(3, n);
        for (size_t i = 0; i < n; i++) pos.col((Eigen::Index)i) = next[i].translation();
        Eigen::Isometry3d A(Eigen::umeyama(pos, in_pos, false));
        double moved = 0;
        for (size_t i = 0; i < n; i++) {
            next[i] = A * next[i];
            moved = std::max(moved, (next[i].translation() - prev[i].translation()).norm());
        }
        rep->moved_m.push_back(moved);
        rep->rounds = round + 1;
        rep->kept = kept;
        if (progress) progress(round + 1, moved, user);
        if (moved < cfg.stop_m) break;
    }
    for (pb_regmap_t *m : maps) pb_regmap_destroy(m);
    /* 3. how good: every scan against the map of the others (leave-one-out), nothing moved */
    rep->loo_m.assign(n, NAN);
    rep->loo_deg.assign(n, NAN);
    rep->change_m.assign(n, NAN);
    for (size_t i = 0; i < n; i++) {
        Match m = match_to_others(scans, *poses, i, &cfg);
        rep->fit_after[i] = m.fit_at_start;
        if (m.ok) {
            rep->loo_m[i] = (m.pose.translation() - (*poses)[i].translation()).norm();
            rep->loo_deg[i] = angle_deg(m.pose, (*poses)[i]);
        }
        rep->change_m[i] = ((*poses)[i].translation() - input[i].translation()).norm();
    }
    return 0;
}
