/* Simulated IMU: specific force and angular rate at the IMU's lever arm, with a
 * per-drive constant bias and white noise (vehicle file's simulation block). */
#ifndef SIM_IMU_H
#define SIM_IMU_H

#include <stdint.h>
#include "body.h"
#include "pb_vehicle.h"

typedef struct {
    double accel_bias[3], gyro_bias[3];     /* imu frame, drawn once per seed */
} imu_sim_t;

void imu_sim_init(imu_sim_t *im, const pb_vehicle_t *v, uint64_t seed);
/* Ideal (noise-free, bias-free) measurement at time t: accel (m/s^2) and gyro (rad/s), imu frame. */
void imu_ideal(const body_model_t *bm, double t, double accel[3], double gyro[3]);
/* Measurement number k at time t (noise keyed by k). */
void imu_measure(const imu_sim_t *im, const body_model_t *bm, double t, uint64_t seed, uint64_t k,
                 double accel[3], double gyro[3]);

#endif
