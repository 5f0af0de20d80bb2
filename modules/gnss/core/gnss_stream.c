/* Frame demultiplexer for UBX + NMEA + RTCM3 byte streams. */
#include "gnss_stream.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define RTCM3_MAX_TOTAL (3 + 1023 + 3)

struct gnss_stream {
    gnss_stream_config_t cfg;
    gnss_stream_handlers_t h;
    uint8_t *buf;
    size_t cap, len;
    int64_t base;              /* absolute offset of buf[0] */
    int64_t skip_start, skip_len;
};

static const char *const ERROR_NAMES[GNSS_ERR_COUNT] = {
    "ubx_bad_checksum", "ubx_too_long", "ubx_truncated",
    "nmea_bad_checksum", "nmea_no_checksum", "nmea_bad_char", "nmea_too_long", "nmea_truncated",
};

const char *gnss_stream_error_name(gnss_stream_error_t e)
{
    return (unsigned)e < GNSS_ERR_COUNT ? ERROR_NAMES[e] : "unknown";
}

void gnss_stream_config_default(gnss_stream_config_t *c)
{
    c->max_ubx_payload = 8192;
    c->max_nmea_len = GNSS_NMEA_MAX_LEN_DEFAULT;
}

gnss_stream_t *gnss_stream_create(const gnss_stream_config_t *cfg, const gnss_stream_handlers_t *h)
{
    gnss_stream_t *s = calloc(1, sizeof *s);
    if (!s) return NULL;
    if (cfg) s->cfg = *cfg;
    else gnss_stream_config_default(&s->cfg);
    if (s->cfg.max_ubx_payload > 65535) s->cfg.max_ubx_payload = 65535;
    if (s->cfg.max_nmea_len < 16) s->cfg.max_nmea_len = 16;
    s->h = *h;
    /* Room for the longest frame that can be waited for, plus one read's worth. */
    size_t longest = s->cfg.max_ubx_payload + GNSS_UBX_OVERHEAD;
    if (s->cfg.max_nmea_len + 8 > longest) longest = s->cfg.max_nmea_len + 8;
    if (RTCM3_MAX_TOTAL > longest) longest = RTCM3_MAX_TOTAL;
    s->cap = longest + 4096;
    s->buf = malloc(s->cap);
    if (!s->buf) { free(s); return NULL; }
    return s;
}

void gnss_stream_destroy(gnss_stream_t *s)
{
    if (!s) return;
    free(s->buf);
    free(s);
}

int64_t gnss_stream_offset(const gnss_stream_t *s) { return s->base + (int64_t)s->len; }

static uint32_t crc24q(const uint8_t *p, size_t n)
{
    uint32_t crc = 0;
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint32_t)p[i] << 16;
        for (int b = 0; b < 8; b++) {
            crc <<= 1;
            if (crc & 0x1000000) crc ^= 0x1864CFB;
        }
    }
    return crc & 0xFFFFFF;
}

int gnss_rtcm3_check(const uint8_t *buf, size_t avail, size_t *total, int *msg_type)
{
    if (avail < 1 || buf[0] != 0xD3) return -1;
    if (avail < 3) return 0;
    if (buf[1] & 0xFC) return -1;      /* 6 reserved bits are zero */
    size_t len = ((size_t)(buf[1] & 0x03) << 8) | buf[2];
    size_t t = 3 + len + 3;
    if (avail < t) return 0;
    uint32_t crc = ((uint32_t)buf[3 + len] << 16) | ((uint32_t)buf[4 + len] << 8) | buf[5 + len];
    if (crc24q(buf, 3 + len) != crc) return -1;
    *total = t;
    *msg_type = len >= 2 ? (buf[3] << 4) | (buf[4] >> 4) : -1;
    return 1;
}

static void flush_skip(gnss_stream_t *s)
{
    if (s->skip_len && s->h.on_skip) s->h.on_skip(s->h.user, s->skip_start, s->skip_len);
    s->skip_len = 0;
}

static void skip_byte(gnss_stream_t *s, int64_t off)
{
    if (s->skip_len == 0) s->skip_start = off;
    s->skip_len++;
}

static void error(gnss_stream_t *s, int64_t off, gnss_stream_error_t e, const char *detail)
{
    flush_skip(s);
    if (s->h.on_error) s->h.on_error(s->h.user, off, e, detail);
}

/* Scans buf; returns how many bytes are decided (the rest waits for more input). */
static size_t scan(gnss_stream_t *s, int at_end)
{
    size_t pos = 0;
    char detail[160];
    while (pos < s->len) {
        const uint8_t *p = s->buf + pos;
        size_t avail = s->len - pos;
        int64_t off = s->base + (int64_t)pos;
        if (p[0] == GNSS_UBX_SYNC1) {
            gnss_ubx_frame_t f;
            gnss_ubx_result_t r = gnss_ubx_frame_check(p, avail, s->cfg.max_ubx_payload, &f);
            if (r == GNSS_UBX_FRAME) {
                flush_skip(s);
                if (s->h.on_ubx) s->h.on_ubx(s->h.user, off, &f);
                pos += f.total;
                continue;
            }
            if (r == GNSS_UBX_NEED_MORE) {
                if (!at_end) return pos;
                if (avail >= 2) {
                    snprintf(detail, sizeof detail, "UBX frame cut short: %zu of %s bytes present",
                             avail, avail >= 6 ? "its" : "at least 8");
                    if (avail >= 6) snprintf(detail, sizeof detail,
                        "UBX frame (class %02x id %02x, %u-byte payload) cut short: %zu of %zu bytes present",
                        f.msg_class, f.msg_id, f.len, avail, f.total);
                    error(s, off, GNSS_ERR_UBX_TRUNCATED, detail);
                    pos += 1;
                } else {
                    skip_byte(s, off);
                    pos++;
                }
                continue;
            }
            if (r == GNSS_UBX_BAD_CHECKSUM) {
                snprintf(detail, sizeof detail,
                         "UBX checksum %02x %02x, computed %02x %02x (class %02x id %02x, %u-byte payload)",
                         f.ck_a, f.ck_b, f.ck_a_calc, f.ck_b_calc, f.msg_class, f.msg_id, f.len);
                error(s, off, GNSS_ERR_UBX_BAD_CHECKSUM, detail);
                pos += 1;
                continue;
            }
            if (r == GNSS_UBX_TOO_LONG) {
                snprintf(detail, sizeof detail, "UBX length %u above the maximum %zu (class %02x id %02x)",
                         f.len, s->cfg.max_ubx_payload, f.msg_class, f.msg_id);
                error(s, off, GNSS_ERR_UBX_TOO_LONG, detail);
                pos += 1;
                continue;
            }
        } else if (p[0] == '$') {
            gnss_nmea_sentence_t ns;
            gnss_nmea_result_t r = gnss_nmea_sentence_check((const char *)p, avail, s->cfg.max_nmea_len, at_end, &ns);
            if (r == GNSS_NMEA_SENTENCE) {
                flush_skip(s);
                if (s->h.on_nmea) s->h.on_nmea(s->h.user, off, &ns);
                pos += ns.total;
                continue;
            }
            if (r == GNSS_NMEA_NEED_MORE) return pos;   /* at_end never answers NEED_MORE */
            if (r != GNSS_NMEA_NOT_START) {
                gnss_stream_error_t e;
                switch (r) {
                case GNSS_NMEA_BAD_CHECKSUM:
                    e = GNSS_ERR_NMEA_BAD_CHECKSUM;
                    snprintf(detail, sizeof detail, "NMEA %s checksum %02X, computed %02X",
                             ns.address, ns.ck_recv, ns.ck_calc);
                    break;
                case GNSS_NMEA_NO_CHECKSUM:
                    e = GNSS_ERR_NMEA_NO_CHECKSUM;
                    snprintf(detail, sizeof detail, "NMEA %s without a *hh checksum (byte %zu of the sentence)",
                             ns.address, ns.error_at);
                    break;
                case GNSS_NMEA_BAD_CHAR:
                    e = GNSS_ERR_NMEA_BAD_CHAR;
                    snprintf(detail, sizeof detail, "NMEA %s: byte 0x%02x at byte %zu of the sentence",
                             ns.address, p[ns.error_at], ns.error_at);
                    break;
                case GNSS_NMEA_TOO_LONG:
                    e = GNSS_ERR_NMEA_TOO_LONG;
                    snprintf(detail, sizeof detail, "NMEA %s: no end within %zu bytes", ns.address,
                             s->cfg.max_nmea_len);
                    break;
                default:
                    e = GNSS_ERR_NMEA_TRUNCATED;
                    snprintf(detail, sizeof detail, "NMEA %s cut short after %zu bytes", ns.address, ns.total);
                    break;
                }
                error(s, off, e, detail);
                pos += ns.total ? ns.total : 1;
                continue;
            }
        } else if (p[0] == 0xD3) {
            size_t total = 0;
            int type = -1;
            int r = gnss_rtcm3_check(p, avail, &total, &type);
            if (r == 1) {
                flush_skip(s);
                if (s->h.on_rtcm3) s->h.on_rtcm3(s->h.user, off, type, total);
                pos += total;
                continue;
            }
            if (r == 0 && !at_end) return pos;
        }
        skip_byte(s, off);
        pos++;
    }
    return pos;
}

static void consume(gnss_stream_t *s, size_t n)
{
    memmove(s->buf, s->buf + n, s->len - n);
    s->len -= n;
    s->base += (int64_t)n;
}

void gnss_stream_feed(gnss_stream_t *s, const uint8_t *data, size_t n)
{
    while (n > 0) {
        size_t room = s->cap - s->len;
        size_t k = n < room ? n : room;
        memcpy(s->buf + s->len, data, k);
        s->len += k;
        data += k;
        n -= k;
        consume(s, scan(s, 0));
    }
}

void gnss_stream_finish(gnss_stream_t *s)
{
    consume(s, scan(s, 1));
    flush_skip(s);
}
