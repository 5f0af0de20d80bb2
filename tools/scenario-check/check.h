/* scenario-check core: checks a loaded scenario against its site's route and the
 * car: volumes used by enter conditions that the car's footprint never touches
 * along the route ("off the route"), arrival-synchronised agents that cannot
 * reach their marks in time, behaviours never started, unused volumes.
 * Pure: findings go to a callback as (is_error, file, line, message). */
#ifndef CHECK_H
#define CHECK_H

#include "pb_route.h"
#include "director/core/scenario.h"

typedef struct { double length, width, height, rear_overhang; } check_vehicle_t;
typedef void (*check_report_fn)(int is_error, const char *file, int line, const char *msg, void *user);

/* Returns the number of errors reported (warnings are not counted). */
int check_scenario(const sc_scenario_t *sc, const pb_route_t *r, const check_vehicle_t *veh, check_report_fn fn, void *user);

#endif
