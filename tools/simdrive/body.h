/* The car's body on the terrain: the base pose in 3-D at any time, and its
 * derivatives (for the IMU, GNSS velocity and ground truth).
 *
 * The four tyre contacts (wheelbase, tracks from the vehicle file) sit on the
 * terrain; their heights give the base origin's height (mean of the rear contacts)
 * and the chassis pitch and roll. The sprung body then pitches under braking and
 * acceleration and rolls out of curves: a damped second-order response (1.5 Hz,
 * damping 0.5, a passenger car's suspension) to the steady-state angles
 * pitch = -pitch_gain * a and roll = roll_gain * kappa v^2 (1.5 deg/g, 4.5 deg/g),
 * integrated once over the whole drive (body_model_init) and read back with cubic
 * Hermite interpolation, so attitude, rate and angular acceleration stay continuous.
 * Derivatives are central differences over BODY_DT: exact to O(dt^2), far below
 * sensor noise, and they stay true to whatever the pose function does. */
#ifndef SIM_BODY_H
#define SIM_BODY_H

#include "pb_vehicle.h"
#include "terrain.h"
#include "trajectory.h"

#define BODY_PITCH_GAIN 0.0027  /* rad per m/s^2 of longitudinal acceleration (1.5 deg/g) */
#define BODY_ROLL_GAIN 0.0080   /* rad per m/s^2 of lateral acceleration (4.5 deg/g) */

#define BODY_FREQ_HZ 1.5
#define BODY_DAMPING 0.5

typedef struct {
    const terrain_t *terrain;
    const trajectory_t *traj;
    const pb_vehicle_t *veh;
    int n;                      /* samples of the body motion, at traj->dt */
    double *ang;                /* per sample: roll, roll rate, pitch, pitch rate (rad, rad/s) */
} body_model_t;

/* Integrates the body's pitch and roll over the drive (set terrain, traj, veh first). */
void body_model_init(body_model_t *m);
void body_model_free(body_model_t *m);

typedef struct {
    traj_state_t st;        /* the planar drive (route arc length, speed, curvature) */
    double p[3];            /* base origin in map */
    double R[9];            /* map <- base, row-major */
    double q[4];            /* the same, w x y z */
    double v[3];            /* velocity of the base origin, map */
    double w[3];            /* angular velocity, base */
    double roll, pitch;     /* ZYX angles of R (yaw = st.yaw) */
} body_state_t;

/* Pose only (cheap: per LiDAR column). */
void body_pose(const body_model_t *m, double t, body_state_t *out);
/* Pose with velocity and angular velocity. */
void body_eval(const body_model_t *m, double t, body_state_t *out);
/* Specific force (m/s^2, gravity included) and angular rate at a point r of base,
 * both in base: the ideal IMU before its mounting rotation. */
void body_imu(const body_model_t *m, double t, const double r[3], double f[3], double w[3]);

#endif
