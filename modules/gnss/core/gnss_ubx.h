/* gnss_ubx: u-blox UBX frames and the NAV-PVT payload. Pure functions, no I/O.
 *
 * Frame: 0xB5 0x62, class, id, payload length (u16 little-endian), payload,
 * CK_A CK_B: the 8-bit Fletcher checksum over class, id, length and payload
 * (u-blox interface description, "UBX checksum"). */
#ifndef GNSS_UBX_H
#define GNSS_UBX_H

#include <stddef.h>
#include <stdint.h>

#define GNSS_UBX_SYNC1 0xB5
#define GNSS_UBX_SYNC2 0x62
#define GNSS_UBX_OVERHEAD 8              /* sync 2 + class/id 2 + length 2 + checksum 2 */
#define GNSS_UBX_CLASS_NAV 0x01
#define GNSS_UBX_ID_NAV_PVT 0x07
#define GNSS_UBX_NAV_PVT_LEN 92          /* u-blox 8 and later */
#define GNSS_UBX_NAV_PVT_LEN_MIN 84      /* u-blox 7: no headVeh, magDec, magAcc */

typedef enum {
    GNSS_UBX_FRAME = 0,        /* a whole frame with a good checksum */
    GNSS_UBX_NEED_MORE,        /* a frame may start here: more bytes needed to decide */
    GNSS_UBX_NOT_SYNC,         /* the bytes do not start with 0xB5 0x62 */
    GNSS_UBX_BAD_CHECKSUM,     /* checksum over the claimed length does not match */
    GNSS_UBX_TOO_LONG,         /* claimed payload length above the configured maximum */
} gnss_ubx_result_t;

typedef struct {
    uint8_t msg_class, msg_id;
    uint16_t len;              /* payload bytes */
    const uint8_t *payload;    /* points into the caller's buffer */
    size_t total;              /* whole frame: len + GNSS_UBX_OVERHEAD */
    uint8_t ck_a, ck_b;        /* as received (on BAD_CHECKSUM: what the frame carries) */
    uint8_t ck_a_calc, ck_b_calc;  /* as computed */
} gnss_ubx_frame_t;

/* Checks whether buf[0..avail) starts with a UBX frame of payload at most max_payload
 * bytes. On GNSS_UBX_FRAME *f describes it (f->total bytes to consume). On
 * BAD_CHECKSUM, f holds the header and both checksums. Never reads past avail. */
gnss_ubx_result_t gnss_ubx_frame_check(const uint8_t *buf, size_t avail, size_t max_payload,
                                       gnss_ubx_frame_t *f);

/* 8-bit Fletcher over data[0..n). */
void gnss_ubx_checksum(const uint8_t *data, size_t n, uint8_t *ck_a, uint8_t *ck_b);

/* Fills buf with a frame (for tests and tools). buf must hold len + 8 bytes.
 * Returns the frame length. */
size_t gnss_ubx_frame_build(uint8_t msg_class, uint8_t msg_id, const uint8_t *payload,
                            uint16_t len, uint8_t *buf);

/* UBX-NAV-PVT, raw fields with their u-blox units, laid out as the payload (a
 * little-endian host decodes it with one copy; gnss_ubx.c checks the offsets). */
typedef struct {
    uint32_t itow_ms;
    uint16_t year;
    uint8_t month, day, hour, min, sec;
    uint8_t valid;             /* bit0 validDate, bit1 validTime, bit2 fullyResolved, bit3 validMag */
    uint32_t t_acc_ns;
    int32_t nano;              /* fraction of the second, ns, -1e9..1e9 */
    uint8_t fix_type;          /* 0 none, 1 DR, 2 2D, 3 3D, 4 GNSS+DR, 5 time only */
    uint8_t flags;             /* bit0 gnssFixOK, bit1 diffSoln, bits2-4 psmState, bit5 headVehValid, bits6-7 carrSoln */
    uint8_t flags2;
    uint8_t num_sv;
    int32_t lon, lat;          /* 1e-7 deg */
    int32_t height_mm, hmsl_mm;
    uint32_t h_acc_mm, v_acc_mm;
    int32_t vel_n, vel_e, vel_d, g_speed;   /* mm/s */
    int32_t head_mot;          /* 1e-5 deg */
    uint32_t s_acc, head_acc;  /* mm/s, 1e-5 deg */
    uint16_t p_dop;            /* 0.01 */
    uint8_t flags3;            /* bit0 invalidLlh */
    uint8_t reserved[5];
    int32_t head_veh;          /* 1e-5 deg (0 in an 84-byte message) */
    int16_t mag_dec;
    uint16_t mag_acc;
} gnss_nav_pvt_t;

#define GNSS_PVT_VALID_DATE 0x01
#define GNSS_PVT_VALID_TIME 0x02
#define GNSS_PVT_FULLY_RESOLVED 0x04
#define GNSS_PVT_FLAG_FIX_OK 0x01
#define GNSS_PVT_FLAGS3_INVALID_LLH 0x01

/* Decodes a NAV-PVT payload. Returns 0, or -1 if len is below GNSS_UBX_NAV_PVT_LEN_MIN. */
int gnss_ubx_nav_pvt_decode(const uint8_t *payload, size_t len, gnss_nav_pvt_t *pvt);

#endif
