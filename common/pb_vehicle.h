/* pb_vehicle: the vehicle file (vehicles/NAME.yaml): dimensions, sensor extrinsics
 * (base <- sensor), the DBC of its CAN bus, and the error model simdrive gives its
 * simulated sensors. Read strictly: unknown keys, wrong types and missing required
 * keys fail with file:line. The one reader of vehicle files for every program.
 * Ownership: pb_vehicle_t is a plain struct the caller owns; nothing inside points
 * into the file. */
#ifndef PB_VEHICLE_H
#define PB_VEHICLE_H

#include "pb_err.h"
#include "pb_math.h"

typedef struct {
    char name[64], lidar_model[32];
    char dbc[512];          /* path of the DBC, resolved against the vehicle file's folder; "" if none */
    double length, width, height, wheelbase, track_front, track_rear, rear_overhang;
    double lidar_xyz[3], lidar_rpy_deg[3], imu_xyz[3], imu_rpy_deg[3], gnss_xyz[3], gnss_rpy_deg[3];
    double seat_eye_xyz[3];  /* the driver's eye in base, m (seat: eye_xyz); valid if has_seat_eye */
    int has_seat_eye;
    double imu_rate_hz, accel_noise, gyro_noise, accel_bias, gyro_bias;
    double lidar_range_noise, lidar_dropout, lidar_max_range, gnss_noise, gnss_noise_tau;
    pb_transform_t base_from_lidar, base_from_imu, base_from_gnss;  /* derived */
} pb_vehicle_t;

#ifdef __cplusplus
extern "C" {
#endif

/* Loads path into *v (defaults first for the optional simulation block). 0 or -1. */
int pb_vehicle_load(const char *path, pb_vehicle_t *v, pb_err_t *err);

/* The car's own body in base, margin_m larger on every side: box = xmin, ymin, zmin, xmax,
 * ymax, zmax (base at the rear axle on the ground). Returns from it (a roof the LiDAR mount
 * lets beams reach) are not the world. */
void pb_vehicle_body_box(const pb_vehicle_t *v, double margin_m, double box[6]);

#ifdef __cplusplus
}
#endif

#endif
