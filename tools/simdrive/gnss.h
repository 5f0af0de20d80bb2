/* Simulated GNSS receiver: the antenna's position through the site's geo-reference,
 * with a first-order Gauss-Markov horizontal error (correlated over gnss_noise_tau). */
#ifndef SIM_GNSS_H
#define SIM_GNSS_H

#include <stdint.h>
#include "pb_geo.h"
#include "body.h"
#include "pb_vehicle.h"
#include "portobello_gnss_fix_t.h"

typedef struct {
    double err[3];          /* current error east-ish x, y (map), up; m */
    double last_heading;
    int64_t k;              /* fixes so far */
    double dt;
} gnss_sim_t;

void gnss_sim_init(gnss_sim_t *g, const pb_vehicle_t *v, uint64_t seed, double dt);
/* Next fix (call at consecutive dt steps) for the body state b (body_eval). */
void gnss_step(gnss_sim_t *g, const pb_vehicle_t *v, const pb_georef_t *geo, double geoid_height_m,
               const body_state_t *b, uint64_t seed, int64_t utime, portobello_gnss_fix_t *fix);

#endif
