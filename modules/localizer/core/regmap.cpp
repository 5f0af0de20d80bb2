/* regmap: prior map -> voxel hash of local planes (see regmap.h). */
#include "regmap.h"
#include "regmap_impl.h"
#include "pb_pcd.h"
#include "pb_split.h"

#include <sys/stat.h>
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <Eigen/Eigenvalues>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

using namespace pb_loc;

void pb_regmap_config_default(pb_regmap_config_t *cfg)
{
    *cfg = pb_regmap_config_t();
}

namespace {

/* Moments of the points of one voxel, relative to the voxel's corner (keeps
 * the sums small so float-sized scatter stays exact in double). */
struct Moments {
    double n = 0, s[3] = {0, 0, 0}, ss[6] = {0, 0, 0, 0, 0, 0};
};

/* Fits a plane (or a line) to n points given by their sums s and scatter ss
 * (relative to one corner). Returns CELL_PLANE, CELL_LINE or 0 (too few points,
 * or neither planar nor linear). */
int fit_target(double n, const double s[3], const double ss[6], const pb_regmap_config_t *cfg,
               Eigen::Vector3d *mu, Eigen::Vector3d *u1, Eigen::Vector3d *u2)
{
    if (n < cfg->min_points) return 0;
    *mu = Eigen::Vector3d(s[0] / n, s[1] / n, s[2] / n);
    Eigen::Matrix3d C;
    C << ss[0] / n, ss[1] / n, ss[2] / n, ss[1] / n, ss[3] / n, ss[4] / n, ss[2] / n, ss[4] / n, ss[5] / n;
    C -= *mu * mu->transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(C);
    Eigen::Vector3d ev = es.eigenvalues();   /* ascending */
    *u1 = es.eigenvectors().col(0);
    *u2 = es.eigenvectors().col(1);
    if (ev(0) <= cfg->planarity_max * ev(1)) {
        u2->setZero();
        return CELL_PLANE;
    }
    if (ev(1) <= cfg->planarity_max * ev(2)) return CELL_LINE;   /* u1, u2 span the normal plane of the line */
    return 0;
}

/* A rough cell's Gaussian from n points given by their sums s and scatter ss (relative to
 * one corner, `corner` in the map): mean and C^-1/2, whose eigenvalues are floored at 5 % of
 * the largest and at (5 cm)^2 (a sheet of leaves is nearly flat, and NDT floors them alike)
 * so that no direction is infinitely stiff. */
void fit_rough(double n, const double s[3], const double ss[6], const double corner[3],
               const pb_regmap_config_t *cfg, Rough *r)
{
    *r = Rough();
    if (n < cfg->min_points) return;
    Eigen::Vector3d mu(s[0] / n, s[1] / n, s[2] / n);
    Eigen::Matrix3d C;
    C << ss[0] / n, ss[1] / n, ss[2] / n, ss[1] / n, ss[3] / n, ss[4] / n, ss[2] / n, ss[4] / n, ss[5] / n;
    C -= mu * mu.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(C);
    const Eigen::Vector3d ev = es.eigenvalues();   /* ascending */
    const double floor = std::max(0.05 * ev(2), 0.0025);
    Eigen::Vector3d inv_sd;
    for (int a = 0; a < 3; a++) inv_sd(a) = 1.0 / std::sqrt(std::max(ev(a), floor));
    const Eigen::Matrix3d W = es.eigenvectors() * inv_sd.asDiagonal() * es.eigenvectors().transpose();
    const int upper[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
    for (int k = 0; k < 6; k++) r->w[k] = (float)W(upper[k][0], upper[k][1]);
    for (int a = 0; a < 3; a++) r->mean[a] = (float)(mu(a) + corner[a]);
}

/* What the voxel of `key` holds (kRough, CELL_PLANE or CELL_LINE; 0 for nothing): the
 * target fitted to its 3x3x3 neighbourhood's moments (shifted to this voxel's corner),
 * else (at a junction such as a wall's foot) to its own points alone, in *cell; a rough
 * cell's Gaussian (of the neighbourhood) in *rough. */
const uint8_t kRough = 3;
uint8_t fit_voxel(const VoxelHash &moment_index, const std::vector<Moments> &moments, uint64_t key,
                  const Moments &own, double voxel, const pb_regmap_config_t *cfg, Cell *cell, Rough *rough)
{
    int64_t ix, iy, iz;
    voxel_unkey(key, &ix, &iy, &iz);
    double N = 0, S[3] = {0, 0, 0}, SS[6] = {0, 0, 0, 0, 0, 0};
    for (int dx = -1; dx <= 1; dx++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dz = -1; dz <= 1; dz++) {
                uint64_t nkey;
                if (!voxel_key(ix + dx, iy + dy, iz + dz, &nkey)) continue;
                int32_t k = moment_index.find(nkey);
                if (k < 0) continue;
                const Moments &m = moments[(size_t)k];
                /* shift sums from the neighbour's corner by o = (dx,dy,dz)*voxel */
                double o[3] = {dx * voxel, dy * voxel, dz * voxel};
                double s[3] = {m.s[0] + m.n * o[0], m.s[1] + m.n * o[1], m.s[2] + m.n * o[2]};
                SS[0] += m.ss[0] + 2 * o[0] * m.s[0] + m.n * o[0] * o[0];
                SS[1] += m.ss[1] + o[0] * m.s[1] + o[1] * m.s[0] + m.n * o[0] * o[1];
                SS[2] += m.ss[2] + o[0] * m.s[2] + o[2] * m.s[0] + m.n * o[0] * o[2];
                SS[3] += m.ss[3] + 2 * o[1] * m.s[1] + m.n * o[1] * o[1];
                SS[4] += m.ss[4] + o[1] * m.s[2] + o[2] * m.s[1] + m.n * o[1] * o[2];
                SS[5] += m.ss[5] + 2 * o[2] * m.s[2] + m.n * o[2] * o[2];
                N += m.n;
                for (int a = 0; a < 3; a++) S[a] += s[a];
            }
    Eigen::Vector3d mu, u1, u2;
    int kind = fit_target(N, S, SS, cfg, &mu, &u1, &u2);
    if (!kind) kind = fit_target(own.n, own.s, own.ss, cfg, &mu, &u1, &u2);
    if (!kind) {
        if (own.n < 2) return 0;   /* a stray point */
        /* scattered (foliage): no plane or line, but where the points are and how they spread */
        const double corner[3] = {ix * voxel, iy * voxel, iz * voxel};
        fit_rough(N, S, SS, corner, cfg, rough);
        return kRough;
    }
    cell->kind = (uint8_t)kind;
    cell->mean[0] = (float)(mu(0) + ix * voxel);
    cell->mean[1] = (float)(mu(1) + iy * voxel);
    cell->mean[2] = (float)(mu(2) + iz * voxel);
    for (int a = 0; a < 3; a++) { cell->u1[a] = (float)u1(a); cell->u2[a] = (float)u2(a); }
    return (uint8_t)kind;
}

}  // namespace

/* Moments per voxel, then per voxel a target fitted to the points of its 3x3x3
 * neighbourhood (regmap_impl.h). */
size_t pb_loc::build_level(const float *xyz, size_t n, double voxel, const pb_regmap_config_t *cfg, Level *lv,
                          bool split)
{
    lv->voxel = voxel;
    lv->inv_voxel = 1.0 / voxel;
    /* 1. moments per occupied voxel */
    VoxelHash moment_index(n / 8 + 16);
    std::vector<Moments> moments;
    std::vector<uint64_t> keys;
    for (size_t i = 0; i < n; i++) {
        const float *p = xyz + 3 * i;
        uint64_t key;
        if (!voxel_key_of(p[0], p[1], p[2], lv->inv_voxel, &key)) continue;
        bool inserted;
        int32_t k = moment_index.insert(key, (int32_t)moments.size(), &inserted);
        if (inserted) { moments.emplace_back(); keys.push_back(key); }
        int64_t ix, iy, iz;
        voxel_unkey(key, &ix, &iy, &iz);
        double d[3] = {p[0] - ix * voxel, p[1] - iy * voxel, p[2] - iz * voxel};
        Moments &m = moments[(size_t)k];
        m.n += 1;
        for (int a = 0; a < 3; a++) m.s[a] += d[a];
        m.ss[0] += d[0] * d[0]; m.ss[1] += d[0] * d[1]; m.ss[2] += d[0] * d[2];
        m.ss[3] += d[1] * d[1]; m.ss[4] += d[1] * d[2]; m.ss[5] += d[2] * d[2];
    }
    /* 2. per voxel: gather the neighbourhood's moments (shifted to this voxel's
     *    corner), fit mean and covariance, classify by eigenvalues (on two threads when
     *    `split`: each voxel's fit is its own) */
    std::vector<Cell> fitted(keys.size());
    std::vector<uint8_t> fit_kind(keys.size());   /* 0 nothing, kRough, or CELL_* */
    std::vector<Rough> rough_fit(keys.size());
    auto fit_run = [&](size_t c0, size_t c1) {
        for (size_t c = c0; c < c1; c++)
            fit_kind[c] = fit_voxel(moment_index, moments, keys[c], moments[c], voxel, cfg, &fitted[c], &rough_fit[c]);
    };
    if (split) pb_split2(keys.size(), fit_run);
    else fit_run(0, keys.size());
    /* 3. the targets in the order their voxels first appear */
    lv->index.reset(keys.size());
    lv->rough.reset(16);
    lv->roughs.clear();
    lv->cells.clear();
    lv->cells.reserve(keys.size());
    lv->keys.clear();
    lv->keys.reserve(keys.size());
    for (size_t c = 0; c < keys.size(); c++) {
        bool inserted;
        if (fit_kind[c] == kRough) {
            lv->rough.insert(keys[c], (int32_t)lv->roughs.size(), &inserted);
            lv->roughs.push_back(rough_fit[c]);
        }
        if (fit_kind[c] != CELL_PLANE && fit_kind[c] != CELL_LINE) continue;
        lv->index.insert(keys[c], (int32_t)lv->cells.size(), &inserted);
        lv->cells.push_back(fitted[c]);
        lv->keys.push_back(keys[c]);
    }
    return lv->cells.size();
}

namespace {

pb_regmap_t *build(const float *xyz, size_t n, const pb_regmap_config_t *cfg, const char *what,
                   pb_err_t *err)
{
    if (!(cfg->voxel_m > 0.01) || cfg->coarse_voxel_m < 0 || cfg->min_points < 3 ||
        !(cfg->planarity_max > 0 && cfg->planarity_max < 1)) {
        pb_err_set(err, "%s: bad regmap config (voxel %g, coarse %g, min_points %d, planarity %g)",
                   what, cfg->voxel_m, cfg->coarse_voxel_m, cfg->min_points, cfg->planarity_max);
        return nullptr;
    }
    if (n == 0) {
        pb_err_set(err, "%s: no map points", what);
        return nullptr;
    }
    pb_regmap_t *m = new (std::nothrow) pb_regmap_t();
    if (!m) { pb_err_set(err, "%s: out of memory", what); return nullptr; }
    m->cfg = *cfg;
    pb_regmap_info_t &info = m->info;
    info.points = (int64_t)n;
    for (int a = 0; a < 3; a++) { info.min[a] = HUGE_VAL; info.max[a] = -HUGE_VAL; }
    for (size_t i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            double v = xyz[3 * i + a];
            if (v < info.min[a]) info.min[a] = v;
            if (v > info.max[a]) info.max[a] = v;
        }
    /* two threads: the coarse level while the fine one takes its moments, then the fine
     * level's fits split between them (the same cells as on one) */
    try {
        pb_both([&]() {
                    info.cells = (int64_t)build_level(xyz, n, cfg->voxel_m, cfg, &m->fine, true);
                    columns_build(m->fine, &m->columns);
                },
                [&]() {
                    if (cfg->coarse_voxel_m > 0) {
                        info.coarse_cells = (int64_t)build_level(xyz, n, cfg->coarse_voxel_m, cfg, &m->coarse);
                        m->coarse.roughs.clear();   /* a 2 m Gaussian is a whole tree: planes and lines only */
                    }
                });
    } catch (const std::bad_alloc &) {
        delete m;
        pb_err_set(err, "%s: out of memory preparing %zu map points", what, n);
        return nullptr;
    }
    for (const Cell &c : m->fine.cells) info.planar_cells += c.kind == CELL_PLANE;
    if (info.cells == 0) {
        delete m;
        pb_err_set(err, "%s: no voxel of %g m holds %d points with a plane or line", what,
                   cfg->voxel_m, cfg->min_points);
        return nullptr;
    }
    return m;
}

}  // namespace

pb_regmap_t *pb_regmap_from_points(const float *xyz, size_t n, const pb_regmap_config_t *cfg,
                                   pb_err_t *err)
{
    pb_regmap_config_t def;
    pb_regmap_config_default(&def);
    if (!cfg) cfg = &def;
    return build(xyz, n, cfg, "points", err);
}

int pb_pcd_read_xyz(const char *pcd_path, std::vector<float> *xyz, size_t *total, pb_err_t *err)
{
    /* PCL parses the header and every data form (ascii, binary, binary_compressed), once
     * the header is known not to crash it */
    if (pb_pcd_check(pcd_path, nullptr, err) != 0) return -1;
    pcl::PCLPointCloud2 blob;
    int rc;
    try {
        pcl::PCDReader reader;
        rc = reader.read(pcd_path, blob);
    } catch (const std::exception &e) {
        return pb_err_set(err, "%s: corrupt PCD: %s", pcd_path, e.what());
    }
    if (rc < 0) return pb_err_set(err, "%s: corrupt or unreadable PCD (PCL reader code %d)", pcd_path, rc);
    bool has[3] = {false, false, false};
    for (const auto &f : blob.fields)
        for (int a = 0; a < 3; a++)
            if (f.name == std::string(1, (char)('x' + a))) has[a] = true;
    if (!has[0] || !has[1] || !has[2]) return pb_err_set(err, "%s: PCD has no x, y, z fields", pcd_path);
    pcl::PointCloud<pcl::PointXYZ> cloud;
    pcl::fromPCLPointCloud2(blob, cloud);
    blob = pcl::PCLPointCloud2();
    xyz->clear();
    xyz->reserve(cloud.size() * 3);
    for (const auto &p : cloud.points)
        if (std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z)) xyz->insert(xyz->end(), {p.x, p.y, p.z});
    if (total) *total = cloud.size();
    return 0;
}

pb_regmap_t *pb_regmap_load(const char *pcd_path, const pb_regmap_config_t *cfg,
                            const double center_xy[2], pb_err_t *err)
{
    pb_regmap_config_t def;
    pb_regmap_config_default(&def);
    if (!cfg) cfg = &def;
    struct stat st;
    if (stat(pcd_path, &st) != 0) {
        pb_err_set(err, "%s: %s", pcd_path, strerror(errno));
        return nullptr;
    }
    if (!S_ISREG(st.st_mode)) {
        pb_err_set(err, "%s: not a regular file", pcd_path);
        return nullptr;
    }
    if (cfg->load_radius_m > 0 && !center_xy) {
        pb_err_set(err, "%s: load radius %g m needs a centre", pcd_path, cfg->load_radius_m);
        return nullptr;
    }
    std::vector<float> xyz;
    size_t total = 0;
    if (pb_pcd_read_xyz(pcd_path, &xyz, &total, err) != 0) return nullptr;
    /* within the load disc if one is asked for */
    double r2 = cfg->load_radius_m * cfg->load_radius_m;
    if (r2 > 0) {
        size_t kept = 0;
        for (size_t i = 0; i + 2 < xyz.size(); i += 3) {
            double dx = xyz[i] - center_xy[0], dy = xyz[i + 1] - center_xy[1];
            if (dx * dx + dy * dy > r2) continue;
            for (int a = 0; a < 3; a++) xyz[kept++] = xyz[i + (size_t)a];
        }
        xyz.resize(kept);
    }
    if (xyz.empty()) {
        if (r2 > 0)
            pb_err_set(err, "%s: none of %zu points within %g m of (%.1f, %.1f)", pcd_path, total,
                       cfg->load_radius_m, center_xy[0], center_xy[1]);
        else
            pb_err_set(err, "%s: no finite points", pcd_path);
        return nullptr;
    }
    pb_regmap_t *m = build(xyz.data(), xyz.size() / 3, cfg, pcd_path, err);
    if (m && r2 > 0) {
        m->info.center_xy[0] = center_xy[0];
        m->info.center_xy[1] = center_xy[1];
        m->info.load_radius_m = cfg->load_radius_m;
    }
    return m;
}

void pb_regmap_destroy(pb_regmap_t *m) { delete m; }

void pb_regmap_info(const pb_regmap_t *m, pb_regmap_info_t *info) { *info = m->info; }

int pb_regmap_covers(const pb_regmap_t *m, double x, double y, double r)
{
    if (m->info.load_radius_m <= 0) return 1;
    double dx = x - m->info.center_xy[0], dy = y - m->info.center_xy[1];
    return std::sqrt(dx * dx + dy * dy) + r <= m->info.load_radius_m ? 1 : 0;
}

int pb_regmap_ground_z(const pb_regmap_t *m, double x, double y, double z_hint, double search_m,
                       int below_only, double *z)
{
    if (!m || !std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z_hint)) return 0;
    const pb_loc::Level &L = m->fine;
    const double v = L.voxel;
    int steps = (int)std::ceil(search_m / v);
    bool found = false;
    double best = 0, best_d = 0;
    /* below_only: from the point down, the first ground is the one under it */
    for (int i = 0; i <= (below_only ? steps : 2 * steps); i++) {
        int k = below_only ? -i : i - steps;
        const pb_loc::Cell *c = L.lookup(x, y, z_hint + k * v);
        if (!c || !c->ground()) continue;
        /* the plane's height at (x, y) */
        double h = c->mean[2] - (c->u1[0] * (x - c->mean[0]) + c->u1[1] * (y - c->mean[1])) / c->u1[2];
        if (below_only && h > z_hint + 0.5 * v) continue;
        double d = std::fabs(h - z_hint);
        if (!found || d < best_d) { found = true; best = h; best_d = d; }
        if (below_only) break;
    }
    if (found) *z = best;
    return found ? 1 : 0;
}

void pb_regmap_cells(const pb_regmap_t *m, std::vector<float> *xyz, std::vector<uint8_t> *ground)
{
    xyz->clear();
    ground->clear();
    if (!m) return;
    const pb_loc::Level &L = m->fine;
    for (const pb_loc::Cell &c : L.cells) {
        xyz->insert(xyz->end(), c.mean, c.mean + 3);
        ground->push_back(c.ground());
    }
    L.rough.for_each([&](uint64_t key, int32_t) {
        int64_t ix, iy, iz;
        pb_loc::voxel_unkey(key, &ix, &iy, &iz);
        float p[3] = { (float)((ix + 0.5) * L.voxel), (float)((iy + 0.5) * L.voxel), (float)((iz + 0.5) * L.voxel) };
        xyz->insert(xyz->end(), p, p + 3);
        ground->push_back(0);
    });
}
