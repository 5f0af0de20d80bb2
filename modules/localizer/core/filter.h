/* filter: error-state Kalman filter (ESKF) of the vehicle's motion for the localizer.
 *
 * Nominal state: position p and velocity v of the IMU in `map`, orientation q
 * (map <- imu), accelerometer and gyro biases. Error state (15): dp, dv, dtheta
 * (local, right-multiplied), dba, dbg. The IMU frame is the filter's body because
 * its kinematics are exact there (the specific force is measured at the IMU, not at
 * the base origin); base <- imu converts on the way in and out.
 *
 *   predict_imu     one IMU sample (specific force, rate; imu frame)
 *   predict_cv      no IMU: constant velocity and turn rate (LiDAR-only mode)
 *   update_pose     a base pose in map from scan matching, 6x6 covariance
 *   update_speed    CAN speed as forward speed of the base origin plus the
 *                   non-holonomic constraint (no sideways speed; the vertical is left
 *                   free, as the body pitches on its suspension)
 *   update_position a position of a point fixed on the vehicle (GNSS antenna); the
 *                   pipeline does not fuse GNSS yet (it uses it to start and to check)
 *
 * Time is the caller's (message utimes). No I/O, no allocation after create.
 * Ownership: plain value type; copy it to predict ahead without touching the original. */
#ifndef LOC_FILTER_H
#define LOC_FILTER_H

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>

namespace pb_loc {

typedef Eigen::Matrix<double, 15, 15> Mat15;
typedef Eigen::Matrix<double, 6, 6> Mat6;
typedef Eigen::Matrix<double, 3, 1> Vec3;

struct filter_config_t {
    double accel_noise = 0.05;       /* m/s^2 / sqrt(Hz)-ish: white noise per sample scaled by dt */
    double gyro_noise = 0.005;       /* rad/s */
    double accel_bias_walk = 1e-3;   /* m/s^2 per sqrt(s) */
    double gyro_bias_walk = 1e-5;    /* rad/s per sqrt(s) */
    double gravity = 9.80665;
    /* LiDAR-only (constant velocity) process noise */
    double cv_accel_noise = 2.0;     /* m/s^2: how fast the speed may change between scans */
    double cv_yaw_accel_noise = 1.0; /* rad/s^2 */
    /* CAN speed: forward speed sigma, and the non-holonomic constraint sigma */
    double speed_sigma = 0.05;       /* m/s */
    double nhc_sigma = 0.05;         /* m/s sideways */
    double speed_scale = 1.0;        /* CAN speed reads this times the true speed */
};

struct filter_t {
    filter_config_t cfg;
    Eigen::Isometry3d base_from_imu = Eigen::Isometry3d::Identity();
    /* nominal state */
    int64_t utime = 0;
    Vec3 p = Vec3::Zero(), v = Vec3::Zero();
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    Vec3 ba = Vec3::Zero(), bg = Vec3::Zero();
    Mat15 P = Mat15::Identity();
    /* last bias-corrected rate and specific force (imu frame), for outputs and CAN */
    Vec3 omega = Vec3::Zero(), accel = Vec3::Zero();
    bool initialized = false;
};

/* Sets up a filter with config and extrinsics (not yet initialized). */
void filter_create(filter_t *f, const filter_config_t &cfg, const Eigen::Isometry3d &base_from_imu);

/* Starts at a base pose with the base origin's velocity (map), the angular rate
 * (imu frame; moves the velocity to the IMU on its lever arm) and diagonal sigmas. */
void filter_reset(filter_t *f, int64_t utime, const Eigen::Isometry3d &map_from_base, const Vec3 &v_base_map,
                  const Vec3 &omega_imu, double pos_sigma, double yaw_sigma, double vel_sigma);

/* IMU predict to utime with the sample (imu frame). dt is taken from f->utime; a
 * non-positive dt only records the sample. */
void filter_predict_imu(filter_t *f, int64_t utime, const Vec3 &accel, const Vec3 &gyro);

/* Constant-velocity predict (no IMU): keeps v and the last omega. */
void filter_predict_cv(filter_t *f, int64_t utime);

/* Fuses a measured base pose. Returns the squared Mahalanobis distance of the innovation
 * (6 dof), or -1 if the update was not applied (non-finite input). */
double filter_update_pose(filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov);
/* The same without the translation along dir (unit, map frame): a match whose sweep does
 * not fix the position that way (a tunnel) says nothing there, not even "where the
 * prediction was" (a prior the registration held it to). */
double filter_update_pose_except(filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov,
                                 const Vec3 &dir);

/* Mahalanobis distance squared of a base-pose measurement without applying it. */
double filter_pose_innovation(const filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov,
                              Eigen::Matrix<double, 6, 1> *residual);

/* Fuses the CAN forward speed of the base origin (m/s, along base x) with the
 * non-holonomic constraint (no sideways speed). Returns the squared Mahalanobis
 * distance (2 dof). */
double filter_update_speed(filter_t *f, double speed_mps);

/* Outputs: base pose, base-origin velocity in map, angular rate in base. */
Eigen::Isometry3d filter_base_pose(const filter_t *f);
Vec3 filter_base_velocity(const filter_t *f);
/* The base origin's velocity in base (forward, left, up). */
Vec3 filter_body_velocity(const filter_t *f);
Vec3 filter_base_rate(const filter_t *f);
/* 6x6 covariance over (x, y, z, roll, pitch, yaw) of the base, approximated from P. */
Mat6 filter_base_covariance(const filter_t *f);

} // namespace pb_loc
#endif
