/* libFuzzer target: common/pb_scan on a LIDAR_SCAN built from arbitrary bytes (either form,
 * or both, with sizes that may disagree; every number, floats included, taken raw from the
 * input, so NaN, infinities and huge values occur). The scan either gives finite points
 * and, when it says them, positive finite beam gaps, or is refused with a reason.
 * (lcm-gen's decoder is not fuzzed here: it mallocs whatever length a message claims.)
 * fuzz-sources: common/pb_scan.c common/pb_err.c */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"
#include "pb_scan.h"
#include "portobello_lidar_scan_t.h"

/* The next 4 input bytes (cyclically; zeros for an empty input). */
static uint32_t take(const uint8_t *data, size_t size, size_t *at)
{
    uint32_t v = 0;
    for (int i = 0; i < 4 && size; i++) v |= (uint32_t)data[(*at)++ % size] << (8 * i);
    return v;
}

static float take_float(const uint8_t *data, size_t size, size_t *at)
{
    uint32_t v = take(data, size, at);
    float f;
    memcpy(&f, &v, sizeof f);
    return f;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 4) return 0;
    size_t at = 4;
    portobello_lidar_scan_t s;
    memset(&s, 0, sizeof s);
    s.rows = data[0] % 9;
    s.cols = data[1] % 17;
    s.npixels = s.rows * s.cols + ((data[3] & 1) ? (data[3] >> 1) % 3 - 1 : 0);   /* sometimes inconsistent */
    s.npoints = (data[3] & 2) || s.npixels <= 0 ? data[2] % 65 : 0;
    if (s.npixels < 0) s.npixels = 0;
    int32_t range[16 * 9 + 2], offs[17], poff[64];
    uint8_t refl[16 * 9 + 2] = { 0 }, ring[64];
    float alt[9], az[9], x[64], y[64], z[64], in[64] = { 0 };
    for (int i = 0; i < s.npixels; i++) range[i] = (int32_t)(take(data, size, &at) % 200000) - 1000;
    for (int c = 0; c < s.cols; c++) offs[c] = (int32_t)take(data, size, &at);
    for (int r = 0; r < s.rows; r++) { alt[r] = take_float(data, size, &at); az[r] = take_float(data, size, &at); }
    for (int i = 0; i < 16; i++) s.lidar_from_beam[i] = (i % 5 == 0) ? 1 : ((data[3] & 4) ? take_float(data, size, &at) : 0);
    s.beam_origin_m = take_float(data, size, &at);
    for (int i = 0; i < s.npoints; i++) {
        x[i] = take_float(data, size, &at); y[i] = take_float(data, size, &at); z[i] = take_float(data, size, &at);
        poff[i] = (int32_t)take(data, size, &at);
        ring[i] = (uint8_t)take(data, size, &at);
    }
    s.range_mm = range; s.reflectivity = refl; s.col_offset_us = offs; s.beam_altitude_rad = alt; s.beam_azimuth_rad = az;
    s.x = x; s.y = y; s.z = z; s.intensity = in; s.point_offset_us = poff; s.ring = ring;

    pb_points_t pts = { 0 };
    pb_err_t err;
    err.msg[0] = 0;
    int n = pb_scan_points(&s, &pts, &err);
    if (n < 0 && !err.msg[0]) abort();              /* a refusal always says why */
    for (int i = 0; i < n; i++)
        if (!isfinite(pts.x[i]) || !isfinite(pts.y[i]) || !isfinite(pts.z[i])) abort();
    double ring_gap, col_gap;
    if (n >= 0 && pb_scan_beam_gaps(&s, &pts, &ring_gap, &col_gap) &&
        !(ring_gap > 0 && isfinite(ring_gap) && col_gap > 0 && isfinite(col_gap)))
        abort();
    pb_points_free(&pts);
    return 0;
}
