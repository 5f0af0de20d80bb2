/* window_search: exhaustive search of a sweep's position and yaw within a window
 * around a seed, by branch and bound over the map's structure above the ground
 * (walls, poles, trunks, foliage) seen as vertical columns of the fine level.
 * Internal to the localizer core; pb_reg_align_global refines its candidates.
 *
 * Why: the start-up search had pulled in a grid of hypotheses (1 m, 5 deg) by
 * Gauss-Newton, ~200 of them for 3 m / 15 deg, 44 ms per start on MulRan, and a
 * hypothesis between grid points could still miss the basin. Here every position
 * (a fine cell apart) and yaw (a cell at the farthest point apart) in the window is
 * scored by how many structure points fall in an occupied column at their height;
 * bounds over blocks of positions, from the column masks OR-ed over the block,
 * prune almost all of them (the scheme of Olson's and Cartographer's correlative
 * matchers, on bit masks of height instead of probabilities).
 *
 * Frames: map <- base poses; the scan in base. The search moves only x, y and yaw
 * (about the seed's position); z, roll and pitch stay the seed's, so each point's
 * height in the map is fixed and the column masks can be OR-ed in x, y alone. */
#ifndef PB_LOC_WINDOW_SEARCH_H
#define PB_LOC_WINDOW_SEARCH_H

#include <stdint.h>
#include <vector>
#include <Eigen/Geometry>
#include "voxel_hash.h"

namespace pb_loc {

struct Level;

/* The fine level's cells above the ground (every target that is not an upward
 * plane, and the rough cells), as a bit per voxel of height in each vertical column,
 * stored in square blocks of columns (dense inside a block: a window of columns is a
 * few block look-ups). Bit k of a column: voxel z index zlo + k, zlo per block; a
 * column taller than 32 voxels keeps its lowest 32. */
struct Columns {
    static constexpr int kBlock = 16;
    struct Block {
        int32_t zlo;
        uint32_t bits[kBlock * kBlock];
    };
    double voxel = 0;
    VoxelHash index;   /* block (bx, by, 0) -> blocks[] */
    std::vector<Block> blocks;
};

void columns_build(const Level &fine, Columns *out);

typedef struct {
    double radius_m = 3;         /* positions within this horizontal distance of the seed */
    double yaw_range_rad = 0.26; /* yaws within +-this of the seed's */
    double max_range_m = 40;     /* scan points used (horizontal distance from base) ... */
    int max_points = 300;        /* ... and at most this many of them (evenly spaced in the input) */
    int candidates = 3;          /* distinct best poses returned, ... */
    double close_ratio = 0.9;    /* ... of those scoring at least this share of the best */
    double distinct_m = 1.0;     /* candidates differ by more than this ... */
    double distinct_rad = 0.035; /* ... or this yaw */
} window_config_t;

struct window_candidate_t {
    Eigen::Isometry3d pose;
    int score;                   /* structure points in an occupied column */
};

/* Searches the window around seed for the scan's n points (base frame, already
 * downsampled).
 * Fills out with up to cfg.candidates poses, best first; *points: structure points
 * scored (the best possible score). Returns the number of candidates. */
int window_search(const Columns &cols, const float *xyz, size_t n,
                  const Eigen::Isometry3d &seed, const window_config_t &cfg,
                  std::vector<window_candidate_t> *out, int *points);

}  // namespace pb_loc

#endif
