/* libFuzzer target: import-scans' pose, time and calib files (tools/import-scans/pose_files)
 * from arbitrary bytes, each reader on the same input. Errors are expected; crashes and
 * undefined behaviour are not, and a pose read must be a rotation with finite numbers.
 * fuzz-sources: tools/import-scans/pose_files.cpp common/pb_err.c
 * fuzz-libs: -Itools/import-scans -I/usr/include/eigen3 */
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "fuzz_common.h"
#include "pose_files.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *path = fuzz_input_file("import_poses", ".txt", data, size);
    if (!path) return 0;
    pb_err_t err;
    std::vector<Eigen::Isometry3d> poses;
    std::vector<int64_t> times;
    PoseFormat fmt;
    if (read_poses(path, poses, times, &fmt, &err) == 0) {
        for (const auto &T : poses)
            if (!T.matrix().allFinite() || std::fabs(T.linear().determinant() - 1) > 1e-6) abort();
        for (size_t k = 1; k < times.size(); k++)
            if (times[k] <= times[k - 1]) abort();
    }
    times.clear();
    read_times(path, times, &err);
    Eigen::Isometry3d Tr;
    read_calib_tr(path, &Tr, &err);
    return 0;
}
