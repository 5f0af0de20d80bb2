/* libFuzzer target: arbitrary bytes as a u-blox serial stream (UBX framing, NAV-PVT
 * decoding, the whole driver). Checks: a frame found is inside the input and its
 * checksum really matches; the driver gives the same fixes and errors however the
 * bytes are chunked; every byte is accounted for.
 * fuzz-sources: modules/gnss/core/gnss_ubx.c modules/gnss/core/gnss_nmea.c modules/gnss/core/gnss_stream.c modules/gnss/core/gnss_driver.c */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gnss/core/gnss_driver.h"

typedef struct {
    uint64_t hash;
    int64_t fixes, errors, last_offset;
} digest_t;

static void mix(digest_t *d, uint64_t v) { d->hash = (d->hash ^ v) * 0x100000001b3ULL; }

static void on_fix(void *u, const gnss_fix_out_t *f)
{
    digest_t *d = u;
    d->fixes++;
    mix(d, (uint64_t)f->offset);
    mix(d, (uint64_t)f->utime);
    mix(d, (uint64_t)f->fix_type);
    if (f->source == GNSS_SRC_UBX_NAV_PVT && !isnan(f->lat_deg) && fabs(f->lat_deg) > 214.75) abort();
    if (f->source == GNSS_SRC_NMEA && !isnan(f->lat_deg) && (fabs(f->lat_deg) > 90 || fabs(f->lon_deg) > 180)) abort();
    if (f->fix_type < 0 || f->fix_type > 7) abort();
}

static void on_error(void *u, gnss_counter_t c, int64_t off, const char *detail)
{
    digest_t *d = u;
    d->errors++;
    mix(d, (uint64_t)c);
    mix(d, (uint64_t)off);
    if (!detail || strlen(detail) == 0) abort();
}

static void run(const uint8_t *data, size_t size, size_t chunk, digest_t *dg, int64_t counters[GNSS_C_COUNT])
{
    memset(dg, 0, sizeof *dg);
    gnss_driver_config_t cfg;
    gnss_driver_config_default(&cfg);
    cfg.stream.max_ubx_payload = 1024;   /* keeps inputs of <= 4 KB interesting */
    gnss_driver_handlers_t h = { .on_fix = on_fix, .on_error = on_error, .user = dg };
    gnss_driver_t *d = gnss_driver_create(&cfg, &h);
    for (size_t off = 0; off < size; off += chunk)
        gnss_driver_feed(d, data + off, size - off < chunk ? size - off : chunk);
    gnss_driver_finish(d);
    if (gnss_driver_offset(d) != (int64_t)size) abort();
    for (int c = 0; c < GNSS_C_COUNT; c++) counters[c] = gnss_driver_counter(d, (gnss_counter_t)c);
    gnss_driver_destroy(d);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    gnss_ubx_frame_t f;
    gnss_ubx_result_t r = gnss_ubx_frame_check(data, size, 65535, &f);
    if (r == GNSS_UBX_FRAME) {
        if (f.total > size || f.total != (size_t)f.len + 8) abort();
        uint8_t a, b;
        gnss_ubx_checksum(data + 2, (size_t)f.len + 4, &a, &b);
        if (a != data[6 + f.len] || b != data[7 + f.len]) abort();
        gnss_nav_pvt_t pvt;
        gnss_fix_out_t fix;
        if (gnss_ubx_nav_pvt_decode(f.payload, f.len, &pvt) == 0) gnss_fix_from_nav_pvt(&pvt, &fix);
    }
    digest_t whole, pieces;
    int64_t c1[GNSS_C_COUNT], c2[GNSS_C_COUNT];
    run(data, size, size ? size : 1, &whole, c1);
    run(data, size, 1 + (size ? data[0] % 97 : 0), &pieces, c2);
    if (whole.hash != pieces.hash || memcmp(c1, c2, sizeof c1) != 0) abort();
    return 0;
}
