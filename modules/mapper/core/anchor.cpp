/* anchor: see anchor.h. */
#include "anchor.h"

#include <algorithm>
#include <cmath>

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
        if (obs[i].fix_3d && obs[i].h_acc_m > 0 && obs[i].h_acc_m <= cfg.max_h_acc_m && obs[i].antenna_map.allFinite() &&
            obs[i].fix_enu.allFinite())
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
