/* Health checks: whether a pose is right (structure fit, GNSS agreement) and the match
 * covariance floor (see docs/localizer.md "Divergence test"). */
#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Eigenvalues>

#include "localizer_impl.h"

namespace pb_loc {

Vec3 antenna_map(const localizer_t *L, const Eigen::Isometry3d &map_from_base)
{
    return map_from_base * L->ex.base_from_gnss.translation();
}

bool fix_fresh(const localizer_t *L, int64_t t)
{
    return L->has_fix && std::llabs(t - L->fix.utime) < 500000;
}

double gnss_gate(const localizer_t *L, double h_acc)
{
    double g = L->cfg.gnss_gate_k * (std::isfinite(h_acc) ? h_acc : 0.0);
    return g > L->cfg.gnss_gate_min_m ? g : L->cfg.gnss_gate_min_m;
}

/* Distance of a pose's antenna from the latest fix, extrapolated by the pose's velocity. */
double candidate_gnss_residual(const localizer_t *L, const Eigen::Isometry3d &pose, const Vec3 &vel, int64_t t)
{
    if (!fix_fresh(L, t)) return NAN;
    Vec3 a = antenna_map(L, pose) + vel * ((L->fix.utime - t) * 1e-6);
    return std::hypot(L->fix_map.x() - a.x(), L->fix_map.y() - a.y());
}

/* The GNSS receiver's clock against the other sensors' (pb_clock_offset.h): its offset is
 * reported once (and again when it changes) and returned, to be subtracted from every fix
 * time. */
int64_t gnss_clock_offset(localizer_t *L, int64_t fix_utime, outputs_t *out)
{
    if (pb_clock_offset_add(&L->gnss_clock, fix_utime, L->newest_t)) {
        if (L->gnss_clock.offset != 0)
            event(out, "gnss_clock_offset", "GNSS_FIX: the receiver's clock is %+.2f s off the other sensors; "
                  "fix times corrected by that", L->gnss_clock.offset * 1e-6);
        else
            event(out, "gnss_clock_offset", "GNSS_FIX: the receiver's clock agrees with the other sensors again");
    }
    return L->gnss_clock.offset;
}

/* Structure test (see localizer.h): share of the points above the local ground that lie
 * on the map's surfaces at pose, or NaN when the sweep has too little structure to judge.
 * "Above the ground" is measured from the map's ground below each point, so crests, sags
 * and banked roads do not turn the road surface into structure; where the map has no
 * ground under a point, from the base plane. */
double structure_inliers(localizer_t *L, const Eigen::Isometry3d &pose)
{
    L->above.clear();
    size_t n = L->xyz.size() / 3, stride = n > 4000 ? n / 4000 : 1;   /* a sample is enough to judge */
    const double hmin = L->cfg.structure_min_z_m, r2min = L->cfg.reg.min_range_m * L->cfg.reg.min_range_m;
    for (size_t k = 0; k < n; k += stride) {
        const float *p = &L->xyz[3 * k];
        if (double(p[0]) * p[0] + double(p[1]) * p[1] < r2min) continue;   /* the car itself */
        Vec3 q = pose * Vec3(p[0], p[1], p[2]);
        double gz;
        double h = pb_regmap_ground_z(L->map, q.x(), q.y(), q.z(), 6.0, 1, &gz) ? q.z() - gz : p[2];
        if (h <= hmin) continue;
        L->above.insert(L->above.end(), p, p + 3);
    }
    if (L->above.size() / 3 < size_t(L->cfg.structure_min_points)) return NAN;
    /* even out the density (near points would dominate) like the registration does */
    pb_reg_downsample(L->above.data(), L->above.size() / 3, &L->cfg.reg, &L->above_ds);
    if (L->above_ds.size() / 3 < size_t(L->cfg.structure_min_points / 3)) return NAN;
    return pb_reg_structure_fit(L->map, L->above_ds.data(), L->above_ds.size() / 3, pose, L->cfg.reg.inlier_m,
                                L->cfg.structure_rough_m);
}

/* The best structure fit of the sweep's points of the last structure_inliers (L->above_ds)
 * 1 or 2 m along, 1 m across or 3 degrees turned from pose. */
static double structure_probe_max(const localizer_t *L, const Eigen::Isometry3d &pose)
{
    static const double probe[8][3] = {   /* along (m), across (m), turn (deg) in the car's frame */
        {1, 0, 0}, {-1, 0, 0}, {2, 0, 0}, {-2, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 3}, {0, 0, -3}};
    double best = 0;
    for (const auto &p : probe) {
        Eigen::Isometry3d q = pose;
        q.translation() += pose.linear() * Vec3(p[0], p[1], 0);
        q.linear() = Eigen::AngleAxisd(p[2] * M_PI / 180, Vec3::UnitZ()) * pose.linear();
        best = std::max(best, pb_reg_structure_fit(L->map, L->above_ds.data(), L->above_ds.size() / 3, q,
                                                   L->cfg.reg.inlier_m, L->cfg.structure_rough_m));
    }
    return best;
}

bool structure_fits(localizer_t *L, const Eigen::Isometry3d &pose, double si, outputs_t *out)
{
    if (!std::isfinite(si) || si >= L->cfg.min_structure_inliers) return true;
    if (si < L->cfg.structure_peak_floor) return false;
    double probe = structure_probe_max(L, pose);
    if (si < L->cfg.structure_peak_ratio * probe) return false;
    event(out, "match_structure_peak", "%.0f%% of the structure above the ground fits the map, %.1f times what fits "
          "1-2 m or 3 deg away: the scene changed, not the pose", 100 * si, probe > 0 ? si / probe : INFINITY);
    return true;
}

/* In a tunnel, or between walls or parapets longer than the LiDAR reaches, the walls and the
 * road fix every direction but the one along them, and a match's covariance (its points'
 * residuals, as if independent) still says centimetres there: the map cells' small errors
 * give the Hessian a little along it (a 272 m simulated tunnel, LiDAR alone: 2-6 cm
 * reported while the pose went 59 m off). A match whose translation Hessian is that
 * ill-conditioned is probed: two registrations started degenerate_probe_m either way along
 * the direction it fixes least (its covariance's longest axis, made horizontal). When
 * either ends more than half of that from the match along it, the sweep does not pull it
 * back: that direction is returned. (A simulated 272 m tunnel: 411 of its 442 such
 * matches; a 156 m bridge between parapets, whose far ends the LiDAR still sees: 2 of 164,
 * both probes back within centimetres on the others.) */
bool match_degenerate(localizer_t *L, const pb_reg_result_t &res, Vec3 *dir)
{
    if (!(res.condition > L->cfg.degenerate_condition) || !std::isfinite(res.condition)) return false;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(res.covariance.topLeftCorner<3, 3>());
    Vec3 v = es.eigenvectors().col(2);
    v.z() = 0;
    if (v.norm() < 0.7) return false;   /* mostly height: not a way along a road */
    v.normalize();
    const double d = L->cfg.degenerate_probe_m;
    for (double s : { -d, d }) {
        Eigen::Isometry3d start = res.pose;
        start.translation() += s * v;
        pb_reg_result_t r;
        pb_err_t err;
        if (pb_reg_align(L->map, L->xyz.data(), L->xyz.size() / 3, start, &L->cfg.reg, &r, &err) >= 0 &&
            r.status != PB_REG_FEW_POINTS && std::fabs((r.pose.translation() - res.pose.translation()).dot(v)) > 0.5 * d) {
            *dir = v;
            return true;
        }
    }
    return false;
}

Mat6 floored(const localizer_t *L, const Mat6 &c)
{
    Mat6 m = c;
    if (!m.allFinite()) m = Mat6::Identity() * 1e-2;
    double ft = L->cfg.pose_sigma_floor_m, fr = L->cfg.pose_sigma_floor_rad;
    for (int i = 0; i < 3; i++) m(i, i) += ft * ft;
    for (int i = 3; i < 6; i++) m(i, i) += fr * fr;
    return m;
}

} // namespace pb_loc
