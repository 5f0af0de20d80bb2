/* deskew: moves each point of a sweep to where it would have been seen at one
 * reference time, given the vehicle's motion during the sweep.
 *
 * Motion model: constant linear velocity v (m/s) and angular velocity w (rad/s),
 * both expressed in `base` at the reference time (what the filter estimates). A
 * point measured dt = t_i - t_ref seconds later, at p (base frame at t_i), is
 *   p_ref = R(w dt) p + v dt        (first order in the small rotation w dt,
 *                                     exact rotation via the exponential map).
 * Points are in `base` (move lidar points with base<-lidar first).
 *
 * Ownership: operates in place on caller arrays; no allocation, no state. */
#ifndef PB_LOC_DESKEW_H
#define PB_LOC_DESKEW_H

#include <stddef.h>
#include <stdint.h>

/* xyz: n points interleaved (float, base frame), modified in place.
 * offset_us: per-point time after the scan utime (pb_points_t.offset_us).
 * ref_offset_us: the reference time as an offset from the scan utime (0 = sweep
 * start; the scan's pose then refers to the scan utime).
 * v, w: base-frame linear (m/s) and angular (rad/s) velocity. */
void pb_deskew(float *xyz, const int32_t *offset_us, size_t n, int32_t ref_offset_us,
               const double v[3], const double w[3]);

#endif
