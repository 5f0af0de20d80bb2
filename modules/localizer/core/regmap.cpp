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

/* The scatter of n points given by their sums s and scatter ss (relative to one corner),
 * decomposed: their mean and the eigen-decomposition of their covariance. False (nothing
 * done) for fewer than cfg->min_points. */
bool scatter_of(double n, const double s[3], const double ss[6], const pb_regmap_config_t *cfg,
                Eigen::Vector3d *mu, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> *es)
{
    if (n < cfg->min_points) return false;
    *mu = Eigen::Vector3d(s[0] / n, s[1] / n, s[2] / n);
    Eigen::Matrix3d C;
    C << ss[0] / n, ss[1] / n, ss[2] / n, ss[1] / n, ss[3] / n, ss[4] / n, ss[2] / n, ss[4] / n, ss[5] / n;
    C -= *mu * mu->transpose();
    es->computeDirect(C);
    return true;
}

/* A plane (or a line) from a scatter_of: CELL_PLANE, CELL_LINE or 0 (neither planar nor
 * linear), with the plane's normal in u1 (u2 zero) or the line's normal plane in u1, u2. */
int fit_target(const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> &es, const pb_regmap_config_t *cfg,
               Eigen::Vector3d *u1, Eigen::Vector3d *u2)
{
    const Eigen::Vector3d ev = es.eigenvalues();   /* ascending */
    *u1 = es.eigenvectors().col(0);
    *u2 = es.eigenvectors().col(1);
    if (ev(0) <= cfg->planarity_max * ev(1)) {
        u2->setZero();
        return CELL_PLANE;
    }
    if (ev(1) <= cfg->planarity_max * ev(2)) return CELL_LINE;   /* u1, u2 span the normal plane of the line */
    return 0;
}

/* A rough cell's Gaussian from a scatter_of whose mean mu is relative to `corner` (in the
 * map): mean and C^-1/2, whose eigenvalues are floored at 5 % of the largest and at
 * (5 cm)^2 (a sheet of leaves is nearly flat, and NDT floors them alike) so that no
 * direction is infinitely stiff. */
void fit_rough(const Eigen::Vector3d &mu, const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> &es,
               const double corner[3], Rough *r)
{
    *r = Rough();
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
uint8_t fit_voxel(const VoxelHash &moment_index, const std::vector<Moments> &moments, const VoxelBits &occupied,
                  uint64_t key, const Moments &own, double voxel, const pb_regmap_config_t *cfg, Cell *cell, Rough *rough)
{
    int64_t ix, iy, iz;
    voxel_unkey(key, &ix, &iy, &iz);
    const bool bits = !occupied.words.empty();   /* else every neighbour is looked up */
    double N = 0, S[3] = {0, 0, 0}, SS[6] = {0, 0, 0, 0, 0, 0};
    for (int dx = -1; dx <= 1; dx++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dz = -1; dz <= 1; dz++) {
                if (bits && !occupied.has(ix + dx, iy + dy, iz + dz)) continue;
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
    /* (one decomposition of the neighbourhood serves its plane or line and its Gaussian) */
    Eigen::Vector3d mu, mu_own, u1, u2;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es, es_own;
    const bool hood = scatter_of(N, S, SS, cfg, &mu, &es);
    int kind = hood ? fit_target(es, cfg, &u1, &u2) : 0;
    if (!kind && scatter_of(own.n, own.s, own.ss, cfg, &mu_own, &es_own)) {
        kind = fit_target(es_own, cfg, &u1, &u2);
        if (kind) mu = mu_own;
    }
    if (!kind) {
        if (own.n < 2) return 0;   /* a stray point */
        /* scattered (foliage): no plane or line, but where the points are and how they spread */
        const double corner[3] = {ix * voxel, iy * voxel, iz * voxel};
        if (hood) fit_rough(mu, es, corner, rough);
        else *rough = Rough();   /* too few points for a covariance: no target */
        return kRough;
    }
    cell->kind = (uint8_t)kind;
    cell->mean[0] = (float)(mu(0) + ix * voxel);
    cell->mean[1] = (float)(mu(1) + iy * voxel);
    cell->mean[2] = (float)(mu(2) + iz * voxel);
    for (int a = 0; a < 3; a++) { cell->u1[a] = (float)u1(a); cell->u2[a] = (float)u2(a); }
    return (uint8_t)kind;
}

/* Sets reuse[c] = -1 for every voxel c (keys[c]) with a changed voxel among its 27
 * neighbours: over a bitmap of the changed voxels when their box is small (a rolling local
 * map: a few MB), else by looking up the 27 neighbours of each changed voxel. */
void mark_near_changed(const std::vector<uint64_t> &keys, const std::vector<uint64_t> &changed,
                       const VoxelHash &index, std::vector<int32_t> *reuse)
{
    /* the box grown by 2: a voxel with a changed neighbour lies within 1 of it, and its own
     * neighbours within 2 */
    VoxelBits near;
    if (near.cover_keys(changed, 2, (int64_t)1 << 30)) {
        for (uint64_t key : changed) near.set(key);
        for (size_t c = 0; c < keys.size(); c++) {
            if ((*reuse)[c] < 0) continue;
            int64_t x, y, z;
            voxel_unkey(keys[c], &x, &y, &z);
            if (!near.inside(x - 1, y - 1, z - 1) || !near.inside(x + 1, y + 1, z + 1)) continue;
            bool any = false;
            for (int dx = -1; dx <= 1 && !any; dx++)
                for (int dy = -1; dy <= 1 && !any; dy++) {
                    const uint64_t b = near.at(x + dx, y + dy, z - 1);
                    any = near.get(b) || near.get(b + 1) || near.get(b + 2);
                }
            if (any) (*reuse)[c] = -1;
        }
        return;
    }
    for (uint64_t key : changed) {
        int64_t ix, iy, iz;
        voxel_unkey(key, &ix, &iy, &iz);
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++)
                for (int dz = -1; dz <= 1; dz++) {
                    uint64_t nkey;
                    if (!voxel_key(ix + dx, iy + dy, iz + dz, &nkey)) continue;
                    const int32_t c = index.find(nkey);
                    if (c >= 0) (*reuse)[(size_t)c] = -1;
                }
    }
}

}  // namespace

/* Moments per voxel, then per voxel a target fitted to the points of its 3x3x3
 * neighbourhood (regmap_impl.h). */
size_t pb_loc::build_level(const float *xyz, size_t n, double voxel, const pb_regmap_config_t *cfg, Level *lv,
                          bool split, const Level *prev, bool keep)
{
    lv->voxel = voxel;
    lv->inv_voxel = 1.0 / voxel;
    /* 1. moments per occupied voxel (a batch of points keyed and their slots prefetched,
     *    then looked up and their moments prefetched, then added in order: the table and
     *    the moments are far larger than the caches) */
    const Memo *pm = prev && !prev->memo.keys.empty() && prev->voxel == voxel ? &prev->memo : nullptr;
    const size_t expect = pm ? pm->keys.size() + pm->keys.size() / 8 + 16 : n / 8 + 16;   /* no growing on the way */
    VoxelHash moment_index(expect);
    std::vector<Moments> moments;
    std::vector<uint64_t> keys;
    moments.reserve(expect);
    keys.reserve(expect);
    KeyBatch batch;
    const int kBatch = KeyBatch::kMax;
    for (size_t i = 0; batch.next(xyz, n, &i, lv->inv_voxel, moment_index) > 0;) {
        int32_t found[kBatch];
        for (int j = 0; j < batch.n; j++) {
            found[j] = moment_index.find(batch.key[j]);
            if (found[j] >= 0) __builtin_prefetch(&moments[(size_t)found[j]], 1);
        }
        for (int j = 0; j < batch.n; j++) {
            const float *p = xyz + 3 * batch.point[j];
            const uint64_t key = batch.key[j];
            /* a key found is there still; one not found may have come with an earlier point */
            bool inserted = false;
            int32_t k = found[j] >= 0 ? found[j] : moment_index.insert(key, (int32_t)moments.size(), &inserted);
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
    }
    /* 1b. with a previous build: the voxels whose neighbourhood changed (a voxel new, gone,
     *     or with other moments changes its 26 neighbours' fits and its own); the others
     *     take prev's fit (fit_voxel is a function of the 27 moments alone) */
    std::vector<int32_t> reuse;   /* prev's memo index of a voxel whose fit is prev's, else -1 */
    if (pm) {
        reuse.assign(keys.size(), -1);
        std::vector<uint64_t> changed;
        std::vector<uint8_t> still(pm->keys.size(), 0);   /* prev's voxels there still */
        /* (in batches whose look-ups are prefetched, as above) */
        for (size_t c0 = 0; c0 < keys.size(); c0 += kBatch) {
            const size_t c1 = std::min(keys.size(), c0 + kBatch);
            for (size_t c = c0; c < c1; c++) pm->index.prefetch(keys[c]);
            for (size_t c = c0; c < c1; c++) {
                reuse[c] = pm->index.find(keys[c]);
                if (reuse[c] >= 0) __builtin_prefetch(&pm->moments[(size_t)reuse[c]]);
            }
            for (size_t c = c0; c < c1; c++) {
                const int32_t k = reuse[c];
                if (k >= 0) still[(size_t)k] = 1;
                if (k >= 0 && std::memcmp(&pm->moments[(size_t)k], &moments[c], sizeof(Moments)) == 0) continue;
                reuse[c] = -1;
                changed.push_back(keys[c]);
            }
        }
        for (size_t k = 0; k < pm->keys.size(); k++)
            if (!still[k]) changed.push_back(pm->keys[k]);
        mark_near_changed(keys, changed, moment_index, &reuse);
    }
    /* 2. per voxel: gather the neighbourhood's moments (shifted to this voxel's
     *    corner), fit mean and covariance, classify by eigenvalues (on two threads when
     *    `split`: each voxel's fit is its own) */
    VoxelBits occupied;   /* the voxels there are, so that a neighbour not there is not looked up */
    if (occupied.cover_keys(keys, 1, (int64_t)1 << 28))
        for (uint64_t key : keys) occupied.set(key);
    std::vector<Cell> fitted(keys.size());
    std::vector<uint8_t> fit_kind(keys.size());   /* 0 nothing, kRough, or CELL_* */
    std::vector<Rough> rough_fit(keys.size());
    auto fit_run = [&](size_t c0, size_t c1) {
        for (size_t c = c0; c < c1; c++) {
            const int32_t k = pm ? reuse[c] : -1;
            if (k < 0) {
                fit_kind[c] = fit_voxel(moment_index, moments, occupied, keys[c], moments[c], voxel, cfg, &fitted[c], &rough_fit[c]);
                continue;
            }
            const uint8_t kind = pm->kind[(size_t)k];
            const size_t slot = (size_t)pm->slot[(size_t)k];
            fit_kind[c] = kind;
            if (kind == CELL_PLANE || kind == CELL_LINE) fitted[c] = prev->cells[slot];
            /* (the coarse level drops its roughs once built: only the voxel's kind is prev's then) */
            else if (kind == kRough && slot < prev->roughs.size()) rough_fit[c] = prev->roughs[slot];
        }
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
    std::vector<int32_t> slot(keep ? keys.size() : 0, -1);
    for (size_t c = 0; c < keys.size(); c++) {
        bool inserted;
        if (fit_kind[c] == kRough) {
            if (keep) slot[c] = (int32_t)lv->roughs.size();
            lv->rough.insert(keys[c], (int32_t)lv->roughs.size(), &inserted);
            lv->roughs.push_back(rough_fit[c]);
        }
        if (fit_kind[c] != CELL_PLANE && fit_kind[c] != CELL_LINE) continue;
        if (keep) slot[c] = (int32_t)lv->cells.size();
        lv->index.insert(keys[c], (int32_t)lv->cells.size(), &inserted);
        lv->cells.push_back(fitted[c]);
        lv->keys.push_back(keys[c]);
    }
    if (keep) {
        lv->memo.index = std::move(moment_index);
        lv->memo.keys = std::move(keys);
        lv->memo.moments = std::move(moments);
        lv->memo.kind = std::move(fit_kind);
        lv->memo.slot = std::move(slot);
    } else {
        lv->memo = Memo();
    }
    return lv->cells.size();
}

namespace {

pb_regmap_t *build(const float *xyz, size_t n, const pb_regmap_config_t *cfg, const char *what,
                   pb_err_t *err, const pb_regmap_t *prev = nullptr, bool keep = false)
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
                    info.cells = (int64_t)build_level(xyz, n, cfg->voxel_m, cfg, &m->fine, true,
                                                      prev ? &prev->fine : nullptr, keep);
                },
                [&]() {
                    if (cfg->coarse_voxel_m > 0) {
                        info.coarse_cells = (int64_t)build_level(xyz, n, cfg->coarse_voxel_m, cfg, &m->coarse, false,
                                                                 prev ? &prev->coarse : nullptr, keep);
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

const Columns &pb_loc::columns_of(const pb_regmap *m)
{
    std::lock_guard<std::mutex> lock(m->columns_mutex);
    if (!m->columns_made) {
        columns_build(m->fine, &m->columns);
        m->columns_made = true;
    }
    return m->columns;
}

pb_regmap_t *pb_regmap_from_points(const float *xyz, size_t n, const pb_regmap_config_t *cfg,
                                   pb_err_t *err)
{
    pb_regmap_config_t def;
    pb_regmap_config_default(&def);
    if (!cfg) cfg = &def;
    return build(xyz, n, cfg, "points", err);
}

pb_regmap_t *pb_regmap_rebuild(const pb_regmap_t *prev, const float *xyz, size_t n,
                              const pb_regmap_config_t *cfg, pb_err_t *err)
{
    pb_regmap_config_t def;
    pb_regmap_config_default(&def);
    if (!cfg) cfg = &def;
    /* prev's fits are this config's only if they came from the same one */
    const bool same = prev && prev->cfg.voxel_m == cfg->voxel_m && prev->cfg.coarse_voxel_m == cfg->coarse_voxel_m &&
                      prev->cfg.min_points == cfg->min_points && prev->cfg.planarity_max == cfg->planarity_max;
    return build(xyz, n, cfg, "points", err, same ? prev : nullptr, true);
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
