/* Unit tests of the mapper's GNSS anchoring (modules/mapper/core/anchor): antenna positions
 * on a 200 m arc, fixes = a known transform of them plus noise, some of them jumps. */
#include <cmath>
#include <random>
#include <vector>

#include "mapper/core/anchor.h"
#include "pb_check.h"

using Vec3 = Eigen::Vector3d;

static Eigen::Isometry3d truth()
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = (Eigen::AngleAxisd(1.1, Vec3::UnitZ()) * Eigen::AngleAxisd(0.02, Vec3::UnitX())).toRotationMatrix();
    T.translation() = Vec3(12.0, -7.0, 3.0);
    return T;
}

static std::vector<pb_anchor_obs_t> make_obs(int n, double radius, double noise, int jumps)
{
    std::mt19937 rng(3);
    std::normal_distribution<double> g(0, noise);
    std::vector<pb_anchor_obs_t> obs;
    for (int i = 0; i < n; i++) {
        double a = 2.0 * i / n;   /* radians along the arc */
        pb_anchor_obs_t o;
        o.antenna_map = Vec3(radius * std::sin(a), radius * (1 - std::cos(a)), 0.02 * i);
        o.fix_enu = truth() * o.antenna_map + Vec3(g(rng), g(rng), 2 * g(rng));
        if (i % (n / std::max(1, jumps)) == 7 && jumps > 0) o.fix_enu += Vec3(25, -10, 0);   /* multipath jump */
        o.h_acc_m = noise;
        o.fix_3d = 1;
        obs.push_back(o);
    }
    return obs;
}

static void test_fit_with_outliers()
{
    std::vector<pb_anchor_obs_t> obs = make_obs(300, 100, 1.0, 5);
    obs[10].fix_3d = 0;          /* a 2-D fix: gated */
    obs[11].h_acc_m = 50;        /* a receiver that says it does not know: gated */
    pb_anchor_result_t r;
    pb_err_t err;
    if (CHECK_OK(pb_anchor_fit(obs, nullptr, &r, &err), err.msg)) return;
    CHECK(r.anchored == 1);
    CHECK(r.gated == 2);
    CHECK(r.rejected == 5);
    CHECK(r.used == 300 - 2 - 5);
    Eigen::Isometry3d d = truth().inverse() * r.enu_from_map;
    double yaw_err = std::fabs(std::atan2(d.linear()(1, 0), d.linear()(0, 0))) * 180 / M_PI;
    std::printf("anchoring: %.3f m, %.4f deg off the truth; residual median %.2f m\n", d.translation().norm(), yaw_err, r.resid_median_m);
    /* measured: 0.147 m, 0.142 deg (1 m of noise a horizontal axis, 2 m vertical, on 293 fixes
     * along 200 m) */
    CHECK(d.translation().norm() < 0.45);
    CHECK(yaw_err < 0.45);
    CHECK(r.resid_median_m > 0.5 && r.resid_median_m < 3);
}

static void test_refusals()
{
    pb_anchor_result_t r;
    pb_err_t err;
    std::vector<pb_anchor_obs_t> few = make_obs(5, 100, 1.0, 0);
    CHECK(pb_anchor_fit(few, nullptr, &r, &err) == 0 && r.anchored == 0);
    CHECK_CONTAINS(r.why, "too few");
    std::vector<pb_anchor_obs_t> standing = make_obs(100, 5, 1.0, 0);   /* a car that barely moved */
    CHECK(pb_anchor_fit(standing, nullptr, &r, &err) == 0 && r.anchored == 0);
    CHECK_CONTAINS(r.why, "span");
    std::vector<pb_anchor_obs_t> none;
    CHECK(pb_anchor_fit(none, nullptr, &r, &err) == -1);
    CHECK_CONTAINS(err.msg, "no GNSS fix");
}

int main()
{
    test_fit_with_outliers();
    test_refusals();
    return pb_check_report("test_mapper_anchor");
}
