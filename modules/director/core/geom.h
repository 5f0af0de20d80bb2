/* geom: convex shapes in the map frame and their intersection test (libccd GJK).
 * The car's footprint is its oriented box (vehicle file dimensions, placed by the
 * pose's full rotation); volumes are boxes, vertical cylinders and vertical
 * prisms over a convex polygon; agents are cylinders or boxes.
 * Plain structs, no allocation. */
#ifndef DIR_GEOM_H
#define DIR_GEOM_H

#include "scenario.h"

typedef enum { GEOM_BOX, GEOM_CYLINDER, GEOM_PRISM } geom_kind_t;

typedef struct {
    geom_kind_t kind;
    double c[3];            /* centre in map */
    double R[9];            /* row-major rotation map <- shape (box, cylinder) */
    double half[3];         /* box half extents; cylinder: radius, -, half height */
    int npts;               /* prism: polygon (map) and z range */
    const double (*pts)[2];
    double z0, z1;
} geom_shape_t;

/* Box from centre, yaw and full size. */
void geom_box_yaw(geom_shape_t *g, const double c[3], double yaw, const double size[3]);
/* Vertical cylinder standing on z0. */
void geom_cylinder(geom_shape_t *g, double x, double y, double z0, double radius, double height);
/* Vertical prism over a convex polygon (the array is referenced, not copied). */
void geom_prism(geom_shape_t *g, const double (*pts)[2], int npts, double z0, double z1);

/* 1 if the two shapes touch or overlap, else 0 (libccd GJK). */
int geom_intersect(const geom_shape_t *a, const geom_shape_t *b);

/* Quaternion (w, x, y, z) to a row-major rotation matrix. */
void geom_quat_to_R(const double q[4], double R[9]);

/* The shape of a scenario's trigger volume. */
void geom_volume(geom_shape_t *g, const sc_volume_t *v);

#endif
