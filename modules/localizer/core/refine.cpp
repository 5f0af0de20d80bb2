/* refine: multi-scan refinement of LiDAR poses (see refine.h). */
#include "refine.h"

#include <algorithm>
#include <cmath>
#include <Eigen/Geometry>
#include <Eigen/LU>

#include "registration.h"
#include "regmap.h"

void refine_config_default(refine_config_t *cfg)
{
    cfg->neighbour_radius_m = 40;
    cfg->max_neighbours = 30;
    cfg->max_rounds = 8;
    cfg->stop_m = 0.005;
    cfg->voxel_m = 0.5;
    cfg->min_points_used = 200;
}

namespace {

/* The scans near scan i (not i itself), nearest first. */
std::vector<size_t> neighbours(const std::vector<Eigen::Isometry3d> &poses, size_t i, const refine_config_t *cfg)
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
                      size_t i, const refine_config_t *cfg)
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

}  // namespace

int refine_poses(const std::vector<std::vector<float>> &scans, std::vector<Eigen::Isometry3d> *poses,
                 const refine_config_t *cfg_in, refine_report_t *rep, void (*progress)(int, double, void *),
                 void *user, pb_err_t *err)
{
    refine_config_t cfg;
    refine_config_default(&cfg);
    if (cfg_in) cfg = *cfg_in;
    const size_t n = poses->size();
    if (scans.size() != n || n < 3) return pb_err_set(err, "refine: %zu scans and %zu poses (need >= 3 of each, equal)", scans.size(), n);
    const std::vector<Eigen::Isometry3d> input = *poses;
    *rep = refine_report_t();
    rep->fit_before.assign(n, NAN);
    rep->fit_after.assign(n, NAN);
    Eigen::Matrix3Xd in_pos(3, n);
    for (size_t i = 0; i < n; i++) in_pos.col((Eigen::Index)i) = input[i].translation();
    for (int round = 0; round < cfg.max_rounds; round++) {
        /* 1. every scan against the others at their current poses (Jacobi step) */
        std::vector<Eigen::Isometry3d> next(n);
        int kept = 0;
        for (size_t i = 0; i < n; i++) {
            Match m = match_to_others(scans, *poses, i, &cfg);
            if (round == 0) rep->fit_before[i] = m.fit_at_start;
            next[i] = m.pose;
            kept += !m.ok;
        }
        /* 2. back into the input's frame: the rigid motion that best aligns the
         *    new positions with the input ones */
        Eigen::Matrix3Xd pos(3, n);
        for (size_t i = 0; i < n; i++) pos.col((Eigen::Index)i) = next[i].translation();
        Eigen::Isometry3d A(Eigen::umeyama(pos, in_pos, false));
        double moved = 0;
        for (size_t i = 0; i < n; i++) {
            next[i] = A * next[i];
            moved = std::max(moved, (next[i].translation() - (*poses)[i].translation()).norm());
        }
        *poses = next;
        rep->moved_m.push_back(moved);
        rep->rounds = round + 1;
        rep->kept = kept;
        if (progress) progress(round + 1, moved, user);
        if (moved < cfg.stop_m) break;
    }
    /* 3. how good: one more evaluation round, nothing moved */
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
