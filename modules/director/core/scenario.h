/* scenario: a study scenario file (YAML in a site's scenarios/ folder), read
 * strictly with pb_config. Volumes, agents, behaviours (paths) and triggers
 * (OpenSCENARIO-style conditions grouped AND-within / OR-across, with edge and
 * delay, and the actions they start). Every id is resolved at load time: an
 * unknown id, a duplicate id, a value out of range or an unknown key fails with
 * "FILE:LINE: what", and nothing is returned half-loaded.
 * docs/scenarios.md documents the format.
 *
 * Ownership: sc_load fills a caller-owned sc_scenario_t whose arrays it
 * allocates; the caller frees them with sc_free. The route passed to sc_load is
 * only read during the call (stop-line ids and positions are copied). */
#ifndef SC_SCENARIO_H
#define SC_SCENARIO_H

#include "pb_err.h"
#include "pb_route.h"

#define SC_ID_LEN 48
#define SC_MAX_PRISM_PTS 16

typedef enum { SC_VOL_BOX, SC_VOL_CYLINDER, SC_VOL_PRISM } sc_vol_type_t;

typedef struct {
    char id[SC_ID_LEN];
    int line;
    sc_vol_type_t type;
    double center[2], yaw;          /* box, cylinder: map, m / rad */
    double size[3];                 /* box: length (along yaw), width, height */
    double radius;                  /* cylinder */
    int npts;                       /* prism: convex polygon in map, CCW or CW */
    double pts[SC_MAX_PRISM_PTS][2];
    double z[2];                    /* bottom and top, m (box and cylinder: z0, z0 + height) */
    double bound_c[2], bound_r;     /* bounding circle in map (broad phase) */
} sc_volume_t;

typedef enum {
    SC_COND_ENTER,          /* the car's footprint (oriented box) touches a volume */
    SC_COND_DISTANCE,       /* distance from the footprint to a point / stop line below or above */
    SC_COND_TTA,            /* time to arrival (distance / speed) at a point / stop line below */
    SC_COND_SPEED,          /* speed above / below */
    SC_COND_STANDSTILL,     /* speed < 0.1 m/s for at least duration_s */
    SC_COND_AFTER,          /* another trigger fired at least delay_s ago */
    SC_COND_INPUT,          /* a PARTICIPANT_INPUT press (value != 0) of that name */
    SC_COND_TIME,           /* seconds since the first pose of the drive above */
} sc_cond_type_t;

typedef enum { SC_EDGE_NONE, SC_EDGE_RISING, SC_EDGE_FALLING, SC_EDGE_BOTH } sc_edge_t;

typedef struct {
    sc_cond_type_t type;
    int line, group;            /* group: index of the AND group within the trigger */
    int volume;                 /* ENTER */
    int stop_line;              /* DISTANCE/TTA: index into sc_scenario_t.stops, -1 = point */
    double point[2];
    int has_below, has_above;
    double below, above;        /* thresholds (m, s or m/s) */
    double duration_s;          /* STANDSTILL */
    int after_trigger;          /* AFTER: trigger index */
    double after_s;
    char input[32];             /* INPUT */
    sc_edge_t edge;
    double delay_s;
} sc_cond_t;

typedef enum { SC_ACT_START, SC_ACT_STOP, SC_ACT_ANIMATE, SC_ACT_PLACE, SC_ACT_EMIT } sc_act_type_t;

typedef struct {
    sc_act_type_t type;
    int line;
    int behaviour, agent;       /* START/STOP: behaviour; ANIMATE/PLACE: agent */
    char name[SC_ID_LEN];       /* ANIMATE: animation; EMIT: event name */
    double xy[2], yaw;          /* PLACE */
} sc_action_t;

typedef struct {
    char id[SC_ID_LEN];
    int line;
    int ngroups, nconds, nactions;
    sc_cond_t *conds;
    sc_action_t *actions;
} sc_trigger_t;

typedef enum { SC_SHAPE_CYLINDER, SC_SHAPE_BOX } sc_shape_t;

typedef struct {
    char id[SC_ID_LEN], kind[16], model[SC_ID_LEN];
    int line;
    double xy[2], yaw;          /* start pose in map */
    sc_shape_t shape;
    double radius, height;      /* cylinder (pedestrians, default 0.3 x 1.8 m) */
    double size[3];             /* box: length, width, height */
} sc_agent_t;

typedef struct {
    double xy[2];
    double speed;               /* m/s on the leg that ends here */
    double wait_s;              /* pause here */
    char gesture[SC_ID_LEN];    /* animation while waiting ("idle" if none) */
    int line;
} sc_waypoint_t;

typedef struct {
    char id[SC_ID_LEN];
    int line, agent;
    int npts;
    sc_waypoint_t *pts;
    /* Arrival synchronisation: reach waypoint `mark` when the car comes to rest
     * at stop line `sync_stop`, re-timing the walk within [speed_min, speed_max]. */
    int sync, sync_mark, sync_stop;
    double speed_min, speed_max, sync_decel, sync_ease;
} sc_behaviour_t;

typedef struct {
    char id[SC_ID_LEN], crosswalk[32];
    double xy[2], s;            /* on the route: s of the line itself */
} sc_stop_t;

typedef enum { SC_JUMP_SKIP, SC_JUMP_FIRE } sc_jump_policy_t;

typedef struct {
    char path[1024];
    char id[SC_ID_LEN];
    char description[256];
    double render_distance_m;   /* default 45 */
    double jump_m;              /* a pose step longer than this is a jump (default 3 m) */
    sc_jump_policy_t on_jump;   /* default skip */
    double stop_gap_m;          /* the car rests with its front bumper this far behind a stop line (0.5) */
    int nvolumes, nagents, nbehaviours, ntriggers, nstops;
    sc_volume_t *volumes;
    sc_agent_t *agents;
    sc_behaviour_t *behaviours;
    sc_trigger_t *triggers;
    sc_stop_t *stops;           /* the route's stop lines (copied) */
} sc_scenario_t;

/* Loads path. route may be NULL (then stop_line references fail). 0 or -1. */
int sc_load(const char *path, const pb_route_t *route, sc_scenario_t *sc, pb_err_t *err);
void sc_free(sc_scenario_t *sc);

/* Index of the item with that id, or -1. */
int sc_find_volume(const sc_scenario_t *sc, const char *id);
int sc_find_agent(const sc_scenario_t *sc, const char *id);
int sc_find_behaviour(const sc_scenario_t *sc, const char *id);
int sc_find_trigger(const sc_scenario_t *sc, const char *id);

/* Length of a behaviour's path from the agent's position p0 to waypoint `upto` (inclusive). */
double sc_path_length(const sc_behaviour_t *b, const double p0[2], int upto);

#endif
