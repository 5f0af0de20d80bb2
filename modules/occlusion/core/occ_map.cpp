/* occ_map: OctoMap occupancy in a rolling window, cleared by the sweep's own view;
 * eye-ray queries (see occ_map.h). */
#include "occ_map.h"
#include "pb_math.h"

#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <unordered_map>
#include <vector>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

using octomap::OcTree;
using octomap::OcTreeKey;

namespace {

const int KEY_ORIGIN = 32768;               /* OctoMap's key of coordinate 0 (tree depth 16) */
const int BLOCK_FINE_LOG2 = 5;              /* 32 fine voxels: 6.4 m blocks at 0.2 m */
/* bitmap index of the fine occupied voxels, a ring over keys (x, y: 102.4 m; z: 12.8 m at 0.2 m),
 * z the fastest: a column of voxels is one word (a LiDAR column's returns on an object are
 * neighbours in z), and neighbours in x are the next words */
const int FX = 512, FZ = 64;
/* bitmap of observed voxels, a ring (x, y: 128 cells; z: 16) */
const int CX = 128, CZ = 16;
/* ground: lowest return per 1 m cell, a 256 x 256 ring; forgotten after GROUND_TTL sweeps */
const int GN = 256, GROUND_TTL = 50;
/* direction bins of a sweep for clearing */
const int NAZ_LOG2 = 10, NAZ = 1 << NAZ_LOG2, NEL = 128;
const int BATCH = 256;                      /* points binned together (bins_of) */
const int SORT_EVERY = 16;                  /* sweeps between sorts of the occupied list */
const double EL_MIN = -0.55, EL_MAX = 0.55;  /* rad (+-31.5 deg) */
/* where this sweep's returns lie inside each voxel hit, across (x, y): 4 x 4 columns of
 * sub-cells (5 cm at 0.2 m) as bits 0-15 (x + 4 y), with how to grow them in bits 16-21
 * (see sub_add), in an open-addressed table by fine bit index */
const int SUB = 4, SUB_TABLE = 1 << 16;
const int SHAPES = 1 << 19;
const uint32_t SUB_XP = 1u << 16, SUB_XN = 1u << 17, SUB_YP = 1u << 18, SUB_YN = 1u << 19;  /* beam along +x, -x, +y, -y */
const int SUB_GROW_SHIFT = 20;              /* 2 bits: grow by 1 or 2 sub-cells; 3: the whole voxel */
const uint32_t SUB_FRESH = 1u << 22;        /* the voxel became occupied in this sweep: a shape left from before is not its */
const uint32_t SUB_HALO = 1u << 23;         /* the voxel is in halo_bits (a neighbour's returns reach it) */
const uint32_t SUB_X0 = 0x1111, SUB_X3 = 0x8888, SUB_Y0 = 0x000f, SUB_Y3 = 0xf000;   /* cells with x = 0, x = 3, y = 0, y = 3 */

struct ground_cell_t { int32_t cx, cy, sweep; float minz; };
/* ground_z of a 1 m cell, kept for the rest of the hit loop (the grid does not change
 * there; a cell's returns come in several columns): direct-mapped, valid for one sweep */
const int GMEMO = 64;     /* cells a side (a ring) */
struct ground_memo_t { int32_t cx, cy, sweep; float z; };

/* The tree node of each live 6.4 m block (direct-mapped by block key): an update walks
 * down from it (5 levels in fine) instead of from the root, twice (OctoMap's early-abort
 * search, then its update). Block nodes are never pruned while live (updates are lazy);
 * an entry goes when roll_window deletes its block. */
const int BLOCK_CACHE = 1 << 11;
struct block_node_t { uint64_t bkey; octomap::OcTreeNode *node; };
/* Tree updates are queued and applied in order, PF_GROUP at a time after their paths were
 * fetched for all of them level by level: a path's nodes lie scattered over the heap (a
 * cache miss per level), and walking one key after another waited for each miss in turn. */
const int PF_GROUP = 32;
const int FINE_BLOCK_DEPTH = 16 - BLOCK_FINE_LOG2;
/* a queued hit: the voxel's bit index, whether it is in the bitmaps' band, and the slot of
 * its sub-cells when its return was the last added (SUB_FRESH goes there), else -1 */
struct hit_req_t { uint32_t bi; int32_t fresh_slot; bool band; };

/* The sub-cells a voxel's returns stand for (16 bits, x + 4 y; 0xffff: all of it): their
 * cells, those behind them along the beam to the voxel's far side (objects are solid),
 * all grown by one or two cells in x and y. */
inline uint32_t sub_cells(uint32_t v)
{
    uint32_t b = v & 0xffff;
    const int grow = (int)(v >> SUB_GROW_SHIFT) & 3;
    if (grow == 3) return 0xffff;
    for (int i = 1; i < SUB; i++) {
        if (v & SUB_XP) b |= (b & ~SUB_X3) << 1;
        if (v & SUB_XN) b |= (b & ~SUB_X0) >> 1;
        if (v & SUB_YP) b |= (b & ~SUB_Y3) << SUB;
        if (v & SUB_YN) b |= (b & ~SUB_Y0) >> SUB;
    }
    for (int g = 0; g < grow; g++) {
        b |= ((b & ~SUB_X3) << 1) | ((b & ~SUB_X0) >> 1);
        b |= ((b & ~SUB_Y3) << SUB) | ((b & ~SUB_Y0) >> SUB);
    }
    return b & 0xffff;
}

inline uint64_t pack(const OcTreeKey &k) { return (uint64_t)k[0] | (uint64_t)k[1] << 16 | (uint64_t)k[2] << 32; }
inline OcTreeKey unpack(uint64_t p) { return OcTreeKey((uint16_t)p, (uint16_t)(p >> 16), (uint16_t)(p >> 32)); }

}  // namespace

struct occ_map_t {
    occ_config_t cfg;
    OcTree fine, observed;
    double inv_res, inv_cres;
    double ring_gap, col_gap;               /* this sweep's beam gaps, rad */
    int clear_el, clear_az;                 /* direction bins either side that clear a voxel, this sweep */
    double sub_r2[2];                       /* squared ranges within which returns grow by 1, 2 sub-cells */
    int cshift;                             /* observed voxel = 2^cshift fine voxels */
    int coff;                               /* observed key = (fine key >> cshift) + coff */
    std::vector<uint64_t> fine_bits, obs_bits;
    std::vector<uint64_t> any_bits;         /* observed-size cells that may hold an occupied fine voxel (queries skip the rest) */
    std::vector<ground_cell_t> ground;
    std::vector<ground_memo_t> ground_memo;
    int32_t sweep = 0;
    std::vector<uint64_t> hit_bits;         /* fine voxels hit this sweep (same ring as fine_bits) */
    std::vector<uint32_t> hit_list;         /* their bit indices (cleared at the next sweep) */
    std::vector<uint64_t> sat_bits;         /* fine voxels at clamp_max (a hit would not change them) */
    std::vector<uint64_t> listed_bits;      /* fine voxels in `occupied` (same ring as fine_bits) */
    std::vector<float> bin_min;             /* NEL x NAZ, +inf = no return in the bin */
    std::unordered_map<uint64_t, char> blocks;   /* live 6.4 m blocks (packed block keys) */
    std::vector<uint64_t> to_clear;
    std::vector<uint64_t> occupied;         /* keys whose bit went 0 -> 1 (stale ones dropped lazily) */
    std::vector<uint64_t> fill_bits;        /* this sweep's columns below objects that reach under the lowest beam */
    std::vector<uint32_t> fill_list;        /* their bit indices (cleared at the next sweep) */
    std::vector<int> low_candidates;        /* scratch: non-ground returns near the car */
    /* SUB_TABLE slots, one per voxel this sweep's returns reach (one cache line holds all a
     * return changes, and the voxel's whole key) */
    struct sub_t {
        uint32_t key;                       /* fine bit index + 1 (0: free) */
        uint32_t mask;                      /* the returns' sub-cell columns and how to grow them (sub_cells), SUB_FRESH, SUB_HALO */
        float top;                          /* top of what the returns stand for, fine key units */
        uint32_t above;                     /* the key's bits the bit index leaves out (key_above) */
    };
    std::vector<sub_t> sub;
    std::vector<uint32_t> sub_used;         /* used slots (freed at the next sweep) */
    /* the shape (columns, top) of every occupied voxel from the sweeps that hit it since it
     * became occupied: direct-mapped by fine bit index; a voxel whose entry another took
     * counts whole */
    struct shape_t { uint64_t pkey; uint32_t mask; float top; };
    std::vector<shape_t> shapes;
    std::vector<uint64_t> halo_bits;        /* voxels this sweep's returns reach into (half a column gap around each) */
    std::vector<uint32_t> halo_list;        /* their bit indices (cleared at the next sweep) */
    size_t sub_last_bi = SIZE_MAX;          /* the voxel of the last return added and its slot (the hit it queues marks that slot fresh) */
    int sub_last_slot = -1;
    std::vector<block_node_t> fine_blocks, obs_blocks;   /* block nodes of both trees (block_node_t) */
    std::vector<uint64_t> hit_keys, obs_keys;   /* this sweep's queued updates: hits of fine, new cells of observed */
    std::vector<hit_req_t> hit_reqs;        /* per queued hit */
    int64_t prefetched = 0;                 /* paths prefetch_paths followed to their leaf */
    unsigned obs_block_depth;               /* depth of a 6.4 m block in observed (fine: 16 - BLOCK_FINE_LOG2) */

    explicit occ_map_t(const occ_config_t &c) : cfg(c), fine(c.resolution), observed(c.observed_resolution) {}
};

static inline size_t fine_bit(const OcTreeKey &k) { return ((size_t)(k[1] & (FX - 1)) * FX + (k[0] & (FX - 1))) * FZ + (k[2] & (FZ - 1)); }
static inline size_t obs_bit(const OcTreeKey &k) { return ((size_t)(k[2] & (CZ - 1)) * CX + (k[1] & (CX - 1))) * CX + (k[0] & (CX - 1)); }
static inline bool get_bit(const std::vector<uint64_t> &b, size_t i) { return (b[i >> 6] >> (i & 63)) & 1; }
static inline void set_bit(std::vector<uint64_t> &b, size_t i) { b[i >> 6] |= 1ull << (i & 63); }
static inline void clr_bit(std::vector<uint64_t> &b, size_t i) { b[i >> 6] &= ~(1ull << (i & 63)); }
/* The key's bits fine_bit leaves out (x, y above 9 bits, z above 6), 24 bits. */
static_assert(FX == 512 && FZ == 64, "key_above takes 9 bits of x and y and 6 of z");
static inline uint32_t key_above(const OcTreeKey &k) { return (uint32_t)(k[0] >> 9) << 17 | (uint32_t)(k[1] >> 9) << 10 | (uint32_t)(k[2] >> 6); }
/* A packed key as a number that orders by fine_bit: the bit index above key_above, so the key
 * comes back from it. */
static inline uint64_t sort_key(uint64_t p)
{
    const OcTreeKey k = unpack(p);
    return (uint64_t)fine_bit(k) << 24 | key_above(k);
}
static inline uint64_t key_of_sort_key(uint64_t v)
{
    const uint64_t b = v >> 24;
    return pack(OcTreeKey((uint16_t)((b >> 6 & 511) | (v >> 17 & 127) << 9), (uint16_t)((b >> 15) | (v >> 10 & 127) << 9),
                          (uint16_t)((b & 63) | (v & 1023) << 6)));
}

/* The observed-size cell holding fine voxel k may hold an occupied voxel (queries walk it). */
static inline void mark_any(occ_map_t *m, const OcTreeKey &k)
{
    set_bit(m->any_bits, obs_bit(OcTreeKey((k[0] >> m->cshift) + m->coff, (k[1] >> m->cshift) + m->coff, (k[2] >> m->cshift) + m->coff)));
}
/* Clears n bits from i (n a power of 2 <= 64, i a multiple of n: within one word). */
static inline void clear_run(std::vector<uint64_t> &b, size_t i, int n)
{
    b[i >> 6] &= ~((n == 64 ? ~0ull : ((1ull << n) - 1)) << (i & 63));
}

occ_map_t *occ_map_create(const occ_config_t *cfg)
{
    occ_map_t *m = new occ_map_t(*cfg);
    for (OcTree *t : { &m->fine, &m->observed }) {
        t->setProbHit(cfg->prob_hit);
        t->setProbMiss(cfg->prob_miss);
        t->setClampingThresMin(cfg->clamp_min);
        t->setClampingThresMax(cfg->clamp_max);
    }
    m->inv_res = 1.0 / cfg->resolution;
    m->inv_cres = 1.0 / cfg->observed_resolution;
    m->cshift = (int)std::lround(std::log2(cfg->observed_resolution / cfg->resolution));
    m->coff = KEY_ORIGIN - (KEY_ORIGIN >> m->cshift);
    m->fine_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->listed_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->obs_bits.assign((size_t)CX * CX * CZ / 64, 0);
    m->any_bits.assign((size_t)CX * CX * CZ / 64, 0);
    m->ground.assign((size_t)GN * GN, ground_cell_t{ 0, 0, -1000000, 0 });
    m->ground_memo.assign((size_t)GMEMO * GMEMO, ground_memo_t{ 0, 0, -1000000, 0 });
    m->bin_min.assign((size_t)NAZ * NEL, INFINITY);
    m->fill_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->hit_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->sat_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->sub.assign(SUB_TABLE, occ_map_t::sub_t{ 0, 0, 0, 0 });
    m->shapes.assign(SHAPES, occ_map_t::shape_t{ 0, 0, 0 });
    m->halo_bits.assign((size_t)FX * FX * FZ / 64, 0);
    m->fine_blocks.assign(BLOCK_CACHE, block_node_t{ 0, nullptr });
    m->obs_blocks.assign(BLOCK_CACHE, block_node_t{ 0, nullptr });
    m->obs_block_depth = 16 - (BLOCK_FINE_LOG2 - m->cshift);
    return m;
}

void occ_map_destroy(occ_map_t *m) { delete m; }

void occ_map_clear(occ_map_t *m)
{
    m->fine.clear();
    m->observed.clear();
    std::fill(m->fine_bits.begin(), m->fine_bits.end(), 0);
    std::fill(m->listed_bits.begin(), m->listed_bits.end(), 0);
    std::fill(m->obs_bits.begin(), m->obs_bits.end(), 0);
    std::fill(m->any_bits.begin(), m->any_bits.end(), 0);
    std::fill(m->fill_bits.begin(), m->fill_bits.end(), 0);
    std::fill(m->sat_bits.begin(), m->sat_bits.end(), 0);
    std::fill(m->hit_bits.begin(), m->hit_bits.end(), 0);
    std::fill(m->halo_bits.begin(), m->halo_bits.end(), 0);
    m->halo_list.clear();
    std::fill(m->shapes.begin(), m->shapes.end(), occ_map_t::shape_t{ 0, 0, 0 });
    m->hit_list.clear();
    m->fill_list.clear();
    for (uint32_t u : m->sub_used) m->sub[u].key = 0;
    m->sub_used.clear();
    m->sub_last_bi = SIZE_MAX;
    for (ground_cell_t &g : m->ground) g.sweep = -1000000;
    for (ground_memo_t &g : m->ground_memo) g.sweep = -1000000;
    m->blocks.clear();
    m->occupied.clear();
    std::fill(m->fine_blocks.begin(), m->fine_blocks.end(), block_node_t{ 0, nullptr });
    std::fill(m->obs_blocks.begin(), m->obs_blocks.end(), block_node_t{ 0, nullptr });
}

void occ_map_size(const occ_map_t *m, int64_t *leaves, int64_t *bytes)
{
    *leaves = (int64_t)m->fine.getNumLeafNodes() + (int64_t)m->observed.getNumLeafNodes();
    *bytes = (int64_t)m->fine.memoryUsage() + (int64_t)m->observed.memoryUsage();
}


static inline bool key_of(double inv, double x, double y, double z, OcTreeKey &k)
{
    double c[3] = { x, y, z };
    for (int i = 0; i < 3; i++) {
        const double v = c[i] * inv;
        if (!(v >= -KEY_ORIGIN && v < KEY_ORIGIN)) return false;    /* floor(v) + KEY_ORIGIN outside the keys */
        k[i] = (uint16_t)((int32_t)pb_floor_i64(v) + KEY_ORIGIN);
    }
    return true;
}

static ground_cell_t *ground_cell(occ_map_t *m, int32_t cx, int32_t cy)
{
    return &m->ground[(size_t)(cy & (GN - 1)) * GN + (cx & (GN - 1))];
}

/* Lowest return over the 3 x 3 cells around (x, y) seen within GROUND_TTL sweeps; +inf if none. */
static float ground_z(occ_map_t *m, float x, float y)
{
    int32_t cx = (int32_t)pb_floor_i64(x), cy = (int32_t)pb_floor_i64(y);
    float z = INFINITY;
    for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++) {
            const ground_cell_t *g = ground_cell(m, cx + dx, cy + dy);
            if (g->cx == cx + dx && g->cy == cy + dy && m->sweep - g->sweep < GROUND_TTL) z = std::min(z, g->minz);
        }
    return z;
}

/* atan2 to 4e-6 rad (the bins are 6 mm rad wide): a minimax polynomial of atan on
 * [0, 1] and the octant symmetries. */
static inline double fast_atan2(double y, double x)
{
    double ax = std::fabs(x), ay = std::fabs(y);
    double mx = std::max(ax, ay), mn = std::min(ax, ay);
    if (mx == 0) return 0;
    double a = mn / mx, s = a * a;
    double r = ((((-0.0134804 * s + 0.0574773) * s - 0.1212390) * s + 0.1956359) * s - 0.3329946) * s * a + 0.9999956 * a;
    if (ay > ax) r = M_PI_2 - r;
    if (x < 0) r = M_PI - r;
    return y < 0 ? -r : r;
}

/* Direction bin of a map point seen from the sweep's mid pose: -1 outside the bins, or
 * farther than rmax (then the angles are not worked out). */
static inline int bin_of(const occ_sweep_t *sw, double px, double py, double pz, double *range, double rmax = INFINITY)
{
    double d[3] = { px - sw->mid_origin[0], py - sw->mid_origin[1], pz - sw->mid_origin[2] };
    const double *R = sw->mid_rot;  /* sensor = R^T * d */
    double lx = R[0] * d[0] + R[3] * d[1] + R[6] * d[2];
    double ly = R[1] * d[0] + R[4] * d[1] + R[7] * d[2];
    double lz = R[2] * d[0] + R[5] * d[1] + R[8] * d[2];
    double h = std::sqrt(lx * lx + ly * ly);
    *range = std::sqrt(h * h + lz * lz);
    if (*range > rmax) return -1;
    double el = fast_atan2(lz, h);
    if (el < EL_MIN || el >= EL_MAX) return -1;
    int e = (int)((el - EL_MIN) / (EL_MAX - EL_MIN) * NEL);
    int a = (int)((fast_atan2(ly, lx) + M_PI) / (2 * M_PI) * NAZ) & (NAZ - 1);
    return e * NAZ + a;
}

/* bin_of for n points (x, y, z arrays), 4 at a time where the CPU has AVX: the same
 * operations in the same order lane by lane (no fused multiply-add), so the same bins and
 * ranges. The divisions and square roots were most of the cost of binning a sweep and of
 * the clearing pass (100,000 points a sweep). */
#if defined(__x86_64__)
#define AVX __attribute__((target("avx")))
/* a where m, else b, by bit masks (GCC turned _mm256_blendv_pd into a branch per lane) */
AVX static inline __m256d select_pd(__m256d m, __m256d a, __m256d b) { return _mm256_or_pd(_mm256_and_pd(m, a), _mm256_andnot_pd(m, b)); }

/* fast_atan2(y, x), lane by lane */
AVX static inline __m256d atan2_pd(__m256d y, __m256d x)
{
    const __m256d zero = _mm256_setzero_pd(), sign = _mm256_set1_pd(-0.0);
    const __m256d ax = _mm256_andnot_pd(sign, x), ay = _mm256_andnot_pd(sign, y);
    const __m256d mx = _mm256_max_pd(ay, ax), mn = _mm256_min_pd(ay, ax);
    const __m256d a = _mm256_div_pd(mn, mx), s = _mm256_mul_pd(a, a);
    __m256d q = _mm256_add_pd(_mm256_mul_pd(_mm256_set1_pd(-0.0134804), s), _mm256_set1_pd(0.0574773));
    q = _mm256_sub_pd(_mm256_mul_pd(q, s), _mm256_set1_pd(0.1212390));
    q = _mm256_add_pd(_mm256_mul_pd(q, s), _mm256_set1_pd(0.1956359));
    q = _mm256_sub_pd(_mm256_mul_pd(q, s), _mm256_set1_pd(0.3329946));
    q = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(q, s), a), _mm256_mul_pd(_mm256_set1_pd(0.9999956), a));
    q = select_pd(_mm256_cmp_pd(ay, ax, _CMP_GT_OQ), _mm256_sub_pd(_mm256_set1_pd(M_PI_2), q), q);
    q = select_pd(_mm256_cmp_pd(x, zero, _CMP_LT_OQ), _mm256_sub_pd(_mm256_set1_pd(M_PI), q), q);
    q = _mm256_xor_pd(q, _mm256_and_pd(_mm256_cmp_pd(y, zero, _CMP_LT_OQ), sign));
    return _mm256_andnot_pd(_mm256_cmp_pd(mx, zero, _CMP_EQ_OQ), q);
}

AVX static void bins_of_avx(const occ_sweep_t *sw, const double *px, const double *py,
                                                        const double *pz, int n, int *bin, double *range, double rmax)
{
    const double *R = sw->mid_rot;
    const __m256d o0 = _mm256_set1_pd(sw->mid_origin[0]), o1 = _mm256_set1_pd(sw->mid_origin[1]), o2 = _mm256_set1_pd(sw->mid_origin[2]);
    __m256d r[9];
    for (int k = 0; k < 9; k++) r[k] = _mm256_set1_pd(R[k]);
    const __m256d vmax = _mm256_set1_pd(rmax);
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        const __m256d d0 = _mm256_sub_pd(_mm256_loadu_pd(px + i), o0), d1 = _mm256_sub_pd(_mm256_loadu_pd(py + i), o1),
                      d2 = _mm256_sub_pd(_mm256_loadu_pd(pz + i), o2);
        const __m256d lx = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r[0], d0), _mm256_mul_pd(r[3], d1)), _mm256_mul_pd(r[6], d2));
        const __m256d ly = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r[1], d0), _mm256_mul_pd(r[4], d1)), _mm256_mul_pd(r[7], d2));
        const __m256d lz = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r[2], d0), _mm256_mul_pd(r[5], d1)), _mm256_mul_pd(r[8], d2));
        const __m256d h = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(lx, lx), _mm256_mul_pd(ly, ly)));
        const __m256d rg = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(h, h), _mm256_mul_pd(lz, lz)));
        _mm256_storeu_pd(range + i, rg);
        const __m256d el = atan2_pd(lz, h);
        const __m256d out = _mm256_or_pd(_mm256_cmp_pd(rg, vmax, _CMP_GT_OQ),
                                         _mm256_or_pd(_mm256_cmp_pd(el, _mm256_set1_pd(EL_MIN), _CMP_LT_OQ),
                                                      _mm256_cmp_pd(el, _mm256_set1_pd(EL_MAX), _CMP_GE_OQ)));
        const __m128i e = _mm256_cvttpd_epi32(_mm256_mul_pd(_mm256_div_pd(_mm256_sub_pd(el, _mm256_set1_pd(EL_MIN)),
                                                                          _mm256_set1_pd(EL_MAX - EL_MIN)), _mm256_set1_pd(NEL)));
        const __m128i a = _mm256_cvttpd_epi32(_mm256_mul_pd(_mm256_div_pd(_mm256_add_pd(atan2_pd(ly, lx), _mm256_set1_pd(M_PI)),
                                                                          _mm256_set1_pd(2 * M_PI)), _mm256_set1_pd(NAZ)));
        /* e * NAZ + (a & (NAZ - 1)), -1 outside (the low halves of the lanes of out: all ones or none) */
        const __m128 o32 = _mm_shuffle_ps(_mm256_castps256_ps128(_mm256_castpd_ps(out)), _mm256_extractf128_ps(_mm256_castpd_ps(out), 1),
                                          _MM_SHUFFLE(2, 0, 2, 0));
        const __m128i b = _mm_add_epi32(_mm_slli_epi32(e, NAZ_LOG2), _mm_and_si128(a, _mm_set1_epi32(NAZ - 1)));
        _mm_storeu_si128((__m128i *)(bin + i), _mm_or_si128(b, _mm_castps_si128(o32)));
    }
    for (; i < n; i++) bin[i] = bin_of(sw, px[i], py[i], pz[i], &range[i], rmax);
}
#undef AVX
#endif

static void bins_of(const occ_sweep_t *sw, const double *px, const double *py, const double *pz, int n, int *bin,
                    double *range, double rmax)
{
#if defined(__x86_64__)
    static const bool avx = __builtin_cpu_supports("avx");
    if (avx) { bins_of_avx(sw, px, py, pz, n, bin, range, rmax); return; }
#endif
    for (int i = 0; i < n; i++) bin[i] = bin_of(sw, px[i], py[i], pz[i], &range[i], rmax);
}

static uint64_t block_of(const OcTreeKey &fine_key)
{
    return pack(OcTreeKey(fine_key[0] >> BLOCK_FINE_LOG2, fine_key[1] >> BLOCK_FINE_LOG2, fine_key[2] >> BLOCK_FINE_LOG2));
}

/* A block's cache entry: 16 x 16 x 8 blocks (102 x 102 x 51 m, more than the window) */
static inline size_t block_index(uint64_t bkey) { return (bkey & 15) | (bkey >> 16 & 15) << 4 | (bkey >> 32 & 7) << 8; }
static inline block_node_t &block_entry(std::vector<block_node_t> &cache, uint64_t bkey) { return cache[block_index(bkey)]; }

/* OctoMap's updateNode(key, lo, lazy) from node n at depth d on key's path, which exists:
 * the same early abort when the node it finds is at the clamp, the same expansion of a
 * pruned node and creation of missing children, the same log-odds update. */
static octomap::OcTreeNode *update_below(OcTree &t, octomap::OcTreeNode *n, unsigned d, const OcTreeKey &k, float lo)
{
    for (; d < 16; d++) {       /* OctoMap's search */
        const unsigned pos = octomap::computeChildIdx(k, 15 - d);
        if (!t.nodeChildExists(n, pos)) break;
        n = t.getNodeChild(n, pos);
    }
    if (d == 16 || !t.nodeHasChildren(n)) {
        const float v = n->getLogOdds();
        if ((lo >= 0 && v >= t.getClampingThresMaxLog()) || (lo <= 0 && v <= t.getClampingThresMinLog())) return n;
    }
    bool just_created = false;  /* n exists: it was reached, not created, as in OctoMap's descent */
    for (; d < 16; d++) {
        const unsigned pos = octomap::computeChildIdx(k, 15 - d);
        bool created = false;
        if (!t.nodeChildExists(n, pos)) {
            if (!t.nodeHasChildren(n) && !just_created) t.expandNode(n);     /* a pruned node */
            else { t.createNodeChild(n, pos); created = true; }
        }
        n = t.getNodeChild(n, pos);
        just_created = created;
    }
    t.updateNodeLogOdds(n, lo);
    return n;
}

/* Reads the protected child array of a node (a pointer to member named through a derived
 * class), to prefetch a child before reading it. */
struct node_peek : octomap::OcTreeNode {
    static octomap::AbstractOcTreeNode *const *kids(const octomap::OcTreeNode *n) { return n->*(&node_peek::children); }
};

/* Fetches the nodes on the paths of n <= PF_GROUP keys below their cached blocks into the
 * cache, a level of all paths at a time (the misses overlap). Reads only; returns how many
 * paths reached their leaf (kept in the map: unused, GCC removed the walk without it). */
static int prefetch_paths(const std::vector<block_node_t> &cache, unsigned bd, const uint64_t *keys, int n)
{
    const octomap::OcTreeNode *p[PF_GROUP];
    octomap::AbstractOcTreeNode *const *kid[PF_GROUP];
    unsigned pos[PF_GROUP];
    const int s = 16 - bd;
    for (int j = 0; j < n; j++) {
        const OcTreeKey k = unpack(keys[j]);
        const uint64_t bkey = pack(OcTreeKey(k[0] >> s, k[1] >> s, k[2] >> s));
        const block_node_t &e = cache[block_index(bkey)];
        p[j] = e.bkey == bkey ? e.node : nullptr;
        if (p[j]) __builtin_prefetch(p[j]);
    }
    for (unsigned d = bd; d < 16; d++) {
        for (int j = 0; j < n; j++) {
            if (!p[j]) continue;
            kid[j] = node_peek::kids(p[j]);
            if (!kid[j]) { p[j] = nullptr; continue; }
            pos[j] = octomap::computeChildIdx(unpack(keys[j]), 15 - d);
            __builtin_prefetch(&kid[j][pos[j]]);
        }
        for (int j = 0; j < n; j++) {
            if (!p[j]) continue;
            p[j] = static_cast<const octomap::OcTreeNode *>(kid[j][pos[j]]);
            if (p[j]) __builtin_prefetch(p[j]);
        }
    }
    int leaves = 0;
    for (int j = 0; j < n; j++) leaves += p[j] != nullptr;
    return leaves;
}

/* updateNode(k, occupied, lazy) through the block cache (block at depth bd). *known: the
 * block was in the cache (so it is in `blocks` already). */
static octomap::OcTreeNode *tree_update(OcTree &t, std::vector<block_node_t> &cache, unsigned bd, const OcTreeKey &k,
                                        bool occupied, bool *known)
{
    const int s = 16 - bd;
    const uint64_t bkey = pack(OcTreeKey(k[0] >> s, k[1] >> s, k[2] >> s));
    block_node_t &e = block_entry(cache, bkey);
    const float lo = occupied ? t.getProbHitLog() : t.getProbMissLog();
    if (e.node && e.bkey == bkey) { *known = true; return update_below(t, e.node, bd, k, lo); }
    *known = false;
    octomap::OcTreeNode *leaf = t.updateNode(k, lo, true);
    octomap::OcTreeNode *n = t.getRoot();
    for (unsigned d = 0; n && d < bd; d++) {
        const unsigned pos = octomap::computeChildIdx(k, 15 - d);
        n = t.nodeChildExists(n, pos) ? t.getNodeChild(n, pos) : nullptr;
    }
    if (n) e = block_node_t{ bkey, n };
    return leaf;
}

/* Makes node a leaf: OctoMap frees a node's child array only when it prunes it (8
 * equal leaf children), and deleting a node that still has that array trips its
 * assertion (OctoMap 1.9.7's deleteNode does, for an emptied parent), so children
 * are completed, equalled and pruned bottom up. */
static void make_leaf(OcTree &t, octomap::OcTreeNode *node)
{
    if (!t.nodeHasChildren(node)) return;
    for (unsigned i = 0; i < 8; i++) {
        if (!t.nodeChildExists(node, i)) t.createNodeChild(node, i);
        else make_leaf(t, t.getNodeChild(node, i));
        t.getNodeChild(node, i)->setLogOdds(0);
    }
    t.pruneNode(node);
}

/* Removes the block (a node at depth) from its parent; the parent stays, possibly
 * with no children (never deleted itself, see make_leaf). */
static void delete_block(OcTree &t, std::vector<block_node_t> &cache, const OcTreeKey &k, unsigned depth)
{
    const int s = 16 - depth;
    const uint64_t bkey = pack(OcTreeKey(k[0] >> s, k[1] >> s, k[2] >> s));
    block_node_t &e = block_entry(cache, bkey);
    if (e.bkey == bkey) e.node = nullptr;
    octomap::OcTreeNode *parent = t.search(k, depth - 1);
    if (!parent || !t.nodeHasChildren(parent)) return;
    unsigned pos = octomap::computeChildIdx(k, 16 - depth);
    if (!t.nodeChildExists(parent, pos)) return;
    make_leaf(t, t.getNodeChild(parent, pos));
    t.deleteNodeChild(parent, pos);
}

/* Deletes the blocks whose centre left the window from both trees and both bitmaps. */
static int roll_window(occ_map_t *m, const double car[3])
{
    const double bs = m->cfg.resolution * (1 << BLOCK_FINE_LOG2);
    const unsigned fine_depth = 16 - BLOCK_FINE_LOG2, obs_depth = 16 - (BLOCK_FINE_LOG2 - m->cshift);
    int n = 0;
    for (auto it = m->blocks.begin(); it != m->blocks.end();) {
        OcTreeKey b = unpack(it->first);
        double cx = ((int)b[0] - (KEY_ORIGIN >> BLOCK_FINE_LOG2) + 0.5) * bs;
        double cy = ((int)b[1] - (KEY_ORIGIN >> BLOCK_FINE_LOG2) + 0.5) * bs;
        if (std::hypot(cx - car[0], cy - car[1]) <= m->cfg.window_m) { ++it; continue; }
        OcTreeKey f0(b[0] << BLOCK_FINE_LOG2, b[1] << BLOCK_FINE_LOG2, b[2] << BLOCK_FINE_LOG2);
        delete_block(m->fine, m->fine_blocks, f0, fine_depth);
        int s = m->cshift, o = m->coff;
        OcTreeKey c0((f0[0] >> s) + o, (f0[1] >> s) + o, (f0[2] >> s) + o);
        delete_block(m->observed, m->obs_blocks, c0, obs_depth);
        /* the block's voxels are runs of nf bits in z (nc in x), aligned: cleared a run at a time */
        const int nf = 1 << BLOCK_FINE_LOG2, nc = nf >> s;
        for (int y = 0; y < nf; y++)
            for (int x = 0; x < nf; x++)
                { size_t b0 = fine_bit(OcTreeKey(f0[0] + x, f0[1] + y, f0[2])); clear_run(m->fine_bits, b0, nf); clear_run(m->sat_bits, b0, nf); }
        for (int z = 0; z < nc; z++)
            for (int y = 0; y < nc; y++) {
                size_t b0 = obs_bit(OcTreeKey(c0[0], c0[1] + y, c0[2] + z));
                clear_run(m->obs_bits, b0, nc);
                clear_run(m->any_bits, b0, nc);
            }
        it = m->blocks.erase(it);
        n++;
    }
    return n;
}

/* Ground under (x, y) near the car, h metres from the sensor: the ground grid's, unless
 * that is unknown or well above the car's own ground (within 6 m the roof LiDAR does not
 * see the ground, so a cell's lowest return may be the bottom of what stands on it). */
static float near_ground_z(occ_map_t *m, const occ_sweep_t *sw, float x, float y, double h)
{
    float g = ground_z(m, x, y), car = (float)sw->car[2] + (float)(0.1 * h);   /* 10 % slope */
    return std::isfinite(g) && g < car + 0.3f ? g : (float)sw->car[2];
}

/* Objects beside the car that reach below the LiDAR's lowest beam (a passing car whose
 * roof and upper doors a roof LiDAR sees, not its lower body): the space under them may
 * have been seen free before they came, and the LiDAR cannot see it now. Objects stand on
 * the ground, so the column below such a return, down to the ground, counts as occupied
 * for this sweep's queries (only this sweep: it is inferred, not seen). */
static void fill_below_view(occ_map_t *m, const occ_sweep_t *sw, occ_integrate_stats_t *s)
{
    const occ_config_t &c = m->cfg;
    for (uint32_t b : m->fill_list) clr_bit(m->fill_bits, b);
    m->fill_list.clear();
    const double *R = sw->mid_rot, r2 = c.fill_radius_m * c.fill_radius_m;
    /* 1. the lowest beam: the least elevation (as a sine, in the sensor frame) of the returns near the car */
    double sin_min = INFINITY;
    m->low_candidates.clear();
    for (int i = 0; i < sw->n; i++) {
        const double *o = sw->origins[sw->origin_index[i]];
        double dx = sw->x[i] - o[0], dy = sw->y[i] - o[1], dz = sw->z[i] - o[2], h2 = dx * dx + dy * dy;
        if (!(h2 <= r2)) continue;      /* also drops NaN */
        double sn = (R[2] * dx + R[5] * dy + R[8] * dz) / std::sqrt(h2 + dz * dz);
        if (sn < sin_min) sin_min = sn;
        m->low_candidates.push_back(i);
    }
    if (!std::isfinite(sin_min)) return;
    const double sin_tol = std::sin(std::asin(std::max(-1.0, sin_min)) + c.fill_elevation_tol_rad);
    /* 2. returns of the lowest beams above the ground: fill down to the ground */
    for (int i : m->low_candidates) {
        const double *o = sw->origins[sw->origin_index[i]];
        double dx = sw->x[i] - o[0], dy = sw->y[i] - o[1], dz = sw->z[i] - o[2], h2 = dx * dx + dy * dy;
        if ((R[2] * dx + R[5] * dy + R[8] * dz) / std::sqrt(h2 + dz * dz) > sin_tol) continue;
        float gz = near_ground_z(m, sw, sw->x[i], sw->y[i], std::sqrt(h2));
        if (sw->z[i] < gz + c.ground_clearance_m) continue;
        OcTreeKey top, bot;
        if (!key_of(m->inv_res, sw->x[i], sw->y[i], sw->z[i], top) ||
            !key_of(m->inv_res, sw->x[i], sw->y[i], gz + c.ground_clearance_m, bot))
            continue;
        for (int kz = top[2]; kz >= bot[2]; kz--) {
            OcTreeKey k(top[0], top[1], (uint16_t)kz);
            size_t bi = fine_bit(k);
            if (get_bit(m->fill_bits, bi)) continue;
            set_bit(m->fill_bits, bi);
            m->fill_list.push_back((uint32_t)bi);
            mark_any(m, k);
            s->filled++;
        }
    }
}

/* Marks the observed cells from o to pe (both ends included) by a 3-D DDA (Amanatides &
 * Woo) over the observed-size cells: the bitmap says which are known already, and only
 * new ones go to the tree. (OctoMap's computeRayKeys visits the same cells, but builds a
 * key list per ray: it was the largest single cost of a sweep.) */
static void trace_observed(occ_map_t *m, const double o[3], const double pe[3], occ_integrate_stats_t *s)
{
    int k[3], step[3], cells = 1;
    double tmax[3], tdelta[3];
    for (int i = 0; i < 3; i++) {
        double u0 = o[i] * m->inv_cres + KEY_ORIGIN, u1 = pe[i] * m->inv_cres + KEY_ORIGIN, du = u1 - u0;
        if (!(u0 >= 0 && u0 < 2 * KEY_ORIGIN && u1 >= 0 && u1 < 2 * KEY_ORIGIN)) return;
        k[i] = (int)u0;
        int kend = (int)u1;
        cells += std::abs(kend - k[i]);
        if (kend > k[i]) { step[i] = 1; tmax[i] = (k[i] + 1 - u0) / du; tdelta[i] = 1 / du; }
        else if (kend < k[i]) { step[i] = -1; tmax[i] = (k[i] - u0) / du; tdelta[i] = -1 / du; }
        else { step[i] = 0; tmax[i] = INFINITY; tdelta[i] = INFINITY; }
    }
    /* the state in scalars: indexed by the axis it went through memory, a store and a
     * reload on every step's critical path (the same steps, twice as fast) */
    int k0 = k[0], k1 = k[1], k2 = k[2];
    double t0 = tmax[0], t1 = tmax[1], t2 = tmax[2];
    const int s0 = step[0], s1 = step[1], s2 = step[2];
    const double d0 = tdelta[0], d1 = tdelta[1], d2 = tdelta[2];
    for (int c = 0; c < cells; c++) {
        OcTreeKey key((uint16_t)k0, (uint16_t)k1, (uint16_t)k2);
        size_t bi = obs_bit(key);
        if (!get_bit(m->obs_bits, bi)) {
            set_bit(m->obs_bits, bi);
            m->obs_keys.push_back(pack(key));    /* to the tree after the tracing (apply_observed) */
            s->observed_new++;
        }
        /* the axis whose cell boundary comes first (ties broken as before) */
        if (t0 < t1) { if (t0 < t2) { k0 += s0; t0 += d0; } else { k2 += s2; t2 += d2; } }
        else if (t1 < t2) { k1 += s1; t1 += d1; }
        else { k2 += s2; t2 += d2; }
    }
}

/* The queued new observed cells into the observed tree, in order. */
static void apply_observed(occ_map_t *m)
{
    const int sh = m->cshift, co = m->coff;
    for (size_t g = 0; g < m->obs_keys.size(); g += PF_GROUP) {
        const int n = (int)std::min<size_t>(PF_GROUP, m->obs_keys.size() - g);
        m->prefetched += prefetch_paths(m->obs_blocks, m->obs_block_depth, &m->obs_keys[g], n);
        for (int j = 0; j < n; j++) {
            const OcTreeKey k = unpack(m->obs_keys[g + j]);
            bool known;
            tree_update(m->observed, m->obs_blocks, m->obs_block_depth, k, false, &known);
            if (!known) m->blocks.try_emplace(block_of(OcTreeKey((k[0] - co) << sh, (k[1] - co) << sh, (k[2] - co) << sh)), 1);
        }
    }
    m->obs_keys.clear();
}

/* The queued hits into the fine tree, in order (as each return came), and what they make
 * occupied into the bitmaps and the occupied list. */
static void apply_hits(occ_map_t *m)
{
    for (size_t g = 0; g < m->hit_keys.size(); g += PF_GROUP) {
        const int n = (int)std::min<size_t>(PF_GROUP, m->hit_keys.size() - g);
        m->prefetched += prefetch_paths(m->fine_blocks, FINE_BLOCK_DEPTH, &m->hit_keys[g], n);
        for (int j = 0; j < n; j++) {
            const OcTreeKey k = unpack(m->hit_keys[g + j]);
            const hit_req_t &q = m->hit_reqs[g + j];
            bool known;
            octomap::OcTreeNode *nd = tree_update(m->fine, m->fine_blocks, FINE_BLOCK_DEPTH, k, true, &known);
            if (nd && m->fine.isNodeOccupied(nd)) {
                if (q.fresh_slot >= 0 && !get_bit(m->fine_bits, q.bi)) m->sub[q.fresh_slot].mask |= SUB_FRESH;
                set_bit(m->fine_bits, q.bi);
                if (q.band && nd->getLogOdds() >= m->fine.getClampingThresMaxLog()) set_bit(m->sat_bits, q.bi);
                mark_any(m, k);
                if (!get_bit(m->listed_bits, q.bi)) { set_bit(m->listed_bits, q.bi); m->occupied.push_back(pack(k)); }
            }
            if (!known) m->blocks.try_emplace(block_of(k), 1);
        }
    }
    m->hit_keys.clear();
    m->hit_reqs.clear();
}

/* The table slot of a voxel hit this sweep (by fine bit index), or -1. */
static int sub_find(const occ_map_t *m, size_t bi)
{
    for (uint32_t h = (uint32_t)(bi * 2654435761u) >> 16, n = 0; n < (uint32_t)SUB_TABLE; h = (h + 1) & (SUB_TABLE - 1), n++) {
        if (m->sub[h].key == bi + 1) return (int)h;
        if (m->sub[h].key == 0) return -1;
    }
    return -1;
}

/* Adds a return at (x, y, z), beam (bx, by, bz) from the sensor with squared length r2, to
 * its voxel's sub-cell columns. Columns: roofs and hoods are seen at grazing angles, their
 * returns far apart. The cells grow (sub_cells) by half the gap between neighbouring
 * columns of the sweep at that range, so the returns' cells cover the surface between
 * them; beyond two cells' worth (or with a full table) the voxel is whole. Where that half
 * gap reaches past the voxel's side, the neighbouring voxels get the cells it covers (the
 * halo, this sweep only): an object's edge lies between its last return and the next
 * column's beam, which may be in the next voxel (a pole 30 m away: 18 cm between columns).
 * The columns end at the top: the highest return plus top_gap_fraction of the gap between
 * rings at that range (applied where the voxel above holds nothing: sub_hit). What is
 * tight is the side edges and tops: a pole, a parked car's end or bonnet, the back of a bus. */
/* the shape table's slot of a voxel: a hash of its ring position z-major (as the bit index
 * was before it put z fastest; which voxels share a slot decides answers) */
static inline size_t shape_slot(size_t bi)
{
    const uint32_t zmajor = (uint32_t)(bi & (FZ - 1)) << 18 | (uint32_t)(bi >> 6);
    return (uint32_t)(zmajor * 2654435761u) >> (32 - 19);
}

static int sub_slot(occ_map_t *m, size_t bi, const OcTreeKey &k)
{
    for (uint32_t h = (uint32_t)(bi * 2654435761u) >> 16, n = 0; n < (uint32_t)SUB_TABLE; h = (h + 1) & (SUB_TABLE - 1), n++) {
        occ_map_t::sub_t &e = m->sub[h];
        if (e.key == 0) {
            if (m->sub_used.size() * 2 > (size_t)SUB_TABLE) return -1;   /* table half full: the voxel stays whole */
            e = occ_map_t::sub_t{ (uint32_t)bi + 1, 0, -INFINITY, key_above(k) };
            m->sub_used.push_back(h);
        }
        if (e.key == bi + 1) return (int)h;
    }
    return -1;
}

static void sub_add(occ_map_t *m, size_t bi, const OcTreeKey &k, double x, double y, double z, double bx, double by, double r2)
{
    const double r = std::sqrt(r2);
    const float top = (float)((z + m->cfg.top_gap_fraction * m->ring_gap * r) * m->inv_res + KEY_ORIGIN);
    const int grow = r2 < m->sub_r2[0] ? 1 : r2 < m->sub_r2[1] ? 2 : 3;
    const double ux = (x * m->inv_res + KEY_ORIGIN - k[0]) * SUB, uy = (y * m->inv_res + KEY_ORIGIN - k[1]) * SUB;
    const int cx = std::min(SUB - 1, std::max(0, (int)ux));
    const int cy = std::min(SUB - 1, std::max(0, (int)uy));
    const double main2 = 0.1225 * r2;       /* a beam component above 0.35 of its length */
    uint32_t v = (1u << (cx + SUB * cy)) | (uint32_t)grow << SUB_GROW_SHIFT;
    if (bx * bx > main2) v |= bx > 0 ? SUB_XP : SUB_XN;
    if (by * by > main2) v |= by > 0 ? SUB_YP : SUB_YN;
    {   /* the halo: the half column gap around the return, where it reaches into the neighbouring voxels */
        const double w = 0.5 * m->col_gap * r * m->inv_res * SUB;   /* sub-cells */
        const int x0 = (int)pb_floor_i64(ux - w), x1 = (int)pb_floor_i64(ux + w);
        const int y0 = (int)pb_floor_i64(uy - w), y1 = (int)pb_floor_i64(uy + w);
        if (x0 < 0 || y0 < 0 || x1 >= SUB || y1 >= SUB) {
            /* the neighbours it reaches (|x0|, x1 - SUB < SUB: never past them), in the order
             * -1..1 in y, then in x (the order slots are taken in matters when the table fills) */
            const int dx0 = x0 < 0 ? -1 : 0, dx1 = x1 >= SUB ? 1 : 0, dy0 = y0 < 0 ? -1 : 0, dy1 = y1 >= SUB ? 1 : 0;
            for (int dy = dy0; dy <= dy1; dy++) {
                /* the rows it covers in that neighbour, as a column of 1 per row */
                const int ly0 = std::max(y0, dy * SUB) - dy * SUB, ly1 = std::min(y1, dy * SUB + SUB - 1) - dy * SUB;
                const uint32_t rows = (((1u << (SUB * (ly1 + 1))) - 1) & ~((1u << (SUB * ly0)) - 1)) & 0x1111;
                for (int dx = dx0; dx <= dx1; dx++) {
                    if (!dx && !dy) continue;
                    const int lx0 = std::max(x0, dx * SUB) - dx * SUB, lx1 = std::min(x1, dx * SUB + SUB - 1) - dx * SUB;
                    const uint32_t mk = rows * ((2u << lx1) - (1u << lx0));    /* lx0..lx1 in each row */
                    OcTreeKey nk((uint16_t)(k[0] + dx), (uint16_t)(k[1] + dy), k[2]);
                    size_t nb = fine_bit(nk);
                    int h = sub_slot(m, nb, nk);
                    if (h < 0) continue;
                    occ_map_t::sub_t &e = m->sub[h];
                    e.mask |= mk;
                    e.top = std::max(e.top, top);
                    if (!(e.mask & SUB_HALO)) {
                        e.mask |= SUB_HALO;
                        set_bit(m->halo_bits, nb);
                        m->halo_list.push_back((uint32_t)nb);
                        mark_any(m, nk);
                    }
                }
            }
        }
    }
    int h = sub_slot(m, bi, k);
    if (h < 0) return;
    occ_map_t::sub_t &e = m->sub[h];
    e.mask |= v;
    e.top = std::max(e.top, top);
    m->sub_last_bi = bi;
    m->sub_last_slot = h;
}

void occ_map_integrate(occ_map_t *m, const occ_sweep_t *sw, occ_integrate_stats_t *st)
{
    const occ_config_t &c = m->cfg;
    occ_integrate_stats_t s = {};
    m->sweep++;
    const double r2max = c.range_m * c.range_m;
    std::fill(m->bin_min.begin(), m->bin_min.end(), INFINITY);
    /* the sensor's beam gaps: how far a return's object may reach (tops, halo), and how many
     * direction bins a voxel between two rings or columns must look across to meet a beam */
    m->ring_gap = sw->ring_gap_rad > 0 ? sw->ring_gap_rad : c.beam_gap_rad;
    m->col_gap = sw->col_gap_rad > 0 ? sw->col_gap_rad : c.beam_gap_az_rad;
    for (int g = 0; g < 2; g++) m->sub_r2[g] = std::pow(2 * (g + 1) * c.resolution / SUB / m->col_gap, 2);
    m->clear_el = std::max(c.clear_bins_el, (int)std::ceil((m->ring_gap / ((EL_MAX - EL_MIN) / NEL) - 1) / 2 - 1e-9));
    m->clear_az = std::max(c.clear_bins_az, (int)std::ceil((m->col_gap / (2 * M_PI / NAZ) - 1) / 2 - 1e-9));

    /* 1. ground: lowest return per 1 m cell; the sweep binned by direction (nearest return).
     * Every point_stride-th return (the others on the next sweeps): neighbouring returns of
     * a 0.35-degree sweep mostly fall in the same 0.2 m voxel anyway */
    const int ps = std::max(1, c.point_stride), p0 = m->sweep % ps;
    for (int i = p0; i < sw->n;) {
        /* a batch of finite returns, binned together (bins_of) */
        double bx[BATCH], by[BATCH], bz[BATCH], br[BATCH];
        int bb[BATCH], nb = 0;
        for (; i < sw->n && nb < BATCH; i += ps) {
            float x = sw->x[i], y = sw->y[i], z = sw->z[i];
            if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
            bx[nb] = x; by[nb] = y; bz[nb] = z; nb++;
        }
        bins_of(sw, bx, by, bz, nb, bb, br, INFINITY);
        for (int j = 0; j < nb; j++) {
            const double r = br[j];
            const int b = bb[j];
            if (b >= 0 && r < m->bin_min[b]) m->bin_min[b] = (float)r;
            if (r * r > r2max) continue;
            const float x = (float)bx[j], y = (float)by[j], z = (float)bz[j];
            int32_t cx = (int32_t)pb_floor_i64(x), cy = (int32_t)pb_floor_i64(y);
            ground_cell_t *g = ground_cell(m, cx, cy);
            if (g->cx != cx || g->cy != cy || m->sweep - g->sweep >= GROUND_TTL) *g = ground_cell_t{ cx, cy, m->sweep, z };
            else { g->minz = std::min(g->minz, z); g->sweep = m->sweep; }
        }
    }

    /* 2. hits: returns above the ground, one update per voxel */
    for (uint32_t b : m->hit_list) clr_bit(m->hit_bits, b);
    m->hit_list.clear();
    for (uint32_t u : m->sub_used) m->sub[u].key = 0;
    m->sub_used.clear();
    m->sub_last_bi = SIZE_MAX;
    for (uint32_t b : m->halo_list) clr_bit(m->halo_bits, b);
    m->halo_list.clear();
    /* the bitmaps are rings of FZ voxels in z: exact for the FZ around the car's height
     * (everything the eye rays cross); returns beyond that band skip the per-sweep shortcuts */
    OcTreeKey car_key;
    const int car_kz = key_of(m->inv_res, sw->car[0], sw->car[1], sw->car[2], car_key) ? car_key[2] : -1000000;
    for (int i = p0; i < sw->n; i += ps) {
        float x = sw->x[i], y = sw->y[i], z = sw->z[i];
        if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
        const double *o = sw->origins[sw->origin_index[i]];
        double dx = x - o[0], dy = y - o[1], dz = z - o[2];
        if (dx * dx + dy * dy + dz * dz > r2max) continue;
        s.points++;
        const int32_t cx = (int32_t)pb_floor_i64(x), cy = (int32_t)pb_floor_i64(y);
        ground_memo_t &gm = m->ground_memo[(size_t)(cy & (GMEMO - 1)) * GMEMO + (cx & (GMEMO - 1))];
        if (gm.sweep != m->sweep || gm.cx != cx || gm.cy != cy) gm = ground_memo_t{ cx, cy, m->sweep, ground_z(m, x, y) };
        if (z < gm.z + c.ground_clearance_m) { s.ground++; continue; }
        OcTreeKey k;
        if (!key_of(m->inv_res, x, y, z, k)) continue;
        size_t bi = fine_bit(k);
        bool band = std::abs((int)k[2] - car_kz) < FZ / 2;
        if (band) {
            sub_add(m, bi, k, x, y, z, dx, dy, dx * dx + dy * dy + dz * dz);
            if (get_bit(m->hit_bits, bi)) continue;        /* one update per voxel and sweep */
            set_bit(m->hit_bits, bi);
            m->hit_list.push_back((uint32_t)bi);
            s.hit_voxels++;
            mark_any(m, k);
            if (get_bit(m->sat_bits, bi)) continue;        /* at clamp_max: OctoMap would not change it */
        }
        /* to the tree after the loop (apply_hits): nothing below reads what the update changes */
        m->hit_keys.push_back(pack(k));
        m->hit_reqs.push_back(hit_req_t{ (uint32_t)bi, band && m->sub_last_bi == bi ? m->sub_last_slot : -1, band });
    }
    apply_hits(m);

    /* 3. misses: occupied voxels in view whose surrounding beams all went on past them */
    m->to_clear.clear();
    /* the occupied voxels come from a list kept beside the tree (iterating the tree's
     * leaves costs more than the rest of the sweep); entries whose bit went are dropped.
     * The list is put in bitmap order now and then, so the bitmaps are read in order
     * (in the order voxels were found, every look-up was a cache miss) */
    if (m->sweep % SORT_EVERY == 0) {
        /* sorted as plain numbers of the bit index and the key's other bits (with the bit index
         * worked out in the comparison, a sorting sweep took twice as long as another); keys
         * sharing a bit index may come in another order, which only the speed depends on */
        for (uint64_t &p : m->occupied) p = sort_key(p);
        std::sort(m->occupied.begin(), m->occupied.end());
        for (uint64_t &p : m->occupied) p = key_of_sort_key(p);
    }
    for (size_t j = 0; j < m->occupied.size();) {
        /* a batch of the occupied voxels not hit this sweep, binned together (bins_of) */
        double bx[BATCH], by[BATCH], bz[BATCH], br[BATCH];
        uint64_t bk[BATCH];
        int bb[BATCH], nb = 0;
        while (j < m->occupied.size() && nb < BATCH) {
            uint64_t pk = m->occupied[j];
            OcTreeKey k = unpack(pk);
            size_t bi = fine_bit(k);
            if (!get_bit(m->fine_bits, bi)) {
                clr_bit(m->listed_bits, bi);
                m->occupied[j] = m->occupied.back();
                m->occupied.pop_back();
                continue;
            }
            j++;
            if (get_bit(m->hit_bits, bi)) continue;
            octomap::point3d p = m->fine.keyToCoord(k);
            bx[nb] = p.x(); by[nb] = p.y(); bz[nb] = p.z(); bk[nb] = pk; nb++;
        }
        s.occupied_checked += nb;
        bins_of(sw, bx, by, bz, nb, bb, br, c.range_m);
        for (int q = 0; q < nb; q++) {
            const double r = br[q];
            const int b = bb[q];
            if (b < 0 || r > c.range_m) continue;
            int e = b / NAZ, a = b % NAZ, seen = 0;
            bool past = true;
            for (int de = -m->clear_el; de <= m->clear_el && past; de++)
                for (int da = -m->clear_az; da <= m->clear_az; da++) {
                    if (e + de < 0 || e + de >= NEL) continue;
                    float rb = m->bin_min[(size_t)(e + de) * NAZ + ((a + da) & (NAZ - 1))];
                    if (!std::isfinite(rb)) continue;
                    seen++;
                    if (rb < r + c.clear_margin_m) { past = false; break; }
                }
            if (past && seen > 0) m->to_clear.push_back(bk[q]);
        }
    }
    for (size_t i = 0; i < m->to_clear.size(); i++) {
        if (i % PF_GROUP == 0) m->prefetched += prefetch_paths(m->fine_blocks, FINE_BLOCK_DEPTH, &m->to_clear[i], (int)std::min<size_t>(PF_GROUP, m->to_clear.size() - i));
        const uint64_t p = m->to_clear[i];
        OcTreeKey k = unpack(p);
        bool known;
        octomap::OcTreeNode *nd = tree_update(m->fine, m->fine_blocks, FINE_BLOCK_DEPTH, k, false, &known);
        clr_bit(m->sat_bits, fine_bit(k));
        if (!nd || !m->fine.isNodeOccupied(nd)) {
            clr_bit(m->fine_bits, fine_bit(k)); s.cleared++;
            occ_map_t::shape_t &sh = m->shapes[shape_slot(fine_bit(k))];
            if (sh.pkey == p) sh.pkey = 0;
        }
    }
    /* the shapes of the voxels hit this sweep: their columns and top join those of the earlier
     * sweeps since the voxel became occupied (a voxel not hit in a later sweep, as the LiDAR
     * looks at another face of its object or past something in front, keeps them). The
     * table is random access: prefetched a few entries ahead */
    for (size_t i = 0, nu = m->sub_used.size(); i < nu; i++) {
        if (i + 32 < nu) __builtin_prefetch(&m->sub[m->sub_used[i + 32]]);   /* the slot first: its key places the shape */
        if (i + 16 < nu) __builtin_prefetch(&m->shapes[shape_slot(m->sub[m->sub_used[i + 16]].key - 1)], 1);
        const uint32_t u = m->sub_used[i];
        const occ_map_t::sub_t &e = m->sub[u];
        if (!get_bit(m->hit_bits, e.key - 1)) continue;    /* only reached by a neighbour's returns */
        occ_map_t::shape_t &sh = m->shapes[shape_slot(e.key - 1)];
        const uint32_t mk = sub_cells(e.mask);
        const uint64_t pkey = key_of_sort_key((uint64_t)(e.key - 1) << 24 | e.above);
        if (sh.pkey != pkey || (e.mask & SUB_FRESH)) sh = occ_map_t::shape_t{ pkey, mk, e.top };
        else { sh.mask |= mk; sh.top = std::max(sh.top, e.top); }
    }

    /* 4. observed space: every Nth beam traced through the coarse cells (new cells only) */
    int stride = std::max(1, c.observed_ray_stride);
    for (int i = m->sweep % stride; i < sw->n; i += stride) {     /* other beams next sweep */
        float x = sw->x[i], y = sw->y[i], z = sw->z[i];
        if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
        const double *o = sw->origins[sw->origin_index[i]];
        double d[3] = { x - o[0], y - o[1], z - o[2] };
        double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if (len < 1e-3) continue;
        double f = std::min(1.0, c.range_m / len);
        double pe[3] = { o[0] + d[0] * f, o[1] + d[1] * f, o[2] + d[2] * f };
        trace_observed(m, o, pe, &s);
    }
    apply_observed(m);

    /* 5. what stands beside the car below the lowest beam (this sweep only) */
    fill_below_view(m, sw, &s);

    /* 6. the rolling window */
    s.blocks_deleted = roll_window(m, sw->car);
    if (st) *st = s;
}

/* ---------------------------------------------------------------- queries */

/* Where the ray e + t d (|d| = 1) leaves the car's box (0 if it starts outside it). */
static double ego_exit(const occ_config_t &c, const double e[3], const double d[3], const double bp[3], double yaw)
{
    double cy = std::cos(yaw), sy = std::sin(yaw);
    double o[3] = { cy * (e[0] - bp[0]) + sy * (e[1] - bp[1]), -sy * (e[0] - bp[0]) + cy * (e[1] - bp[1]), e[2] - bp[2] };
    double v[3] = { cy * d[0] + sy * d[1], -sy * d[0] + cy * d[1], d[2] };
    double lo[3] = { c.ego_x0, -c.ego_half_width, 0 }, hi[3] = { c.ego_x1, c.ego_half_width, c.ego_height };
    for (int i = 0; i < 3; i++)
        if (o[i] < lo[i] || o[i] > hi[i]) return 0;
    double t = INFINITY;
    for (int i = 0; i < 3; i++) {
        if (v[i] > 1e-12) t = std::min(t, (hi[i] - o[i]) / v[i]);
        else if (v[i] < -1e-12) t = std::min(t, (lo[i] - o[i]) / v[i]);
    }
    return std::isfinite(t) ? t : 0;
}

/* Where the ray (u0 + du t, fine-voxel units) first meets the sub-cells of voxel key
 * between t0 and t1 that hold what its returns stand for, below their top; -1 if it passes
 * them (across x and y: the columns; in z: the top). The cells: for a voxel hit this
 * sweep, this sweep's (grown, with its neighbours' halo); for an occupied voxel not hit
 * this sweep, its shape from the sweeps that hit it (what it held may still be there) or,
 * without one, all of it (t0); for a voxel only in a neighbour's halo, that halo.
 * Sampled every 1/8 sub-cell: a corner clipped by less is not a hit. */
static double sub_hit(const occ_map_t *m, size_t fb, const int key[3], const double u0[3], const double du[3], double t0,
                      double t1)
{
    int slot = sub_find(m, fb);
    uint32_t mask;
    float stop;
    const bool occupied = get_bit(m->fine_bits, fb);
    if (get_bit(m->hit_bits, fb)) {
        if (slot < 0) return t0;
        mask = sub_cells(m->sub[slot].mask); stop = m->sub[slot].top;
    } else if (occupied) {
        const occ_map_t::shape_t &sh = m->shapes[shape_slot(fb)];
        if (sh.pkey != pack(OcTreeKey((uint16_t)key[0], (uint16_t)key[1], (uint16_t)key[2]))) return t0;
        mask = sh.mask; stop = sh.top;
        if (slot >= 0) { mask |= sub_cells(m->sub[slot].mask); stop = std::max(stop, m->sub[slot].top); }
    } else {
        if (slot < 0) return -1;
        mask = sub_cells(m->sub[slot].mask); stop = m->sub[slot].top;
    }
    /* the top: where the voxel above holds nothing, the object ends within this one */
    double top = INFINITY;
    if (key[2] + 1 < 2 * KEY_ORIGIN) {
        size_t up = fine_bit(OcTreeKey((uint16_t)key[0], (uint16_t)key[1], (uint16_t)(key[2] + 1)));
        if (!get_bit(m->fine_bits, up) && !get_bit(m->hit_bits, up) && !get_bit(m->fill_bits, up) && !get_bit(m->halo_bits, up)) top = stop;
    }
    if (mask == 0xffff && !(top < key[2] + 1)) return t0;
    const double dt = m->cfg.resolution / SUB / 8;
    for (double t = t0; t < t1 + dt; t += dt) {
        double tt = std::min(t, t1);
        if (u0[2] + du[2] * tt > top) continue;
        int c[2];
        for (int i = 0; i < 2; i++) c[i] = std::min(SUB - 1, std::max(0, (int)((u0[i] + du[i] * tt - key[i]) * SUB)));
        if ((mask >> (c[0] + SUB * c[1])) & 1) return tt;
    }
    return -1;
}

static int8_t query_one(const occ_map_t *m, const double e[3], const double bp[3], double yaw, double sx, double sy,
                        double sz, float *occ)
{
    const occ_config_t &c = m->cfg;
    *occ = NAN;
    double d[3] = { sx - e[0], sy - e[1], sz - e[2] };
    double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (!(len <= c.range_m)) return OCC_UNKNOWN;
    double tend = len - c.stop_short_m;
    if (tend <= 0) return OCC_VISIBLE;
    for (int i = 0; i < 3; i++) d[i] /= len;
    double t = ego_exit(c, e, d, bp, yaw);
    if (t >= tend) return OCC_VISIBLE;
    /* Two-level 3-D DDA (Amanatides & Woo) in units of fine voxels from t to tend: over the
     * observed-size cells (4 x 4 x 4 fine voxels), and over the fine voxels only inside
     * cells that may hold an occupied one (most of a ray crosses empty cells). */
    double u0[3], du[3], step[3];
    int ck[3], cstep[3];
    double ctmax[3], ctdelta[3], tdelta[3];
    const int sh = m->cshift, cw = 1 << sh, co = m->coff;
    for (int i = 0; i < 3; i++) {
        u0[i] = e[i] * m->inv_res + KEY_ORIGIN;
        du[i] = d[i] * m->inv_res;
        double u = u0[i] + du[i] * t;
        if (!(u >= 0 && u < 2 * KEY_ORIGIN)) return OCC_UNKNOWN;
        ck[i] = (int)u >> sh;
        if (du[i] > 1e-12) { cstep[i] = 1; ctmax[i] = t + ((ck[i] + 1) * cw - u) / du[i]; ctdelta[i] = cw / du[i]; tdelta[i] = 1 / du[i]; }
        else if (du[i] < -1e-12) { cstep[i] = -1; ctmax[i] = t + (ck[i] * cw - u) / du[i]; ctdelta[i] = -cw / du[i]; tdelta[i] = -1 / du[i]; }
        else { cstep[i] = 0; ctmax[i] = INFINITY; ctdelta[i] = INFINITY; tdelta[i] = INFINITY; }
        step[i] = cstep[i];
    }
    bool unknown = false;
    for (;;) {
        if (ck[0] < 0 || ck[1] < 0 || ck[2] < 0 || ck[0] >= (2 * KEY_ORIGIN >> sh) || ck[1] >= (2 * KEY_ORIGIN >> sh) ||
            ck[2] >= (2 * KEY_ORIGIN >> sh))
            return OCC_UNKNOWN;
        size_t cb = obs_bit(OcTreeKey((uint16_t)(ck[0] + co), (uint16_t)(ck[1] + co), (uint16_t)(ck[2] + co)));
        int ca = ctmax[0] < ctmax[1] ? (ctmax[0] < ctmax[2] ? 0 : 2) : (ctmax[1] < ctmax[2] ? 1 : 2);
        double tout = std::min(ctmax[ca], tend);
        if (get_bit(m->any_bits, cb)) {
            /* the fine voxels of this cell from t to tout; keys clamped into the cell (rounding at its faces) */
            int key[3];
            double tmax[3];
            for (int i = 0; i < 3; i++) {
                double u = u0[i] + du[i] * t;
                key[i] = std::min(ck[i] * cw + cw - 1, std::max(ck[i] * cw, (int)u));
                tmax[i] = step[i] > 0 ? t + (key[i] + 1 - u) / du[i] : step[i] < 0 ? t + (key[i] - u) / du[i] : INFINITY;
            }
            double tf = t;
            for (;;) {
                OcTreeKey k((uint16_t)key[0], (uint16_t)key[1], (uint16_t)key[2]);
                size_t fb = fine_bit(k);
                if (get_bit(m->fill_bits, fb)) { *occ = (float)tf; return OCC_HIDDEN; }
                int a = tmax[0] < tmax[1] ? (tmax[0] < tmax[2] ? 0 : 2) : (tmax[1] < tmax[2] ? 1 : 2);
                /* a voxel hit this sweep stands for what the LiDAR sees now, whether or not the
                 * tree holds it occupied yet (after a miss from another viewpoint it takes two
                 * hits); other voxels as the tree says, and the halo of this sweep's returns */
                const bool fine = get_bit(m->fine_bits, fb), hit = get_bit(m->hit_bits, fb);
                if (fine || hit || get_bit(m->halo_bits, fb)) {
                    const octomap::OcTreeNode *nd = fine && !hit ? m->fine.search(k) : nullptr;
                    if (!fine || hit || (nd && m->fine.isNodeOccupied(nd))) {
                        double th = sub_hit(m, fb, key, u0, du, tf, std::min(tmax[a], tend));
                        if (th >= 0) { *occ = (float)th; return OCC_HIDDEN; }
                    }
                }
                tf = tmax[a];
                if (tf >= tout) break;
                key[a] += (int)step[a];
                if ((key[a] >> sh) != ck[a]) break;
                tmax[a] += tdelta[a];
            }
        }
        if (!unknown && !get_bit(m->obs_bits, cb)) unknown = true;
        if (ctmax[ca] >= tend) break;
        t = ctmax[ca];
        ck[ca] += cstep[ca];
        ctmax[ca] += ctdelta[ca];
    }
    return unknown ? OCC_UNKNOWN : OCC_VISIBLE;
}

double occ_map_ego_exit(const occ_map_t *m, const double eye[3], const double d[3], const double base_pos[3], double base_yaw)
{
    return ego_exit(m->cfg, eye, d, base_pos, base_yaw);
}

void occ_map_query(const occ_map_t *m, const double eye[3], const double base_pos[3], double base_yaw, const float *x,
                   const float *y, const float *z, int n, int8_t *state, float *occluder_m)
{
    for (int i = 0; i < n; i++) state[i] = query_one(m, eye, base_pos, base_yaw, x[i], y[i], z[i], &occluder_m[i]);
}

