#include "pb_math.h"

void pb_quat_from_rpy(double roll, double pitch, double yaw, double q[4])
{
    /* ZYX: R = Rz(yaw) Ry(pitch) Rx(roll) */
    double cr = cos(roll / 2), sr = sin(roll / 2), cp = cos(pitch / 2), sp = sin(pitch / 2);
    double cy = cos(yaw / 2), sy = sin(yaw / 2);
    q[0] = cr * cp * cy + sr * sp * sy;
    q[1] = sr * cp * cy - cr * sp * sy;
    q[2] = cr * sp * cy + sr * cp * sy;
    q[3] = cr * cp * sy - sr * sp * cy;
}

void pb_quat_to_rpy(const double q[4], double *roll, double *pitch, double *yaw)
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    *roll = atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y));
    double s = 2 * (w * y - z * x);
    *pitch = s >= 1 ? M_PI / 2 : s <= -1 ? -M_PI / 2 : asin(s);
    *yaw = atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z));
}

void pb_quat_to_matrix(const double q[4], double R[9])
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - w * z);     R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);     R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);     R[7] = 2 * (y * z + w * x);     R[8] = 1 - 2 * (x * x + y * y);
}

void pb_matrix_to_quat(const double R[9], double q[4])
{
    double tr = R[0] + R[4] + R[8];
    if (tr > 0) {
        double s = sqrt(tr + 1.0) * 2;
        q[0] = 0.25 * s; q[1] = (R[7] - R[5]) / s; q[2] = (R[2] - R[6]) / s; q[3] = (R[3] - R[1]) / s;
    } else if (R[0] > R[4] && R[0] > R[8]) {
        double s = sqrt(1.0 + R[0] - R[4] - R[8]) * 2;
        q[0] = (R[7] - R[5]) / s; q[1] = 0.25 * s; q[2] = (R[1] + R[3]) / s; q[3] = (R[2] + R[6]) / s;
    } else if (R[4] > R[8]) {
        double s = sqrt(1.0 + R[4] - R[0] - R[8]) * 2;
        q[0] = (R[2] - R[6]) / s; q[1] = (R[1] + R[3]) / s; q[2] = 0.25 * s; q[3] = (R[5] + R[7]) / s;
    } else {
        double s = sqrt(1.0 + R[8] - R[0] - R[4]) * 2;
        q[0] = (R[3] - R[1]) / s; q[1] = (R[2] + R[6]) / s; q[2] = (R[5] + R[7]) / s; q[3] = 0.25 * s;
    }
    if (q[0] < 0) for (int i = 0; i < 4; i++) q[i] = -q[i];
    pb_quat_normalize(q);
}

void pb_quat_mul(const double a[4], const double b[4], double o[4])
{
    double w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    double x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    double y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    double z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    o[0] = w; o[1] = x; o[2] = y; o[3] = z;
}

void pb_quat_rotate(const double q[4], const double v[3], double out[3])
{
    double R[9];
    pb_quat_to_matrix(q, R);
    double x = R[0] * v[0] + R[1] * v[1] + R[2] * v[2];
    double y = R[3] * v[0] + R[4] * v[1] + R[5] * v[2];
    double z = R[6] * v[0] + R[7] * v[1] + R[8] * v[2];
    out[0] = x; out[1] = y; out[2] = z;
}

void pb_quat_normalize(double q[4])
{
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (n > 0) for (int i = 0; i < 4; i++) q[i] /= n;
    else { q[0] = 1; q[1] = q[2] = q[3] = 0; }
}

void pb_transform_compose(const pb_transform_t *a, const pb_transform_t *b, pb_transform_t *out)
{
    double t[3], q[4];
    pb_quat_rotate(a->q, b->t, t);
    for (int i = 0; i < 3; i++) t[i] += a->t[i];
    pb_quat_mul(a->q, b->q, q);
    pb_quat_normalize(q);
    for (int i = 0; i < 3; i++) out->t[i] = t[i];
    for (int i = 0; i < 4; i++) out->q[i] = q[i];
}

void pb_transform_inverse(const pb_transform_t *a, pb_transform_t *out)
{
    double qi[4] = { a->q[0], -a->q[1], -a->q[2], -a->q[3] }, t[3];
    pb_quat_rotate(qi, a->t, t);
    for (int i = 0; i < 3; i++) out->t[i] = -t[i];
    for (int i = 0; i < 4; i++) out->q[i] = qi[i];
}

void pb_transform_apply(const pb_transform_t *a, const double p[3], double out[3])
{
    double r[3];
    pb_quat_rotate(a->q, p, r);
    for (int i = 0; i < 3; i++) out[i] = r[i] + a->t[i];
}

double pb_wrap_angle(double a)
{
    a = fmod(a + M_PI, 2 * M_PI);
    if (a <= 0) a += 2 * M_PI;
    return a - M_PI;
}
