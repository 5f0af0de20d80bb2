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

#endif
