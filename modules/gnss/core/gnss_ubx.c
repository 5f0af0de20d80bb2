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

/* The struct is the payload: the wire is little-endian, and so is every host we build for. */
_Static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "gnss_nav_pvt_t is copied from a little-endian payload");
_Static_assert(offsetof(gnss_nav_pvt_t, lon) == 24 && offsetof(gnss_nav_pvt_t, p_dop) == 76, "NAV-PVT offsets");
_Static_assert(offsetof(gnss_nav_pvt_t, head_veh) == 84 && sizeof(gnss_nav_pvt_t) == GNSS_UBX_NAV_PVT_LEN, "NAV-PVT size");

int gnss_ubx_nav_pvt_decode(const uint8_t *p, size_t len, gnss_nav_pvt_t *v)
{
    memset(v, 0, sizeof *v);
    if (len < GNSS_UBX_NAV_PVT_LEN_MIN) return -1;
    /* An 84-byte (u-blox 7) payload leaves head_veh, mag_dec and mag_acc 0. */
    memcpy(v, p, len < GNSS_UBX_NAV_PVT_LEN ? GNSS_UBX_NAV_PVT_LEN_MIN : GNSS_UBX_NAV_PVT_LEN);
    return 0;
}
