/* IMU: rigid-body kinematics of the lever arm plus the error model. */
#include "imu.h"

#include "rng.h"

#define GRAVITY 9.80665

void imu_sim_init(imu_sim_t *im, const pb_vehicle_t *v, uint64_t seed)
{
    for (int i = 0; i < 3; i++) {
        im->accel_bias[i] = v->accel_bias * rng_gauss(seed, RNG_IMU_BIAS, 0, (uint64_t)i);
        im->gyro_bias[i] = v->gyro_bias * rng_gauss(seed, RNG_IMU_BIAS, 1, (uint64_t)i);
    }
}

void imu_ideal(const pb_vehicle_t *v, const traj_state_t *st, double accel[3], double gyro[3])
{
    /* In base (level, yaw only): base origin acceleration a_t along x, kappa v^2 along y.
     * The lever arm r adds alpha x r + omega x (omega x r), with omega = (0, 0, w). */
    const double *r = v->base_from_imu.t;
    double w = st->omega, al = st->alpha;
    double ab[3] = {
        st->a - al * r[1] - w * w * r[0],
        st->kappa * st->v * st->v + al * r[0] - w * w * r[1],
        0.0,
    };
    /* specific force = a - g, with g = (0, 0, -9.81): +9.81 on z at rest */
    double f_base[3] = { ab[0], ab[1], ab[2] + GRAVITY }, w_base[3] = { 0, 0, w };
    /* into the imu frame: R_imu^T */
    double R[9];
    pb_quat_to_matrix(v->base_from_imu.q, R);
    for (int i = 0; i < 3; i++) {
        accel[i] = R[i] * f_base[0] + R[3 + i] * f_base[1] + R[6 + i] * f_base[2];
        gyro[i] = R[i] * w_base[0] + R[3 + i] * w_base[1] + R[6 + i] * w_base[2];
    }
}

void imu_measure(const imu_sim_t *im, const pb_vehicle_t *v, const traj_state_t *st, uint64_t seed, uint64_t k,
                 double accel[3], double gyro[3])
{
    imu_ideal(v, st, accel, gyro);
    for (int i = 0; i < 3; i++) {
        accel[i] += im->accel_bias[i] + v->accel_noise * rng_gauss(seed, RNG_IMU, k, (uint64_t)i);
        gyro[i] += im->gyro_bias[i] + v->gyro_noise * rng_gauss(seed, RNG_IMU, k, (uint64_t)(3 + i));
    }
}
