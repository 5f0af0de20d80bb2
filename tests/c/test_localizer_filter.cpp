/* Unit tests of the localizer's ESKF (modules/localizer/core/filter): a car on a
 * 50 m circle at 10 m/s with the IMU on a lever arm, IMU samples from the exact
 * rigid-body motion. */
#include <cmath>

#include "localizer/core/filter.h"
#include "pb_check.h"

using namespace pb_loc;

static const double R0 = 50.0, V = 10.0, W = V / R0, G = 9.80665;

static Eigen::Isometry3d base_pose(double t)
{
    double th = W * t;   /* centre at the origin, car at (R0 cos th, R0 sin th) heading th + 90 deg */
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(th + M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
    T.translation() = Vec3(R0 * std::cos(th), R0 * std::sin(th), 0);
    return T;
}

static Vec3 base_velocity(double t) { return Vec3(-V * std::sin(W * t), V * std::cos(W * t), 0); }

/* Exact IMU sample (imu frame) for base_from_imu. */
static void imu_sample(const Eigen::Isometry3d &bi, double t, Vec3 *acc, Vec3 *gyro)
{
    Eigen::Isometry3d mi = base_pose(t) * bi;
    Vec3 a = -W * W * Vec3(mi.translation().x(), mi.translation().y(), 0);   /* centripetal, toward the centre */
    *acc = mi.rotation().transpose() * (a + Vec3(0, 0, G));
    *gyro = mi.rotation().transpose() * Vec3(0, 0, W);
}

static Eigen::Isometry3d lever()
{
    Eigen::Isometry3d bi = Eigen::Isometry3d::Identity();
    bi.translation() = Vec3(1.2, 0.0, 0.4);
    return bi;
}

static void test_dead_reckoning()
{
    filter_t f;
    filter_create(&f, filter_config_t(), lever());
    filter_reset(&f, 0, base_pose(0), base_velocity(0), Vec3(0, 0, W), 0.1, 0.01, 0.1);
    Vec3 a, g;
    imu_sample(lever(), 0, &a, &g);
    filter_predict_imu(&f, 0, a, g);
    for (int k = 1; k <= 2000; k++) {   /* 10 s at 200 Hz */
        double t = k * 0.005;
        imu_sample(lever(), t, &a, &g);
        filter_predict_imu(&f, int64_t(k) * 5000, a, g);
    }
    Eigen::Isometry3d T = filter_base_pose(&f);
    CHECK((T.translation() - base_pose(10).translation()).norm() < 0.3);
    CHECK((filter_base_velocity(&f) - base_velocity(10)).norm() < 0.1);
    CHECK_NEAR(filter_base_rate(&f).z(), W, 1e-9);
    /* the covariance grew from the start */
    CHECK(filter_base_covariance(&f)(0, 0) > 0.01);
}

static void test_bias_and_pose_updates()
{
    filter_t f;
    filter_create(&f, filter_config_t(), lever());
    filter_reset(&f, 0, base_pose(0), base_velocity(0), Vec3(0, 0, W), 0.1, 0.01, 0.1);
    Vec3 bias(0.08, -0.05, 0.0), a, g;
    Mat6 cov = Mat6::Identity() * 1e-4;
    for (int k = 0; k <= 12000; k++) {   /* 60 s, pose every 0.1 s */
        double t = k * 0.005;
        imu_sample(lever(), t, &a, &g);
        filter_predict_imu(&f, int64_t(k) * 5000, a + bias, g);
        if (k % 20 == 0 && k > 0) filter_update_pose(&f, base_pose(t), cov);
    }
    CHECK_NEAR(f.ba.x(), bias.x(), 0.02);
    CHECK_NEAR(f.ba.y(), bias.y(), 0.02);
    CHECK((filter_base_pose(&f).translation() - base_pose(60).translation()).norm() < 0.02);
    /* a pose 20 m away is far outside the innovation gate; the true one is inside */
    Eigen::Isometry3d wrong = base_pose(60);
    wrong.translation() += Vec3(20, 0, 0);
    CHECK(filter_pose_innovation(&f, wrong, cov, nullptr) > 1000);
    CHECK(filter_pose_innovation(&f, base_pose(60), cov, nullptr) < 20);
}

static void test_speed_and_nhc()
{
    filter_t f;
    filter_create(&f, filter_config_t(), lever());
    /* start with the velocity 2 m/s short and 1 m/s sideways */
    Vec3 v0 = base_velocity(0) * 0.8 + Vec3(1, 0, 0);
    filter_reset(&f, 0, base_pose(0), v0, Vec3(0, 0, W), 0.1, 0.01, 2.0);
    Vec3 a, g;
    for (int k = 0; k <= 400; k++) {   /* 2 s, CAN speed at 50 Hz */
        double t = k * 0.005;
        imu_sample(lever(), t, &a, &g);
        filter_predict_imu(&f, int64_t(k) * 5000, a, g);
        if (k % 4 == 0 && k > 0) filter_update_speed(&f, V);
    }
    Vec3 vb = filter_body_velocity(&f);
    CHECK_NEAR(vb.x(), V, 0.1);
    CHECK_NEAR(vb.y(), 0.0, 0.1);
    CHECK_NEAR(vb.z(), 0.0, 0.1);
}

static void test_constant_velocity_mode()
{
    filter_t f;
    filter_create(&f, filter_config_t(), Eigen::Isometry3d::Identity());
    Eigen::Isometry3d T0 = Eigen::Isometry3d::Identity();
    filter_reset(&f, 0, T0, Vec3(5, 0, 0), Vec3(0, 0, 0), 0.1, 0.01, 0.1);
    filter_predict_cv(&f, 1000000);
    Eigen::Isometry3d T = filter_base_pose(&f);
    CHECK_NEAR(T.translation().x(), 5.0, 1e-9);
    CHECK_NEAR(T.translation().y(), 0.0, 1e-9);
    /* turning, one long step (sparse sweeps) follows the circle: the car of the other
     * tests, 3 s (30 m, 34 degrees) from its exact state; a straight step along the first
     * velocity ends 9 m off the circle */
    filter_t c;
    filter_create(&c, filter_config_t(), Eigen::Isometry3d::Identity());
    filter_reset(&c, 0, base_pose(0), base_velocity(0), Vec3(0, 0, W), 0.1, 0.01, 0.1);
    filter_predict_cv(&c, 3000000);
    CHECK((filter_base_pose(&c).translation() - base_pose(3).translation()).norm() < 1e-6);
    CHECK((filter_base_velocity(&c) - base_velocity(3)).norm() < 1e-6);
    CHECK_NEAR(std::atan2(filter_base_pose(&c).linear()(1, 0), filter_base_pose(&c).linear()(0, 0)),
               std::atan2(base_pose(3).linear()(1, 0), base_pose(3).linear()(0, 0)), 1e-9);
    /* a pose update moves the state toward the measurement and shrinks the covariance */
    double before = f.P(0, 0);
    Eigen::Isometry3d M = T;
    M.translation().x() += 0.2;
    double d2 = filter_update_pose(&f, M, Mat6::Identity() * 1e-4);
    CHECK(d2 > 0);
    CHECK(filter_base_pose(&f).translation().x() > 5.15);
    CHECK(f.P(0, 0) < before);
    /* non-finite measurements are refused, the state untouched */
    Eigen::Isometry3d bad = M;
    bad.translation().x() = NAN;
    double x = filter_base_pose(&f).translation().x();
    CHECK(filter_update_pose(&f, bad, Mat6::Identity() * 1e-4) < 0);
    CHECK_NEAR(filter_base_pose(&f).translation().x(), x, 0);
}

int main()
{
    test_dead_reckoning();
    test_bias_and_pose_updates();
    test_speed_and_nhc();
    test_constant_velocity_mode();
    return pb_check_report("test_localizer_filter");
}
