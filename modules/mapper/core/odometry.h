/* odometry: LiDAR odometry for the mapper. Each sweep is registered to a rolling
 * local map of the sweeps before it, with the localizer's registration core
 * (registration.h: point-to-plane Gauss-Newton on a voxel hash of local planes).
 *
 * Frames and units: points in `base` (metres; move LiDAR points with base <- lidar
 * first), each with its time after the sweep's utime. Poses are map <- base at the
 * middle of the sweep (result.utime); `map` is the base frame of the first sweep.
 *
 * Pipeline of pb_odom_add:
 *   1. predict the pose at the sweep's middle: dead reckoning on the car's own speed
 *      (VEHICLE_SPEED) and turn rate (IMU gyro) when both came with the sweep, else the
 *      last step's motion carried on (constant velocity; none yet on the first steps)
 *      with the speed or the rate in place of its part when one of them came;
 *   2. deskew the sweep to its middle with the motion at the sweep (the measured one
 *      when there is one);
 *   3. register it to the local map from the prediction; when the motion is not yet
 *      known, or too few points match, search around the prediction instead
 *      (pb_reg_align_global);
 *   4. the step from the last pose gives the next motion;
 *   5. add the sweep's points to the local map (one centroid per cell), and every
 *      few metres rebuild the registration map from the cells near the car (after
 *      every sweep, at once, when the sweeps come far apart).
 *
 * No I/O and no clock: the same sweeps give the same poses.
 * Ownership: pb_odom_create and pb_odom_restore return an object the caller frees with
 * pb_odom_destroy (NULL is a no-op). Inputs are copied; no pointer into them is kept. */
#ifndef PB_MAPPER_ODOMETRY_H
#define PB_MAPPER_ODOMETRY_H

#include <stddef.h>
#include <stdint.h>
#include <vector>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include "pb_err.h"
#include "registration.h"

/* The defaults stand beside each field (a value-initialised struct holds them). */
typedef struct {
    double cell_m = 0.25;            /* local map: one centroid per cell of this edge (the mapper takes
                                      * pb_odom_cell_m of its sensor's columns) */
    double local_radius_m = 100;     /* the registration map holds the cells within this of the car */
    double rebuild_m = 10;           /* rebuild the registration map after the car moved this far ... */
    int rebuild_sweeps = 30;         /* ... or after this many sweeps (the LiDAR sees far ahead: the
                                      * map of 10 m ago still covers the sweep) */
    double weak_inlier_fraction = 0.3; /* a match explaining less than this is counted weak (the
                                        * report); not searched again: real roadsides (foliage)
                                        * explain 10-20 % at the right pose, and a search then
                                        * finds wrong places that explain as much */
    double search_radius_m = 10;     /* that search: within this of the prediction ... */
    double search_yaw_deg = 30;      /* ... and this of its yaw */
    double prior_sigma_m = 0.5;      /* spread of the constant-velocity prediction (registration.h) */
    double measured_sigma_m = 0.2;   /* with speed and rate measured, the dead reckoning over a sweep is the
                                      * match's prior, of this spread ... */
    double measured_sigma_deg = 0.5; /* ... and this: a street of porous crowns hardly fixes its length, and
                                      * a match there stalled 0.8 m in a sweep at 10 m/s against CAN's
                                      * speed (docs/history/mapper.md, "The measured motion as a prior") */
    double sparse_gap_s = 0.3;       /* sweeps further apart than this are sparse (a dataset's keyframes,
                                      * a LiDAR that drops sweeps): the registration map is rebuilt with
                                      * each at once, not on another thread a few sweeps later (it would
                                      * lie metres behind the car), and ... */
    double sparse_prior_sigma_mps = 10; /* ... the prediction's spread is this times the gap (the last
                                      * step's speed, from sweeps 0.5 s apart, holds for the next one
                                      * only roughly; held at 0.5 m it kept a wrong speed for good) */
    double sparse_fit_drop = 0.6;    /* a sparse sweep whose match explains less than this share of the
                                      * median of the last 10 sparse sweeps' is matched again to the sweep
                                      * before alone, from the prediction, and ... */
    double sparse_apart_m = 1.0;     /* ... placed there when the two lie this far apart ... */
    double sparse_apart_deg = 1.0;   /* ... or turned this much (PB_ODOM_PREVIOUS): a local map of sweeps
                                      * placed wrong fits a wrong step best and stalls the odometry for
                                      * good (docs/mapper.md, "Sparse sweeps") */
    double max_gap_s = 1.0;          /* a longer gap between sweeps forgets the motion (searched again);
                                      * dead reckoning bridges it */
    double max_sample_age_s = 0.2;   /* a speed or rate sample older than this at the sweep's middle is
                                      * stale (CAN or IMU stopped): constant velocity instead */
    double start_place_m = 1.0;      /* the sweeps before the car first gets this far from where the drive
                                      * starts were aligned to a map of the standing car's own view (a sweep
                                      * aligned to one from nearly the same place finds about half the
                                      * attitude change between them: the body pitching on its springs as
                                      * the car sets off), so ... */
    double start_realign_m = 3.0;    /* ... they are aligned again, once the car is this far from the start,
                                      * to the view from there (pb_odom_result_t.corrected) ... */
    int start_hold_max = 32;         /* ... the last this many of them (3.2 s at 10 Hz) */
} pb_odom_config_t;

/* What the car measures of its own motion: signed forward speed of base (VEHICLE_SPEED,
 * m/s) and angular rate in base (IMU gyro rotated into base, rad/s), each with its time. */
typedef struct { int64_t utime; double speed_mps; } pb_odom_speed_t;
typedef struct { int64_t utime; double rate[3]; } pb_odom_rate_t;

/* The samples that arrived since the last sweep, in time order (one older than the newest
 * before it is left out). Either list may be empty; the odometry keeps the newest of each. */
typedef struct {
    const pb_odom_speed_t *speed;
    size_t n_speed;
    const pb_odom_rate_t *rate;
    size_t n_rate;
} pb_odom_motion_t;

/* How a sweep's pose was found (pb_odom_result_t.status). */
enum {
    PB_ODOM_FIRST = 0,      /* the first sweep: the map's origin */
    PB_ODOM_TRACKED = 1,    /* registered from the prediction */
    PB_ODOM_SEARCHED = 2,   /* registered after a search around the prediction */
    PB_ODOM_WEAK = 3,       /* the match explained less than weak_inlier_fraction:
                             * kept (it is the best estimate there is), counted in the report */
    PB_ODOM_PREDICTED = 4,  /* no match at all (too few points): the prediction */
    PB_ODOM_PREVIOUS = 5    /* a sparse sweep the local map fitted far worse than the sweeps before:
                             * placed by a match to the sweep before alone (sparse_fit_drop) */
};

/* What the prediction of a sweep came from (pb_odom_result_t.motion). */
enum {
    PB_ODOM_MOTION_NONE = 0,      /* no motion known: the last pose (first sweep, after a gap) */
    PB_ODOM_MOTION_CONSTANT = 1,  /* the last step's motion carried on */
    PB_ODOM_MOTION_MEASURED = 2   /* dead reckoning on speed and turn rate */
};

typedef struct {
    int status;                   /* PB_ODOM_* */
    int motion;                   /* PB_ODOM_MOTION_* */
    int64_t utime;                /* the time the pose refers to: the middle of the sweep */
    Eigen::Isometry3d pose;       /* map <- base at utime */
    Eigen::Vector3d v_base;       /* the motion the sweep was deskewed with: m/s ... */
    Eigen::Vector3d w_base;       /* ... and rad/s, both in base */
    double inlier_fraction;       /* of the match (registration.h); NaN for FIRST/PREDICTED */
    int rebuilt;                  /* 1 if a new registration map was started or swapped in after this sweep */
    /* Earlier sweeps' poses aligned again with this one (start_realign_m): n_corrected of them, valid
     * until the next pb_odom_add; they replace those given for the same utime before. */
    const struct pb_odom_correction *corrected;
    size_t n_corrected;
} pb_odom_result_t;

typedef struct pb_odom_correction {
    int64_t utime;                /* pb_odom_result_t.utime of the sweep ... */
    Eigen::Isometry3d pose;       /* ... and its pose aligned again */
} pb_odom_correction_t;

typedef struct pb_odom pb_odom_t;

/* The local map's cell for a sensor of `cols` columns a turn (a range image's width; 0 when
 * the sweeps do not say): the default cell_m, or two columns' gap 20 m out when that is
 * wider. A cell narrower than that holds too few returns of a sparse sensor to make a plane
 * of foliage: on a street of porous trees a 512-column sweep lost the odometry with 0.25 m
 * cells and held with 0.5 m (docs/history/mapper.md, "512 columns on the street of porous
 * trees"); 1024 columns and more keep 0.25 m. */
double pb_odom_cell_m(int cols);

/* cfg NULL = defaults; reg NULL = registration defaults. */
pb_odom_t *pb_odom_create(const pb_odom_config_t *cfg, const pb_reg_config_t *reg);
void pb_odom_destroy(pb_odom_t *o);

/* Adds one sweep: n points (xyz interleaved, base frame) with their offsets after utime
 * (microseconds), and the speed and rate samples received since the last sweep (motion
 * NULL = none: LiDAR alone). Sweeps must come in time order. Returns 0 with *out filled,
 * or -1 with err set (n == 0, a sweep not after the last one); the odometry is then
 * unchanged. */
int pb_odom_add(pb_odom_t *o, int64_t utime, const float *xyz, const int32_t *offset_us, size_t n,
                const pb_odom_motion_t *motion, pb_odom_result_t *out, pb_err_t *err);

/* The last sweep added, deskewed, in base at its pose's time (valid until the next
 * pb_odom_add; empty before the first). */
const std::vector<float> &pb_odom_last_sweep(const pb_odom_t *o);

/* The odometry's whole state as bytes, for a checkpoint (out is replaced): the local map's
 * cells and index, the motion, the points the registration map (and the one being built)
 * come from, the start's sweeps held. An odometry restored from them gives the same poses for the next sweeps as
 * the saved one would have, byte for byte. */
void pb_odom_save(const pb_odom_t *o, std::vector<uint8_t> *out);

/* An odometry from pb_odom_save's bytes, with this config (cfg, reg as pb_odom_create; the
 * caller gives the ones it saved with). Returns NULL with err set when the bytes are not
 * a whole state of this version. */
pb_odom_t *pb_odom_restore(const uint8_t *data, size_t n, const pb_odom_config_t *cfg, const pb_reg_config_t *reg,
                           pb_err_t *err);

#endif
