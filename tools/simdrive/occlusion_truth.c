/* Staged agents, the simulated head and OCCLUSION_TRUTH (see occlusion_truth.h). */
#include "occlusion_truth.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "director.h"
#include "agents_msg.h"
#include "pb_body.h"
#include "scenario.h"
#include "portobello_agents_t.h"
#include "portobello_head_pose_t.h"
#include "portobello_occlusion_t.h"

#define AGENTS_EVERY 3      /* of the 100 Hz poses: ~33 Hz */
#define SURFACE_EPS_M 0.02  /* a sample closer than this to a surface is not hidden by it */

struct sim_occ {
    const pb_route_t *route;
    const pb_vehicle_t *veh;
    const world_t *world;
    pb_ground_t *ground;        /* the terrain's raster (NULL: the plane z = 0) */
    sc_scenario_t sc;
    director_t *dir;
    dir_agent_out_t *agents;
    portobello_agent_t *msg_agents;
    portobello_agent_occlusion_t *occ;
    float (*xyz)[3][PB_BODY_MAX_SAMPLES];
    int8_t (*state)[PB_BODY_MAX_SAMPLES];
    float (*occ_m)[PB_BODY_MAX_SAMPLES];
    uint32_t *mail, stamp;
    int head;
    uint64_t seed;
    int64_t poses;
};

static void no_events(const dir_event_t *ev, void *user) { (void)ev; (void)user; }

sim_occ_t *sim_occ_create(const char *scenario_path, const pb_route_t *route, const pb_vehicle_t *veh,
                          const world_t *world, int head, uint64_t seed, pb_err_t *err)
{
    if (!veh->has_seat_eye) {
        pb_err_set(err, "%s: no seat.eye_xyz: the truth needs the driver's eye", veh->name);
        return NULL;
    }
    sim_occ_t *so = calloc(1, sizeof *so);
    so->route = route; so->veh = veh; so->world = world; so->head = head; so->seed = seed;
    if (sc_load(scenario_path, route, &so->sc, err)) { free(so); return NULL; }
    dir_vehicle_t dv = { veh->length, veh->width, veh->height, veh->rear_overhang };
    so->dir = dir_create(&so->sc, route, &dv, no_events, NULL, err);
    if (!so->dir) { sc_free(&so->sc); free(so); return NULL; }
    so->ground = terrain_ground(&world->terrain, 0);
    dir_set_ground(so->dir, so->ground);
    int n = so->sc.nagents ? so->sc.nagents : 1;
    so->agents = calloc(n, sizeof *so->agents);
    so->msg_agents = calloc(n, sizeof *so->msg_agents);
    so->occ = calloc(n, sizeof *so->occ);
    so->xyz = calloc(n, sizeof *so->xyz);
    so->state = calloc(n, sizeof *so->state);
    so->occ_m = calloc(n, sizeof *so->occ_m);
    so->mail = calloc(world->nprims ? world->nprims : 1, sizeof *so->mail);
    return so;
}

void sim_occ_destroy(sim_occ_t *so)
{
    if (!so) return;
    dir_destroy(so->dir);
    pb_ground_destroy(so->ground);
    sc_free(&so->sc);
    free(so->agents); free(so->msg_agents); free(so->occ); free(so->xyz); free(so->state); free(so->occ_m);
    free(so->mail);
    free(so);
}

/* The head in base at time t: the seat's eye, moving a few centimetres as a seated
 * person does (slow, smooth, deterministic). */
static void head_at(const sim_occ_t *so, double t, double h[3])
{
    const double *e = so->veh->seat_eye_xyz;
    h[0] = e[0] + (so->head ? 0.04 * sin(2 * M_PI * 0.23 * t) : 0);
    h[1] = e[1] + (so->head ? 0.06 * sin(2 * M_PI * 0.17 * t + 1.0) : 0);
    h[2] = e[2] + (so->head ? 0.02 * sin(2 * M_PI * 0.31 * t + 2.0) : 0);
}

void sim_occ_pose(sim_occ_t *so, const body_state_t *b, int64_t utime, pb_log_out_t *out)
{
    const traj_state_t *st = &b->st;
    dir_pose_t p = { .utime = utime };
    memcpy(p.pos, b->p, sizeof p.pos);
    memcpy(p.q, b->q, sizeof p.q);
    memcpy(p.vel, b->v, sizeof p.vel);
    pb_err_t err;
    dir_pose(so->dir, &p, &err);    /* ground truth is finite and in order: never refused */
    if (so->head) {
        portobello_head_pose_t h = { .utime = utime, .tracking = 1 };
        head_at(so, st->t, h.position);
        h.orientation[0] = 1;
        PB_LOG_WRITE_MSG(out, "HEAD_POSE", portobello_head_pose_t, &h);
    }
    if (so->poses++ % AGENTS_EVERY) return;
    int n = dir_agents(so->dir, so->agents);
    dir_agents_to_msg(so->agents, n, so->msg_agents);
    portobello_agents_t m = { .utime = utime, .scenario = so->sc.id, .nagents = n, .agents = so->msg_agents };
    PB_LOG_WRITE_MSG(out, "AGENTS", portobello_agents_t, &m);
}

void sim_occ_truth(sim_occ_t *so, const body_state_t *b, int64_t utime, pb_log_out_t *out)
{
    const traj_state_t *st = &b->st;
    /* the agents and the traffic at this instant, the eye in map */
    dir_tick(so->dir, utime);
    int n = dir_agents(so->dir, so->agents);
    mover_t mov[WORLD_MAX_MOVERS];
    int nmov = world_movers(so->world, so->route, st->t, so->seed, mov);
    double h[3], eye[3];
    head_at(so, st->t, h);
    for (int r = 0; r < 3; r++)     /* map <- base: the body's 3-D pose on the terrain */
        eye[r] = b->p[r] + b->R[3 * r] * h[0] + b->R[3 * r + 1] * h[1] + b->R[3 * r + 2] * h[2];
    for (int i = 0; i < n; i++) {
        const dir_agent_out_t *a = &so->agents[i];
        portobello_agent_occlusion_t *o = &so->occ[i];
        float *x = so->xyz[i][0], *y = so->xyz[i][1], *z = so->xyz[i][2];
        int ns = pb_body_samples(a->kind, a->pos, a->yaw, x, y, z), vis = 0;
        for (int k = 0; k < ns; k++) {
            double d[3] = { x[k] - eye[0], y[k] - eye[1], z[k] - eye[2] };
            double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int j = 0; j < 3; j++) d[j] /= len;
            if (++so->stamp == 0) { memset(so->mail, 0, so->world->nprims * sizeof *so->mail); so->stamp = 1; }
            hit_t hit;
            if (len > SURFACE_EPS_M &&
                world_raycast(so->world, eye, d, len - SURFACE_EPS_M, mov, nmov, so->mail, so->stamp, 0, &hit)) {
                so->state[i][k] = PORTOBELLO_AGENT_OCCLUSION_T_STATE_HIDDEN;
                so->occ_m[i][k] = (float)hit.t;
            } else {
                so->state[i][k] = PORTOBELLO_AGENT_OCCLUSION_T_STATE_VISIBLE;
                so->occ_m[i][k] = NAN;
                vis++;
            }
        }
        o->agent_id = (char *)a->id;
        o->nsamples = ns;
        o->visible_fraction = ns ? (float)vis / ns : 0;
        o->sample_x = x; o->sample_y = y; o->sample_z = z;
        o->state = so->state[i];
        o->occluder_m = so->occ_m[i];
    }
    portobello_occlusion_t m = { .utime = utime, .eye_source = so->head ? PORTOBELLO_OCCLUSION_T_EYE_HEAD_POSE
                                                                        : PORTOBELLO_OCCLUSION_T_EYE_SEAT,
                                 .nagents = n, .agents = so->occ };
    memcpy(m.viewer, eye, sizeof eye);
    PB_LOG_WRITE_MSG(out, "OCCLUSION_TRUTH", portobello_occlusion_t, &m);
}
