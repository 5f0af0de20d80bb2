// mapper, steps 4-5: the map in tiles, the ground model, the carving (mapper.h, docs/mapper.md
// "Memory"; the logic in core/carve and common/pb_map_build).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <future>
#include <map>
#include <unordered_map>
#include <unordered_set>
#include "mapper.h"
#include "pb_bytes.h"
#include "carve.h"
#include "under.h"
#include "ground_build.h"
#include "pb_split.h"

/* The tiles of grid within reach of a sweep's points (the farthest point's range, of those
 * within range_m of the LiDAR), into [lo, hi] (x, y): around the base's
 * positions at its first and last point's times, with the LiDAR's lever and 2 m (the path's
 * bend within a sweep). false when the track does not cover the sweep (pass 2 skips it). */
static bool sweep_reach(const Run *R, const pb_pose_track_t *track, const pb_points_t &pts, int64_t utime, double range_m,
                        const TileGrid &grid, int64_t lo[2], int64_t hi[2])
{
    int32_t omin = pts.offset_us && pts.n > 0 ? pts.offset_us[0] : 0, omax = omin;   /* as pb_map_builder_add_timed */
    double r2 = 0;
    const float range2 = (float)(range_m * range_m);   /* as pb_map_builder_set_max_range */
    for (int i = 0; i < pts.n; i++) {
        if (pts.offset_us) { omin = std::min(omin, pts.offset_us[i]); omax = std::max(omax, pts.offset_us[i]); }
        if (pts.x[i] * pts.x[i] + pts.y[i] * pts.y[i] + pts.z[i] * pts.z[i] <= range2)
            r2 = std::max(r2, (double)pts.x[i] * pts.x[i] + (double)pts.y[i] * pts.y[i] + (double)pts.z[i] * pts.z[i]);
    }
    pb_transform_t a, b;
    if (!pb_pose_track_at(track, utime + omin, &a) || !pb_pose_track_at(track, utime + omax, &b)) return false;
    const double *l = R->veh.base_from_lidar.t;
    const double reach = std::sqrt(r2) + std::sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) + 2;
    for (int k = 0; k < 2; k++) {
        lo[k] = grid.of(std::min(a.t[k], b.t[k]) - reach);
        hi[k] = grid.of(std::max(a.t[k], b.t[k]) + reach);
    }
    return true;
}

/* Tile k of the map's grid moved out into *vox (empty when not held). */
static void take_tile(pb_map_builder_t *map, int64_t k, std::vector<pb_map_voxel_t> *vox)
{
    const int32_t tx = (int32_t)((uint64_t)k >> 32), ty = (int32_t)(uint32_t)k;
    vox->resize((size_t)pb_map_builder_tile_size(map, tx, ty));
    pb_map_builder_tile_take(map, tx, ty, vox->data());
}

/* Every tile's finished voxels (those held by map, those paged out) as points in the
 * carving's tiles (by its cells: no cell spans two), appended to their files; the map's
 * extent for the ground model. */
static int to_carving_tiles(Run *R, pb_map_builder_t *map, std::vector<int64_t> all, const std::unordered_set<int64_t> &out,
                            pb_err_t *err)
{
    const pb_carve_config_t ccfg{};
    const TileGrid cgrid{1.0 / ccfg.cell_m, std::max<int64_t>(1, std::lround(R->tile_m / ccfg.cell_m))};
    std::sort(all.begin(), all.end());
    R->ground_lo[0] = R->ground_lo[1] = INFINITY;
    R->ground_hi[0] = R->ground_hi[1] = -INFINITY;
    std::vector<pb_map_voxel_t> vox;
    std::map<int64_t, std::vector<TilePoint>> parts;
    for (int64_t k : all) {
        if (!out.count(k)) take_tile(map, k, &vox);
        else if (tile_read(tile_path(R, 'v', k), &vox, err) != 0) return -1;
        std::remove(tile_path(R, 'v', k).c_str());
        parts.clear();
        for (const pb_map_voxel_t &v : vox) {
            TilePoint tp;
            tp.seq = v.seq;
            tp.n = v.n;
            tp.first = v.first;
            tp.last = v.last;
            pb_map_voxel_point(map, &v, tp.p);
            parts[tile_key(cgrid.of(tp.p[0]), cgrid.of(tp.p[1]))].push_back(tp);
            gb_bounds(tp.p, 1, 4, R->ground_lo, R->ground_hi);
        }
        R->voxels += vox.size();
        for (const auto &pt : parts) {
            R->carve_tiles.insert(pt.first);
            if (tile_write(tile_path(R, 'p', pt.first), pt.second.data(), pt.second.size(), true, err) != 0) return -1;
        }
    }
    if (R->voxels == 0)
        return pb_err_set(err, "%s: the map has no points (no scan had bracketing poses?)", R->path("map.pcd").c_str()), -1;
    return 0;
}

/* A sweep copied for a stage on another thread (the reader's buffer is the next sweep's once
 * the callback returns), and where pb_map_builder_place_timed placed its returns. */
struct PlacedSweep {
    std::vector<float> x, y, z, intensity;
    std::vector<int32_t> offset_us, index;
    std::vector<uint8_t> ring;
    std::vector<double> xyz;
    pb_points_t pts = {};
    int n = 0;            /* returns placed (-1: the track does not bracket the sweep) */
    int64_t beyond = 0;   /* returns beyond the builder's range */
    uint32_t stamp = 0;   /* the map's stamp of the sweep */

    void take(const pb_points_t &from)
    {
        const size_t m = (size_t)from.n;
        auto copy = [m](auto *a, auto *to) { if (a) to->assign(a, a + m); return a ? to->data() : nullptr; };
        pts = {from.n, from.n, copy(from.x, &x), copy(from.y, &y), copy(from.z, &z), copy(from.intensity, &intensity),
               copy(from.offset_us, &offset_us), copy(from.ring, &ring)};
        xyz.resize(3 * m);
        index.resize(m);
    }
    void place(const pb_map_builder_t *placer, int64_t utime, const pb_pose_track_t *track, const pb_transform_t *bl)
    {
        n = pb_map_builder_place_timed(placer, &pts, utime, track, bl, xyz.data(), index.data(), &beyond);
    }
};

/* Several drives on one clock, each an hour after the last: so the carving's rays and the
 * road under what moved never take two drives whose logs' clocks overlap for one time. */
struct DriveClock {
    const Run *now = nullptr;
    int64_t offset = 0, last = INT64_MIN;   /* drive's time + offset: the one clock */
    bool next(const Run *D)                  /* true when D starts a drive */
    {
        if (D == now) return false;
        now = D;
        if (last != INT64_MIN) offset = last + 3600 * (int64_t)1000000 - D->traj.front().utime;
        last = D->traj.back().utime + offset;
        return true;
    }
};

/* Pass 2: the map, every return within the carving's reach with the pose at its time
 * (pb_map_builder_set_max_range), in tiles: those the sweep can
 * reach are held (paged back in when they were out), those no sweep of the last 20 reached
 * are paged out; of every drive placed, one after the other. Then the finished voxels are
 * sorted into the carving's tiles. Each voxel keeps the first and last sweep that hit it
 * (pb_map_builder_stamp; R->sweep_times says when, for pass 4). The poses are at the
 * sweeps' middles: the track is carried on by the first and last steps' motion to cover the
 * first sweep's first half and the last one's second half. */
int pass_map(Run *R, pb_err_t *err)
{
    for (Run *D : R->drives) {
        if (!D->placement.placed) continue;
        const std::vector<SweepPose> &traj = D->traj;
        D->track = pb_pose_track_create();
        for (const SweepPose &s : traj) {
            pb_transform_t t = to_transform(s.pose);
            pb_pose_track_add(D->track, s.utime, &t);
        }
        for (int end = 0; end < 2; end++) {
            const SweepPose &a = end ? traj[traj.size() - 2] : traj[1], &b = end ? traj.back() : traj[0];
            pb_transform_t t = to_transform(b.pose * (a.pose.inverse() * b.pose));
            pb_pose_track_add(D->track, b.utime + (b.utime - a.utime), &t);
        }
    }
    std::error_code ec;
    std::filesystem::remove_all(R->tiles_dir, ec);   /* an interrupted run's */
    if (!std::filesystem::create_directory(R->tiles_dir, ec))
        return pb_err_set(err, "%s: cannot create: %s", R->tiles_dir.c_str(), ec.message().c_str()), -1;
    const TileGrid grid{1.0 / R->voxel, std::max<int64_t>(1, std::lround(R->tile_m / R->voxel))};
    pb_map_builder_t *map = pb_map_builder_create_tiled(R->voxel, (int)grid.per, err);
    if (!map) return -1;
    /* The map holds only what the carving can judge: a return farther than its rays and views
     * reach (max_range_m) could be a car that left, and nothing would say so; it is also the
     * least accurate (a tenth of a degree of the pose is 0.1 m at 60 m). */
    const double range_m = pb_carve_config_t{}.max_range_m;
    pb_map_builder_set_max_range(map, range_m);
    std::unordered_map<int64_t, long> held;   /* tile -> the sweep that last reached it */
    std::unordered_set<int64_t> out;           /* tiles paged out */
    std::vector<pb_map_voxel_t> vox;
    std::vector<int32_t> xy;
    auto page_out = [&](int64_t k, pb_err_t *e) {
        take_tile(map, k, &vox);
        held.erase(k);
        if (vox.empty()) return 0;   /* reached, no point fell there */
        out.insert(k);
        R->tiles_paged_out++;
        return tile_write(tile_path(R, 'v', k), vox.data(), vox.size(), false, e);
    };
    long sweep = 0;
    DriveClock clock;   /* pass 4's time */
    R->sweep_times.clear();
    /* Two stages: a sweep placed on another thread (its own copy of the sweep) while the one
     * before is added here; each sweep's tiles held, its points added, then the paging, in
     * the sweeps' order as with one stage (the same map, byte for byte). */
    pb_map_builder_t *placer = pb_map_builder_create(R->voxel, err);
    if (!placer) return pb_map_builder_destroy(map), -1;
    pb_map_builder_set_max_range(placer, range_m);
    PlacedSweep stage[2];
    std::future<void> placing;
    auto add = [&](long s, const PlacedSweep &P, pb_err_t *e) {   /* sweep s (1, 2, ...) into the map */
        pb_map_builder_stamp(map, P.stamp);
        if (P.n >= 0 && pb_map_builder_add_placed(map, &P.pts, P.xyz.data(), P.index.data(), P.n, P.beyond, e) != 0)
            return -1;
        (P.n >= 0 ? R->placed : R->unplaced)++;
        // a point beyond the reach would have started a paged-out tile afresh
        xy.resize(2 * (size_t)pb_map_builder_tiles(map, nullptr, 0));
        pb_map_builder_tiles(map, xy.data(), (int)(xy.size() / 2));
        for (size_t i = 0; i < xy.size(); i += 2)
            if (!held.count(tile_key(xy[i], xy[i + 1])))
                return pb_err_set(e, "internal: a point fell in map tile (%d, %d), beyond the sweep's reach", xy[i],
                                  xy[i + 1]), -1;
        R->tiles_held_max = std::max(R->tiles_held_max, (long)(xy.size() / 2));   /* those with points */
        R->voxels_held_max = std::max(R->voxels_held_max, (int64_t)pb_map_builder_size(map));
        // the tiles no sweep of the last 20 reached paged out
        if (s % 10 == 0) {
            std::vector<int64_t> old;
            for (const auto &h : held)
                if (h.second < s - 20) old.push_back(h.first);
            std::sort(old.begin(), old.end());
            for (int64_t k : old)
                if (page_out(k, e) != 0) return -1;
        }
        return 0;
    };
    int rc = for_each_drive_sweep(R, "mapper: map", 1,
        [&](Run *D, int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            sweep++;
            clock.next(D);
            PlacedSweep &P = stage[sweep % 2];
            P.stamp = (uint32_t)R->sweep_times.size();
            R->sweep_times.push_back(utime + clock.offset);
            P.take(pts);
            if (placing.valid()) placing.get();
            placing = std::async(std::launch::async, [&P, D, utime, placer, R] { P.place(placer, utime, D->track, &R->veh.base_from_lidar); });
            if (sweep > 1 && add(sweep - 1, stage[(sweep - 1) % 2], e) != 0) return -1;   /* the sweep before */
            // the tiles this sweep can reach held
            int64_t lo[2], hi[2];
            if (sweep_reach(R, D->track, pts, utime, range_m, grid, lo, hi))
                for (int64_t tx = lo[0]; tx <= hi[0]; tx++)
                    for (int64_t ty = lo[1]; ty <= hi[1]; ty++) {
                        const int64_t k = tile_key(tx, ty);
                        auto it = held.find(k);
                        if (it != held.end()) { it->second = sweep; continue; }
                        held[k] = sweep;
                        if (!out.count(k)) continue;
                        if (tile_read(tile_path(R, 'v', k), &vox, e) != 0 || pb_map_builder_put(map, vox.data(), vox.size(), e) != 0)
                            return -1;
                        out.erase(k);
                        R->tiles_paged_in++;
                    }
            return 0;
        }, err);
    if (placing.valid()) placing.get();
    if (rc == 0 && sweep > 0) rc = add(sweep, stage[sweep % 2], err);
    pb_map_builder_destroy(placer);
    R->beyond_range = pb_map_builder_points_beyond(map);
    // every tile's finished points into the carving's tiles
    std::vector<int64_t> all(out.begin(), out.end());
    for (const auto &h : held) all.push_back(h.first);
    if (rc == 0) rc = to_carving_tiles(R, map, all, out, err);
    pb_map_builder_destroy(map);
    return rc;
}

/* The ground model (tools/build-ground's core) from the map, tile by tile; a site without
 * one is still a site for the localizer: say why, go on. Kept for the carving. */
pb_ground_t *make_ground(Run *R, pb_err_t *err)
{
    gb_config_t gcfg;
    gb_config_default(&gcfg);
    size_t nground = 0;
    gb_accum_t *acc = gb_begin(R->ground_lo, R->ground_hi, &gcfg);
    std::vector<TilePoint> pts;
    for (int64_t k : R->carve_tiles) {
        if (acc && tile_read(tile_path(R, 'p', k), &pts, err) != 0) {
            R->ground_why = err->msg;
            break;
        }
        if (acc && !pts.empty()) gb_add(acc, pts[0].p, pts.size(), sizeof(TilePoint) / sizeof(float));
    }
    pb_ground_t *ground = acc ? gb_finish(acc, &nground) : nullptr;
    if (!R->ground_why.empty()) { pb_ground_destroy(ground); ground = nullptr; }
    const std::string ground_path = R->path("ground.yaml");
    if (!ground && R->ground_why.empty()) R->ground_why = "no ground in the map";
    else if (ground && pb_ground_save(ground, ground_path.c_str(), err) != 0) R->ground_why = err->msg;
    if (!R->ground_why.empty()) {
        std::remove(ground_path.c_str());
        std::fprintf(stderr, "mapper: warning: no ground model written: %s\n", R->ground_why.c_str());
    }
    return ground;
}

/* The carving's tiles (those that hold points): each held as a pb_carve_t of its points,
 * its counts paged out to its 'c' file and back. */
struct CarveTiles {
    Run *R;
    const pb_ground_t *ground;
    pb_carve_config_t cfg;
    struct Held { pb_carve_t *carve; long last; };   /* last: the sampled sweep that last reached it */
    std::map<int64_t, Held> held;
    std::vector<TilePoint> pts;                      /* the last tile read */
    std::vector<uint8_t> bytes;

    ~CarveTiles() { for (auto &h : held) pb_carve_destroy(h.second.carve); }

    /* Tile k's carving made from its points (read into *pts) and given its counts (through
     * *bytes), if it was paged out; NULL on error. Reads only the tile's files: tiles can be
     * made on two threads at once, each with its own buffers. */
    pb_carve_t *make(int64_t k, bool *was_out, std::vector<TilePoint> *pts, std::vector<uint8_t> *bytes, pb_err_t *e) const
    {
        if (tile_read(tile_path(R, 'p', k), pts, e) != 0) return nullptr;
        if (pts->empty()) return pb_err_set(e, "%s: no point in the tile", tile_path(R, 'p', k).c_str()), nullptr;
        pb_carve_t *c = pb_carve_create((*pts)[0].p, pts->size(), sizeof(TilePoint) / sizeof(float), ground, &cfg);
        const std::string counts = tile_path(R, 'c', k);
        *was_out = read_file(counts, bytes) == 0;
        if (*was_out && pb_carve_load(c, bytes->data(), bytes->size()) != 0) {
            pb_carve_destroy(c);
            return pb_err_set(e, "%s: not this tile's counts", counts.c_str()), nullptr;
        }
        return c;
    }

    /* Tile k held (paged back in if it was out); NULL on error. */
    pb_carve_t *hold(int64_t k, long sampled, pb_err_t *e)
    {
        auto it = held.find(k);
        if (it == held.end()) {
            bool was_out;
            pb_carve_t *c = make(k, &was_out, &pts, &bytes, e);
            if (!c) return nullptr;
            R->carve_tiles_paged_in += was_out;
            it = held.emplace(k, Held{c, 0}).first;
        }
        it->second.last = sampled;
        return it->second.carve;
    }

    /* The tiles no sampled sweep since `since` reached: their counts paged out. */
    int page_out(long since, pb_err_t *e)
    {
        for (auto it = held.begin(); it != held.end();) {
            if (it->second.last >= since) { ++it; continue; }
            pb_carve_save(it->second.carve, &bytes);
            pb_carve_destroy(it->second.carve);
            const std::string path = tile_path(R, 'c', it->first);
            it = held.erase(it);
            R->carve_tiles_paged_out++;
            if (tile_write(path, bytes.data(), bytes.size(), false, e) != 0) return -1;
        }
        return 0;
    }

    /* Every tile's verdicts: its kept points sorted by seq (map.pcd's order) to its 'k'
     * file, the carved ones to the picture's layer. First every tile's cells carved on
     * their own counts, so that a cell on a tile's border sees its neighbours over it. Each
     * step on two threads, half the tiles each (a tile's verdicts read only its own files
     * and the sorted keys of all), the results then taken in tile order: the same files. */
    int finish(pb_err_t *err)
    {
        const std::vector<int64_t> keys(R->carve_tiles.begin(), R->carve_tiles.end());
        struct Half {
            std::vector<TilePoint> pts, kept;
            std::vector<uint8_t> bytes, keep, objects;
            std::vector<uint64_t> gone, seeds;
            std::vector<pb_carve_group_cell_t> cells;
            pb_err_t err;
            int rc = 0;
        } half[2];
        /* the tile's carving: the one held, else made (and destroyed by the caller: *made) */
        auto carving = [&](int64_t k, Half &H, bool *made) -> pb_carve_t * {
            auto it = held.find(k);
            *made = it == held.end();
            if (!*made) return it->second.carve;
            bool was_out;
            pb_carve_t *c = make(k, &was_out, &H.pts, &H.bytes, &H.err);
            if (!c) H.rc = -1;
            return c;
        };
        /* every tile's results of one step, in key order, sorted */
        auto gather = [&](auto Half::*field) {
            auto all = std::move(half[0].*field);
            all.insert(all.end(), (half[1].*field).begin(), (half[1].*field).end());
            return all;
        };
        /* step(c, H, i, made) on every tile's carving (made: read from its files, its points in
         * H.pts), half the tiles on each thread */
        auto each_tile = [&](auto step) {
            pb_split2(keys.size(), [&](size_t a, size_t b) {
                Half &H = half[a == 0 ? 0 : 1];
                for (size_t i = a; i < b && H.rc == 0; i++) {
                    bool made;
                    pb_carve_t *c = carving(keys[i], H, &made);
                    if (!c) break;
                    step(c, H, i, made);
                    if (made) pb_carve_destroy(c);
                }
            }, 2);
            return half[0].rc != 0 ? (*err = half[0].err, -1) : half[1].rc != 0 ? (*err = half[1].err, -1) : 0;
        };
        // 1. the cells each tile carves on its own counts, and the points over the ground views saw through
        if (each_tile([](pb_carve_t *c, Half &H, size_t, bool) { pb_carve_gone(c, &H.gone); pb_carve_seeds(c, &H.seeds); }) != 0)
            return -1;
        std::vector<uint64_t> gone = gather(&Half::gone), seeds = gather(&Half::seeds);
        std::sort(gone.begin(), gone.end());
        // 1b. the kept points over the ground near those, by group cell; then the groups that go
        pb_carve_near_t *near = pb_carve_near_create(seeds, &cfg);
        const int rc = seeds.empty() ? 0 : each_tile([&](pb_carve_t *c, Half &H, size_t, bool) {
            pb_carve_group_cells(c, &gone, near, &H.cells);
        });
        pb_carve_near_destroy(near);
        if (rc != 0) return -1;
        std::vector<pb_carve_group_cell_t> cells = gather(&Half::cells);
        std::vector<uint64_t> group_gone;
        pb_carve_groups(&cells, &cfg, &group_gone);
        // 2. each tile's kept points to its 'k' file, what it carved kept for the picture
        struct Verdict {
            size_t carved = 0, kept = 0, grouped = 0;
            uint32_t first = UINT32_MAX;
            std::pair<uint64_t, uint64_t> sum;
            std::vector<float> removed, objects;
            std::vector<uint32_t> hits;   /* per removed point: first, last sweep */
        };
        std::vector<Verdict> verdicts(keys.size());
        const int rc2 = each_tile([&](pb_carve_t *c, Half &H, size_t i, bool made) {
            const int64_t k = keys[i];
            if (!made && tile_read(tile_path(R, 'p', k), &H.pts, &H.err) != 0) { H.rc = -1; return; }
            Verdict &V = verdicts[i];
            V.carved = pb_carve_keep(c, &gone, &group_gone, &H.keep, &H.objects);
            H.kept.clear();
            for (size_t j = 0; j < H.pts.size(); j++) {
                if (H.keep[j]) H.kept.push_back(H.pts[j]);
                else {
                    V.removed.insert(V.removed.end(), {H.pts[j].p[0], H.pts[j].p[1], H.pts[j].p[2]});
                    V.hits.insert(V.hits.end(), {H.pts[j].first, H.pts[j].last});
                }
                if (H.objects[j]) {
                    V.grouped++;
                    V.objects.insert(V.objects.end(), {H.pts[j].p[0], H.pts[j].p[1], H.pts[j].p[2]});
                }
            }
            std::sort(H.kept.begin(), H.kept.end(), [](const TilePoint &x, const TilePoint &y) { return x.seq < y.seq; });
            V.kept = H.kept.size();
            V.first = H.kept.empty() ? UINT32_MAX : H.kept[0].seq;
            V.sum = {H.kept.size() * sizeof(TilePoint), pb_fnv1a64(H.kept.data(), H.kept.size() * sizeof(TilePoint))};
            if (tile_write(tile_path(R, 'k', k), H.kept.data(), H.kept.size(), false, &H.err) != 0) { H.rc = -1; return; }
            std::remove(tile_path(R, 'p', k).c_str());
            std::remove(tile_path(R, 'c', k).c_str());
        });
        for (auto &h : held) pb_carve_destroy(h.second.carve);
        held.clear();
        if (rc2 != 0) return -1;
        for (size_t i = 0; i < keys.size(); i++) {
            const Verdict &V = verdicts[i];
            R->carved += V.carved;
            R->carved_groups += V.grouped;
            R->layers.removed.insert(R->layers.removed.end(), V.removed.begin(), V.removed.end());
            R->carved_hits.insert(R->carved_hits.end(), V.hits.begin(), V.hits.end());
            R->layers.objects.insert(R->layers.objects.end(), V.objects.begin(), V.objects.end());
            R->map_points += V.kept;
            R->kept_tiles.push_back({keys[i], V.first});
            R->kept_sums.push_back(V.sum);
        }
        return 0;
    }
};

/* Pass 4: the road under what moved (core/under.h): when each carved voxel was hit is pass
 * 2's (its first and last sweep); every sweep of every placed drive read again, its returns
 * placed as pass 2 placed them (pb_map_builder_place_timed), those at the road under a body
 * the carving took counted; then each kept tile's points without them (a voxel left with
 * none goes, to the picture's carved layer). */
static int pass_under(Run *R, const pb_ground_t *ground, pb_err_t *err)
{
    const size_t ncarved = R->layers.removed.size() / 3;
    std::vector<int64_t> hit(2 * ncarved);
    for (size_t i = 0; i < hit.size(); i++) hit[i] = R->sweep_times.at(R->carved_hits.at(i));
    pb_under_t *u = pb_under_create(R->layers.removed.data(), ncarved, 3, hit.data(), R->voxel, ground, nullptr);
    pb_map_builder_t *placer = pb_map_builder_create(R->voxel, err);
    if (!placer) return pb_under_destroy(u), -1;
    pb_map_builder_set_max_range(placer, pb_carve_config_t{}.max_range_m);   /* as pass 2 */
    /* Two stages: a sweep placed on another thread while the one before goes through
     * pb_under_sweep here (in the sweeps' order); each stage has its own copy of the sweep. */
    PlacedSweep stage[2];
    std::future<void> placing;
    size_t sweep = 0;   /* pass 2's number of the sweep */
    long sweeps = 0;    /* those placed */
    auto under_sweep = [&](PlacedSweep &P) { if (P.n > 0) pb_under_sweep(u, P.xyz.data(), (size_t)P.n, &P.pts, P.index.data()); };
    int rc = for_each_drive_sweep(R, "mapper: under", 1,
        [&](Run *D, int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            if (sweep >= R->sweep_times.size())
                return pb_err_set(e, "internal: the log holds more sweeps than the map pass read (%zu)", R->sweep_times.size());
            // a sweep when no body was hit takes nothing: not placed
            if (!pb_under_busy(u, R->sweep_times[sweep++])) return 0;
            R->under_sweeps++;
            PlacedSweep &P = stage[sweeps % 2];
            P.take(pts);
            if (placing.valid()) placing.get();
            placing = std::async(std::launch::async, [&P, D, utime, placer, R] { P.place(placer, utime, D->track, &R->veh.base_from_lidar); });
            if (sweeps++ > 0) under_sweep(stage[sweeps % 2]);   /* the sweep before */
            return 0;
        }, err);
    if (placing.valid()) placing.get();
    if (rc == 0 && sweeps > 0) under_sweep(stage[(sweeps - 1) % 2]);
    pb_map_builder_destroy(placer);
    // each kept tile without the returns taken out; the points where a body stood noted
    std::vector<TilePoint> pts, kept;
    std::vector<float> near;                          /* x y z of points a bump test may need ... */
    std::vector<std::pair<uint32_t, uint32_t>> where; /* ... and their tile and place in it */
    std::vector<std::pair<uint32_t, uint32_t>> looks; /* the one-look voxels' tile and place, by number */
    auto at = [&](uint32_t sweep) { return R->sweep_times.at(sweep); };
    auto rewrite = [&](size_t t, const std::string &path) {
        R->map_points -= pts.size() - kept.size();
        R->kept_tiles[t].second = kept.empty() ? UINT32_MAX : kept[0].seq;
        R->kept_sums[t] = {kept.size() * sizeof(TilePoint), pb_fnv1a64(kept.data(), kept.size() * sizeof(TilePoint))};
        return tile_write(path, kept.data(), kept.size(), false, err);
    };
    for (size_t t = 0; rc == 0 && t < R->kept_tiles.size(); t++) {
        const std::string path = tile_path(R, 'k', R->kept_tiles[t].first);
        if (tile_read(path, &pts, err) != 0) { rc = -1; break; }
        kept.clear();
        bool changed = false;
        for (TilePoint tp : pts) {
            const uint32_t left = pb_under_adjust(u, tp.p, tp.n);
            if (left != tp.n) { changed = true; R->under_moved++; }
            if (left == 0) {
                R->under_gone++;
                R->layers.removed.insert(R->layers.removed.end(), {tp.p[0], tp.p[1], tp.p[2]});
                continue;
            }
            tp.n = left;
            if (pb_under_look(u, tp.p, at(tp.first), at(tp.last)) >= 0) looks.push_back({(uint32_t)t, (uint32_t)kept.size()});
            if (pb_under_near(u, tp.p)) {
                near.insert(near.end(), {tp.p[0], tp.p[1], tp.p[2]});
                where.push_back({(uint32_t)t, (uint32_t)kept.size()});
            }
            kept.push_back(tp);
        }
        if (changed && rewrite(t, path) != 0) rc = -1;
    }
    // the bumps: what a tyre left of a voxel, with the road all round it; the one-look voxels,
    // when every tile has said which voxels beside them were seen for long (core/under.h)
    std::vector<uint8_t> gone(where.size());
    std::vector<std::pair<uint32_t, uint32_t>> drops;   /* tile, place */
    if (rc == 0 && pb_under_bumps(u, near.data(), where.size(), 3, gone.data()) > 0)
        for (size_t i = 0; i < where.size(); i++)
            if (gone[i]) drops.push_back(where[i]);
    for (size_t t = 0; rc == 0 && !looks.empty() && t < R->kept_tiles.size(); t++) {
        if (tile_read(tile_path(R, 'k', R->kept_tiles[t].first), &pts, err) != 0) { rc = -1; break; }
        for (const TilePoint &tp : pts) pb_under_look_support(u, tp.p, tp.n, at(tp.first), at(tp.last));
    }
    for (size_t i = 0; i < looks.size(); i++)
        if (pb_under_look_gone(u, (int)i)) drops.push_back(looks[i]);
    std::sort(drops.begin(), drops.end());
    drops.erase(std::unique(drops.begin(), drops.end()), drops.end());
    for (size_t i = 0; rc == 0 && i < drops.size();) {
        const size_t t = drops[i].first;
        const std::string path = tile_path(R, 'k', R->kept_tiles[t].first);
        if (tile_read(path, &pts, err) != 0) { rc = -1; break; }
        std::vector<uint8_t> drop(pts.size());
        for (; i < drops.size() && drops[i].first == t; i++) drop[drops[i].second] = 1;
        kept.clear();
        for (size_t k = 0; k < pts.size(); k++) {
            if (drop[k]) {
                R->under_moved++, R->under_gone++;
                R->layers.removed.insert(R->layers.removed.end(), {pts[k].p[0], pts[k].p[1], pts[k].p[2]});
                continue;
            }
            kept.push_back(pts[k]);
        }
        if (rewrite(t, path) != 0) rc = -1;
    }
    uint64_t voxels;
    pb_under_counts(u, &R->under_returns, &voxels);
    pb_under_destroy(u);
    return rc;
}

/* Pass 3: what moved is carved out of the map (core/carve.h), on a sample of the rays
 * (every 2nd sweep, every 13th point: 13 is prime to the beam count, so every beam takes
 * its turn) of every drive placed, each an hour after the last in the carving's time (two
 * drives' clocks may overlap), with the drive's number (pb_carve_set_drive); the band over
 * the ground model is spared. A tile of the carving is held while the rays of the last 10
 * sampled sweeps could reach it (max_range_m of their origins), else its counts are paged
 * out; each ray is cast in the tiles under it. Then every tile's verdicts. */
int pass_carve(Run *R, const pb_ground_t *ground, pb_err_t *err)
{
    CarveTiles tiles{R, ground, pb_carve_config_t{}, {}, {}, {}};
    const pb_carve_config_t &ccfg = tiles.cfg;
    const TileGrid cgrid{1.0 / ccfg.cell_m, std::max<int64_t>(1, std::lround(R->tile_m / ccfg.cell_m))};
    const Eigen::Isometry3d bl = pb_reg_from_transform(&R->veh.base_from_lidar);
    struct Ray { int64_t utime; Eigen::Vector3d o, e; };
    std::vector<Ray> rays;
    std::vector<std::vector<uint32_t>> rays_in;   /* per tile in reach (as under): the rays its box holds, in order */
    std::vector<uint32_t> order;                  /* the tiles with rays, the most first */
    std::vector<pb_carve_t *> under;   /* the sweep's reach, row by row: the tile's carving or NULL */
    long sampled = 0;
    int drive = -1, view_drive = -1;
    int64_t last_view = 0;
    std::vector<double> returns;   /* the sweep's returns in the map frame, and their beams */
    std::vector<uint8_t> beam;
    /* The sweep as a view: every return at its own time, seen from the LiDAR at the sweep's
     * middle; NULL when the trajectory does not reach the sweep's middle. It reads only the
     * sweep, the track and the ground: made on another thread while the rays are cast. */
    auto make_view = [&](Run *D, int64_t utime, const pb_points_t &pts) -> pb_carve_view_t * {
        returns.clear();
        beam.clear();
        int32_t cached = INT32_MIN, olo = INT32_MAX, ohi = INT32_MIN;
        Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
        bool have = false;
        for (int i = 0; i < pts.n; i++) {
            if (pts.offset_us[i] != cached) {
                cached = pts.offset_us[i];
                pb_transform_t t;
                have = pb_pose_track_at(D->track, utime + cached, &t);
                if (have) T = pb_reg_from_transform(&t) * bl;
                olo = std::min(olo, cached);
                ohi = std::max(ohi, cached);
            }
            if (!have || !std::isfinite(pts.x[i])) continue;
            const Eigen::Vector3d q = T * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i]);
            returns.insert(returns.end(), {q.x(), q.y(), q.z()});
            beam.push_back(pts.ring ? pts.ring[i] : 255);
        }
        pb_transform_t t;
        if (returns.empty() || !pb_pose_track_at(D->track, utime + (olo + (int64_t)ohi) / 2, &t)) return nullptr;
        const Eigen::Isometry3d M = pb_reg_from_transform(&t) * bl;
        Eigen::Matrix<double, 3, 3, Eigen::RowMajor> Rm = M.rotation();
        return pb_carve_view_create(returns.data(), beam.data(), beam.size(), M.translation().data(), Rm.data(),
                                    tiles.ground);
    };
    /* The view counted by every tile held in reach, half the tiles on another thread. */
    auto look = [&](pb_carve_view_t *v, const std::vector<pb_carve_t *> &tiles_in_reach) {
        if (!v) return;
        std::vector<pb_carve_t *> parts;
        for (pb_carve_t *c : tiles_in_reach)
            if (c) parts.push_back(c);
        pb_take2(parts.size(), [&](size_t i) { pb_carve_look(parts[i], v); });
        R->views++;
        pb_carve_view_destroy(v);
    };
    DriveClock clock;   /* the carving's time */
    int rc = for_each_drive_sweep(R, "mapper: carve", 2,
        [&](Run *D, int64_t utime, const std::vector<float> &, const pb_points_t &pts, const pb_event_t &, pb_err_t *e) {
            if (clock.next(D)) drive++;
            sampled++;
            // the sampled rays, and the extent of their origins
            rays.clear();
            double olo[2] = {INFINITY, INFINITY}, ohi[2] = {-INFINITY, -INFINITY};
            int32_t cached = INT32_MIN;
            Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
            bool have = false;
            for (int i = 0; i < pts.n; i += 13) {
                if (pts.offset_us[i] != cached) {   /* a column's points share their time */
                    cached = pts.offset_us[i];
                    pb_transform_t t;
                    have = pb_pose_track_at(D->track, utime + cached, &t);
                    if (have) T = pb_reg_from_transform(&t) * bl;
                    for (int k = 0; have && k < 2; k++) {
                        olo[k] = std::min(olo[k], T.translation()[k]);
                        ohi[k] = std::max(ohi[k], T.translation()[k]);
                    }
                }
                if (!have) continue;
                rays.push_back({utime + cached + clock.offset, T.translation(), T * Eigen::Vector3d(pts.x[i], pts.y[i], pts.z[i])});
            }
            if (rays.empty()) return 0;
            // the tiles its rays can reach held
            int64_t lo[2], hi[2];
            for (int k = 0; k < 2; k++) {
                lo[k] = cgrid.of(olo[k] - ccfg.max_range_m - 1);
                hi[k] = cgrid.of(ohi[k] + ccfg.max_range_m + 1);
            }
            const int64_t w = hi[0] - lo[0] + 1;
            under.assign((size_t)(w * (hi[1] - lo[1] + 1)), nullptr);
            for (int64_t tx = lo[0]; tx <= hi[0]; tx++)
                for (int64_t ty = lo[1]; ty <= hi[1]; ty++) {
                    const int64_t k = tile_key(tx, ty);
                    if (!R->carve_tiles.count(k)) continue;
                    pb_carve_t *c = tiles.hold(k, sampled, e);
                    if (!c) return -1;
                    pb_carve_set_drive(c, drive);
                    under[(size_t)((ty - lo[1]) * w + (tx - lo[0]))] = c;
                }
            R->carve_tiles_held_max = std::max(R->carve_tiles_held_max, (long)tiles.held.size());
            // each ray cast in the tiles under it (one longer than max_range_m: those within it),
            // tile by tile, the tiles with the most rays first taken in turn by two threads (a
            // tile's counts are its own: each sees its rays in the same order either way)
            rays_in.resize(under.size());
            for (std::vector<uint32_t> &v : rays_in) v.clear();
            for (size_t k = 0; k < rays.size(); k++) {
                const Ray &r = rays[k];
                const int64_t x0 = std::max(lo[0], cgrid.of(std::min(r.o.x(), r.e.x()))),
                              x1 = std::min(hi[0], cgrid.of(std::max(r.o.x(), r.e.x()))),
                              y0 = std::max(lo[1], cgrid.of(std::min(r.o.y(), r.e.y()))),
                              y1 = std::min(hi[1], cgrid.of(std::max(r.o.y(), r.e.y())));
                for (int64_t ty = y0; ty <= y1; ty++)
                    for (int64_t tx = x0; tx <= x1; tx++) {
                        const size_t t = (size_t)((ty - lo[1]) * w + (tx - lo[0]));
                        if (under[t]) rays_in[t].push_back((uint32_t)k);
                    }
            }
            order.clear();
            for (size_t t = 0; t < under.size(); t++)
                if (!rays_in[t].empty()) order.push_back((uint32_t)t);
            std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return rays_in[a].size() > rays_in[b].size(); });
            auto cast = [&](size_t i) {
                for (uint32_t k : rays_in[order[i]]) pb_carve_ray(under[order[i]], rays[k].utime, rays[k].o.data(), rays[k].e.data());
            };
            // about once a second of the drive, the whole sweep as a view of the tiles in reach
            // (made while the rays are cast, counted after them)
            std::future<pb_carve_view_t *> view;
            if (view_drive != drive || utime - last_view >= (int64_t)1000000) {
                view_drive = drive;
                last_view = utime;
                view = std::async(std::launch::async, make_view, D, utime, std::cref(pts));
            }
            pb_take2(order.size(), cast);
            if (view.valid()) look(view.get(), under);
            // the tiles no sampled sweep of the last 10 reached paged out
            return sampled % 5 == 0 ? tiles.page_out(sampled - 10, e) : 0;
        }, err);
    if (rc != 0) return -1;
    return tiles.finish(err) == 0 ? pass_under(R, ground, err) : -1;
}
