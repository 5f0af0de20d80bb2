/* The mapper's shell (docs/mapper.md): what its steps share. main.cpp runs the steps in
 * order; each file holds one part of the shell, the logic is in core/:
 *   sweeps.cpp      the log read sweep by sweep (read ahead on a second thread)
 *   restart.cpp     checkpoints of the odometry pass, the files they are written through
 *   trajectory.cpp  steps 1-3: odometry (or --poses), loop closure, GNSS anchoring
 *   tiles.cpp       steps 4-5: the map in tiles, the ground model, the carving, the road under
 *                   what moved
 *   site.cpp        step 6: map.pcd, the trajectories, map.tiles, site.yaml, report.json
 * A Run is owned by main(); the steps fill it in turn. Functions return 0 or -1 with err set. */
#ifndef PB_MAPPER_H
#define PB_MAPPER_H

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <functional>
#include <initializer_list>
#include <set>
#include <string>
#include <utility>
#include <vector>
#include <cerrno>
#include <Eigen/Geometry>

#include "anchor.h"
#include "loops.h"
#include "odometry.h"
#include "pb_err.h"
#include "pb_geo.h"
#include "pb_ground.h"
#include "pb_log.h"
#include "pb_map_build.h"
#include "pb_progress.h"
#include "pb_scan.h"
#include "pb_vehicle.h"
#include "picture.h"
#include "registration.h"

/* SweepPose.status and .motion of a pose given by --poses (not the odometry's). */
static const int kGiven = -1;

struct SweepPose {
    int64_t utime;
    Eigen::Isometry3d pose;      /* the odometry's; after loop closure, corrected */
    Eigen::Isometry3d odometry;
    int status, motion;          /* PB_ODOM_* and PB_ODOM_MOTION_* */
    double inlier_fraction, cpu_ms;
    int keyframe;                /* index of the last keyframe at or before it */
    double measured_mps;         /* the car's own forward speed the sweep was predicted with (VEHICLE_SPEED),
                                  * NaN when not measured */
};

/* Keyframes for loop closure every this much path; their points kept at this voxel (about
 * 40 KB a keyframe on the simulated OS1-64). */
static const double kKeyframeSpacingM = 2.0;
static const double kKeyframeVoxelM = 0.5;

inline pb_transform_t to_transform(const Eigen::Isometry3d &T)
{
    pb_transform_t t;
    pb_reg_to_transform(T, &t);
    return t;
}

using SweepKey = std::pair<int, int64_t>;   /* a sweep's drive and utime */

/* One run: the options, and what each step hands the next. */
struct Run {
    const char *log_path, *out_dir, *scan_ch;
    const char *poses_path = nullptr;   /* --poses: the sweeps placed with these, no odometry */
    double voxel;
    int quiet;
    int checkpoint_every;   /* sweeps between checkpoints of the odometry pass */
    pb_vehicle_t veh;
    long total = 0, empty = 0, out_of_order = 0;
    int sweep_cols = 0;         /* the first sweep's columns (a range image's width; 0: not one) */
    pb_odom_config_t odom_cfg;  /* the odometry's, its cell from sweep_cols */
    pb_reg_config_t reg;        /* its registration's and the loops': seen from the vehicle's LiDAR */
    std::vector<SweepPose> traj;
    std::vector<pb_keyframe_t> kf;
    pb_loops_report_t loops = {};
    std::vector<std::pair<SweepKey, SweepKey>> loop_times;   /* kept loops: (earlier, later) keyframe */
    pb_anchor_result_t anchor = {};
    pb_anchor_hold_result_t hold = {};
    pb_georef_t georef = {};
    pb_picture_layers_t layers;
    pb_pose_track_t *track = nullptr;
    long placed = 0, unplaced = 0;
    long beyond_range = 0;   /* returns left out of the map: farther than the carving reaches (pass 2) */
    /* the map in tiles (pass 2 -> map.pcd): their folder, their edge (--tile-m) */
    std::string tiles_dir;
    double tile_m = 32;
    size_t voxels = 0;                       /* made by pass 2 (seq 0 .. voxels - 1) */
    std::vector<int64_t> sweep_times;        /* pass 2's sweep number -> its time on the drives' one clock */
    std::vector<uint32_t> carved_hits;       /* per point carved (layers.removed, as the carving left it): first, last sweep */
    double ground_lo[2], ground_hi[2];       /* the map's extent, for the ground model */
    std::set<int64_t> carve_tiles;           /* the carving's tiles that hold points */
    std::vector<std::pair<int64_t, uint32_t>> kept_tiles;   /* after it: tile, seq of its next point to write */
    long tiles_held_max = 0, carve_tiles_held_max = 0, tiles_paged_out = 0, carve_tiles_paged_out = 0;
    long tiles_paged_in = 0, carve_tiles_paged_in = 0;   /* paged out, then back in */
    int64_t voxels_held_max = 0;
    size_t map_points = 0;                   /* in map.pcd */
    std::string ground_why;                  /* empty: ground.yaml written */
    size_t carved = 0;
    size_t carved_groups = 0;                /* of those, in groups that views saw through */
    uint64_t under_returns = 0;              /* pass 4: returns at the road under a body taken out */
    size_t under_moved = 0, under_gone = 0;   /* kept voxels it moved (those that went included), those that went */
    size_t under_sweeps = 0;                  /* sweeps it read when a body was hit (pb_under_busy) */
    long views = 0;                          /* sweeps taken as views by the carving */
    double m_per_px = 0;
    double peak_mb[5] = {};                  /* peak resident memory of each step (kPeakStep) */
    double wall_s[5] = {};                   /* wall time of each step (kPeakStep; 0: done before a restart) */
    /* restart (checkpoint_*): what a checkpoint must match, and the odometry pass's state */
    std::string log_id, build_id, options_id;
    long resumed_from = 0;                   /* scans the checkpoint had read; 0: not resumed */
    std::string checkpoint_refused;          /* why a checkpoint found was not used */
    /* restart inside the later steps (the first drive's Run: stage_*) */
    std::string resumed_after;               /* the last step a stage checkpoint had done ("" none) */
    std::string stage_refused;               /* why a stage checkpoint found was not used */
    uint64_t poses_sum = 0;                  /* poses.bin's checksum (carved.bin follows it) */
    std::vector<std::pair<uint64_t, uint64_t>> kept_sums;   /* per kept tile: bytes, checksum */
    std::string why_kept;                    /* placement.why / anchor.why restored (they point here) */
    FILE *kf_file = nullptr;                 /* keyframes.bin, appended at each checkpoint */
    size_t kf_saved = 0;                     /* keyframes in it */
    uint64_t kf_bytes = 0;                   /* its valid length */
    pb_odom_t *odom = nullptr;               /* restored odometry (NULL: start at the first scan) */
    long seen = 0;                           /* scans read by the odometry pass */
    int64_t last_scan_utime = 0;
    bool odometry_done = false;              /* restored after the whole odometry pass */
    /* several drives (--log repeated): one Run each, the first one's also the site's */
    int drive = 0;                           /* 0, 1, ... in the order of --log */
    std::vector<Run *> drives;               /* in the first: every drive's Run, itself first */
    pb_drive_report_t placement = {true, "", 0, 0, 0, Eigen::Isometry3d::Identity()};
    int64_t gnss_clock_offset_us = 0;        /* taken out of this drive's fix times (pb_clock_offset_median) */
    int gnss_clock_lags = 0;                 /* fixes it was measured on */
    std::string path(const char *name) const { return std::string(out_dir) + "/" + name; }
    std::string label(const char *what) const   /* a progress bar's */
    {
        return drive ? std::string(what) + " (drive " + std::to_string(drive + 1) + ")" : what;
    }
    /* a drive's own work file: NAME.bin for the first, NAME.N.bin for drive N */
    std::string work(const char *name) const
    {
        return drive ? path(name) + "." + std::to_string(drive + 1) + ".bin" : path(name) + ".bin";
    }
};

/* ---- restart.cpp: files */
/* The whole file into *out; -1 when it cannot be opened or read. */
int read_file(const std::string &path, std::vector<uint8_t> *out);
/* Writes the pieces one after the other to path through path.tmp, synced, renamed. */
int write_file_synced(const std::string &path, std::initializer_list<const std::vector<uint8_t> *> pieces,
                      pb_err_t *err);

/* ---- The map in tiles (docs/mapper.md, "Memory"): pass 2 holds the tiles of voxels its
 * sweeps can reach and pages the others out to SITE_DIR/map-tiles.tmp/; the finished voxels
 * are then sorted into the carving's tiles (by its cells, so that no cell spans two), which
 * pass 3 holds while its rays can reach them, with their counts paged out and back; map.pcd
 * is assembled from the kept points in the order the voxels were made (what one builder of
 * the whole map writes). A tile is keyed tx << 32 | uint32 ty. */
inline int64_t tile_key(int64_t tx, int64_t ty) { return (int64_t)((uint64_t)tx << 32 | (uint32_t)ty); }

/* Square tiles of `per` units (voxels, carving cells) a side: unit = floor(x * inv). */
struct TileGrid {
    double inv;
    int64_t per;
    int64_t of(double x) const
    {
        int64_t u = pb_floor_i64(x * inv);
        return u >= 0 ? u / per : -((-u + per - 1) / per);
    }
};

/* A point of the finished map in a tile file: the voxel's seq (the order it was made in),
 * x y z intensity, the returns it is the mean of, and the first and last sweep that hit it
 * (pass 2's numbers: Run::sweep_times). */
struct TilePoint {
    uint32_t seq;
    float p[4];
    uint32_t n;
    uint32_t first, last;
};
static_assert(sizeof(TilePoint) == 8 * sizeof(float), "TilePoint: x y z at a stride of 8 floats");

inline std::string tile_path(const Run *R, char kind, int64_t key)
{
    char name[64];
    std::snprintf(name, sizeof name, "/%c_%d_%d.bin", kind, (int32_t)((uint64_t)key >> 32), (int32_t)(uint32_t)key);
    return R->tiles_dir + name;
}

template <class T>
int tile_write(const std::string &path, const T *v, size_t n, bool append, pb_err_t *err)
{
    FILE *f = std::fopen(path.c_str(), append ? "ab" : "wb");
    bool ok = f && std::fwrite(v, sizeof(T), n, f) == n;
    if (f) ok &= std::fclose(f) == 0;
    if (!ok) return pb_err_set(err, "%s: cannot write: %s", path.c_str(), std::strerror(errno)), -1;
    return 0;
}

template <class T>
int tile_read(const std::string &path, std::vector<T> *v, pb_err_t *err)
{
    std::vector<uint8_t> bytes;
    if (read_file(path, &bytes) != 0 || bytes.size() % sizeof(T) != 0)
        return pb_err_set(err, "%s: cannot read the tile back", path.c_str()), -1;
    v->resize(bytes.size() / sizeof(T));
    if (!bytes.empty()) std::memcpy(v->data(), bytes.data(), bytes.size());
    return 0;
}

/* ---- sweeps.cpp */
using SweepFn = std::function<int(int64_t utime, const std::vector<float> &xyz_base, const pb_points_t &lidar,
                                  const pb_event_t &ev, pb_err_t *err)>;
using DriveSweepFn = std::function<int(Run *D, int64_t utime, const std::vector<float> &xyz_base,
                                       const pb_points_t &lidar, const pb_event_t &ev, pb_err_t *err)>;
using OtherFn = std::function<int(const pb_event_t &, pb_err_t *)>;
/* Every LIDAR_SCAN of the log in turn after the first *seen (skipped unread), without the
 * points on the car's own body: fn(utime, points in base, the same points in the lidar
 * frame, event) returns 0 or -1; *seen counts the scans read (fn's included). other (if
 * given) sees every other event after the skipped scans, in log order, and returns 0 or -1.
 * read_ahead: the log is read and the sweeps decoded on a second thread, a few sweeps ahead
 * of fn (a pass whose own work is single-threaded: the decoding costs a fifth of the map
 * pass); fn and other run on the caller's thread, in log order, either way. */
int for_each_sweep(const char *log_path, const char *scan_ch, const pb_vehicle_t &veh, long every, long *seen,
                   pb_progress_t *prog, const SweepFn &fn, long *empty, pb_err_t *err, const OtherFn &other = nullptr,
                   bool read_ahead = false);
/* fn(D, utime, points in base, in the lidar frame, event, err) on every `every`-th sweep of
 * each placed drive D in turn, read ahead, each drive with its progress bar ("what"). */
int for_each_drive_sweep(Run *R, const char *what, long every, const DriveSweepFn &fn, pb_err_t *err);

/* ---- restart.cpp */
int checkpoint_ids(Run *R, pb_err_t *err);
int checkpoint_read(Run *R, pb_err_t *err);
int checkpoint_write(Run *R, const pb_odom_t *odom, pb_err_t *err);
/* keyframes.bin's first n keyframes (utime, pose, where their record starts as points_key;
 * with_points: the points too) into *kf, which must hold bytes bytes. false when it does not. */
bool read_keyframes(const std::string &path, uint64_t n, uint64_t bytes, bool with_points,
                    std::vector<pb_keyframe_t> *kf);
/* The points of the keyframe whose record starts at byte at of keyframes.bin (open as f). */
int keyframe_points(FILE *f, const std::string &path, uint64_t at, std::vector<float> *xyz, pb_err_t *err);

/* Restart inside the later steps: SITE_DIR/poses.bin after the loops and the anchoring
 * (every drive's poses and placement, the loops' and the anchoring's results), then
 * SITE_DIR/carved.bin after the map and the carving (its kept tiles in map-tiles.tmp/ with
 * their sizes and checksums, and the counts). stage_read restores what matches this run
 * (the logs, the build, the options, the poses given), *done = 0 none, 1 poses.bin, 2 both;
 * one that does not match (or whose tiles are not as written) is refused, said on stderr
 * and in R->stage_refused, and those steps run again. */
int stage_read(Run *R, int *done, pb_err_t *err);
/* Their first 8 bytes (a new layout gets a new one, so that an old file is refused). */
extern const char kPosesMagic[8], kCarvedMagic[8];
/* What a stage checkpoint must match: the build, the options the later steps depend on,
 * every drive's log (checkpoint_ids) and the poses given. */
std::string stage_id(const Run *R);
int stage_write_poses(Run *R, pb_err_t *err);
int stage_write_carved(Run *R, pb_err_t *err);

/* ---- trajectory.cpp: steps 1-3 */
int read_poses(Run *R, pb_err_t *err);
int pass_odometry(Run *R, pb_err_t *err);
int close_loops(Run *R, pb_err_t *err);
int anchor(Run *R, pb_err_t *err);

/* ---- tiles.cpp: steps 4-5 */
int pass_map(Run *R, pb_err_t *err);
pb_ground_t *make_ground(Run *R, pb_err_t *err);
int pass_carve(Run *R, const pb_ground_t *ground, pb_err_t *err);

/* ---- site.cpp: step 6 */
int write_site(Run *R, pb_err_t *err);
int write_report(const Run &R, const double cpu_ms[4], double wall_s, pb_err_t *err);

#endif
