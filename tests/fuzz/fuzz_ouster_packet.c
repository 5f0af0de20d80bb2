/* libFuzzer target: a stream of Ouster lidar and IMU packets, arbitrary bytes, into the
 * driver of a small sensor (8 beams, 64 columns, 4 per packet) of each profile. Every
 * published scan must be consistent (pb_scan accepts it) and every IMU sample finite.
 * Input: byte 0 = profile (low 2 bits) and return (bit 2); then records of
 * [u16 length (bit 15: IMU)][bytes].
 * fuzz-sources: modules/ouster/core/ouster_driver.c modules/ouster/core/ouster_packet.c modules/ouster/core/ouster_meta.c common/pb_scan.c common/pb_err.c
 * fuzz-libs: -lcjson */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"
#include "ouster/core/ouster_driver.h"
#include "pb_scan.h"

static pb_points_t pts;

static void on_scan(const portobello_lidar_scan_t *s, int64_t t, void *user)
{
    pb_err_t err;
    if (s->npixels != s->rows * s->cols || s->seq < 0 || s->seq > 65535) abort();
    if (pb_scan_points(s, &pts, &err) < 0) abort();
    for (int i = 0; i < s->npixels; i++) if (s->range_mm[i] < 0 || s->range_mm[i] >= (1 << 20)) abort();
}

static void on_imu(const portobello_imu_t *m, int64_t t, void *user)
{
    for (int i = 0; i < 3; i++) if (!isfinite(m->accel[i]) || !isfinite(m->gyro[i])) abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    ouster_meta_t m;
    memset(&m, 0, sizeof m);
    m.rows = 8;
    m.cols_per_frame = 64;
    m.cols_per_packet = 4;
    m.column_window[1] = 63;
    m.frame_rate_hz = 10;
    m.profile = (ouster_profile_t)(OUSTER_PROFILE_LEGACY + (data[0] & 3));
    m.imu_profile_legacy = 1;
    m.init_id = (data[0] & 8) ? 0x010203 : 0;
    for (int r = 0; r < 8; r++) { m.beam_altitude_deg[r] = 10 - 3 * r; m.beam_azimuth_deg[r] = r % 2 ? 1.5 : -1.5; }
    static const double I[16] = { 1, 0, 0, 12.163, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 };
    static const double L[16] = { -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 36.18, 0, 0, 0, 1 };
    memcpy(m.beam_to_lidar, I, sizeof I);
    memcpy(m.lidar_to_sensor, L, sizeof L);
    memcpy(m.imu_to_sensor, I, sizeof I);
    ouster_config_t cfg;
    ouster_config_default(&cfg);
    cfg.which_return = (data[0] & 4) ? 2 : 1;
    pb_err_t err;
    ouster_driver_t *d = ouster_driver_create(&m, &cfg, on_scan, on_imu, NULL, &err);
    if (!d) abort();
    size_t off = 1;
    int64_t t = 1700000000000000;
    while (off + 2 <= size) {
        unsigned h = data[off] | data[off + 1] << 8;
        off += 2;
        size_t n = h & 0x7fff;
        if (n > size - off) n = size - off;
        uint8_t *p = fuzz_copy(data + off, n);     /* a private copy: ASan sees reads past the packet */
        if (h & 0x8000) ouster_driver_imu_packet(d, p, n, t);
        else ouster_driver_lidar_packet(d, p, n, t);
        free(p);
        off += n;
        t += 1000;
        ouster_driver_tick(d, t);
    }
    ouster_driver_flush(d, t);
    ouster_driver_destroy(d);
    return 0;
}
