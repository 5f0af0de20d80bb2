/* Unit tests of the CAN core: DBC parsing and its errors, signal extraction (Intel,
 * Motorola, signed), the Toyota checksum on real RAV4 frames, the speed decoder's
 * verdicts, and the kernel frame layout (struct can_frame / canfd_frame bytes and
 * cmsg timestamps packed exactly as recvmsg returns them). */
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <linux/can.h>
#include <linux/errqueue.h>     /* after <time.h>: it needs struct timespec */

#include "can/core/can_dbc.h"
#include "can/core/can_kernel.h"
#include "can/core/can_speed.h"
#include "pb_check.h"

#define DBC_PRIUS PB_SOURCE_DIR "/vehicles/dbc/toyota_prius_2017_pt_generated.dbc"
#define DBC_RAV4 PB_SOURCE_DIR "/vehicles/dbc/toyota_rav4_hybrid_2017_pt_generated.dbc"

static void hex(const char *s, uint8_t *out)
{
    for (int i = 0; s[2 * i]; i++) {
        unsigned v;
        sscanf(s + 2 * i, "%2x", &v);
        out[i] = (uint8_t)v;
    }
}

static can_dbc_t *parse(const char *text, pb_err_t *err)
{
    return can_dbc_parse(text, strlen(text), err);
}

static void test_dbc_parse(void)
{
    pb_err_t err;
    const char *text =
        "VERSION \"\"\n"
        "CM_ \"a comment that spans lines\n"
        "BO_ 99 NOT_A_MESSAGE: 8 XXX\n"
        "\"; \n"
        "BO_ 100 INTEL: 8 XXX\r\n"
        " SG_ U12 : 4|12@1+ (0.5,-10) [0|100] \"km/h\" XXX\n"
        " SG_ S8 : 16|8@1- (1,0) [-128|127] \"\" A,B\n"
        "\n"
        "BO_ 2147484672 EXT_MOT: 4 XXX\n"          /* 0x80000400: extended id 0x400 */
        " SG_ M16 : 7|16@0+ (0.01,0) [0|655.35] \"m/s\" XXX\n"
        " SG_ SM10 : 17|10@0- (2,1) [0|0] \"\" XXX\n"
        "BO_TX_BU_ 100 : A,B;\n"
        "BO_ 3221225472 VECTOR__INDEPENDENT_SIG_MSG: 0 Vector__XXX\n"
        " SG_ LOOSE : 0|8@1+ (1,0) [0|0] \"\" XXX\n"
        "BA_ \"GenMsgCycleTime\" BO_ 100 10;\n";
    can_dbc_t *db = parse(text, &err);
    CHECK(db != NULL);
    if (!db) { fprintf(stderr, "%s\n", err.msg); return; }
    CHECK(can_dbc_message_count(db) == 2);
    CHECK(can_dbc_find(db, 99, 0) == NULL);           /* inside the comment string */
    const can_message_t *m = can_dbc_find(db, 100, 0);
    CHECK(m && m->length == 8 && m->nsignals == 2 && !m->extended && !strcmp(m->name, "INTEL"));
    CHECK(can_dbc_find(db, 0x400, 0) == NULL);
    const can_message_t *e = can_dbc_find(db, 0x400, 1);
    CHECK(e && e->extended && e->nsignals == 2);
    if (m && e) {
        uint8_t d[8];
        hex("F0FFFE8000000000", d);
        /* U12: bits 4..15 = 0xFFF -> 4095*0.5-10; S8: byte 2 = 0xFE = -2 */
        const can_signal_t *u = can_message_signal(m, "U12"), *s = can_message_signal(m, "S8");
        CHECK(u && !strcmp(u->unit, "km/h") && u->last_byte == 1);
        CHECK(can_signal_raw(u, d) == 0xFFF);
        CHECK_NEAR(can_signal_value(u, d, 8, NULL), 4095 * 0.5 - 10, 1e-12);
        CHECK(can_signal_raw(s, d) == -2);
        uint8_t b[4];
        hex("1234C1C0", b);
        /* M16: Motorola from bit 7 of byte 0: 0x1234. SM10: MSB bit 17 (byte 2 bit 1),
         * 10 bits: byte 2 bits 1..0 then byte 3 bits 7..0 = 01 11000000 = 0x1C0, signed 10 bit = 448 */
        const can_signal_t *m16 = can_message_signal(e, "M16"), *sm = can_message_signal(e, "SM10");
        CHECK(can_signal_raw(m16, b) == 0x1234);
        CHECK_NEAR(can_signal_value(m16, b, 4, NULL), 46.60, 1e-12);
        CHECK(sm && sm->last_byte == 3 && can_signal_raw(sm, b) == 0x1C0);
        b[2] = 0xC3;                                   /* bits 1..0 = 11 -> 11 11000000 = -64 */
        CHECK(can_signal_raw(sm, b) == -64);
        CHECK_NEAR(can_signal_value(sm, b, 4, NULL), -127, 1e-12);
        int ok = 1;
        can_signal_value(sm, b, 3, &ok);               /* frame too short for the signal */
        CHECK(ok == 0);
    }
    can_dbc_destroy(db);
}

static void expect_error(const char *text, const char *where, const char *what)
{
    pb_err_t err = { "" };
    can_dbc_t *db = parse(text, &err);
    CHECK(db == NULL);
    can_dbc_destroy(db);
    CHECK_CONTAINS(err.msg, where);
    CHECK_CONTAINS(err.msg, what);
}

static void test_dbc_errors(void)
{
    expect_error("BO_ 1 A: 8 X\n SG_ S : 60|8@1+ (1,0) [0|0] \"\" X\n", "2:1:", "does not fit in A's 8 bytes");
    expect_error("BO_ 1 A: 2 X\n SG_ S : 0|16@0+ (1,0) [0|0] \"\" X\n", "2:1:", "does not fit");
    expect_error("BO_ x A: 8 X\n", "1:5:", "message id");
    expect_error("BO_ 1 A 8 X\n", "1:9:", "':' expected");
    expect_error("BO_ 1 A: 65 X\n", "1:10:", "message length");
    expect_error("BO_ 2048 A: 8 X\n", "1:1:", "11 bits");
    expect_error("BO_ 1 A: 8 X\nBO_ 1 B: 8 X\n", "2:1:", "duplicate message id");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|0@1+ (1,0) [0|0] \"\" X\n", "2:", "bit length");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|8@2+ (1,0) [0|0] \"\" X\n", "2:14:", "byte order");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|8@1+ (1;0) [0|0] \"\" X\n", "2:", "',' expected");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|8@1+ (1,0) [0|0] \"km/h X\n", "2:", "unterminated");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|8@1+ (1,nan) [0|0] \"\" X\n", "2:", "offset");
    expect_error(" SG_ S : 0|8@1+ (1,0) [0|0] \"\" X\n", "1:", "signal outside a message");
    expect_error("BO_ 1 A: 8 X\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" X\n SG_ S : 8|8@1+ (1,0) [0|0] \"\" X\n", "3:1:", "duplicate signal");
    expect_error("BO_ 1 A: 8 X\nVAL_ 1 S 0 \"D\" 16 \"R\"\n", "2:", "';' expected");
    expect_error("BO_ 1 A: 8 X\nVAL_ 1 S 0 D ;\n", "2:", "quoted label expected");
    expect_error("BO_ 1 A: 8 X\nVAL_ 1 S 0 \"D ;\n", "2:", "unterminated");
    static const char nul[] = "BO_ 1 A: 8 X\n BO_\0\n";
    pb_err_t err = { "" };
    CHECK(can_dbc_parse(nul, sizeof nul - 1, &err) == NULL);
    CHECK_CONTAINS(err.msg, "2:5: NUL byte");
}

static void test_real_dbcs(void)
{
    pb_err_t err;
    const char *paths[2] = { DBC_PRIUS, DBC_RAV4 };
    for (int k = 0; k < 2; k++) {
        can_dbc_t *db = can_dbc_load(paths[k], &err);
        CHECK(db != NULL);
        if (!db) { fprintf(stderr, "%s\n", err.msg); continue; }
        const can_message_t *ws = can_dbc_find(db, 0x0AA, 0), *sp = can_dbc_find(db, 0x0B4, 0);
        CHECK(ws && !strcmp(ws->name, "WHEEL_SPEEDS") && ws->nsignals == 4);
        CHECK(sp && !strcmp(sp->name, "SPEED") && can_message_signal(sp, "CHECKSUM"));
        can_dbc_destroy(db);
    }
    /* the value tables: GEAR_PACKET.GEAR "R" is 16 in both, GEAR_PACKET_HYBRID's 1 (Prius) */
    for (int k = 0; k < 2; k++) {
        can_dbc_t *db = can_dbc_load(paths[k], &err);
        if (!db) continue;
        int64_t raw = -1;
        CHECK(can_dbc_value_raw(db, can_dbc_find_name(db, "GEAR_PACKET"), "GEAR", "R", &raw) == 0 && raw == 16);
        CHECK(can_dbc_value_raw(db, can_dbc_find_name(db, "GEAR_PACKET"), "GEAR", "X", &raw) == -1);
        const can_message_t *h = can_dbc_find_name(db, "GEAR_PACKET_HYBRID");
        CHECK(k == 1 || (h && can_dbc_value_raw(db, h, "GEAR", "R", &raw) == 0 && raw == 1));
        can_dbc_destroy(db);
    }
    CHECK(can_dbc_load("/nonexistent.dbc", &err) == NULL);
    CHECK_CONTAINS(err.msg, "/nonexistent.dbc: ");
}

static void test_checksum(void)
{
    /* Real RAV4 frames (tests/data/can_rav4, comma2k19): SPEED 0x0B4 and PCM_CRUISE 0x1D2,
     * checksum in the last byte: (0x00 + 0xB4 + 8 + sum of bytes 0..6) & 0xFF. */
    uint8_t d[8];
    hex("0000000000000000", d);
    CHECK(can_checksum_toyota(0x0B4, d, 8) == 0xBC);
    hex("000000001D0B7A5E", d);    /* sample line 1: 0xB4 + 8 + 0x1D + 0x0B + 0x7A = 0x15E */
    CHECK(can_checksum_toyota(0x0B4, d, 8) == 0x5E);
    hex("00000000210B7D65", d);
    CHECK(can_checksum_toyota(0x0B4, d, 8) == 0x65);
    hex("8104007C007B0057", d);    /* PCM_CRUISE: 0x01 + 0xD2 + 8 + 0x81 + 0x04 + 0x7C + 0x7B = 0x257 */
    CHECK(can_checksum_toyota(0x1D2, d, 8) == 0x57);
}

static can_rx_t frame(int64_t t, int bus, uint32_t id, const char *data)
{
    can_rx_t f;
    memset(&f, 0, sizeof f);
    f.utime = t;
    f.bus = bus;
    f.id = id;
    f.len = (uint8_t)(strlen(data) / 2);
    hex(data, f.data);
    return f;
}

static void test_decoder(void)
{
    pb_err_t err;
    can_dbc_t *db = can_dbc_load(DBC_RAV4, &err);
    if (!db) { CHECK(0); return; }
    can_speed_config_t cfg;
    can_speed_config_default(&cfg);
    cfg.checksum = CAN_CHECKSUM_TOYOTA;
    can_speed_dec_t *d = can_speed_create(db, &cfg, &err);
    CHECK(d != NULL);
    if (!d) { can_dbc_destroy(db); return; }
    can_speed_t s;
    int back;
    /* WHEEL_SPEEDS of the RAV4 sample (1533226488.439005) against comma's decoding
     * (can_speed_wheelspeeds_mps_first2s.csv, first row, m/s to 6 decimals). */
    can_rx_t f = frame(1533226488439005, 0, 0x0AA, "25B525B525A0258D");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED && !back);
    CHECK(!strcmp(s.source, "WHEEL_SPEEDS") && s.has_wheel_speeds && !s.has_yaw_rate);
    CHECK_NEAR(s.wheel_speed_mps[0], 8.016667, 1e-6);  /* FL */
    CHECK_NEAR(s.wheel_speed_mps[1], 8.016667, 1e-6);  /* FR */
    CHECK_NEAR(s.wheel_speed_mps[2], 7.905556, 1e-6);  /* RL */
    CHECK_NEAR(s.wheel_speed_mps[3], 7.958333, 1e-6);  /* RR */
    CHECK_NEAR(s.speed_mps, 7.974306, 1e-6);
    CHECK_NEAR(s.speed_mps, (s.wheel_speed_mps[0] + s.wheel_speed_mps[1] + s.wheel_speed_mps[2] + s.wheel_speed_mps[3]) / 4, 1e-12);
    /* KINEMATICS (sample, 1533226488.434472): YAW_RATE 1|10@0+ (0.244,-125) deg/s,
     * byte 0 bits 1..0 and byte 1: 01 11111110 = 510 -> -0.56 deg/s */
    f = frame(1533226488440000, 0, 0x024, "01FE01D541F980BB");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_DECODED);
    f = frame(1533226488450000, 0, 0x0B4, "000000001D0B7A5E");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED);
    CHECK(!strcmp(s.source, "SPEED") && !s.has_wheel_speeds && s.has_yaw_rate);
    CHECK_NEAR(s.speed_mps, 0x0B7A * 0.01 / 3.6, 1e-12);
    CHECK_NEAR(s.yaw_rate_rps, (510 * 0.244 - 125) * M_PI / 180, 1e-12);
    f.data[7] ^= 1;
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_BAD_CHECKSUM);
    f = frame(1533226488460000, 0, 0x0B4, "000000001D0B7A");        /* 7 bytes */
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_BAD_LENGTH);
    f = frame(1533226488460000, 0, 0x0B4, "000000001D0B7A5E");
    f.utime -= 100000;                                               /* late frame: still decoded */
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED && back);
    CHECK(s.has_yaw_rate == 0);                                      /* yaw 90 ms away */
    f = frame(1533226488470000, 1, 0x0B4, "000000001D0B7A5E");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_OTHER_BUS);
    f = frame(1533226488470000, 0, 0x7FF, "00");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_UNKNOWN_ID);
    f.error = 1;
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_ERROR_FRAME);
    f = frame(1533226488470000, 0, 0x0B4, "");
    f.rtr = 1;
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_REMOTE_FRAME);
    CHECK(!strcmp(can_verdict_name(CAN_V_BAD_CHECKSUM), "bad_checksum"));
    /* GEAR_PACKET of the RAV4 sample (1533226489.239759): GEAR 0 = "D"; speeds stay
     * magnitudes. In R (16 by the DBC's value table) the speed turns negative; a gear
     * older than 5 s is no longer used. */
    f = frame(1533226489239759, 0, 0x3BC, "000000DE00800000");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_DECODED);
    f = frame(1533226489250000, 0, 0x0B4, "000000001D0B7A5E");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED && s.has_gear && !s.reverse && s.speed_mps > 0);
    f = frame(1533226489260000, 0, 0x3BC, "0010000000000000");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_DECODED);
    f = frame(1533226489270000, 0, 0x0AA, "25B525B525A0258D");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED && s.has_gear && s.reverse);
    CHECK_NEAR(s.speed_mps, -7.974306, 1e-6);
    CHECK(s.wheel_speed_mps[0] > 0);
    f = frame(1533226495270000, 0, 0x0AA, "25B525B525A0258D");
    CHECK(can_speed_decode(d, &f, &s, &back) == CAN_V_SPEED && !s.has_gear && s.speed_mps > 0);
    can_speed_destroy(d);

    cfg.speed_msg = "NO_SUCH";
    CHECK(can_speed_create(db, &cfg, &err) == NULL);
    CHECK_CONTAINS(err.msg, "NO_SUCH");
    can_speed_destroy(NULL);
    can_dbc_destroy(db);

    /* A unit the decoder does not know fails at create, naming the signal. */
    const char *t = "BO_ 180 SPEED: 8 X\n SG_ SPEED : 47|16@0+ (0.01,0) [0|250] \"furlong\" X\n";
    db = parse(t, &err);
    can_speed_config_default(&cfg);
    CHECK(db && can_speed_create(db, &cfg, &err) == NULL);
    CHECK_CONTAINS(err.msg, "furlong");
    can_dbc_destroy(db);
}

/* The control buffer recvmsg fills: cmsgs laid out with the CMSG macros. */
typedef struct {
    _Alignas(struct cmsghdr) uint8_t buf[512];
    size_t len;
} control_t;

static void add_cmsg(control_t *c, int level, int type, const void *data, size_t n)
{
    struct cmsghdr *h = (struct cmsghdr *)(c->buf + c->len);
    h->cmsg_level = level;
    h->cmsg_type = type;
    h->cmsg_len = CMSG_LEN(n);
    memcpy(CMSG_DATA(h), data, n);
    c->len += CMSG_SPACE(n);
}

static void test_kernel_frames(void)
{
    can_rx_t f;
    can_kernel_extra_t ex;
    control_t c = { .len = 0 };
    struct timespec ts = { 1533226488, 439005123 };
    uint32_t dropped = 7;
    add_cmsg(&c, SOL_SOCKET, SCM_TIMESTAMPNS, &ts, sizeof ts);
    add_cmsg(&c, SOL_SOCKET, SO_RXQ_OVFL, &dropped, sizeof dropped);

    /* struct can_frame as the kernel writes it: WHEEL_SPEEDS on can0. */
    struct can_frame k;
    memset(&k, 0, sizeof k);
    k.can_id = 0x0AA;
    k.len = 8;
    hex("1C221C2E1C0D1C16", k.data);
    uint8_t bytes[CAN_MTU];
    memcpy(bytes, &k, sizeof bytes);
    CHECK(sizeof k == 16 && bytes[4] == 8 && bytes[8] == 0x1C && bytes[15] == 0x16);   /* layout */
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 0, &f, &ex) == CAN_K_OK);
    CHECK(f.utime == 1533226488439005 && f.id == 0x0AA && f.len == 8 && !f.extended && !f.fd && !f.rtr && !f.error);
    CHECK(f.data[1] == 0x22 && f.bus == 0);
    CHECK(ex.has_dropped && ex.dropped == 7);

    /* 29-bit id, RTR, error frame. */
    k.can_id = 0x1ABCDEF0 | CAN_EFF_FLAG;
    memcpy(bytes, &k, sizeof bytes);
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 1, &f, NULL) == CAN_K_OK);
    CHECK(f.extended && f.id == 0x1ABCDEF0 && f.bus == 1);
    k.can_id = 0x123 | CAN_RTR_FLAG;
    k.len = 4;
    memcpy(bytes, &k, sizeof bytes);
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 0, &f, NULL) == CAN_K_OK);
    CHECK(f.rtr && f.id == 0x123 && f.len == 4 && f.data[0] == 0);
    k.can_id = CAN_ERR_FLAG | 0x4;       /* CAN_ERR_CRTL */
    k.len = 8;
    memcpy(bytes, &k, sizeof bytes);
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 0, &f, NULL) == CAN_K_OK);
    CHECK(f.error && f.id == 0x4);
    k.len = 9;
    memcpy(bytes, &k, sizeof bytes);
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 0, &f, NULL) == CAN_K_E_LEN);

    /* struct canfd_frame, 12 bytes, SO_TIMESTAMPING software stamp only. */
    struct canfd_frame fd;
    memset(&fd, 0, sizeof fd);
    fd.can_id = 0x456;
    fd.len = 12;
    fd.flags = CANFD_BRS;
    for (int i = 0; i < 12; i++) fd.data[i] = (uint8_t)(i + 1);
    control_t c2 = { .len = 0 };
    struct scm_timestamping st;
    memset(&st, 0, sizeof st);
    st.ts[0] = (struct timespec){ 1700000000, 1000 };
    st.ts[2] = (struct timespec){ 5, 0 };        /* hardware raw clock: not used */
    add_cmsg(&c2, SOL_SOCKET, SCM_TIMESTAMPING, &st, sizeof st);
    CHECK(can_kernel_frame(&fd, CANFD_MTU, c2.buf, c2.len, 0, &f, &ex) == CAN_K_OK);
    CHECK(f.fd && f.len == 12 && f.data[11] == 12 && f.utime == 1700000000000001 && !ex.has_dropped);
    fd.len = 13;
    CHECK(can_kernel_frame(&fd, CANFD_MTU, c2.buf, c2.len, 0, &f, NULL) == CAN_K_E_LEN);

    /* No timestamp, wrong sizes, a corrupt cmsg length. */
    memcpy(bytes, &k, sizeof bytes);
    bytes[4] = 8;
    CHECK(can_kernel_frame(bytes, CAN_MTU, NULL, 0, 0, &f, NULL) == CAN_K_NO_TIMESTAMP && f.utime == 0);
    CHECK(can_kernel_frame(bytes, 8, c.buf, c.len, 0, &f, NULL) == CAN_K_E_SIZE);
    CHECK(can_kernel_frame(bytes, 17, c.buf, c.len, 0, &f, NULL) == CAN_K_E_SIZE);
    control_t c3 = { .len = 0 };
    struct timespec bad_ts = { 1533226488, 1000000000 };    /* tv_nsec out of range */
    add_cmsg(&c3, SOL_SOCKET, SCM_TIMESTAMPNS, &bad_ts, sizeof bad_ts);
    CHECK(can_kernel_frame(bytes, CAN_MTU, c3.buf, c3.len, 0, &f, NULL) == CAN_K_E_CONTROL);
    ((struct cmsghdr *)c.buf)->cmsg_len = 4096;
    CHECK(can_kernel_frame(bytes, CAN_MTU, c.buf, c.len, 0, &f, NULL) == CAN_K_E_CONTROL);
    CHECK(strlen(can_kernel_strerror(CAN_K_E_CONTROL)) > 0);
}

int main(void)
{
    test_dbc_parse();
    test_dbc_errors();
    test_real_dbcs();
    test_checksum();
    test_decoder();
    test_kernel_frames();
    return pb_check_report("test_can");
}
