/* Staged agents and the analytic OCCLUSION_TRUTH of simdrive (--scenario).
 *
 * The agents of a scenario file are run by the director's core against the
 * drive's ground truth (AGENTS at ~33 Hz, as the director publishes them), the
 * participant's head is simulated (--head: HEAD_POSE at 100 Hz, a head moving
 * around the seat's eye point; otherwise no HEAD_POSE and the seat's eye), and at
 * the end of every LiDAR sweep OCCLUSION_TRUTH gives, for every sample point of
 * every agent (common/pb_body), whether the straight segment from the eye to it
 * meets the world (static objects, the traffic at that instant, the ground):
 * state hidden with the distance to the first surface, else visible. On a site
 * with terrain the agents stand on the true height field (the director's core with
 * the terrain's raster as its ground model) and the eye rides the body's 3-D pose.
 *
 * Ownership: sim_occ_create keeps pointers to route, vehicle and world (they must
 * outlive it); sim_occ_destroy frees the rest. */
#ifndef SIM_OCCLUSION_TRUTH_H
#define SIM_OCCLUSION_TRUTH_H

#include <stdint.h>
#include "pb_err.h"
#include "pb_log.h"
#include "pb_route.h"
#include "pb_vehicle.h"
#include "body.h"
#include "world.h"

typedef struct sim_occ sim_occ_t;

sim_occ_t *sim_occ_create(const char *scenario_path, const pb_route_t *route, const pb_vehicle_t *veh,
                          const world_t *world, int head, uint64_t seed, pb_err_t *err);
void sim_occ_destroy(sim_occ_t *so);

/* A ground-truth pose of the body (on the terrain): advances the agents; writes
 * HEAD_POSE (with --head) and, every third pose, AGENTS. */
void sim_occ_pose(sim_occ_t *so, const body_state_t *b, int64_t utime, pb_log_out_t *out);

/* OCCLUSION_TRUTH for the instant t (the end of a sweep). */
void sim_occ_truth(sim_occ_t *so, const body_state_t *b, int64_t utime, pb_log_out_t *out);

#endif
