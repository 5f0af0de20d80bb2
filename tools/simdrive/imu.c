/* IMU: rigid-body kinematics of the lever arm plus the error model. */
#include "imu.h"

#include "rng.h"


void imu_sim_init(imu_sim_t *im, const pb_vehicle_t *v, uint64_t seed)
{
    for (int i = 0; i < 3; i++) {
        im->accel_bias[i] = v->accel_bias * rng_gauss(seed, RNG_IMU_BIAS, 0, (uint64_t)i);
        im->gyro_bias[i] = v->gyro_bias * rng_gauss(seed, RNG_IMU_BIAS, 1, (uint64_t)i);
    }
}

void imu_ideal(const body_model_t *bm, double t, double accel[3], double gyro[3])
{
    /* The lever arm's motion in 3-D (the body on the terrain): specific force and
     * rate in base, then into the imu frame with R_imu^T. At rest on a slope the
     * accelerometer sees gravity tilted by the pitch and roll. */
    const pb_vehicle_t *v = bm->veh;
    double f_base[3], w_base[3];
    body_imu(bm, t, v->base_from_imu.t, f_base, w_base);
    double R[9];
    pb_quat_to_matrix(v->base_from_imu.q, R);
    for (int i = 0; i < 3; i++) {
        accel[i] = R[i] * f_base[0] + R[3 + i] * f_base[1] + R[6 + i] * f_base[2];
        gyro[i] = R[i] * w_base[0] + R[3 + i] * w_base[1] + R[6 + i] * w_base[2];
    }
}

void imu_measure(const imu_sim_t *im, const body_model_t *bm, double t, uint64_t seed, uint64_t k,
                 double accel[3], double gyro[3])
{
    const pb_vehicle_t *v = bm->veh;
    imu_ideal(bm, t, accel, gyro);
    for (int i = 0; i < 3; i++) {
        accel[i] += im->accel_bias[i] + v->accel_noise * rng_gauss(seed, RNG_IMU, k, (uint64_t)i);
        gyro[i] += im->gyro_bias[i] + v->gyro_noise * rng_gauss(seed, RNG_IMU, k, (uint64_t)(3 + i));
    }
}
