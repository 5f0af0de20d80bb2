/* pb_math: small rigid-body helpers (quaternions w,x,y,z; 3x3 row-major). */
#ifndef PB_MATH_H
#define PB_MATH_H

#include <math.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    double t[3];    /* translation, metres */
    double q[4];    /* rotation as unit quaternion w, x, y, z */
} pb_transform_t;

void pb_quat_from_rpy(double roll, double pitch, double yaw, double q[4]);
void pb_quat_to_rpy(const double q[4], double *roll, double *pitch, double *yaw);
void pb_quat_to_matrix(const double q[4], double R[9]);
void pb_matrix_to_quat(const double R[9], double q[4]);
void pb_quat_mul(const double a[4], const double b[4], double out[4]);
void pb_quat_rotate(const double q[4], const double v[3], double out[3]);
void pb_quat_normalize(double q[4]);
/* out = a * b (apply b first) */
void pb_transform_compose(const pb_transform_t *a, const pb_transform_t *b, pb_transform_t *out);
void pb_transform_inverse(const pb_transform_t *a, pb_transform_t *out);
void pb_transform_apply(const pb_transform_t *a, const double p[3], double out[3]);
/* Wraps an angle to (-pi, pi]. */
double pb_wrap_angle(double a);

#ifdef __cplusplus
}
#endif
#endif
