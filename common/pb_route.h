/* The route (route.yaml): the lane centreline as a closed C2 curve (periodic cubic
 * spline through the file's points, parametrised by arc length), its stop lines,
 * crosswalks and speed profiles. */
#ifndef PB_ROUTE_H
#define PB_ROUTE_H

#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct { double cruise, accel, decel, lat_accel; } pb_speed_profile_t;
enum { PB_PROFILE_CAUTIOUS, PB_PROFILE_NORMAL, PB_PROFILE_AGGRESSIVE, PB_PROFILE_COUNT };
extern const char *const pb_profile_names[PB_PROFILE_COUNT];

typedef struct { char id[32], crosswalk[32]; double xy[2], yaw_deg, s; } pb_stop_line_t;
typedef struct { char id[32]; double center[2], yaw_deg, length, width; } pb_crosswalk_t;

typedef struct {
    double x, y;        /* map, m */
    double yaw;         /* heading of the tangent, rad */
    double kappa;       /* curvature, 1/m, + left */
    double dkappa;      /* d kappa / ds, 1/m^2 */
} pb_route_point_t;

typedef struct {
    int n;                      /* control points = spline segments (closed) */
    double *cx, *cy;            /* 4 coefficients per segment: p(t) = c0 + c1 t + c2 t^2 + c3 t^3, t in [0,1] */
    double *seg_s;              /* arc length at the start of segment i, n+1 entries */
    double length;              /* one lap, m */
    double lane_width;
    double dwell_s[2];          /* stop dwell range, s */
    int nstops, ncw;
    pb_stop_line_t *stops;         /* sorted by s */
    pb_crosswalk_t *cw;
    pb_speed_profile_t profiles[PB_PROFILE_COUNT];
} pb_route_t;

int pb_route_load(const char *path, pb_route_t *r, pb_err_t *err);
void pb_route_free(pb_route_t *r);
/* Point at arc length s (any real s: wraps around the loop). */
void pb_route_eval(const pb_route_t *r, double s, pb_route_point_t *out);
/* Arc length of the route point nearest to (x, y). */
double pb_route_project(const pb_route_t *r, double x, double y);

#ifdef __cplusplus
}
#endif
#endif
