/* director: the scenario runtime (pure core: no I/O, time only from message utimes).
 *
 * Each vehicle pose (POSE from the localizer or the lab twin, or GROUND_TRUTH)
 * advances the scenario: trigger conditions are evaluated against the car's
 * oriented footprint (libccd), fired triggers run their actions, agents walk
 * their paths (arrival-synchronised ones re-timed from the car's predicted
 * arrival at a stop line), virtual collisions are detected. Events go to a
 * callback; the agents' state is read with dir_agents.
 *
 * Ownership: dir_create keeps a pointer to the scenario and the route (both must
 * outlive the director); dir_destroy frees the director only. */
#ifndef DIR_DIRECTOR_H
#define DIR_DIRECTOR_H

#include <stddef.h>
#include <stdint.h>

#include "pb_err.h"
#include "pb_ground.h"
#include "pb_route.h"
#include "scenario.h"

typedef struct {
    double length, width, height, rear_overhang;   /* the car's box (vehicle file), m */
} dir_vehicle_t;

typedef struct {
    int64_t utime;
    double pos[3];          /* base origin in map */
    double q[4];            /* w, x, y, z: map <- base */
    double vel[3];          /* map, m/s */
} dir_pose_t;

typedef struct {
    int64_t utime;
    const char *kind;           /* "trigger", "action", "collision", "warning", "mark" */
    char event_id[112];
    char agent_id[SC_ID_LEN];
    dir_pose_t vehicle;
    double agent_pos[3];
    char detail[320];
} dir_event_t;

typedef void (*dir_event_fn)(const dir_event_t *ev, void *user);

typedef struct {
    const char *id, *kind, *model;
    double pos[3], yaw, vel[3];
    const char *animation;
    float phase;
    int in_range;
    float distance_m;
} dir_agent_out_t;

typedef struct director director_t;

director_t *dir_create(const sc_scenario_t *sc, const pb_route_t *route, const dir_vehicle_t *veh,
                       dir_event_fn on_event, void *user, pb_err_t *err);
void dir_destroy(director_t *d);
/* The site's ground model (borrowed; NULL: the plane z = 0). Agents' feet and paths
 * are put on it, and every trigger volume's heights count from the ground at the
 * volume's centre (a volume z 0..3 on a road 12 m up spans 12..15 m); the car's
 * box is placed by its pose in 3-D. Where the model is unknown, the ground is z = 0. */
void dir_set_ground(director_t *d, const pb_ground_t *ground);

/* Advances to the pose's time and evaluates everything. Returns 0, or -1 if the
 * pose was refused (not finite, or older than the previous one: err says why). */
int dir_pose(director_t *d, const dir_pose_t *p, pb_err_t *err);
/* A participant input; it counts at the next pose at or after its utime. */
void dir_input(director_t *d, int64_t utime, const char *input, int value);
/* Moves the agents to time t without a new pose (AGENTS between poses). */
void dir_tick(director_t *d, int64_t t);
/* POSE stale (or missing): synchronised behaviours hold their agents still until
 * poses return. An event (kind warning) reports each change. */
void dir_set_stale(director_t *d, int stale, int64_t utime, double age_s);
int dir_is_stale(const director_t *d);
int dir_has_pose(const director_t *d);
int64_t dir_time(const director_t *d);

/* The agents now (n = scenario agents; out has room for them). */
int dir_agents(const director_t *d, dir_agent_out_t *out);
int dir_triggers_fired(const director_t *d);

/* Recovery: the state as text (fired triggers, agents mid-behaviour), and back.
 * dir_state_write returns the length written (< cap), or -1 if cap is too small.
 * dir_state_read refuses a state of another scenario; after it, no fired trigger
 * fires again and rising edges start from the next pose. 0 or -1. */
int dir_state_write(const director_t *d, char *buf, size_t cap);
int dir_state_read(director_t *d, const char *text, pb_err_t *err);

/* Predicted time (s) until a car at distance d (m, along the route) with speed v
 * (m/s) and longitudinal acceleration a (m/s^2) comes to rest, braking at `decel`
 * if it is not braking yet and easing off the brake for `ease` s at the end;
 * INFINITY when stopped short of the line. */
double dir_predict_arrival(double d, double v, double a, double decel, double ease);

#endif
