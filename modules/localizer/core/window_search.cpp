/* window_search: branch and bound over positions and yaws (see window_search.h). */
#include "window_search.h"
#include "regmap_impl.h"

#include <algorithm>
#include <cmath>

namespace pb_loc {

namespace {

/* The block holding column (ix, iy): its index in cols.blocks, or -1. */
int32_t block_of(const Columns &cols, int64_t bx, int64_t by)
{
    uint64_t key;
    return voxel_key(bx, by, 0, &key) ? cols.index.find(key) : -1;
}

/* o[x] = a[x] | b[x] and o[x] |= a[x] | b[x] for x < n, n a multiple of 8: the level
 * grids are built a row at a time in whole vectors */
inline void or2(uint32_t *__restrict o, const uint32_t *__restrict a, const uint32_t *__restrict b, int n)
{
    for (int x0 = 0; x0 < n; x0 += 8)
        for (int k = 0; k < 8; k++) o[x0 + k] = a[x0 + k] | b[x0 + k];
}
inline void or2_into(uint32_t *__restrict o, const uint32_t *__restrict a, const uint32_t *__restrict b, int n)
{
    for (int x0 = 0; x0 < n; x0 += 8)
        for (int k = 0; k < 8; k++) o[x0 + k] |= a[x0 + k] | b[x0 + k];
}

/* A node of the search: positions [dx, dx + 2^level) x [dy, dy + 2^level) in cells
 * from the seed, at one yaw; bound = its score at that level. */
struct Node {
    int yaw, dx, dy, bound;
};

struct Search {
    int candidates = 0;
    double close_ratio = 1;
    double distinct_m = 0, distinct_rad = 0;
    int nx = 0, W = 0;                         /* the grids' row stride (cells); window half-width */
    std::vector<std::vector<uint32_t>> grid;   /* per level: column masks OR-ed over 2^level cells */
    std::vector<uint32_t> mask;                /* per point: its height voxel and the two beside it */
    std::vector<int32_t> cell;                 /* per yaw, per point: grid index at offset (0, 0) */
    size_t m = 0;
    double voxel = 0, yaw_step = 0;
    std::vector<Node> best;                    /* leaves, distinct, any order; bound = score */

    int score(const Node &nd, int level) const
    {
        const uint32_t *g = grid[(size_t)level].data();
        const int32_t *c = &cell[(size_t)nd.yaw * m];
        const int32_t off = nd.dy * nx + nd.dx;
        int s = 0;
        for (size_t i = 0; i < m; i++) s += (g[c[i] + off] & mask[i]) != 0;
        return s;
    }

    /* a node is worth opening when it can beat the lowest candidate held (once there
     * are enough) and can still make the share of the best that is kept in the end */
    bool worth(int bound) const
    {
        int lo = best.empty() ? 0 : best[0].bound, hi = 0;
        for (const Node &b : best) lo = std::min(lo, b.bound), hi = std::max(hi, b.bound);
        if ((int)best.size() < candidates) lo = 0;
        return bound > lo && bound >= close_ratio * hi;
    }

    /* A leaf worth keeping (see worth): it replaces the candidates near it
     * that score less, or, when none is near, the lowest one. */
    void offer(const Node &nd)
    {
        for (size_t k = 0; k < best.size(); k++) {
            const Node &o = best[k];
            double dyaw = std::fabs((o.yaw - nd.yaw) * yaw_step);
            double dd = std::hypot(o.dx - nd.dx, o.dy - nd.dy) * voxel;
            if (dd <= distinct_m && dyaw <= distinct_rad) {
                if (o.bound >= nd.bound) return;
                best.erase(best.begin() + (long)k);
                k--;
            }
        }
        if ((int)best.size() >= candidates)
            best.erase(std::min_element(best.begin(), best.end(),
                                        [](const Node &p, const Node &q) { return p.bound < q.bound; }));
        best.push_back(nd);
    }

    void branch(const Node &nd, int level)
    {
        if (!worth(nd.bound)) return;
        if (level == 0) {
            if (nd.dx * nd.dx + nd.dy * nd.dy <= W * W) offer(nd);
            return;
        }
        int s = 1 << (level - 1);
        Node kids[4];
        int nk = 0;
        for (int a = 0; a < 2; a++)
            for (int b = 0; b < 2; b++) {
                Node k = { nd.yaw, nd.dx + a * s, nd.dy + b * s, 0 };
                if (k.dx > W || k.dy > W) continue;
                k.bound = score(k, level - 1);
                kids[nk++] = k;
            }
        std::stable_sort(kids, kids + nk, [](const Node &p, const Node &q) { return p.bound > q.bound; });
        for (int k = 0; k < nk; k++) branch(kids[k], level - 1);
    }
};

}  // namespace

void columns_build(const Level &fine, Columns *out)
{
    const int B = Columns::kBlock;
    out->voxel = fine.voxel;
    out->blocks.clear();
    out->index.reset(fine.cells.size() / 64 + 16);
    /* the structure's voxels: targets that are not ground, and the rough cells */
    std::vector<uint64_t> keys;
    keys.reserve(fine.cells.size());
    for (size_t c = 0; c < fine.cells.size(); c++)
        if (!fine.cells[c].ground()) keys.push_back(fine.keys[c]);
    fine.rough.for_each([&](uint64_t key, int32_t) { keys.push_back(key); });
    /* 1. blocks and their lowest voxel; 2. the bits */
    for (int pass = 0; pass < 2; pass++)
        for (uint64_t key : keys) {
            int64_t ix, iy, iz;
            voxel_unkey(key, &ix, &iy, &iz);
            int64_t bx = pb_floor_div(ix, B), by = pb_floor_div(iy, B);
            uint64_t bkey;
            if (!voxel_key(bx, by, 0, &bkey)) continue;
            bool inserted;
            int32_t k = out->index.insert(bkey, (int32_t)out->blocks.size(), &inserted);
            if (inserted) {
                Columns::Block blk;
                blk.zlo = (int32_t)iz;
                std::fill(blk.bits, blk.bits + B * B, 0u);
                out->blocks.push_back(blk);
            }
            Columns::Block &blk = out->blocks[(size_t)k];
            if (pass == 0) {
                blk.zlo = std::min(blk.zlo, (int32_t)iz);
            } else if (iz - blk.zlo < 32) {
                blk.bits[(iy - by * B) * B + (ix - bx * B)] |= 1u << (iz - blk.zlo);
            }
        }
}

int window_search(const Columns &cols, const float *xyz, size_t n,
                  const Eigen::Isometry3d &seed, const window_config_t &cfg,
                  std::vector<window_candidate_t> *out, int *points)
{
    out->clear();
    *points = 0;
    if (cols.blocks.empty() || n == 0 || cfg.candidates < 1) return 0;
    const double v = cols.voxel, inv = 1.0 / v;
    const Eigen::Matrix3d Rs = seed.linear();
    const Eigen::Vector3d ts = seed.translation();
    /* 1. the structure points: within range and above the sweep's own ground (the ground
     *    fits everywhere along a road): more than 0.3 m above the lowest return of their
     *    1 m column, the sweep seen from above. Each keeps its height voxel in the map. */
    VoxelHash col_index(2 * n + 16);
    std::vector<float> col_min;
    std::vector<int32_t> col_of(n, -1);
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + 3 * i;
        uint64_t key;
        if (!(std::hypot(p[0], p[1]) <= cfg.max_range_m) || !voxel_key_of(p[0], p[1], 0.0, 1.0, &key)) continue;
        bool inserted;
        int32_t k = col_index.insert(key, (int32_t)col_min.size(), &inserted);
        if (inserted) col_min.push_back(p[2]);
        col_min[(size_t)k] = std::min(col_min[(size_t)k], p[2]);
        col_of[i] = k;
    }
    std::vector<float> qx, qy;
    std::vector<int64_t> qz;
    double r_far = 0, r_cells = 0;
    for (size_t i = 0; i < n; i++) {
        if (col_of[i] < 0 || xyz[3 * i + 2] <= col_min[(size_t)col_of[i]] + 0.3f) continue;
        Eigen::Vector3d p(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
        Eigen::Vector3d q = Rs * p, w = q + ts;
        int64_t ix, iy, iz;
        if (!voxel_index_of(w.x(), w.y(), w.z(), inv, &ix, &iy, &iz)) continue;
        qx.push_back((float)q.x());
        qy.push_back((float)q.y());
        qz.push_back(iz);
        r_far = std::max(r_far, std::hypot(p.x(), p.y()));
        /* the grid must hold the points as the seed turns them: a seed with roll or pitch
         * (a slope) moves high points sideways beyond their reach in the sweep */
        r_cells = std::max(r_cells, std::hypot(q.x(), q.y()));
    }
    if (qz.empty()) return 0;
    int64_t iz0 = *std::min_element(qz.begin(), qz.end()) - 1;
    Search S;
    S.candidates = cfg.candidates;
    S.close_ratio = cfg.close_ratio;
    S.distinct_m = cfg.distinct_m;
    S.distinct_rad = cfg.distinct_rad;
    S.voxel = v;
    std::vector<float> px, py;
    for (size_t i = 0; i < qz.size(); i++) {
        int64_t b = qz[i] - iz0;   /* >= 1 */
        if (b > 30) continue;      /* 15 m above the lowest: beyond the column masks */
        S.mask.push_back(7u << (b - 1));
        px.push_back(qx[i]);
        py.push_back(qy[i]);
    }
    /* the bound of every node costs a pass over the points: a few hundred decide */
    if (cfg.max_points > 0 && S.mask.size() > (size_t)cfg.max_points) {
        size_t k = 0, total = S.mask.size();
        for (size_t i = 0; i < (size_t)cfg.max_points; i++) {
            size_t j = i * total / (size_t)cfg.max_points;
            S.mask[k] = S.mask[j]; px[k] = px[j]; py[k] = py[j];
            k++;
        }
        S.mask.resize(k); px.resize(k); py.resize(k);
    }
    S.m = S.mask.size();
    *points = (int)S.m;
    /* 2. the window of columns around the seed, and its levels: level h holds at each
     *    cell the OR of the 2^h x 2^h cells from it (an upper bound for every position
     *    of a block) */
    S.W = (int)std::ceil(cfg.radius_m * inv);
    /* levels up to blocks of 64 cells (32 m): a wider window (a poor GNSS fix) gets
     * several roots per yaw rather than levels of its whole size */
    int H = 0;
    while ((1 << H) < 2 * S.W + 1 && H < 6) H++;
    int rc = (int)std::ceil(std::max(r_far, r_cells) * inv) + 1;
    /* nx x nx cells, nx whole vectors; each row is followed by 8 empty cells, so that
     * reading a few cells past a row's end reads nothing */
    const int nx = (2 * (rc + S.W) + 2 + (1 << H) + 7) & ~7;
    S.nx = nx + 8;
    const int64_t gx0 = pb_floor_i64(ts.x() * inv) - rc - S.W, gy0 = pb_floor_i64(ts.y() * inv) - rc - S.W;
    S.grid.assign((size_t)H + 1, std::vector<uint32_t>((size_t)nx * S.nx, 0u));
    const int B = Columns::kBlock;
    std::vector<uint32_t> &g0 = S.grid[0];
    for (int64_t bx = pb_floor_div(gx0, B); bx <= pb_floor_div(gx0 + nx - 1, B); bx++)
        for (int64_t by = pb_floor_div(gy0, B); by <= pb_floor_div(gy0 + nx - 1, B); by++) {
            int32_t k = block_of(cols, bx, by);
            if (k < 0) continue;
            const Columns::Block &blk = cols.blocks[(size_t)k];
            int64_t sh = blk.zlo - iz0;   /* column bit j is window bit j + sh */
            if (sh >= 32 || sh <= -32) continue;
            for (int j = 0; j < B; j++) {
                int64_t y = by * B + j - gy0;
                if (y < 0 || y >= nx) continue;
                for (int i = 0; i < B; i++) {
                    int64_t x = bx * B + i - gx0;
                    if (x < 0 || x >= nx) continue;
                    uint32_t b = blk.bits[j * B + i];
                    g0[(size_t)(y * S.nx + x)] = sh >= 0 ? b << sh : b >> -sh;
                }
            }
        }
    {
        /* a surface on a cell border puts its points in either cell: a point counts in
         * its cell or a face neighbour's (rows at a time: no test per cell) */
        std::vector<uint32_t> d(g0.size(), 0u);
        for (int y = 0; y < nx; y++) {
            const uint32_t *r = &g0[(size_t)y * S.nx];
            const uint32_t *up = y > 0 ? r - S.nx : r, *dn = y + 1 < nx ? r + S.nx : r;
            uint32_t *o = &d[(size_t)y * S.nx];
            or2(o, up, dn, nx);
            or2_into(o, r, r + 1, nx);
            or2_into(o + 8, r + 7, r + 7, nx - 8);
            for (int x = 1; x < 8; x++) o[x] |= r[x - 1];
        }
        g0.swap(d);
    }
    for (int h = 1; h <= H; h++) {
        const std::vector<uint32_t> &lo = S.grid[(size_t)h - 1];
        std::vector<uint32_t> &hi = S.grid[(size_t)h];
        int s = 1 << (h - 1);
        for (int y = 0; y < nx; y++) {
            const uint32_t *a = &lo[(size_t)y * S.nx], *b = y + s < nx ? a + (size_t)s * S.nx : a;
            uint32_t *o = &hi[(size_t)y * S.nx];
            or2(o, a, b, nx);
            or2_into(o, a + s, b + s, s < 8 ? nx : nx - s);
        }
    }
    /* 3. yaws a cell apart at the farthest point; each yaw's points as grid cells */
    double step = r_far > v ? 2 * std::asin(0.5 * v / r_far) : 0.5;
    double range = std::min(cfg.yaw_range_rad, M_PI);
    int ny = std::max(1, (int)std::ceil(2 * range / step) + 1);
    if (range >= M_PI - 1e-9) ny = std::max(1, (int)std::ceil(2 * M_PI / step));   /* a full turn: -pi only */
    S.yaw_step = ny > 1 ? (range >= M_PI - 1e-9 ? 2 * M_PI / ny : 2 * range / (ny - 1)) : 0;
    const double yaw0 = ny > 1 ? -range : 0;   /* yaw of index 0, from the seed's */
    S.cell.resize((size_t)ny * S.m);
    std::vector<Node> roots;
    for (int j = 0; j < ny; j++) {
        double yaw = yaw0 + j * S.yaw_step, c = std::cos(yaw), s = std::sin(yaw);
        int32_t *cj = &S.cell[(size_t)j * S.m];
        for (size_t i = 0; i < S.m; i++) {
            double x = ts.x() + c * px[i] - s * py[i], y = ts.y() + s * px[i] + c * py[i];
            int64_t cx = pb_floor_i64(x * inv) - gx0, cy = pb_floor_i64(y * inv) - gy0;
            cj[i] = (int32_t)(cy * S.nx + cx);
        }
        for (int dx = -S.W; dx <= S.W; dx += 1 << H)
            for (int dy = -S.W; dy <= S.W; dy += 1 << H) {
                Node nd = { j, dx, dy, 0 };
                nd.bound = S.score(nd, H);
                roots.push_back(nd);
            }
    }
    /* 4. best first: a block whose bound cannot beat the candidates held is skipped */
    std::stable_sort(roots.begin(), roots.end(), [](const Node &p, const Node &q) { return p.bound > q.bound; });
    for (const Node &r : roots) S.branch(r, H);
    std::stable_sort(S.best.begin(), S.best.end(), [](const Node &p, const Node &q) { return p.bound > q.bound; });
    for (const Node &nd : S.best) {
        window_candidate_t c;
        c.pose = seed;
        c.pose.linear() = Eigen::AngleAxisd(yaw0 + nd.yaw * S.yaw_step, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                          seed.linear();
        c.pose.translation() += Eigen::Vector3d(nd.dx * v, nd.dy * v, 0);
        c.score = nd.bound;
        out->push_back(c);
    }
    /* a clear winner is refined alone; near-equals (a road alike both ways) are all tried */
    while (out->size() > 1 && out->back().score < cfg.close_ratio * out->front().score) out->pop_back();
    return (int)out->size();
}

}  // namespace pb_loc
