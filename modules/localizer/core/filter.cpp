/* ESKF of the localizer (see filter.h). Error-state formulation after J. Sola,
 * "Quaternion kinematics for the error-state Kalman filter" (2017): local
 * (right-multiplied) attitude error, Joseph-form covariance update. */
#include "filter.h"

#include <cmath>

namespace pb_loc {

enum { IP = 0, IV = 3, ITH = 6, IBA = 9, IBG = 12 };

static Eigen::Matrix3d skew(const Vec3 &v)
{
    Eigen::Matrix3d m;
    m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
    return m;
}

static Eigen::Quaterniond so3_exp(const Vec3 &w)
{
    double a = w.norm();
    if (a < 1e-12) return Eigen::Quaterniond(1, 0.5 * w.x(), 0.5 * w.y(), 0.5 * w.z()).normalized();
    return Eigen::Quaterniond(Eigen::AngleAxisd(a, w / a));
}

static Vec3 so3_log(const Eigen::Quaterniond &q_in)
{
    Eigen::Quaterniond q = q_in.w() < 0 ? Eigen::Quaterniond(-q_in.w(), -q_in.x(), -q_in.y(), -q_in.z()) : q_in;
    Vec3 v(q.x(), q.y(), q.z());
    double s = v.norm();
    if (s < 1e-12) return 2.0 * v;
    double a = 2.0 * std::atan2(s, q.w());
    return v * (a / s);
}

void filter_create(filter_t *f, const filter_config_t &cfg, const Eigen::Isometry3d &base_from_imu)
{
    *f = filter_t();
    f->cfg = cfg;
    f->base_from_imu = base_from_imu;
}

void filter_reset(filter_t *f, int64_t utime, const Eigen::Isometry3d &map_from_base, const Vec3 &v_base_map,
                  const Vec3 &omega_imu, double pos_sigma, double yaw_sigma, double vel_sigma)
{
    Eigen::Isometry3d mi = map_from_base * f->base_from_imu;
    f->utime = utime;
    f->p = mi.translation();
    f->q = Eigen::Quaterniond(mi.rotation()).normalized();
    f->omega = omega_imu;
    /* v_imu = v_base + omega x lever (both in map) */
    f->v = v_base_map + (mi.rotation() * omega_imu).cross(map_from_base.rotation() * f->base_from_imu.translation());
    f->P.setZero();
    f->P.block<3, 3>(IP, IP).diagonal() << pos_sigma * pos_sigma, pos_sigma * pos_sigma, pos_sigma * pos_sigma;
    f->P.block<3, 3>(IV, IV).diagonal().setConstant(vel_sigma * vel_sigma);
    /* roll and pitch from a level start are good to a degree; yaw as told */
    double rp = 0.02;
    f->P.block<3, 3>(ITH, ITH).diagonal() << rp * rp, rp * rp, yaw_sigma * yaw_sigma;
    f->P.block<3, 3>(IBA, IBA).diagonal().setConstant(0.05 * 0.05);
    f->P.block<3, 3>(IBG, IBG).diagonal().setConstant(0.002 * 0.002);
    f->initialized = true;
}

void filter_predict_imu(filter_t *f, int64_t utime, const Vec3 &accel, const Vec3 &gyro)
{
    Vec3 am = accel - f->ba, wm = gyro - f->bg;
    f->omega = wm;
    f->accel = am;
    if (!f->initialized) { f->utime = utime; return; }
    double dt = (utime - f->utime) * 1e-6;
    if (dt <= 0) return;
    Eigen::Matrix3d R = f->q.toRotationMatrix();
    Vec3 g(0, 0, -f->cfg.gravity);
    Vec3 a = R * am + g;
    f->p += f->v * dt + 0.5 * a * dt * dt;
    f->v += a * dt;
    Eigen::Quaterniond dq = so3_exp(wm * dt);
    f->q = (f->q * dq).normalized();

    Mat15 F = Mat15::Identity();
    F.block<3, 3>(IP, IV) = Eigen::Matrix3d::Identity() * dt;
    F.block<3, 3>(IV, ITH) = -R * skew(am) * dt;
    F.block<3, 3>(IV, IBA) = -R * dt;
    F.block<3, 3>(ITH, ITH) = dq.toRotationMatrix().transpose();
    F.block<3, 3>(ITH, IBG) = -Eigen::Matrix3d::Identity() * dt;
    Mat15 Q = Mat15::Zero();
    const filter_config_t &c = f->cfg;
    Q.block<3, 3>(IV, IV).diagonal().setConstant(c.accel_noise * c.accel_noise * dt);
    Q.block<3, 3>(ITH, ITH).diagonal().setConstant(c.gyro_noise * c.gyro_noise * dt);
    Q.block<3, 3>(IBA, IBA).diagonal().setConstant(c.accel_bias_walk * c.accel_bias_walk * dt);
    Q.block<3, 3>(IBG, IBG).diagonal().setConstant(c.gyro_bias_walk * c.gyro_bias_walk * dt);
    f->P = F * f->P * F.transpose() + Q;
    f->utime = utime;
}

void filter_predict_cv(filter_t *f, int64_t utime)
{
    if (!f->initialized) { f->utime = utime; return; }
    double dt = (utime - f->utime) * 1e-6;
    if (dt <= 0) return;
    Eigen::Quaterniond q0 = f->q;
    f->q = (f->q * so3_exp(f->omega * dt)).normalized();
    /* a car's velocity turns with it (constant turn rate), and its position follows the
     * arc: the chord, turned by half the turn and sin(a/2)/(a/2) of the arc's length. A
     * straight step along the old velocity leaves a curve by metres between sparse sweeps
     * (MulRan keyframes 3 s apart in a 35 degree turn: 5 m) */
    Vec3 turn = f->omega * dt;
    double half = 0.5 * turn.norm();
    double chord = half > 1e-9 ? std::sin(half) / half : 1.0;
    f->p += (q0 * so3_exp(0.5 * turn) * (q0.conjugate() * f->v)) * (chord * dt);
    f->v = f->q * (q0.conjugate() * f->v);
    Mat15 F = Mat15::Identity();
    F.block<3, 3>(IP, IV) = Eigen::Matrix3d::Identity() * dt;
    Mat15 Q = Mat15::Zero();
    const filter_config_t &c = f->cfg;
    /* white-noise acceleration over the step: the position spreads within it too, so one
     * long step (sparse or skipped sweeps) is as uncertain as many short ones */
    const double qa = c.cv_accel_noise * c.cv_accel_noise;
    Q.block<3, 3>(IP, IP).diagonal().setConstant(qa * dt * dt * dt / 3);
    Q.block<3, 3>(IP, IV).diagonal().setConstant(qa * dt * dt / 2);
    Q.block<3, 3>(IV, IP).diagonal().setConstant(qa * dt * dt / 2);
    Q.block<3, 3>(IV, IV).diagonal().setConstant(qa * dt);
    Q.block<3, 3>(ITH, ITH).diagonal().setConstant(c.cv_yaw_accel_noise * c.cv_yaw_accel_noise * dt * dt * dt);
    f->P = F * f->P * F.transpose() + Q;
    f->utime = utime;
}

/* Generic update: residual r (m), H (m x 15), noise Rn. Returns r' S^-1 r or -1. */
template <int M>
static double kf_update(filter_t *f, const Eigen::Matrix<double, M, 1> &r, const Eigen::Matrix<double, M, 15> &H,
                        const Eigen::Matrix<double, M, M> &Rn, bool apply)
{
    if (!r.allFinite() || !Rn.allFinite()) return -1;
    Eigen::Matrix<double, M, M> S = H * f->P * H.transpose() + Rn;
    Eigen::LDLT<Eigen::Matrix<double, M, M>> ldlt(S);
    if (ldlt.info() != Eigen::Success) return -1;
    double d2 = r.dot(ldlt.solve(r));
    if (!apply) return d2;
    Eigen::Matrix<double, 15, M> K = ldlt.solve(H * f->P).transpose();
    Eigen::Matrix<double, 15, 1> dx = K * r;
    Mat15 IKH = Mat15::Identity() - K * H;
    f->P = IKH * f->P * IKH.transpose() + K * Rn * K.transpose();
    f->P = 0.5 * (f->P + f->P.transpose());
    f->p += dx.segment<3>(IP);
    f->v += dx.segment<3>(IV);
    f->q = (f->q * so3_exp(dx.segment<3>(ITH))).normalized();
    f->ba += dx.segment<3>(IBA);
    f->bg += dx.segment<3>(IBG);
    return d2;
}

static void pose_residual(const filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov,
                          Eigen::Matrix<double, 6, 1> *r, Eigen::Matrix<double, 6, 15> *H, Mat6 *Rn)
{
    Eigen::Isometry3d mi = map_from_base * f->base_from_imu;
    Eigen::Quaterniond qm(mi.rotation());
    r->segment<3>(0) = mi.translation() - f->p;
    r->segment<3>(3) = so3_log(f->q.conjugate() * qm);
    H->setZero();
    H->block<3, 3>(0, IP).setIdentity();
    H->block<3, 3>(3, ITH).setIdentity();
    /* covariance: map-frame angles into the filter's local attitude error */
    Eigen::Matrix3d Rt = f->q.toRotationMatrix().transpose();
    *Rn = cov;
    Rn->block<3, 3>(3, 3) = Rt * cov.block<3, 3>(3, 3) * Rt.transpose();
    Rn->block<3, 3>(0, 3) = cov.block<3, 3>(0, 3) * Rt.transpose();
    Rn->block<3, 3>(3, 0) = Rn->block<3, 3>(0, 3).transpose();
}

double filter_update_pose(filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov)
{
    Eigen::Matrix<double, 6, 1> r;
    Eigen::Matrix<double, 6, 15> H;
    Mat6 Rn;
    pose_residual(f, map_from_base, cov, &r, &H, &Rn);
    return kf_update<6>(f, r, H, Rn, true);
}

double filter_update_pose_except(filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov,
                                 const Vec3 &dir)
{
    Eigen::Matrix<double, 6, 1> r;
    Eigen::Matrix<double, 6, 15> H;
    Mat6 Rn;
    pose_residual(f, map_from_base, cov, &r, &H, &Rn);
    /* the residual in the two translations across dir and the three rotations */
    Vec3 a = dir.normalized(), b = a.unitOrthogonal(), c = a.cross(b);
    Eigen::Matrix<double, 5, 6> T = Eigen::Matrix<double, 5, 6>::Zero();
    T.block<1, 3>(0, 0) = b.transpose();
    T.block<1, 3>(1, 0) = c.transpose();
    T.block<3, 3>(2, 3).setIdentity();
    Eigen::Matrix<double, 5, 1> r5 = T * r;
    Eigen::Matrix<double, 5, 15> H5 = T * H;
    Eigen::Matrix<double, 5, 5> R5 = T * Rn * T.transpose();
    return kf_update<5>(f, r5, H5, R5, true);
}

double filter_pose_innovation(const filter_t *f, const Eigen::Isometry3d &map_from_base, const Mat6 &cov,
                              Eigen::Matrix<double, 6, 1> *residual)
{
    Eigen::Matrix<double, 6, 1> r;
    Eigen::Matrix<double, 6, 15> H;
    Mat6 Rn;
    pose_residual(f, map_from_base, cov, &r, &H, &Rn);
    if (residual) *residual = r;
    return kf_update<6>(const_cast<filter_t *>(f), r, H, Rn, false);
}

double filter_update_speed(filter_t *f, double speed_mps)
{
    if (!f->initialized || !std::isfinite(speed_mps)) return -1;
    Eigen::Matrix3d R = f->q.toRotationMatrix();
    Eigen::Matrix3d Rbi = f->base_from_imu.rotation();
    Vec3 r_bi = f->base_from_imu.translation();
    Vec3 u = R.transpose() * f->v;                       /* IMU velocity, imu frame */
    Vec3 vb = Rbi * u - (Rbi * f->omega).cross(r_bi);    /* base origin velocity, base frame */
    /* forward speed and no sideways speed; not "no vertical speed": the body pitches on
     * its suspension when the car speeds up or brakes (squat, dive), so its own z axis
     * sees a share of the speed (0.5 deg at 14 m/s is 0.12 m/s), and taking it for 0
     * pulled the height 2-4 cm off on every grade */
    Eigen::Matrix<double, 2, 1> r(speed_mps / f->cfg.speed_scale - vb.x(), -vb.y());
    Eigen::Matrix<double, 3, 15> J = Eigen::Matrix<double, 3, 15>::Zero();
    J.block<3, 3>(0, IV) = Rbi * R.transpose();
    J.block<3, 3>(0, ITH) = Rbi * skew(u);
    Eigen::Matrix<double, 2, 15> H = J.topRows<2>();
    Eigen::Matrix2d Rn = Eigen::Matrix2d::Zero();
    Rn.diagonal() << f->cfg.speed_sigma * f->cfg.speed_sigma, f->cfg.nhc_sigma * f->cfg.nhc_sigma;
    return kf_update<2>(f, r, H, Rn, true);
}

Eigen::Isometry3d filter_base_pose(const filter_t *f)
{
    Eigen::Isometry3d mi = Eigen::Isometry3d::Identity();
    mi.linear() = f->q.toRotationMatrix();
    mi.translation() = f->p;
    return mi * f->base_from_imu.inverse();
}

Vec3 filter_base_velocity(const filter_t *f)
{
    Eigen::Matrix3d R = f->q.toRotationMatrix();
    Eigen::Isometry3d mb = filter_base_pose(f);
    Vec3 lever = mb.rotation() * f->base_from_imu.translation();   /* base -> imu, map frame */
    return f->v - (R * f->omega).cross(lever);
}

Vec3 filter_body_velocity(const filter_t *f)
{
    return filter_base_pose(f).linear().transpose() * filter_base_velocity(f);
}

Vec3 filter_base_rate(const filter_t *f) { return f->base_from_imu.rotation() * f->omega; }

Mat6 filter_base_covariance(const filter_t *f)
{
    Mat6 c = Mat6::Zero();
    Eigen::Matrix3d R = f->q.toRotationMatrix();
    c.block<3, 3>(0, 0) = f->P.block<3, 3>(IP, IP);
    c.block<3, 3>(3, 3) = R * f->P.block<3, 3>(ITH, ITH) * R.transpose();
    c.block<3, 3>(0, 3) = f->P.block<3, 3>(IP, ITH) * R.transpose();
    c.block<3, 3>(3, 0) = c.block<3, 3>(0, 3).transpose();
    return c;
}

} // namespace pb_loc
