/* The world (world.yaml): the ground (the plane z = 0, or the terrain height field
 * of terrain.h) with painted crosswalks, static
 * primitives (oriented boxes, vertical cylinders, spheres) in a 2-D uniform grid
 * for ray casting, and moving traffic (a few boxes, tested against every ray). */
#ifndef SIM_WORLD_H
#define SIM_WORLD_H

#include <stdint.h>
#include "pb_err.h"
#include "pb_route.h"
#include "terrain.h"

#define WORLD_MAX_CLASSES 32
#define WORLD_MAX_TRAFFIC 64
#define WORLD_MAX_MOVERS (5 * WORLD_MAX_TRAFFIC)   /* a road user's body and its four wheels */

enum { PRIM_BOX, PRIM_CYLINDER, PRIM_SPHERE };
enum { DAY_BOTH, DAY_MAP, DAY_DRIVE };

#define WORLD_MAX_GROUPS 16

typedef struct {
    uint8_t kind, cls, day;
    uint8_t group;              /* 0: none, else 1 + index into world_t.group_name */
    double cx, cy, cz;          /* centre (boxes, cylinders: cz unused) */
    double c, s;                /* cos, sin of yaw (boxes) */
    double hx, hy;              /* half length, half width (boxes) */
    double r;                   /* radius (cylinders, spheres) */
    double z0, z1;              /* bottom, top (boxes, cylinders) */
} prim_t;

typedef struct {
    char kind[16];
    uint8_t cls;
    double size[3], z0, speed, phase_s, lane_offset;
} traffic_t;

typedef struct {                /* a mover placed at one instant: a box turned by (c, s) */
    double cx, cy, c, s, hx, hy, z0, z1;   /* z0, z1: its bottom and top at its centre */
    double gx, gy;              /* the road's slope under it along its own x and y: its heights follow it */
    uint8_t cls;
} mover_t;

struct actors_s;

typedef struct {
    int nclasses;
    char class_name[WORLD_MAX_CLASSES][24];
    double albedo[WORLD_MAX_CLASSES];
    uint8_t ground_cls, paint_cls;
    terrain_t terrain;          /* the ground; objects' z0 and traffic stand on it */
    struct actors_s *actors;    /* lead car, crossers, the car's body (actors.h) */
    int nprims;
    prim_t *prims;
    int ngroups;                /* named changes of the drive day (object key `group`) */
    char group_name[WORLD_MAX_GROUPS][24];
    uint32_t groups_off;        /* bit g set: group g + 1 is left out */
    int ntraffic;
    traffic_t traffic[WORLD_MAX_TRAFFIC];
    /* crosswalk paint (from the route): centre, axes, half sizes */
    int ncw;
    double (*cw)[6];
    /* grid over the static primitives of one day */
    double gx0, gy0, cell;
    int gnx, gny;
    int32_t *cell_start;        /* gnx*gny+1 offsets into cell_items */
    int32_t *cell_items;
    float *cell_maxz;
    double max_z;
    /* Foliage as a LiDAR sees it (simdrive --foliage-depth): 0 = solid spheres; > 0 = a
     * beam entering a canopy of class "foliage" stops at a depth drawn from an exponential
     * of this mean (m), or passes through when that is beyond the canopy (leaves and gaps:
     * a real canopy returns from its whole depth and differently at every sweep). */
    double foliage_depth_m;
    int foliage_cls;            /* -1: no class "foliage" */
} world_t;

/* Terrain rasters reach this far beyond the route (the LiDAR's range and more). */
#define WORLD_TERRAIN_MARGIN_M 140.0
int world_load(const char *path, const pb_route_t *route, world_t *w, pb_err_t *err);
/* Leaves out every object of a group (e.g. "fence"); -1 with the known groups in err. */
int world_group_off(world_t *w, const char *name, pb_err_t *err);
/* Builds the grid over the primitives present on `day` (DAY_MAP or DAY_DRIVE), minus
 * the groups left out. */
void world_build_grid(world_t *w, int day, double cell_m);
void world_free(world_t *w);

/* Places traffic at time t (s since start, seed-dependent phase), each vehicle a body and
 * four wheels (world_vehicle), then the actors switched on (actors.h; the same count and
 * order at every t). out holds WORLD_MAX_MOVERS. Returns the count. */
int world_movers(const world_t *w, const pb_route_t *route, double t, uint64_t seed, mover_t *out);
/* A vehicle at (cx, cy) heading (c, s), size length, width, height, its body z0 over the road:
 * the body follows the road's slope under it (the clearance holds from end to end, as on its
 * wheels), and four wheels stand on the road (what a LiDAR sees of a vehicle at road level is
 * its tyres). bury: every part 1000 m down (a slot kept while it is gone). Writes 5 movers to
 * out (room for them is the caller's); returns 5. */
int world_vehicle(const world_t *w, double cx, double cy, double c, double s, const double size[3], double z0,
                  uint8_t cls, int bury, mover_t *out);

typedef struct { double t; int cls; } hit_t;

/* Nearest hit of the ray o + t d (d unit) with t in (0, tmax], among ground, static
 * primitives and movers. mail is per-thread scratch of nprims entries, stamp a
 * fresh value per ray (mailboxing: each primitive is tested once per ray).
 * ray_key: this ray's random key for porous foliage (w->foliage_depth_m > 0); 0 = foliage
 * is solid for this ray (a line of sight, not a beam). Returns 1 on a hit. */
int world_raycast(const world_t *w, const double o[3], const double d[3], double tmax,
                  const mover_t *movers, int nmovers, uint32_t *mail, uint32_t stamp, uint64_t ray_key, hit_t *hit);

/* The ground's height under (x, y): the terrain's, or 0 on a flat site. */
double world_ground_z(const world_t *w, double x, double y);

/* Distance from p to the nearest static surface of the grid's day: the ground (vertical
 * distance to the terrain) and the primitives within a grid cell of p; at most cap. For
 * scoring a map against the world (simdrive --surface-distance). */
double world_distance(const world_t *w, const double p[3], double cap);

#endif
