// pb_map_build: see pb_map_build.h.
#include "pb_map_build.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <new>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>


namespace {

struct TimedPose {
    int64_t utime;
    Eigen::Vector3d t;
    Eigen::Quaterniond q;
};

Eigen::Quaterniond to_eigen_q(const double q[4])
{
    Eigen::Quaterniond e(q[0], q[1], q[2], q[3]);
    e.normalize();
    return e;
}

// A rigid transform as a 3x4 matrix, what the per-point loop wants.
struct Rt {
    Eigen::Matrix3d R;
    Eigen::Vector3d t;
};

Rt compose(const Eigen::Quaterniond &q, const Eigen::Vector3d &t, const Rt *right)
{
    Rt out;
    Eigen::Matrix3d R = q.toRotationMatrix();
    if (right) {
        out.R = R * right->R;
        out.t = R * right->t + t;
    } else {
        out.R = R;
        out.t = t;
    }
    return out;
}

Rt from_transform(const pb_transform_t *x)
{
    Rt r;
    r.R = to_eigen_q(x->q).toRotationMatrix();
    r.t = Eigen::Vector3d(x->t[0], x->t[1], x->t[2]);
    return r;
}

} // namespace

// ---------------------------------------------------------------- pose track
struct pb_pose_track {
    mutable std::vector<TimedPose> poses;
    /* sorted on the first read after an add out of order; readers on several threads at once
     * (the mapper places a sweep on one while it looks up the next sweep's reach on another)
     * must not both sort */
    mutable std::atomic<bool> sorted{true};
    mutable std::mutex sorting;

    void sort() const
    {
        if (sorted.load(std::memory_order_acquire)) return;
        std::lock_guard<std::mutex> lock(sorting);
        if (sorted.load(std::memory_order_relaxed)) return;
        std::stable_sort(poses.begin(), poses.end(),
                         [](const TimedPose &a, const TimedPose &b) { return a.utime < b.utime; });
        sorted.store(true, std::memory_order_release);
    }

    // Interpolated pose at utime; false outside the track.
    bool at(int64_t utime, Eigen::Vector3d &t, Eigen::Quaterniond &q) const
    {
        sort();
        auto it = std::upper_bound(poses.begin(), poses.end(), utime,
                                   [](int64_t u, const TimedPose &p) { return u < p.utime; });
        if (it == poses.begin()) return false;
        const TimedPose &a = *(it - 1);
        if (a.utime == utime) {
            t = a.t;
            q = a.q;
            return true;
        }
        if (it == poses.end()) return false;
        const TimedPose &b = *it;
        double s = double(utime - a.utime) / double(b.utime - a.utime);
        t = a.t + s * (b.t - a.t);
        q = a.q.slerp(s, b.q);
        return true;
    }
};

extern "C" pb_pose_track_t *pb_pose_track_create(void)
{
    return new (std::nothrow) pb_pose_track;
}

extern "C" void pb_pose_track_destroy(pb_pose_track_t *t) { delete t; }

extern "C" void pb_pose_track_add(pb_pose_track_t *t, int64_t utime, const pb_transform_t *pose)
{
    if (!t->poses.empty() && utime < t->poses.back().utime) t->sorted.store(false, std::memory_order_relaxed);
    t->poses.push_back({utime, Eigen::Vector3d(pose->t[0], pose->t[1], pose->t[2]), to_eigen_q(pose->q)});
}

extern "C" int pb_pose_track_count(const pb_pose_track_t *t) { return (int)t->poses.size(); }

extern "C" int pb_pose_track_span(const pb_pose_track_t *t, int64_t *first, int64_t *last)
{
    if (t->poses.empty()) return -1;
    t->sort();
    if (first) *first = t->poses.front().utime;
    if (last) *last = t->poses.back().utime;
    return 0;
}

extern "C" int pb_pose_track_at(const pb_pose_track_t *t, int64_t utime, pb_transform_t *out)
{
    Eigen::Vector3d p;
    Eigen::Quaterniond q;
    if (!t->at(utime, p, q)) return 0;
    for (int k = 0; k < 3; k++) out->t[k] = p[k];
    out->q[0] = q.w(); out->q[1] = q.x(); out->q[2] = q.y(); out->q[3] = q.z();
    return 1;
}

// ---------------------------------------------------------------- map builder
namespace {

constexpr int64_t KEY_HALF = int64_t(1) << 20;   // 21 bits per axis, signed

// sums of offsets from the voxel's min corner (small: precise in float), of intensities
using Voxel = pb_map_voxel_t;

// The voxels in blocks of fixed size: the store grows a block at a time, never copying
// (a vector doubling its capacity held old and new, three times the voxels, at its peak).
// A tile's store has smaller blocks (a tile at the sensor's far range holds few voxels).
class VoxelStore {
public:
    explicit VoxelStore(int shift = 16) : shift_(shift), mask_((size_t(1) << shift) - 1) {}
    size_t size() const { return n_; }
    Voxel &operator[](size_t i) { return blocks_[i >> shift_][i & mask_]; }
    const Voxel &operator[](size_t i) const { return blocks_[i >> shift_][i & mask_]; }
    void push_back(const Voxel &v)
    {
        if (n_ == blocks_.size() << shift_) blocks_.emplace_back(new Voxel[mask_ + 1]);
        (*this)[n_++] = v;
    }
private:
    int shift_;
    size_t mask_;
    std::vector<std::unique_ptr<Voxel[]>> blocks_;
    size_t n_ = 0;
};

inline uint64_t mix(uint64_t k)
{
    k ^= k >> 33; k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33; k *= 0xc4ceb9fe1a85ec53ULL;
    k ^= k >> 33;
    return k;
}

} // namespace

// Voxel key of a point (inv: 1 / the voxel's edge); false if outside the key range. f* =
// voxel min corner indices.
static bool voxel_key_of(double inv, double x, double y, double z, uint64_t *key, double f[3])
{
    f[0] = std::floor(x * inv); f[1] = std::floor(y * inv); f[2] = std::floor(z * inv);
    if (!(std::fabs(f[0]) < KEY_HALF && std::fabs(f[1]) < KEY_HALF && std::fabs(f[2]) < KEY_HALF)) return false;
    *key = uint64_t(int64_t(f[0]) + KEY_HALF) << 42 | uint64_t(int64_t(f[1]) + KEY_HALF) << 21 |
           uint64_t(int64_t(f[2]) + KEY_HALF);
    return true;
}

struct pb_map_builder {
    double voxel = 0, inv = 0;
    int64_t points_in = 0;
    float max_range2 = 0;        // points farther than its root left out (0: none) ...
    int64_t points_beyond = 0;   // ... and counted
    // voxel mode: open-addressing table of indices (+1, 0 = empty) into voxels
    VoxelStore voxels;
    std::vector<uint32_t> slots;
    uint64_t mask = 0;
    int64_t last = -1;          // voxel of the previous point
    uint32_t made_here = 0, *made = &made_here;   // voxels made: the next one's seq (a tile counts in its builder's)
    uint32_t stamp_here = 0, *stamp = &stamp_here;   // the points' stamp (a tile's is its builder's)
    size_t first_table = size_t(1) << 16;
    static constexpr int BATCH = 64;
    // keep-all mode
    std::vector<float> px, py, pz, pi;
    // tiled: a builder per tile of `tile` voxels a side, by (tx << 32 | uint32 ty)
    int64_t tile = 0;
    std::unordered_map<int64_t, std::unique_ptr<pb_map_builder>> tiles;
    int64_t last_tile = 0;
    pb_map_builder *last_sub = nullptr;

    pb_map_builder() = default;
    explicit pb_map_builder(const pb_map_builder &parent)
        : voxel(parent.voxel), inv(parent.inv), voxels(12), made(parent.made), stamp(parent.stamp),
          first_table(size_t(1) << 10) {}
    pb_map_builder &operator=(const pb_map_builder &) = delete;

    static int64_t floor_div(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
    static int64_t tile_key(int64_t tx, int64_t ty) { return int64_t(uint64_t(tx) << 32 | uint32_t(ty)); }

    // The tile builder of voxel index (ix, iy), made when not held.
    pb_map_builder *sub(int64_t ix, int64_t iy)
    {
        int64_t k = tile_key(floor_div(ix, tile), floor_div(iy, tile));
        if (last_sub && k == last_tile) return last_sub;
        std::unique_ptr<pb_map_builder> &t = tiles[k];
        if (!t) t.reset(new pb_map_builder(*this));
        last_tile = k;
        return last_sub = t.get();
    }

    void grow()
    {
        size_t cap = slots.empty() ? first_table : slots.size() * 2;
        slots.assign(cap, 0);
        mask = cap - 1;
        for (size_t k = 0; k < voxels.size(); k++) {
            uint64_t h = mix(voxels[k].key) & mask;
            while (slots[h]) h = (h + 1) & mask;
            slots[h] = uint32_t(k + 1);
        }
    }

    bool key_of(double x, double y, double z, uint64_t *key, double f[3]) const { return voxel_key_of(inv, x, y, z, key, f); }

    // Adds one point to its voxel (voxel > 0).
    void insert(uint64_t key, const double f[3], double x, double y, double z, float intensity)
    {
        float ox = float(x - f[0] * voxel), oy = float(y - f[1] * voxel), oz = float(z - f[2] * voxel);
        auto add = [&](Voxel &v) {
            v.sx += ox; v.sy += oy; v.sz += oz; v.si += intensity; v.n++;
            v.first = std::min(v.first, *stamp);
            v.last = std::max(v.last, *stamp);
        };
        // Neighbouring points of a sweep often share a voxel: skip the hash then.
        if (last >= 0 && voxels[size_t(last)].key == key) {
            add(voxels[size_t(last)]);
            return;
        }
        if ((voxels.size() + 1) * 10 > slots.size() * 7) grow();     // load <= 0.7
        uint64_t h = mix(key) & mask;
        for (;;) {
            uint32_t s = slots[h];
            if (!s) {
                slots[h] = uint32_t(voxels.size() + 1);
                last = int64_t(voxels.size());
                voxels.push_back({key, ox, oy, oz, intensity, 1, (*made)++, *stamp, *stamp});
                return;
            }
            Voxel &v = voxels[s - 1];
            if (v.key == key) {
                add(v);
                last = int64_t(s - 1);
                return;
            }
            h = (h + 1) & mask;
        }
    }

    // Adds n points (xyz interleaved, map frame). The table is far larger than
    // the caches, so a batch first computes every key and prefetches its slot,
    // then its voxel record, and only then updates: the misses overlap instead
    // of being paid one after the other. Returns the index of a point outside
    // the key range, or -1.
    int add_batch(const double *xyz, const float *inten, int n)
    {
        if (voxel <= 0) {
            for (int k = 0; k < n; k++) {
                px.push_back(float(xyz[3 * k])); py.push_back(float(xyz[3 * k + 1]));
                pz.push_back(float(xyz[3 * k + 2])); pi.push_back(inten[k]);
            }
            return -1;
        }
        uint64_t keys[BATCH];
        double f[BATCH][3];
        if (tile) {   // the same three steps, each point in its tile's table
            pb_map_builder *sub_of[BATCH];
            for (int k = 0; k < n; k++) {
                if (!key_of(xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2], &keys[k], f[k])) return k;
                pb_map_builder *t = sub_of[k] = sub(int64_t(f[k][0]), int64_t(f[k][1]));
                if (!t->slots.empty()) __builtin_prefetch(&t->slots[mix(keys[k]) & t->mask]);
            }
            for (int k = 0; k < n; k++) {
                pb_map_builder *t = sub_of[k];
                uint32_t s = t->slots.empty() ? 0 : t->slots[mix(keys[k]) & t->mask];
                if (s) __builtin_prefetch(&t->voxels[s - 1], 1);
            }
            for (int k = 0; k < n; k++)
                sub_of[k]->insert(keys[k], f[k], xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2], inten[k]);
            return -1;
        }
        for (int k = 0; k < n; k++) {
            if (!key_of(xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2], &keys[k], f[k])) return k;
            if (!slots.empty()) __builtin_prefetch(&slots[mix(keys[k]) & mask]);
        }
        if (!slots.empty())
            for (int k = 0; k < n; k++) {
                uint32_t s = slots[mix(keys[k]) & mask];
                if (s) __builtin_prefetch(&voxels[s - 1], 1);
            }
        for (int k = 0; k < n; k++) insert(keys[k], f[k], xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2], inten[k]);
        return -1;
    }

    int64_t size() const
    {
        int64_t n = voxel > 0 ? int64_t(voxels.size()) : int64_t(px.size());
        for (const auto &t : tiles) n += t.second->size();
        return n;
    }

    void point(int64_t k, float out[4]) const
    {
        if (voxel <= 0) {
            out[0] = px[k]; out[1] = py[k]; out[2] = pz[k]; out[3] = pi[k];
            return;
        }
        voxel_point(voxels[k], out);
    }

    void voxel_point(const Voxel &v, float out[4]) const
    {
        double ix = double(int64_t(v.key >> 42) - KEY_HALF);
        double iy = double(int64_t((v.key >> 21) & 0x1fffff) - KEY_HALF);
        double iz = double(int64_t(v.key & 0x1fffff) - KEY_HALF);
        out[0] = float(ix * voxel + v.sx / v.n);
        out[1] = float(iy * voxel + v.sy / v.n);
        out[2] = float(iz * voxel + v.sz / v.n);
        out[3] = v.si / v.n;
    }

    int out_of_range(pb_err_t *err, double x, double y, double z) const
    {
        return pb_err_set(err, "point (%.1f, %.1f, %.1f) is more than %.0f m from the map origin "
                          "(2^20 voxels of %.3f m)", x, y, z, double(KEY_HALF) * voxel, voxel);
    }
};

namespace {
// Collects transformed points and hands them to the builder BATCH at a time.
struct Batch {
    pb_map_builder *b;
    double xyz[3 * pb_map_builder::BATCH];
    float inten[pb_map_builder::BATCH];
    int n = 0;
    int bad = -1;
    explicit Batch(pb_map_builder *b_) : b(b_) {}
    int push(const Eigen::Vector3d &p, float i)
    {
        xyz[3 * n] = p.x(); xyz[3 * n + 1] = p.y(); xyz[3 * n + 2] = p.z();
        inten[n++] = i;
        return n == pb_map_builder::BATCH ? flush() : 0;
    }
    int flush()
    {
        bad = n ? b->add_batch(xyz, inten, n) : -1;
        n = 0;
        return bad < 0 ? 0 : -1;
    }
    int fail(pb_err_t *err) const
    {
        return b->out_of_range(err, xyz[3 * bad], xyz[3 * bad + 1], xyz[3 * bad + 2]);
    }
};
} // namespace

extern "C" pb_map_builder_t *pb_map_builder_create(double voxel_m, pb_err_t *err)
{
    if (!std::isfinite(voxel_m)) {
        pb_err_set(err, "voxel size must be a finite number of metres");
        return nullptr;
    }
    pb_map_builder_t *b = new (std::nothrow) pb_map_builder;
    if (!b) {
        pb_err_set(err, "out of memory");
        return nullptr;
    }
    b->voxel = voxel_m > 0 ? voxel_m : 0;
    b->inv = voxel_m > 0 ? 1.0 / voxel_m : 0;
    return b;
}

extern "C" void pb_map_builder_destroy(pb_map_builder_t *b) { delete b; }

extern "C" pb_map_builder_t *pb_map_builder_create_tiled(double voxel_m, int tile_voxels, pb_err_t *err)
{
    if (!(voxel_m > 0) || tile_voxels < 1) {
        pb_err_set(err, "a tiled map needs voxels (%g m) and tiles of one voxel or more (%d)", voxel_m, tile_voxels);
        return nullptr;
    }
    pb_map_builder_t *b = pb_map_builder_create(voxel_m, err);
    if (b) b->tile = tile_voxels;
    return b;
}

extern "C" int pb_map_builder_tiles(const pb_map_builder_t *b, int32_t *xy, int max)
{
    int n = 0;
    for (const auto &t : b->tiles) {
        if (n < max) {
            xy[2 * n] = int32_t(uint64_t(t.first) >> 32);
            xy[2 * n + 1] = int32_t(uint32_t(t.first));
        }
        n++;
    }
    return n;
}

extern "C" int64_t pb_map_builder_tile_size(const pb_map_builder_t *b, int32_t tx, int32_t ty)
{
    auto it = b->tiles.find(pb_map_builder::tile_key(tx, ty));
    return it == b->tiles.end() ? 0 : int64_t(it->second->voxels.size());
}

extern "C" void pb_map_builder_tile_take(pb_map_builder_t *b, int32_t tx, int32_t ty, pb_map_voxel_t *out)
{
    auto it = b->tiles.find(pb_map_builder::tile_key(tx, ty));
    if (it == b->tiles.end()) return;
    const VoxelStore &v = it->second->voxels;
    for (size_t i = 0; i < v.size(); i++) out[i] = v[i];
    if (b->last_sub == it->second.get()) b->last_sub = nullptr;
    b->tiles.erase(it);
}

extern "C" int pb_map_builder_put(pb_map_builder_t *b, const pb_map_voxel_t *v, size_t n, pb_err_t *err)
{
    try {
        for (size_t i = 0; i < n; i++) {
            pb_map_builder *t = b->tile ? b->sub(int64_t(v[i].key >> 42) - KEY_HALF,
                                                 int64_t((v[i].key >> 21) & 0x1fffff) - KEY_HALF) : b;
            if ((t->voxels.size() + 1) * 10 > t->slots.size() * 7) t->grow();
            uint64_t h = mix(v[i].key) & t->mask;
            for (; t->slots[h]; h = (h + 1) & t->mask)
                if (t->voxels[t->slots[h] - 1].key == v[i].key)
                    return pb_err_set(err, "map voxel %llx put back while held", (unsigned long long)v[i].key);
            t->slots[h] = uint32_t(t->voxels.size() + 1);
            t->voxels.push_back(v[i]);
            t->last = -1;
        }
    } catch (const std::bad_alloc &) {
        return pb_err_set(err, "out of memory after %lld map points", (long long)b->size());
    }
    return 0;
}

extern "C" void pb_map_voxel_point(const pb_map_builder_t *b, const pb_map_voxel_t *v, float out[4])
{
    b->voxel_point(*v, out);
}

// Every point of the scan moved by transform_of(i) into map: fn(i, p); no-return markers
// skipped, points beyond the max range counted in *beyond and skipped.
template <typename TransformOf, typename Fn>
static void place_each(const pb_map_builder_t *b, const pb_points_t *pts, TransformOf transform_of, int64_t *beyond, Fn fn)
{
    for (int i = 0; i < pts->n; i++) {
        /* a point at the sensor's own origin is no return (Velodyne organized clouds
         * write (0, 0, 0)): a trail of them along the drive is not part of the world */
        if (pts->x[i] == 0 && pts->y[i] == 0 && pts->z[i] == 0) continue;
        if (b->max_range2 > 0 && pts->x[i] * pts->x[i] + pts->y[i] * pts->y[i] + pts->z[i] * pts->z[i] > b->max_range2) {
            (*beyond)++;
            continue;
        }
        const Rt &T = transform_of(i);
        if (fn(i, Eigen::Vector3d(T.R * Eigen::Vector3d(pts->x[i], pts->y[i], pts->z[i]) + T.t)) != 0) return;
    }
}

// Moves every point by transform_of(i) into map and adds it. Returns 0 or -1.
template <typename TransformOf>
static int add_points(pb_map_builder_t *b, const pb_points_t *pts, TransformOf transform_of, pb_err_t *err)
{
    Batch batch(b);
    try {
        int bad = 0;
        place_each(b, pts, transform_of, &b->points_beyond, [&](int i, const Eigen::Vector3d &p) {
            return bad = batch.push(p, pts->intensity ? pts->intensity[i] : 0.f);
        });
        if (bad != 0 || batch.flush() != 0) return batch.fail(err);
    } catch (const std::bad_alloc &) {
        return pb_err_set(err, "out of memory after %lld map points", (long long)b->size());
    }
    b->points_in += pts->n;
    return 0;
}

extern "C" int pb_map_builder_add(pb_map_builder_t *b, const pb_points_t *pts,
                                  const pb_transform_t *map_from_lidar, pb_err_t *err)
{
    Rt T = from_transform(map_from_lidar);
    return add_points(b, pts, [&](int) -> const Rt & { return T; }, err);
}

// The transform of point i of a scan at scan_utime: track(scan_utime + offset_us[i]) *
// base_from_lidar, computed again only when the offset changes (a column's points share it).
struct TimedTransform {
    const pb_pose_track_t *track;
    const pb_points_t *pts;
    int64_t scan_utime;
    const Rt *bl;
    int32_t cached = 0;
    bool have = false;
    Rt T{Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()};
    Eigen::Vector3d t = Eigen::Vector3d::Zero();
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    TimedTransform(const pb_pose_track_t *track_, const pb_points_t *pts_, int64_t utime, const Rt *bl_)
        : track(track_), pts(pts_), scan_utime(utime), bl(bl_) {}
    const Rt &operator()(int i)
    {
        int32_t off = pts->offset_us ? pts->offset_us[i] : 0;
        if (!have || off != cached) {
            track->at(scan_utime + off, t, q);
            T = compose(q, t, bl);
            cached = off;
            have = true;
        }
        return T;
    }
};

// Whether the track brackets every point's time (the track is sorted: both ends suffice).
static bool brackets(const pb_pose_track_t *track, const pb_points_t *pts, int64_t scan_utime)
{
    int32_t omin = 0, omax = 0;
    if (pts->offset_us) {
        omin = omax = pts->offset_us[0];
        for (int i = 1; i < pts->n; i++) {
            omin = std::min(omin, pts->offset_us[i]);
            omax = std::max(omax, pts->offset_us[i]);
        }
    }
    Eigen::Vector3d t;
    Eigen::Quaterniond q;
    return track->at(scan_utime + omin, t, q) && track->at(scan_utime + omax, t, q);
}

extern "C" int pb_map_builder_add_timed(pb_map_builder_t *b, const pb_points_t *pts, int64_t scan_utime,
                                        const pb_pose_track_t *track, const pb_transform_t *base_from_lidar,
                                        pb_err_t *err)
{
    if (pts->n == 0) return 1;
    if (!brackets(track, pts, scan_utime)) return 0;
    Rt bl;
    if (base_from_lidar) bl = from_transform(base_from_lidar);
    return add_points(b, pts, TimedTransform{track, pts, scan_utime, base_from_lidar ? &bl : nullptr}, err) == 0 ? 1 : -1;
}

extern "C" int pb_map_builder_place_timed(const pb_map_builder_t *b, const pb_points_t *pts, int64_t scan_utime,
                                          const pb_pose_track_t *track, const pb_transform_t *base_from_lidar,
                                          double *xyz, int32_t *index, int64_t *beyond)
{
    int64_t far = 0;
    if (beyond) *beyond = 0;
    if (pts->n == 0) return 0;
    if (!brackets(track, pts, scan_utime)) return -1;
    Rt bl;
    if (base_from_lidar) bl = from_transform(base_from_lidar);
    int n = 0;
    place_each(b, pts, TimedTransform{track, pts, scan_utime, base_from_lidar ? &bl : nullptr}, beyond ? beyond : &far,
               [&](int i, const Eigen::Vector3d &p) {
                   xyz[3 * n] = p.x(); xyz[3 * n + 1] = p.y(); xyz[3 * n + 2] = p.z();
                   if (index) index[n] = i;
                   n++;
                   return 0;
               });
    return n;
}

extern "C" int pb_map_builder_add_placed(pb_map_builder_t *b, const pb_points_t *pts, const double *xyz,
                                         const int32_t *index, int n, int64_t beyond, pb_err_t *err)
{
    /* as add_points: the same points in the same order, so the same voxels, sums and seq */
    Batch batch(b);
    try {
        for (int k = 0; k < n; k++)
            if (batch.push(Eigen::Vector3d(xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2]),
                           pts->intensity ? pts->intensity[index[k]] : 0.f) != 0)
                return batch.fail(err);
        if (batch.flush() != 0) return batch.fail(err);
    } catch (const std::bad_alloc &) {
        return pb_err_set(err, "out of memory after %lld map points", (long long)b->size());
    }
    b->points_beyond += beyond;
    b->points_in += pts->n;
    return 0;
}

extern "C" int pb_map_voxel_key(double voxel_m, double x, double y, double z, uint64_t *key)
{
    double f[3];
    return voxel_m > 0 && voxel_key_of(1.0 / voxel_m, x, y, z, key, f) ? 0 : -1;
}

extern "C" void pb_map_voxel_corner(double voxel_m, uint64_t key, double corner[3])
{
    corner[0] = double(int64_t(key >> 42) - KEY_HALF) * voxel_m;
    corner[1] = double(int64_t((key >> 21) & 0x1fffff) - KEY_HALF) * voxel_m;
    corner[2] = double(int64_t(key & 0x1fffff) - KEY_HALF) * voxel_m;
}

extern "C" int64_t pb_map_builder_points_in(const pb_map_builder_t *b) { return b->points_in; }
extern "C" void pb_map_builder_stamp(pb_map_builder_t *b, uint32_t stamp) { *b->stamp = stamp; }
extern "C" void pb_map_builder_set_max_range(pb_map_builder_t *b, double max_m) { b->max_range2 = max_m > 0 ? (float)(max_m * max_m) : 0; }
extern "C" int64_t pb_map_builder_points_beyond(const pb_map_builder_t *b) { return b->points_beyond; }
extern "C" int64_t pb_map_builder_size(const pb_map_builder_t *b) { return b->size(); }

extern "C" int pb_map_builder_bounds(const pb_map_builder_t *b, double mn[3], double mx[3])
{
    int64_t n = b->size();
    if (n == 0 || b->tile) return -1;   /* a tiled map: its tiles' voxels */
    for (int k = 0; k < 3; k++) { mn[k] = INFINITY; mx[k] = -INFINITY; }
    float p[4];
    for (int64_t i = 0; i < n; i++) {
        b->point(i, p);
        for (int k = 0; k < 3; k++) {
            mn[k] = std::min(mn[k], double(p[k]));
            mx[k] = std::max(mx[k], double(p[k]));
        }
    }
    return 0;
}

// Writes n points as binary PCD with the header PCL writes for pcl::PointXYZI, 64K points
// at a time: fill(i, count, out) gives points i .. i + count - 1 (0, or -1 with err set).
// Returns 0 or -1.
template <typename Fill>
static int write_xyzi(const char *path, int64_t n, Fill fill, pb_err_t *err)
{
    if (n > INT32_MAX) return pb_err_set(err, "%s: %lld points do not fit a PCD", path, (long long)n);
    FILE *f = std::fopen(path, "wb");
    if (!f) return pb_err_set(err, "%s: cannot write the PCD: %s", path, std::strerror(errno));
    bool ok = std::fprintf(f,
                           "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\n"
                           "SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH %lld\nHEIGHT 1\n"
                           "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS %lld\nDATA binary\n",
                           (long long)n, (long long)n) > 0;
    std::vector<float> chunk;
    bool filled = true;
    for (int64_t i = 0; ok && i < n;) {
        const int64_t count = std::min<int64_t>(n - i, 65536);
        chunk.resize(4 * size_t(count));
        if (!(filled = fill(i, count, chunk.data()) == 0)) break;
        ok = std::fwrite(chunk.data(), sizeof(float), chunk.size(), f) == chunk.size();
        i += count;
    }
    ok &= std::fclose(f) == 0;
    if (!filled) std::remove(path);
    if (!filled) return -1;
    if (!ok) return pb_err_set(err, "%s: cannot write the PCD: %s", path, std::strerror(errno));
    return 0;
}

extern "C" int pb_pcd_write_xyzi_from(const char *path, int64_t n,
                                      int (*fill)(void *user, int64_t first, int64_t count, float *xyzi, pb_err_t *err),
                                      void *user, pb_err_t *err)
{
    return write_xyzi(path, n, [&](int64_t i, int64_t count, float *out) { return fill(user, i, count, out, err); }, err);
}

extern "C" int pb_map_builder_write_pcd(const pb_map_builder_t *b, const char *path, pb_err_t *err)
{
    int64_t n = b->size();
    if (b->tile) return pb_err_set(err, "%s: a tiled map is written from its tiles", path);
    if (n == 0) return pb_err_set(err, "%s: the map has no points (no scan had bracketing poses?)", path);
    try {
        std::filesystem::path parent = std::filesystem::path(path).parent_path();
        if (!parent.empty()) std::filesystem::create_directories(parent);
    } catch (const std::exception &e) {
        return pb_err_set(err, "%s: cannot create the directory: %s", path, e.what());
    }
    return write_xyzi(path, n, [&](int64_t i, int64_t count, float *out) {
        for (int64_t k = 0; k < count; k++) b->point(i + k, out + 4 * k);
        return 0;
    }, err);
}

// ---------------------------------------------------------------- vehicle
