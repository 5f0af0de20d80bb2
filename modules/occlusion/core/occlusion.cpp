/* occlusion: sweeps, poses, head and agents to per-sample visibility (see occlusion.h). */
#include "occlusion.h"
#include "pb_clock_offset.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <deque>

namespace {

const int64_t POSE_KEEP_US = 2000000;       /* pose history kept */
const int64_t EXTRAPOLATE_US = 150000;      /* a pose may be carried this far past the newest */
const int64_t GAP_US = 500000;              /* poses further apart than this do not interpolate */
const int64_t HEAD_FRESH_US = 500000;       /* HEAD_POSE older than this: the seat */
const int64_t WAIT_US = 300000;             /* a sweep waits this long (message time) for its pose */
const int64_t AGENTS_MAX_DT_US = 1000000;   /* agents extrapolated at most this far */
const double JUMP_M = 3.0;                  /* a pose this far off the previous one's motion: the map is reset */
const int SLOTS = 64;                       /* sensor poses per sweep */

struct sweep_t {
    int64_t utime, end;
    pb_points_t pts;
    double ring_gap_rad, col_gap_rad;
};

}  // namespace

struct occlusion_t {
    occ_config_t cfg;
    occlusion_vehicle_t veh;
    occ_map_t *map;
    std::deque<occ_pose_in_t> poses;
    std::deque<sweep_t> sweeps;
    int64_t head_utime = INT64_MIN;   /* on the car's clock (the headset's offset taken out) */
    double head[3] = { 0, 0, 0 };
    bool head_tracking = false;
    pb_clock_offset_t head_clock;     /* the headset's clock against the car's sensors' */
    int64_t newest_t = 0;             /* newest POSE time or sweep end: the car's clock */
    int64_t agents_utime = INT64_MIN;
    std::vector<occ_agent_in_t> agents;
    int last_eye = -1;
    bool had_pose_ok = true;
    occ_clock_fn clock = nullptr;
    /* scratch */
    std::vector<float> mx, my, mz;
    std::vector<uint16_t> oi;
    occ_sweep_t last = {};
    double last_origins[64][3];
    bool has_last = false;
};

occlusion_t *occlusion_create(const occ_config_t *cfg, const occlusion_vehicle_t *veh)
{
    occlusion_t *o = new occlusion_t;
    o->cfg = *cfg;
    o->veh = *veh;
    o->cfg.ego_x0 = -veh->rear_overhang;
    o->cfg.ego_x1 = veh->length - veh->rear_overhang;
    o->cfg.ego_half_width = veh->width / 2;
    o->cfg.ego_height = veh->height;
    o->map = occ_map_create(&o->cfg);
    pb_clock_offset_init(&o->head_clock, PB_CLOCK_OFFSET_TOL_US);
    return o;
}

void occlusion_destroy(occlusion_t *o)
{
    if (!o) return;
    for (sweep_t &s : o->sweeps) pb_points_free(&s.pts);
    occ_map_destroy(o->map);
    delete o;
}

occ_map_t *occlusion_map(occlusion_t *o) { return o->map; }

bool occlusion_last_sweep(const occlusion_t *o, occ_sweep_t *sw)
{
    if (o->has_last) *sw = o->last;
    return o->has_last;
}
void occlusion_set_clock(occlusion_t *o, occ_clock_fn fn) { o->clock = fn; }

/* The base pose at t, interpolated (or carried on with its velocity a little); false if
 * the history does not cover t or the pose there is not usable. */
static bool pose_at(const occlusion_t *o, int64_t t, double pos[3], double q[4])
{
    const std::deque<occ_pose_in_t> &P = o->poses;
    if (P.empty() || t < P.front().utime) return false;
    if (t >= P.back().utime) {
        const occ_pose_in_t &b = P.back();
        if (!b.usable || t - b.utime > EXTRAPOLATE_US) return false;
        double dt = (t - b.utime) * 1e-6;
        for (int i = 0; i < 3; i++) pos[i] = b.pos[i] + b.vel[i] * dt;
        memcpy(q, b.q, sizeof b.q);
        return true;
    }
    size_t hi = std::upper_bound(P.begin(), P.end(), t, [](int64_t v, const occ_pose_in_t &p) { return v < p.utime; }) - P.begin();
    const occ_pose_in_t &a = P[hi - 1], &b = P[hi];
    if (!a.usable || !b.usable || b.utime - a.utime > GAP_US) return false;
    double f = (double)(t - a.utime) / (double)(b.utime - a.utime);
    for (int i = 0; i < 3; i++) pos[i] = a.pos[i] + f * (b.pos[i] - a.pos[i]);
    double dot = 0;
    for (int i = 0; i < 4; i++) dot += a.q[i] * b.q[i];
    double sgn = dot < 0 ? -1 : 1;
    for (int i = 0; i < 4; i++) q[i] = a.q[i] + f * (sgn * b.q[i] - a.q[i]);
    pb_quat_normalize(q);
    return true;
}

static double yaw_of(const double q[4])
{
    return std::atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] * q[2] + q[3] * q[3]));
}

static void base_to_map(const double pos[3], const double q[4], const double pb[3], double out[3])
{
    pb_quat_rotate(q, pb, out);
    for (int i = 0; i < 3; i++) out[i] += pos[i];
}

/* Every agent's samples at time t, all unknown (the map has nothing to say yet). */
static void agents_at(const occlusion_t *o, int64_t t, occ_output_t *r)
{
    double dt = 0;
    if (o->agents_utime != INT64_MIN)
        dt = std::max<double>(-AGENTS_MAX_DT_US, std::min<double>(AGENTS_MAX_DT_US, (double)(t - o->agents_utime))) * 1e-6;
    r->agents.resize(o->agents.size());
    for (size_t i = 0; i < o->agents.size(); i++) {
        const occ_agent_in_t &a = o->agents[i];
        occ_agent_out_t &g = r->agents[i];
        g.id = a.id;
        double p[3];
        for (int k = 0; k < 3; k++) p[k] = a.pos[k] + a.vel[k] * dt;
        bool finite = std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]) && std::isfinite(a.yaw);
        g.n = finite ? pb_body_samples(a.kind.c_str(), p, a.yaw, g.x, g.y, g.z) : 0;
        for (int k = 0; k < g.n; k++) { g.state[k] = OCC_UNKNOWN; g.occluder_m[k] = NAN; }
        g.visible_fraction = 0;
        g.evaluated = false;
    }
}

/* One sweep: into the map (if posed), then the agents from the eye. */
static void process(occlusion_t *o, sweep_t &s, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev)
{
    occ_output_t r;
    r.utime = s.end;
    r.integrate = occ_integrate_stats_t{};
    r.integrate_ms = r.query_ms = 0;
    agents_at(o, s.end, &r);
    double bpos[3], bq[4];
    /* 1. poses at the sweep's start, its end and SLOTS times between (each point takes the nearest) */
    bool ok = pose_at(o, s.utime, bpos, bq) && pose_at(o, s.end, bpos, bq);
    double origins[SLOTS][3], lq[SLOTS][4], lt[SLOTS][3];
    int64_t span = std::max<int64_t>(1, s.end - s.utime);
    for (int k = 0; ok && k < SLOTS; k++) {
        double p[3], q[4];
        ok = pose_at(o, s.utime + span * k / (SLOTS - 1), p, q);
        pb_quat_mul(q, o->veh.base_from_lidar.q, lq[k]);
        base_to_map(p, q, o->veh.base_from_lidar.t, lt[k]);
        memcpy(origins[k], lt[k], sizeof lt[k]);
    }
    r.pose_ok = ok;
    if (!ok) {
        r.viewer[0] = r.viewer[1] = r.viewer[2] = NAN;
        r.eye_source = o->last_eye < 0 ? OCC_EYE_SEAT : o->last_eye;
        ev->push_back({ "sweep_without_pose", o->had_pose_ok ? "no usable pose (none, lost, initializing or too old) "
                                                                "for the sweep: every sample unknown" : "" });
        o->had_pose_ok = false;
        out->push_back(std::move(r));
        return;
    }
    if (!o->had_pose_ok) ev->push_back({ "pose_back", "" });
    o->had_pose_ok = true;
    double t0 = o->clock ? o->clock() : 0;
    /* 2. points into the map, each with the sensor pose of its time slot */
    int n = s.pts.n;
    o->mx.resize(n); o->my.resize(n); o->mz.resize(n); o->oi.resize(n);
    double rot[SLOTS][9];   /* pb_quat_rotate's matrices, made once per slot instead of per point */
    for (int k = 0; k < SLOTS; k++) pb_quat_to_matrix(lq[k], rot[k]);
    for (int i = 0; i < n; i++) {
        int k = (int)std::min<int64_t>(SLOTS - 1, std::max<int64_t>(0, (int64_t)s.pts.offset_us[i] * (SLOTS - 1) / span));
        const double *R = rot[k], px = s.pts.x[i], py = s.pts.y[i], pz = s.pts.z[i];
        const double mx = R[0] * px + R[1] * py + R[2] * pz, my = R[3] * px + R[4] * py + R[5] * pz, mz = R[6] * px + R[7] * py + R[8] * pz;
        o->mx[i] = (float)(mx + lt[k][0]); o->my[i] = (float)(my + lt[k][1]); o->mz[i] = (float)(mz + lt[k][2]);
        o->oi[i] = (uint16_t)k;
    }
    occ_sweep_t sw = {};
    sw.n = n; sw.x = o->mx.data(); sw.y = o->my.data(); sw.z = o->mz.data();
    sw.origin_index = o->oi.data(); sw.norigins = SLOTS; sw.origins = origins;
    memcpy(sw.mid_origin, lt[SLOTS / 2], sizeof sw.mid_origin);
    pb_quat_to_matrix(lq[SLOTS / 2], sw.mid_rot);
    memcpy(sw.car, bpos, sizeof sw.car);
    sw.ring_gap_rad = s.ring_gap_rad;
    sw.col_gap_rad = s.col_gap_rad;
    /* 3. integrate */
    occ_map_integrate(o->map, &sw, &r.integrate);
    memcpy(o->last_origins, origins, sizeof origins);
    o->last = sw;
    o->last.origins = o->last_origins;
    o->has_last = true;
    double t1 = o->clock ? o->clock() : 0;
    /* 4. the eye: HEAD_POSE when fresh and tracking, else the seat, else the LiDAR */
    double eye_b[3];
    int src;
    if (o->head_tracking && o->head_utime != INT64_MIN && std::llabs(s.end - o->head_utime) <= HEAD_FRESH_US) {
        memcpy(eye_b, o->head, sizeof eye_b); src = OCC_EYE_HEAD;
    } else if (o->veh.has_seat_eye) {
        memcpy(eye_b, o->veh.seat_eye, sizeof eye_b); src = OCC_EYE_SEAT;
    } else {
        memcpy(eye_b, o->veh.base_from_lidar.t, sizeof eye_b); src = OCC_EYE_LIDAR;
    }
    if (src != o->last_eye) {
        static const char *why[] = { "eye from HEAD_POSE", "no fresh tracking HEAD_POSE: eye from the vehicle file's seat",
                                     "no HEAD_POSE and no seat in the vehicle file: eye at the LiDAR" };
        std::string msg = why[src];
        if (src == OCC_EYE_HEAD && o->head_clock.offset) {   /* STATUS keeps the last message: say both */
            char note[96];
            snprintf(note, sizeof note, " (its clock %+.2f s off the car's, corrected)", o->head_clock.offset * 1e-6);
            msg += note;
        }
        ev->push_back({ src == OCC_EYE_HEAD ? "eye_head" : src == OCC_EYE_SEAT ? "eye_seat_fallback" : "eye_lidar_fallback",
                        msg });
        o->last_eye = src;
    }
    r.eye_source = src;
    base_to_map(bpos, bq, eye_b, r.viewer);
    /* 5. every agent in render range: its samples from the eye */
    double yaw = yaw_of(bq);
    for (size_t i = 0; i < r.agents.size(); i++) {
        occ_agent_out_t &g = r.agents[i];
        if (!o->agents[i].in_render_range || g.n == 0) continue;
        occ_map_query(o->map, r.viewer, bpos, yaw, g.x, g.y, g.z, g.n, g.state, g.occluder_m);
        g.evaluated = true;
        int vis = 0;
        for (int k = 0; k < g.n; k++) vis += g.state[k] == OCC_VISIBLE;
        g.visible_fraction = (float)vis / g.n;
    }
    double t2 = o->clock ? o->clock() : 0;
    r.integrate_ms = t1 - t0;
    r.query_ms = t2 - t1;
    out->push_back(std::move(r));
}

static void drain(occlusion_t *o, bool force, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev)
{
    while (!o->sweeps.empty()) {
        sweep_t &s = o->sweeps.front();
        bool covered = !o->poses.empty() && o->poses.back().utime >= s.end;
        bool late = o->sweeps.size() > 1 && o->sweeps.back().utime - s.end > WAIT_US;
        if (!covered && !late && !force) break;
        process(o, s, out, ev);
        pb_points_free(&s.pts);
        o->sweeps.pop_front();
    }
}

void occlusion_pose(occlusion_t *o, const occ_pose_in_t *p, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev)
{
    bool finite = true;
    for (int i = 0; i < 3; i++) finite = finite && std::isfinite(p->pos[i]) && std::isfinite(p->vel[i]);
    for (int i = 0; i < 4; i++) finite = finite && std::isfinite(p->q[i]);
    if (!finite) { ev->push_back({ "pose_not_finite", "pose with NaN/inf fields ignored" }); return; }
    if (!o->poses.empty() && p->utime <= o->poses.back().utime) {
        ev->push_back({ "pose_out_of_order", "pose older than the previous one ignored" });
        return;
    }
    occ_pose_in_t q = *p;
    pb_quat_normalize(q.q);
    if (!o->poses.empty() && o->poses.back().usable && q.usable) {
        const occ_pose_in_t &b = o->poses.back();
        double dt = (q.utime - b.utime) * 1e-6, jump = 0;
        for (int i = 0; i < 2; i++) jump += std::pow(q.pos[i] - (b.pos[i] + b.vel[i] * dt), 2);
        if (std::sqrt(jump) > JUMP_M) {
            occ_map_clear(o->map);
            ev->push_back({ "pose_jump_map_reset", "the pose jumped: the occupancy map was reset" });
        }
    }
    o->poses.push_back(q);
    o->newest_t = std::max(o->newest_t, q.utime);
    while (o->poses.size() > 2 && o->poses.back().utime - o->poses.front().utime > POSE_KEEP_US) o->poses.pop_front();
    drain(o, false, out, ev);
}

void occlusion_head(occlusion_t *o, int64_t utime, const double pos[3], bool tracking, std::vector<occ_event_t> *ev)
{
    bool finite = std::isfinite(pos[0]) && std::isfinite(pos[1]) && std::isfinite(pos[2]);
    if (pb_clock_offset_add(&o->head_clock, utime, o->newest_t) && ev) {
        char msg[160];
        if (o->head_clock.offset)
            snprintf(msg, sizeof msg, "HEAD_POSE: the headset's clock is %+.2f s off the car's; its times corrected by that",
                     o->head_clock.offset * 1e-6);
        else
            snprintf(msg, sizeof msg, "HEAD_POSE: the headset's clock agrees with the car's again");
        ev->push_back({ "head_clock_offset", msg });
    }
    o->head_utime = utime - o->head_clock.offset;
    o->head_tracking = tracking && finite;
    if (finite) memcpy(o->head, pos, sizeof o->head);
}

void occlusion_agents(occlusion_t *o, int64_t utime, const std::vector<occ_agent_in_t> &agents)
{
    o->agents_utime = utime;
    o->agents = agents;
}

void occlusion_scan(occlusion_t *o, int64_t utime, const pb_points_t *pts, double ring_gap_rad, double col_gap_rad,
                    std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev)
{
    sweep_t s;
    s.utime = utime;
    s.ring_gap_rad = ring_gap_rad;
    s.col_gap_rad = col_gap_rad;
    int32_t last = 0;
    for (int i = 0; i < pts->n; i++) last = std::max(last, pts->offset_us[i]);
    s.end = utime + last;
    o->newest_t = std::max(o->newest_t, s.end);
    memset(&s.pts, 0, sizeof s.pts);
    /* copy: the caller's buffer is reused */
    s.pts.n = s.pts.cap = pts->n;
    size_t nn = pts->n ? pts->n : 1;
    s.pts.x = (float *)malloc(nn * sizeof(float)); s.pts.y = (float *)malloc(nn * sizeof(float));
    s.pts.z = (float *)malloc(nn * sizeof(float)); s.pts.intensity = (float *)malloc(nn * sizeof(float));
    s.pts.offset_us = (int32_t *)malloc(nn * sizeof(int32_t)); s.pts.ring = (uint8_t *)malloc(nn);
    memcpy(s.pts.x, pts->x, pts->n * sizeof(float)); memcpy(s.pts.y, pts->y, pts->n * sizeof(float));
    memcpy(s.pts.z, pts->z, pts->n * sizeof(float)); memcpy(s.pts.offset_us, pts->offset_us, pts->n * sizeof(int32_t));
    if (!o->sweeps.empty() && s.end <= o->sweeps.back().end) {
        ev->push_back({ "scan_out_of_order", "LIDAR_SCAN older than the previous one ignored" });
        pb_points_free(&s.pts);
        return;
    }
    o->sweeps.push_back(s);
    drain(o, false, out, ev);
}

void occlusion_finish(occlusion_t *o, std::vector<occ_output_t> *out, std::vector<occ_event_t> *ev)
{
    drain(o, true, out, ev);
}
