/* The site folder's site.yaml: name, geo-reference and the files it points to. */
#ifndef PB_SITE_H
#define PB_SITE_H

#include "pb_err.h"
#include "pb_geo.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    char dir[1024];
    char name[64];
    pb_georef_t geo;
    double geoid_height_m;      /* geoid above the ellipsoid (for heights above sea level) */
    char route_path[1300], world_path[1300];
    char ground_path[1300];     /* the ground model (pb_ground.h; built by tools/build-ground) */
} pb_site_t;

int pb_site_load(const char *dir, pb_site_t *s, pb_err_t *err);

#ifdef __cplusplus
}
#endif
#endif
