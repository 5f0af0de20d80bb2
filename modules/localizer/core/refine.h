/* refine: multi-scan refinement of a sequence of LiDAR poses (a better
 * reference than a SLAM estimate, and the mapper's consistency step).
 *
 * Each round registers every scan, with the localizer's registration
 * (pb_reg_align), to the map of each single scan near it (within
 * neighbour_radius_m, the nearest max_neighbours), starting from their current
 * relative pose: one relative-pose edge per pair, with the registration's
 * covariance (pairs, not a map of many scans, so one scan's error never shows
 * as doubled walls that the others lock onto). Then all poses are solved at
 * once by least squares over the edges (Gauss-Newton, Cauchy-robust), and the
 * whole set is moved back by the one rigid transform that best aligns it with
 * the input poses (the input fixes the frame: refinement removes
 * inconsistency, not the frame). Rounds repeat until the largest move is
 * below stop_m or max_rounds.
 *
 * How good the result is, measured by pb_refine_poses itself (pb_refine_report_t):
 *   edge residuals: how far each pair's registration disagrees with the
 *     solved poses (translation, m);
 *   leave-one-out: each scan registered to a map of all the other scans near
 *     it at their refined poses; how far it would still move (median / p90 /
 *     max). Small = the poses agree with each other.
 *   fit: share of each scan's points within 0.1 m of the map of the others,
 *     at the input poses and at the refined poses.
 *
 * Frames: poses are map <- sensor; scans are points in the sensor frame (one
 * instant, deskewed). Pure: no I/O, no clocks; deterministic.
 * Ownership: the caller owns every array; nothing is kept after the call. */
#ifndef PB_LOC_REFINE_H
#define PB_LOC_REFINE_H

#include <vector>
#include <Eigen/Geometry>
#include "pb_err.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double neighbour_radius_m = 40;  /* scans within this distance form a scan's map */
    int max_neighbours = 30;         /* the nearest this many */
    int max_rounds = 8;
    double stop_m = 0.005;           /* stop when no scan moves more than this in a round */
    double voxel_m = 0.5;            /* map cell of the neighbour maps */
    int min_points_used = 200;       /* a scan whose match uses fewer points keeps its pose */
    double min_pair_inliers = 0.3;   /* a pair registration with a smaller inlier share gives no edge */
    int coarse_iterations = 0;       /* pb_reg_config_t's coarse retry; 0 = fine level only (the input
                                      * is within a metre, and the coarse level can alias repeated structure) */
} pb_refine_config_t;

void pb_refine_config_default(pb_refine_config_t *cfg);

typedef struct {
    int rounds;
    std::vector<double> moved_m;        /* per round: the largest move of a scan */
    std::vector<double> loo_m, loo_deg; /* per scan: leave-one-out move after the last round */
    std::vector<double> fit_before, fit_after;  /* per scan: inlier share against the others */
    std::vector<double> change_m;       /* per scan: refined minus input position */
    int kept;                           /* scans with no edge in the last round (left where the graph puts them) */
    int edges;                          /* pair registrations used in the last round */
    std::vector<double> edge_resid_m;   /* per edge: translation residual at the solution */
} pb_refine_report_t;

/* Refines poses (n of them, in/out) of scans[k] (xyz interleaved, sensor frame).
 * progress (may be NULL) is called after each round with (round, largest move). */
int pb_refine_poses(const std::vector<std::vector<float>> &scans, std::vector<Eigen::Isometry3d> *poses,
                    const pb_refine_config_t *cfg, pb_refine_report_t *report, void (*progress)(int, double, void *),
                    void *user, pb_err_t *err);

#endif
