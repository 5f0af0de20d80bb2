/* regmap_impl: the inside of pb_regmap_t, shared by regmap.cpp and
 * registration.cpp only (not part of the API). */
#ifndef PB_LOC_REGMAP_IMPL_H
#define PB_LOC_REGMAP_IMPL_H

#include <vector>
#include "regmap.h"
#include "voxel_hash.h"

namespace pb_loc {

enum { CELL_PLANE = 1, CELL_LINE = 2 };

/* One target around the neighbourhood centroid: a plane (normal u1; residual
 * u1 . (q - mean)) or a line (u1, u2 orthonormal and perpendicular to it; two
 * residuals). */
struct Cell {
    float mean[3];
    float u1[3], u2[3];
    uint8_t kind;    /* CELL_* */
};

struct Level {
    double voxel = 0, inv_voxel = 0;
    VoxelHash index;
    std::vector<Cell> cells;

    const Cell *lookup(double x, double y, double z) const
    {
        uint64_t key;
        if (!voxel_key_of(x, y, z, inv_voxel, &key)) return nullptr;
        int32_t i = index.find(key);
        return i < 0 ? nullptr : &cells[(size_t)i];
    }
};

}  // namespace pb_loc

struct pb_regmap {
    pb_regmap_config_t cfg;
    pb_loc::Level fine, coarse;
    pb_regmap_info_t info;
};

#endif
