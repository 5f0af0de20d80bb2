/* The vehicle file (vehicles/NAME.yaml): dimensions, sensor extrinsics, sensor error model. */
#ifndef SIM_VEHICLE_H
#define SIM_VEHICLE_H

#include "pb_err.h"
#include "pb_math.h"

typedef struct {
    char name[64], dbc[256], lidar_model[32];
    double length, width, height, wheelbase, track_front, track_rear, rear_overhang;
    double lidar_xyz[3], lidar_rpy_deg[3], imu_xyz[3], imu_rpy_deg[3], gnss_xyz[3], gnss_rpy_deg[3];
    double imu_rate_hz, accel_noise, gyro_noise, accel_bias, gyro_bias;
    double lidar_range_noise, lidar_dropout, lidar_max_range, gnss_noise, gnss_noise_tau;
    pb_transform_t base_from_lidar, base_from_imu;  /* derived */
} vehicle_t;

int vehicle_load(const char *path, vehicle_t *v, pb_err_t *err);

#endif
