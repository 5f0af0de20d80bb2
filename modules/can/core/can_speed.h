/* can_speed: CAN frames -> vehicle speed, wheel speeds and yaw rate, through a DBC.
 *
 * The pure core of modules/can: no I/O, time only from the frames' utimes.
 * Each frame is classified (one can_verdict_t) and, when it carries a speed,
 * gives one vehicle speed record:
 *   - the wheel-speed message (Toyota: WHEEL_SPEEDS 0x0AA, signals WHEEL_SPEED_FL/
 *     FR/RL/RR): the four wheel speeds, speed = their mean (comma's definition of
 *     the car speed from wheel speeds, which the RAV4 reference data follows);
 *   - the speed message (Toyota: SPEED 0x0B4, signal SPEED): the speed alone.
 *   - the yaw-rate message (Toyota: KINEMATICS 0x024, signal YAW_RATE) gives no
 *     record of its own; its newest value is attached to the next speed record
 *     if it is at most yaw_max_age_us old.
 *   - the gear message (Toyota: GEAR_PACKET 0x3BC, signal GEAR) gives no record of its
 *     own; while its newest value is at most gear_max_age_us old, a speed record says
 *     so, and in reverse (the raw value the DBC's value table gives gear_reverse, "R")
 *     its speed is negative. Speeds are otherwise magnitudes, as the car sends them.
 * Every frame of a message the DBC knows is checked: its length against the DBC
 * (a frame of another length is not decoded), and, when the DBC message has a
 * CHECKSUM signal and a checksum kind is configured, the checksum.
 * Units are taken from the DBC ("km/h", "m/s", "mph"; "deg/s", "rad/s") and
 * converted to m/s and rad/s; another unit on a used signal fails at create.
 *
 * Ownership: can_speed_create borrows the DBC (which must outlive the decoder);
 * the caller frees the decoder with can_speed_destroy. */
#ifndef CAN_SPEED_H
#define CAN_SPEED_H

#include <stdint.h>
#include "can_dbc.h"
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

/* One received frame, however it arrived (kernel socket, candump line, CAN_FRAME). */
typedef struct {
    int64_t utime;          /* us since UNIX epoch: receive time */
    int32_t bus;            /* N of canN */
    uint32_t id;            /* 11- or 29-bit id; error class for error frames */
    uint8_t extended, rtr, error, fd;
    uint8_t len;            /* payload bytes, 0-64 */
    uint8_t data[64];
} can_rx_t;

typedef enum {
    CAN_CHECKSUM_NONE = 0,
    CAN_CHECKSUM_TOYOTA,    /* (id high byte + id low byte + length + data[0..len-2]) & 0xFF in the last byte */
} can_checksum_kind_t;

typedef struct {
    int bus;                        /* bus whose frames are decoded; -1: every bus */
    can_checksum_kind_t checksum;
    const char *wheel_msg, *wheel_fl, *wheel_fr, *wheel_rl, *wheel_rr;
    const char *speed_msg, *speed_sig;
    const char *yaw_msg, *yaw_sig;
    int64_t yaw_max_age_us;
    const char *gear_msg, *gear_sig, *gear_reverse;    /* gear_reverse: the value-table label */
    int64_t gear_max_age_us;
} can_speed_config_t;

/* Toyota message and signal names (opendbc), bus 0, no checksum check, yaw 50 ms,
 * gear 5 s (the RAV4 sends GEAR_PACKET about once a second). */
void can_speed_config_default(can_speed_config_t *cfg);

/* What became of a frame; every frame gets exactly one. */
typedef enum {
    CAN_V_SPEED = 0,        /* decoded: *out holds a speed record */
    CAN_V_DECODED,          /* a DBC message, length and checksum good, not a speed (yaw, others) */
    CAN_V_OTHER_BUS,        /* not the configured bus */
    CAN_V_UNKNOWN_ID,       /* the DBC has no message with this id */
    CAN_V_ERROR_FRAME,      /* a bus error frame */
    CAN_V_REMOTE_FRAME,     /* a remote (RTR) frame: no data */
    CAN_V_BAD_LENGTH,       /* length differs from the DBC's */
    CAN_V_BAD_CHECKSUM,     /* checksum byte wrong */
    CAN_V_COUNT
} can_verdict_t;

/* Short reason names, used as STATUS counter names ("bad_checksum", ...). */
const char *can_verdict_name(can_verdict_t v);

typedef struct {
    int64_t utime;
    const char *source;             /* DBC message name (points into the DBC) */
    double speed_mps;
    int has_wheel_speeds;
    double wheel_speed_mps[4];      /* FL, FR, RL, RR */
    int has_yaw_rate;
    double yaw_rate_rps;
    int has_gear;                   /* the gear is known: speed_mps is signed */
    int reverse;                    /* ... and it is reverse */
} can_speed_t;

typedef struct can_speed_dec can_speed_dec_t;

/* Looks the configured messages and signals up in the DBC. A message the DBC
 * lacks is simply not decoded (the speed message is required: else NULL + err). */
can_speed_dec_t *can_speed_create(const can_dbc_t *dbc, const can_speed_config_t *cfg, pb_err_t *err);
void can_speed_destroy(can_speed_dec_t *dec);

/* Classifies and decodes one frame. *out is filled when CAN_V_SPEED is returned.
 * A frame older than its predecessor still decodes (nothing is dropped), and
 * *time_backwards is set so the shell can count it. */
can_verdict_t can_speed_decode(can_speed_dec_t *dec, const can_rx_t *frame, can_speed_t *out, int *time_backwards);

/* The checksum byte a frame should carry (kind TOYOTA); len >= 1. */
uint8_t can_checksum_toyota(uint32_t id, const uint8_t *data, int len);

#ifdef __cplusplus
}
#endif
#endif
