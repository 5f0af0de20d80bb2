/* occlusion: the module's pipeline (pure: no I/O, no clocks; time from messages).
 *
 * Inputs, each with its message time: vehicle poses (POSE), the head (HEAD_POSE),
 * the agents (AGENTS) and LiDAR sweeps (points in the `lidar` frame). A sweep waits
 * until a pose at or after its end arrives (the localizer stamps POSE at the
 * sweep's end), then it is moved into the map point by point (pose interpolated
 * at each point's time), integrated into occ_map, and every agent's body samples
 * (common/pb_body), moved on to the sweep's end, are queried from the eye:
 * HEAD_POSE in the car if fresh and tracking, else the vehicle file's seat (else
 * the LiDAR). One output per sweep.
 * Without a usable pose (none, lost or initializing, or too old) the sweep is not
 * integrated and every sample is unknown, never visible.
 *
 * Ownership: occlusion_create copies the config; outputs belong to the caller. */
#ifndef OCCLUSION_H
#define OCCLUSION_H

#include <stdint.h>

#include <string>
#include <vector>

#include "occ_map.h"
#include "pb_body.h"
#include "pb_math.h"
#include "pb_scan.h"

struct occlusion_vehicle_t {
    pb_transform_t base_from_lidar;
    double seat_eye[3];         /* base, m */
    bool has_seat_eye;
    double length, width, height, rear_overhang;
};

struct occ_pose_in_t {
    int64_t utime;
    double pos[3], q[4], vel[3];
    bool usable;                /* status tracking or degraded */
};

struct occ_agent_in_t {
    std::string id, kind;
    double pos[3], yaw, vel[3];
    bool in_render_range;
};

struct occ_agent_out_t {
    std::string id;
    int n;
    float x[PB_BODY_MAX_SAMPLES], y[PB_BODY_MAX_SAMPLES], z[PB_BODY_MAX_SAMPLES];
    int8_t state[PB_BODY_MAX_SAMPLES];
    float occluder_m[PB_BODY_MAX_SAMPLES];
    float visible_fraction;
    bool evaluated;             /* queried (in render range, posed); else every sample unknown */
};

enum { OCC_EYE_HEAD = 0, OCC_EYE_SEAT = 1, OCC_EYE_LIDAR = 2 };

struct occ_output_t {
    int64_t utime;              /* end of the sweep */
    double viewer[3];           /* map; NaN without a pose */
    int eye_source;
    bool pose_ok;               /* false: the sweep was not integrated, every sample unknown */
    std::vector<occ_agent_out_t> agents;
    occ_integrate_stats_t integrate;
    double integrate_ms, query_ms;  /* filled by the caller if it times the steps */
};

/* What happened, for STATUS (counter name; message when it is worth saying). */
struct occ_event_t {
    std::string counter, message;
};

struct occlusion_t;

occlusion_t *occlusion_create(const occ_config_t *cfg, const occlusion_vehicle_t *veh);
void occlusion_destroy(occlusion_t *o);

void occlusion_pose(occlusion_t *o, const occ_pose_in_t *p, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev);
/* HEAD_POSE. A headset whose clock is off the car's (its times against the newest POSE or
 * sweep end they arrive with, pb_clock_offset.h) has the offset taken out of its times, and ev
 * (may be NULL) gets "head_clock_offset" when it is found, changes or goes. */
void occlusion_head(occlusion_t *o, int64_t utime, const double pos[3], bool tracking,
                    std::vector<occ_event_t> *ev = nullptr);
void occlusion_agents(occlusion_t *o, int64_t utime, const std::vector<occ_agent_in_t> &agents);
/* A sweep (points in `lidar`, offsets after utime) and its sensor's beam gaps (rad;
 * pb_scan_beam_gaps; 0 when the scan does not say: the config's). Processed once a pose
 * covers its end; a sweep still waiting when the next one is 0.3 s newer goes out
 * without a pose. */
void occlusion_scan(occlusion_t *o, int64_t utime, const pb_points_t *pts, double ring_gap_rad, double col_gap_rad,
                    std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev);
/* End of input: pending sweeps go out (without a pose if none covers them). */
void occlusion_finish(occlusion_t *o, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev);

/* The sweep last integrated, in the map frame (pointers into the pipeline, valid until
 * its next call), and the map: for benchmarks and tests. false if none yet. */
bool occlusion_last_sweep(const occlusion_t *o, occ_sweep_t *sw);
/* The map, for benchmarks and tests. */
occ_map_t *occlusion_map(occlusion_t *o);
/* Wall time spent in the last sweep's integration and query, measured by a callback the
 * shell may set (the core has no clock). */
typedef double (*occ_clock_fn)(void);
void occlusion_set_clock(occlusion_t *o, occ_clock_fn fn);

#endif
