/* libFuzzer target: import-scans' scan readers (tools/import-scans/scan_files) from
 * arbitrary bytes. The first byte picks a --bin-fields list, the rest is the .bin file;
 * the same bytes are read as a PCD; a .bin read is given point times from azimuth (seam
 * from the file, then a fixed one). Errors are expected; crashes and undefined behaviour
 * are not, and every point kept must be finite with its time within the sweep.
 * fuzz-sources: tools/import-scans/scan_files.cpp common/pb_pcd.c common/pb_err.c
 * fuzz-libs: -Wno-deprecated -Itools/import-scans -I/usr/include/pcl-1.13 -I/usr/include/eigen3 -lpcl_io -lpcl_common
 * fuzz-max-len: 20000 */
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "fuzz_common.h"
#include "scan_files.h"

static const char *const kLayouts[] = {"x,y,z,i", "x,y,z", "x,y,z,i,ring", "x,y,z,i,ring,t", "_,x,y,z,t",
                                       "t,ring,z,y,x,_,_,_"};

static void check(const Scan &s, double sweep_us)
{
    if (s.y.size() != s.x.size() || s.z.size() != s.x.size() || s.intensity.size() != s.x.size()) abort();
    if (s.has_ring && s.ring.size() != s.x.size()) abort();
    if (s.has_time && s.offset_us.size() != s.x.size()) abort();
    for (size_t k = 0; k < s.x.size(); k++)
        if (!std::isfinite(s.x[k]) || !std::isfinite(s.y[k]) || !std::isfinite(s.z[k]) || !std::isfinite(s.intensity[k]))
            abort();
    if (sweep_us > 0)
        for (int32_t t : s.offset_us)
            if (t < 0 || t > sweep_us) abort();
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    BinLayout L;
    pb_err_t err;
    if (parse_bin_fields(kLayouts[data[0] % 6], &L, &err) != 0) abort();
    const char *path = fuzz_input_file("import_scans", ".bin", data + 1, size - 1);
    if (!path) return 0;
    Scan s;
    if (read_bin(path, L, (data[0] & 8) != 0, s, &err) == 0) {
        check(s, 0);
        for (double seam : {double(NAN), 1.0}) {
            Scan t = s;
            if (!t.has_time && times_from_azimuth(path, t, (data[0] & 16) != 0, seam, 100000, &err) == 0) check(t, 100000);
        }
    }
    Scan p;
    if (read_pcd(path, p, &err) == 0) check(p, 0);
    return 0;
}
