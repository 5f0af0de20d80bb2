/* LiDAR: beam model, per-column sensor poses and the threaded ray casting. */
#include "lidar.h"

#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"

#define MIN_RANGE_M 0.3

void lidar_model_os1_64(lidar_model_t *m)
{
    /* Evenly spaced beams over +16.6..-16.6 deg (the OS1-64 Gen1 span), top beam first;
     * azimuth offsets repeat in fours like the Gen1 staggered columns. */
    static const double az_deg[4] = { 3.164, 1.055, -1.055, -3.164 };
    for (int r = 0; r < LIDAR_ROWS; r++) {
        m->alt[r] = (float)((16.6 - 33.2 * r / (LIDAR_ROWS - 1)) * M_PI / 180);
        m->az[r] = (float)(az_deg[r % 4] * M_PI / 180);
    }
    m->origin_m = 0.015806f;    /* OS1 Gen1 lidar_origin_to_beam_origin_mm */
    for (int c = 0; c < LIDAR_COLS; c++)
        m->col_off_us[c] = (int32_t)lround((double)c * LIDAR_PERIOD_US / LIDAR_COLS);
}

void lidar_sim_init(lidar_sim_t *ls)
{
    for (int i = 0; i < LIDAR_THREADS; i++) {
        ls->mail[i] = calloc(ls->world->nprims ? ls->world->nprims : 1, sizeof(uint32_t));
        ls->stamp[i] = 0;
    }
}

void lidar_sim_free(lidar_sim_t *ls)
{
    for (int i = 0; i < LIDAR_THREADS; i++) free(ls->mail[i]);
}

typedef struct {
    lidar_sim_t *ls;
    int tid;
    int32_t seq;
    double t0;
    const mover_t *mov0, *mov1;     /* traffic at sweep start and end */
    int nmov;
    portobello_lidar_scan_t *msg;
} job_t;

static void *worker(void *arg)
{
    job_t *j = arg;
    lidar_sim_t *ls = j->ls;
    const lidar_model_t *m = ls->model;
    const pb_vehicle_t *v = ls->veh;
    double Rl[9];
    pb_quat_to_matrix(v->base_from_lidar.q, Rl);
    const double n = m->origin_m, sigma = v->lidar_range_noise, maxr = v->lidar_max_range;
    const uint64_t seed = ls->seed, scan = (uint64_t)j->seq;
    mover_t mov[WORLD_MAX_MOVERS];
    uint32_t *mail = ls->mail[j->tid];
    /* blocks of 32 columns, alternating between threads, balance near and far views */
    for (int c0 = 32 * j->tid; c0 < LIDAR_COLS; c0 += 32 * LIDAR_THREADS)
        for (int c = c0; c < c0 + 32; c++) {
            double tc = j->t0 + m->col_off_us[c] * 1e-6;
            /* map <- lidar at this column's time: the body's pose on the terrain * base <- lidar */
            body_state_t b;
            body_pose(ls->body, tc, &b);
            double R[9], T[3];
            const double *lt = v->base_from_lidar.t;
            for (int i = 0; i < 3; i++) {
                for (int k = 0; k < 3; k++)
                    R[3 * i + k] = b.R[3 * i] * Rl[k] + b.R[3 * i + 1] * Rl[3 + k] + b.R[3 * i + 2] * Rl[6 + k];
                T[i] = b.p[i] + b.R[3 * i] * lt[0] + b.R[3 * i + 1] * lt[1] + b.R[3 * i + 2] * lt[2];
            }
            /* traffic moves < 1.5 m per sweep: linear interpolation is exact to mm */
            double f = m->col_off_us[c] / (double)LIDAR_PERIOD_US;
            for (int k = 0; k < j->nmov; k++) {
                const mover_t *a = &j->mov0[k], *b = &j->mov1[k];
                mov[k] = *a;
                mov[k].cx = a->cx + (b->cx - a->cx) * f; mov[k].cy = a->cy + (b->cy - a->cy) * f;
                mov[k].c = a->c + (b->c - a->c) * f; mov[k].s = a->s + (b->s - a->s) * f;
                double nrm = hypot(mov[k].c, mov[k].s);
                mov[k].c /= nrm; mov[k].s /= nrm;
            }
            double enc = 2 * M_PI * (1.0 - (double)c / LIDAR_COLS);
            double ol[3] = { n * cos(enc), n * sin(enc), 0 }, o[3];
            for (int k = 0; k < 3; k++) o[k] = R[3 * k] * ol[0] + R[3 * k + 1] * ol[1] + R[3 * k + 2] * ol[2] + T[k];
            for (int r = 0; r < LIDAR_ROWS; r++) {
                int px = r * LIDAR_COLS + c;
                double th = enc + m->az[r], ph = m->alt[r];
                double dl[3] = { cos(th) * cos(ph), sin(th) * cos(ph), sin(ph) }, d[3];
                for (int k = 0; k < 3; k++) d[k] = R[3 * k] * dl[0] + R[3 * k + 1] * dl[1] + R[3 * k + 2] * dl[2];
                if (++ls->stamp[j->tid] == 0) {     /* wrapped: clear the mailboxes */
                    memset(mail, 0, ls->world->nprims * sizeof *mail);
                    ls->stamp[j->tid] = 1;
                }
                hit_t hit;
                int32_t mm = 0;
                uint8_t refl = 0;
                uint64_t h = rng_u64(seed, RNG_LIDAR_DROP, scan, (uint64_t)px);
                int seen = world_raycast(ls->world, o, d, maxr, mov, j->nmov, mail, ls->stamp[j->tid],
                                          rng_u64(seed, RNG_FOLIAGE, scan, (uint64_t)px) | 1, &hit);
                if (ls->body_range && ls->body_range[px] < (seen ? hit.t : INFINITY)) {   /* the car's own body */
                    seen = 1;
                    hit.t = ls->body_range[px];
                    hit.cls = ls->body_cls;
                }
                if (seen && hit.t > MIN_RANGE_M &&
                    (double)(h >> 11) * (1.0 / 9007199254740992.0) >= v->lidar_dropout) {
                    /* range counts from the axis: R = n + distance from the beam origin */
                    double range = n + hit.t + sigma * rng_gauss(seed, RNG_LIDAR_NOISE, scan, (uint64_t)px);
                    mm = (int32_t)lround(range * 1000);
                    if (mm < 1) mm = 1;
                    /* reflectivity: albedo in percent (Ouster's scale for diffuse targets), +-5 % */
                    double jit = ((double)(h & 0x7ff) / 2047.0 - 0.5) * 0.1;
                    long rf = lround(ls->world->albedo[hit.cls] * 100 * (1 + jit));
                    refl = (uint8_t)(rf < 1 ? 1 : rf > 255 ? 255 : rf);
                }
                j->msg->range_mm[px] = mm;
                j->msg->reflectivity[px] = refl;
            }
        }
    return NULL;
}

void lidar_simulate(lidar_sim_t *ls, int32_t seq, double t0, int64_t utime, portobello_lidar_scan_t *msg)
{
    const lidar_model_t *m = ls->model;
    msg->utime = utime;
    msg->seq = seq;
    msg->rows = LIDAR_ROWS;
    msg->cols = LIDAR_COLS;
    msg->npixels = LIDAR_ROWS * LIDAR_COLS;
    msg->nsignal = 0;
    for (int c = 0; c < LIDAR_COLS; c++) msg->col_offset_us[c] = m->col_off_us[c];
    for (int r = 0; r < LIDAR_ROWS; r++) { msg->beam_altitude_rad[r] = m->alt[r]; msg->beam_azimuth_rad[r] = m->az[r]; }
    msg->beam_origin_m = m->origin_m;
    for (int k = 0; k < 16; k++) msg->lidar_from_beam[k] = (k % 5 == 0) ? 1.0 : 0.0;
    msg->npoints = 0;

    mover_t mov0[WORLD_MAX_MOVERS], mov1[WORLD_MAX_MOVERS];
    int nmov = 0;
    if (ls->traffic) {
        mover_t a[WORLD_MAX_MOVERS], b[WORLD_MAX_MOVERS];
        int na = world_movers(ls->world, ls->route, t0, ls->seed, a);
        world_movers(ls->world, ls->route, t0 + LIDAR_PERIOD_US * 1e-6, ls->seed, b);
        traj_state_t st;
        traj_eval(ls->traj, t0, &st);
        for (int k = 0; k < na; k++)    /* only traffic within reach of this sweep */
            if (hypot(a[k].cx - st.x, a[k].cy - st.y) < ls->veh->lidar_max_range + 30) {
                mov0[nmov] = a[k];
                mov1[nmov++] = b[k];
            }
    }
    job_t jobs[LIDAR_THREADS];
    pthread_t th[LIDAR_THREADS];
    for (int i = 0; i < LIDAR_THREADS; i++)
        jobs[i] = (job_t){ ls, i, seq, t0, mov0, mov1, nmov, msg };
    for (int i = 1; i < LIDAR_THREADS; i++) pthread_create(&th[i], NULL, worker, &jobs[i]);
    worker(&jobs[0]);
    for (int i = 1; i < LIDAR_THREADS; i++) pthread_join(th[i], NULL);
}
