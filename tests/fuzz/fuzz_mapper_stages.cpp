/* libFuzzer target: the mapper's checkpoints between its later steps (modules/mapper/
 * restart.cpp: poses.bin, carved.bin) from arbitrary bytes behind a valid magic, id and
 * checksum (a damaged file fails those first; this reaches the fields behind them). A file
 * restored must leave a Run the report can be written from; errors and refusals are
 * expected, crashes, undefined behaviour and leaks are not.
 * fuzz-sources: modules/mapper/restart.cpp modules/mapper/core/odometry.cpp modules/localizer/core/registration.cpp modules/localizer/core/regmap.cpp modules/localizer/core/deskew.cpp modules/localizer/core/window_search.cpp modules/localizer/core/map_tiles.cpp modules/localizer/core/places.cpp common/pb_err.c common/pb_pcd.c
 * fuzz-libs: -Wno-deprecated -Imodules/mapper -Imodules/localizer/core -Imodules/mapper/core -I/usr/include/pcl-1.13 -I/usr/include/eigen3 -lpcl_io -lpcl_common -lpthread */
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <cstdlib>
#include <string>
#include <sys/stat.h>
#include <unistd.h>
#include <vector>

#include "mapper.h"
#include "pb_bytes.h"

static std::string dir()
{
    static std::string d;
    if (d.empty()) {
        char tmpl[] = "/tmp/fuzz_mapper_stages.XXXXXX";
        if (!mkdtemp(tmpl)) abort();
        d = tmpl;
        mkdir((d + "/map-tiles.tmp").c_str(), 0777);
        std::atexit([] { std::error_code ec; std::filesystem::remove_all(dir(), ec); });
    }
    return d;
}

/* magic, the run's id, [prefix], the fuzzed bytes, the checksum: to SITE_DIR/name */
static void put(const Run &R, const char *name, const char magic[8], const std::vector<uint8_t> &prefix,
                const uint8_t *data, size_t size)
{
    std::vector<uint8_t> buf;
    ByteWriter w{&buf};
    for (int i = 0; i < 8; i++) w.put(magic[i]);
    w.put_string(stage_id(&R));
    buf.insert(buf.end(), prefix.begin(), prefix.end());
    buf.insert(buf.end(), data, data + size);
    w.put(pb_fnv1a64(buf.data(), buf.size()));
    FILE *f = std::fopen(R.path(name).c_str(), "wb");
    if (!f || std::fwrite(buf.data(), 1, buf.size(), f) != buf.size()) abort();
    std::fclose(f);
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    const std::string d = dir();
    Run R;
    R.out_dir = d.c_str();
    R.tiles_dir = d + "/map-tiles.tmp";
    R.voxel = 0.15;
    R.drives = {&R};
    for (int i = 0; i < 3; i++) R.traj.push_back({1000000 + 100000 * i, Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity(), 1, 1, 0.5, 1.0, 0});
    pb_err_t err;
    std::remove(R.path("carved.bin").c_str());
    if (data[0] & 1) {   /* a whole poses.bin, then carved.bin fuzzed */
        if (stage_write_poses(&R, &err) != 0) abort();
        std::vector<uint8_t> sum;
        ByteWriter{&sum}.put(R.poses_sum);
        put(R, "carved.bin", kCarvedMagic, sum, data + 1, size - 1);
    } else {
        put(R, "poses.bin", kPosesMagic, {}, data + 1, size - 1);
    }
    Run S;
    S.out_dir = R.out_dir;
    S.tiles_dir = R.tiles_dir;
    S.voxel = R.voxel;
    S.drives = {&S};
    S.traj = R.traj;
    int done = -1;
    if (stage_read(&S, &done, &err) != 0) return 0;
    if (done < 0 || done > 2) abort();
    if (done >= 1 && (!S.anchor.why || !S.placement.why)) abort();   /* the report reads them */
    if (done == 2 && S.kept_tiles.size() != S.kept_sums.size()) abort();
    return 0;
}
