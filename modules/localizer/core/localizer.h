/* localizer: the pure pipeline of the localizer module.
 *
 * Inputs, each with its message time (us): IMU samples, CAN speeds, GNSS fixes,
 * INITIAL_POSE requests, LiDAR sweeps (points in the lidar frame with per-point
 * time offsets). Outputs: POSE once per sweep (and at 10 Hz from prediction while
 * the LiDAR is missing), POSE_PREDICTED at every IMU sample (or every
 * cfg.predict_period_us from a tick when there is no IMU), and events (named
 * counters with a reason) for the STATUS heartbeat.
 *
 * State machine (status of every output):
 *   INITIALIZING  no pose yet, or a candidate pose that has not passed
 *                 cfg.verify_scans consecutive consistency checks;
 *   TRACKING      scans match and the pose passes the divergence test;
 *   DEGRADED      running on prediction: no LiDAR for a while, an empty or
 *                 unmatched sweep, or a rejected match (a few in a row);
 *   LOST          the divergence test says the pose is wrong (or too many
 *                 rejected matches): relocalisation runs on each sweep until a
 *                 candidate is verified.
 * Start-up / relocalisation sources, in order: an INITIAL_POSE message or
 * --initial-pose (pose hint, verified like any candidate); GNSS position plus
 * heading from GNSS course when moving, else a yaw search over 360 degrees
 * (pb_reg_align_global).
 *
 * Divergence test (see docs/localizer.md): a match is accepted only if the map
 * explains the sweep (inlier fraction), it agrees with the motion prediction
 * (Mahalanobis gate on the innovation), and the pose agrees with GNSS when GNSS
 * is present (the antenna position predicted from the pose against a window of
 * fixes, gated by their accuracy). The GNSS check is what catches a pose that is
 * wrong yet matches well (a long straight road, a kidnapped or mis-initialised car).
 *
 * No I/O; time only from message utimes; deterministic.
 * Ownership: localizer_create returns an object the caller frees with
 * localizer_destroy; the map is borrowed and must outlive it. */
#ifndef LOC_LOCALIZER_H
#define LOC_LOCALIZER_H

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "filter.h"
#include "pb_clock_offset.h"
#include "pb_geo.h"
#include "pb_scan.h"
#include "registration.h"
#include "regmap.h"

namespace pb_loc {

enum { ST_INITIALIZING = 0, ST_TRACKING = 1, ST_DEGRADED = 2, ST_LOST = 3 };
enum { SRC_LOCALIZER = 0, SRC_PREDICTED = 3 };
/* Covariance diagonal of a POSE without an estimate (status initializing, pose identity):
 * 10 km standard deviation in position, pi in each angle. */
static const double UNKNOWN_POS_VAR = 1e8, UNKNOWN_ROT_VAR = M_PI * M_PI;

struct localizer_config_t {
    filter_config_t filter;
    pb_reg_config_t reg;
    int64_t predict_period_us = 5000;      /* POSE_PREDICTED period without IMU (200 Hz) */
    int64_t imu_timeout_us = 250000;       /* IMU older than this: LiDAR-only prediction */
    int64_t imu_gap_us = 50000;            /* a gap between IMU samples worth reporting */
    int64_t lidar_timeout_us = 250000;     /* no sweep for this long: DEGRADED, POSE from prediction */
    int64_t lidar_lost_us = 10000000;      /* no sweep for this long: LOST (dead reckoning is no pose) */
    int64_t time_jump_us = 1000000;        /* inputs this much older than the newest: the clock stepped back ... */
    int time_jump_inputs = 3;              /* ... when this many in a row say so (one stray message does not) */
    int64_t reinit_gap_us = 60000000;      /* no input for this long (a log gap): start afresh */
    int64_t gnss_clock_tol_us = PB_CLOCK_OFFSET_TOL_US;   /* GNSS time off the other sensors by more: an offset, compensated */
    int64_t gap_pose_period_us = 100000;   /* POSE period while the LiDAR is missing */
    int64_t speed_timeout_us = 500000;     /* VEHICLE_SPEED older than this is not used */
    double reverse_detect_mps = 0.5;       /* matches moving backwards faster: an unsigned CAN speed is negated */
    double standstill_mps = 0.05;          /* CAN speed below this: the car stands (a departure follows) */
    double depart_detect_mps = 0.15;       /* IMU-integrated speed since standing that fixes its direction */
    int min_scan_points = 500;             /* fewer valid points: the sweep is not matched */
    /* match acceptance */
    /* of downsampled points within reg.inlier_m of a plane: a sanity floor only (the
     * structure test judges the pose). Real scans at their reference pose: median 0.22,
     * 10% under 0.11 (MulRan, vegetation), the simulator about 0.9. */
    double min_inlier_fraction = 0.08;
    /* structure test: the share of points higher than structure_min_z_m above the local
     * ground (the map's ground below each point; base z where the map has none) that lie
     * on the map's surfaces at the pose: within reg.inlier_m of a plane, or inside an
     * occupied cell of rough structure (trees, bushes, fences). The ground fits almost
     * any pose on a road, so the overall score stays high when the pose is wrong; walls,
     * poles, vegetation and parked cars do not. Applied when at least
     * structure_min_points such points exist. */
    double structure_min_z_m = 0.7;
    int structure_min_points = 300;
    /* MulRan odd keyframes against a map of the even ones: 0.55 passes 69% at the
     * reference pose and 5% of poses 20 m along the road; the simulator fits 0.88 when
     * right, 0.15 when 20 m off */
    double min_structure_inliers = 0.55;
    double structure_rough_m = 0.25;       /* a point this near a cell of rough structure fits it */
    /* A fit below min_structure_inliers passes when it is a sharp peak:
     * at least structure_peak_floor, and structure_peak_ratio times the best fit of the
     * same points 1 or 2 m along, 1 m across or 3 degrees turned. Parked cars that came
     * after the map was made can be half the structure of a street without buildings: the
     * right pose then fits 0.44-0.55 but 2.4-3.6 times its neighbours (simulated trees and
     * poles, solid), and 10 sweeps of it made a car that was tracked to 5 cm LOST. A pose
     * slid along a road fits its neighbours as well as itself; so does any pose among
     * rough structure (MulRan's vegetation: 0.85-1.05 times, right or wrong), where the
     * rule never applies. A candidate's sweep that fails only the structure test but fits
     * at least structure_peak_floor neither verifies nor drops the candidate (at most
     * verify_scans - 1 times): at the reference pose 31% of MulRan's keyframes fit under
     * 0.55, so a right candidate was dropped by one sweep in three; a wrong one still
     * needs verify_scans fits. */
    double structure_peak_floor = 0.3;
    double structure_peak_ratio = 2.0;
    /* GNSS that disagrees while the structure fitted this well within the last second is
     * taken to be the faulty one (multipath, spoofing): counted, the pose is kept.
     * Measured: 0.6-0.9 at the right pose, 0-0.15 at a pose 20 m off. */
    double structure_trust = 0.6;
    double gate_chi2 = 40.0;               /* innovation Mahalanobis^2 (6 dof) above which a match is rejected */
    double gate_min_m = 0.5;               /* ... but never reject a step smaller than this */
    double pose_sigma_floor_m = 0.01;      /* floor on the match covariance (sd, m) */
    double pose_sigma_floor_rad = 0.001;   /* (sd, rad) */
    /* Added to the published horizontal covariance, not to the filter's: the error against
     * the map that more sweeps do not average out (the map's own cells, structure that
     * differs from it in the same way sweep after sweep). The filter takes each sweep's
     * match as independent, and its sd fell to 4 mm fused (10 mm LiDAR alone) while the
     * errors were 1-9 cm on the simulated streets and 2.4 cm median, 6.3 cm p90 on MulRan
     * against its refined reference: 12-65 % of POSE lay beyond 3 sd. With 3 cm: at most
     * 0.8 % on every street, and 0.7 % on MulRan where it tracked within 0.5 m (2 dof: 1.1 % expected). */
    double pose_bias_sigma_m = 0.03;
    /* A match whose sweep does not fix a horizontal direction (match_degenerate: a tunnel,
     * walls or parapets longer than the LiDAR reaches): tested when its translation
     * Hessian's condition number exceeds degenerate_condition (streets here: at most about
     * 700; a simulated tunnel: 2,500-6,000), by registrations started degenerate_probe_m
     * either way along it. The filter is then updated without that direction (the motion
     * carries the position there; the motion gate's variance along it grows by
     * degenerate_sigma_m squared), and tracking on such matches is DEGRADED once the
     * position's sd exceeds degenerate_degraded_m. */
    double degenerate_condition = 300;
    double degenerate_probe_m = 2.0;
    double degenerate_sigma_m = 10.0;
    double degenerate_degraded_m = 0.3;
    double degenerate_lost_m = 3.0;        /* ... and LOST (relocalised where the walls end) once over this */
    int degenerate_enter_sweeps = 3;       /* in a row, before a direction is not used (a sweep of a street of porous crowns alone) */
    int degenerate_clear_sweeps = 5;       /* ... until this many accepted in a row fix it (a sweep in a tunnel now and then seems to) */
    int rejects_to_lost = 10;              /* consecutive rejected sweeps -> LOST ... */
    /* ... unless every one failed only the structure test and no place within hold_search_m
     * and hold_search_yaw_deg fits better: the scene changed since the map (parked cars
     * where little else stands), so the pose is held, DEGRADED, and searched around again
     * every hold_recheck_us; at most lidar_lost_us after the last accepted sweep */
    double hold_search_m = 20;
    double hold_search_yaw_deg = 20;
    int64_t hold_recheck_us = 1000000;
    int verify_scans = 3;                  /* consecutive accepted sweeps to leave INITIALIZING/LOST */
    /* ... each deskewed with a speed that its own match confirms: one whose speed was off
     * by dv moves its points by dv * sweep / 2 on average (up to dv * sweep), and its match
     * along the road with them (a moving start on LiDAR alone: 0.3-0.45 m on the porous
     * street). Compared with this bound; a candidate waits while it is exceeded. */
    double verify_deskew_m = 0.1;
    /* LiDAR alone, after a start or restart: the speed a sweep is deskewed with is smoothed
     * (new = a old + (1 - a) filter's) over this many accepted sweeps. A moving start's
     * first speed comes from two matches and is often 2-3 m/s off; deskewed with it, the
     * next match moves along the road by tenths of a metre and the speed further off.
     * Afterwards the filter's own (a lag would cost accuracy in every acceleration). */
    double deskew_smooth = 0.5;
    int deskew_smooth_sweeps = 20;
    /* GNSS */
    int64_t gnss_window_us = 1000000;      /* fixes averaged by the divergence test */
    double gnss_gate_min_m = 8.0;          /* pose vs GNSS: mean residual above max(this, k*h_acc) fails */
    double gnss_gate_k = 4.0;
    double gnss_init_speed_mps = 3.0;      /* GNSS course used as heading above this speed */
    double gnss_init_heading_acc_deg = 10.0;
    double gnss_search_radius_m = 4.0;     /* relocalisation search around the GNSS position */
    /* an initial pose (INITIAL_POSE, --initial-pose) is a prior: searched within this */
    double hint_radius_m = 3.0;
    double hint_yaw_deg = 15.0;
    int hint_retries = 20;                 /* sweeps a failing prior is tried on before it is dropped */
    double lost_search_max_m = 12.0;       /* the dead-reckoned search when lost grows with the covariance to this */
    int lost_searches = 20;                /* ... and runs on this many sweeps, then the global search */
    double max_speed_mps = 25.0;           /* how far a car may have moved between a start's first two sweeps */
    double max_yaw_rate_dps = 30.0;        /* ... and turned (a 20 m radius at 10 m/s) */
    /* no prior at all: global relocalisation in the whole map (place descriptor, see startup.cpp) */
    bool global_search = true;
    /* places verified by registration per sweep (the best-ranked, distinct ones).
     * MulRan's tree-lined roads rank the true place below the 8th on some keyframes: with
     * 8, two no-prior starts of 20 took 5.4 and 6.4 s (keyframes 1 s apart), with 16 they
     * took 2.8 and 1.4 s; a search costs twice as long (MulRan median 0.11 -> 0.25 s) */
    int global_candidates = 16;
    /* a place fitting less of the structure than global_sure_fit is taken only when the
     * search, waiting one sweep more, would run past global_patience_s (sweep time) */
    double global_sure_fit = 0.8;
    double global_patience_s = 1.0;
    /* a place is taken only when no other place further than rival_m (or turned more than
     * rival_yaw_deg) from it fits the sweep's structure within rival_ratio of it (MulRan:
     * a tree-lined road fits 0.75-0.8 at 180 degrees and 13 m to the side, the true pose
     * 0.7-0.9) */
    double rival_m = 5.0;
    double rival_yaw_deg = 30.0;
    double rival_ratio = 0.9;
    /* --initial-pose, applied to the first sweep if nothing better came */
    bool has_initial_pose = false;
    double initial_pose[6] = { 0 };        /* x, y, z, roll, pitch, yaw (m, rad) */
};

/* One pose output (POSE or POSE_PREDICTED). */
struct pose_out_t {
    bool predicted;            /* POSE_PREDICTED (else POSE) */
    int64_t utime;
    Eigen::Isometry3d map_from_base;
    Vec3 velocity, angular_velocity;
    Mat6 covariance;
    int status, source;
    double match_score;        /* NaN when not from a match */
};

/* Something the STATUS heartbeat should count (and show as last error if message != ""). */
struct event_t {
    std::string counter, message;
};

/* Per-sweep diagnostics (for the shell's statistics and tests). */
struct scan_diag_t {
    int64_t utime;
    int status;
    bool matched, accepted;
    double inlier_fraction, score, innovation_chi2, gnss_residual_m, structure_inliers;
};

struct outputs_t {
    std::vector<pose_out_t> poses;
    std::vector<event_t> events;
    bool has_scan_diag = false;
    scan_diag_t scan_diag;
    void clear() { poses.clear(); events.clear(); has_scan_diag = false; }
};

struct extrinsics_t {
    Eigen::Isometry3d base_from_lidar, base_from_imu, base_from_gnss;
};

typedef struct localizer localizer_t;

localizer_t *localizer_create(const localizer_config_t &cfg, const extrinsics_t &ex, const pb_regmap_t *map,
                              const pb_georef_t *geo /* NULL: GNSS is ignored */);
void localizer_destroy(localizer_t *L);

/* The map is paged by the caller (core/map_tiles): before the core searches far from
 * the car (a start with no prior tries places all over the map), it asks for the tiles
 * around map (x, y) with pager(user, x, y). Without a pager the map is taken as whole. */
typedef void (*localizer_pager_fn)(void *user, double x, double y);
void localizer_set_pager(localizer_t *L, localizer_pager_fn pager, void *user);

/* The place descriptors of the whole map (core/places, stored with the map tiles) for a
 * start with no prior; L takes ownership. Without them, the first global search builds
 * them from the map it has (the whole map when there is no pager). */
struct places;
void localizer_set_places(localizer_t *L, struct places *places);

void localizer_imu(localizer_t *L, int64_t utime, const Vec3 &accel, const Vec3 &gyro, outputs_t *out);
void localizer_speed(localizer_t *L, int64_t utime, double speed_mps, outputs_t *out);
struct gnss_in_t {
    int64_t utime;
    int fix_type;              /* portobello gnss_fix_t FIX_* */
    double lat_deg, lon_deg, alt_m, h_acc_m, speed_mps, heading_deg, heading_acc_deg;
};
void localizer_gnss(localizer_t *L, const gnss_in_t &fix, outputs_t *out);
/* An operator's (or tool's) pose hint; verified before it is trusted. */
void localizer_initial_pose(localizer_t *L, int64_t utime, const Eigen::Isometry3d &map_from_base, outputs_t *out);
/* A sweep: points in the lidar frame, per-point offsets after utime. */
void localizer_scan(localizer_t *L, int64_t utime, const pb_points_t *pts, outputs_t *out);
/* Called on a timer: publishes POSE_PREDICTED when there is no IMU to drive it. */
void localizer_tick(localizer_t *L, int64_t now_utime, outputs_t *out);

/* End of input (end of a replayed log): matches a sweep still waiting for the IMU. */
void localizer_finish(localizer_t *L, outputs_t *out);

int localizer_status(const localizer_t *L);
const char *localizer_status_name(int status);

} // namespace pb_loc
#endif
