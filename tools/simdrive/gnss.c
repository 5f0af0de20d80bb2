/* GNSS: Gauss-Markov error process and the fix message. */
#include "gnss.h"

#include <math.h>

#include "rng.h"

#define VERT_FACTOR 1.5     /* vertical error sigma relative to horizontal, typical of GNSS */

static double sigma_axis(const pb_vehicle_t *v, int axis)
{
    return axis < 2 ? v->gnss_noise : v->gnss_noise * VERT_FACTOR;
}

void gnss_sim_init(gnss_sim_t *g, const pb_vehicle_t *v, uint64_t seed, double dt)
{
    /* start in the stationary distribution, so the first fixes are as wrong as later ones */
    for (int i = 0; i < 3; i++) g->err[i] = sigma_axis(v, i) * rng_gauss(seed, RNG_GNSS, 0, (uint64_t)i);
    g->last_heading = 0;
    g->k = 0;
    g->dt = dt;
}

void gnss_step(gnss_sim_t *g, const pb_vehicle_t *v, const pb_georef_t *geo, double geoid_height_m,
               const body_state_t *b, uint64_t seed, int64_t utime, portobello_gnss_fix_t *fix)
{
    if (g->k > 0) {
        /* e[k] = phi e[k-1] + sigma sqrt(1 - phi^2) w: stationary sigma per axis */
        double phi = exp(-g->dt / v->gnss_noise_tau);
        for (int i = 0; i < 3; i++)
            g->err[i] = phi * g->err[i] +
                        sigma_axis(v, i) * sqrt(1 - phi * phi) * rng_gauss(seed, RNG_GNSS, (uint64_t)g->k, (uint64_t)i);
    }
    g->k++;
    /* the antenna on the body (its height follows the terrain, pitch and roll) */
    const double *a = v->gnss_xyz, *R = b->R;
    double p[3], ra[3];
    for (int i = 0; i < 3; i++) {
        ra[i] = R[3 * i] * a[0] + R[3 * i + 1] * a[1] + R[3 * i + 2] * a[2];
        p[i] = b->p[i] + ra[i] + g->err[i];
    }
    pb_geo_map_to_wgs84(geo, p, &fix->lat_deg, &fix->lon_deg, &fix->alt_m);
    fix->utime = utime;
    fix->fix_type = PORTOBELLO_GNSS_FIX_T_FIX_3D;
    fix->num_sv = (int16_t)(12 + (rng_u64(seed, RNG_GNSS, (uint64_t)(g->k / 600), 99) % 6));
    fix->alt_msl_m = fix->alt_m - geoid_height_m;
    /* 1 sigma per horizontal axis: the reported accuracy is what the error model uses */
    fix->h_acc_m = v->gnss_noise * M_SQRT2;   /* horizontal RMS of two axes of sigma gnss_noise */
    fix->v_acc_m = v->gnss_noise * VERT_FACTOR;
    /* velocity of the antenna (lever arm: omega x r), 5 cm/s white noise per axis */
    double wm[3], vm[3];    /* w in map, then v + w x (R a) */
    for (int i = 0; i < 3; i++) wm[i] = R[3 * i] * b->w[0] + R[3 * i + 1] * b->w[1] + R[3 * i + 2] * b->w[2];
    vm[0] = b->v[0] + wm[1] * ra[2] - wm[2] * ra[1];
    vm[1] = b->v[1] + wm[2] * ra[0] - wm[0] * ra[2];
    vm[2] = b->v[2] + wm[0] * ra[1] - wm[1] * ra[0];
    for (int i = 0; i < 2; i++) vm[i] += 0.05 * rng_gauss(seed, RNG_GNSS, (uint64_t)g->k, (uint64_t)(3 + i));
    double enu[3];
    pb_geo_map_to_enu_vec(geo, vm, enu);
    fix->vel_ned_mps[0] = enu[1];
    fix->vel_ned_mps[1] = enu[0];
    fix->vel_ned_mps[2] = -enu[2];
    fix->speed_mps = hypot(enu[0], enu[1]);
    if (fix->speed_mps > 0.5) {
        double h = atan2(enu[0], enu[1]) * 180 / M_PI;
        g->last_heading = h < 0 ? h + 360 : h;
        fix->heading_acc_deg = fmin(180, 0.05 / fix->speed_mps * 180 / M_PI + 0.3);
    } else {
        fix->heading_acc_deg = 180;     /* course is meaningless at rest: keep the last one */
    }
    fix->heading_deg = g->last_heading >= 360 ? 0 : g->last_heading;
}
