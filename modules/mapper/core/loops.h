/* loops: loop closure for the mapper. Where the drive comes back to a place it passed
 * before, the sweep there is registered to the map of the earlier pass; each such match
 * found good becomes a loop edge, and the keyframes' poses are solved again over the
 * odometry edges and the loop edges together.
 *
 * Pipeline of pb_loops_close:
 *   1. candidates, each kind tried at most once per try_every keyframes:
 *      a. by position: the nearest earlier keyframe within search_radius_m (by the
 *         odometry's positions) that is at least min_separation_m of path behind it;
 *      b. by place recognition: each keyframe's Scan-Context-like descriptor (the
 *         localizer's places_describe / places_compare: highest structure in a polar grid
 *         around the base, compared under every sector shift, which gives the yaw, so a
 *         place driven the other way is found too); among the keyframes at least
 *         min_separation_m of path behind (no position gate: this is what finds a loop
 *         after drift beyond search_radius_m), the place_candidates most alike distinct
 *         places, at most place_max_distance apart, that the odometry can have drifted from
 *         (the bound of step 2, tested before any registration);
 *   2. verification: the keyframe's points registered (pb_reg_align) to a map of the
 *      stored keyframes within submap_radius_m of path around the earlier one, from the
 *      odometry's pose (a) or from the earlier keyframe's pose turned by the descriptor's
 *      yaw (b), and searched for (pb_reg_align_global) when that does not fit; kept if
 *      min_inliers of the points above the ground lie on the map's surfaces and the
 *      correction of the keyframe's pose is one the odometry can have drifted: at most
 *      max_correction_m plus max_drift (a) or place_max_drift (b) of the path between,
 *      and max_correction_deg plus max_drift_deg per 100 m of it;
 *   3. agreement: two loops agree when the cycle (a's earlier keyframe, by the odometry to
 *      b's, over b's loop, by the odometry back to a's later one, over a's loop) closes
 *      within max_correction_m + max_drift and max_correction_deg + max_drift_deg of its
 *      two odometry legs. The largest set of loops that agree pairwise (greedily, from the
 *      loop with the most partners) is kept, the others dropped; a loop by place needs a
 *      partner. A place that merely looks alike (a street that repeats itself) passes
 *      step 2 often; this is what refuses it when it lies within the drift bounds;
 *   4. pose graph (Ceres: a maintained sparse least-squares solver, in Debian, with
 *      manifolds for rotations; GTSAM is not packaged for Debian 12, g2o has no released
 *      Debian package with a stable API): odometry edges between consecutive keyframes,
 *      the loop edges, the first keyframe fixed. A false loop that passed steps 2-3 cannot
 *      agree with the odometry and the other loops: after the solve, the loop whose edge
 *      is off the solution by more than loop_reject_m is dropped and the graph solved
 *      again, until every loop left agrees. (Not a robust loss: a true loop after a long
 *      drive is many sigmas off the odometry, and a loss scaled to the edges' noise would
 *      down-weight exactly the loops that matter.)
 *
 * Several drives of the same course (the keyframes in drive order, drive 0 first): no
 * odometry edge joins two drives, and each later drive is first placed in the map of the
 * drives before it (pb_loops_close's step 0): its keyframes' descriptors are compared with
 * the earlier drives' (no position or drift gate: its odometry frame is its own), the most
 * alike verified by registration as in step 2 (no drift bound), and the drive is placed by
 * the first verified match that a second one, at least submap_radius_m of its path further
 * on, agrees with (as in step 3). Those two matches join the loops; its keyframes, moved
 * by the placement, then go through steps 1-4 with the rest (every keyframe of an earlier
 * drive counts as far enough behind; the path between keyframes of two drives, for the
 * drift bounds, is counted through the drives one after the other: loose). A drive
 * no two matches agree for is not placed (never placed by one look-alike); nor is one
 * whose links to the earlier drives all disagreed with the graph (steps 3-4): the whole is
 * then done again without it. An unplaced drive's poses come back unchanged.
 *
 * Frames: poses are map <- base (a later drive's odometry: its own frame); keyframe points
 * are in base. Pure: no I/O, no clock;
 * deterministic (Ceres with one thread).
 * Ownership: the caller owns every array; nothing is kept after the call. */
#ifndef PB_MAPPER_LOOPS_H
#define PB_MAPPER_LOOPS_H

#include <stdint.h>
#include <vector>
#include <Eigen/Geometry>
#include "pb_err.h"
#include "registration.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double search_radius_m = 15;     /* a candidate lies within this of the keyframe (odometry positions) */
    double min_separation_m = 100;   /* ... and at least this much path behind it */
    double submap_radius_m = 30;     /* the earlier pass's map: stored keyframes within this of the candidate */
    double min_inliers = 0.4;        /* a loop match must put this share of the keyframe's points above the
                                      * ground on the map's surfaces (the ground fits a pose metres off) */
    double max_correction_m = 1.0;   /* and move the keyframe by at most this ... */
    double max_drift = 0.02;         /* ... plus this share of the path between the two (by position) */
    double place_max_drift = 0.15;   /* ... or this share (by place: drift beyond search_radius_m is
                                      * what these candidates are for) */
    double max_correction_deg = 3;   /* and turn it by at most this plus ... */
    double max_drift_deg = 10;       /* ... this per 100 m of the path between */
    int try_every = 5;               /* each kind of candidate is tried at most once per this many keyframes */
    int place_candidates = 2;        /* by place: the most alike earlier places tried */
    double place_max_distance = 0.06; /* ... if their descriptor distance (0..1) is at most this (the
                                      * simulated loop: the same place 0.01-0.05, others 0.04 up) */
    double place_search_m = 4;       /* ... searched within this of the earlier keyframe's position */
    double search_yaw_deg = 10;      /* a match that does not fit from its seed is searched for within
                                      * the correction allowed (by position) or place_search_m (by
                                      * place) and this yaw */
    double odom_sigma_m = 0.01;      /* odometry edge: per metre of the step, and at least this */
    double odom_sigma_deg = 0.05;    /* rotation, per edge */
    double loop_sigma_m = 0.05;      /* loop edge */
    double loop_sigma_deg = 0.1;
    double loop_reject_m = 0.3;      /* a loop edge this far off the solved poses is dropped */
    pb_reg_config_t reg;             /* a match's registration (its view_xyz: the vehicle's LiDAR) */
} pb_loops_config_t;

typedef struct {
    int64_t utime;
    Eigen::Isometry3d pose;          /* map <- base from the odometry */
    std::vector<float> xyz;          /* base frame, deskewed, downsampled; may be empty (no submap use) */
    int drive = 0;                   /* several drives: 0, 1, ... in order (no odometry edge between two) */
    uint64_t points_key = 0;         /* with a pb_keyframe_points_t: where it finds xyz (xyz left empty) */
} pb_keyframe_t;

/* Keyframes' points kept elsewhere (the mapper: its keyframes.bin), so that loop closure holds
 * only those it works on (a few hundred at a time), not an hour of drive's: read fills *xyz
 * with keyframe k's points (as pb_keyframe_t.xyz) and returns 0, or -1 with err. */
typedef struct {
    int (*read)(void *user, const pb_keyframe_t &k, std::vector<float> *xyz, pb_err_t *err);
    void *user;
} pb_keyframe_points_t;

/* Per drive: how it was placed in the map of the drives before it (drive 0: the map's frame). */
typedef struct {
    bool placed;
    const char *why;                 /* not placed: why (static text) */
    int tried, matched;              /* step 0: matches to the earlier drives tried, verified */
    int links;                       /* loops kept between it and other drives */
    Eigen::Isometry3d placement;     /* map <- the drive's odometry frame, before the solve */
} pb_drive_report_t;

typedef struct {
    int candidates, verified, rejected;  /* loops tried, kept, refused by step 2 */
    int dropped;                         /* verified but disagreeing with the rest (step 3 or 4) */
    int place_candidates, place_loops;   /* of those tried and kept: found by place recognition */
    int iterations;                      /* of the solver */
    double max_change_m;                 /* largest move of a keyframe by the solve */
    std::vector<std::pair<int, int>> loops;  /* the kept loops (earlier, later keyframe) */
    std::vector<std::pair<int, int>> refused; /* the candidates refused or dropped (earlier, later) */
    std::vector<pb_drive_report_t> drives;    /* one per drive */
} pb_loops_report_t;

/* Solves the keyframes' poses (n = kf.size()) with the loops found; out gets n poses, in
 * drive 0's frame (an unplaced drive's: as given). points: where the keyframes' points are
 * read from (NULL: kf[k].xyz). Returns 0, or -1 with err set (fewer than two keyframes,
 * drives not numbered 0, 1, ... in order, points that cannot be read). With no loop, out =
 * the input. */
int pb_loops_close(const std::vector<pb_keyframe_t> &kf, const pb_loops_config_t *cfg,
                   std::vector<Eigen::Isometry3d> *out, pb_loops_report_t *report, pb_err_t *err,
                   const pb_keyframe_points_t *points = nullptr);

#endif
