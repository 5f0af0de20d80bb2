/* carve: removes what moved from the mapper's map. A place the LiDAR saw through before or
 * after the moment it was hit was empty then: what the map holds there (a car that drove by,
 * a pedestrian) was there only for a moment. Each sampled ray of the drive counts a hit in the
 * cell it ended in and a pass in every occupied cell it crossed on the way, when it crossed
 * an eighth of the cell (a half along each axis) that holds map points: a ray through the
 * cell's empty part (beside a wall, over a roof's edge) says nothing about its points.
 * A cell's hits make visits: hits more than `revisit_s` apart are two (two road users at one
 * place, or one place passed at the drive's start and again at its end). Only the passes
 * outside the visits count (before the first, between them, after the last): a cell passed
 * through at least `min_passes` times so, hit on at most `max_visits` visits of at most
 * `transient_s` each, is carved: its map points go; so is one whose visits last up to
 * `long_visit_s` (road users one after the other) and that was passed `min_passes_long` times.
 * A cell the sampled rays never hit has no visit: all its passes count (its points came from
 * rays left out of the sample). Then a cell that passes the visits' test (visits of at most
 * `transient_s`, or none) but was passed fewer times, or never, or one hit over visits of up
 * to `long_visit_s` and passed `min_passes` times, goes too when `carved_beside` of its 26
 * neighbours went: the rest of the same body, which the sparse sample crossed less
 * often or not at all (a bus's roof, higher than the LiDAR: what passes through its place
 * after it left goes up into the sky and returns nothing).
 * Passes outside the visits tell a car that drove by (seen through after it left) from a
 * wall seen edge-on (its grazing rays pass through its cells while it is hit), and a static
 * thing hit by few sampled rays from one that was there for a moment. The first version
 * (all passes against five times the hits, the whole ground band spared) left 1,400 times
 * as many points on moving objects of the simulated loop (44,496 against 31) and carved more
 * of the static world (0.71 % of it against 0.49 %).
 *
 * Cells are `cell_m` cubes over the map's points. What a ray crosses near its end is not
 * counted (the end's own cell, and `end_margin_m` before it: the beam's footprint and the
 * pose's error there). A ray longer than `max_range_m` counts no hit, but passes up to
 * `max_range_m` (the beam was free there: a bus's place seen through to a hill 100 m off).
 * Cells within `ground_band_m` above the ground model are never carved
 * (grazing rays run along the road for metres before they hit it), but their points higher
 * than `raise_m` over the ground (at the cell's centre) are judged apart, as a cell of their
 * own: hits that end there and passes of rays that stay higher through the cell (a car's
 * sill over the road; it shared its cell with the road, hit all drive long). What stood still
 * through the drive (parked cars, a pedestrian waiting at a crossing) stays: one drive cannot
 * tell it from the world. Several drives of the course can (pb_carve_set_drive): a cell passed
 * through at least `min_passes_empty` times in one drive and never hit in it was empty that
 * day, and what the other drives saw there (a car parked, then gone) is carved.
 *
 * What the sampled rays cross too seldom (a car seen for a moment at the drive's start or end,
 * a bus whose cells they missed) is judged again by views, after Removert (Kim and Kim, IROS
 * 2020): about once a second a whole sweep becomes a range image seen from the LiDAR at its
 * middle (pb_carve_view_create). A map point within max_range_m is seen through by a view
 * when every return in the 3 x 3 bins around its direction (5 of them at least) lies farther
 * than the point by view_margin_m or view_margin_share of its range, seen when its own bin
 * returned at or beyond it, and hit when that return lies at it (pb_carve_look). On real LiDAR one point seen through says
 * little: silhouette edges, thin poles hit by one sweep and missed by the next, foliage and
 * poses decimetres off all let a beam pass a point that stays (on MulRan's keyframes a
 * per-point rule took bands of roadside structure). So the verdict is on objects: the kept
 * points higher than group_ground_m over the ground, joined where their group_cell_m cells
 * touch (26 neighbours), make groups; a group goes when at least group_share of its points
 * were seen through by view_min_through views or more, by half the views that saw them, and
 * never between two of its hits (a railing, a hedge: seen through and hit in turn), and it has the shape of a road user: group_min_points or more, standing on the ground (its
 * lowest point within group_foot_m of it), at most group_max_height_m tall and at least
 * group_min_width_m long or wide (a pole or a post, seen by one sweep and missed by the
 * next, is narrower) and lies within group_reach_m of its points seen through (a bus is 12-18
 * m long). Static structure seen through in part is joined to what holds it and stays. So
 * would a bus that passed a parked car or a tree within a cell of it: the cells that are
 * at least half seen through are also joined on their own, and such a group of them goes
 * when it has a road user's shape and a footprint at least group_min_depth_m deep across its
 * length (the spread of its points; a vehicle's side with its roof or bonnet is, the part of
 * a rail or fence seen through is a line). And the groups are judged again with the points
 * the cells carved among them (they count for the size and shape, not the share): what the
 * rays took of a car joins the few points of it they left, which go when seen through.
 * The points just over the ground (higher than low_point_m, not group_ground_m: a car's sill,
 * whose body the cells took) join no group: the road beside them would join everything. One
 * goes alone when seen through by low_min_through views or more, by three quarters of those
 * that saw it, and hit by one at most, and nothing kept stands higher in its cell_m column
 * (else it is the foot of what stays: a post, a bush). Under a body that went (a point of its
 * column over group_ground_m carved), view_min_through views are enough: it is that body's
 * foot, a wheel (a car that passed in a drive's last seconds leaves few views after it). For such a point a view's 3 x 3 bins
 * would hold the road in front of it, so it is seen through when its row's three bins returned
 * beyond it and lower over the ground by low_drop_m: the beams came down behind it (a beam
 * over a kerb or a raised pavement ends on it, as high as the point).
 *
 * Pure: no I/O, no clock. Ownership: pb_carve_create copies what it needs; the caller
 * frees the result with pb_carve_destroy (NULL is a no-op). */
#ifndef PB_MAPPER_CARVE_H
#define PB_MAPPER_CARVE_H

#include <stddef.h>
#include <stdint.h>
#include <vector>
#include "pb_ground.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double cell_m = 0.5;
    double end_margin_m = 1.0;
    double ground_band_m = 0.4;
    double raise_m = 0.1;      /* a band cell's points higher over the ground than this are judged apart */
    int min_passes = 10;       /* passes outside the visits the cell was hit in */
    double max_range_m = 60;   /* rays count up to here (a farther return: no hit, passes up to here): beams widen */
    double transient_s = 2;    /* a cell hit over a longer visit than this was there, not passing by ... */
    double long_visit_s = 4;   /* ... unless passed min_passes_long times: road users one after the other */
    int min_passes_long = 22;
    double revisit_s = 10;     /* hits farther apart than this are two visits (two road users) */
    int max_visits = 2;        /* a cell hit on more visits than this holds something that stays */
    int carved_beside = 5;     /* a cell hit on short visits, if at all, goes when this many of its 26 neighbours went */
    int min_passes_empty = 24; /* several drives: passes in one drive that never hit the cell */
    double view_margin_m = 0.4;      /* views: a return this much farther than a point ... */
    double view_margin_share = 0.02; /* ... or this share of its range, whichever is more */
    int view_min_through = 2;        /* a point seen through by this many views (and half those that saw it) */
    double group_cell_m = 0.5;       /* groups: points in touching cells of this edge are one object */
    double group_ground_m = 0.3;     /* only points higher than this over the ground join groups */
    double group_foot_m = 0.7;       /* a road user stands on the ground: its lowest point within this */
    double group_max_height_m = 4.5; /* and no taller than this over it */
    double group_min_width_m = 1.2;  /* at least this long or wide (x or y extent) */
    int group_min_points = 10;
    double group_share = 0.5;        /* the share of a group's points seen through that takes it */
    double group_reach_m = 15;       /* a road user lies within this of its points seen through (x-y) */
    double group_min_depth_m = 0.3;  /* seen through whole but touching what stays: its footprint this deep (a rail is not) */
    double low_point_m = 0.15;       /* points higher than this over the ground, but not group_ground_m, are judged alone */
    double low_drop_m = 0.1;         /* seen through when the beams around end beyond, this much lower over the ground */
    int low_min_through = 4;         /* by this many views (and three quarters of those that saw it; hit once at most) */
} pb_carve_config_t;

typedef struct pb_carve pb_carve_t;

/* The cells of n map points (x, y, z floats, stride floats apart); ground NULL = none. */
pb_carve_t *pb_carve_create(const float *xyz, size_t n, size_t stride, const pb_ground_t *ground,
                            const pb_carve_config_t *cfg);
void pb_carve_destroy(pb_carve_t *c);

/* One ray of a sweep at utime, from the sensor's origin to its return, both in the map frame. */
void pb_carve_ray(pb_carve_t *c, int64_t utime, const double origin[3], const double end[3]);

/* The rays that follow are of drive `drive` (0, 1, ... up to 255, in order; each drive's ray
 * times after the last's by more than revisit_s). A cell is touched as the drive's rays reach
 * it; its visits are each drive's own, a cell hit on more than max_visits visits in any drive
 * stays, and it needs min_passes for every drive that hit it. */
void pb_carve_set_drive(pb_carve_t *c, int drive);

/* A view: n returns (x y z, 3 doubles each, in the map frame) of one sweep and their beams
 * (ring: NULL or 255 when not known), seen from origin with the LiDAR's axes R (map <- lidar,
 * row-major), and the ground model the returns' heights are taken over (NULL: none; then no
 * point just over the ground is seen through). NULL when no return lies 0.5 m or more from
 * origin. The caller destroys it; it keeps no pointer to ground. */
typedef struct pb_carve_view pb_carve_view_t;
pb_carve_view_t *pb_carve_view_create(const double *xyz, const uint8_t *ring, size_t n, const double origin[3],
                                      const double R[9], const pb_ground_t *ground);
void pb_carve_view_destroy(pb_carve_view_t *v);
/* The map points within max_range_m of the view's origin count it: seen, seen through. */
void pb_carve_look(pb_carve_t *c, const pb_carve_view_t *v);

/* Per map point (as given to create): 1 keep, 0 carved. Returns the number carved (objects,
 * unless NULL: 1 per point that went as a group seen through, else 0). gone_keys NULL: the neighbours'
 * verdicts from this map's own cells; else a sorted list of the keys of every part's cells
 * that step 1 carves (pb_carve_gone), so that a part's cell on its border sees its neighbours
 * in the next part. group_keys NULL: the groups of this map's own points; else the sorted
 * group cells (group_cell_m) of every part's groups that go (pb_carve_groups). */
size_t pb_carve_keep(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, const std::vector<uint64_t> *group_keys,
                     std::vector<uint8_t> *keep, std::vector<uint8_t> *objects = nullptr);
/* Appends to keys the cell keys (the voxel keys of cell_m cells) that step 1 carves here. */
void pb_carve_gone(const pb_carve_t *c, std::vector<uint64_t> *keys);

/* The groups over parts: every part's seeds (the group cells of its points over the ground
 * seen through, appended to keys), then with all of them indexed once (pb_carve_near_create;
 * the caller destroys it) every part's cells within group_reach_m of a seed (appended to
 * cells: per cell an entry of the points the cells kept, one of those they carved), then all
 * those cells joined into groups, once without the carved entries and once with them: the
 * sorted keys of the cells whose groups go (appended to gone). A group reaching farther than
 * group_reach_m from every seed is no road user and stays, so the few cells gathered decide
 * as the whole map's would. */
typedef struct {
    uint64_t key;              /* the group cell */
    uint32_t n, kept, through; /* its points over the ground, those the cells kept, those of them seen through */
    float lo[2], hi[2];        /* their x-y extent */
    float hmin, hmax;          /* their heights over the ground */
    double sum[5];             /* their x, y, xx, xy, yy summed: the footprint's spread */
    uint8_t edge;              /* within 2 cells of group_reach_m from the nearest seed */
    uint8_t carved;            /* 1: the entry of the cell's points the cells carved (kept 0) */
} pb_carve_group_cell_t;
typedef struct pb_carve_near pb_carve_near_t;
void pb_carve_seeds(const pb_carve_t *c, std::vector<uint64_t> *keys);
pb_carve_near_t *pb_carve_near_create(const std::vector<uint64_t> &seeds, const pb_carve_config_t *cfg);
void pb_carve_near_destroy(pb_carve_near_t *n);
void pb_carve_group_cells(const pb_carve_t *c, const std::vector<uint64_t> *gone_keys, const pb_carve_near_t *seeds,
                          std::vector<pb_carve_group_cell_t> *cells);
void pb_carve_groups(std::vector<pb_carve_group_cell_t> *cells, const pb_carve_config_t *cfg, std::vector<uint64_t> *gone);

/* A map in parts (the mapper's tiles, each its own pb_carve_t): every part given the rays
 * and views that may reach it carves as one pb_carve_t of the whole map would, provided no
 * cell's column spans two parts (the parts are squares of whole cells in x-y, as the mapper's
 * tiles: a low point's column is judged whole) and every part's pb_carve_keep is given all
 * parts' pb_carve_gone and pb_carve_groups; a ray that misses a part's cells costs little
 * there. To page a part out and back: its counts so far (out replaced), and given to a part
 * made again from the same points and ground. load returns 0, or -1 when the bytes are not of such a part. */
void pb_carve_save(const pb_carve_t *c, std::vector<uint8_t> *out);
int pb_carve_load(pb_carve_t *c, const uint8_t *data, size_t len);

#endif
