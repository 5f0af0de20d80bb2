/* The drive day's other road users and the car's own body, each a group switched on
 * with `simdrive --with` (all off by default: the figures of the other tests stay
 * as they were):
 *   lead        a lead car in the car's own lane (world.yaml `lead_car:`). It drives
 *               the route with its own speed and stops, and the car follows it
 *               (Intelligent Driver Model: Treiber, Hennecke, Helbing 2000) and stops
 *               behind it, then moves up to the stop line: the car's speed curve is no
 *               longer the planner's own.
 *   crossing    cars crossing the route at junctions (world.yaml `crossers:` of kind car)
 *   pedestrians people walking sidewalks and crosswalks (`crossers:` of kind pedestrian):
 *               LiDAR-visible bodies, unlike the director's virtual agents
 *   roof        returns from the car's own body (two boxes from the vehicle file's
 *               dimensions: the lower body and the cabin); whether a beam reaches them
 *               depends on the LiDAR's mount
 * Crossers walk or drive a polyline once per period (seed-dependent phase), and yield:
 * a pass is delayed while the car or the lead car would be on its way. Everything is a
 * pure function of (world, seed, the car's trajectory), so a seed gives the same drive. */
#ifndef SIM_ACTORS_H
#define SIM_ACTORS_H

#include <stdint.h>
#include "pb_config.h"
#include "pb_err.h"
#include "pb_route.h"
#include "pb_vehicle.h"
#include "trajectory.h"
#include "world.h"

#define ACTORS_MAX_CROSSERS 32
#define ACTORS_MAX_PATH 8
#define ACTORS_MAX_PASSES 512

enum { ACT_LEAD = 1, ACT_CROSSING = 2, ACT_PEDESTRIANS = 4, ACT_ROOF = 8 };

typedef struct {
    int pedestrian;             /* 0: a car (absent between passes), 1: a pedestrian (waits at the end) */
    uint8_t cls;
    double size[3], z0, speed, period_s;
    int npath;
    double path[ACTORS_MAX_PATH][2];
    double length;              /* of the path, m */
    int npass;
    double pass_t[ACTORS_MAX_PASSES];   /* start of each pass, s (after yielding) */
} crosser_t;

typedef struct actors_s {
    unsigned on;                /* ACT_* groups switched on */
    /* lead car (world.yaml lead_car:) */
    int has_lead;
    uint8_t lead_cls;
    double lead_size[3], lead_z0, lead_rear_overhang, lead_gap_m, lead_cruise_factor, lead_spread, lead_dwell[2];
    trajectory_t lead;          /* its drive (s counts from the route start, like the car's) */
    int ncross;
    crosser_t cross[ACTORS_MAX_CROSSERS];
    uint8_t body_cls;           /* class of the car's own body (roof returns) */
    int yielded;                /* passes delayed by yielding (reported) */
} actors_t;

/* Reads world.yaml's lead_car: and crossers: (either may be NULL) into A. */
int actors_load(actors_t *A, const world_t *w, const pb_cfg_node_t *lead, const pb_cfg_node_t *crossers, pb_err_t *err);
/* Switches groups on from a comma-separated list; -1 with the known names in err. */
int actors_switch_on(actors_t *A, const char *list, pb_err_t *err);
void actors_free(actors_t *A);

/* With the lead car on: plans the car's drive behind it (replaces traj_plan's result
 * in ego, same fields) and the lead car's own drive. front_m: base origin to the car's
 * front bumper; stop_offset_m as traj_plan's. */
int actors_plan_follow(actors_t *A, trajectory_t *ego, const pb_route_t *r, const pb_speed_profile_t *p,
                       double duration, double front_m, double stop_offset_m, const traj_driver_t *drv,
                       uint64_t seed, pb_err_t *err);
/* Times the crossers' passes over [0, duration] around the car (and lead car). */
void actors_schedule(actors_t *A, const pb_route_t *r, const trajectory_t *ego, const pb_vehicle_t *veh,
                     double duration, uint64_t seed);
/* Appends the movers present at time t (lead car, crossers) to out (room for max). */
int actors_movers(const actors_t *A, const world_t *w, double t, mover_t *out, int max);

/* Range (m, from the beam origin) at which each beam of a LiDAR at base <- lidar hits
 * the car's own body, INFINITY where it does not: rows*cols entries, index r*cols+c. */
void actors_body_ranges(const pb_vehicle_t *veh, const float *alt, const float *az, float origin_m, int rows,
                        int cols, double *range);

#endif
