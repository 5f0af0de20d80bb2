/* Unit tests of the gnss core: UBX/NMEA/RTCM3 framing, resynchronisation, chunking
 * invariance, field decoding and the NMEA fallback rule. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gnss_driver.h"
#include "gnss_nmea.h"
#include "gnss_stream.h"
#include "gnss_ubx.h"
#include "pb_check.h"

/* ---------------------------------------------------------------- builders */

typedef struct {
    uint8_t b[1 << 16];
    size_t n;
} bytes_t;

static void put(bytes_t *s, const void *p, size_t n) { memcpy(s->b + s->n, p, n); s->n += n; }

static void put_nmea(bytes_t *s, const char *body)
{
    uint8_t ck = 0;
    for (const char *p = body; *p; p++) ck ^= (uint8_t)*p;
    char line[256];
    int n = snprintf(line, sizeof line, "$%s*%02X\r\n", body, ck);
    put(s, line, (size_t)n);
}

static void le32(uint8_t *p, int32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)((uint32_t)v >> (8 * i)); }

/* NAV-PVT at hh:mm:ss.000 UTC on 2022-01-18, lat/lon in 1e-7 deg. */
static void put_pvt(bytes_t *s, int hh, int mm, int ss, int32_t lat, int32_t lon, uint8_t flags)
{
    uint8_t p[92] = { 0 };
    le32(p + 0, ((hh * 60 + mm) * 60 + ss) * 1000);
    p[4] = 2022 & 0xFF; p[5] = 2022 >> 8; p[6] = 1; p[7] = 18; p[8] = (uint8_t)hh; p[9] = (uint8_t)mm; p[10] = (uint8_t)ss;
    p[11] = 0x07;          /* validDate, validTime, fullyResolved */
    p[20] = 3;
    p[21] = flags;
    p[23] = 9;
    le32(p + 24, lon);
    le32(p + 28, lat);
    le32(p + 32, 85162);
    le32(p + 36, 36678);
    le32(p + 40, 1500);
    le32(p + 64, -9000000);  /* headMot -90 deg */
    uint8_t f[100];
    put(s, f, gnss_ubx_frame_build(1, 7, p, 92, f));
}

static void put_rtcm3(bytes_t *s, int type, size_t len)
{
    uint8_t f[1100] = { 0xD3, (uint8_t)(len >> 8), (uint8_t)len };
    f[3] = (uint8_t)(type >> 4);
    f[4] = (uint8_t)(type << 4);
    for (size_t i = 2; i < len; i++) f[3 + i] = (uint8_t)(i * 7);
    /* CRC-24Q, same polynomial as the core, computed here bit by bit. */
    uint32_t crc = 0;
    for (size_t i = 0; i < 3 + len; i++) {
        crc ^= (uint32_t)f[i] << 16;
        for (int b = 0; b < 8; b++) { crc <<= 1; if (crc & 0x1000000) crc ^= 0x1864CFB; }
    }
    f[3 + len] = (uint8_t)(crc >> 16); f[4 + len] = (uint8_t)(crc >> 8); f[5 + len] = (uint8_t)crc;
    put(s, f, 6 + len);
}

/* ---------------------------------------------------------------- stream trace */

typedef struct {
    char text[1 << 16];
    size_t n;
} trace_t;

static void tr(trace_t *t, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int k = vsnprintf(t->text + t->n, sizeof t->text - t->n, fmt, ap);
    va_end(ap);
    if (k > 0) t->n += (size_t)k;
}
static void t_ubx(void *u, int64_t off, const gnss_ubx_frame_t *f) { tr(u, "U%lld:%02x%02x/%u ", (long long)off, f->msg_class, f->msg_id, f->len); }
static void t_nmea(void *u, int64_t off, const gnss_nmea_sentence_t *s) { tr(u, "N%lld:%s ", (long long)off, s->address); }
static void t_rtcm(void *u, int64_t off, int type, size_t total) { tr(u, "R%lld:%d/%zu ", (long long)off, type, total); }
static void t_err(void *u, int64_t off, gnss_stream_error_t e, const char *d) { tr(u, "E%lld:%s ", (long long)off, gnss_stream_error_name(e)); }
static void t_skip(void *u, int64_t off, int64_t n) { tr(u, "S%lld+%lld ", (long long)off, (long long)n); }

static void trace_stream(const bytes_t *in, size_t chunk, unsigned seed, trace_t *t)
{
    memset(t, 0, sizeof *t);
    gnss_stream_handlers_t h = { t_ubx, t_nmea, t_rtcm, t_err, t_skip, t };
    gnss_stream_t *s = gnss_stream_create(NULL, &h);
    size_t off = 0;
    while (off < in->n) {
        size_t k = chunk ? chunk : 1 + (size_t)(rand_r(&seed) % 700);
        if (k > in->n - off) k = in->n - off;
        gnss_stream_feed(s, in->b + off, k);
        off += k;
    }
    gnss_stream_finish(s);
    CHECK(gnss_stream_offset(s) == (int64_t)in->n);
    gnss_stream_destroy(s);
}

static void test_ubx_frames(void)
{
    const uint8_t poll[] = { 0xB5, 0x62, 0x06, 0x00, 0x00, 0x00, 0x06, 0x18 };   /* UBX-CFG-PRT poll */
    gnss_ubx_frame_t f;
    CHECK(gnss_ubx_frame_check(poll, sizeof poll, 8192, &f) == GNSS_UBX_FRAME && f.total == 8);
    for (size_t n = 0; n < sizeof poll; n++) CHECK(gnss_ubx_frame_check(poll, n, 8192, &f) == GNSS_UBX_NEED_MORE);
    uint8_t bad[8];
    memcpy(bad, poll, 8);
    bad[7] ^= 1;
    CHECK(gnss_ubx_frame_check(bad, 8, 8192, &f) == GNSS_UBX_BAD_CHECKSUM && f.ck_b_calc == 0x18 && f.ck_b == 0x19);
    CHECK(gnss_ubx_frame_check((const uint8_t *)"\xB5\x63", 2, 8192, &f) == GNSS_UBX_NOT_SYNC);
    const uint8_t longhdr[] = { 0xB5, 0x62, 0x01, 0x07, 0xFF, 0xFF };
    CHECK(gnss_ubx_frame_check(longhdr, 6, 8192, &f) == GNSS_UBX_TOO_LONG);   /* decided on the header */
}

static void test_resync_and_chunking(void)
{
    static bytes_t in;
    memset(&in, 0, sizeof in);
    put(&in, "{\"class\":\"VERSION\"}\n", 20);                         /* gpsd JSON in front: skipped */
    put_pvt(&in, 8, 2, 47, 534507167, -22402308, 1);
    put_nmea(&in, "GPGGA,080247.00,5327.04300,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,");
    /* A header claiming 200 bytes, then a good frame inside that span. */
    const uint8_t fake[] = { 0xB5, 0x62, 0x01, 0x07, 200, 0 };
    size_t fake_at = in.n;
    put(&in, fake, sizeof fake);
    size_t inner_at = in.n;
    put_pvt(&in, 8, 2, 48, 534507186, -22402314, 1);
    put_rtcm3(&in, 1077, 120);
    put(&in, "$GPGGA,080249.00,5327.0", 23);                           /* cut by a new sentence */
    put_nmea(&in, "GNRMC,080249.00,A,5327.04300,N,00214.41385,W,0.025,,180122,,,A,V");
    put(&in, "$GPGGA,1*00\r\n", 13);                                    /* wrong checksum */
    put(&in, "$GPGSA333333333333,A,3*00\r\n", 27);                      /* address too long: not a sentence */
    put(&in, "$GPGGA,123\xB5\x62", 12);                                 /* binary inside a sentence */
    put_pvt(&in, 8, 2, 50, 534507207, -22402319, 1);
    put(&in, (const uint8_t[]){ 0xB5, 0x62, 0x01, 0x07, 92, 0, 1, 2 }, 8);   /* cut at the end */

    trace_t whole, bytewise, random;
    trace_stream(&in, in.n, 0, &whole);
    trace_stream(&in, 1, 0, &bytewise);
    CHECK(strcmp(whole.text, bytewise.text) == 0);
    for (unsigned seed = 1; seed < 20; seed++) {
        trace_stream(&in, 0, seed, &random);
        CHECK(strcmp(whole.text, random.text) == 0);
    }
    char want[64];
    snprintf(want, sizeof want, "E%zu:ubx_bad_checksum ", fake_at);
    CHECK_CONTAINS(whole.text, want);
    snprintf(want, sizeof want, "U%zu:0107/92 ", inner_at);
    CHECK_CONTAINS(whole.text, want);      /* the good frame inside the bad one's length */
    CHECK_CONTAINS(whole.text, "S0+20 ");
    CHECK_CONTAINS(whole.text, ":1077/126 ");
    CHECK_CONTAINS(whole.text, ":nmea_truncated ");
    CHECK_CONTAINS(whole.text, ":GNRMC ");
    CHECK_CONTAINS(whole.text, ":nmea_bad_checksum ");
    CHECK_CONTAINS(whole.text, ":nmea_bad_char ");
    CHECK_CONTAINS(whole.text, ":ubx_truncated ");
    int pvts = 0;
    for (const char *p = whole.text; (p = strstr(p, ":0107/92 ")); p++) pvts++;
    CHECK(pvts == 3);
    if (strcmp(whole.text, bytewise.text) != 0) fprintf(stderr, "whole:    %s\nbytewise: %s\n", whole.text, bytewise.text);
}

/* ---------------------------------------------------------------- NMEA fields */

static int check_sentence(const char *text, gnss_nmea_sentence_t *s)
{
    return gnss_nmea_sentence_check(text, strlen(text), GNSS_NMEA_MAX_LEN_DEFAULT, 1, s);
}

static void test_nmea_fields(void)
{
    gnss_nmea_sentence_t s;
    int bad;
    CHECK(check_sentence("$GNGGA,003956.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,*56\r\n", &s) == GNSS_NMEA_SENTENCE);
    CHECK(strcmp(s.address, "GNGGA") == 0 && strcmp(s.type, "GGA") == 0);
    gnss_nmea_gga_t g;
    CHECK(gnss_nmea_parse_gga(&s, &g, &bad) == 0);
    CHECK(g.tod_ms == (39 * 60 + 56) * 1000);
    CHECK_NEAR(g.lat_deg, -45.8775671667, 1e-10);    /* pynmeagps, oracle */
    CHECK_NEAR(g.lon_deg, 170.5001113333, 1e-10);
    CHECK(g.quality == 1 && g.num_sv == 12);
    CHECK_NEAR(g.alt_msl_m, 14.2, 1e-12);
    CHECK_NEAR(g.geoid_sep_m, 1.8, 1e-12);
    CHECK(check_sentence("$GNRMC,003956.00,A,4552.65403,S,17030.00668,E,0.025,,120419,,,A,V*07", &s) == GNSS_NMEA_SENTENCE);
    gnss_nmea_rmc_t r;
    CHECK(gnss_nmea_parse_rmc(&s, &r, &bad) == 0);
    CHECK(r.has_date && r.year == 2019 && r.month == 4 && r.day == 12 && r.mode == 'A' && r.status == 'A');
    CHECK_NEAR(r.speed_knots, 0.025, 1e-12);
    CHECK(isnan(r.course_deg));
    /* An empty fix (receiver without position yet): fields empty, no error. */
    bytes_t e = { .n = 0 };
    put_nmea(&e, "GPGGA,,,,,,0,00,99.99,,,,,,");
    e.b[e.n] = 0;
    CHECK(check_sentence((const char *)e.b, &s) == GNSS_NMEA_SENTENCE);
    CHECK(gnss_nmea_parse_gga(&s, &g, &bad) == 0 && g.tod_ms == -1 && !g.has_pos && isnan(g.alt_msl_m));
    /* Malformed fields: minutes >= 60, a hemisphere that is not N/S, letters in a number. */
    const char *bads[] = { "GPGGA,080247.00,5360.00000,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,",
                           "GPGGA,080247.00,5327.04300,X,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,",
                           "GPGGA,080247.00,5327.04300,N,00214.41385,W,1,07,1.63,3e6,M,48.5,M,,",
                           "GPGGA,256000.00,5327.04300,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,",
                           "GPGGA,080247.00,5327.04300,N" };
    for (size_t i = 0; i < sizeof bads / sizeof bads[0]; i++) {
        bytes_t b = { .n = 0 };
        put_nmea(&b, bads[i]);
        b.b[b.n] = 0;
        CHECK(check_sentence((const char *)b.b, &s) == GNSS_NMEA_SENTENCE);
        CHECK(gnss_nmea_parse_gga(&s, &g, &bad) == -1 && bad > 0);
    }
    CHECK(check_sentence("$GNGST,003956.00,235111,,,,2.3,3.5,4.0*46", &s) == GNSS_NMEA_SENTENCE);
    gnss_nmea_gst_t t;
    CHECK(gnss_nmea_parse_gst(&s, &t, &bad) == 0 && t.tod_ms == (39 * 60 + 56) * 1000);
    CHECK(isnan(t.std_major_m) && t.std_lat_m == 2.3 && t.std_lon_m == 3.5 && t.std_alt_m == 4.0);
    CHECK(gnss_nmea_parse_gst(&s, &t, &bad) == 0);
    CHECK(check_sentence("$GPGGA,1,2", &s) == GNSS_NMEA_TRUNCATED);
    CHECK(gnss_nmea_sentence_check("$GPGGA,1,2", 10, 200, 0, &s) == GNSS_NMEA_NEED_MORE);
    CHECK(check_sentence("$GPGGA,1,2\r\n", &s) == GNSS_NMEA_NO_CHECKSUM);
    CHECK(check_sentence("$\x01\x02", &s) == GNSS_NMEA_NOT_START);
}

/* ---------------------------------------------------------------- NAV-PVT -> fix */

static void test_nav_pvt_fix(void)
{
    uint8_t p[92] = { 0 };
    p[4] = 2022 & 0xFF; p[5] = 2022 >> 8; p[6] = 1; p[7] = 18; p[8] = 8; p[9] = 2; p[10] = 47;
    p[11] = 0x07;
    le32(p + 16, -175377);   /* nano: fix time is 175.377 us before the second */
    p[20] = 3;
    p[21] = 0x01 | (2 << 6); /* gnssFixOK, carrSoln fixed */
    le32(p + 64, -9000000);
    gnss_nav_pvt_t v;
    gnss_fix_out_t f;
    CHECK(gnss_ubx_nav_pvt_decode(p, 92, &v) == 0);
    CHECK(gnss_ubx_nav_pvt_decode(p, 83, &v) == -1);
    gnss_ubx_nav_pvt_decode(p, 92, &v);
    gnss_fix_from_nav_pvt(&v, &f);
    CHECK(f.fix_type == GNSS_FIX_RTK_FIXED);
    CHECK(f.has_utime && f.utime == 1642492967LL * 1000000 - 175);   /* 2022-01-18T08:02:47Z */
    CHECK_NEAR(f.heading_deg, 270.0, 1e-9);
    v.flags = 0;           /* gnssFixOK clear */
    gnss_fix_from_nav_pvt(&v, &f);
    CHECK(f.fix_type == GNSS_FIX_NONE);
    v.flags = 1;
    v.flags3 = 1;          /* invalidLlh */
    gnss_fix_from_nav_pvt(&v, &f);
    CHECK(f.fix_type == GNSS_FIX_NONE && isnan(f.lat_deg) && isnan(f.alt_m));
    v.flags3 = 0;
    v.valid = 0x01;        /* date without time */
    gnss_fix_from_nav_pvt(&v, &f);
    CHECK(!f.has_utime && f.fix_type == GNSS_FIX_3D);
    CHECK(gnss_days_from_civil(1970, 1, 1) == 0 && gnss_days_from_civil(2000, 3, 1) == 11017);
}

/* ---------------------------------------------------------------- fallback rule */

typedef struct {
    int n;
    gnss_source_t src[64];
    int64_t utime[64];
} fixes_t;
static void on_fix(void *u, const gnss_fix_out_t *f)
{
    fixes_t *x = u;
    if (x->n < 64) { x->src[x->n] = f->source; x->utime[x->n] = f->utime; x->n++; }
}

static int n_acc;
static void on_fix_acc(void *u, const gnss_fix_out_t *f)
{
    if (n_acc < 8) ((double *)u)[n_acc++] = f->h_acc_m;
}

static gnss_driver_t *run_driver(const bytes_t *in, fixes_t *out)
{
    memset(out, 0, sizeof *out);
    gnss_driver_handlers_t h = { .on_fix = on_fix, .user = out };
    gnss_driver_t *d = gnss_driver_create(NULL, &h);
    gnss_driver_feed(d, in->b, in->n);
    gnss_driver_finish(d);
    return d;
}

static void epoch_nmea(bytes_t *b, int ss)
{
    char s[160];
    snprintf(s, sizeof s, "GNRMC,0802%02d.00,A,5327.04300,N,00214.41385,W,0.1,,180122,,,A,V", ss);
    put_nmea(b, s);
    snprintf(s, sizeof s, "GNGGA,0802%02d.00,5327.04300,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,", ss);
    put_nmea(b, s);
}

static void test_fallback(void)
{
    static bytes_t b;
    fixes_t x;
    gnss_driver_t *d;
    const int64_t t0 = 1642492920LL * 1000000;   /* 2022-01-18T08:02:00Z */

    /* NAV-PVT first each epoch; the 08:02:12 NAV-PVT is lost: its NMEA fills in. */
    b.n = 0;
    for (int ss = 10; ss < 15; ss++) {
        if (ss != 12) put_pvt(&b, 8, 2, ss, 534507167, -22402308, 1);
        epoch_nmea(&b, ss);
    }
    d = run_driver(&b, &x);
    CHECK(x.n == 5);
    for (int i = 0; i < x.n && i < 5; i++) {
        CHECK(x.utime[i] == t0 + (10 + i) * 1000000LL);
        CHECK(x.src[i] == (i == 2 ? GNSS_SRC_NMEA : GNSS_SRC_UBX_NAV_PVT));
    }
    CHECK(gnss_driver_counter(d, GNSS_C_NMEA_FILLS) == 1 && gnss_driver_counter(d, GNSS_C_NMEA_SUPPRESSED) == 4);
    gnss_driver_destroy(d);

    /* NMEA first each epoch: a lost NAV-PVT is not filled (its NMEA came before we could
     * know), and no epoch is published twice. */
    b.n = 0;
    for (int ss = 10; ss < 15; ss++) {
        epoch_nmea(&b, ss);
        if (ss != 12) put_pvt(&b, 8, 2, ss, 534507167, -22402308, 1);
    }
    d = run_driver(&b, &x);
    CHECK(x.n == 5);   /* the first epoch: NMEA (no NAV-PVT yet), then its NAV-PVT */
    CHECK(x.src[0] == GNSS_SRC_NMEA && x.src[1] == GNSS_SRC_UBX_NAV_PVT && x.utime[0] == x.utime[1]);
    for (int i = 2; i < x.n; i++) CHECK(x.src[i] == GNSS_SRC_UBX_NAV_PVT);
    gnss_driver_destroy(d);

    /* NAV-PVT stops on a NAV-PVT-first stream: 11 and 12 are fills (within the 2 s
     * hold-off), from 13 on plain fallback. */
    b.n = 0;
    put_pvt(&b, 8, 2, 10, 534507167, -22402308, 1);
    for (int ss = 10; ss < 16; ss++) epoch_nmea(&b, ss);
    d = run_driver(&b, &x);
    CHECK(x.n == 1 + 5);
    for (int i = 1; i < x.n; i++) CHECK(x.utime[i] == t0 + (10 + i) * 1000000LL && x.src[i] == GNSS_SRC_NMEA);
    CHECK(gnss_driver_counter(d, GNSS_C_NMEA_FILLS) == 2 && gnss_driver_counter(d, GNSS_C_FIXES_NMEA) == 5);
    gnss_driver_destroy(d);

    /* NAV-PVT stops on an NMEA-first stream (fills impossible): NMEA resumes only
     * after the hold-off, at 13 (12 is exactly 2 s after the last NAV-PVT). */
    b.n = 0;
    epoch_nmea(&b, 10);
    put_pvt(&b, 8, 2, 10, 534507167, -22402308, 1);
    for (int ss = 11; ss < 16; ss++) epoch_nmea(&b, ss);
    d = run_driver(&b, &x);
    CHECK(x.n == 2 + 3);
    CHECK(x.src[2] == GNSS_SRC_NMEA && x.utime[2] == t0 + 13 * 1000000LL);
    CHECK(gnss_driver_counter(d, GNSS_C_NMEA_FILLS) == 0);
    gnss_driver_destroy(d);

    /* GST after GGA and RMC: once seen, epochs wait for it and take its sigmas. */
    b.n = 0;
    for (int ss = 10; ss < 13; ss++) {
        char gst[96];
        epoch_nmea(&b, ss);
        snprintf(gst, sizeof gst, "GNGST,0802%02d.00,43,,,,3.0,4.0,5.0", ss);
        put_nmea(&b, gst);
    }
    memset(&x, 0, sizeof x);
    static double hacc[8];
    {
        gnss_driver_handlers_t h = { .on_fix = on_fix_acc, .user = hacc };
        d = gnss_driver_create(NULL, &h);
        gnss_driver_feed(d, b.b, b.n);
        gnss_driver_finish(d);
        CHECK(gnss_driver_counter(d, GNSS_C_FIXES_NMEA) == 3 && gnss_driver_counter(d, GNSS_C_NMEA_GST) == 3);
        CHECK(isnan(hacc[0]) && hacc[1] == 5.0 && hacc[2] == 5.0);   /* sqrt(3^2 + 4^2) */
        gnss_driver_destroy(d);
    }

    /* Midnight: the date moves on for a GGA-only epoch after the RMC's day. */
    b.n = 0;
    put_nmea(&b, "GNRMC,235959.00,A,5327.04300,N,00214.41385,W,0.1,,311221,,,A,V");
    put_nmea(&b, "GNGGA,235959.00,5327.04300,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,");
    put_nmea(&b, "GNGGA,000000.00,5327.04300,N,00214.41385,W,1,07,1.63,36.7,M,48.5,M,,");
    d = run_driver(&b, &x);
    CHECK(x.n == 2 && x.utime[1] == 1640995200LL * 1000000);   /* 2022-01-01T00:00:00Z */
    gnss_driver_destroy(d);
}

int main(void)
{
    test_ubx_frames();
    test_resync_and_chunking();
    test_nmea_fields();
    test_nav_pvt_fix();
    test_fallback();
    return pb_check_report("test_gnss_core");
}
