/* NMEA 0183 sentence framing and GGA/RMC fields. */
#include "gnss_nmea.h"

#include <math.h>
#include <string.h>

static int is_addr_char(char c) { return (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); }
static int hex_val(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

gnss_nmea_result_t gnss_nmea_sentence_check(const char *buf, size_t avail, size_t max_len,
                                            int at_end, gnss_nmea_sentence_t *s)
{
    memset(s, 0, sizeof *s);
    if (avail < 1) return at_end ? GNSS_NMEA_NOT_START : GNSS_NMEA_NEED_MORE;
    if (buf[0] != '$') return GNSS_NMEA_NOT_START;
    /* Address: 2..15 of [A-Z0-9], then ','. Anything else means this '$' is not a
     * sentence start (e.g. a '$' byte inside binary data): no error is counted. */
    size_t i = 1;
    while (i < avail && i <= 16 && is_addr_char(buf[i])) i++;
    size_t alen = i - 1;
    if (alen > 15) return GNSS_NMEA_NOT_START;   /* decided without reading past avail */
    if (i == avail) return at_end ? GNSS_NMEA_NOT_START : GNSS_NMEA_NEED_MORE;
    if (alen < 2 || buf[i] != ',') return GNSS_NMEA_NOT_START;
    memcpy(s->address, buf + 1, alen);
    s->address[alen] = 0;
    s->type = alen >= 3 ? s->address + alen - 3 : s->address;
    s->body = buf + 1;

    /* Every error says where it is (error_at) and how far to skip (total): up to the
     * offending byte, which may itself start the next frame. */
    size_t star = 0;
    for (i = i + 1; ; i++) {
        if (i >= max_len) { s->error_at = s->total = i; return GNSS_NMEA_TOO_LONG; }
        if (i >= avail) {
            if (!at_end) return GNSS_NMEA_NEED_MORE;
            s->error_at = s->total = i;
            return GNSS_NMEA_TRUNCATED;
        }
        unsigned char c = (unsigned char)buf[i];
        if (c == '*') { star = i; break; }
        if (c == '$') { s->error_at = s->total = i; return GNSS_NMEA_TRUNCATED; }
        if (c == '\r' || c == '\n') { s->error_at = s->total = i; return GNSS_NMEA_NO_CHECKSUM; }
        if (c < 0x20 || c > 0x7E) { s->error_at = s->total = i; return GNSS_NMEA_BAD_CHAR; }
    }
    s->body_len = star - 1;
    if (star + 2 >= max_len) { s->error_at = s->total = star; return GNSS_NMEA_TOO_LONG; }
    if (star + 2 >= avail) {
        if (!at_end) return GNSS_NMEA_NEED_MORE;
        s->error_at = star;
        s->total = avail;
        return GNSS_NMEA_TRUNCATED;
    }
    int h1 = hex_val(buf[star + 1]), h2 = hex_val(buf[star + 2]);
    if (h1 < 0 || h2 < 0) { s->error_at = star; s->total = star + 1; return GNSS_NMEA_NO_CHECKSUM; }
    uint8_t ck = 0;
    for (size_t k = 1; k < star; k++) ck ^= (uint8_t)buf[k];
    s->ck_calc = ck;
    s->ck_recv = (uint8_t)(h1 * 16 + h2);
    size_t end = star + 3;
    /* Take the CR LF that ends the line with it (either may be missing). */
    if (end == avail && !at_end) return GNSS_NMEA_NEED_MORE;
    if (end < avail && buf[end] == '\r') {
        end++;
        if (end == avail && !at_end) return GNSS_NMEA_NEED_MORE;
    }
    if (end < avail && buf[end] == '\n') end++;
    s->total = end;
    if (s->ck_recv != s->ck_calc) { s->error_at = star + 1; return GNSS_NMEA_BAD_CHECKSUM; }
    return GNSS_NMEA_SENTENCE;
}

/* ---------------------------------------------------------------- fields */

typedef struct {
    const char *p;
    size_t len;
} field_t;

static int split(const gnss_nmea_sentence_t *s, field_t *f, int max)
{
    int n = 0;
    size_t start = 0;
    for (size_t i = 0; i <= s->body_len; i++) {
        if (i == s->body_len || s->body[i] == ',') {
            if (n == max) return n;
            f[n].p = s->body + start;
            f[n].len = i - start;
            n++;
            start = i + 1;
        }
    }
    return n;
}

/* Unsigned decimal "ddd[.ddd]": integer part and fraction kept apart, so that
 * ddmm.mmmm splits exactly. */
typedef struct {
    int64_t ip;        /* integer part */
    double frac;       /* fraction, [0, 1) */
    int int_digits;    /* digits of the integer part */
} udec_t;

/* Returns 0 or -1. */
static int parse_udec(field_t f, udec_t *d)
{
    size_t i = 0;
    int64_t v = 0;
    int nd = 0;
    while (i < f.len && f.p[i] >= '0' && f.p[i] <= '9') {
        if (nd >= 15) return -1;
        v = v * 10 + (f.p[i] - '0');
        nd++;
        i++;
    }
    double fr = 0;
    int nf = 0;
    if (i < f.len && f.p[i] == '.') {
        i++;
        int64_t m = 0, div = 1;
        while (i < f.len && f.p[i] >= '0' && f.p[i] <= '9') {
            if (nf < 15) { m = m * 10 + (f.p[i] - '0'); div *= 10; }
            nf++;
            i++;
        }
        fr = (double)m / (double)div;
    }
    if (i != f.len || nd + nf == 0) return -1;
    d->ip = v;
    d->frac = fr;
    d->int_digits = nd;
    return 0;
}

/* Signed decimal; empty -> NaN (ok). Returns 0 or -1. */
static int parse_num(field_t f, double *out)
{
    if (f.len == 0) { *out = NAN; return 0; }
    int neg = 0;
    if (f.p[0] == '-' || f.p[0] == '+') { neg = f.p[0] == '-'; f.p++; f.len--; }
    udec_t u;
    if (parse_udec(f, &u) != 0) return -1;
    double v = (double)u.ip + u.frac;
    *out = neg ? -v : v;
    return 0;
}

static int parse_int(field_t f, int *out)
{
    if (f.len == 0) { *out = -1; return 0; }
    udec_t u;
    if (parse_udec(f, &u) != 0 || u.frac != 0 || u.ip > 1000000) return -1;
    for (size_t i = 0; i < f.len; i++) if (f.p[i] == '.') return -1;
    *out = (int)u.ip;
    return 0;
}

/* hhmmss[.sss] -> ms of the day; empty -> -1. */
static int parse_tod(field_t f, int32_t *ms)
{
    if (f.len == 0) { *ms = -1; return 0; }
    udec_t u;
    if (parse_udec(f, &u) != 0 || u.int_digits != 6) return -1;
    int hh = (int)(u.ip / 10000), mm = (int)(u.ip / 100 % 100), ss = (int)(u.ip % 100);
    if (hh > 23 || mm > 59 || ss > 60) return -1;
    *ms = (int32_t)(((hh * 60 + mm) * 60 + ss) * 1000 + (int32_t)floor(u.frac * 1000.0 + 0.5));
    return 0;
}

/* (d)ddmm.mmmm + hemisphere -> signed degrees. Both empty -> *has = 0. */
static int parse_coord(field_t v, field_t hemi, int deg_digits, char pos, char neg, double *deg, int *has)
{
    if (v.len == 0 && hemi.len == 0) { *has = 0; return 0; }
    udec_t u;
    if (parse_udec(v, &u) != 0 || u.int_digits < 3 || u.int_digits > deg_digits + 2) return -1;
    if (hemi.len != 1 || (hemi.p[0] != pos && hemi.p[0] != neg)) return -1;
    int64_t d = u.ip / 100;
    double minutes = (double)(u.ip % 100) + u.frac;
    if (minutes >= 60.0 || d > (deg_digits == 2 ? 90 : 180)) return -1;
    double value = (double)d + minutes / 60.0;
    if (value > (deg_digits == 2 ? 90.0 : 180.0)) return -1;
    *deg = hemi.p[0] == neg ? -value : value;
    *has = 1;
    return 0;
}

int gnss_nmea_parse_gga(const gnss_nmea_sentence_t *s, gnss_nmea_gga_t *g, int *bad_field)
{
    field_t f[GNSS_NMEA_MAX_FIELDS];
    int n = split(s, f, GNSS_NMEA_MAX_FIELDS);
    memset(g, 0, sizeof *g);
    g->hdop = g->alt_msl_m = g->geoid_sep_m = NAN;
    *bad_field = 0;
    /* address,time,lat,N,lon,E,quality,numSV,HDOP,alt,M,sep,M[,diffAge,diffStation] */
    if (n < 13) { *bad_field = n; return -1; }
    if (parse_tod(f[1], &g->tod_ms)) { *bad_field = 1; return -1; }
    int has_lat = 0, has_lon = 0;
    if (parse_coord(f[2], f[3], 2, 'N', 'S', &g->lat_deg, &has_lat)) { *bad_field = 2; return -1; }
    if (parse_coord(f[4], f[5], 3, 'E', 'W', &g->lon_deg, &has_lon)) { *bad_field = 4; return -1; }
    if (has_lat != has_lon) { *bad_field = has_lat ? 4 : 2; return -1; }
    g->has_pos = has_lat;
    if (parse_int(f[6], &g->quality) || g->quality > 9) { *bad_field = 6; return -1; }
    if (parse_int(f[7], &g->num_sv) || g->num_sv > 999) { *bad_field = 7; return -1; }
    if (parse_num(f[8], &g->hdop)) { *bad_field = 8; return -1; }
    if (parse_num(f[9], &g->alt_msl_m)) { *bad_field = 9; return -1; }
    if (f[10].len && !(f[10].len == 1 && f[10].p[0] == 'M')) { *bad_field = 10; return -1; }
    if (parse_num(f[11], &g->geoid_sep_m)) { *bad_field = 11; return -1; }
    if (f[12].len && !(f[12].len == 1 && f[12].p[0] == 'M')) { *bad_field = 12; return -1; }
    return 0;
}

int gnss_nmea_parse_rmc(const gnss_nmea_sentence_t *s, gnss_nmea_rmc_t *r, int *bad_field)
{
    field_t f[GNSS_NMEA_MAX_FIELDS];
    int n = split(s, f, GNSS_NMEA_MAX_FIELDS);
    memset(r, 0, sizeof *r);
    r->speed_knots = r->course_deg = NAN;
    *bad_field = 0;
    /* address,time,status,lat,N,lon,E,spd,cog,date,mv,mvEW[,posMode[,navStatus]] */
    if (n < 12) { *bad_field = n; return -1; }
    if (parse_tod(f[1], &r->tod_ms)) { *bad_field = 1; return -1; }
    if (f[2].len > 1 || (f[2].len == 1 && f[2].p[0] != 'A' && f[2].p[0] != 'V')) { *bad_field = 2; return -1; }
    r->status = f[2].len ? f[2].p[0] : 0;
    int has_lat = 0, has_lon = 0;
    if (parse_coord(f[3], f[4], 2, 'N', 'S', &r->lat_deg, &has_lat)) { *bad_field = 3; return -1; }
    if (parse_coord(f[5], f[6], 3, 'E', 'W', &r->lon_deg, &has_lon)) { *bad_field = 5; return -1; }
    if (has_lat != has_lon) { *bad_field = has_lat ? 5 : 3; return -1; }
    r->has_pos = has_lat;
    if (parse_num(f[7], &r->speed_knots) || r->speed_knots < 0) { *bad_field = 7; return -1; }
    if (parse_num(f[8], &r->course_deg) || r->course_deg < 0 || r->course_deg > 360) { *bad_field = 8; return -1; }
    if (f[9].len) {
        udec_t u;
        if (parse_udec(f[9], &u) || u.int_digits != 6 || u.frac != 0 || f[9].len != 6) { *bad_field = 9; return -1; }
        r->day = (int)(u.ip / 10000);
        r->month = (int)(u.ip / 100 % 100);
        int yy = (int)(u.ip % 100);
        r->year = yy < 80 ? 2000 + yy : 1900 + yy;   /* two-digit year: 1980..2079 */
        if (r->day < 1 || r->day > 31 || r->month < 1 || r->month > 12) { *bad_field = 9; return -1; }
        r->has_date = 1;
    }
    if (n >= 13 && f[12].len) {
        if (f[12].len != 1 || f[12].p[0] < 'A' || f[12].p[0] > 'Z') { *bad_field = 12; return -1; }
        r->mode = f[12].p[0];
    }
    return 0;
}

int gnss_nmea_parse_gst(const gnss_nmea_sentence_t *s, gnss_nmea_gst_t *g, int *bad_field)
{
    field_t f[GNSS_NMEA_MAX_FIELDS];
    int n = split(s, f, GNSS_NMEA_MAX_FIELDS);
    memset(g, 0, sizeof *g);
    *bad_field = 0;
    /* address,time,rangeRms,stdMajor,stdMinor,orient,stdLat,stdLong,stdAlt */
    if (n < 9) { *bad_field = n; return -1; }
    if (parse_tod(f[1], &g->tod_ms)) { *bad_field = 1; return -1; }
    double *v[7] = { &g->rms_range_m, &g->std_major_m, &g->std_minor_m, &g->orient_deg,
                     &g->std_lat_m, &g->std_lon_m, &g->std_alt_m };
    for (int i = 0; i < 7; i++)
        if (parse_num(f[2 + i], v[i]) || *v[i] < 0) { *bad_field = 2 + i; return -1; }
    return 0;
}
