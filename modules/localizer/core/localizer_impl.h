/* localizer_impl: the inside of localizer_t, shared by the pipeline (localizer.cpp),
 * start-up and relocalisation (startup.cpp) and the health checks (health.cpp).
 * Not part of the API. */
#ifndef LOC_LOCALIZER_IMPL_H
#define LOC_LOCALIZER_IMPL_H

#include <cstdarg>
#include <deque>

#include "localizer.h"
#include "pb_clock_offset.h"
#include "places.h"

namespace pb_loc {

enum { EV_IMU = 0, EV_SPEED = 1 };

struct input_ev_t {
    int64_t t;
    int kind;
    Vec3 accel, gyro;   /* EV_IMU, raw (imu frame) */
    double speed;       /* EV_SPEED */
};

struct gnss_res_t {
    int64_t t;
    Eigen::Vector2d r;  /* fix minus predicted antenna position, map xy */
    double h_acc;
};

struct pose_sample_t {
    int64_t t;
    Eigen::Isometry3d map_from_imu;
};

struct localizer {
    localizer_config_t cfg;
    extrinsics_t ex;
    const pb_regmap_t *map;
    bool has_geo;
    pb_georef_t geo;

    filter_t kf;       /* committed: at the last sweep (or the last commit of old inputs) */
    filter_t pred;     /* kf moved forward by every input since */
    std::deque<input_ev_t> buf;
    Vec3 last_accel = Vec3::Zero(), last_gyro = Vec3::Zero();

    int64_t newest_t = 0;      /* newest IMU, CAN or LiDAR time: the clock of the sensors */
    int jump_count = 0;        /* successive inputs far behind newest_t, the newest of them */
    int64_t jump_last_t = 0;
    int64_t jump_step = 0;     /* how far the clock stepped back, from the first input of the run */
    int64_t last_imu_t = 0, last_speed_t = 0, last_scan_t = 0, last_pose_out_t = 0, last_pred_out_t = 0;
    int64_t imu_dt = 0, speed_dt = 0, scan_dt = 0;   /* the last interval of each input */
    int status = ST_INITIALIZING;
    bool candidate = false;     /* kf holds a pose still being verified */
    bool cand_vel_unknown = false;   /* ... whose velocity is not known yet */
    bool cand_no_speed = false;      /* ... started with the speed unknown (LiDAR alone) */
    bool cand_global = false;        /* ... found by the global search (no prior at all) */
    bool cand_retry_hint = false;    /* ... found around an initial pose (a prior) with the speed
                                      * unknown: a failed verification searches there again */
    Eigen::Isometry3d cand_pose = Eigen::Isometry3d::Identity();
    int64_t cand_t = 0;
    int verify_count = 0, reject_count = 0;
    int cand_holds = 0;              /* structure misses the candidate was kept through */
    int structure_run = 0;           /* consecutive rejected sweeps that failed only the structure test */
    int weak_run = 0;                /* consecutive matches that did not fix a direction (match_degenerate) */
    Vec3 weak_dir = Vec3::Zero();    /* ... after degenerate_enter_sweeps of them: the direction not used ... */
    int weak_clear = 0;              /* ... and the accepted matches since that fixed it: the way along a tunnel
                                      * stays unused until degenerate_clear_sweeps of them in a row */
    int64_t verified_t = 0;          /* sweep time of the last accepted match */
    int64_t held_t = 0;              /* of the last search that found no better place (scene_changed), 0 = none */
    bool lidar_gap_reported = false;

    places_t *places = nullptr;     /* place descriptors of the map (given, or built at the first global search) */
    localizer_pager_fn pager = nullptr;   /* pages the map around a place (NULL: a whole map) */
    void *pager_user = nullptr;
    bool places_failed = false;
    int64_t global_since = 0;       /* sweep time the global search began (0: not searching) */
    bool has_hint = false;
    int hint_tries = 0;
    int lost_searches = 0;     /* dead-reckoned searches since lost */
    double init_inliers = NAN, init_structure = NAN;   /* of the last start-up match (diagnostics) */
    Eigen::Isometry3d hint;
    int64_t hint_t = 0;
    Vec3 hint_body_vel = Vec3::Zero();   /* velocity in base before the hint, carried over */

    bool has_fix = false;
    gnss_in_t fix;
    Vec3 fix_map = Vec3::Zero();
    int64_t fix_raw_utime = 0;             /* the fix's own time, before the clock offset */
    pb_clock_offset_t gnss_clock;          /* the receiver's clock against the sensors' (fix time - newest_t) */
    std::deque<gnss_res_t> gnss_res;

    /* the direction of travel an unsigned CAN speed lacks (Toyota without the gear) */
    bool speed_signed = false;  /* a negative VEHICLE_SPEED came: the car reports reverse itself */
    bool stood = false;         /* the car was seen standing (CAN speed under standstill_mps) */
    double depart_v = 0;        /* forward speed from the IMU alone since the car last stood */
    int depart_dir = 0;         /* its sign once clear (+1 forwards, -1 backwards), 0 at rest */
    /* forward speed from successive accepted matches (the direction of travel) */
    Eigen::Isometry3d last_match_pose = Eigen::Isometry3d::Identity();
    int64_t last_match_t = 0;
    double match_fwd_mps = 0;
    /* LiDAR alone: the velocity sweeps are deskewed with (base frame), smoothed over
     * the last accepted matches */
    bool deskew_vel_ok = false;
    int deskew_vel_n = 0;
    Vec3 deskew_vel = Vec3::Zero();
    /* LiDAR-only turn rate from successive poses */
    bool has_prev_pose = false;
    Eigen::Isometry3d prev_pose;
    int64_t prev_pose_t = 0;

    double last_structure = NAN;       /* the last structure fit >= cfg.structure_trust, and its time */
    int64_t last_structure_t = 0;
    std::vector<float> xyz, above, above_ds;
    /* a sweep waiting for the IMU to reach its end */
    bool has_pending = false;
    int64_t pend_utime = 0, pend_t_ref = 0;
    std::vector<float> pend_x, pend_y, pend_z;
    std::vector<int32_t> pend_off;
    std::vector<pose_sample_t> samples;
};

/* localizer.cpp */
bool imu_fresh(const localizer_t *L, int64_t t);
double newest_speed(const localizer_t *L, int64_t t);   /* CAN speed within cfg.speed_timeout_us, else NaN */
void event(outputs_t *out, const char *counter, const char *fmt = nullptr, ...) __attribute__((format(printf, 3, 4)));
void set_status(localizer_t *L, int s, outputs_t *out, const char *why);
void rebuild_pred(localizer_t *L);
Eigen::Isometry3d imu_pose(const filter_t &f);

/* startup.cpp: start-up or relocalisation on this sweep; true with kf reset at a candidate */
double motion_reach_m(const localizer_t *L, double dt_s);   /* how far a car of unknown speed may go */
std::vector<Eigen::Isometry3d> motion_seeds(const localizer_t *L, const Eigen::Isometry3d &from, double dt_s,
                                            double *step);
bool search_seeds(localizer_t *L, const std::vector<Eigen::Isometry3d> &seeds, double radius, double yaw_range,
                  bool page, pb_reg_result_t *res, double *fit, double *rival);
/* A place that fits while another one far from it (rival: its fit, < 0 for none) fits
 * about as well is not known yet. */
bool ambiguous(const localizer_t *L, double fit, double rival);
bool global_search(localizer_t *L, double searching_s, pb_reg_result_t *res, outputs_t *out);
bool try_initialize(localizer_t *L, int64_t t_ref, outputs_t *out);

/* health.cpp */
Vec3 antenna_map(const localizer_t *L, const Eigen::Isometry3d &map_from_base);
bool fix_fresh(const localizer_t *L, int64_t t);
double gnss_gate(const localizer_t *L, double h_acc);
double candidate_gnss_residual(const localizer_t *L, const Eigen::Isometry3d &pose, const Vec3 &vel, int64_t t);
int64_t gnss_clock_offset(localizer_t *L, int64_t fix_utime, outputs_t *out);
double structure_inliers(localizer_t *L, const Eigen::Isometry3d &pose);
/* The structure test on si = structure_inliers(L, pose), called right after it: true when
 * si is NaN (too little structure to judge), at least min_structure_inliers, or a sharp
 * peak (structure_peak_floor, structure_peak_ratio; counted as match_structure_peak). */
bool structure_fits(localizer_t *L, const Eigen::Isometry3d &pose, double si, outputs_t *out);
Mat6 floored(const localizer_t *L, const Mat6 &c);
/* The horizontal direction (unit, map) a match's sweep does not fix, if there is one (see
 * health.cpp); uses L->xyz, the sweep as matched. */
bool match_degenerate(localizer_t *L, const pb_reg_result_t &res, Vec3 *dir);

} // namespace pb_loc
#endif
