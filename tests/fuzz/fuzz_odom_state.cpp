/* libFuzzer target: the mapper's odometry state as a checkpoint holds it
 * (modules/mapper/core/odometry: pb_odom_restore) from arbitrary bytes; a state that
 * restores is saved again and must restore to the same bytes, and takes a sweep.
 * Errors are expected; crashes, undefined behaviour and leaks are not.
 * fuzz-sources: modules/mapper/core/odometry.cpp modules/localizer/core/registration.cpp modules/localizer/core/regmap.cpp modules/localizer/core/deskew.cpp modules/localizer/core/window_search.cpp modules/localizer/core/map_tiles.cpp modules/localizer/core/places.cpp common/pb_err.c common/pb_pcd.c
 * fuzz-libs: -Wno-deprecated -Imodules/localizer/core -Imodules/mapper/core -I/usr/include/pcl-1.13 -I/usr/include/eigen3 -lpcl_io -lpcl_common -lpthread */
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "odometry.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    pb_err_t err;
    pb_odom_t *o = pb_odom_restore(data, size, nullptr, nullptr, &err);
    if (!o) return 0;
    std::vector<uint8_t> again;
    pb_odom_save(o, &again);
    pb_odom_t *o2 = pb_odom_restore(again.data(), again.size(), nullptr, nullptr, &err);
    if (!o2) abort();   /* what was saved must restore */
    std::vector<uint8_t> third;
    pb_odom_save(o2, &third);
    if (third != again) abort();
    float sweep[3 * 40];
    int32_t offset[40];
    for (int i = 0; i < 40; i++) {
        sweep[3 * i] = (float)(5 + i % 7); sweep[3 * i + 1] = (float)(i % 5) - 2; sweep[3 * i + 2] = (float)(i % 3);
        offset[i] = 2500 * i;
    }
    pb_odom_result_t r;
    pb_odom_add(o2, 1700000000000000LL, sweep, offset, 40, nullptr, &r, &err);
    pb_odom_destroy(o2);
    pb_odom_destroy(o);
    return 0;
}
