/* libFuzzer target: Ouster metadata JSON, arbitrary bytes. Accepted metadata must be
 * self-consistent and give a driver; refused metadata must say why.
 * fuzz-sources: modules/ouster/core/ouster_meta.c modules/ouster/core/ouster_driver.c modules/ouster/core/ouster_packet.c common/pb_err.c
 * fuzz-libs: -lcjson */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "ouster/core/ouster_driver.h"
#include "ouster/core/ouster_meta.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static ouster_meta_t m;
    pb_err_t err = { { 0 } };
    if (ouster_meta_parse((const char *)data, size, &m, &err) != 0) {
        if (err.msg[0] == 0) abort();
        return 0;
    }
    if (m.rows < 1 || m.rows > OUSTER_MAX_ROWS || m.cols_per_frame < 1 || m.cols_per_frame > OUSTER_MAX_COLS) abort();
    if (m.cols_per_packet < 1 || m.cols_per_packet > m.cols_per_frame) abort();
    if (m.column_window[0] < 0 || m.column_window[1] >= m.cols_per_frame) abort();
    if (m.profile == OUSTER_PROFILE_UNKNOWN) abort();
    ouster_config_t cfg;
    ouster_config_default(&cfg);
    ouster_driver_t *d = ouster_driver_create(&m, &cfg, NULL, NULL, NULL, &err);
    if (!d && err.msg[0] == 0) abort();
    if (d) {
        /* one packet of zeros of the right size: columns invalid, nothing published */
        size_t n = ouster_driver_layout(d)->packet_size;
        if (n <= 65536) {
            uint8_t *z = calloc(1, n);
            ouster_driver_lidar_packet(d, z, n, 0);
            free(z);
        }
        ouster_driver_destroy(d);
    }
    return 0;
}
