/* voxel_hash: open-addressing hash from an integer voxel (ix, iy, iz) to an
 * int32 index, for the map cells and the scan downsampling. Internal to the
 * localizer core. Keys pack 21 bits per axis, so |i| < 2^20 voxels per axis. */
#ifndef PB_LOC_VOXEL_HASH_H
#define PB_LOC_VOXEL_HASH_H

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>
#include "pb_math.h"

namespace pb_loc {

static constexpr int64_t kVoxelLimit = (int64_t)1 << 20;

/* Packs a voxel index; returns false when it is outside the key range. */
inline bool voxel_key(int64_t ix, int64_t iy, int64_t iz, uint64_t *key)
{
    if (ix <= -kVoxelLimit || ix >= kVoxelLimit || iy <= -kVoxelLimit || iy >= kVoxelLimit ||
        iz <= -kVoxelLimit || iz >= kVoxelLimit)
        return false;
    *key = ((uint64_t)(ix + kVoxelLimit) << 42) | ((uint64_t)(iy + kVoxelLimit) << 21) |
           (uint64_t)(iz + kVoxelLimit);
    return true;
}

/* Voxel of a point; false for non-finite or far-out coordinates. */
inline bool voxel_index_of(double x, double y, double z, double inv_voxel, int64_t *ix, int64_t *iy, int64_t *iz)
{
    double vx = x * inv_voxel, vy = y * inv_voxel, vz = z * inv_voxel;
    if (!(std::fabs(vx) < 1e6 && std::fabs(vy) < 1e6 && std::fabs(vz) < 1e6))   /* also NaN */
        return false;
    *ix = pb_floor_i64(vx); *iy = pb_floor_i64(vy); *iz = pb_floor_i64(vz);
    return true;
}

inline bool voxel_key_of(double x, double y, double z, double inv_voxel, uint64_t *key)
{
    int64_t ix, iy, iz;
    return voxel_index_of(x, y, z, inv_voxel, &ix, &iy, &iz) && voxel_key(ix, iy, iz, key);
}

inline void voxel_unkey(uint64_t key, int64_t *ix, int64_t *iy, int64_t *iz)
{
    const uint64_t m = ((uint64_t)1 << 21) - 1;
    *ix = (int64_t)((key >> 42) & m) - kVoxelLimit;
    *iy = (int64_t)((key >> 21) & m) - kVoxelLimit;
    *iz = (int64_t)(key & m) - kVoxelLimit;
}

class VoxelHash {
public:
    static constexpr uint64_t kEmpty = ~(uint64_t)0;

    explicit VoxelHash(size_t expected = 16) { reset(expected); }

    /* Empties the table, sized for about `expected` keys without growing. */
    void reset(size_t expected)
    {
        size_t cap = 16;
        while (cap < expected * 2) cap <<= 1;
        keys_.assign(cap, kEmpty);
        vals_.assign(cap, -1);
        set_capacity(cap);
        size_ = 0;
    }

    size_t size() const { return size_; }

    /* Index stored for key, or -1. */
    int32_t find(uint64_t key) const
    {
        for (size_t i = slot(key);; i = (i + 1) & mask_) {
            if (keys_[i] == key) return vals_[i];
            if (keys_[i] == kEmpty) return -1;
        }
    }

    /* Asks for key's slot in the cache: a look-up soon after finds it there (a batch of
     * keys prefetched, then looked up, overlaps their misses in a large table). */
    void prefetch(uint64_t key) const
    {
        const size_t i = slot(key);
        __builtin_prefetch(&keys_[i]);
        __builtin_prefetch(&vals_[i]);
    }

    /* Returns the index stored for key; inserts value_if_new when absent
     * (*inserted tells which). */
    int32_t insert(uint64_t key, int32_t value_if_new, bool *inserted)
    {
        if ((size_ + 1) * 2 > keys_.size()) grow();
        for (size_t i = slot(key);; i = (i + 1) & mask_) {
            if (keys_[i] == key) { *inserted = false; return vals_[i]; }
            if (keys_[i] == kEmpty) {
                keys_[i] = key; vals_[i] = value_if_new; size_++;
                *inserted = true;
                return value_if_new;
            }
        }
    }

    /* Removes key (if there); true if it was. The entries after it in its run move back
     * into the gap, so that every look-up still finds its key before an empty slot. */
    bool erase(uint64_t key)
    {
        size_t i = slot(key);
        for (;; i = (i + 1) & mask_) {
            if (keys_[i] == key) break;
            if (keys_[i] == kEmpty) return false;
        }
        for (size_t j = (i + 1) & mask_; keys_[j] != kEmpty; j = (j + 1) & mask_) {
            /* the entry at j may fill the gap at i unless its own slot lies in (i, j] */
            const size_t home = slot(keys_[j]);
            if (((j - home) & mask_) < ((j - i) & mask_)) continue;
            keys_[i] = keys_[j];
            vals_[i] = vals_[j];
            i = j;
        }
        keys_[i] = kEmpty;
        vals_[i] = -1;
        size_--;
        return true;
    }

    /* Calls fn(key, value) for every entry, in table order (deterministic for one
     * sequence of insertions and erasures). */
    template <class F> void for_each(F fn) const
    {
        for (size_t i = 0; i < keys_.size(); i++)
            if (keys_[i] != kEmpty) fn(keys_[i], vals_[i]);
    }

private:
    /* Fibonacci hashing: the top bits of the product mix every bit of the key */
    size_t slot(uint64_t key) const { return (size_t)((key * 0x9E3779B97F4A7C15ull) >> shift_); }

    void set_capacity(size_t cap)
    {
        mask_ = cap - 1;
        shift_ = 64;
        while (cap > 1) { cap >>= 1; shift_--; }
    }

    void grow()
    {
        std::vector<uint64_t> k; std::vector<int32_t> v;
        k.swap(keys_); v.swap(vals_);
        keys_.assign(k.size() * 2, kEmpty);
        vals_.assign(k.size() * 2, -1);
        set_capacity(keys_.size());
        for (size_t j = 0; j < k.size(); j++) {
            if (k[j] == kEmpty) continue;
            size_t i = slot(k[j]);
            while (keys_[i] != kEmpty) i = (i + 1) & mask_;
            keys_[i] = k[j]; vals_[i] = v[j];
        }
    }

    std::vector<uint64_t> keys_;
    std::vector<int32_t> vals_;
    size_t mask_ = 0, size_ = 0;
    int shift_ = 60;
};

/* A set of voxels as bits over a box of voxel indices (z fastest, so a voxel's 27 neighbours
 * lie in 9 runs of 3 bits): a test costs a cached read where a hash look-up of a voxel that
 * is not there costs a miss. */
struct VoxelBits {
    int64_t lo[3] = {0, 0, 0}, hi[3] = {-1, -1, -1}, ny = 0, nz = 0;
    std::vector<uint64_t> words;   /* empty: nothing held (the box was too large) */

    /* No bit set over the box lo..hi (inclusive); false, and nothing held, when it would
     * take more than max_bits. */
    bool cover(const int64_t box_lo[3], const int64_t box_hi[3], int64_t max_bits)
    {
        words.clear();
        for (int a = 0; a < 3; a++) { lo[a] = box_lo[a]; hi[a] = box_hi[a]; }
        const int64_t nx = hi[0] - lo[0] + 1;
        ny = hi[1] - lo[1] + 1;
        nz = hi[2] - lo[2] + 1;
        if (nx < 1 || ny < 1 || nz < 1 || nx * ny > max_bits / nz) return false;
        words.assign((size_t)((nx * ny * nz + 63) / 64), 0);
        return true;
    }
    /* The same over the box of keys grown by margin. */
    bool cover_keys(const std::vector<uint64_t> &keys, int margin, int64_t max_bits)
    {
        int64_t l[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, h[3] = {INT64_MIN, INT64_MIN, INT64_MIN};
        for (uint64_t key : keys) {
            int64_t v[3];
            voxel_unkey(key, &v[0], &v[1], &v[2]);
            for (int a = 0; a < 3; a++) { l[a] = std::min(l[a], v[a] - margin); h[a] = std::max(h[a], v[a] + margin); }
        }
        if (keys.empty()) { words.clear(); return false; }
        return cover(l, h, max_bits);
    }
    bool inside(int64_t x, int64_t y, int64_t z) const
    {
        return x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1] && z >= lo[2] && z <= hi[2];
    }
    /* the bit of (x, y, z), which must lie in the box */
    uint64_t at(int64_t x, int64_t y, int64_t z) const { return (uint64_t)(((x - lo[0]) * ny + (y - lo[1])) * nz + (z - lo[2])); }
    bool get(uint64_t b) const { return (words[b >> 6] >> (b & 63)) & 1; }
    bool has(int64_t x, int64_t y, int64_t z) const { return get(at(x, y, z)); }
    void set(uint64_t key)
    {
        int64_t x, y, z;
        voxel_unkey(key, &x, &y, &z);
        const uint64_t b = at(x, y, z);
        words[b >> 6] |= (uint64_t)1 << (b & 63);
    }
};

/* The voxel keys of the next points of a cloud, a batch at a time, each key's slot in a
 * hash prefetched: the caller then adds the batch's points in order, and the misses of a
 * table far larger than the caches overlap instead of coming one after the other. */
struct KeyBatch {
    static constexpr int kMax = 32;
    uint64_t key[kMax];
    size_t point[kMax];   /* the point's index in the cloud */
    int n = 0;

    /* The next points of xyz (n_points, interleaved) from *i on, without those that have no
     * key; *i moves past them. Returns the batch's size (0: the cloud is done). */
    int next(const float *xyz, size_t n_points, size_t *i, double inv_voxel, const VoxelHash &hash)
    {
        n = 0;
        for (; *i < n_points && n < kMax; ++*i) {
            const float *p = xyz + 3 * *i;
            if (!voxel_key_of(p[0], p[1], p[2], inv_voxel, &key[n])) continue;
            hash.prefetch(key[n]);
            point[n++] = *i;
        }
        return n;
    }
};

}  // namespace pb_loc
#endif
