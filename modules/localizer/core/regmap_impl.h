/* regmap_impl: the inside of pb_regmap_t, shared by regmap.cpp and
 * registration.cpp only (not part of the API). */
#ifndef PB_LOC_REGMAP_IMPL_H
#define PB_LOC_REGMAP_IMPL_H

#include <mutex>
#include <vector>
#include "regmap.h"
#include "voxel_hash.h"
#include "window_search.h"

namespace pb_loc {

enum { CELL_PLANE = 1, CELL_LINE = 2 };

/* One target around the neighbourhood centroid: a plane (normal u1; residual
 * u1 . (q - mean)) or a line (u1, u2 orthonormal and perpendicular to it; two
 * residuals). */
struct Cell {
    float mean[3];
    float u1[3], u2[3];
    uint8_t kind;    /* CELL_* */

    /* an upward-facing plane: the ground (or a roof) */
    bool ground() const { return kind == CELL_PLANE && (u1[2] >= 0.8f || u1[2] <= -0.8f); }
};

/* The target of a rough cell (foliage, scattered structure: no plane or line fits): the
 * points of its 3x3x3 neighbourhood as a Gaussian. w is the upper triangle of C^-1/2
 * (w00 w01 w02 w11 w12 w22), so |W (q - mean)| is q's Mahalanobis distance; w[0] = 0
 * when the neighbourhood has too few points for a covariance (no target). */
struct Rough {
    float mean[3];
    float w[6];

    bool target() const { return w[0] > 0; }
};

/* Moments of the points of one voxel, relative to the voxel's corner (keeps the sums small
 * so float-sized scatter stays exact in double). */
struct Moments {
    double n = 0, s[3] = {0, 0, 0}, ss[6] = {0, 0, 0, 0, 0, 0};
};

/* A level's voxels as they were built (kept by pb_regmap_rebuild only): each voxel's moments
 * and what its fit gave (kind: 0, CELL_PLANE, CELL_LINE or 3 = rough; slot: its index in
 * cells or roughs), so that the next build from mostly the same points fits only the voxels
 * whose neighbourhood changed. */
struct Memo {
    VoxelHash index;               /* voxel key -> i */
    std::vector<uint64_t> keys;
    std::vector<Moments> moments;
    std::vector<uint8_t> kind;
    std::vector<int32_t> slot;
};

struct Level {
    double voxel = 0, inv_voxel = 0;
    VoxelHash index;
    std::vector<Cell> cells;
    std::vector<uint64_t> keys;   /* voxel key of each cell (for tiling and paging) */
    /* cells the map's points occupy without a reliable target (foliage, scattered
     * structure): no registration target, but evidence for the structure test */
    VoxelHash rough;            /* voxel key -> index in roughs */
    std::vector<Rough> roughs;  /* the fine level's only (the coarse level steps on planes and lines) */
    Memo memo;                  /* empty unless built by pb_regmap_rebuild */

    const Cell *lookup(double x, double y, double z) const
    {
        uint64_t key;
        if (!voxel_key_of(x, y, z, inv_voxel, &key)) return nullptr;
        int32_t i = index.find(key);
        return i < 0 ? nullptr : &cells[(size_t)i];
    }

    /* The cell of (x, y, z), or when it holds no target, those of its 6 face
     * neighbours (a point just across a cell face from its surface); n of them. */
    int lookup_near(double x, double y, double z, const Cell *out[7]) const
    {
        int64_t ix, iy, iz;
        if (!voxel_index_of(x, y, z, inv_voxel, &ix, &iy, &iz)) return 0;
        uint64_t key;
        if (!voxel_key(ix, iy, iz, &key)) return 0;
        int32_t i = index.find(key);
        if (i >= 0) { out[0] = &cells[(size_t)i]; return 1; }
        static const int d[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
        int n = 0;
        for (int k = 0; k < 6; k++) {
            if (!voxel_key(ix + d[k][0], iy + d[k][1], iz + d[k][2], &key)) continue;
            i = index.find(key);
            if (i >= 0) out[n++] = &cells[(size_t)i];
        }
        return n;
    }
};

/* Builds one level of edge `voxel` from n points (xyz interleaved): moments per voxel,
 * then per voxel a target fitted to the points of its 3x3x3 neighbourhood. Cells come in
 * the order their voxel first appears in the points; the same when `split` (the fits on
 * two threads). With `prev` (a level of the same edge and config that kept its memo), a
 * voxel whose 27 neighbours' moments are bitwise those of prev takes prev's fit: the same
 * result as fitting it again. `keep` keeps this level's memo. Returns the number of
 * targets. */
size_t build_level(const float *xyz, size_t n, double voxel, const pb_regmap_config_t *cfg, Level *lv,
                   bool split = false, const Level *prev = nullptr, bool keep = false);

}  // namespace pb_loc

struct pb_regmap;
namespace pb_loc {
/* m's columns, made now if they are not yet (thread-safe). */
const Columns &columns_of(const pb_regmap *m);
}  // namespace pb_loc

struct pb_regmap {
    pb_regmap_config_t cfg;
    pb_loc::Level fine, coarse;
    /* the fine level's structure as columns, for pb_reg_align_global's search: made on the
     * first search (pb_loc::columns_of), as a map that is only tracked against never needs
     * them (the mapper's local maps, rebuilt every few metres), or by map_tiles as it pages */
    mutable std::mutex columns_mutex;
    mutable bool columns_made = false;
    mutable pb_loc::Columns columns;
    pb_regmap_info_t info;
};

#endif
