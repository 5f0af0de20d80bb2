/* score: a map's points against the simulated world (simdrive --surface-distance).
 *
 * Each point's distance to the static world of the grid's day (world_distance), and
 * whether it lies on a road user that moved through the drive:
 *   on a moving object  farther than SCORE_STATIC_M from the static world, and within
 *                       SCORE_MARGIN_M of a road user's box (opposite-lane traffic, and
 *                       the lead car, crossing cars and pedestrians when switched on) as
 *                       the LiDAR saw it at some sweep of the drive, and nearer to that
 *                       box than to the static world, and not under the ground (road
 *                       users stand on it: a road point placed a few centimetres low
 *                       lies as near to a wheel's box bottom as to the road). The
 *                       boxes are placed as lidar.c
 *                       places them (at each sweep's start and end, interpolated), at
 *                       steps of at most SCORE_STEP_M of the box's motion.
 *   on the own body     (roof returns switched on) the same rule with the car's own body
 *                       box (the vehicle file's length, width and height about base) at
 *                       the same times, for points not on a moving object.
 * The road users are a pure function of (world, seed, the car's trajectory), so the
 * score must be given the drive's own options (seed, duration, speed profile, --with,
 * driver spread, dwells, reverse) to know the drive's road users.
 * Ownership: plain function; reads FILE, prints one JSON line on stdout, and, when
 * labels_path is given, writes there one byte per point (SCORE_LABEL_*), in FILE's order. */
#ifndef SIM_SCORE_H
#define SIM_SCORE_H

#include "body.h"
#include "pb_err.h"
#include "pb_route.h"
#include "pb_vehicle.h"
#include "trajectory.h"
#include "world.h"

#define SCORE_STATIC_M 0.05    /* on the static world: never counted on a mover */
#define SCORE_MARGIN_M 0.2     /* the beam's footprint, noise and the map's pose error */
#define SCORE_STEP_M 0.1       /* a box's motion between two placements (< the margin) */

enum {                         /* --surface-labels: one byte per point */
    SCORE_LABEL_STATIC = 0,    /* within SCORE_STATIC_M of the static world */
    SCORE_LABEL_OFF = 1,       /* farther, on no road user and not the own body */
    SCORE_LABEL_MOVING = 2,    /* on a moving object (the rule above) */
    SCORE_LABEL_OWN_BODY = 3   /* on the car's own body */
};

typedef struct {
    const world_t *world;          /* grid built for the day scored */
    const pb_route_t *route;
    const body_model_t *body;      /* the car's body on its trajectory */
    const pb_vehicle_t *veh;
    double duration;               /* s: the drive's sweeps start in [0, duration) */
    uint64_t seed;
    int traffic;                   /* 0: the mapping day (no road users) */
} score_drive_t;

/* Scores the points of `path` (float32 x y z, the site's frame) against the drive;
 * labels_path: NULL, or a file to write the points' labels to.
 * 0, or -1 with err set (file unreadable or not writable, size not a multiple of 12, out
 * of memory). */
int score_surface_distance(const score_drive_t *drv, const char *path, const char *labels_path, pb_err_t *err);

#endif
