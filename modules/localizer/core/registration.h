/* registration: aligns one LiDAR sweep to the prior map (pb_regmap_t).
 *
 * Frames and units: the scan is given in `base` (metres), already deskewed to
 * the time the pose refers to (see deskew.h). Poses are map <- base as
 * Eigen::Isometry3d (the same as pb_transform_t: rotation base -> map, then
 * translation; convert with pb_reg_to_transform / pb_reg_from_transform).
 *
 * Method (chosen on docs/localizer-registration.md's benchmark): the scan is
 * voxel-downsampled (adaptively, to about cfg.target_points), then Gauss-Newton
 * on SE(3) minimises a robust (Geman-McClure) point-to-plane distance to the
 * plane stored in the map cell each point falls into (O(1) hash lookup, no
 * k-d tree), tightening the correspondence gate as it converges.
 *
 * Pipeline of pb_reg_align:
 *   1. downsample the scan (range filter + adaptive voxel grid);
 *   2. Gauss-Newton on the fine level from the guess: transform, look up
 *      cells, accumulate J^T W J and J^T W r, solve the damped 6x6 system,
 *      update, shrink the gate, stop on a small step;
 *   3. only if that did not converge or moved more than min_corr_m / 1 deg
 *      (a poor guess): again from the guess, first a few steps on the coarse
 *      map level (every 4th point, wide gate), then the fine level; the fine
 *      run, if it stopped early, is finished (without a prior, followed on
 *      every 4th point first: arriving near the coarse-to-fine minimum, it is
 *      taken to end there) and the result with more inliers wins (see prior_sigma_m);
 *   4. at the result: covariance, scores and divergence evidence.
 *
 * Ownership: a pb_reg_result_t is a plain value. pb_reg_align does not keep any
 * pointer; it allocates scratch internally per call (no state between calls).
 * Thread-safe for different results against one (read-only) map. */
#ifndef PB_LOC_REGISTRATION_H
#define PB_LOC_REGISTRATION_H

#include <stddef.h>
#include <vector>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include "pb_err.h"
#include "pb_math.h"
#include "regmap.h"

/* max_iterations 0 (and coarse_iterations 0) only evaluates the guess: the
 * result's scores then describe the given pose (e.g. the filter's), for a
 * divergence test. The defaults stand beside each field (a value-initialised
 * struct holds them). */
typedef struct {
    double scan_voxel_m = 0.5;    /* first downsampling cell, metres */
    int target_points = 2000;     /* adaptive downsampling aims for this many points (0 = fixed voxel) */
    double min_range_m = 2.0;     /* drop points nearer than this to base (the car itself) */
    double max_range_m = 80;      /* and farther than this */
    int max_iterations = 12;      /* Gauss-Newton iterations */
    double max_corr_m = 1.0;      /* initial correspondence gate, metres */
    double min_corr_m = 0.3;      /* the gate shrinks to this as steps get small */
    double kernel_m = 0.1;        /* Geman-McClure scale, metres */
    double step_eps_m = 5e-4;     /* stop when translation step < this (0.5 mm, a tenth of the error) ... */
    double step_eps_rad = 5e-5;   /* ... and rotation step < this */
    double inlier_m = 0.1;        /* |point-to-plane| for the inlier fraction */
    int rough_targets = 0;        /* 1 = a point with no plane or line near is pulled by its rough cell's
                                   * Gaussian (foliage). Off by default: on MulRan it tracks better, on the
                                   * simulated porous street LiDAR-only moving starts fail more often
                                   * (docs/localizer-registration.md); never for refinement of disturbed
                                   * poses, where a thick surface is misalignment, not foliage */
    int coarse_iterations = 16;   /* Gauss-Newton steps on the coarse level in step 3, 0 = never */
    double prior_sigma_m = 0;     /* the guess's horizontal standard deviation (a tracking filter's prediction);
                                   * when one of step 3's two results lies more than 3 sigma from the guess,
                                   * the farther must explain clearly more of the scan to be taken, however
                                   * near the two lie; 0 = no prior: more inliers wins, and a fine run stopped early
                                   * ends where it comes near the coarse-to-fine minimum (step 3) */
    double body_box[6] = {};      /* drop points inside this box of base (the car's own body: xmin, ymin, zmin,
                                   * xmax, ymax, zmax); all 0 = none */
    double same_minimum_m = 0.02; /* pb_reg_align_global: a candidate whose refinement comes within this ... */
    double same_minimum_rad = 1.7453292519943296e-3;   /* ... and this (0.1 degree) of the best minimum so
                                   * far stops there, as that minimum again; 0 = each refined to its end */
    double line_along_view = 1.0; /* the weight of the part of a point's distance to a line (a pole, a
                                   * trunk) that lies along its view from view_xyz; across the view it
                                   * weighs 1. A sweep sees the arc of a pole that faces it: along the
                                   * view the distance is partly the arcs' offset, not the pose's. 1 for
                                   * a site's map, seen from all along the road (the offsets mostly
                                   * cancel, and that part is much of what fixes the pose along a street
                                   * of trunks); the mapper's local map saw each pole from the sweeps
                                   * behind only: 0.3 there (docs/history/mapper.md, "Poles seen from
                                   * one side") */
    double view_xyz[3] = {};      /* the LiDAR's origin in base (the vehicle file's sensors.lidar.xyz) */
} pb_reg_config_t;

void pb_reg_config_default(pb_reg_config_t *cfg);

/* Return codes of pb_reg_align / pb_reg_align_global (result.status). */
enum {
    PB_REG_OK = 0,            /* converged (step below eps) */
    PB_REG_MAX_ITER = 1,      /* ran out of iterations; pose is the last iterate (often fine) */
    PB_REG_FEW_POINTS = 2,    /* fewer than 30 scan points matched the map: pose = guess */
    PB_REG_BAD_INPUT = -1     /* n == 0, NULL map, non-finite guess: err set, pose = guess */
};

typedef struct {
    int status;                  /* PB_REG_* */
    Eigen::Isometry3d pose;      /* map <- base at the scan's reference time */
    /* Covariance of the pose, 6x6, of the error state [dt (m); dtheta (rad)]
     * with both parts in the map frame: t' = t + dt, R' = Exp(dtheta) R (a
     * rotation about the vehicle, not about the map origin). For a level car
     * dtheta is approximately (roll, pitch, yaw) errors.
     * From the inverse Gauss-Newton Hessian scaled by the residual variance
     * (sigma^2 = robust mean square residual). Degenerate directions show as
     * large variances (the Hessian is damped by 1e-6 before inversion). */
    Eigen::Matrix<double, 6, 6> covariance;
    Eigen::Matrix<double, 6, 1> hessian_eigenvalues;  /* of J^T W J / matched points, ascending */
    double condition;            /* largest / smallest eigenvalue of the translation block */
    int iterations;
    int points_used;             /* scan points after downsampling */
    int points_matched;          /* with a map cell within the gate at the result */
    /* Divergence evidence, all at the result pose: */
    double overlap;              /* points_matched / points_used (0..1) */
    double inlier_fraction;      /* share of points_used with |residual| < inlier_m */
    double rmse_m;               /* RMS residual of matched points */
    double median_abs_m;         /* median |residual| of matched points */
    double score;                /* mean Geman-McClure similarity (1 = perfect), NDT-like */
    /* Appended after the first API commit. The ground is often half the points
     * and fixes only z, roll and pitch, so inlier_fraction stays near 0.5 at a
     * pose 0.5 m off sideways. This one counts only points whose target is
     * upright (walls, poles: |normal z| < 0.7), i.e. those that see horizontal
     * errors: inliers among them / all of them (any distance). NaN if none. */
    double upright_inlier_fraction;
    int upright_points;          /* its denominator */
} pb_reg_result_t;

/* Aligns n points (xyz interleaved, base frame, deskewed) to the map starting
 * at guess (map <- base). cfg NULL = defaults. Returns result->status (>= 0 is a
 * usable pose, see enum); on -1 err is set. */
int pb_reg_align(const pb_regmap_t *map, const float *xyz, size_t n,
                 const Eigen::Isometry3d &guess, const pb_reg_config_t *cfg,
                 pb_reg_result_t *result, pb_err_t *err);

/* pb_reg_align with the guess as a prior of covariance prior_cov (6x6, the result's
 * error state; a tracking filter's prediction): each fine Gauss-Newton step weighs the
 * distance from the guess by prior_cov^-1 beside the points (weighted by their mean
 * square residual, as the result's covariance is). Directions the sweep fixes well move
 * as they would without it; a direction it hardly fixes (along a street of porous crowns)
 * stays near the guess instead of ending wherever the run's start leads it. The result's
 * covariance is the points' alone. -1 (err set) also when prior_cov is not positive
 * definite. */
int pb_reg_align_prior(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &guess,
                       const Eigen::Matrix<double, 6, 6> &prior_cov, const pb_reg_config_t *cfg,
                       pb_reg_result_t *result, pb_err_t *err);

/* Global alignment for initialisation and relocalisation: the true pose is within
 * `radius_m` (horizontal) of seed's position and within +-yaw_range_rad (up to pi)
 * of seed's yaw (z, roll and pitch taken from seed). Every position and yaw of that
 * window is scored by branch and bound on the map's structure above the ground
 * (window_search.h); the best few distinct ones are refined with pb_reg_align (one
 * whose refinement comes within cfg->same_minimum_m / _rad of a minimum already
 * found stops there), and the one with the most inliers is returned. result->inlier_fraction
 * and ->overlap tell whether to trust it. */
int pb_reg_align_global(const pb_regmap_t *map, const float *xyz, size_t n,
                        const Eigen::Isometry3d &seed, double radius_m, double yaw_range_rad,
                        const pb_reg_config_t *cfg, pb_reg_result_t *result, pb_err_t *err);

/* Structure fit: the share of n points (base frame) that lie on the map at pose:
 * within inlier_m of a plane or line target, or inside a cell of rough structure
 * (foliage, fences: occupied by map points without a target) or next to one within
 * rough_m. Evaluated at the pose, not optimised. *counted: points that had a map cell
 * near them at all (the rest are in free space). Returns the share, NaN for n == 0. */
double pb_reg_structure_fit(const pb_regmap_t *map, const float *xyz, size_t n, const Eigen::Isometry3d &pose,
                            double inlier_m, double rough_m);

/* Downsamples n points to about cfg->target_points (one centroid per voxel,
 * voxel grown geometrically from scan_voxel_m), after the range filter; out is
 * resized. Deterministic. pb_reg_align calls this itself; exposed for benches. */
void pb_reg_downsample(const float *xyz, size_t n, const pb_reg_config_t *cfg,
                       std::vector<float> *out);

/* Conversions between the project's C transform and Eigen. */
Eigen::Isometry3d pb_reg_from_transform(const pb_transform_t *t);
void pb_reg_to_transform(const Eigen::Isometry3d &T, pb_transform_t *out);

#endif
