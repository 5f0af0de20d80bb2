/* libFuzzer target: what recvmsg on a raw CAN socket returns, arbitrary bytes.
 * Input: byte 0 picks the frame size (even: CAN_MTU, odd: CANFD_MTU, or the
 * remaining bytes' count when byte 0 >= 0xF0), then the frame bytes, then the
 * control buffer. A frame it converts must be self-consistent, and then goes
 * through the speed decoder with a Toyota DBC excerpt.
 * fuzz-sources: modules/can/core/can_kernel.c modules/can/core/can_dbc.c modules/can/core/can_speed.c common/pb_err.c */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <linux/can.h>

#include "can/core/can_dbc.h"
#include "can/core/can_kernel.h"
#include "can/core/can_speed.h"
#include "fuzz_common.h"

static const char dbc_text[] =
    "BO_ 36 KINEMATICS: 8 XXX\n"
    " SG_ YAW_RATE : 1|10@0+ (0.244,-125) [0|65535] \"deg/s\" XXX\n"
    "BO_ 170 WHEEL_SPEEDS: 8 XXX\n"
    " SG_ WHEEL_SPEED_FR : 7|16@0+ (0.01,-67.67) [0|250] \"km/h\" XXX\n"
    " SG_ WHEEL_SPEED_FL : 23|16@0+ (0.01,-67.67) [0|250] \"km/h\" XXX\n"
    " SG_ WHEEL_SPEED_RR : 39|16@0+ (0.01,-67.67) [0|250] \"km/h\" XXX\n"
    " SG_ WHEEL_SPEED_RL : 55|16@0+ (0.01,-67.67) [0|250] \"km/h\" XXX\n"
    "BO_ 180 SPEED: 8 XXX\n"
    " SG_ ENCODER : 39|8@0+ (1,0) [0|255] \"\" XXX\n"
    " SG_ SPEED : 47|16@0+ (0.01,0) [0|250] \"km/h\" XXX\n"
    " SG_ CHECKSUM : 63|8@0+ (1,0) [0|255] \"\" XXX\n";

static can_dbc_t *db;
static can_speed_dec_t *dec;

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!db) {
        db = can_dbc_parse(dbc_text, sizeof dbc_text - 1, NULL);
        can_speed_config_t cfg;
        can_speed_config_default(&cfg);
        cfg.checksum = CAN_CHECKSUM_TOYOTA;
        cfg.bus = -1;
        dec = db ? can_speed_create(db, &cfg, NULL) : NULL;
        if (!dec) abort();
    }
    if (size < 1) return 0;
    size_t n = data[0] >= 0xF0 ? size - 1 : (data[0] & 1) ? CANFD_MTU : CAN_MTU;
    if (n > size - 1) n = size - 1;
    /* Exact-size heap copies, aligned as recvmsg's buffers are: ASan sees any overread. */
    uint8_t *frame = fuzz_copy(data + 1, n);
    size_t clen = size - 1 - n;
    uint8_t *control = fuzz_copy(data + 1 + n, clen);
    can_rx_t f;
    can_kernel_extra_t ex;
    int r = can_kernel_frame(frame, n, clen ? control : NULL, clen, data[0] & 2, &f, &ex);
    if (r >= 0) {
        if (f.len > (f.fd ? 64 : 8)) abort();
        if (f.id > (f.extended || f.error ? 0x1FFFFFFFu : 0x7FFu)) abort();
        can_speed_t out;
        int back;
        can_verdict_t v = can_speed_decode(dec, &f, &out, &back);
        if ((unsigned)v >= CAN_V_COUNT) abort();
        if (v == CAN_V_SPEED && !(out.speed_mps == out.speed_mps)) abort();   /* NaN */
    } else if (r != CAN_K_E_SIZE && r != CAN_K_E_LEN && r != CAN_K_E_CONTROL) {
        abort();
    }
    free(frame);
    free(control);
    return 0;
}
