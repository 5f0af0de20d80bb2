/* odometry: see odometry.h. */
#include "odometry.h"

#include <algorithm>
#include <cstring>
#include <cmath>
#include <future>
#include <string>
#include <vector>

#include "deskew.h"
#include "pb_bytes.h"
#include "voxel_hash.h"

using Vec3 = Eigen::Vector3d;

namespace {
struct Cell {
    double sum[3];
    int n;          /* 0: dropped (beyond the local radius), its slot kept until the cells are compacted */
    uint64_t key;   /* the key the index holds it under; kEmpty: none (see rebuild) */
};
}  // namespace

struct pb_odom {
    pb_odom_config_t cfg;
    pb_reg_config_t reg;
    int64_t sweeps = 0;
    int64_t last_utime = 0;
    Eigen::Isometry3d last_pose = Eigen::Isometry3d::Identity();
    Vec3 v = Vec3::Zero(), w = Vec3::Zero();   /* base frame, of the last step */
    bool motion_known = false;
    /* the local map: cell -> centroid accumulator */
    pb_loc::VoxelHash index;
    std::vector<Cell> cells;
    size_t dropped = 0;   /* cells with n 0 */
    /* the registration map and where it was built */
    pb_regmap_t *regmap = nullptr;
    std::vector<float> regmap_src;   /* the points it was built from (for pb_odom_save) */
    std::vector<float> last_sweep;
    Vec3 built_at = Vec3::Zero();
    int64_t built_sweep = 0;
    /* the next registration map, built on another thread from the cells near the car
     * while the sweeps go on; swapped in at the next rebuild (a fixed sweep, whatever the
     * threads' timing: the same sweeps give the same poses) */
    std::future<pb_regmap_t *> next;
    std::vector<float> next_src;     /* the points it is built from */
    int64_t next_sweep = 0;   /* the sweep it is swapped in before ... */
    Vec3 next_from = Vec3::Zero();   /* ... or once the car is kSwapAfterM from where it started */
    std::string next_err;
    /* the last sweep's points going into the cells on another thread, while the next sweep
     * is registered (the registration reads the registration map, not the cells); settled
     * before anything reads or changes the cells */
    mutable std::future<void> adding;
    /* the car's own motion samples: from the newest one at or before the last sweep's middle on */
    std::vector<pb_odom_speed_t> speed;
    std::vector<pb_odom_rate_t> rate;
    /* the drive's start (start_place_m): its sweeps held, deskewed in base, until aligned again */
    struct Held { int64_t utime; Eigen::Isometry3d pose; std::vector<float> pts; };
    bool start_open = true;
    std::vector<Held> held;
    std::vector<pb_odom_correction_t> corrected;
    std::vector<double> sparse_fits;   /* the last sparse sweeps' inlier shares (check_sparse), oldest first */
};

/* Sweeps after its start that a new registration map is swapped in (waiting for it if it is
 * not ready): long enough for a build of the whole local map to overlap the sweeps, short
 * enough that the map keeps up with the car (a map 30 sweeps old doubled the error of a
 * moving start). */
static const int kSwapAfter = 8;
/* ... or once the car has moved this far since: sweeps metres apart (keyframes of a dataset)
 * would otherwise be registered to a map tens of metres behind them. */
static const double kSwapAfterM = 4.0;

/* A cell stops taking points after this many: its centroid is settled, and a cell
 * that keeps being hit (the road under the car) costs nothing more. */
static const int kCellFull = 20;

double pb_odom_cell_m(int cols)
{
    const double cell = pb_odom_config_t().cell_m;
    return cols > 0 ? std::max(cell, 2 * 20.0 * 2 * M_PI / cols) : cell;
}

pb_odom_t *pb_odom_create(const pb_odom_config_t *cfg, const pb_reg_config_t *reg)
{
    pb_odom_t *o = new pb_odom();
    if (cfg) o->cfg = *cfg;
    if (reg) o->reg = *reg;
    else pb_reg_config_default(&o->reg);
    return o;
}

static void settle(const pb_odom_t *o)
{
    if (o->adding.valid()) o->adding.get();
}

void pb_odom_destroy(pb_odom_t *o)
{
    if (!o) return;
    settle(o);
    if (o->next.valid()) pb_regmap_destroy(o->next.get());
    pb_regmap_destroy(o->regmap);
    delete o;
}

static Eigen::Isometry3d exp_step(const Vec3 &v, const Vec3 &w, double dt)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    double a = w.norm() * dt;
    if (a > 1e-12) T.linear() = Eigen::AngleAxisd(a, w.normalized()).toRotationMatrix();
    T.translation() = v * dt;
    return T;
}

static void add_to_map(pb_odom_t *o, const std::vector<float> &xyz, const Eigen::Isometry3d &pose)
{
    const double inv = 1.0 / o->cfg.cell_m;
    uint64_t last_key = pb_loc::VoxelHash::kEmpty;   /* neighbouring points often share a cell: no lookup then */
    int32_t k = -1;
    /* a batch of points keyed and their slots prefetched, then looked up and their cells
     * prefetched, then added in order (the index and cells of a 100 m local map are far
     * larger than the caches: the misses overlap instead of coming one after the other); a
     * key found in the look-up is there still, one not found may have come in with an
     * earlier point of the batch, so only those are inserted */
    const int kBatch = 32;
    Vec3 p[kBatch];
    uint64_t key[kBatch];
    int32_t found[kBatch];
    const size_t n = xyz.size() / 3;
    for (size_t i = 0; i < n;) {
        int m = 0;
        for (; i < n && m < kBatch; i++) {
            p[m] = pose * Vec3(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
            if (!pb_loc::voxel_key_of(p[m].x(), p[m].y(), p[m].z(), inv, &key[m])) continue;
            o->index.prefetch(key[m]);
            m++;
        }
        for (int j = 0; j < m; j++) {
            found[j] = o->index.find(key[j]);
            if (found[j] >= 0) __builtin_prefetch(&o->cells[(size_t)found[j]], 1);
        }
        for (int j = 0; j < m; j++) {
            if (key[j] != last_key) {
                bool fresh = false;
                k = found[j] >= 0 ? found[j] : o->index.insert(key[j], (int32_t)o->cells.size(), &fresh);
                if (fresh) o->cells.push_back(Cell{{0, 0, 0}, 0, key[j]});
                last_key = key[j];
            }
            Cell &c = o->cells[(size_t)k];
            if (c.n >= kCellFull) continue;
            c.sum[0] += p[j].x(); c.sum[1] += p[j].y(); c.sum[2] += p[j].z();
            c.n++;
        }
    }
}

/* Times (microseconds since 1970) this far apart at most: their differences cannot overflow. */
static bool utime_ok(int64_t t) { return t >= 0 && t < ((int64_t)1 << 62); }

/* Appends the samples that come in time order after the ones kept; the others (two
 * sources merged out of order, a time out of range) are left out. */
template <class S>
static void append_in_order(std::vector<S> *kept, const S *add, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (utime_ok(add[i].utime) && (kept->empty() || add[i].utime >= kept->back().utime)) kept->push_back(add[i]);
}

/* Whether samples cover [t0, t1] with no hole longer than max_age_us (the newest one
 * before t0 counts, as does the first one after it when it comes within max_age_us). */
template <class S>
static bool covers(const std::vector<S> &v, int64_t t0, int64_t t1, int64_t max_age_us)
{
    int64_t held = INT64_MIN;
    for (const S &x : v) {
        if (x.utime > t1) break;
        if (x.utime <= t0) { held = x.utime; continue; }
        if ((held == INT64_MIN ? x.utime - t0 : x.utime - held) > max_age_us) return false;
        held = x.utime;
    }
    return held != INT64_MIN && t1 - held <= max_age_us;
}

/* The sample held at t: the newest at or before t, else the first. */
template <class S>
static const S &held_at(const std::vector<S> &v, int64_t t)
{
    size_t k = 0;
    while (k + 1 < v.size() && v[k + 1].utime <= t) k++;
    return v[k];
}

/* The mean rate of the samples within [t0, t1] (a real gyro's noise and the car's
 * vibration average out over a sweep), else the one held at t1. */
static Vec3 mean_rate(const std::vector<pb_odom_rate_t> &v, int64_t t0, int64_t t1)
{
    Vec3 sum = Vec3::Zero();
    int n = 0;
    for (const pb_odom_rate_t &x : v)
        if (x.utime >= t0 && x.utime <= t1) sum += Eigen::Map<const Vec3>(x.rate), n++;
    return n ? Vec3(sum / n) : Vec3(Eigen::Map<const Vec3>(held_at(v, t1).rate));
}

/* Drops the samples before the one held at t. */
template <class S>
static void drop_before(std::vector<S> *v, int64_t t)
{
    size_t k = 0;
    while (k + 1 < v->size() && (*v)[k + 1].utime <= t) k++;
    v->erase(v->begin(), v->begin() + (long)k);
}

/* Dead reckoning from t0 to t1 on the held speed (along base x) and rate, piecewise
 * constant between samples: base(t0) <- base(t1). */
static Eigen::Isometry3d reckon(const std::vector<pb_odom_speed_t> &sp, const std::vector<pb_odom_rate_t> &rt,
                                int64_t t0, int64_t t1)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    size_t i = 0, j = 0;
    int64_t t = t0;
    while (t < t1) {
        while (i + 1 < sp.size() && sp[i + 1].utime <= t) i++;
        while (j + 1 < rt.size() && rt[j + 1].utime <= t) j++;
        int64_t next = t1;
        if (i + 1 < sp.size()) next = std::min(next, sp[i + 1].utime);
        if (j + 1 < rt.size()) next = std::min(next, rt[j + 1].utime);
        if (next <= t) next = t1;
        T = T * exp_step(Vec3(sp[i].speed_mps, 0, 0), Vec3(rt[j].rate[0], rt[j].rate[1], rt[j].rate[2]),
                         (next - t) * 1e-6);
        t = next;
    }
    return T;
}

/* The map being built becomes the registration map. */
static int swap_in(pb_odom_t *o, pb_err_t *err)
{
    if (!o->next.valid()) return 0;
    pb_regmap_t *m = o->next.get();
    if (!m) return pb_err_set(err, "local map: %s", o->next_err.c_str()), -1;
    pb_regmap_destroy(o->regmap);
    o->regmap = m;
    o->regmap_src.swap(o->next_src);
    o->next_src.clear();
    return 0;
}

/* Starts building the next registration map from o->next_src on another thread (it
 * reads o->next_src until swap_in takes the map). */
static void start_next(pb_odom_t *o)
{
    o->next = std::async(std::launch::async, [o]() {
        pb_err_t e;
        /* most of the cells are the last map's: only the voxels whose neighbourhood changed
         * are fitted again (o->regmap is only read, by both threads, until swap_in) */
        pb_regmap_t *m = pb_regmap_rebuild(o->regmap, o->next_src.data(), o->next_src.size() / 3, nullptr, &e);
        if (!m) o->next_err = e.msg;
        return m;
    });
}

/* Drops the cells beyond the local radius and starts building the next registration map
 * from the cells kept (at the first sweep, or when now is set, built at once). */
static int rebuild(pb_odom_t *o, const Vec3 &at, bool now, pb_err_t *err)
{
    const double r2 = o->cfg.local_radius_m * o->cfg.local_radius_m;
    const double inv = 1.0 / o->cfg.cell_m;
    /* the cells kept: their centroids, in their order, are the registration map's points.
     * The index holds each under its centroid's key, the first in order where two share one
     * (a cell added since the last rebuild is held under its first point's key, and a
     * centroid rounded to floats may lie in the next key): the dropped ones are taken out of
     * it and those not under their centroid's key put right, the others stay */
    std::vector<float> pts;
    pts.reserve(3 * (o->cells.size() - o->dropped));
    std::vector<size_t> drop;
    struct Odd { size_t i; uint64_t key; };   /* a kept cell not held under its centroid's key */
    std::vector<Odd> odd;
    for (size_t i = 0; i < o->cells.size(); i++) {
        const Cell &c = o->cells[i];
        if (c.n == 0) continue;
        Vec3 p(c.sum[0] / c.n, c.sum[1] / c.n, c.sum[2] / c.n);
        if ((p.head<2>() - at.head<2>()).squaredNorm() > r2) {
            drop.push_back(i);
            continue;
        }
        pts.insert(pts.end(), {(float)p.x(), (float)p.y(), (float)p.z()});
        uint64_t key;
        const float *q = &pts[pts.size() - 3];
        if (!pb_loc::voxel_key_of(q[0], q[1], q[2], inv, &key)) key = pb_loc::VoxelHash::kEmpty;
        if (key != c.key) odd.push_back({i, key});
    }
    const uint64_t kNone = pb_loc::VoxelHash::kEmpty;
    auto unkey = [o, kNone](Cell &c) {   /* c out of the index */
        if (c.key != kNone) o->index.erase(c.key);
        c.key = kNone;
    };
    if (2 * (o->dropped + drop.size()) <= o->cells.size()) {
        for (size_t i : drop) {
            unkey(o->cells[i]);
            o->cells[i].n = 0;
        }
        o->dropped += drop.size();
        for (const Odd &d : odd) unkey(o->cells[d.i]);
        /* in order: a key goes to the first kept cell whose centroid is in it */
        for (const Odd &d : odd) {
            if (d.key == kNone) continue;
            const int32_t j = o->index.find(d.key);
            if (j >= 0 && (size_t)j < d.i) continue;
            if (j >= 0) unkey(o->cells[(size_t)j]);
            bool fresh;
            o->index.insert(d.key, (int32_t)d.i, &fresh);
            o->cells[d.i].key = d.key;
        }
    } else {
        /* half of the cells dropped: the kept ones compacted, and the index made again over
         * them in their order (deterministic; the same keys as above) */
        size_t k = 0, d = 0;
        for (size_t i = 0; i < o->cells.size(); i++) {
            if (o->cells[i].n == 0) continue;
            if (d < drop.size() && drop[d] == i) { d++; continue; }
            o->cells[k++] = o->cells[i];
        }
        o->cells.resize(k);
        o->dropped = 0;
        o->index.reset(o->cells.size());
        for (size_t i = 0; i < o->cells.size(); i++) {
            uint64_t key;
            bool fresh = false;
            if (pb_loc::voxel_key_of(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2], inv, &key))
                o->index.insert(key, (int32_t)i, &fresh);
            o->cells[i].key = fresh ? key : kNone;
        }
    }
    o->built_at = at;
    o->built_sweep = o->sweeps;
    if (!o->regmap || now) {
        if (o->next.valid()) pb_regmap_destroy(o->next.get());   /* the map being built is older */
        o->next_src.clear();
        pb_regmap_t *m = pb_regmap_rebuild(o->regmap, pts.data(), pts.size() / 3, nullptr, err);
        if (!m) return -1;
        pb_regmap_destroy(o->regmap);
        o->regmap = m;
        o->regmap_src.swap(pts);
        return 0;
    }
    if (swap_in(o, err) != 0) return -1;
    o->next_sweep = o->sweeps + kSwapAfter;
    o->next_from = at;
    o->next_src.swap(pts);
    start_next(o);
    return 0;
}

/* The points xyz (x y z, interleaved) moved by T. */
static std::vector<float> moved(const std::vector<float> &xyz, const Eigen::Isometry3d &T)
{
    std::vector<float> out(xyz.size());
    for (size_t i = 0; i + 2 < xyz.size(); i += 3) {
        const Vec3 q = T * Vec3(xyz[i], xyz[i + 1], xyz[i + 2]);
        for (int a = 0; a < 3; a++) out[i + a] = (float)q[a];
    }
    return out;
}

/* The drive's start: a sweep within start_place_m of the first pose is held; the first one
 * start_realign_m away is the view the held ones are aligned to again (a map of it alone:
 * its beams fall elsewhere on the same surfaces, so their pattern pulls no attitude along). */
static int start_hold(pb_odom_t *o, const pb_odom_result_t &r, const std::vector<float> &pts, pb_err_t *err)
{
    const double d = r.pose.translation().norm();   /* the first pose is the origin */
    if (d < o->cfg.start_place_m) {
        if ((int)o->held.size() >= o->cfg.start_hold_max) o->held.erase(o->held.begin());
        if (o->cfg.start_hold_max > 0) o->held.push_back({r.utime, r.pose, pts});
        return 0;
    }
    if (d < o->cfg.start_realign_m) return 0;
    o->start_open = false;
    if (o->held.empty()) return 0;
    const std::vector<float> view = moved(pts, r.pose);
    pb_regmap_t *m = pb_regmap_from_points(view.data(), view.size() / 3, nullptr, err);
    if (!m) return -1;
    for (const pb_odom::Held &h : o->held) {
        pb_reg_result_t a;
        const int rc = pb_reg_align(m, h.pts.data(), h.pts.size() / 3, h.pose, &o->reg, &a, err);
        if (rc < 0) {
            pb_regmap_destroy(m);
            return -1;
        }
        if (rc != PB_REG_FEW_POINTS) o->corrected.push_back({h.utime, a.pose});
    }
    pb_regmap_destroy(m);
    o->held.clear();
    o->held.shrink_to_fit();
    return 0;
}

static const size_t kSparseFits = 10;

/* A sparse sweep's match r, checked (sparse_fit_drop): when it explains far less than the
 * sweeps before it, the local map may hold sweeps placed wrong (which fit a wrong step best,
 * and each sweep placed by them makes it worse); the sweep before alone, matched from the
 * prediction, cannot pull back that way. r takes that match when the two disagree. */
static int check_sparse(pb_odom_t *o, const std::vector<float> &pts, const Eigen::Isometry3d &pred,
                        pb_odom_result_t *r, pb_err_t *err)
{
    if (!std::isfinite(r->inlier_fraction) || o->last_sweep.empty()) return 0;
    std::vector<double> recent = o->sparse_fits;
    o->sparse_fits.push_back(r->inlier_fraction);
    if (o->sparse_fits.size() > kSparseFits) o->sparse_fits.erase(o->sparse_fits.begin());
    if (recent.size() < kSparseFits / 2) return 0;
    std::nth_element(recent.begin(), recent.begin() + recent.size() / 2, recent.end());
    if (!(r->inlier_fraction < o->cfg.sparse_fit_drop * recent[recent.size() / 2])) return 0;
    const std::vector<float> before = moved(o->last_sweep, o->last_pose);
    pb_err_t e;
    pb_regmap_t *m = pb_regmap_from_points(before.data(), before.size() / 3, nullptr, &e);
    if (!m) return 0;   /* the sweep before holds no surface to match: r stands */
    pb_reg_config_t cfg = o->reg;
    cfg.prior_sigma_m = 0;
    pb_reg_result_t f;
    const int rc = pb_reg_align(m, pts.data(), pts.size() / 3, pred, &cfg, &f, err);
    pb_regmap_destroy(m);
    if (rc < 0) return -1;
    if (rc == PB_REG_FEW_POINTS) return 0;
    const Eigen::Isometry3d d = r->pose.inverse() * f.pose;
    if (d.translation().norm() <= o->cfg.sparse_apart_m &&
        Eigen::AngleAxisd(d.linear()).angle() <= o->cfg.sparse_apart_deg * M_PI / 180)
        return 0;
    r->pose = f.pose;
    r->status = PB_ODOM_PREVIOUS;
    return 0;
}

int pb_odom_add(pb_odom_t *o, int64_t utime, const float *xyz, const int32_t *offset_us, size_t n,
                const pb_odom_motion_t *motion, pb_odom_result_t *out, pb_err_t *err)
{
    if (n == 0) return pb_err_set(err, "sweep at utime %lld has no points", (long long)utime), -1;
    if (!utime_ok(utime)) return pb_err_set(err, "sweep at utime %lld: a time out of range", (long long)utime), -1;
    static const pb_odom_motion_t kNone = {};
    if (!motion) motion = &kNone;
    /* The pose refers to the middle of the sweep: deskewed about its middle, a wrong
     * motion distorts the sweep evenly both ways and does not shift the match. (About
     * its start, the match moves by half the motion's error, the next step's motion
     * errs the other way, and the two feed each other into an oscillation.) */
    int32_t off_min = offset_us[0], off_max = offset_us[0];
    for (size_t i = 1; i < n; i++) {
        off_min = std::min(off_min, offset_us[i]);
        off_max = std::max(off_max, offset_us[i]);
    }
    const int32_t ref_off = (int32_t)(((int64_t)off_min + off_max) / 2);
    const int64_t t_ref = utime + ref_off;
    if (o->sweeps > 0 && t_ref <= o->last_utime)
        return pb_err_set(err, "sweep at utime %lld is not after the last one", (long long)utime), -1;
    const double dt = o->sweeps > 0 ? (t_ref - o->last_utime) * 1e-6 : 0;
    const bool sparse = dt > o->cfg.sparse_gap_s;
    if (dt > o->cfg.max_gap_s) o->motion_known = false;
    append_in_order(&o->speed, motion->speed, motion->n_speed);
    append_in_order(&o->rate, motion->rate, motion->n_rate);
    const int64_t max_age = (int64_t)(o->cfg.max_sample_age_s * 1e6);
    const int64_t t_from = o->sweeps > 0 ? o->last_utime : utime + off_min;
    const bool has_speed = covers(o->speed, t_from, utime + off_max, max_age),
               has_rate = covers(o->rate, t_from, utime + off_max, max_age), measured = has_speed && has_rate;

    // 1. prediction: dead reckoning on the measured motion; else the last step's motion
    //    carried on, with whichever of speed or rate was measured in place of its part
    //    (across a gap only as the centre of the search: standing still is a worse guess
    //    for a car that was moving)
    Vec3 v = o->v, w = o->w;
    if (has_speed) v = Vec3(held_at(o->speed, t_ref).speed_mps, 0, 0);
    if (has_rate) w = mean_rate(o->rate, utime + off_min, utime + off_max);
    Eigen::Isometry3d pred = o->last_pose * (measured ? reckon(o->speed, o->rate, o->last_utime, t_ref)
                                                      : exp_step(v, w, dt));

    // 2. the sweep deskewed to its utime with the motion at the sweep
    std::vector<float> pts(xyz, xyz + 3 * n);
    pb_deskew(pts.data(), offset_us, n, ref_off, v.data(), w.data());

    pb_odom_result_t r;
    r.motion = measured ? PB_ODOM_MOTION_MEASURED : o->motion_known ? PB_ODOM_MOTION_CONSTANT : PB_ODOM_MOTION_NONE;
    r.utime = t_ref;
    r.v_base = v;
    r.w_base = w;
    r.inlier_fraction = NAN;
    r.rebuilt = 0;
    if (o->sweeps == 0) {
        r.status = PB_ODOM_FIRST;
        r.pose = Eigen::Isometry3d::Identity();
    } else {
        // 3. registration from the prediction; a search around it when that is not enough
        const bool predicted = measured || o->motion_known;
        pb_reg_config_t tcfg = o->reg;
        tcfg.prior_sigma_m = !predicted ? 0 : sparse ? o->cfg.sparse_prior_sigma_mps * dt : o->cfg.prior_sigma_m;
        pb_reg_result_t m;
        //    (measured motion over one sweep is a prior of the match: where the sweep hardly
        //    fixes a direction, the dead reckoning does)
        int rc = PB_REG_FEW_POINTS;
        if (measured && !sparse) {
            const double sm = o->cfg.measured_sigma_m, sr = o->cfg.measured_sigma_deg * M_PI / 180;
            Eigen::Matrix<double, 6, 1> var;
            var << sm * sm, sm * sm, sm * sm, sr * sr, sr * sr, sr * sr;
            rc = pb_reg_align_prior(o->regmap, pts.data(), n, pred, var.asDiagonal().toDenseMatrix(), &tcfg, &m, err);
        } else if (predicted) {
            rc = pb_reg_align(o->regmap, pts.data(), n, pred, &tcfg, &m, err);
        }
        if (rc < 0) return -1;
        r.status = PB_ODOM_TRACKED;
        if (rc == PB_REG_FEW_POINTS) {
            pb_reg_result_t g;
            int rg = pb_reg_align_global(o->regmap, pts.data(), n, pred, o->cfg.search_radius_m,
                                         o->cfg.search_yaw_deg * M_PI / 180, &o->reg, &g, err);
            if (rg < 0) return -1;
            if (rg != PB_REG_FEW_POINTS) {
                m = g;
                rc = rg;
                r.status = PB_ODOM_SEARCHED;
            }
        }
        if (rc == PB_REG_FEW_POINTS) {
            r.status = PB_ODOM_PREDICTED;
            r.pose = pred;
        } else {
            r.pose = m.pose;
            r.inlier_fraction = m.inlier_fraction;
            if (!(m.inlier_fraction >= o->cfg.weak_inlier_fraction)) r.status = PB_ODOM_WEAK;
        }
        //    (a sparse sweep the local map fits far worse than those before: checked against
        //    the sweep before alone)
        if (sparse && r.status != PB_ODOM_PREDICTED && check_sparse(o, pts, pred, &r, err) != 0) return -1;
        // 4. the step gives the motion for the next sweep
        Eigen::Isometry3d step = o->last_pose.inverse() * r.pose;
        Eigen::AngleAxisd aa(step.linear());
        o->v = step.translation() / dt;
        o->w = aa.axis() * (aa.angle() / dt);
        o->motion_known = true;
    }

    // 5. the start's sweeps held, and aligned again once the car is far enough from them
    o->corrected.clear();
    if (o->start_open && o->sweeps > 0 && start_hold(o, r, pts, err) != 0) return -1;
    r.corrected = o->corrected.data();
    r.n_corrected = o->corrected.size();

    // 6. the sweep into the local map (on another thread unless the registration map is
    //    rebuilt from it now); the registration map rebuilt every few metres
    settle(o);
    o->last_sweep.swap(pts);
    o->sweeps++;
    o->last_utime = t_ref;
    o->last_pose = r.pose;
    if (o->next.valid() &&
        (o->sweeps >= o->next_sweep || (r.pose.translation() - o->next_from).norm() >= kSwapAfterM)) {
        if (swap_in(o, err) != 0) return -1;
        r.rebuilt = 1;
    }
    if (!o->regmap || sparse || (r.pose.translation() - o->built_at).norm() >= o->cfg.rebuild_m ||
        o->sweeps - o->built_sweep >= o->cfg.rebuild_sweeps) {
        add_to_map(o, o->last_sweep, r.pose);
        if (rebuild(o, r.pose.translation(), sparse, err) != 0) return -1;
        r.rebuilt = 1;
    } else {
        const Eigen::Isometry3d pose = r.pose;
        o->adding = std::async(std::launch::async, [o, pose]() { add_to_map(o, o->last_sweep, pose); });
    }
    drop_before(&o->speed, t_ref);   /* the sample held at this middle starts the next reckoning */
    drop_before(&o->rate, t_ref);
    *out = r;
    return 0;
}

const std::vector<float> &pb_odom_last_sweep(const pb_odom_t *o) { return o->last_sweep; }

/* ---- checkpoint: the state written field by field (no padding), read back with bounds */
static const char kStateMagic[8] = {'P', 'B', 'O', 'D', 'O', 'M', '0', '3'};

static void put_vec3(ByteWriter &w, const Vec3 &v) { for (int k = 0; k < 3; k++) w.put(v[k]); }
static Vec3 get_vec3(ByteReader &r)
{
    Vec3 v;
    for (int k = 0; k < 3; k++) v[k] = r.get<double>();
    return v;
}

void pb_odom_save(const pb_odom_t *o, std::vector<uint8_t> *out)
{
    settle(o);   /* the cells with the last sweep's points */
    out->clear();
    size_t held_bytes = 1 + 8;
    for (const pb_odom::Held &h : o->held) held_bytes += 8 + 96 + 8 + 4 * h.pts.size();
    const size_t live = o->cells.size() - o->dropped;
    out->reserve(256 + 28 * live + 12 * o->index.size() +
                 4 * (o->regmap_src.size() + o->next_src.size()) + 16 * o->speed.size() +
                 32 * o->rate.size() + held_bytes + 8 + 8 * o->sparse_fits.size() + 8 + 4 * o->last_sweep.size());   /* exactly: no doubling */
    ByteWriter w{out};
    for (char c : kStateMagic) w.put(c);
    w.put(o->sweeps); w.put(o->last_utime);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 4; c++) w.put(o->last_pose.matrix()(r, c));
    put_vec3(w, o->v); put_vec3(w, o->w); w.put((uint8_t)o->motion_known);
    put_vec3(w, o->built_at); w.put(o->built_sweep);
    /* the cells as if compacted (the dropped left out, the index's values moved down with
     * them): a state is the same bytes however often its cells were compacted */
    std::vector<int32_t> at(o->cells.size(), -1);
    int32_t k = 0;
    for (size_t i = 0; i < o->cells.size(); i++)
        if (o->cells[i].n > 0) at[i] = k++;
    w.put((uint64_t)live);
    for (const Cell &c : o->cells)
        if (c.n > 0) { w.put(c.sum[0]); w.put(c.sum[1]); w.put(c.sum[2]); w.put(c.n); }
    /* the index as it is: keys of cells added since the last rebuild come from their first
     * point, the others from their centroid, and two centroids may share a key */
    w.put((uint64_t)o->index.size());
    /* in key order: the table's own order depends on its size and on the order the keys came
     * in (a key probed past the table's end lands at its start), and a state restored must save
     * to the same bytes */
    std::vector<std::pair<uint64_t, int32_t>> keyed;
    keyed.reserve(o->index.size());
    o->index.for_each([&](uint64_t key, int32_t value) { keyed.push_back({key, at[(size_t)value]}); });
    std::sort(keyed.begin(), keyed.end());
    for (const auto &kv : keyed) { w.put(kv.first); w.put(kv.second); }
    w.put_array(o->regmap_src.data(), o->regmap_src.size());
    w.put((uint8_t)o->next.valid());
    w.put(o->next_sweep); put_vec3(w, o->next_from);
    w.put_array(o->next_src.data(), o->next_src.size());
    w.put((uint64_t)o->speed.size());
    for (const pb_odom_speed_t &x : o->speed) { w.put(x.utime); w.put(x.speed_mps); }
    w.put((uint64_t)o->rate.size());
    for (const pb_odom_rate_t &x : o->rate) { w.put(x.utime); w.put(x.rate[0]); w.put(x.rate[1]); w.put(x.rate[2]); }
    w.put((uint8_t)o->start_open);
    w.put((uint64_t)o->held.size());
    for (const pb_odom::Held &h : o->held) {
        w.put(h.utime);
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 4; c++) w.put(h.pose.matrix()(r, c));
        w.put_array(h.pts.data(), h.pts.size());
    }
    w.put_array(o->sparse_fits.data(), o->sparse_fits.size());
    w.put_array(o->last_sweep.data(), o->last_sweep.size());
}

/* What a saved state must hold (a checksum passed, but the bytes may still be another
 * program's): a rigid pose, finite motions, cells with 1 to kCellFull points, finite
 * points, samples in time order. */
static bool rigid(const Eigen::Isometry3d &T)
{
    const Eigen::Matrix3d &R = T.linear();
    return T.matrix().allFinite() && ((R.transpose() * R) - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
           std::fabs(R.determinant() - 1) < 1e-6;
}

static bool state_sane(const pb_odom_t *o)
{
    if (!rigid(o->last_pose)) return false;
    if (!o->v.allFinite() || !o->w.allFinite() || !o->built_at.allFinite() || !o->next_from.allFinite() || o->sweeps < 0 ||
        !utime_ok(o->last_utime) || o->built_sweep < 0 || o->built_sweep > o->sweeps || o->next_sweep < 0 ||
        o->next_sweep > o->sweeps + kSwapAfter)
        return false;
    for (const Cell &c : o->cells)
        if (c.n < 1 || c.n > kCellFull || !std::isfinite(c.sum[0] + c.sum[1] + c.sum[2])) return false;
    if (o->sparse_fits.size() > kSparseFits) return false;
    for (double f : o->sparse_fits)
        if (!(f >= 0 && f <= 1)) return false;
    for (const std::vector<float> *v : {&o->regmap_src, &o->next_src, &o->last_sweep}) {
        if (v->size() % 3) return false;
        for (float x : *v)
            if (!std::isfinite(x)) return false;
    }
    for (size_t i = 0; i < o->speed.size(); i++)
        if (!std::isfinite(o->speed[i].speed_mps) || !utime_ok(o->speed[i].utime) ||
            (i && o->speed[i].utime < o->speed[i - 1].utime))
            return false;
    for (size_t i = 0; i < o->rate.size(); i++)
        if (!Eigen::Map<const Vec3>(o->rate[i].rate).allFinite() || !utime_ok(o->rate[i].utime) ||
            (i && o->rate[i].utime < o->rate[i - 1].utime))
            return false;
    if ((int)o->held.size() > std::max(o->cfg.start_hold_max, 0) || (!o->start_open && !o->held.empty())) return false;
    for (size_t i = 0; i < o->held.size(); i++) {
        const pb_odom::Held &h = o->held[i];
        if (!rigid(h.pose) || !utime_ok(h.utime) || h.utime > o->last_utime || (i && h.utime <= o->held[i - 1].utime) || h.pts.size() % 3)
            return false;
        for (float x : h.pts)
            if (!std::isfinite(x)) return false;
    }
    return true;
}

pb_odom_t *pb_odom_restore(const uint8_t *data, size_t n, const pb_odom_config_t *cfg, const pb_reg_config_t *reg,
                           pb_err_t *err)
{
    ByteReader r{data, data + n};
    for (char c : kStateMagic)
        if (r.get<char>() != c || !r.ok) return pb_err_set(err, "odometry state: not of this version"), nullptr;
    pb_odom_t *o = pb_odom_create(cfg, reg);
    o->sweeps = r.get<int64_t>(); o->last_utime = r.get<int64_t>();
    for (int i = 0; i < 3; i++)
        for (int c = 0; c < 4; c++) o->last_pose.matrix()(i, c) = r.get<double>();
    o->v = get_vec3(r); o->w = get_vec3(r); o->motion_known = r.get<uint8_t>() != 0;
    o->built_at = get_vec3(r); o->built_sweep = r.get<int64_t>();
    uint64_t ncells = r.get<uint64_t>();
    if (r.ok && ncells <= n / 28) {
        o->cells.resize(ncells);
        for (Cell &c : o->cells) {
            c.sum[0] = r.get<double>(); c.sum[1] = r.get<double>(); c.sum[2] = r.get<double>(); c.n = r.get<int>();
            c.key = pb_loc::VoxelHash::kEmpty;
        }
    } else r.ok = false;
    uint64_t nindex = r.get<uint64_t>();
    if (r.ok && nindex <= n / 12) {
        o->index.reset(nindex);
        std::vector<uint8_t> indexed(ncells, 0);   /* a cell has one key at most */
        for (uint64_t i = 0; i < nindex && r.ok; i++) {
            uint64_t key = r.get<uint64_t>();
            int32_t value = r.get<int32_t>();
            if (value < 0 || (uint64_t)value >= ncells || indexed[(size_t)value]++) { r.ok = false; break; }
            bool fresh;
            o->index.insert(key, value, &fresh);
            if (!fresh) r.ok = false;   /* a key twice */
            o->cells[(size_t)value].key = key;
        }
    } else r.ok = false;
    r.get_array(&o->regmap_src);
    bool pending = r.get<uint8_t>() != 0;
    o->next_sweep = r.get<int64_t>(); o->next_from = get_vec3(r);
    r.get_array(&o->next_src);
    const uint64_t nspeed = r.get<uint64_t>();
    for (uint64_t i = 0; i < nspeed && r.ok && i <= n / 16; i++) {
        pb_odom_speed_t x;
        x.utime = r.get<int64_t>(); x.speed_mps = r.get<double>();
        o->speed.push_back(x);
    }
    const uint64_t nrate = r.get<uint64_t>();
    for (uint64_t i = 0; i < nrate && r.ok && i <= n / 32; i++) {
        pb_odom_rate_t x;
        x.utime = r.get<int64_t>(); x.rate[0] = r.get<double>(); x.rate[1] = r.get<double>(); x.rate[2] = r.get<double>();
        o->rate.push_back(x);
    }
    o->start_open = r.get<uint8_t>() != 0;
    const uint64_t nheld = r.get<uint64_t>();
    for (uint64_t i = 0; i < nheld && r.ok && i <= n / 112; i++) {
        pb_odom::Held h;
        h.pose = Eigen::Isometry3d::Identity();
        h.utime = r.get<int64_t>();
        for (int a = 0; a < 3; a++)
            for (int c = 0; c < 4; c++) h.pose.matrix()(a, c) = r.get<double>();
        r.get_array(&h.pts);
        o->held.push_back(std::move(h));
    }
    r.get_array(&o->sparse_fits);
    r.get_array(&o->last_sweep);
    if (!r.ok || r.p != r.end || o->held.size() != nheld) {
        pb_odom_destroy(o);
        return pb_err_set(err, "odometry state: truncated or damaged"), nullptr;
    }
    if (!state_sane(o)) {
        pb_odom_destroy(o);
        return pb_err_set(err, "odometry state: damaged (a value out of its range)"), nullptr;
    }
    /* the registration maps again from their points (a build is deterministic) */
    if (!o->regmap_src.empty() && !(o->regmap = pb_regmap_rebuild(nullptr, o->regmap_src.data(), o->regmap_src.size() / 3, nullptr, err))) {
        pb_odom_destroy(o);
        return nullptr;
    }
    if (pending) start_next(o);
    return o;
}
