/* The drive: a speed profile planned along the route (accel / decel / lateral
 * acceleration limits, a stop with a seed-dependent dwell at every stop line),
 * then smoothed in time so that acceleration is continuous and jerk bounded.
 * Evaluated at any time, it gives the base pose and its derivatives. */
#ifndef SIM_TRAJECTORY_H
#define SIM_TRAJECTORY_H

#include <stdint.h>
#include "pb_err.h"
#include "pb_route.h"

typedef struct {
    const pb_route_t *route;
    double dt;          /* sample period of the profile, s */
    int n;              /* samples */
    double *v, *s;      /* speed (m/s) and distance travelled (m) at k*dt */
    double t_end;       /* last time with a valid profile, s */
    int stops_made;     /* stops planned within t_end */
    double reverse_t0, reverse_t1;  /* the gear is R in [t0, t1) (both 0: no reversing) */
} trajectory_t;

typedef struct {
    double t;           /* s since start */
    double dist;        /* distance travelled, m */
    double v, a;        /* speed (m/s) and tangential acceleration (m/s^2) of the base origin */
    double x, y, yaw;   /* base pose in map (z = 0, level) */
    double kappa;       /* path curvature, 1/m */
    double omega;       /* yaw rate, rad/s */
    double alpha;       /* yaw acceleration, rad/s^2 */
} traj_state_t;

/* A human driver's variation from stop to stop (0: the planner's own curve).
 * For each leg ending at a stop, three factors are drawn uniformly in
 * [1 - spread, 1 + spread] per seed: the cruise speed, the deceleration of the
 * main braking, and the braking point (where braking from cruise begins, relative to
 * the nominal v^2 / 2 decel). Braking then runs in two phases: the main one down to
 * half the cruise speed, and a final one whose deceleration makes the car stop at
 * the line anyway (harder when the driver braked late, softer when early). */
typedef struct {
    double spread;
    const double *dwells;   /* may be NULL: the rest at the first ndwells stops met, s */
    int ndwells;
    /* reverse_m > 0: at the first stop met after reverse_after_s (and at least reverse_m + 5 m
     * into the route) the driver shifts to R, backs reverse_m along the route at
     * TRAJ_REVERSE_MPS, stops, shifts to D, drives back to the stop line, then dwells */
    double reverse_m, reverse_after_s;
} traj_driver_t;

#define TRAJ_REVERSE_MPS 2.5     /* reversing speed (9 km/h, a parking manoeuvre) */
#define TRAJ_REVERSE_ACCEL 1.0   /* m/s^2, speeding up and slowing down in the manoeuvre */

/* Plans a drive from rest at the start of the route. duration > 0: long enough
 * for duration seconds (laps repeat). duration <= 0: exactly one lap, ending at
 * rest at the start point (the mapping drive). stop_offset_m: how far behind a
 * stop line the base origin halts (front bumper at the line). driver (may be NULL:
 * the planner's own curve); its dwells are the rest at the first ndwells stops met, in
 * seconds (>= 1.5, so the car comes to rest within the smoothing window); the others
 * are drawn from the seed. */
int traj_plan(trajectory_t *tr, const pb_route_t *r, const pb_speed_profile_t *p, double duration,
              double stop_offset_m, const traj_driver_t *driver, uint64_t seed, pb_err_t *err);
void traj_free(trajectory_t *tr);
void traj_eval(const trajectory_t *tr, double t, traj_state_t *st);

#endif
