/* Unit test of pb_map_build's tiled builder (the mapper's paging): a car's worth of
 * scans, each 2,000 points within 30 m of a sensor that drives out along x and back, added
 * to a builder of the whole map and to a tiled one whose tiles farther than 40 m from the
 * sensor are taken out and put back when it comes near again. The tiled builder's voxels,
 * in the order they were made (seq), must be the whole builder's, sums and all; each voxel's
 * stamps the first and last scan that hit it (scan s stamped s), through the paging too. */
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <thread>
#include <vector>

#include "pb_check.h"
#include "pb_map_build.h"

int main()
{
    pb_err_t err;
    const double voxel = 0.15;
    const int tile = 100;   /* voxels: 15 m */
    pb_map_builder_t *whole = pb_map_builder_create(voxel, &err), *tiled = pb_map_builder_create_tiled(voxel, tile, &err);
    std::map<std::pair<int32_t, int32_t>, std::vector<pb_map_voxel_t>> out;   /* tiles taken out */
    uint32_t rng = 12345;
    auto uni = [&] { rng = rng * 1664525u + 1013904223u; return (rng >> 8) / 16777216.0; };
    std::vector<float> x(2000), y(2000), z(2000), in(2000);
    int taken = 0, put = 0, bad = 0;
    std::map<uint64_t, std::pair<uint32_t, uint32_t>> hit;   /* voxel -> first and last scan, counted here */
    for (int s = 0; s < 200; s++) {
        const double cx = s < 100 ? 2.0 * s : 2.0 * (199 - s);   /* out 200 m and back */
        for (int i = 0; i < 2000; i++) {
            double a = 2 * M_PI * uni(), r = 30 * std::sqrt(uni());
            x[i] = (float)(r * std::cos(a)); y[i] = (float)(r * std::sin(a)); z[i] = (float)(3 * uni()); in[i] = (float)uni();
            uint64_t key;
            CHECK(pb_map_voxel_key(voxel, cx + x[i], y[i], z[i], &key) == 0);
            auto h = hit.emplace(key, std::make_pair((uint32_t)s, (uint32_t)s)).first;
            h->second.second = (uint32_t)s;
        }
        pb_points_t pts = {};
        pts.n = 2000; pts.x = x.data(); pts.y = y.data(); pts.z = z.data(); pts.intensity = in.data();
        pb_transform_t T = {{cx, 0, 0}, {1, 0, 0, 0}};
        /* the tiles within 40 m put back, then the scan, then the tiles beyond taken out */
        for (auto it = out.begin(); it != out.end();) {
            const double tx = (it->first.first + 0.5) * tile * voxel;
            if (std::fabs(tx - cx) < 40) {
                bad += pb_map_builder_put(tiled, it->second.data(), it->second.size(), &err) != 0;
                put++;
                it = out.erase(it);
            } else {
                ++it;
            }
        }
        pb_map_builder_stamp(whole, (uint32_t)s);
        pb_map_builder_stamp(tiled, (uint32_t)s);
        CHECK_OK(pb_map_builder_add(whole, &pts, &T, &err), err.msg);
        CHECK_OK(pb_map_builder_add(tiled, &pts, &T, &err), err.msg);
        std::vector<int32_t> xy(2 * (size_t)pb_map_builder_tiles(tiled, nullptr, 0));
        pb_map_builder_tiles(tiled, xy.data(), (int)(xy.size() / 2));
        for (size_t i = 0; i < xy.size(); i += 2) {
            const double tx = (xy[i] + 0.5) * tile * voxel;
            if (std::fabs(tx - cx) < 40) continue;
            std::vector<pb_map_voxel_t> &v = out[{xy[i], xy[i + 1]}];
            CHECK(v.empty());   /* a tile is either held or out */
            v.resize((size_t)pb_map_builder_tile_size(tiled, xy[i], xy[i + 1]));
            pb_map_builder_tile_take(tiled, xy[i], xy[i + 1], v.data());
            taken++;
        }
    }
    /* every voxel: those still held and those out, by seq */
    std::vector<int32_t> xy(2 * (size_t)pb_map_builder_tiles(tiled, nullptr, 0));
    pb_map_builder_tiles(tiled, xy.data(), (int)(xy.size() / 2));
    for (size_t i = 0; i < xy.size(); i += 2) {
        std::vector<pb_map_voxel_t> &v = out[{xy[i], xy[i + 1]}];
        size_t at = v.size();
        v.resize(at + (size_t)pb_map_builder_tile_size(tiled, xy[i], xy[i + 1]));
        pb_map_builder_tile_take(tiled, xy[i], xy[i + 1], v.data() + at);
    }
    std::vector<pb_map_voxel_t> all;
    for (const auto &t : out) all.insert(all.end(), t.second.begin(), t.second.end());
    std::sort(all.begin(), all.end(), [](const pb_map_voxel_t &a, const pb_map_voxel_t &b) { return a.seq < b.seq; });
    const int64_t n = pb_map_builder_size(whole);
    size_t same = 0;
    /* the whole builder's PCD order is its voxels' order: compare point by point */
    const char *path = "/tmp/test_map_build_whole.pcd";
    CHECK_OK(pb_map_builder_write_pcd(whole, path, &err), err.msg);
    FILE *f = std::fopen(path, "rb");
    char line[256];
    while (f && std::fgets(line, sizeof line, f) && std::strcmp(line, "DATA binary\n") != 0) {}
    std::vector<float> pcd(4 * (size_t)n);
    CHECK(f && std::fread(pcd.data(), sizeof(float), pcd.size(), f) == pcd.size());
    if (f) std::fclose(f);
    std::remove(path);
    size_t stamped = 0;
    for (size_t i = 0; i < all.size() && i < (size_t)n; i++) {
        float p[4];
        pb_map_voxel_point(tiled, &all[i], p);
        same += all[i].seq == i && std::memcmp(p, &pcd[4 * i], sizeof p) == 0;
        auto h = hit.find(all[i].key);
        stamped += h != hit.end() && all[i].first == h->second.first && all[i].last == h->second.second;
    }
    std::printf("%lld voxels; tiles taken out %d times, put back %d times; %zu of %zu the same, in the same order\n",
                (long long)n, taken, put, same, all.size());
    CHECK(taken > 20 && put > 10 && bad == 0);
    CHECK((int64_t)all.size() == n && (int64_t)same == n);
    std::printf("%zu of %zu voxels stamped with their first and last scan\n", stamped, all.size());
    CHECK(stamped == all.size() && hit.size() == all.size());
    CHECK(std::any_of(all.begin(), all.end(), [](const pb_map_voxel_t &v) { return v.last - v.first > 100; }));   /* passed on the way back */
    /* a voxel held already is refused */
    pb_map_voxel_t v = all[0];
    CHECK(pb_map_builder_put(tiled, &v, 1, &err) == 0);
    CHECK(pb_map_builder_put(tiled, &v, 1, &err) == -1);
    CHECK_CONTAINS(err.msg, "put back while held");
    pb_map_builder_destroy(whole);
    pb_map_builder_destroy(tiled);
    /* a range limit: the points farther than it from the sensor are left out and counted (the
     * frame's origin is the sensor's, wherever the scan is placed) */
    {
        float px[4] = {3, 0, 59.9f, 70}, py[4] = {4, 0, 0, 0}, pz[4] = {0, 0, 0, 1}, pi[4] = {1, 1, 1, 1};
        pb_points_t four = {};
        four.n = 4; four.x = px; four.y = py; four.z = pz; four.intensity = pi;
        pb_transform_t far = {{1000, 0, 0}, {1, 0, 0, 0}};
        pb_map_builder_t *b = pb_map_builder_create(0, &err);
        pb_map_builder_set_max_range(b, 60);
        CHECK_OK(pb_map_builder_add(b, &four, &far, &err), err.msg);
        /* (0, 0, 0) is no return, (70, 0, 1) beyond 60 m */
        CHECK(pb_map_builder_size(b) == 2 && pb_map_builder_points_beyond(b) == 1);
        pb_map_builder_set_max_range(b, 0);
        CHECK_OK(pb_map_builder_add(b, &four, &far, &err), err.msg);
        CHECK(pb_map_builder_size(b) == 5 && pb_map_builder_points_beyond(b) == 1);
        pb_map_builder_destroy(b);
    }
    {
        /* a track added to out of order, then read by two threads at once from its first read
         * (the mapper's map pass places a sweep on one thread while it looks up the next
         * sweep's reach on another): each reader gets the sorted track's poses. The track
         * sorted itself inside the read, on both threads at once, before it was made safe:
         * this failed in most of its rounds then. */
        const int kPoses = 20000, kRounds = 40;
        int wrong = 0;
        for (int round = 0; round < kRounds; round++) {
            pb_pose_track_t *t = pb_pose_track_create();
            for (int i = 1; i < kPoses; i++) {
                pb_transform_t p = {{(double)i, 0, 0}, {1, 0, 0, 0}};
                pb_pose_track_add(t, (int64_t)i * 1000, &p);
            }
            pb_transform_t first = {{0, 0, 0}, {1, 0, 0, 0}};
            pb_pose_track_add(t, 0, &first);   /* out of order: the track sorts on its first read */
            int bad[2] = {0, 0};
            auto read = [&](int who) {
                for (int i = 0; i < kPoses - 1; i += 7) {
                    pb_transform_t out;
                    if (!pb_pose_track_at(t, (int64_t)i * 1000 + 500, &out) || std::fabs(out.t[0] - (i + 0.5)) > 1e-9) bad[who]++;
                }
            };
            std::thread other(read, 1);
            read(0);
            other.join();
            wrong += bad[0] + bad[1];
            pb_pose_track_destroy(t);
        }
        CHECK(wrong == 0);
    }
    return pb_check_report("test_map_build");
}
