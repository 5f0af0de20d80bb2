/* Simulated Ouster OS1-64 (1024 x 10 Hz): one sweep as a range image, every
 * column ray-cast from the sensor pose at that column's time (the car moves
 * during the sweep). Noise is keyed by (seed, scan, pixel), so the output does not
 * depend on the number of threads. */
#ifndef SIM_LIDAR_H
#define SIM_LIDAR_H

#include <stdint.h>
#include "body.h"
#include "pb_vehicle.h"
#include "world.h"
#include "portobello_lidar_scan_t.h"

#define LIDAR_ROWS 64
#define LIDAR_COLS 1024
#define LIDAR_PERIOD_US 100000
#define LIDAR_THREADS 2

typedef struct {
    float alt[LIDAR_ROWS], az[LIDAR_ROWS];   /* rad */
    float origin_m;                           /* beam origin offset from the axis */
    int32_t col_off_us[LIDAR_COLS];
} lidar_model_t;

void lidar_model_os1_64(lidar_model_t *m);

typedef struct {
    const world_t *world;
    const pb_route_t *route;
    const trajectory_t *traj;
    const body_model_t *body;   /* the car's 3-D pose on the terrain */
    const pb_vehicle_t *veh;
    const lidar_model_t *model;
    uint64_t seed;
    int traffic;                /* simulate moving traffic */
    const double *body_range;   /* per pixel, range to the car's own body (actors_body_ranges); NULL: not seen */
    uint8_t body_cls;
    uint32_t *mail[LIDAR_THREADS];  /* per-thread mailboxes */
    uint32_t stamp[LIDAR_THREADS];
} lidar_sim_t;

void lidar_sim_init(lidar_sim_t *ls);
void lidar_sim_free(lidar_sim_t *ls);

/* Simulates sweep `seq` starting at t0 (s since the drive start) into msg, whose
 * arrays (range_mm, reflectivity, col_offset_us, beam_*) must hold 64x1024. */
void lidar_simulate(lidar_sim_t *ls, int32_t seq, double t0, int64_t utime, portobello_lidar_scan_t *msg);

#endif
