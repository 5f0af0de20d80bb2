/* lab_vehicle: the in-lab twin of the study car (the pure core: no I/O; time only
 * from the caller's utimes).
 *
 * The twin drives the site's route with a speed profile. At every stop line it
 * comes to rest with its front bumper stop_gap_m behind the line (where simdrive's
 * road car rests), asks for the participant's "proceed" (event awaiting_proceed),
 * and departs once a proceed press arrived and the crosswalk ahead is clear of
 * staged agents. Each leg between stops is planned at departure (lv_plan.h).
 *
 * Use: lv_create, then per tick lv_step(utime) -> pose, lv_on_input / lv_on_agents
 * as messages arrive, lv_next_event to drain what happened.
 * Ownership: lv_create copies the config; the route is borrowed and must outlive
 * the lab_vehicle_t; lv_destroy frees it (NULL is a no-op). */
#ifndef LAB_VEHICLE_H
#define LAB_VEHICLE_H

#include <stdint.h>
#include "pb_err.h"
#include "pb_route.h"

typedef struct {
    int profile;                /* PB_PROFILE_* (default normal) */
    double base_to_front_m;     /* rear-axle origin to front bumper: length - rear_overhang (default Prius 3.50) */
    double stop_gap_m;          /* front bumper behind the stop line at rest (default 0.5, as simdrive) */
    double start_s;             /* arc length where the drive starts, at rest (default 0) */
    double depart_delay_s;      /* rest at the start before moving off (default 1.0, as simdrive) */
    int laps;                   /* > 0: end at rest at the start point after this many laps; 0: drive on */
    char proceed_input[32];     /* PARTICIPANT_INPUT.input that releases the car (default "proceed") */
    double crossing_margin_m;   /* the crosswalk area grows by this along the road, both sides; also the
                                   depth of the kerb zone beyond each end (default 1.0) */
    double crossing_horizon_s;  /* agents whose straight path enters the crossing within this hold the car (default 2.0) */
    double agents_timeout_s;    /* AGENTS older than this are stale: hold (default 1.0) */
    int require_agents;         /* 1: hold at a crossing until AGENTS have been received (default 0) */
    int ignore_objects;         /* 1: agents of kind "object" never block a crossing (default 1) */
} lv_config_t;

typedef enum {
    LV_STATE_STARTING,          /* at rest at the start, before depart_delay_s */
    LV_STATE_DRIVING,
    LV_STATE_AWAIT_PROCEED,     /* at rest at a stop line, no proceed yet */
    LV_STATE_AWAIT_CLEAR,       /* proceed given, crossing not clear (or AGENTS stale) */
    LV_STATE_FINISHED,          /* at rest at the end of the drive */
} lv_state_t;
extern const char *const lv_state_names[];

typedef struct {
    int64_t utime;
    double x, y, yaw;           /* base (rear-axle centre, ground) in map */
    double v, a;                /* speed, tangential acceleration of the base origin */
    double omega;               /* yaw rate, rad/s */
    double dist;                /* unwrapped arc length (start_s + distance driven), m */
    double route_s;             /* arc length on the loop, [0, length) */
    lv_state_t state;
} lv_pose_t;

/* What happened, in order. ids: "awaiting_proceed", "proceed", "crossing_occupied",
 * "agents_stale", "agents_missing", "crossing_clear", "departed", "finished". */
typedef struct {
    int64_t utime;
    char id[32];
    char stop_line[32], crosswalk[32];
    char agent_id[64];          /* the blocking agent, "" if none */
    double agent_xy[2];
    char detail[256];
} lv_event_t;

/* One agent of AGENTS as the crossing check needs it (map frame). */
typedef struct {
    const char *id, *kind;
    double x, y;
    double vx, vy;              /* m/s */
} lv_agent_t;

/* Result of lv_on_input. */
enum { LV_INPUT_ACCEPTED = 0, LV_INPUT_OTHER, LV_INPUT_RELEASE, LV_INPUT_NOT_WAITING, LV_INPUT_EARLY };
extern const char *const lv_input_results[];

typedef struct lab_vehicle lab_vehicle_t;

void lv_config_default(lv_config_t *cfg);
/* Checks the config against the route; NULL with err on bad values. */
lab_vehicle_t *lv_create(const pb_route_t *route, const lv_config_t *cfg, pb_err_t *err);
void lv_destroy(lab_vehicle_t *lv);

/* Advances to utime (not before the previous one) and fills *pose. The first call
 * sets the start time. 0, or -1 (err) if utime goes back or a leg cannot be planned. */
int lv_step(lab_vehicle_t *lv, int64_t utime, lv_pose_t *pose, pb_err_t *err);

/* The crossing is held by an agent (not of kind "object" when ignore_objects) that is
 * on the crosswalk (widened along the road by crossing_margin_m), that stands (under
 * 0.3 m/s) in the kerb zone within crossing_margin_m beyond either end (about to
 * cross), or whose straight-line path at its current velocity enters the crosswalk
 * within crossing_horizon_s. Someone walking along the sidewalk past the end holds
 * nothing. */

/* A PARTICIPANT_INPUT (press time utime). A proceed press (value != 0) is accepted
 * only while the car waits at a stop line and not stamped before it came to rest. */
int lv_on_input(lab_vehicle_t *lv, int64_t utime, const char *input, int32_t value);

/* An AGENTS message received at recv_utime (the staleness clock). Agents with
 * non-finite positions make the message invalid: -1 (err), the previous one stays. */
int lv_on_agents(lab_vehicle_t *lv, int64_t recv_utime, const lv_agent_t *agents, int n, pb_err_t *err);

/* Pops the oldest pending event into *ev: 1, or 0 when none. */
int lv_next_event(lab_vehicle_t *lv, lv_event_t *ev);

lv_state_t lv_state(const lab_vehicle_t *lv);
/* Arc length (unwrapped) where the base origin rests at stop line k on lap 0. */
double lv_stop_target(const lab_vehicle_t *lv, int k);

#endif
