/* under: the road under what moved, return by return. The carving (carve.h) judges the map's
 * voxels, and a voxel of the road holds the road's returns of the whole drive and, mixed in
 * with them, the returns of the lowest few centimetres of every tyre that stood on it: the
 * tyres lift its centroid by 5-10 cm, and no verdict on the whole voxel can take them out
 * without the road. So the drive is read once more after the carving. When each carved voxel
 * was hit the map knows (the first and last sweep whose returns fell in it): a body is a
 * carved voxel body_min_m to body_max_m over the ground whose returns all came within
 * body_span_s (what moved through; one hit over a longer time is something that stands there
 * and that the carving took, such as foliage it saw through). In the read, a return of a
 * sweep no higher than return_max_m over the ground is taken out of its voxel as the bottom of
 * a body, or what passed under one, when
 *  - it lies within reach_m of a column (column_m square in x-y) where a return of the sweep
 *    fell in a body, and where a body stood at some time of the drive (a body's column or one
 *    beside it); or
 *  - the sweep's columns are known and the beam just above it, in the same column of the
 *    sweep, ended in a body no farther than above_beyond_m beyond it: a wheel's bottom at a
 *    range where one beam hits the wheel and the next its body, and what a beam that passed
 *    under a nearer car's body met (the far wheel's inner face), with no body return near it.
 * Measured on the simulated loop with true poses (points left on moving objects, and points
 * within 5 cm of the static world taken, of 678 and 7.24 M before): within one column 237
 * and 261, within 0.5 m 94 and 348, within 1 m 72 and 394; judging every return within
 * 0.5 m of a body's column, not only where a body stood, 92 and 752; within 0.5 m and the
 * beam above, 58 and 369 (two beams above: 55 and 374). Then (5 Dec 2026), against those 58
 * points and 7,242,511 static ones: bodies only where hit within 1 s, 60 and 7,242,712 (of the
 * carved voxels hit, 95 % of those on moving objects were hit within 1 s, 20 % of those on
 * the static world); and returns up to 0.3 m taken, not 0.15 (a tyre's lower half, which had
 * stayed in the voxel and held its centroid 0.15-0.19 m up), 30 and 7,242,711. Taking whole
 * voxels 0.15-0.3 m up when every return was taken too: 20 and 7,242,463, and on MulRan 907
 * more voxels, along kerbs and hedges (no time tells there: each keyframe stands alone).
 * Most of those taken lay 4-6 cm over the ground model: voxels that only the bodies' bottoms
 * filled. A voxel keeps the rest of its returns (the road seen before and after), and goes
 * when it had no other. Only voxels lifted over the ground (lifted_m) and within the road's
 * band (road_max_m) are judged: one that lies on the ground is the road, seen beside or under
 * the body (on the simulated drives the voxels that went without this were the road, 4-12 mm
 * over it at the median, where the tyres' lay 7-9 cm); one higher is what stands there (on
 * MulRan, 162 voxels of a kerb's or a bush's base beside a car, whose centroid the taking of
 * their lowest returns lifted).
 *
 * Pure: no I/O, no clock. The voxels are the map builder's (pb_map_voxel_key). Ownership:
 * pb_under_create copies the points and keeps a pointer to the ground model, which must
 * outlive it; the caller frees it with pb_under_destroy (NULL is a no-op). */
#ifndef PB_MAPPER_UNDER_H
#define PB_MAPPER_UNDER_H

#include <stddef.h>
#include <stdint.h>
#include "pb_ground.h"
#include "pb_scan.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double column_m = 0.25;   /* x-y columns ... */
    double reach_m = 0.5;     /* ... a body marks within this of its own */
    double body_min_m = 0.1;  /* a carved voxel this high over the ground or higher is a body ... */
    double body_max_m = 2.0;  /* ... up to this (a carved voxel higher up says nothing of the road) */
    double body_span_s = 1.0;  /* ... whose returns all came within this time */
    double return_max_m = 0.3; /* returns no higher than this over the ground under a body are taken out ... */
    double road_max_m = 0.15;  /* ... of voxels no higher than this ... */
    double lifted_m = 0.03;    /* ... and lifted this much over the ground (one lower is the road itself) */
    double above_beyond_m = 0.5; /* a low return goes when its beam above ended in a body at most this beyond it */
    double bump_m = 0.05;        /* a patch of map points where a body stood, this much over the ground and ... */
    double bump_reach_m = 0.5;   /* ... every map point within this (x-y), no wider than this, ... */
    double bump_fill = 0.75;     /* ... with map points in this share of the voxel columns round it, goes */
    int look_returns = 10;       /* a voxel of the road band hit in one sweep only, beside one of this many returns ... */
    double look_span_s = 5.0;    /* ... over this long or longer, goes (pb_under_look) */
} pb_under_config_t;

typedef struct pb_under pb_under_t;

/* The carved map points (x y z floats, stride floats apart) of a map of voxel_m voxels, with
 * hit[2 i], hit[2 i + 1] the first and last time a sweep's return fell in point i's voxel (NULL:
 * never; several drives: on one clock on which they do not overlap), over the ground model
 * (NULL: nothing is taken out). */
pb_under_t *pb_under_create(const float *carved, size_t n, size_t stride, const int64_t *hit, double voxel_m,
                            const pb_ground_t *ground, const pb_under_config_t *cfg);
void pb_under_destroy(pb_under_t *u);

/* One sweep's n returns placed in the map frame (x y z doubles, as the map placed them:
 * pb_map_builder_place_timed), return i being pts' return index[i] (index NULL: the i-th). From
 * pts (NULL: none of these) its intensity, its position in the sensor's frame and its column
 * (offset_us: the returns of one firing share their time; a sweep with more than 256 of them
 * one after the other at one time has no columns). */
void pb_under_sweep(pb_under_t *u, const double *xyz, size_t n, const pb_points_t *pts = nullptr,
                    const int32_t *index = nullptr);

/* 1 when a sweep at time t (on the clock of hit) may have a return in a body: one was hit at
 * t, between its first and last hit; else 0. pb_under_sweep takes nothing from a sweep at
 * any other time (a body return marks what it takes), so such a sweep need not be read. */
int pb_under_busy(pb_under_t *u, int64_t t);

/* A voxel's map point p (x y z intensity) of n returns: p without the returns taken out of
 * its voxel, when it lies higher than lifted_m over the ground and no higher than road_max_m.
 * Returns the returns left (0: the voxel goes; n: p unchanged). */
uint32_t pb_under_adjust(const pb_under_t *u, float p[4], uint32_t n);

/* After pb_under_adjust, the bumps: what a tyre left of a voxel that no body return of its
 * sweeps came near (the tests above need one). A bump is a patch of map points no wider than
 * bump_reach_m (points within two voxels of each other joined), each of them within bump_reach_m
 * of a column where a body stood (a wheel stands at its body's corner, and only the body's
 * voxels the map held were carved), bump_m to return_max_m over the ground, and bump_m or more over every map
 * point not of the patch within bump_reach_m of it (x-y); its neighbours there fill bump_fill of the voxel columns there: the
 * road seen all round it, and nothing over it. A kerb's row is wider; a post or a bush's foot
 * has itself above; a ditch's edge is not over the ground. Measured on the simulated drives
 * (points on moving objects, true poses): loop 30 -> 8, hills 8 -> 3, no static point; each
 * left is beside another lifted voxel farther than two voxels. On MulRan 13 of 1.28 M points. Within bump_reach_m of
 * where a body stood rather than in its columns (5 Dec): one more on each of the loop and the
 * hills, with the mapper's poses and with the true ones, nothing static, MulRan's map the same.
 * pb_under_near says which map points a bump test may need (those within twice bump_reach_m
 * of a column where a body stood); pb_under_bumps takes them (x y z floats, stride floats apart),
 * sets gone[i] = 1 for each point of a bump and returns their number. */
int pb_under_near(const pb_under_t *u, const float p[3]);
size_t pb_under_bumps(const pb_under_t *u, const float *xyz, size_t n, size_t stride, uint8_t *gone);

/* After pb_under_adjust, the one-look voxels: a voxel of the road band (lifted_m to road_max_m
 * over the ground) whose returns all came in one sweep goes when a voxel beside it (its 3 x 3
 * columns, at its level or the one below) held look_returns returns or more over look_span_s
 * or longer. The road there was in view for seconds, and what stands on it returns in sweep
 * after sweep; one look is a tyre's or a foot's bottom where no body return came near (the
 * tests above need one). Measured on the simulated loop (LiDAR alone, the mapper's poses, 7 Dec
 * 2026): the 7 points left on moving objects were all voxels of one return 5-9 cm over the
 * ground, beside voxels of 20-146 returns over 11-230 s; this takes them and 3,638 more of the
 * band (of 7.30 M; the share within 5 cm of the static world the same, 96.85 %). On the hills
 * it takes 957 and leaves the 3 there: a wheel's returns 20-28 cm up, over road seen 1-5 times
 * in 3 s or less (no evidence either way). On MulRan it takes none.
 * pb_under_look notes map point p (its voxel first and last hit at those times) when it is
 * such a voxel and returns its number (0, 1, ...), else -1; pb_under_look_support gives it
 * every map point (of n returns), in any order; pb_under_look_gone then says whether look
 * number i goes. */
int pb_under_look(pb_under_t *u, const float p[3], int64_t first, int64_t last);
void pb_under_look_support(pb_under_t *u, const float p[3], uint32_t n, int64_t first, int64_t last);
int pb_under_look_gone(const pb_under_t *u, int i);

/* Returns taken out so far, and the voxels they came from. */
void pb_under_counts(const pb_under_t *u, uint64_t *returns, uint64_t *voxels);

#endif
