/* libFuzzer target: arbitrary bytes as one NMEA sentence (framing, GGA, RMC, GST fields)
 * and as an NMEA stream through the driver. Checks: consumed length inside the input,
 * checksum really matches, decoded values in range.
 * fuzz-sources: modules/gnss/core/gnss_ubx.c modules/gnss/core/gnss_nmea.c modules/gnss/core/gnss_stream.c modules/gnss/core/gnss_driver.c */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "gnss/core/gnss_driver.h"

static void on_fix(void *u, const gnss_fix_out_t *f)
{
    if (!isnan(f->lat_deg) && (fabs(f->lat_deg) > 90 || fabs(f->lon_deg) > 180)) abort();
    if (f->has_utime && f->utime < 0) abort();
    if (!isnan(f->heading_deg) && (f->heading_deg < 0 || f->heading_deg >= 360.0001)) abort();
    if (f->h_acc_m < 0 || f->v_acc_m < 0) abort();   /* NaN compares false */
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    const char *p = (const char *)data;
    for (int at_end = 0; at_end < 2; at_end++) {
        gnss_nmea_sentence_t s;
        gnss_nmea_result_t r = gnss_nmea_sentence_check(p, size, GNSS_NMEA_MAX_LEN_DEFAULT, at_end, &s);
        if (r == GNSS_NMEA_NEED_MORE && at_end) abort();
        if (r != GNSS_NMEA_SENTENCE && r != GNSS_NMEA_NEED_MORE && r != GNSS_NMEA_NOT_START &&
            (s.total == 0 || s.total > size)) abort();
        if (r != GNSS_NMEA_SENTENCE) continue;
        if (s.total > size || s.body_len + 4 > s.total) abort();
        uint8_t ck = 0;
        for (size_t i = 0; i < s.body_len; i++) ck ^= (uint8_t)s.body[i];
        if (ck != s.ck_recv) abort();
        int bad;
        gnss_nmea_gga_t g;
        if (gnss_nmea_parse_gga(&s, &g, &bad) == 0) {
            if (g.has_pos && (fabs(g.lat_deg) > 90 || fabs(g.lon_deg) > 180)) abort();
            if (g.tod_ms >= 86401000) abort();
        } else if (bad < 0) abort();
        gnss_nmea_gst_t t;
        if (gnss_nmea_parse_gst(&s, &t, &bad) == 0 && (t.std_lat_m < 0 || t.std_lon_m < 0 || t.std_alt_m < 0)) abort();
        gnss_nmea_rmc_t m;
        if (gnss_nmea_parse_rmc(&s, &m, &bad) == 0) {
            if (m.has_pos && (fabs(m.lat_deg) > 90 || fabs(m.lon_deg) > 180)) abort();
            if (m.has_date && (m.month < 1 || m.month > 12 || m.day < 1 || m.day > 31)) abort();
        }
    }
    gnss_driver_handlers_t h = { .on_fix = on_fix };
    gnss_driver_t *d = gnss_driver_create(NULL, &h);
    gnss_driver_feed(d, data, size);
    gnss_driver_finish(d);
    gnss_driver_destroy(d);
    return 0;
}
