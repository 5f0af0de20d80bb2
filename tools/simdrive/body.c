/* Body: the car's 3-D pose on the terrain and its derivatives. */
#include "body.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "pb_math.h"

#define BODY_DT 0.010       /* s, central-difference step (smooth motion: the O(dt^2) error is < 1 mm/s^2) */
#define GRAVITY 9.80665

void body_model_init(body_model_t *m)
{
    const trajectory_t *tr = m->traj;
    m->n = tr->n;
    m->ang = malloc((size_t)m->n * 4 * sizeof *m->ang);
    const double wn = 2 * M_PI * BODY_FREQ_HZ, z = BODY_DAMPING, dt = tr->dt;
    double x[2] = { 0, 0 }, v[2] = { 0, 0 };   /* roll, pitch and their rates */
    for (int k = 0; k < m->n; k++) {
        traj_state_t st;
        traj_eval(tr, k * dt, &st);
        double target[2] = { BODY_ROLL_GAIN * st.kappa * st.v * st.v, -BODY_PITCH_GAIN * st.a };
        if (k == 0) { x[0] = target[0]; x[1] = target[1]; }
        for (int i = 0; i < 2; i++) {
            m->ang[4 * k + 2 * i] = x[i];
            m->ang[4 * k + 2 * i + 1] = v[i];
            /* semi-implicit Euler: stable and accurate at wn dt = 0.02 */
            v[i] += dt * (wn * wn * (target[i] - x[i]) - 2 * z * wn * v[i]);
            x[i] += dt * v[i];
        }
    }
}

void body_model_free(body_model_t *m)
{
    free(m->ang);
    m->ang = NULL;
}

/* Body roll and pitch at t: cubic Hermite through the samples' angles and rates. */
static void body_angles(const body_model_t *m, double t, double *roll, double *pitch)
{
    double dt = m->traj->dt, f = t / dt;
    if (f < 0) f = 0;
    int k = (int)f;
    if (k > m->n - 2) k = m->n - 2;
    double u = f - k;
    if (u > 1) u = 1;
    double h00 = 2 * u * u * u - 3 * u * u + 1, h10 = u * u * u - 2 * u * u + u;
    double h01 = -2 * u * u * u + 3 * u * u, h11 = u * u * u - u * u;
    const double *a = m->ang + 4 * k, *b = a + 4;
    *roll = h00 * a[0] + h10 * dt * a[1] + h01 * b[0] + h11 * dt * b[1];
    *pitch = h00 * a[2] + h10 * dt * a[3] + h01 * b[2] + h11 * dt * b[3];
}

void body_pose(const body_model_t *m, double t, body_state_t *out)
{
    traj_eval(m->traj, t, &out->st);
    const traj_state_t *st = &out->st;
    const pb_vehicle_t *v = m->veh;
    double c = cos(st->yaw), s = sin(st->yaw);
    /* tyre contacts: rear axle at the base origin, front axle one wheelbase ahead */
    double zr[2], zf[2];
    for (int k = 0; k < 2; k++) {
        double sg = k ? -1 : 1;     /* left, right */
        double hr = sg * v->track_rear / 2, hf = sg * v->track_front / 2;
        zr[k] = terrain_height_near(m->terrain, st->x - s * hr, st->y + c * hr, st->dist);
        zf[k] = terrain_height_near(m->terrain, st->x + c * v->wheelbase - s * hf, st->y + s * v->wheelbase + c * hf,
                                    st->dist + v->wheelbase);
    }
    double grade_pitch = -atan2(0.5 * (zf[0] + zf[1]) - 0.5 * (zr[0] + zr[1]), v->wheelbase);
    double bank_roll = atan2(0.5 * (zr[0] + zf[0]) - 0.5 * (zr[1] + zf[1]), 0.5 * (v->track_rear + v->track_front));
    double body_roll, body_pitch;
    body_angles(m, t, &body_roll, &body_pitch);
    out->pitch = grade_pitch + body_pitch;
    out->roll = bank_roll + body_roll;
    out->p[0] = st->x; out->p[1] = st->y; out->p[2] = 0.5 * (zr[0] + zr[1]);
    pb_quat_from_rpy(out->roll, out->pitch, st->yaw, out->q);
    pb_quat_to_matrix(out->q, out->R);
}

void body_eval(const body_model_t *m, double t, body_state_t *out)
{
    body_state_t a, b;
    double h = BODY_DT / 2;
    body_pose(m, t - h, &a);
    body_pose(m, t + h, &b);
    body_pose(m, t, out);
    for (int i = 0; i < 3; i++) out->v[i] = (b.p[i] - a.p[i]) / BODY_DT;
    /* w: R(t)^T dR/dt, the skew-symmetric part, in base */
    double D[9], W[9];
    for (int i = 0; i < 9; i++) D[i] = (b.R[i] - a.R[i]) / BODY_DT;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) W[3 * i + j] = out->R[i] * D[j] + out->R[3 + i] * D[3 + j] + out->R[6 + i] * D[6 + j];
    out->w[0] = 0.5 * (W[7] - W[5]);
    out->w[1] = 0.5 * (W[2] - W[6]);
    out->w[2] = 0.5 * (W[3] - W[1]);
}

void body_imu(const body_model_t *m, double t, const double r[3], double f[3], double w[3])
{
    body_state_t s[3];
    double pt[3][3];
    double h = BODY_DT / 2;
    for (int k = 0; k < 3; k++) {
        body_pose(m, t + (k - 1) * h, &s[k]);
        for (int i = 0; i < 3; i++)
            pt[k][i] = s[k].p[i] + s[k].R[3 * i] * r[0] + s[k].R[3 * i + 1] * r[1] + s[k].R[3 * i + 2] * r[2];
    }
    /* acceleration of the point, map; specific force = a - g with g = (0, 0, -9.81) */
    double am[3];
    for (int i = 0; i < 3; i++) am[i] = (pt[2][i] - 2 * pt[1][i] + pt[0][i]) / (h * h);
    am[2] += GRAVITY;
    const double *R = s[1].R;
    for (int i = 0; i < 3; i++) f[i] = R[i] * am[0] + R[3 + i] * am[1] + R[6 + i] * am[2];
    body_state_t e;
    body_eval(m, t, &e);
    memcpy(w, e.w, sizeof e.w);
}
