/* lv_plan: one leg of the lab drive, from rest at one arc length to rest at a
 * later one (the next stop line, or the end of the drive).
 *
 * The twin cannot plan the whole drive ahead (it waits at every stop line for
 * the participant), so it plans each leg when it departs. A leg is planned the
 * way simdrive plans its road drive (tools/simdrive/trajectory.c): a speed limit
 * along the route from the profile's cruise speed and lateral acceleration,
 * forward / backward passes for the acceleration and deceleration limits, a time
 * profile, then two 0.5 s box filters so acceleration is continuous and jerk
 * bounded. Unlike simdrive, the end point is exact: the grid ends on the target
 * and the distance is rescaled to it, so the car rests where asked (1e-9 m).
 *
 * Ownership: lv_leg_t is a plain struct the caller owns; lv_leg_plan allocates
 * its arrays, lv_leg_free releases them (a zeroed leg may be freed). */
#ifndef LV_PLAN_H
#define LV_PLAN_H

#include "pb_err.h"
#include "pb_route.h"

#define LV_PLAN_DT 0.002    /* s, grid of the time profile */
#define LV_BOX_S 0.5        /* s, width of each of the two box filters */

typedef struct {
    double d0, length;  /* start (unwrapped arc length, m) and length of the leg, m */
    double dt;          /* sample period, s */
    int n;              /* samples; the car is at rest at sample 0 and sample n-1 */
    double *v, *s;      /* speed (m/s) and distance from d0 (m) at k*dt */
    double t_end;       /* (n-1)*dt: when the car comes to rest at d0+length */
} lv_leg_t;

/* Plans a leg from rest at d0 to rest at d0+length (length > 0). The car starts
 * to move right at t = 0 (the smoothing window is padded with rest). 0 or -1. */
int lv_leg_plan(lv_leg_t *leg, const pb_route_t *r, const pb_speed_profile_t *p, double d0, double length,
                pb_err_t *err);
void lv_leg_free(lv_leg_t *leg);
/* Distance from d0 (m), speed (m/s) and acceleration (m/s^2) at t s after departure
 * (clamped to [0, t_end]). */
void lv_leg_eval(const lv_leg_t *leg, double t, double *s, double *v, double *a);

#endif
