/* The road under what moved (modules/mapper/core/under.h): a tyre stood on the road for two
 * sweeps of twelve. The map's voxels are made by the real map builder; the road voxels its
 * bottom returns fell in must come out as the builder makes them from the road's returns
 * alone, a voxel only the tyre's bottom filled goes, and nothing else moves: the road away
 * from the tyre, a post's foot beside it higher than road_max_m, a voxel whose point lies
 * higher than road_max_m (a kerb's top) though its lowest returns were under a body, the
 * road under a carved voxel higher than body_max_m, and everything when there is no ground
 * model. A low return whose beam just above, in the same column of the sweep, ended on a
 * nearer body goes without a body return near it (and stays when the columns are not known).
 * A carved voxel hit over more than body_span_s is no body; a tyre's return higher than the
 * road's band but within return_max_m goes from a lifted road voxel. A voxel lifted over all
 * the road round it where a body stood goes, alone or in a patch of two (pb_under_bumps); a kerb's, a post's, one over
 * road seen sparsely, one away from the body's columns, and a ditch's edge stay. A voxel of
 * the road band hit in one sweep goes beside road seen for seconds (pb_under_look).
 * pb_map_builder_place_timed places a scan's points as pb_map_builder_add_timed does. */
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <map>
#include <vector>

#include "mapper/core/under.h"
#include "pb_check.h"
#include "pb_map_build.h"

static const double kVoxel = 0.15;

struct Scene {
    std::vector<std::vector<double>> sweeps;   /* x y z per return */
    std::vector<double> road, tyre_low, alone, under_road;   /* returns: see scene() */
};

/* A point cloud's voxels as the builder makes them: key -> (x y z i, n). */
static std::map<uint64_t, std::pair<std::vector<float>, uint32_t>> voxels_of(const std::vector<double> &xyz)
{
    pb_map_builder_t *b = pb_map_builder_create_tiled(kVoxel, 64, nullptr);
    pb_points_t pts = {};
    std::vector<float> x, y, z, in;
    for (size_t i = 0; i < xyz.size(); i += 3) {
        x.push_back((float)xyz[i]); y.push_back((float)xyz[i + 1]); z.push_back((float)xyz[i + 2]); in.push_back(0);
    }
    pts.n = (int)x.size(); pts.x = x.data(); pts.y = y.data(); pts.z = z.data(); pts.intensity = in.data();
    pb_transform_t id = {{0, 0, 0}, {1, 0, 0, 0}};
    pb_map_builder_add(b, &pts, &id, nullptr);
    std::map<uint64_t, std::pair<std::vector<float>, uint32_t>> out;
    std::vector<int32_t> tiles(2 * (size_t)pb_map_builder_tiles(b, nullptr, 0));
    pb_map_builder_tiles(b, tiles.data(), (int)tiles.size() / 2);
    for (size_t t = 0; t < tiles.size(); t += 2) {
        std::vector<pb_map_voxel_t> v((size_t)pb_map_builder_tile_size(b, tiles[t], tiles[t + 1]));
        pb_map_builder_tile_take(b, tiles[t], tiles[t + 1], v.data());
        for (const pb_map_voxel_t &vx : v) {
            std::vector<float> p(4);
            pb_map_voxel_point(b, &vx, p.data());
            out[vx.key] = {p, vx.n};
        }
    }
    pb_map_builder_destroy(b);
    return out;
}

static void add(std::vector<double> *v, double x, double y, double z) { v->insert(v->end(), {x, y, z}); }

/* When each carved point's voxel was hit (first, last), as the map records it: the times of
 * the sweeps (time, x y z per return) with a return in it; INT64_MAX, INT64_MIN for none. */
static std::vector<int64_t> hits_of(const std::vector<float> &carved,
                                    const std::vector<std::pair<int64_t, std::vector<double>>> &timed)
{
    std::vector<int64_t> hit;
    for (size_t i = 0; i < carved.size(); i += 3) {
        uint64_t key, k;
        CHECK(pb_map_voxel_key(kVoxel, carved[i], carved[i + 1], carved[i + 2], &key) == 0);
        int64_t first = INT64_MAX, last = INT64_MIN;
        for (const auto &t : timed)
            for (size_t j = 0; j < t.second.size(); j += 3)
                if (pb_map_voxel_key(kVoxel, t.second[j], t.second[j + 1], t.second[j + 2], &k) == 0 && k == key) {
                    first = std::min(first, t.first);
                    last = std::max(last, t.first);
                }
        hit.insert(hit.end(), {first, last});
    }
    return hit;
}

/* The carving's points over the ground, told when the map's sweeps hit them, then the read of
 * a drive whose sweeps come 0.1 s apart (from dt_us: another rate). */
static pb_under_t *read_drive(const std::vector<float> &carved, const pb_ground_t *ground,
                              const std::vector<std::vector<double>> &sweeps, int64_t dt_us = 100000)
{
    std::vector<std::pair<int64_t, std::vector<double>>> timed;
    for (size_t k = 0; k < sweeps.size(); k++) timed.push_back({(int64_t)k * dt_us, sweeps[k]});
    const std::vector<int64_t> hit = hits_of(carved, timed);
    pb_under_t *u = pb_under_create(carved.data(), carved.size() / 3, 3, hit.data(), kVoxel, ground, nullptr);
    for (const auto &w : sweeps) pb_under_sweep(u, w.data(), w.size() / 3);
    return u;
}

/* Twelve sweeps of the road (x -1 .. 2, y -1 .. 2, a return per voxel per sweep, 5 mm over the
 * ground; never two patches under a car: x 0.45 .. 0.6 and 0.6 .. 0.75, y 1.05 .. 1.2); sweeps
 * 5 and 6 also see a tyre's face at x 0.5, y 0.4 .. 1.0, z 0 .. 0.66 (its bottom 12 cm in the
 * road's voxels; the road behind it hidden), under the car the first patch's tyre bottom (6 cm
 * over the ground) and the second patch's road, and a bus's side at 2.5 m over x 1.8, y -0.9.
 * A post's foot at 0.35 m beside the tyre (x 0.62, y 0.2), every sweep. scene.road: the
 * returns of the voxels the tyre lifted as they should be: where the tyre stood (its columns,
 * 0.25 m, and their neighbours: x 0.25 .. 1.0, y 0 .. 1.25) the road's returns of sweeps 5
 * and 6 are taken out with the tyre's. */
static Scene scene()
{
    Scene s;
    for (int k = 0; k < 12; k++) {
        std::vector<double> w;
        const bool tyre = k == 5 || k == 6;
        for (int i = 0; i <= 20; i++)
            for (int j = 0; j <= 20; j++) {
                /* off the voxels' and columns' edges */
                const double x = -0.97 + 0.15 * i + 0.001 * k, y = -0.958 + 0.15 * j;
                if (tyre && x > 0.5 && x < 0.8 && y > 0.4 && y < 1.0) continue;   /* behind the tyre */
                if (x >= 0.45 && x < 0.75 && y >= 1.05 && y < 1.2) continue;      /* under the car */
                add(&w, x, y, 0.005);
                if (!(tyre && x >= 0.25 && x < 1.0 && y >= 0 && y < 1.25)) add(&s.road, x, y, 0.005);
            }
        add(&w, 0.62, 0.2, 0.35);
        if (tyre)
            for (double y = 0.41; y < 1.0; y += 0.03)
                for (double z = 0.0; z < 0.66; z += 0.03) {
                    add(&w, 0.5, y, z + 0.001 * k);
                    if (z + 0.001 * k <= 0.3) add(&s.tyre_low, 0.5, y, z + 0.001 * k);
                }
        if (tyre) {
            for (double y = 1.07; y < 1.18; y += 0.02) {
                add(&w, 0.52, y, 0.06);
                add(&s.alone, 0.52, y, 0.06);
                add(&w, 0.67, y, 0.005);
                add(&s.under_road, 0.67, y, 0.005);
            }
            for (double x = 1.8; x < 2.0; x += 0.05) add(&w, x, -0.9, 2.5);
        }
        s.sweeps.push_back(w);
    }
    return s;
}

int main()
{
    pb_ground_t *ground = pb_ground_create(-5, -5, 0.5, 21, 21);
    for (int i = 0; i < 21; i++)
        for (int j = 0; j < 21; j++) pb_ground_set(ground, i, j, 0.0);
    const Scene s = scene();
    std::vector<double> all;
    for (const auto &w : s.sweeps) all.insert(all.end(), w.begin(), w.end());
    auto map = voxels_of(all);
    /* the carving took the tyre's voxels over 0.15 m and the bus's side */
    std::vector<float> carved;
    for (const auto &v : map)
        if (v.second.first[2] > 0.15 && !(std::fabs(v.second.first[0] - 0.62f) < 0.1 && std::fabs(v.second.first[1] - 0.2f) < 0.1))
            carved.insert(carved.end(), v.second.first.begin(), v.second.first.begin() + 3);
    CHECK(carved.size() / 3 > 20);
    auto run = [&](const pb_ground_t *g) { return read_drive(carved, g, s.sweeps); };
    pb_under_t *u = run(ground);
    /* what each kept voxel should be: the builder's voxels of the road alone (and the post) */
    std::vector<double> road = s.road;
    for (int k = 0; k < 12; k++) add(&road, 0.62, 0.2, 0.35);
    auto want = voxels_of(road);
    auto mixed = voxels_of(s.tyre_low), alone = voxels_of(s.alone), under_road = voxels_of(s.under_road);
    size_t moved = 0, gone = 0, same = 0, right = 0, wrong = 0;
    for (const auto &v : map) {
        if (v.second.first[2] > 0.15 && !(std::fabs(v.second.first[0] - 0.62f) < 0.1)) continue;   /* carved */
        float p[4] = {v.second.first[0], v.second.first[1], v.second.first[2], v.second.first[3]};
        const uint32_t left = pb_under_adjust(u, p, v.second.second);
        if (left == 0) {
            gone++;
            if (!alone.count(v.first) || want.count(v.first)) wrong++;
            continue;
        }
        if (left == v.second.second) same++;
        else moved++;
        /* a voxel left must be the road's (and the post's) returns alone where it was lifted,
         * else as it was */
        const bool lifted = v.second.first[2] > 0.03f;
        auto w = want.find(v.first);
        const std::vector<float> &q = lifted && w != want.end() ? w->second.first : v.second.first;
        const uint32_t nq = lifted && w != want.end() ? w->second.second : v.second.second;
        const bool ok = (!lifted || w != want.end()) && left == nq && std::fabs(p[0] - q[0]) < 1e-5 &&
                        std::fabs(p[1] - q[1]) < 1e-5 && std::fabs(p[2] - q[2]) < 1e-5;
        (ok ? right : wrong)++;
    }
    std::printf("voxels: %zu moved, %zu gone, %zu unchanged; %zu as the road alone, %zu wrong\n", moved, gone, same, right, wrong);
    /* every road voxel the tyre's bottom reached moved back onto the road */
    size_t mixed_road = 0;
    for (const auto &m : mixed)
        if (want.count(m.first) && m.second.first[2] < 0.15f) mixed_road++;
    CHECK(mixed_road >= 4);
    /* the road under the car, on the ground: as it was */
    CHECK(under_road.size() == 1);
    for (const auto &v : under_road) {
        float p[4] = {v.second.first[0], v.second.first[1], v.second.first[2], v.second.first[3]};
        CHECK(pb_under_adjust(u, p, v.second.second) == v.second.second && p[2] == v.second.first[2]);
    }
    CHECK(moved >= mixed_road);
    CHECK(gone == alone.size() && gone == 1);
    CHECK(wrong == 0);
    CHECK(right == moved + same);
    /* the post's foot and the road under the bus's side (2.5 m: higher than body_max_m) kept */
    float post[4];
    for (const auto &v : map)
        if (std::fabs(v.second.first[0] - 0.62f) < 0.1f && std::fabs(v.second.first[1] - 0.2f) < 0.1f && v.second.first[2] > 0.3f) {
            std::copy(v.second.first.begin(), v.second.first.end(), post);
            CHECK(pb_under_adjust(u, post, v.second.second) == v.second.second);
        }
    float bus_road[4] = {1.85f, -0.9f, 0.01f, 0};
    CHECK(pb_under_adjust(u, bus_road, 12) == 12);
    uint64_t returns, voxels;
    pb_under_counts(u, &returns, &voxels);
    CHECK(returns > 0 && voxels >= moved + gone);
    pb_under_destroy(u);
    /* a sweep when no body was hit takes nothing (pb_under_busy): the tyre was hit in sweeps 5
     * and 6 only, and a read of those two alone leaves every voxel as the read of all twelve */
    {
        std::vector<std::pair<int64_t, std::vector<double>>> timed;
        for (size_t k = 0; k < s.sweeps.size(); k++) timed.push_back({(int64_t)k * 100000, s.sweeps[k]});
        const std::vector<int64_t> hit = hits_of(carved, timed);
        pb_under_t *every = read_drive(carved, ground, s.sweeps);
        pb_under_t *busy = pb_under_create(carved.data(), carved.size() / 3, 3, hit.data(), kVoxel, ground, nullptr);
        std::vector<int> read;
        for (const auto &t : timed)
            if (pb_under_busy(busy, t.first)) {
                read.push_back((int)(t.first / 100000));
                pb_under_sweep(busy, t.second.data(), t.second.size() / 3);
            }
        CHECK(read == std::vector<int>({5, 6}));
        CHECK(pb_under_busy(busy, 550000) && !pb_under_busy(busy, 499999) && !pb_under_busy(busy, 600001));
        size_t differ = 0, changed = 0;
        for (const auto &v : map) {
            float p[4], q[4];
            std::copy(v.second.first.begin(), v.second.first.end(), p);
            std::copy(v.second.first.begin(), v.second.first.end(), q);
            const uint32_t a = pb_under_adjust(every, p, v.second.second), b = pb_under_adjust(busy, q, v.second.second);
            differ += a != b || std::memcmp(p, q, sizeof p) != 0;
            changed += a != v.second.second;
        }
        std::printf("busy sweeps: %zu of %zu read, %zu voxels changed by both, %zu differ\n", read.size(), s.sweeps.size(),
                    changed, differ);
        CHECK(changed >= 5 && differ == 0);
        pb_under_destroy(every);
        pb_under_destroy(busy);
    }
    /* a body over body_max_m marks nothing: the bus's side alone taken as carved */
    {
        std::vector<float> bus;
        for (double x = 1.8; x < 2.0; x += 0.05) bus.insert(bus.end(), {(float)x, -0.9f, 2.5f});
        pb_under_t *b = read_drive(bus, ground, s.sweeps);
        pb_under_counts(b, &returns, &voxels);
        CHECK(returns == 0);
        pb_under_destroy(b);
    }
    /* a voxel higher than the road's band (a kerb's top beside a car, 0.2-0.25 m over the
     * ground) keeps its lowest returns; one in the band (0.09 m) loses them */
    for (int i = 15; i <= 18; i++)
        for (int j = 15; j <= 18; j++) pb_ground_set(ground, i, j, 0.02);   /* 2 cm higher round (3, 3) */
    for (double top : {0.29, 0.12}) {
        std::vector<float> car = {3.05f, 3.05f, 0.6f};
        const std::vector<double> w = {3.05, 3.05, 0.6, 3.1, 3.1, top == 0.29 ? 0.16 : 0.03};   /* 0.14 / 0.01 over it */
        pb_under_t *b = read_drive(car, ground, {w, w});
        /* the voxel: 10 returns at `top`, 2 low ones (taken) */
        const float z = top == 0.29 ? (float)((10 * 0.29 + 2 * 0.16) / 12) : (float)((10 * 0.12 + 2 * 0.03) / 12);
        float p[4] = {3.1f, 3.1f, z, 0};
        const uint32_t left = pb_under_adjust(b, p, 12);
        uint64_t taken, voxels;
        pb_under_counts(b, &taken, &voxels);
        CHECK(taken == 2);
        CHECK(top == 0.29 ? left == 12 && p[2] == z : left == 10 && std::fabs(p[2] - 0.12f) < 1e-5);
        pb_under_destroy(b);
    }
    /* a beam under a nearer car's body: the low return (a far wheel's inner face, 6 cm over the
     * ground at x 4) has no body return within 0.5 m in x-y, but the beam just above it in the
     * same column of the sweep ended on the nearer car's body (x 2.5, 1 m up): taken. The
     * same with the body return in another column, or the columns not known: kept. The LiDAR
     * at (0, 0, 1.9); the far wheel was carved at another time (where a body stood). */
    for (int kind = 0; kind < 3; kind++) {
        std::vector<float> bodies = {2.5f, 0.0f, 1.0f, 4.0f, 0.0f, 0.4f};
        const std::vector<double> w = {4.0, 0.02, 0.06, 2.5, 0.02, 1.0};
        /* the far wheel, carved, hit at another time */
        const std::vector<int64_t> hit = hits_of(bodies, {{0, w}, {500000, {4.0, 0.0, 0.4}}});
        pb_under_t *b = pb_under_create(bodies.data(), 2, 3, hit.data(), kVoxel, ground, nullptr);
        float sx[2] = {4.0f, 2.5f}, sy[2] = {0.02f, 0.02f}, sz[2] = {0.06f - 1.9f, 1.0f - 1.9f};
        int32_t column[2] = {7, kind == 1 ? 8 : 7};
        pb_points_t sweep = {};
        sweep.n = 2; sweep.x = sx; sweep.y = sy; sweep.z = sz; sweep.offset_us = kind == 2 ? nullptr : column;
        pb_under_sweep(b, w.data(), 2, &sweep);
        float p[4] = {4.0f, 0.02f, 0.035f, 0};   /* with a road return at 0.01 of another sweep */
        const uint32_t left = pb_under_adjust(b, p, 2);
        CHECK_CASE(kind == 0 ? "beam above on a body: taken" : kind == 1 ? "other column: kept" : "no columns: kept",
                   kind == 0 ? left == 1 && std::fabs(p[2] - 0.01f) < 1e-5 : left == 2);
        pb_under_destroy(b);
    }
    /* ... and kept when the sweep's "column" holds 300 returns (a keyframe without per-point
     * times: one time for all) */
    {
        std::vector<float> bodies = {2.5f, 0.0f, 1.0f, 4.0f, 0.0f, 0.4f};
        std::vector<double> w = {4.0, 0.02, 0.06, 2.5, 0.02, 1.0};
        std::vector<float> sx = {4.0f, 2.5f}, sy = {0.02f, 0.02f}, sz = {0.06f - 1.9f, 1.0f - 1.9f};
        for (int k = 0; k < 298; k++) {   /* more of the body, higher up */
            w.insert(w.end(), {2.5, 0.02 + 0.0005 * k, 1.2});
            sx.push_back(2.5f); sy.push_back(0.02f + 0.0005f * k); sz.push_back(1.2f - 1.9f);
        }
        std::vector<int32_t> column(300, 0);
        pb_points_t sweep = {};
        sweep.n = 300; sweep.x = sx.data(); sweep.y = sy.data(); sweep.z = sz.data(); sweep.offset_us = column.data();
        const std::vector<int64_t> hit = hits_of(bodies, {{0, w}});
        pb_under_t *b = pb_under_create(bodies.data(), 2, 3, hit.data(), kVoxel, ground, nullptr);
        pb_under_sweep(b, w.data(), 300, &sweep);
        float p[4] = {4.0f, 0.02f, 0.035f, 0};
        CHECK(pb_under_adjust(b, p, 2) == 2);
        pb_under_destroy(b);
    }
    /* a carved voxel is a body only when its returns all came within body_span_s (1 s): the
     * same carved voxel (0.6 m up) over a road voxel lifted by two low returns of sweeps 5 and 6,
     * hit in sweeps 5 and 6 only (0.1 s apart) / in all twelve (1.1 s: something that stands
     * there, which the carving took) / in 5 and 6 of a drive at one sweep in 1.5 s */
    for (int kind = 0; kind < 3; kind++) {
        std::vector<float> car = {-3.95f, -3.95f, 0.6f};
        std::vector<std::vector<double>> sweeps(12);
        for (int k = 0; k < 12; k++) {
            if (kind == 1 || k == 5 || k == 6) sweeps[k].insert(sweeps[k].end(), {-3.95, -3.95, 0.6});
            if (k == 5 || k == 6) sweeps[k].insert(sweeps[k].end(), {-3.97, -3.97, 0.12});
        }
        pb_under_t *b = read_drive(car, ground, sweeps, kind == 2 ? 1500000 : 100000);
        float p[4] = {-3.97f, -3.97f, (float)((6 * 0.01 + 2 * 0.12) / 8), 0};   /* with 6 road returns at 0.01 */
        CHECK_CASE(kind == 0 ? "hit within 0.1 s: a body" : kind == 1 ? "hit over 1.1 s: no body" : "hit 1.5 s apart: no body",
                   kind == 0 ? pb_under_adjust(b, p, 8) == 6 && std::fabs(p[2] - 0.01f) < 1e-5 : pb_under_adjust(b, p, 8) == 8);
        pb_under_destroy(b);
    }
    /* a lifted road voxel (the ground model 2 cm low round (3, 3)) with a tyre's returns 0.16 m
     * over the ground (higher than the voxel's band, within return_max_m): taken; a return of
     * the same voxel 0.31 m over another ground (higher than return_max_m): kept */
    for (double over : {0.16, 0.31}) {
        for (int i = 15; i <= 18; i++)
            for (int j = 15; j <= 18; j++) pb_ground_set(ground, i, j, over == 0.16 ? -0.02 : -0.17);
        std::vector<float> car = {3.05f, 3.05f, 0.6f};
        const std::vector<double> w = {3.05, 3.05, 0.6, 3.1, 3.1, 0.14};
        pb_under_t *b = read_drive(car, ground, {w, w});
        const float z = (float)((10 * 0.01 + 2 * 0.14) / 12);   /* 10 road returns at 0.01 */
        float p[4] = {3.1f, 3.1f, z, 0};
        const uint32_t left = pb_under_adjust(b, p, 12);
        CHECK_CASE(over == 0.16 ? "a tyre's return 0.16 m up in a lifted road voxel: taken" : "0.31 m up: kept",
                   over == 0.16 ? left == 10 && std::fabs(p[2] - 0.01f) < 1e-5 : left == 12 && p[2] == z);
        pb_under_destroy(b);
    }
    /* bumps (pb_under_bumps): the road round (-3, 3) a voxel a point (0.15 m), 5 mm over the
     * ground, and one voxel lifted at (-3, 3) where a body stood (a carved voxel 0.6 m over it,
     * hit within 0.1 s); it goes when it stands bump_m over all the road round it, and not:
     * 4 cm over the road round it (7 cm over the ground), 0.35 m up (higher than return_max_m), with the road as a kerb's row at its
     * height, with a post's point over it, where the road round it is seen in every other voxel
     * only (less than bump_fill), 1 m from where the body stood, or where the road round it
     * lies 10 cm under the ground model and it on it (a ditch's edge); two lifted voxels side
     * by side (a tyre's patch, no wider than bump_reach_m) go together; a row of five (0.6 m)
     * where bodies stood over all of it, and a kerb's row, are wider; one 0.55 m from the body
     * (a column beyond those round it: where its wheel may stand) goes */
    for (int kind = 0; kind < 11; kind++) {
        static const char *what[11] = {"a bump 8 cm up: gone", "4 cm over the road: kept", "0.35 m up: kept", "a kerb's row: kept",
                                      "a post over it: kept", "the road seen sparsely: kept",
                                      "1 m from the body: kept", "a ditch's edge: kept",
                                      "a patch of two voxels: gone", "a row of five (0.6 m): kept",
                                      "0.55 m from the body: gone"};
        const double bx = kind == 6 ? -2.0 : kind == 10 ? -2.45 : -3.0, by = 3.0;
        /* the row of five: bodies stood over all of it */
        std::vector<float> car = {-2.99f, 3.01f, 0.6f, -3.29f, 3.01f, 0.6f, -2.69f, 3.01f, 0.6f};
        const size_t cars = kind == 9 ? 3 : 1;
        const std::vector<double> w(car.begin(), car.begin() + 3 * cars);
        car.resize(3 * cars);
        pb_under_t *b = read_drive(car, ground, {w, w});
        std::vector<float> pts;
        size_t bump = 0;
        for (int i = 0; i <= 16; i++)
            for (int j = 0; j <= 16; j++) {
                const double x = bx - 1.2 + 0.15 * i + 0.01, y = by - 1.2 + 0.15 * j + 0.01;
                const bool here = i == 8 && j == 8;
                if (kind == 5 && !here && (i + j) % 2) continue;
                double z = kind == 7 ? -0.1 : kind == 1 ? 0.03 : 0.005;
                if (here) z = kind == 1 ? 0.07 : kind == 2 ? 0.35 : kind == 7 ? 0.04 : 0.08;
                if ((kind == 3 && i == 8) || (kind == 8 && i == 9 && j == 8) || (kind == 9 && i >= 6 && i <= 10 && j == 8))
                    z = 0.08;
                if (here) bump = pts.size() / 3;
                pts.insert(pts.end(), {(float)x, (float)y, (float)z});
                if (kind == 4 && here) pts.insert(pts.end(), {(float)x, (float)y, 0.5f});
            }
        bool near = true;
        for (size_t i = 0; i < pts.size(); i += 3)
            if (std::hypot(pts[i] - pts[3 * bump], pts[i + 1] - pts[3 * bump + 1]) <= 0.5 && kind != 6) near = near && pb_under_near(b, &pts[i]);
        std::vector<uint8_t> gone(pts.size() / 3);
        const size_t n = pb_under_bumps(b, pts.data(), pts.size() / 3, 3, gone.data());
        CHECK_CASE(what[kind], near && (kind == 0 || kind == 10 ? n == 1 && gone[bump] == 1 : kind == 8 ? n == 2 && gone[bump] == 1 : n == 0));
        pb_under_destroy(b);
    }
    /* no ground model: nothing is taken out */
    pb_under_t *none = run(nullptr);
    pb_under_counts(none, &returns, &voxels);
    CHECK(returns == 0 && voxels == 0);
    pb_under_destroy(none);

    /* place_timed places a scan's points as add_timed adds them: the same voxels */
    {
        pb_pose_track_t *track = pb_pose_track_create();
        pb_transform_t a = {{10.3, -4.2, 1.7}, {1, 0, 0, 0}}, b2 = a;
        b2.t[0] += 1.3;
        pb_quat_from_rpy(0.01, -0.02, 0.1, b2.q);
        pb_pose_track_add(track, 1000, &a);
        pb_pose_track_add(track, 101000, &b2);
        std::vector<float> x, y, z, in;
        std::vector<int32_t> off;
        for (int i = 0; i < 2000; i++) {
            const double ang = 0.0031 * i;
            x.push_back((float)(7 * std::cos(ang))); y.push_back((float)(7 * std::sin(ang))); z.push_back((float)(0.001 * i - 1));
            in.push_back((float)i);
            off.push_back(i / 20 * 1000);
        }
        x[5] = y[5] = z[5] = 0;   /* a no-return marker */
        x[6] = 90;                /* beyond the range */
        pb_points_t pts = {};
        pts.n = 2000; pts.x = x.data(); pts.y = y.data(); pts.z = z.data(); pts.intensity = in.data(); pts.offset_us = off.data();
        pb_map_builder_t *timed = pb_map_builder_create(kVoxel, nullptr), *placed = pb_map_builder_create(kVoxel, nullptr);
        pb_map_builder_set_max_range(timed, 60);
        pb_map_builder_set_max_range(placed, 60);
        CHECK(pb_map_builder_add_timed(timed, &pts, 1000, track, &a, nullptr) == 1);
        std::vector<double> xyz(3 * 2000);
        std::vector<int32_t> index(2000);
        const int n = pb_map_builder_place_timed(placed, &pts, 1000, track, &a, xyz.data(), index.data(), nullptr);
        CHECK(n == 1998 && index[5] == 7);
        /* the placed points' voxels and counts are the timed builder's */
        std::map<uint64_t, uint32_t> from_placed, from_timed;
        for (int k = 0; k < n; k++) {
            uint64_t key;
            if (pb_map_voxel_key(kVoxel, xyz[3 * k], xyz[3 * k + 1], xyz[3 * k + 2], &key) == 0) from_placed[key]++;
        }
        pb_map_builder_t *tiled = pb_map_builder_create_tiled(kVoxel, 64, nullptr);
        pb_map_builder_set_max_range(tiled, 60);
        CHECK(pb_map_builder_add_timed(tiled, &pts, 1000, track, &a, nullptr) == 1);
        std::vector<int32_t> tiles(2 * (size_t)pb_map_builder_tiles(tiled, nullptr, 0));
        pb_map_builder_tiles(tiled, tiles.data(), (int)tiles.size() / 2);
        for (size_t t = 0; t < tiles.size(); t += 2) {
            std::vector<pb_map_voxel_t> v((size_t)pb_map_builder_tile_size(tiled, tiles[t], tiles[t + 1]));
            pb_map_builder_tile_take(tiled, tiles[t], tiles[t + 1], v.data());
            for (const pb_map_voxel_t &vx : v) from_timed[vx.key] = vx.n;
        }
        pb_map_builder_destroy(tiled);
        CHECK(from_placed.size() > 100 && from_placed == from_timed);
        CHECK((int64_t)from_timed.size() == pb_map_builder_size(timed));
        /* add_placed after place_timed builds add_timed's map, byte for byte, counts and all */
        {
            pb_map_builder_t *one = pb_map_builder_create_tiled(kVoxel, 64, nullptr), *two = pb_map_builder_create_tiled(kVoxel, 64, nullptr);
            pb_map_builder_set_max_range(one, 60);
            pb_map_builder_set_max_range(two, 60);
            int64_t beyond = -1;
            for (int s = 0; s < 2; s++) {   /* twice: the second scan's points fall in voxels made by the first */
                pb_map_builder_stamp(one, (uint32_t)s);
                pb_map_builder_stamp(two, (uint32_t)s);
                CHECK(pb_map_builder_add_timed(one, &pts, 1000 + s, track, &a, nullptr) == 1);
                const int m = pb_map_builder_place_timed(two, &pts, 1000 + s, track, &a, xyz.data(), index.data(), &beyond);
                CHECK(m == 1998 && beyond == 1);
                CHECK(pb_map_builder_add_placed(two, &pts, xyz.data(), index.data(), m, beyond, nullptr) == 0);
            }
            CHECK(pb_map_builder_points_in(one) == pb_map_builder_points_in(two) && pb_map_builder_points_in(two) == 4000);
            CHECK(pb_map_builder_points_beyond(one) == 2 && pb_map_builder_points_beyond(two) == 2);
            std::vector<int32_t> t1(2 * (size_t)pb_map_builder_tiles(one, nullptr, 0)), t2(2 * (size_t)pb_map_builder_tiles(two, nullptr, 0));
            pb_map_builder_tiles(one, t1.data(), (int)t1.size() / 2);
            pb_map_builder_tiles(two, t2.data(), (int)t2.size() / 2);
            std::map<std::pair<int32_t, int32_t>, std::vector<pb_map_voxel_t>> v1, v2;
            for (int k = 0; k < 2; k++) {
                pb_map_builder_t *b = k ? two : one;
                const std::vector<int32_t> &t = k ? t2 : t1;
                for (size_t i = 0; i < t.size(); i += 2) {
                    std::vector<pb_map_voxel_t> &v = (k ? v2 : v1)[{t[i], t[i + 1]}];
                    v.resize((size_t)pb_map_builder_tile_size(b, t[i], t[i + 1]));
                    pb_map_builder_tile_take(b, t[i], t[i + 1], v.data());
                }
            }
            bool same = v1.size() == v2.size() && v1.size() > 1;
            for (const auto &kv : v1) {
                const auto it = v2.find(kv.first);
                same = same && it != v2.end() && it->second.size() == kv.second.size() &&
                       std::memcmp(it->second.data(), kv.second.data(), kv.second.size() * sizeof(pb_map_voxel_t)) == 0;
            }
            CHECK(same);
            pb_map_builder_destroy(one);
            pb_map_builder_destroy(two);
        }
        CHECK(pb_map_builder_place_timed(placed, &pts, 500000, track, &a, xyz.data(), nullptr, nullptr) == -1);
        pb_map_builder_destroy(timed);
        pb_map_builder_destroy(placed);
        pb_pose_track_destroy(track);
    }
    /* one look (pb_under_look): a voxel of the road band hit in one sweep goes beside a voxel
     * seen look_returns times over look_span_s; not beside one seen as often over a shorter
     * time or as long with fewer returns, not when hit in two sweeps, not above the band or
     * on the ground, and not with no ground model */
    {
        pb_under_t *l = pb_under_create(nullptr, 0, 3, nullptr, kVoxel, ground, nullptr);
        const pb_under_config_t c;
        const int64_t s0 = 1000000000;
        const float low[3] = {2.07f, 2.07f, 0.08f}, brief[3] = {3.07f, 2.07f, 0.08f},
                    sparse[3] = {4.07f, 2.07f, 0.08f}, twice[3] = {5.07f, 2.07f, 0.08f}, high[3] = {6.07f, 2.07f, 0.2f},
                    road[3] = {7.07f, 2.07f, 0.02f};
        CHECK(c.road_max_m < 0.2 && c.lifted_m > 0.02 && c.lifted_m < 0.08);
        const int a = pb_under_look(l, low, s0, s0), b = pb_under_look(l, brief, s0, s0), d = pb_under_look(l, sparse, s0, s0);
        CHECK(a == 0 && b == 1 && d == 2);
        CHECK(pb_under_look(l, twice, s0, s0 + 100000) == -1);
        CHECK(pb_under_look(l, high, s0, s0) == -1);
        CHECK(pb_under_look(l, road, s0, s0) == -1);
        const int64_t span = (int64_t)(c.look_span_s * 1e6);
        /* the road beside each: a voxel below and to the side */
        const float below_a[3] = {2.07f + (float)kVoxel, 2.07f, 0.0f}, below_b[3] = {3.07f, 2.07f - (float)kVoxel, 0.0f},
                    below_d[3] = {4.07f, 2.07f, -0.01f};
        pb_under_look_support(l, below_a, (uint32_t)c.look_returns, s0, s0 + span);
        pb_under_look_support(l, below_b, 100, s0, s0 + span - 1);
        pb_under_look_support(l, below_d, (uint32_t)c.look_returns - 1, s0, s0 + 10 * span);
        /* a voxel two apart is not beside it */
        const float far_b[3] = {3.07f + 2 * (float)kVoxel, 2.07f, 0.0f};
        pb_under_look_support(l, far_b, 100, s0, s0 + 10 * span);
        CHECK(pb_under_look_gone(l, a) && !pb_under_look_gone(l, b) && !pb_under_look_gone(l, d));
        CHECK(!pb_under_look_gone(l, -1) && !pb_under_look_gone(l, 3));
        pb_under_destroy(l);
        pb_under_t *none = pb_under_create(nullptr, 0, 3, nullptr, kVoxel, nullptr, nullptr);
        CHECK(pb_under_look(none, low, s0, s0) == -1);
        pb_under_destroy(none);
    }
    pb_ground_destroy(ground);
    return pb_check_report("test_mapper_under");
}
