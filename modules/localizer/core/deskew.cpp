/* deskew: constant-velocity motion compensation of a sweep (see deskew.h). */
#include "deskew.h"

#include <Eigen/Geometry>

void pb_deskew(float *xyz, const int32_t *offset_us, size_t n, int32_t ref_offset_us,
               const double v[3], const double w[3])
{
    const Eigen::Vector3d vel(v[0], v[1], v[2]), omega(w[0], w[1], w[2]);
    const double wn = omega.norm();
    /* the motion of the last time seen: a spinning LiDAR's column shares its time, so one
     * rotation serves the whole column */
    int32_t held = ref_offset_us;
    double dt = 0;
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    for (size_t i = 0; i < n; i++) {
        if (offset_us[i] == ref_offset_us) continue;
        if (offset_us[i] != held) {
            held = offset_us[i];
            dt = 1e-6 * (double)(held - ref_offset_us);
            /* pose of base(t_i) in base(t_ref): rotation Exp(w dt), translation v dt */
            R = wn * std::fabs(dt) < 1e-12 ? Eigen::Matrix3d::Identity()
                                           : Eigen::AngleAxisd(wn * dt, omega / wn).toRotationMatrix();
        }
        Eigen::Vector3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
        Eigen::Vector3d q = R * p + vel * dt;
        for (int a = 0; a < 3; a++) xyz[3 * i + a] = (float)q(a);
    }
}
