/* anchor: GNSS anchoring for the mapper. The trajectory is in the frame of its first pose;
 * the receiver's fixes say where the antenna was on the earth. The rigid transform that
 * takes the trajectory's antenna positions onto the fixes (in a local east-north-up frame)
 * places the map on the earth: it becomes the site's geo-reference.
 *
 * Pipeline of pb_anchor_fit:
 *   1. gate: fixes without a 3-D solution, or whose reported horizontal accuracy is worse
 *      than max_h_acc_m, are not used;
 *   2. fit: the rigid transform (rotation and translation, no scale; Umeyama's closed form)
 *      from the antenna positions to the fixes, each fix weighted by 1 / h_acc^2;
 *   3. reject: fixes farther from the fitted positions than reject_sigmas times the median
 *      distance (and at least min_reject_m) are outliers (multipath, a jump); fit again
 *      without them, until none is rejected;
 *   4. refuse: fewer than min_fixes left, or the antenna positions spanning less than
 *      min_extent_m (the heading would be a guess): not anchored, and the result says why.
 *
 * A rigid transform cannot take out drift: when the fitted trajectory stays farther from the
 * fixes than they say they err, pb_anchor_hold bends it onto them (a pose graph).
 *
 * Pipeline of pb_anchor_hold (the drives' trajectories already moved onto the fixes by
 * pb_anchor_fit):
 *   1. test: held only when the fit's residual p90 exceeds inconsistent_ratio times the
 *      fixes' median reported accuracy, i.e. the fixes see a drift their own errors do not
 *      explain (a trajectory that fits them rigidly is left as it is: its shape is better
 *      than theirs over the few hundred metres their errors are correlated);
 *   2. nodes: a pose every node_spacing_m of each drive's path; steps between them are edges
 *      (the trajectory's own shape, with step_sigma_* freedom); the places the loops joined
 *      (within a drive or between two) are edges too, as tight as a loop (link_sigma_*) and
 *      never loosened: bent onto the fixes, a drive still meets itself and the other drives
 *      where the registration said it does (held one by one, two drives would part by the
 *      fixes' own error);
 *   3. fixes: at most one per fix_every_s (a receiver's errors are correlated over
 *      seconds: ten a second would count one error ten times), each a unary edge on the
 *      antenna's position at the fix's time, seen from the node before it; accuracy as
 *      reported, vertical 1.5 times horizontal; a Cauchy loss (multipath, jumps);
 *   4. solve (Ceres, one thread; no node fixed: the fixes hold the frame); while the fixes
 *      still disagree beyond inconsistent_ratio, again with the steps' freedom tripled (the
 *      odometry drifted more than its sigmas say), up to max_rounds; every pose moved by its
 *      nodes' corrections (pose_graph.h).
 *
 * Pure: no I/O, no clock. Ownership: plain values; nothing is kept. */
#ifndef PB_MAPPER_ANCHOR_H
#define PB_MAPPER_ANCHOR_H

#include <vector>
#include <Eigen/Geometry>
#include "pb_err.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double max_h_acc_m = 10;     /* fixes reporting a worse horizontal accuracy are not used */
    double reject_sigmas = 4;    /* outlier: farther than this many times the median distance ... */
    double min_reject_m = 2;     /* ... and than this */
    int min_fixes = 10;
    double min_extent_m = 30;    /* the antenna positions must span this (largest distance between two) */
} pb_anchor_config_t;

typedef struct {
    int64_t utime = 0;             /* of the fix (pb_anchor_hold) */
    Eigen::Vector3d antenna_map;   /* where the trajectory puts the antenna at the fix's time (map frame) */
    Eigen::Vector3d fix_enu;       /* the fix in the local east-north-up frame, metres */
    double h_acc_m;                /* the receiver's horizontal accuracy */
    int fix_3d;                    /* 1 for a 3-D fix (or better) */
} pb_anchor_obs_t;

typedef struct {
    int anchored;                  /* 1: enu_from_map is valid */
    const char *why;               /* when not: a sentence (static storage) */
    Eigen::Isometry3d enu_from_map;
    int used, gated, rejected;     /* fixes in the fit, refused by the gate, rejected as outliers */
    double resid_median_m, resid_p90_m, resid_max_m;  /* distances fix - fitted antenna, over the used ones */
    double extent_m;
} pb_anchor_result_t;

/* Fits obs; returns 0 (result->anchored tells whether it did), -1 with err for no input. */
int pb_anchor_fit(const std::vector<pb_anchor_obs_t> &obs, const pb_anchor_config_t *cfg, pb_anchor_result_t *result,
                  pb_err_t *err);

typedef struct {
    double inconsistent_ratio = 3;   /* held when the fit's residual p90 > this x the fixes' median h_acc */
    double node_spacing_m = 2;       /* graph nodes along the path */
    double fix_every_s = 1;          /* at most one fix in the graph per this */
    double step_sigma_m = 0.01;      /* a step between nodes: per metre of it, at least 1 cm ... */
    double step_sigma_deg = 0.05;    /* ... and this per step */
    double loss_sigmas = 3;          /* Cauchy loss scale, in sigmas of the fix */
    int max_rounds = 4;              /* solves, the steps' freedom tripled each time the fixes still disagree */
    double link_sigma_m = 0.05;      /* a place the loops joined (pb_loops_config_t's loop edge) */
    double link_sigma_deg = 0.1;
} pb_anchor_hold_config_t;

/* One drive for pb_anchor_hold: its poses (enu <- base, every sweep in time order, at utime;
 * moved in place) and its fixes (the obs of pb_anchor_fit, fix_enu in the same ENU frame). */
typedef struct {
    std::vector<int64_t> utime;
    std::vector<Eigen::Isometry3d> poses;
    std::vector<pb_anchor_obs_t> obs;
} pb_anchor_drive_t;

/* Two places the loops found to be one: drive a at time a, drive b at time b (indices into
 * the drives; a == b for a loop within a drive). */
typedef struct {
    int a_drive;
    int64_t a_utime;
    int b_drive;
    int64_t b_utime;
} pb_anchor_link_t;

typedef struct {
    int held;                        /* 1: the trajectory was bent onto the fixes */
    double ratio;                    /* the fit's residual p90 / the fixes' median h_acc (step 1) */
    int nodes, fixes, links, iterations;   /* of the graph */
    double max_change_m;             /* largest move of a pose */
    double step_scale;               /* the steps' freedom used, times step_sigma_* */
    double resid_p90_m;              /* the fixes' p90 distance from the held antenna */
} pb_anchor_hold_result_t;

/* Step 1-4 above on the drives (their poses moved in place) joined by links (a link outside
 * its drives' times is not used), with pb_anchor_fit's result on all their fixes. antenna:
 * the antenna's position in base. Returns 0 (result->held tells whether it bent anything),
 * -1 with err (the graph did not solve; poses unchanged). */
int pb_anchor_hold(std::vector<pb_anchor_drive_t> *drives, const std::vector<pb_anchor_link_t> &links,
                   const pb_anchor_result_t &fit, const Eigen::Vector3d &antenna, const pb_anchor_hold_config_t *cfg,
                   pb_anchor_hold_result_t *result, pb_err_t *err);

#endif
