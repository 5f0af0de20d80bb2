/* pb_body: the sample points on a staged agent's body whose visibility OCCLUSION
 * reports (feet, knees, hips, hands, shoulders and head of a pedestrian; corners,
 * sides and roof of a vehicle). One definition for the occlusion module and for
 * simdrive's OCCLUSION_TRUTH, so both report the same points in the same order.
 * Ownership: plain functions; the caller owns the arrays. */
#ifndef PB_BODY_H
#define PB_BODY_H

#ifdef __cplusplus
extern "C" {
#endif

#define PB_BODY_MAX_SAMPLES 16

/* Sample points (map frame, metres) of an agent of `kind` ("pedestrian", "cyclist",
 * "vehicle", "object"; anything else is treated as "object") standing at pos (its
 * origin on the ground) with heading yaw (rad, CCW from +x). x, y, z need room for
 * PB_BODY_MAX_SAMPLES. Returns the number of samples. */
int pb_body_samples(const char *kind, const double pos[3], double yaw, float *x, float *y, float *z);

/* Name of sample i of kind (e.g. "left_knee"), for tables and docs. */
const char *pb_body_sample_name(const char *kind, int i);

#ifdef __cplusplus
}
#endif
#endif
