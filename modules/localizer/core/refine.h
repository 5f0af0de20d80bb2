/* refine: multi-scan refinement of a sequence of LiDAR poses (a better
 * reference than a SLAM estimate, and the mapper's consistency step).
 *
 * Each round registers every scan, with the localizer's registration
 * (pb_reg_align), to a map built from the OTHER scans near it (within
 * neighbour_radius_m of its pose, at their current poses; itself left out).
 * All scans move at once to their registered poses (a Jacobi step of the
 * multi-view alignment), then the whole set is moved back by the one rigid
 * transform that best aligns it with the input poses (the input fixes the
 * frame: refinement removes inconsistency, not the frame). Rounds repeat until
 * the largest move is below stop_m or max_rounds.
 *
 * How good the result is, measured by pb_refine_poses itself (refine_report_t):
 *   leave-one-out: one more round after the last; how far each scan would
 *     still move given all the others (median / p90 / max). Small = the poses
 *     agree with each other.
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

typedef struct {
    double neighbour_radius_m;  /* scans within this distance form a scan's map (default 40) */
    int max_neighbours;         /* the nearest this many (default 30) */
    int max_rounds;             /* (default 8) */
    double stop_m;              /* stop when no scan moves more than this in a round (default 0.005) */
    double voxel_m;             /* map cell of the neighbour maps (default 0.5) */
    int min_points_used;        /* a scan whose match uses fewer points keeps its pose (default 200) */
} refine_config_t;

void refine_config_default(refine_config_t *cfg);

typedef struct {
    int rounds;
    std::vector<double> moved_m;        /* per round: the largest move of a scan */
    std::vector<double> loo_m, loo_deg; /* per scan: leave-one-out move after the last round */
    std::vector<double> fit_before, fit_after;  /* per scan: inlier share against the others */
    std::vector<double> change_m;       /* per scan: refined minus input position */
    int kept;                           /* scans left at their pose (too few matched points) in the last round */
} refine_report_t;

/* Refines poses (n of them, in/out) of scans[k] (xyz interleaved, sensor frame).
 * progress (may be NULL) is called after each round with (round, largest move). */
int refine_poses(const std::vector<std::vector<float>> &scans, std::vector<Eigen::Isometry3d> *poses,
                 const refine_config_t *cfg, refine_report_t *report, void (*progress)(int, double, void *),
                 void *user, pb_err_t *err);

#endif
