/* pb_math: small rigid-body helpers (quaternions w,x,y,z; 3x3 row-major). */
#ifndef PB_MATH_H
#define PB_MATH_H

#include <math.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* floor(v) as an integer without a libm call: x86-64 without SSE4.1 has no floor
 * instruction, and GCC's floor there is some 20 instructions, a tenth of a hot loop's.
 * |v| < 2^63 is the caller's to check. */
static inline int64_t pb_floor_i64(double v)
{
    int64_t i = (int64_t)v;
    return i - (v < (double)i);
}

/* floor(a / b) for b != 0 (C division truncates towards zero) */
static inline int64_t pb_floor_div(int64_t a, int64_t b)
{
    int64_t q = a / b;
    return q - (a % b != 0 && ((a < 0) != (b < 0)));
}

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
