/* UBX framing and NAV-PVT decoding (offsets from the u-blox interface description). */
#include "gnss_ubx.h"

#include <string.h>

void gnss_ubx_checksum(const uint8_t *data, size_t n, uint8_t *ck_a, uint8_t *ck_b)
{
    uint8_t a = 0, b = 0;
    for (size_t i = 0; i < n; i++) {
        a = (uint8_t)(a + data[i]);
        b = (uint8_t)(b + a);
    }
    *ck_a = a;
    *ck_b = b;
}

gnss_ubx_result_t gnss_ubx_frame_check(const uint8_t *buf, size_t avail, size_t max_payload,
                                       gnss_ubx_frame_t *f)
{
    memset(f, 0, sizeof *f);
    if (avail < 1) return GNSS_UBX_NEED_MORE;
    if (buf[0] != GNSS_UBX_SYNC1) return GNSS_UBX_NOT_SYNC;
    if (avail < 2) return GNSS_UBX_NEED_MORE;
    if (buf[1] != GNSS_UBX_SYNC2) return GNSS_UBX_NOT_SYNC;
    if (avail < 6) return GNSS_UBX_NEED_MORE;
    f->msg_class = buf[2];
    f->msg_id = buf[3];
    f->len = (uint16_t)(buf[4] | (buf[5] << 8));
    /* Decided on the header alone, so a garbage length never waits for (and holds
     * back) up to 64 KB of good frames behind it. */
    if (f->len > max_payload) return GNSS_UBX_TOO_LONG;
    f->total = (size_t)f->len + GNSS_UBX_OVERHEAD;
    if (avail < f->total) return GNSS_UBX_NEED_MORE;
    f->payload = buf + 6;
    gnss_ubx_checksum(buf + 2, (size_t)f->len + 4, &f->ck_a_calc, &f->ck_b_calc);
    f->ck_a = buf[6 + f->len];
    f->ck_b = buf[7 + f->len];
    if (f->ck_a != f->ck_a_calc || f->ck_b != f->ck_b_calc) return GNSS_UBX_BAD_CHECKSUM;
    return GNSS_UBX_FRAME;
}

size_t gnss_ubx_frame_build(uint8_t msg_class, uint8_t msg_id, const uint8_t *payload,
                            uint16_t len, uint8_t *buf)
{
    buf[0] = GNSS_UBX_SYNC1;
    buf[1] = GNSS_UBX_SYNC2;
    buf[2] = msg_class;
    buf[3] = msg_id;
    buf[4] = (uint8_t)(len & 0xFF);
    buf[5] = (uint8_t)(len >> 8);
    if (len) memcpy(buf + 6, payload, len);
    gnss_ubx_checksum(buf + 2, (size_t)len + 4, &buf[6 + len], &buf[7 + len]);
    return (size_t)len + GNSS_UBX_OVERHEAD;
}

static uint16_t u2(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t u4(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static int32_t i4(const uint8_t *p) { return (int32_t)u4(p); }

int gnss_ubx_nav_pvt_decode(const uint8_t *p, size_t len, gnss_nav_pvt_t *v)
{
    memset(v, 0, sizeof *v);
    if (len < GNSS_UBX_NAV_PVT_LEN_MIN) return -1;
    v->itow_ms = u4(p + 0);
    v->year = u2(p + 4);
    v->month = p[6];
    v->day = p[7];
    v->hour = p[8];
    v->min = p[9];
    v->sec = p[10];
    v->valid = p[11];
    v->t_acc_ns = u4(p + 12);
    v->nano = i4(p + 16);
    v->fix_type = p[20];
    v->flags = p[21];
    v->flags2 = p[22];
    v->num_sv = p[23];
    v->lon = i4(p + 24);
    v->lat = i4(p + 28);
    v->height_mm = i4(p + 32);
    v->hmsl_mm = i4(p + 36);
    v->h_acc_mm = u4(p + 40);
    v->v_acc_mm = u4(p + 44);
    v->vel_n = i4(p + 48);
    v->vel_e = i4(p + 52);
    v->vel_d = i4(p + 56);
    v->g_speed = i4(p + 60);
    v->head_mot = i4(p + 64);
    v->s_acc = u4(p + 68);
    v->head_acc = u4(p + 72);
    v->p_dop = u2(p + 76);
    v->flags3 = p[78];
    if (len >= GNSS_UBX_NAV_PVT_LEN) {
        v->head_veh = i4(p + 84);
        v->mag_dec = (int16_t)u2(p + 88);
        v->mag_acc = u2(p + 90);
    }
    return 0;
}
