/* Unit tests of the localizer's registration core (modules/localizer/core):
 * regmap loading and errors, point-to-plane alignment on a synthetic street,
 * divergence evidence, degeneracy, global alignment, deskew, and the real
 * HDL-32E pair (tests/data/lidar_pair_hdl32) against its reference transform;
 * map tiles (paging along a long street: memory bounded, poses identical to the
 * whole map, corrupt files named) and the multi-scan pose refinement on a
 * simulated sequence with known truth. */
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <cstdlib>
#include <map>
#include <random>
#include <vector>
#include <Eigen/Geometry>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include "pb_check.h"
#include "deskew.h"
#include "map_tiles.h"
#include "places.h"
#include "refine.h"
#include "registration.h"
#include "regmap.h"
#include "regmap_impl.h"
#include "window_search.h"

/* A street along x: ground z = 0, building fronts at y = +-8 m (10 m tall) with
 * doorway recesses every 7 m and 11 m (so x is observable), a few poles. Points
 * on a 0.1 m grid, map frame. */
static void street(std::vector<float> *xyz, bool recesses, double x0, double x1)
{
    auto add = [&](double x, double y, double z) { xyz->push_back((float)x); xyz->push_back((float)y); xyz->push_back((float)z); };
    for (double x = x0; x < x1; x += 0.1)
        for (double y = -8; y < 8; y += 0.1) add(x, y, 0);
    for (double x = x0; x < x1; x += 0.1)
        for (double z = 0; z < 10; z += 0.1) {
            bool recess_l = recesses && std::fmod(x + 1000, 7.0) < 1.5;
            bool recess_r = recesses && std::fmod(x + 1000, 11.0) < 2.0;
            add(x, recess_l ? 9.0 : 8.0, z);
            add(x, recess_r ? -9.0 : -8.0, z);
        }
    if (recesses)   /* recess side walls: the planes that fix x */
        for (double xs = std::ceil(x0 / 7) * 7; xs < x1; xs += 7)
            for (double y = 8; y < 9; y += 0.1)
                for (double z = 0; z < 10; z += 0.1) { add(xs, y, z); add(xs + 1.5, y, z); }
    if (recesses)
        for (double xs = std::ceil(x0 / 11) * 11; xs < x1; xs += 11)
            for (double y = -9; y < -8; y += 0.1)
                for (double z = 0; z < 10; z += 0.1) { add(xs, y, z); add(xs + 2.0, y, z); }
}

/* A regmap (default configuration) of the points; nullptr, after a failed check that
 * prints the error, when it does not build. */
static pb_regmap_t *regmap_of(const std::vector<float> &m)
{
    pb_err_t err;
    pb_regmap_t *map = pb_regmap_from_points(m.data(), m.size() / 3, nullptr, &err);
    CHECK(map != nullptr);
    if (!map) std::fprintf(stderr, "%s\n", err.msg);
    return map;
}

/* The street from x = -60 to 60 m (its points into *m) and its regmap, as regmap_of. */
static pb_regmap_t *street_map(std::vector<float> *m, bool recesses)
{
    street(m, recesses, -60, 60);
    return regmap_of(*m);
}

/* The scan: map points within 40 m of the vehicle at T (map <- base), in base,
 * every 3rd point, with 1 cm noise. */
static std::vector<float> scan_of(const std::vector<float> &map, const Eigen::Isometry3d &T)
{
    std::mt19937 rng(7);
    std::normal_distribution<double> n(0, 0.01);
    std::vector<float> out;
    Eigen::Isometry3d Ti = T.inverse();
    for (size_t i = 0; i < map.size() / 3; i += 3) {
        Eigen::Vector3d p = Ti * Eigen::Vector3d(map[3 * i], map[3 * i + 1], map[3 * i + 2]);
        if (p.head<2>().norm() > 40) continue;
        for (int a = 0; a < 3; a++) out.push_back((float)(p(a) + n(rng)));
    }
    return out;
}

static Eigen::Isometry3d pose(double x, double y, double yaw_deg)
{
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(yaw_deg * M_PI / 180, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(x, y, 0.1);
    return T;
}

static double yaw_err_deg(const Eigen::Isometry3d &a, const Eigen::Isometry3d &b)
{
    Eigen::Matrix3d D = a.linear().transpose() * b.linear();
    return std::fabs(std::atan2(D(1, 0), D(0, 0))) * 180 / M_PI;
}

static void test_align_street(void)
{
    std::vector<float> m;
    pb_regmap_t *map = street_map(&m, true);
    if (!map) return;
    pb_err_t err;
    pb_regmap_info_t info;
    pb_regmap_info(map, &info);
    CHECK(info.cells > 1000);
    CHECK(info.planar_cells > info.cells / 2);
    CHECK(pb_regmap_covers(map, 0, 0, 1000) == 1);

    Eigen::Isometry3d truth = pose(3.2, 0.6, 12);
    std::vector<float> scan = scan_of(m, truth);
    pb_reg_result_t r;
    /* tracking start: 20 cm and 1 degree off */
    int rc = pb_reg_align(map, scan.data(), scan.size() / 3, pose(3.35, 0.5, 13), nullptr, &r, &err);
    CHECK(rc == PB_REG_OK || rc == PB_REG_MAX_ITER);
    std::printf("street: err %.4f m, yaw %.4f deg, inliers %.3f, overlap %.3f, rmse %.4f, %d it, %d pts\n",
                (r.pose.translation() - truth.translation()).norm(), yaw_err_deg(r.pose, truth), r.inlier_fraction,
                r.overlap, r.rmse_m, r.iterations, r.points_used);
    CHECK((r.pose.translation() - truth.translation()).norm() < 0.01);
    CHECK(yaw_err_deg(r.pose, truth) < 0.05);
    /* voxel centroids at corners sit off every plane: not all points are inliers */
    CHECK(r.inlier_fraction > 0.8);
    CHECK(r.overlap > 0.9);
    CHECK(r.rmse_m < 0.08);
    CHECK(r.points_used > 500 && r.points_used <= 2600);
    /* covariance: symmetric, positive, small */
    CHECK((r.covariance - r.covariance.transpose()).norm() < 1e-9 * r.covariance.norm() + 1e-15);
    CHECK(r.covariance(0, 0) > 0 && r.covariance(0, 0) < 1e-3);
    /* 1 m / 3 degrees off: the coarse level pulls it in */
    pb_reg_align(map, scan.data(), scan.size() / 3, pose(2.5, 1.3, 15), nullptr, &r, &err);
    CHECK((r.pose.translation() - truth.translation()).norm() < 0.01);

    /* divergence evidence: evaluating (max_iterations 0) a pose 0.5 m off gives
     * a far smaller inlier share than the true pose, though cells still match */
    pb_reg_config_t cfg;
    pb_reg_config_default(&cfg);
    cfg.max_iterations = 0;
    cfg.coarse_iterations = 0;
    pb_reg_result_t at_truth, at_wrong;
    pb_reg_align(map, scan.data(), scan.size() / 3, truth, &cfg, &at_truth, &err);
    pb_reg_align(map, scan.data(), scan.size() / 3, pose(3.2, 1.1, 12), &cfg, &at_wrong, &err);
    std::printf("inlier share at the truth %.3f (upright %.3f of %d), 0.5 m off %.3f (upright %.3f of %d)\n",
                at_truth.inlier_fraction, at_truth.upright_inlier_fraction, at_truth.upright_points,
                at_wrong.inlier_fraction, at_wrong.upright_inlier_fraction, at_wrong.upright_points);
    CHECK(at_truth.inlier_fraction > 0.8);
    CHECK(at_wrong.inlier_fraction < 0.6);   /* the ground still fits: a weak test alone */
    CHECK(at_truth.upright_inlier_fraction > 0.7);
    CHECK(at_wrong.upright_inlier_fraction < 0.2);
    CHECK(at_truth.upright_points > 200);
    CHECK(at_truth.pose.isApprox(truth));   /* evaluation only: pose unchanged */

    /* global alignment: 1.8 m and 9 degrees off, searched within 2 m / 12 deg */
    rc = pb_reg_align_global(map, scan.data(), scan.size() / 3, pose(4.6, 1.8, 21), 2.0, 12 * M_PI / 180,
                             nullptr, &r, &err);
    CHECK(rc >= 0);
    CHECK((r.pose.translation() - truth.translation()).norm() < 0.02);
    CHECK(yaw_err_deg(r.pose, truth) < 0.1);

    /* bad input */
    CHECK(pb_reg_align(map, scan.data(), 0, truth, nullptr, &r, &err) == PB_REG_BAD_INPUT);
    CHECK_CONTAINS(err.msg, "empty scan");
    Eigen::Isometry3d nan = truth;
    nan.translation()(0) = NAN;
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, nan, nullptr, &r, &err) == PB_REG_BAD_INPUT);
    CHECK(r.pose.matrix().hasNaN());   /* the guess comes back untouched */
    /* a scan far from the map matches nothing */
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, pose(500, 500, 0), nullptr, &r, &err) == PB_REG_FEW_POINTS);
    pb_regmap_destroy(map);
}

/* The window search alone: on the street (recesses fix x), from 2.5 m / 14 deg off, the
 * best candidate lies within a cell and a half (0.75 m: a point scores in its cell or a
 * neighbour's, so the score is flat a cell either way along the fronts) and a yaw step
 * of the truth, and a window holding no structure (the seed far from the street) gives
 * no candidate. */
static void test_window_search(void)
{
    std::vector<float> m;
    pb_regmap_t *map = street_map(&m, true);
    if (!map) return;
    Eigen::Isometry3d truth = pose(3.2, 0.6, 12);
    std::vector<float> scan = scan_of(m, truth), pts;
    pb_reg_config_t cfg;
    pb_reg_config_default(&cfg);
    pb_reg_downsample(scan.data(), scan.size() / 3, &cfg, &pts);
    pb_loc::window_config_t wc;
    wc.radius_m = 3.0;
    wc.yaw_range_rad = 15 * M_PI / 180;
    std::vector<pb_loc::window_candidate_t> cand;
    int points = 0;
    int nc = pb_loc::window_search(pb_loc::columns_of(map), pts.data(), pts.size() / 3, pose(5.2, -0.9, 26),
                                   wc, &cand, &points);
    CHECK(nc >= 1 && nc <= wc.candidates);
    CHECK(points == wc.max_points);   /* the fronts give more structure points than are scored */
    if (nc >= 1) {
        double e = (cand[0].pose.translation() - truth.translation()).norm();
        std::printf("window search: best of %d at %.2f m / %.2f deg from the truth, %d of %d points\n", nc, e,
                    yaw_err_deg(cand[0].pose, truth), cand[0].score, points);
        CHECK(e < 0.75);
        CHECK(yaw_err_deg(cand[0].pose, truth) < 1.0);
        CHECK(cand[0].score > points / 2);
    }
    nc = pb_loc::window_search(pb_loc::columns_of(map), pts.data(), pts.size() / 3, pose(500, 500, 0), wc, &cand,
                               &points);
    CHECK(nc == 0);
    pb_regmap_destroy(map);
}

static void test_degenerate_corridor(void)
{
    /* plain walls and ground: nothing fixes x; the result must say so */
    std::vector<float> m;
    pb_regmap_t *map = street_map(&m, false);
    if (!map) return;
    pb_err_t err;
    Eigen::Isometry3d truth = pose(0, 0.3, 0);
    std::vector<float> scan = scan_of(m, truth);
    pb_reg_result_t r;
    pb_reg_align(map, scan.data(), scan.size() / 3, pose(0.4, 0.5, 1), nullptr, &r, &err);
    CHECK(std::fabs(r.pose.translation()(1) - 0.3) < 0.01);   /* across: observable */
    CHECK(r.condition > 1e4);
    CHECK(r.covariance(0, 0) > 1e3 * r.covariance(1, 1));
    CHECK(std::fabs(r.pose.translation()(0) - 0.4) < 0.05);    /* along: stays at the guess */
    pb_regmap_destroy(map);
}

/* A prior on the guess (pb_reg_align_prior): on the corridor, the direction the walls fix
 * moves to the truth as without it, and the one nothing fixes stays at the guess; in the
 * crowns, which hold the pose only weakly, a run from near the truth stays nearer it than
 * one without. A covariance that is not positive definite is an error. */
static void test_align_prior(void)
{
    std::vector<float> m;
    pb_regmap_t *map = street_map(&m, false);
    if (!map) return;
    pb_err_t err;
    std::vector<float> scan = scan_of(m, pose(0, 0.3, 0));
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Identity();
    cov.diagonal() << 0.04, 0.04, 0.01, 1e-4, 1e-4, 1e-3;   /* 0.2 m, 0.1 m, 0.6 deg, 1.8 deg */
    pb_reg_result_t r;
    CHECK(pb_reg_align_prior(map, scan.data(), scan.size() / 3, pose(0.4, 0.5, 1), cov, nullptr, &r, &err) >= 0);
    CHECK(std::fabs(r.pose.translation()(1) - 0.3) < 0.01);   /* across: observable */
    CHECK(std::fabs(r.pose.translation()(0) - 0.4) < 0.01);   /* along: held at the guess */
    CHECK(yaw_err_deg(r.pose, pose(0, 0.3, 0)) < 0.05);
    Eigen::Matrix<double, 6, 6> bad = cov;
    bad(0, 0) = -1;
    CHECK(pb_reg_align_prior(map, scan.data(), scan.size() / 3, pose(0.4, 0.5, 1), bad, nullptr, &r, &err) == PB_REG_BAD_INPUT);
    CHECK(std::strstr(err.msg, "positive definite") != nullptr);
    pb_regmap_destroy(map);
}

/* The fits split between two threads give the same level as on one: the same cells, keys
 * and rough voxels in the same order (the street has more voxels than a split needs). */
static void test_build_split(void)
{
    std::vector<float> m;
    street(&m, true, 0, 100);
    pb_regmap_config_t cfg;
    pb_regmap_config_default(&cfg);
    pb_loc::Level one, two;
    const size_t n1 = pb_loc::build_level(m.data(), m.size() / 3, cfg.voxel_m, &cfg, &one, false);
    CHECK(n1 > 2 * 4096);
    CHECK(pb_loc::build_level(m.data(), m.size() / 3, cfg.voxel_m, &cfg, &two, true) == n1);
    CHECK(two.keys == one.keys);
    CHECK(two.cells.size() == one.cells.size() &&
          std::memcmp(two.cells.data(), one.cells.data(), one.cells.size() * sizeof(pb_loc::Cell)) == 0);
    std::vector<uint64_t> r1, r2;
    one.rough.for_each([&](uint64_t k, int32_t) { r1.push_back(k); });
    two.rough.for_each([&](uint64_t k, int32_t) { r2.push_back(k); });
    CHECK(!r1.empty() && r1 == r2);
    for (size_t i = 0; i < one.keys.size(); i += 997) CHECK(two.index.find(one.keys[i]) == (int32_t)i);
}

/* The fine cell of the voxel holding (x, y, z), or nullptr. */
static pb_loc::Cell *cell_at(pb_regmap_t *m, double x, double y, double z)
{
    const pb_loc::Cell *c = m->fine.lookup(x, y, z);
    return const_cast<pb_loc::Cell *>(c);
}

static bool same_level(const pb_loc::Level &a, const pb_loc::Level &b)
{
    std::vector<uint64_t> ra, rb;
    a.rough.for_each([&](uint64_t k, int32_t) { ra.push_back(k); });
    b.rough.for_each([&](uint64_t k, int32_t) { rb.push_back(k); });
    return a.keys == b.keys && a.cells.size() == b.cells.size() &&
           std::memcmp(a.cells.data(), b.cells.data(), a.cells.size() * sizeof(pb_loc::Cell)) == 0 && ra == rb &&
           a.roughs.size() == b.roughs.size() &&
           std::memcmp(a.roughs.data(), b.roughs.data(), a.roughs.size() * sizeof(pb_loc::Rough)) == 0;
}

/* A map built again from mostly the same points (pb_regmap_rebuild: the mapper's rolling
 * local map) is the one built from scratch, byte for byte; a voxel whose neighbourhood did
 * not change takes the earlier map's fit (seen by tampering with it), and one beside a
 * changed, removed or new voxel is fitted again. */
static void test_rebuild(void)
{
    std::vector<float> a;
    street(&a, true, 0, 60);
    std::mt19937 rng(5);
    std::normal_distribution<float> g(0, 0.6f);
    for (int i = 0; i < 3000; i++) a.insert(a.end(), {30 + g(rng), 4 + g(rng), 2 + g(rng)});   /* a bush: rough cells */
    pb_err_t err;
    pb_regmap_t *prev = pb_regmap_rebuild(nullptr, a.data(), a.size() / 3, nullptr, &err);
    CHECK(prev != nullptr);
    if (!prev) return;
    CHECK(!prev->fine.roughs.empty());
    /* the next points: the first 5 m dropped (the car moved on), one wall voxel's points
     * moved by 2 cm (x 40-41, z 3-3.5), 10 m more street appended, in the same order */
    std::vector<float> b;
    for (size_t i = 0; i < a.size(); i += 3) {
        float x = a[i], y = a[i + 1], z = a[i + 2];
        if (x < 5) continue;
        if (x >= 40 && x < 41 && y > 7.9f && y < 8.1f && z >= 3 && z < 3.5f) y += 0.02f;
        b.insert(b.end(), {x, y, z});
    }
    street(&b, true, 60, 70);
    /* and the same with a new point far away: the changed voxels' box is then too large
     * for a bitmap, and the neighbours are looked up instead */
    std::vector<float> far = b;
    far.insert(far.end(), {3000.f, 3000.f, 60.f});
    /* that lone point is no target, so both give the same levels: the fits over the bitmap
     * of the voxels there are (b) and by looking each neighbour up (far) agree */
    {
        pb_regmap_t *bits = pb_regmap_from_points(b.data(), b.size() / 3, nullptr, &err);
        pb_regmap_t *lookups = pb_regmap_from_points(far.data(), far.size() / 3, nullptr, &err);
        CHECK(bits && lookups && same_level(bits->fine, lookups->fine) && same_level(bits->coarse, lookups->coarse));
        pb_regmap_destroy(bits);
        pb_regmap_destroy(lookups);
    }
    for (const std::vector<float> *pts : {&b, &far}) {
        pb_regmap_t *scratch = pb_regmap_from_points(pts->data(), pts->size() / 3, nullptr, &err);
        pb_regmap_t *again = pb_regmap_rebuild(prev, pts->data(), pts->size() / 3, nullptr, &err);
        CHECK(scratch && again);
        if (!scratch || !again) return;
        CHECK(same_level(again->fine, scratch->fine));
        CHECK(same_level(again->coarse, scratch->coarse));
        CHECK(std::memcmp(&again->info, &scratch->info, sizeof(pb_regmap_info_t)) == 0);
        /* a map built again is built again from it in turn */
        pb_regmap_t *third = pb_regmap_rebuild(again, pts->data(), pts->size() / 3, nullptr, &err);
        CHECK(third && same_level(third->fine, scratch->fine));
        pb_regmap_destroy(third);
        /* prev tampered with: a far voxel's fit is taken from it; the voxels beside the moved
         * one (x 41-41.5), the removed ones (x 5-5.5) and the new ones (x 59.5-60) are not */
        const double kept[3] = {20.2, 8.0, 6.2};
        const double refit[3][3] = {{41.2, 8.0, 3.2}, {5.2, 8.0, 6.2}, {59.7, 8.0, 6.2}};
        pb_loc::Cell saved[4];
        pb_loc::Cell *t[4] = {cell_at(prev, kept[0], kept[1], kept[2]), nullptr, nullptr, nullptr};
        for (int k = 0; k < 3; k++) t[k + 1] = cell_at(prev, refit[k][0], refit[k][1], refit[k][2]);
        bool all = true;
        for (int k = 0; k < 4; k++) all = all && t[k];
        CHECK(all);
        if (!all) return;
        for (int k = 0; k < 4; k++) { saved[k] = *t[k]; t[k]->mean[0] += 1.0f; }
        pb_regmap_t *tampered = pb_regmap_rebuild(prev, pts->data(), pts->size() / 3, nullptr, &err);
        for (int k = 0; k < 4; k++) *t[k] = saved[k];
        CHECK(tampered != nullptr);
        if (!tampered) return;
        const pb_loc::Cell *s0 = cell_at(scratch, kept[0], kept[1], kept[2]);
        const pb_loc::Cell *k0 = cell_at(tampered, kept[0], kept[1], kept[2]);
        CHECK(s0 && k0 && k0->mean[0] == s0->mean[0] + 1.0f);
        for (int k = 0; k < 3; k++) {
            const pb_loc::Cell *sk = cell_at(scratch, refit[k][0], refit[k][1], refit[k][2]);
            const pb_loc::Cell *tk = cell_at(tampered, refit[k][0], refit[k][1], refit[k][2]);
            CHECK(sk && tk && std::memcmp(sk, tk, sizeof(pb_loc::Cell)) == 0);
        }
        pb_regmap_destroy(tampered);
        pb_regmap_destroy(again);
        pb_regmap_destroy(scratch);
    }
    /* another config: built from scratch, not from prev's fits */
    pb_regmap_config_t other;
    pb_regmap_config_default(&other);
    other.planarity_max = 0.05;
    pb_regmap_t *o1 = pb_regmap_rebuild(prev, b.data(), b.size() / 3, &other, &err);
    pb_regmap_t *o2 = pb_regmap_from_points(b.data(), b.size() / 3, &other, &err);
    CHECK(o1 && o2 && same_level(o1->fine, o2->fine));
    pb_regmap_destroy(o1);
    pb_regmap_destroy(o2);
    pb_regmap_destroy(prev);
}

/* VoxelHash::erase keeps every other key findable: keys put in a small table (long runs,
 * some wrapping past its end), half of them taken out in a random order, others put in
 * again, each step checked against a std::map. */
static void test_voxel_hash_erase(void)
{
    std::mt19937_64 rng(3);
    pb_loc::VoxelHash h(64);
    std::map<uint64_t, int32_t> ref;
    std::vector<uint64_t> keys;
    for (int i = 0; i < 3000; i++) {
        const uint64_t key = rng() >> 1;
        bool inserted;
        h.insert(key, i, &inserted);
        if (inserted) { ref[key] = i; keys.push_back(key); }
    }
    std::shuffle(keys.begin(), keys.end(), rng);
    bool all = true;
    for (size_t k = 0; k < keys.size(); k++) {
        if (k % 2 == 0) {
            all = all && h.erase(keys[k]) && !h.erase(keys[k]);
            ref.erase(keys[k]);
        } else if (k % 7 == 0) {
            bool inserted;
            h.insert(rng() >> 1, -2, &inserted);
        }
        if (k % 97 == 0)
            for (uint64_t key : keys) {
                auto it = ref.find(key);
                all = all && h.find(key) == (it == ref.end() ? -1 : it->second);
            }
    }
    CHECK(all);
    CHECK(h.size() >= ref.size());
    size_t n = 0;
    h.for_each([&](uint64_t, int32_t v) { n += v >= 0; });
    CHECK(n == ref.size());
}

static void test_regmap_errors(void)
{
    pb_err_t err;
    CHECK(pb_regmap_load("/nonexistent/site/map.pcd", nullptr, nullptr, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "/nonexistent/site/map.pcd");
    const char *bad = "/tmp/test_registration_corrupt.pcd";
    FILE *f = std::fopen(bad, "w");
    std::fputs("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\nHEIGHT 1\n"
               "POINTS 100\nDATA binary\n\x01\x02", f);
    std::fclose(f);
    CHECK(pb_regmap_load(bad, nullptr, nullptr, &err) == nullptr);
    CHECK_CONTAINS(err.msg, bad);
    const char *nox = "/tmp/test_registration_noxyz.pcd";
    f = std::fopen(nox, "w");
    std::fputs("# .PCD v0.7\nVERSION 0.7\nFIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\n"
               "POINTS 1\nDATA ascii\n1 2 3\n", f);
    std::fclose(f);
    CHECK(pb_regmap_load(nox, nullptr, nullptr, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "no x, y, z");
    pb_regmap_config_t cfg;
    pb_regmap_config_default(&cfg);
    cfg.load_radius_m = 50;
    CHECK(pb_regmap_load(nox, &cfg, nullptr, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "centre");
    std::remove(bad);
    std::remove(nox);
    CHECK(pb_regmap_from_points(nullptr, 0, nullptr, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "no map points");
}

static void test_load_radius(void)
{
    /* a PCD street 240 m long, loaded within 50 m of x = 100 */
    std::vector<float> m;
    street(&m, true, -20, 220);
    pcl::PointCloud<pcl::PointXYZ> cloud;
    for (size_t i = 0; i < m.size() / 3; i++) cloud.push_back(pcl::PointXYZ(m[3 * i], m[3 * i + 1], m[3 * i + 2]));
    const char *path = "/tmp/test_registration_street.pcd";
    CHECK(pcl::io::savePCDFileBinary(path, cloud) == 0);
    pb_regmap_config_t cfg;
    pb_regmap_config_default(&cfg);
    cfg.load_radius_m = 50;
    const double c[2] = {100, 0};
    pb_err_t err;
    pb_regmap_t *map = pb_regmap_load(path, &cfg, c, &err);
    CHECK(map != nullptr);
    if (map) {
        pb_regmap_info_t info;
        pb_regmap_info(map, &info);
        CHECK(info.min[0] >= 49.9 && info.max[0] <= 150.1);
        CHECK(pb_regmap_covers(map, 100, 0, 40) == 1);
        CHECK(pb_regmap_covers(map, 130, 0, 40) == 0);
        Eigen::Isometry3d truth = pose(104, -0.4, -5);
        std::vector<float> scan = scan_of(m, truth);
        pb_reg_result_t r;
        pb_reg_align(map, scan.data(), scan.size() / 3, pose(104.3, -0.2, -4), nullptr, &r, &err);
        CHECK((r.pose.translation() - truth.translation()).norm() < 0.01);
        pb_regmap_destroy(map);
    }
    const double far[2] = {5000, 0};
    CHECK(pb_regmap_load(path, &cfg, far, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "none of");
    std::remove(path);
}

static void test_poor_guess_settles(void)
{
    /* starts 0.36 m and 1 deg off along the street: the fine run stops early (it
     * moves more than its gate in 3 steps) and the coarse-to-fine run takes over;
     * the stopped run is finished (or, with no prior as here, ends where it reaches
     * the coarse-to-fine minimum). When the stopped run was compared unfinished it won
     * on inlier count at 6 of 11 places, 2-7 cm short along x (measured: 0.021-0.071
     * m); finished, every place ends as from the truth (max 0.0128 m, 0.0126 m since it
     * may end in the coarse-to-fine minimum; from the truth itself 0.0126 m) */
    std::vector<float> m;
    street(&m, true, -20, 220);
    pb_regmap_t *map = regmap_of(m);
    if (!map) return;
    pb_err_t err;
    double worst = 0, worst_from_truth = 0;
    for (double x = 80; x <= 120; x += 4) {
        Eigen::Isometry3d truth = pose(x, -0.4, -5);
        std::vector<float> scan = scan_of(m, truth);
        pb_reg_result_t r, rt;
        pb_reg_align(map, scan.data(), scan.size() / 3, pose(x + 0.3, -0.2, -4), nullptr, &r, &err);
        pb_reg_align(map, scan.data(), scan.size() / 3, truth, nullptr, &rt, &err);
        worst = std::max(worst, (r.pose.translation() - truth.translation()).norm());
        worst_from_truth = std::max(worst_from_truth, (rt.pose.translation() - truth.translation()).norm());
        CHECK(r.status == PB_REG_OK);
    }
    std::printf("poor guesses: worst %.4f m (from the truth %.4f m)\n", worst, worst_from_truth);
    CHECK(worst < 0.03);
    pb_regmap_destroy(map);
}

static void test_deskew(void)
{
    /* moving forward at 10 m/s and turning at 0.5 rad/s: a point seen 50 ms
     * after the reference at (10, 0, 0) was, in the reference base frame, at
     * R(0.025 rad) (10, 0, 0) + (0.5, 0, 0) */
    float xyz[6] = {10, 0, 0, 10, 0, 0};
    int32_t off[2] = {0, 50000};
    double v[3] = {10, 0, 0}, w[3] = {0, 0, 0.5};
    pb_deskew(xyz, off, 2, 0, v, w);
    CHECK_NEAR(xyz[0], 10, 1e-6);
    CHECK_NEAR(xyz[3], 10 * std::cos(0.025) + 0.5, 1e-5);
    CHECK_NEAR(xyz[4], 10 * std::sin(0.025), 1e-5);
    CHECK_NEAR(xyz[5], 0, 1e-6);
    /* reference in the middle of the sweep: earlier points move backwards */
    float p[3] = {0, 0, 0};
    int32_t o[1] = {0};
    pb_deskew(p, o, 1, 50000, v, w);
    CHECK_NEAR(p[0], -0.5, 1e-6);
}

/* Two real HDL-32E scans (fast_gicp data, BSD-3): the source aligned to the
 * target from identity must reproduce relative.txt (T_target_source) within 5 cm. */
static void test_hdl32_pair(void)
{
    std::string dir = std::string(PB_SOURCE_DIR) + "/tests/data/lidar_pair_hdl32/";
    pb_err_t err;
    pb_regmap_t *map = pb_regmap_load((dir + "251370668.pcd").c_str(), nullptr, nullptr, &err);
    CHECK(map != nullptr);
    if (!map) { std::fprintf(stderr, "%s\n", err.msg); return; }
    pcl::PointCloud<pcl::PointXYZ> src;
    CHECK(pcl::io::loadPCDFile(dir + "251371071.pcd", src) == 0);
    std::vector<float> xyz;
    for (const auto &p : src.points) { xyz.push_back(p.x); xyz.push_back(p.y); xyz.push_back(p.z); }
    Eigen::Matrix4d ref;
    FILE *f = std::fopen((dir + "relative.txt").c_str(), "r");
    CHECK(f != nullptr);
    if (!f) return;
    for (int i = 0; i < 16; i++) CHECK(std::fscanf(f, "%lf", &ref(i / 4, i % 4)) == 1);
    std::fclose(f);
    pb_reg_result_t r;
    int rc = pb_reg_align(map, xyz.data(), xyz.size() / 3, Eigen::Isometry3d::Identity(), nullptr, &r, &err);
    CHECK(rc >= 0);
    double dt = (r.pose.translation() - ref.block<3, 1>(0, 3)).norm();
    Eigen::Matrix3d dR = r.pose.linear().transpose() * ref.block<3, 3>(0, 0);
    double drot = Eigen::AngleAxisd(dR).angle() * 180 / M_PI;
    std::printf("hdl32 pair: |t - relative.txt| = %.4f m, rotation %.4f deg, inliers %.2f, %d iterations\n", dt, drot,
                r.inlier_fraction, r.iterations);
    CHECK(dt < 0.05);
    CHECK(drot < 0.5);
    /* start-up search on real data: starts 3 m off in eight directions, yaw 15 deg off
     * either way, searched within 3 m / 15 deg; and one 150 deg off, searched over the
     * full turn (a GNSS fix without heading). Each must end on the reference. The
     * search runs twice: as configured, and with every candidate refined to its end
     * (same_minimum_m 0). Candidates that stop in the best minimum so far must leave
     * the answer where the full runs put it (within 5 mm / 0.05 deg) and save steps
     * (measured: 171 against 199 in all). */
    Eigen::Isometry3d ref_pose(ref);
    pb_reg_config_t full;
    pb_reg_config_default(&full);
    full.same_minimum_m = 0;
    int on_ref = 0, starts = 0, iterations = 0, iterations_full = 0, same_answer = 0;
    double worst = 0;
    for (int k = 0; k < 9; k++) {
        Eigen::Isometry3d start = ref_pose;
        double a = k * M_PI / 4, yaw = (k % 2 ? 15 : -15) * M_PI / 180, range = 15 * M_PI / 180;
        if (k == 8) { a = 1.0; yaw = 150 * M_PI / 180; range = M_PI; }
        start.translation() += 3.0 * Eigen::Vector3d(std::cos(a), std::sin(a), 0);
        start.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * ref_pose.linear();
        rc = pb_reg_align_global(map, xyz.data(), xyz.size() / 3, start, 3.0, range, nullptr, &r, &err);
        double e = (r.pose.translation() - ref_pose.translation()).norm();
        double er = Eigen::AngleAxisd(r.pose.linear().transpose() * ref_pose.linear()).angle() * 180 / M_PI;
        worst = std::max(worst, e);
        iterations += r.iterations;
        starts++;
        on_ref += rc >= 0 && e < 0.05 && er < 0.5;
        pb_reg_result_t f;
        CHECK(pb_reg_align_global(map, xyz.data(), xyz.size() / 3, start, 3.0, range, &full, &f, &err) >= 0);
        iterations_full += f.iterations;
        double dt2 = (f.pose.translation() - r.pose.translation()).norm();
        double dr2 = Eigen::AngleAxisd(f.pose.linear().transpose() * r.pose.linear()).angle() * 180 / M_PI;
        same_answer += dt2 < 0.005 && dr2 < 0.05;
    }
    std::printf("hdl32 pair, start-up search: %d of %d starts on the reference (worst %.3f m); %d iterations, "
                "%d with every candidate refined to its end (same answer for %d)\n",
                on_ref, starts, worst, iterations, iterations_full, same_answer);
    CHECK(on_ref == starts);
    CHECK(same_answer == starts);
    CHECK(iterations < iterations_full);
    pb_regmap_destroy(map);
}

/* Tile file bytes in memory, read through the pager's callback. */
struct MemFile { std::vector<uint8_t> bytes; };
static int mem_read(void *user, uint64_t off, void *buf, size_t len)
{
    const MemFile *f = (const MemFile *)user;
    if (off > f->bytes.size() || len > f->bytes.size() - off) return -1;
    std::memcpy(buf, f->bytes.data() + off, len);
    return 0;
}

static void test_tiled_prepare(const std::vector<float> &m, const pb_regmap_t *whole);

static void test_map_tiles(void)
{
    /* a street 640 m long, driven end to end: the pager holds only the tiles near the
     * car, and every pose equals the whole map's bit for bit */
    std::vector<float> m;
    street(&m, true, -20, 620);
    /* bushes on the pavements: scattered points that fit no plane or line (rough cells,
     * which the structure test counts as map evidence) */
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1, 1);
    for (double bx = -10; bx < 610; bx += 15)
        for (int k = 0; k < 400; k++) {
            double d[3] = {u(rng), u(rng), u(rng)};
            if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > 1) continue;
            m.push_back((float)(bx + d[0])); m.push_back((float)((bx / 15 - std::floor(bx / 30) * 2 > 0.5 ? 6 : -6) + d[1]));
            m.push_back((float)(1.5 + d[2]));
        }
    pb_regmap_t *whole = regmap_of(m);
    if (!whole) return;
    pb_err_t err;
    MemFile f;
    CHECK(pb_tiles_encode(whole, 32, pb_tiles_source_t{0, 0}, {}, &f.bytes, &err) == 0);
    CHECK(pb_tiles_encode(whole, 33, pb_tiles_source_t{0, 0}, {}, &f.bytes, &err) == -1);   /* not a multiple of 2 m */
    CHECK_CONTAINS(err.msg, "multiple");
    CHECK(pb_tiles_encode(whole, 32, pb_tiles_source_t{0, 0}, {}, &f.bytes, &err) == 0);
    pb_tiles_config_t tc;
    pb_tiles_config_default(&tc);
    tc.load_radius_m = 60;   /* the scans reach 40 m */
    tc.keep_radius_m = 90;
    pb_tiles_t *t = pb_tiles_open(mem_read, &f, f.bytes.size(), "street.tiles", &tc, &err);
    CHECK(t != nullptr);
    if (!t) { pb_regmap_destroy(whole); return; }
    pb_regmap_info_t wi;
    pb_regmap_info(whole, &wi);
    int64_t max_cells = 0, max_first_half = 0, max_second_half = 0;
    int max_tiles = 0;
    int identical = 0, steps = 0, fit_identical = 0, global_identical = 0, global_steps = 0, rough_identical = 0;
    pb_reg_config_t with_rough;
    pb_reg_config_default(&with_rough);
    with_rough.rough_targets = 1;
    int64_t max_rough = 0;
    for (double x = 0; x <= 600; x += 10) {
        CHECK(pb_tiles_page(t, x, 0, &err) >= 0);
        pb_tiles_stats_t st;
        pb_tiles_stats(t, &st);
        max_cells = std::max(max_cells, st.fine_cells);
        max_tiles = std::max(max_tiles, st.tiles_loaded);
        int64_t &half = x < 300 ? max_first_half : max_second_half;
        half = std::max(half, st.fine_cells);
        Eigen::Isometry3d truth = pose(x + 0.3, -0.4, 4);
        std::vector<float> scan = scan_of(m, truth);
        pb_reg_result_t a, b;
        pb_reg_align(whole, scan.data(), scan.size() / 3, pose(x + 0.1, -0.2, 3), nullptr, &a, &err);
        pb_reg_align(pb_tiles_map(t), scan.data(), scan.size() / 3, pose(x + 0.1, -0.2, 3), nullptr, &b, &err);
        identical += a.pose.matrix() == b.pose.matrix() && a.inlier_fraction == b.inlier_fraction;
        /* with rough targets too: the bushes' Gaussians come back from the tiles as built */
        pb_reg_align(whole, scan.data(), scan.size() / 3, pose(x + 0.1, -0.2, 3), &with_rough, &a, &err);
        pb_reg_align(pb_tiles_map(t), scan.data(), scan.size() / 3, pose(x + 0.1, -0.2, 3), &with_rough, &b, &err);
        rough_identical += a.pose.matrix() == b.pose.matrix() && a.inlier_fraction == b.inlier_fraction;
        /* the start-up search too: the columns it scores are built again with each page */
        if (std::fmod(x, 100) == 0) {
            pb_reg_align_global(whole, scan.data(), scan.size() / 3, pose(x + 2.0, 1.2, 14), 3.0, 15 * M_PI / 180,
                                nullptr, &a, &err);
            pb_reg_align_global(pb_tiles_map(t), scan.data(), scan.size() / 3, pose(x + 2.0, 1.2, 14), 3.0,
                                15 * M_PI / 180, nullptr, &b, &err);
            global_identical += a.pose.matrix() == b.pose.matrix() && (a.pose.translation() - truth.translation()).norm() < 0.02;
            global_steps++;
        }
        /* the structure test (planes, lines and rough cells) gives the same fit too */
        std::vector<float> above;
        for (size_t i = 0; i < scan.size() / 3; i++)
            if (scan[3 * i + 2] > 0.7) above.insert(above.end(), &scan[3 * i], &scan[3 * i + 3]);
        double fa = pb_reg_structure_fit(whole, above.data(), above.size() / 3, truth, 0.1, 0.25);
        double fb = pb_reg_structure_fit(pb_tiles_map(t), above.data(), above.size() / 3, truth, 0.1, 0.25);
        fit_identical += fa == fb && fa > 0.9;
        max_rough = std::max(max_rough, st.rough_cells);
        steps++;
    }
    pb_tiles_stats_t st;
    pb_tiles_stats(t, &st);
    std::printf("tiles: %d tiles, whole map %lld fine cells, paged at most %lld in %d tiles (%lld in the first half of "
                "the drive, %lld in the second), %lld loads, %lld drops, %d/%d poses identical\n", st.tiles_total,
                (long long)wi.cells, (long long)max_cells, max_tiles, (long long)max_first_half,
                (long long)max_second_half, (long long)st.loads, (long long)st.drops, identical, steps);
    CHECK(identical == steps);
    CHECK(rough_identical == steps);
    CHECK(fit_identical == steps);
    std::printf("tiles: start-up search %d/%d identical to the whole map's and on the truth\n", global_identical,
                global_steps);
    CHECK(global_steps == 7 && global_identical == global_steps);
    CHECK(max_rough > 0);   /* the bushes' rough cells are paged with their tiles */
    /* measured: at most 31% of the street's cells in 12 tiles (two rows: the street
     * spans y = -9..9); a tile is held only while within keep_radius (90 m) of the car,
     * so at most 2 rows of 2 * (90 + 32) / 32 + 1 = 8 */
    CHECK(max_cells < wi.cells / 2);
    CHECK(max_tiles <= 16);
    CHECK(st.drops > 0);
    /* flat: the second half of the drive holds no more than the first */
    CHECK(max_first_half > 0 && max_second_half <= max_first_half * 11 / 10);
    CHECK(pb_tiles_page(t, 600, 0, &err) == 0);   /* nothing to do: no change */
    pb_tiles_destroy(t);

    /* the place descriptors stored with the tiles answer a query as the built ones do */
    pb_loc::places_config_t pc;
    pb_loc::places_t *built = pb_loc::places_build(whole, pc);
    CHECK(built != nullptr);
    if (built) {
        std::vector<uint8_t> pbytes;
        pb_loc::places_encode(built, &pbytes);
        MemFile pf;
        CHECK(pb_tiles_encode(whole, 32, pb_tiles_source_t{123, 456}, pbytes, &pf.bytes, &err) == 0);
        pb_tiles_t *pt = pb_tiles_open(mem_read, &pf, pf.bytes.size(), "places.tiles", &tc, &err);
        CHECK(pt != nullptr);
        std::vector<uint8_t> back;
        if (pt) {
            CHECK(pb_tiles_source(pt).bytes == 123 && pb_tiles_source(pt).crc32 == 456);
            CHECK(pb_tiles_read_places(pt, &back, &err) == 0 && back == pbytes);
            pb_tiles_destroy(pt);
        }
        char msg[200];
        pb_loc::places_t *read = pb_loc::places_decode(back.data(), back.size(), msg, sizeof msg);
        CHECK(read != nullptr && pb_loc::places_count(read) == pb_loc::places_count(built));
        if (read) {
            std::vector<float> scan = scan_of(m, pose(300.3, -0.4, 4));
            pb_loc::place_desc_t d;
            pb_loc::places_describe(built, scan.data(), scan.size() / 3, &d);
            std::vector<pb_loc::place_match_t> qa, qb;
            pb_loc::places_query(built, d, 8, &qa);
            pb_loc::places_query(read, d, 8, &qb);
            bool same = qa.size() == qb.size() && !qa.empty();
            for (size_t i = 0; same && i < qa.size(); i++)
                same = qa[i].x == qb[i].x && qa[i].y == qb[i].y && qa[i].yaw == qb[i].yaw && qa[i].distance == qb[i].distance;
            CHECK(same);
            /* the answers are distinct places: a search around one covers its neighbours
             * (with a place every metre, the best 8 would otherwise be neighbours of one or two) */
            bool apart = qa.size() == 8;
            for (size_t i = 0; i < qa.size(); i++)
                for (size_t j = 0; j < i; j++) apart &= std::hypot(qa[i].x - qa[j].x, qa[i].y - qa[j].y) >= 3.0;   /* the default separation_m */
            CHECK(apart);
            /* a car pitched on a 4 % grade sees the same place: heights are taken above
             * the ground around each bin, not above its tilted base plane (which is 1.6 m
             * off the ground 40 m ahead) */
            std::vector<float> tilted(scan.size());
            Eigen::Matrix3f pitch = Eigen::AngleAxisf(0.04f, Eigen::Vector3f::UnitY()).toRotationMatrix();
            for (size_t i = 0; i < scan.size() / 3; i++) {
                Eigen::Map<Eigen::Vector3f> to(&tilted[3 * i]);
                to = pitch * Eigen::Map<const Eigen::Vector3f>(&scan[3 * i]);
            }
            pb_loc::place_desc_t dt;
            pb_loc::places_describe(built, tilted.data(), tilted.size() / 3, &dt);
            int bins = 0, off = 0;
            for (int r = 0; r < pb_loc::PLACE_RINGS; r++)
                for (int s = 0; s < pb_loc::PLACE_SECTORS; s++) {
                    if (d.h[r][s] <= 0 && dt.h[r][s] <= 0) continue;
                    bins++;
                    off += std::fabs(d.h[r][s] - dt.h[r][s]) > 0.5;
                }
            std::printf("places: %d of %d bins with structure more than 0.5 m apart on a 4 %% pitch\n", off, bins);
            /* measured 8 of 69 (bins whose edge the tilt moves); above the tilted base
             * plane it was 55 of 114 */
            CHECK(bins > 0 && off * 100 <= bins * 30);
            pb_loc::places_destroy(read);
        }
        /* damaged descriptors: refused with the byte named, never a crash */
        std::vector<uint8_t> bad = pbytes;
        bad.resize(bad.size() - 1);
        CHECK(pb_loc::places_decode(bad.data(), bad.size(), msg, sizeof msg) == nullptr);
        CHECK_CONTAINS(msg, "byte");
        bad = pbytes;
        std::memset(bad.data() + 8, 0xff, 8);   /* ring width NaN */
        CHECK(pb_loc::places_decode(bad.data(), bad.size(), msg, sizeof msg) == nullptr);
        bad = pbytes;
        bad[7] = '3';   /* the previous version (a place every 3 m, 112 bytes each) */
        CHECK(pb_loc::places_decode(bad.data(), bad.size(), msg, sizeof msg) == nullptr);
        CHECK_CONTAINS(msg, "(PBPLACE3, this localizer reads PBPLACE4): rebuild the site's map.tiles");
        pb_loc::places_destroy(built);
    }

    /* bad files: named, with the byte offset */
    MemFile bad = f;
    CHECK(pb_tiles_open(mem_read, &bad, 100, "short.tiles", &tc, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "short.tiles: byte 0");
    bad.bytes[0] = 'X';
    CHECK(pb_tiles_open(mem_read, &bad, bad.bytes.size(), "magic.tiles", &tc, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "not a map tile file");
    bad = f;
    bad.bytes[8] = 2;   /* version 2 (place descriptors as one grid over the bounding box) */
    CHECK(pb_tiles_open(mem_read, &bad, bad.bytes.size(), "v2.tiles", &tc, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "v2.tiles: byte 8: tile file version 2, this localizer reads 4 (rebuild it with map-tiles)");
    bad = f;
    bad.bytes.resize(bad.bytes.size() - 48);   /* the last tile's cells run out of the file */
    CHECK(pb_tiles_open(mem_read, &bad, bad.bytes.size(), "cut.tiles", &tc, &err) == nullptr);
    CHECK_CONTAINS(err.msg, "out of the file");
    /* tile i's row of the table (after the 192-byte header, 32 bytes a row): its tile, where
     * its cells begin, and how many (48 bytes each; then its rough cells) */
    struct TileRow { int32_t tx, ty; uint64_t off; uint32_t fine, coarse, rough; };
    auto tile_row = [](const MemFile &file, uint32_t i) {
        const uint8_t *row = file.bytes.data() + 192 + 32 * i;
        TileRow r;
        std::memcpy(&r.tx, row, 4); std::memcpy(&r.ty, row + 4, 4); std::memcpy(&r.off, row + 8, 8);
        std::memcpy(&r.fine, row + 16, 4); std::memcpy(&r.coarse, row + 20, 4); std::memcpy(&r.rough, row + 24, 4);
        return r;
    };
    /* a damaged tile opens, and paging it in names it */
    auto page_fails = [&](MemFile &file, const char *name, const TileRow &r, const char *what) {
        pb_tiles_t *tb = pb_tiles_open(mem_read, &file, file.bytes.size(), name, &tc, &err);
        CHECK(tb != nullptr);
        if (!tb) return;
        CHECK(pb_tiles_page(tb, r.tx * 32.0 + 16, r.ty * 32.0 + 16, &err) == -1);
        CHECK_CONTAINS(err.msg, what);
        pb_tiles_destroy(tb);
    };
    bad = f;
    const TileRow first = tile_row(bad, 0);
    bad.bytes[first.off + 44] = 7;   /* a cell kind that does not exist, in the first tile */
    page_fails(bad, "kind.tiles", first, "corrupt cell");
    /* a rough cell whose Gaussian is not one (C^-1/2's first diagonal entry negative) */
    bad = f;
    uint32_t ntiles;
    std::memcpy(&ntiles, bad.bytes.data() + 12, 4);
    uint32_t i = 0;
    while (i < ntiles && tile_row(bad, i).rough == 0) i++;
    CHECK(i < ntiles);
    if (i < ntiles) {
        const TileRow r = tile_row(bad, i);
        const float neg = -1.0f;
        std::memcpy(bad.bytes.data() + r.off + 48 * ((uint64_t)r.fine + r.coarse) + 20, &neg, 4);
        page_fails(bad, "rough.tiles", r, "corrupt rough cell");
    }
    test_tiled_prepare(m, whole);
    pb_regmap_destroy(whole);
}

/* pb_tiles_point_tiles names the tiles of a point's voxel and its 8 neighbours at both
 * levels, each once, in the order of a walk by rows over the fine level's, then the coarse
 * one's new ones (the tiles' margins, and so map.tiles, follow that order): against that
 * walk written out, on points near tile borders and corners on both sides of the origin,
 * for tiles of 32 m, and of 0.5 and 1 m (a fine voxel a tile, where all 9 neighbours
 * differ; no coarse voxel fits them). */
static void test_point_tiles_walk()
{
    pb_regmap_config_t cfg;
    pb_regmap_config_default(&cfg);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> off(-1.2, 1.2);
    std::uniform_int_distribution<int> border(-4, 4);
    long same = 0, runs = 0, tiles = 0;
    for (double tile_m : {32.0, 0.5, 1.0}) {
        for (int i = 0; i < 20000; i++) {
            const float p[3] = {(float)(border(rng) * tile_m + off(rng)), (float)(border(rng) * tile_m + off(rng)),
                                (float)off(rng)};
            int32_t walk[18][2];
            int n = 0;
            for (int l = 0; l < 2; l++) {
                const double voxel = l == 0 ? cfg.voxel_m : cfg.coarse_voxel_m;
                const double k = tile_m / voxel;
                const int64_t per = std::fabs(k - std::round(k)) < 1e-9 * k && k >= 1 ? (int64_t)std::llround(k) : 0;
                if (per == 0) continue;
                const int64_t ix = (int64_t)std::floor(p[0] / voxel), iy = (int64_t)std::floor(p[1] / voxel);
                for (int dy = -1; dy <= 1; dy++)
                    for (int dx = -1; dx <= 1; dx++) {
                        const int32_t tx = (int32_t)std::floor((double)(ix + dx) / per),
                                      ty = (int32_t)std::floor((double)(iy + dy) / per);
                        bool seen = false;
                        for (int j = 0; j < n && !seen; j++) seen = walk[j][0] == tx && walk[j][1] == ty;
                        if (!seen && n < 9) { walk[n][0] = tx; walk[n][1] = ty; n++; }
                    }
            }
            int32_t got[9][2];
            const int k = pb_tiles_point_tiles(&cfg, tile_m, p, got);
            same += k == n && std::memcmp(got, walk, sizeof(int32_t) * 2 * (size_t)n) == 0;
            runs++;
            tiles += k;
        }
    }
    std::printf("point tiles: %ld of %ld points name the walk's tiles in its order (%ld tiles)\n", same, runs, tiles);
    CHECK(same == runs && tiles > 2 * runs);
}

/* The tiled preparation (map-tiles, the mapper's site step: a tile at a time from its
 * points and a margin of its neighbours') writes the whole map's file byte for byte. */
static std::vector<uint8_t> tiled_file(const std::vector<float> &m, bool margin, size_t *sent)
{
    pb_regmap_config_t cfg;
    pb_regmap_config_default(&cfg);
    pb_regmap_info_t info = pb_regmap_info_t();
    for (int a = 0; a < 3; a++) { info.min[a] = HUGE_VAL; info.max[a] = -HUGE_VAL; }
    std::map<std::pair<int32_t, int32_t>, std::vector<float>> bucket;
    *sent = 0;
    for (size_t i = 0; i < m.size() / 3; i++) {
        const float *p = &m[3 * i];
        info.points++;
        for (int a = 0; a < 3; a++) { info.min[a] = std::min(info.min[a], (double)p[a]); info.max[a] = std::max(info.max[a], (double)p[a]); }
        int32_t to[9][2];
        int k = pb_tiles_point_tiles(&cfg, 32, p, to);
        for (int j = 0; j < k; j++) {
            /* without the margin: only the tile the point's fine voxel lies in */
            if (!margin && (to[j][0] != (int32_t)std::floor(p[0] / 32) || to[j][1] != (int32_t)std::floor(p[1] / 32))) continue;
            bucket[{to[j][0], to[j][1]}].insert(bucket[{to[j][0], to[j][1]}].end(), p, p + 3);
            (*sent)++;
        }
    }
    std::vector<pb_tiles_row_t> rows;
    std::vector<uint8_t> body, head;
    std::vector<std::vector<float>> cell_xyz;
    std::vector<std::vector<uint8_t>> cell_ground;
    pb_err_t err;
    for (const auto &b : bucket) {
        pb_tiles_row_t row;
        std::vector<float> x;
        std::vector<uint8_t> g;
        CHECK(pb_tiles_prepare_tile(&cfg, 32, b.first.first, b.first.second, b.second.data(), b.second.size() / 3, &row,
                                    &body, &x, &g, &err) == 0);
        if (row.fine + row.coarse + row.rough == 0) continue;
        rows.push_back(row);
        info.cells += row.fine;
        info.coarse_cells += row.coarse;
        cell_xyz.push_back(x);
        cell_ground.push_back(g);
    }
    /* the places from the tiles' cells, in another order than the tiles' (any order gives the same) */
    pb_loc::places_config_t pc;
    pb_loc::places_builder_t *pb = pb_loc::places_builder_new(pc);
    for (int pass = 0; pass < 3; pass++)
        for (size_t k = cell_xyz.size(); k-- > 0;) {
            size_t n = cell_ground[k].size();
            if (pass == 0) pb_loc::places_builder_extent(pb, cell_xyz[k].data(), n);
            if (pass == 1) pb_loc::places_builder_ground(pb, cell_xyz[k].data(), cell_ground[k].data(), n);
            if (pass == 2) pb_loc::places_builder_structure(pb, cell_xyz[k].data(), cell_ground[k].data(), n);
        }
    pb_loc::places_t *places = pb_loc::places_builder_finish(pb);
    std::vector<uint8_t> pbytes;
    if (places) pb_loc::places_encode(places, &pbytes);
    pb_loc::places_destroy(places);
    CHECK(pb_tiles_encode_head(&cfg, 32, info, rows, pb_tiles_source_t{7, 9}, pbytes.size(), &head, &err) == 0);
    head.insert(head.end(), body.begin(), body.end());
    head.insert(head.end(), pbytes.begin(), pbytes.end());
    return head;
}

static void test_tiled_prepare(const std::vector<float> &m, const pb_regmap_t *whole)
{
    pb_loc::places_config_t pc;
    pb_loc::places_t *places = pb_loc::places_build(whole, pc);
    CHECK(places != nullptr);
    std::vector<uint8_t> pbytes, want;
    if (places) pb_loc::places_encode(places, &pbytes);
    pb_loc::places_destroy(places);
    pb_err_t err;
    CHECK(pb_tiles_encode(whole, 32, pb_tiles_source_t{7, 9}, pbytes, &want, &err) == 0);
    size_t sent = 0, sent_own = 0;
    std::vector<uint8_t> tiled = tiled_file(m, true, &sent);
    std::vector<uint8_t> own = tiled_file(m, false, &sent_own);
    std::printf("tiled preparation: %zu bytes, %s the whole map's; %zu points sent to tiles for %zu map points "
                "(margins); without the margins %s\n", tiled.size(), tiled == want ? "identical to" : "NOT identical to",
                sent, m.size() / 3, own == want ? "identical too (the test would not see a missing margin)" : "different");
    CHECK(tiled == want);
    CHECK(own != want);   /* the margin matters: the check can fail */
    CHECK(sent > m.size() / 3 && sent < m.size() / 3 * 2);
}

/* Position error of poses against truth after removing the best rigid motion
 * between the two sets (refinement keeps the input's frame, not the truth's). */
static double rms_after_rigid(const std::vector<Eigen::Isometry3d> &p, const std::vector<Eigen::Isometry3d> &truth)
{
    Eigen::Matrix3Xd a(3, p.size()), b(3, p.size());
    for (size_t i = 0; i < p.size(); i++) { a.col((Eigen::Index)i) = p[i].translation(); b.col((Eigen::Index)i) = truth[i].translation(); }
    Eigen::Isometry3d A(Eigen::umeyama(a, b, false));
    double s = 0;
    for (size_t i = 0; i < p.size(); i++) s += ((A * p[i]).translation() - truth[i].translation()).squaredNorm();
    return std::sqrt(s / p.size());
}

static void test_refine(void)
{
    /* 20 scans 8 m apart along a street, poses disturbed by 0.3 m / 1 degree (like a
     * SLAM estimate that disagrees with itself); refinement must bring them together */
    std::vector<float> m;
    street(&m, true, -50, 210);
    std::mt19937 rng(3);
    std::normal_distribution<double> nrm(0, 1);
    std::vector<std::vector<float>> scans;
    std::vector<Eigen::Isometry3d> truth, poses;
    for (int k = 0; k < 20; k++) {
        Eigen::Isometry3d T = pose(8.0 * k, 0.5 * std::sin(k * 0.7), 3 * std::sin(k * 0.3));
        std::vector<float> s = scan_of(m, T), thin;
        for (size_t i = 0; i + 2 < s.size(); i += 3 * 10) thin.insert(thin.end(), {s[i], s[i + 1], s[i + 2]});
        scans.push_back(thin);
        truth.push_back(T);
        Eigen::Isometry3d P = T;
        P.translation() += Eigen::Vector3d(0.3 * nrm(rng), 0.3 * nrm(rng), 0.05 * nrm(rng));
        P.linear() = Eigen::AngleAxisd(0.3 * M_PI / 180 * nrm(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix() * P.linear();
        poses.push_back(P);
    }
    double before = rms_after_rigid(poses, truth);
    pb_refine_report_t rep;
    pb_err_t err;
    CHECK(pb_refine_poses(scans, &poses, nullptr, &rep, nullptr, nullptr, &err) == 0);
    double after = rms_after_rigid(poses, truth);
    std::vector<double> loo = rep.loo_m;
    std::sort(loo.begin(), loo.end());
    std::printf("refine: %d rounds, rms error (modulo one rigid motion) %.3f -> %.4f m; leave-one-out median %.4f m; "
                "fit %.3f -> %.3f (scan 10)\n", rep.rounds, before, after, loo[loo.size() / 2], rep.fit_before[10],
                rep.fit_after[10]);
    /* measured: 0.403 -> 0.221 m (the street repeats its recesses every 7 and 11 m, so
     * some groups of scans settle one recess or a fraction of a degree off together),
     * leave-one-out median 0.011 m, 5 rounds */
    CHECK(before > 0.2);
    CHECK(after < 0.7 * before);
    CHECK(loo[loo.size() / 2] < 0.033);
    CHECK(rep.fit_after[10] > rep.fit_before[10]);
    /* bad input: named */
    std::vector<Eigen::Isometry3d> two(2);
    CHECK(pb_refine_poses(scans, &two, nullptr, &rep, nullptr, nullptr, &err) == -1);
    CHECK_CONTAINS(err.msg, "refine");
}

/* The car's own body (roof returns from a low mount) is dropped by the body box; a point
 * outside it at the same range from base is kept (the 2 m sphere alone keeps both). */
/* Foliage: flat ground and 60 tree crowns around the car, each a shell of leaves 1.5-2.5 m
 * in radius and 0.5 m thick (no plane or line in them: rough cells); the scan draws other
 * points from the same crowns, as a LiDAR's returns from leaves differ from pass to pass.
 * The ground fixes z, roll and pitch only, so x, y and yaw come from the crowns' Gaussians
 * (rough targets) or from nothing. */
static void test_foliage(void)
{
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-1, 1);
    std::normal_distribution<double> nrm(0, 1);
    std::vector<Eigen::Vector4d> crowns;   /* centre, radius */
    for (int k = 0; k < 60; k++) crowns.emplace_back(35 * u(rng), 35 * u(rng), 4.5 + 1.5 * u(rng), 2 + 0.5 * u(rng));
    auto crown_points = [&](std::vector<float> *out, const Eigen::Isometry3d &to, int each) {
        for (const Eigen::Vector4d &c : crowns)
            for (int i = 0; i < each; i++) {
                Eigen::Vector3d d(nrm(rng), nrm(rng), nrm(rng));
                Eigen::Vector3d p = to * (c.head<3>() + d.normalized() * (c(3) + 0.25 * nrm(rng)));
                out->insert(out->end(), {(float)p(0), (float)p(1), (float)p(2)});
            }
    };
    std::vector<float> m;
    for (double x = -45; x < 45; x += 0.2)
        for (double y = -45; y < 45; y += 0.2) m.insert(m.end(), {(float)x, (float)y, 0.f});
    crown_points(&m, Eigen::Isometry3d::Identity(), 1500);
    pb_regmap_t *map = regmap_of(m);
    if (!map) return;
    const Eigen::Isometry3d truth = pose(1.3, -0.7, 20);
    std::vector<float> scan;
    for (size_t i = 0; i < m.size() / 3 - 60 * 1500; i += 7) {   /* the ground, in base */
        Eigen::Vector3d p = truth.inverse() * Eigen::Vector3d(m[3 * i], m[3 * i + 1], m[3 * i + 2]);
        if (p.head<2>().norm() < 40) scan.insert(scan.end(), {(float)p(0), (float)p(1), (float)(p(2) + 0.01 * nrm(rng))});
    }
    crown_points(&scan, truth.inverse(), 800);
    const Eigen::Isometry3d guess = pose(1.3 + 0.4, -0.7 - 0.3, 22);
    pb_reg_config_t on, off;
    pb_reg_config_default(&off);
    CHECK(off.rough_targets == 0);   /* the default (see registration.h) */
    on = off;
    on.rough_targets = 1;
    pb_reg_result_t r_on, r_off;
    pb_err_t err;
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, guess, &on, &r_on, &err) >= 0);
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, guess, &off, &r_off, &err) >= 0);
    double e_on = (r_on.pose.translation() - truth.translation()).norm();
    double e_off = (r_off.pose.translation() - truth.translation()).norm();
    std::printf("foliage: from 0.5 m / 2 deg off, with rough targets %.3f m / %.3f deg, planes alone %.3f m / %.3f deg\n",
                e_on, yaw_err_deg(r_on.pose, truth), e_off, yaw_err_deg(r_off.pose, truth));
    /* measured: 0.063 m / 0.032 deg with, 0.254 m / 0.080 deg without (a few cells of the
     * crowns fit planes) */
    CHECK(e_on < 0.19);
    CHECK(yaw_err_deg(r_on.pose, truth) < 0.1);
    CHECK(e_off > 0.15);
    /* from a tracking filter's prediction near the truth, planes alone: the prior keeps the
     * run near it, where without one it ends in the crowns' biased minimum */
    const Eigen::Isometry3d near = pose(1.3 + 0.05, -0.7 + 0.03, 20.1);
    Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Identity();
    cov.diagonal() << 0.05 * 0.05, 0.05 * 0.05, 0.02 * 0.02, 1e-5, 1e-5, 3e-6;
    pb_reg_result_t r_pr, r_np;
    CHECK(pb_reg_align_prior(map, scan.data(), scan.size() / 3, near, cov, &off, &r_pr, &err) >= 0);
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, near, &off, &r_np, &err) >= 0);
    double e_pr = (r_pr.pose.translation() - truth.translation()).norm();
    double e_np = (r_np.pose.translation() - truth.translation()).norm();
    std::printf("foliage: from 6 cm / 0.1 deg off, planes alone, with a prior %.3f m, without %.3f m\n", e_pr, e_np);
    /* measured: 0.067 m with (the guess is 0.058 m off), 0.276 m without */
    CHECK(e_pr < 0.1);
    CHECK(e_np > 0.2);
    /* rough targets steer the steps but are no inliers: the same share at a given pose */
    on.max_iterations = off.max_iterations = 0;
    on.coarse_iterations = off.coarse_iterations = 0;
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, truth, &on, &r_on, &err) >= 0);
    CHECK(pb_reg_align(map, scan.data(), scan.size() / 3, truth, &off, &r_off, &err) >= 0);
    CHECK(r_on.inlier_fraction == r_off.inlier_fraction);
    pb_regmap_destroy(map);
}

static void test_body_box(void)
{
    pb_reg_config_t cfg;
    pb_reg_config_default(&cfg);
    cfg.target_points = 0;
    const float pts[] = { 1.6f, 0.3f, 1.5f,     /* on the roof, 2.2 m from base */
                          -1.6f, 0.3f, 1.5f,    /* behind the car at the same range */
                          10.0f, 2.0f, 0.5f };  /* far */
    std::vector<float> out;
    pb_reg_downsample(pts, 3, &cfg, &out);
    CHECK(out.size() == 9);
    const double box[6] = { -1.14, -0.98, -0.1, 3.6, 0.98, 1.57 };
    memcpy(cfg.body_box, box, sizeof box);
    pb_reg_downsample(pts, 3, &cfg, &out);
    CHECK(out.size() == 6);
    for (size_t i = 0; i < out.size(); i += 3) CHECK(!(out[i] > 1.0f && out[i] < 2.0f));
}

/* The yaw of a place comes from comparing the descriptors under every sector shift. Here
 * every sector holds the same mean height (one tall bin each, at a ring drawn at random
 * for each sector), so no per-sector summary can tell the shifts apart: a comparison of
 * the few shifts such a summary proposed (until 6 Dec 2026) found shift 0 or its
 * neighbours, not the true one. Unknown bins (-1) on one side only are left out. */
static void test_places_every_shift(void)
{
    pb_loc::places_config_t pc;
    pb_loc::place_desc_t a, b;
    std::mt19937 rng(5);
    int tall[pb_loc::PLACE_SECTORS];
    for (int s = 0; s < pb_loc::PLACE_SECTORS; s++) tall[s] = (int)(rng() % pb_loc::PLACE_RINGS);
    for (int r = 0; r < pb_loc::PLACE_RINGS; r++)
        for (int s = 0; s < pb_loc::PLACE_SECTORS; s++) a.h[r][s] = r == tall[s] ? 3.0f : 1.0f;
    for (int shift : { 0, 17, 30, 59 }) {
        for (int r = 0; r < pb_loc::PLACE_RINGS; r++)
            for (int s = 0; s < pb_loc::PLACE_SECTORS; s++) {
                b.h[r][(s + shift) % pb_loc::PLACE_SECTORS] = a.h[r][s];
                if ((r + s) % 5 == 0) b.h[r][(s + shift) % pb_loc::PLACE_SECTORS] = -1;   /* hidden in b */
            }
        double yaw = -1, d = pb_loc::places_compare(pc, a, b, &yaw);
        CHECK(d < 1e-9);
        CHECK(std::fabs(yaw - shift * 2 * M_PI / pb_loc::PLACE_SECTORS) < 1e-9);
        if (std::fabs(yaw - shift * 2 * M_PI / pb_loc::PLACE_SECTORS) >= 1e-9)
            std::printf("places: shift %d found as %.1f sectors (distance %.3f)\n", shift,
                        yaw / (2 * M_PI / pb_loc::PLACE_SECTORS), d);
    }
    /* nothing comparable: distance 1 */
    for (int r = 0; r < pb_loc::PLACE_RINGS; r++)
        for (int s = 0; s < pb_loc::PLACE_SECTORS; s++) b.h[r][s] = -1;
    double yaw;
    CHECK(pb_loc::places_compare(pc, a, b, &yaw) == 1.0);
}

/* Poles seen from one side (a street of poles, no walls): the map holds each pole all
 * round, a sweep only the arcs that face its LiDAR. Pulling those arcs onto the poles'
 * axes shifts the pose towards the poles (ahead here: 0.05 m along the street with
 * 0.12 m poles); with the part of the distance along the view weighed 0.3 (the mapper's
 * line_along_view) the shift is a tenth of that. The LiDAR sits 1.1 m ahead of base and
 * 1.95 m up, as on the Prius (view_xyz). */
static void test_poles_seen_from_one_side(void)
{
    std::vector<float> m, scan;
    auto add = [](std::vector<float> *v, const Eigen::Vector3d &p) { for (int a = 0; a < 3; a++) v->push_back((float)p(a)); };
    for (double x = -30; x < 30; x += 0.1)
        for (double y = -10; y < 10; y += 0.1) add(&m, Eigen::Vector3d(x, y, 0));
    const double r = 0.12;   /* a lamp post; a line in 1 m cells (the mapper's odometry) */
    std::vector<Eigen::Vector2d> axes;
    for (double x = -16; x <= 24; x += 8)
        for (double y : {-4.5, 5.5}) axes.push_back(Eigen::Vector2d(x + (y > 0 ? 3.5 : 0.5), y));   /* mid-cell */
    for (const Eigen::Vector2d &c : axes)
        for (double z = 0.05; z < 4; z += 0.1)
            for (int k = 0; k < 36; k++) {
                double a = k * M_PI / 18;
                add(&m, Eigen::Vector3d(c(0) + r * std::cos(a), c(1) + r * std::sin(a), z));
            }
    const Eigen::Isometry3d truth = pose(2.0, 0.4, 3);
    const Eigen::Vector3d lidar(1.1, 0, 1.95);
    const Eigen::Vector3d eye = truth * lidar;
    const Eigen::Isometry3d Ti = truth.inverse();
    for (size_t i = 0; i < m.size() / 3; i++) {
        Eigen::Vector3d p(m[3 * i], m[3 * i + 1], m[3 * i + 2]);
        if (p(2) > 0.01) {   /* a pole's point: only the half that faces the LiDAR is seen */
            size_t k = 0;
            while ((axes[k] - p.head<2>()).norm() > r + 0.01) k++;
            if ((p.head<2>() - axes[k]).dot(eye.head<2>() - axes[k]) <= 0) continue;
        } else if ((p - eye).head<2>().norm() > 25 || i % 3) {
            continue;
        }
        add(&scan, Ti * p);
    }
    pb_regmap_config_t mc;
    pb_regmap_config_default(&mc);
    mc.voxel_m = 1.0;
    pb_err_t err;
    pb_regmap_t *map = pb_regmap_from_points(m.data(), m.size() / 3, &mc, &err);
    CHECK(map != nullptr);
    if (!map) return;
    pb_regmap_info_t info;
    pb_regmap_info(map, &info);
    CHECK(info.cells - info.planar_cells >= 3 * (int64_t)axes.size());   /* each pole 3 lines (its foot is the ground's plane) */
    pb_reg_config_t cfg;
    pb_reg_config_default(&cfg);
    cfg.line_along_view = 0.3;   /* the mapper's */
    for (int a = 0; a < 3; a++) cfg.view_xyz[a] = lidar(a);
    pb_reg_result_t res;
    int rc = pb_reg_align(map, scan.data(), scan.size() / 3, pose(2.25, 0.3, 2), &cfg, &res, &err);
    Eigen::Vector3d e = truth.inverse() * res.pose.translation();
    std::printf("poles seen from one side: error along %.4f m, across %.4f m, yaw %.4f deg (rc %d)\n", e(0), e(1),
                yaw_err_deg(res.pose, truth), rc);
    CHECK(rc == PB_REG_OK || rc == PB_REG_MAX_ITER);
    /* measured 0.0056 m along, 0.0004 m across, 0.027 deg (the part along the view left out:
     * 0.0014 m along); both parts at full weight gave 0.052 m along */
    CHECK(std::fabs(e(0)) < 0.015);
    CHECK(std::fabs(e(1)) < 0.002);
    CHECK(yaw_err_deg(res.pose, truth) < 0.08);
    pb_regmap_destroy(map);
}

int main(void)
{
    test_body_box();
    test_align_street();
    test_degenerate_corridor();
    test_align_prior();
    test_regmap_errors();
    test_build_split();
    test_rebuild();
    test_voxel_hash_erase();
    test_load_radius();
    test_poor_guess_settles();
    test_foliage();
    test_poles_seen_from_one_side();
    test_deskew();
    test_hdl32_pair();
    test_window_search();
    test_point_tiles_walk();
    test_map_tiles();
    test_places_every_shift();
    test_refine();
    return pb_check_report("test_registration");
}
