/* can_dbc: a DBC file (Vector CAN database) read at start-up, and signal decoding.
 *
 * Only what decoding needs is kept: messages (BO_: id, name, length), their
 * signals (SG_: name, start bit, length, byte order, sign, factor, offset, unit,
 * multiplexing) and the signals' value tables (VAL_ id signal raw "label" ... ;).
 * Every other section (BU_, CM_, BA_, ...) is skipped, with
 * quoted strings that span lines tracked so a comment can never be read as a
 * message. BO_, SG_ and VAL_ lines are parsed strictly: a malformed one, a signal that
 * does not fit its message, or a duplicate id is an error "LINE:COL: what".
 *
 * Bit numbering is the DBC one: bit b is bit (b % 8) of byte (b / 8).
 * Intel (@1) signals start at their least significant bit; Motorola (@0) at their
 * most significant bit and run towards higher bytes (the "sawtooth" order).
 *
 * Fuzz-friendly: can_dbc_parse takes any bytes with a length (no terminator
 * needed, NUL bytes are errors) and reads nothing outside them.
 *
 * Ownership: can_dbc_parse / can_dbc_load return a database the caller frees
 * with can_dbc_destroy; messages and signals point into it. */
#ifndef CAN_DBC_H
#define CAN_DBC_H

#include <stddef.h>
#include <stdint.h>
#include "pb_err.h"

#ifdef __cplusplus
extern "C" {
#endif

#define CAN_DBC_NAME_MAX 64
#define CAN_DBC_UNIT_MAX 32

typedef struct {
    char name[CAN_DBC_NAME_MAX];
    char unit[CAN_DBC_UNIT_MAX];
    uint16_t start;         /* DBC start bit */
    uint8_t length;         /* 1-64 bits */
    uint8_t big_endian;     /* Motorola (@0) */
    uint8_t is_signed;      /* two's complement (-) */
    uint8_t is_multiplexer; /* "M" */
    uint8_t multiplexed;    /* "mN": present only when the multiplexer's raw value is mux_value */
    uint32_t mux_value;
    uint8_t last_byte;      /* highest payload byte the signal touches (frame must be longer) */
    double factor, offset;
    double minimum, maximum;
} can_signal_t;

typedef struct {
    uint32_t id;            /* 11- or 29-bit arbitration id (the DBC's bit 31 removed) */
    uint8_t extended;       /* the DBC id had bit 31 (0x80000000) set */
    uint8_t length;         /* payload bytes the DBC declares (0-64) */
    char name[CAN_DBC_NAME_MAX];
    can_signal_t *signals;
    int nsignals;
} can_message_t;

typedef struct can_dbc can_dbc_t;

/* Parses DBC text. Returns the database, or NULL with err "LINE:COL: what". */
can_dbc_t *can_dbc_parse(const char *text, size_t len, pb_err_t *err);
/* Reads and parses a file; errors are prefixed with the path. */
can_dbc_t *can_dbc_load(const char *path, pb_err_t *err);
void can_dbc_destroy(can_dbc_t *dbc);

int can_dbc_message_count(const can_dbc_t *dbc);
const can_message_t *can_dbc_message_at(const can_dbc_t *dbc, int index);
/* The message with this id (extended: 29-bit id space), or NULL. O(log n). */
const can_message_t *can_dbc_find(const can_dbc_t *dbc, uint32_t id, int extended);
const can_message_t *can_dbc_find_name(const can_dbc_t *dbc, const char *name);
const can_signal_t *can_message_signal(const can_message_t *msg, const char *name);

/* The raw value the DBC's value table gives `label` of msg's `signal` (e.g. GEAR "R"):
 * 0 and *raw, or -1 when the DBC has no such entry. */
int can_dbc_value_raw(const can_dbc_t *dbc, const can_message_t *msg, const char *signal, const char *label,
                      int64_t *raw);
/* Raw value of a signal (sign-extended if signed). The caller guarantees
 * len > sig->last_byte. */
int64_t can_signal_raw(const can_signal_t *sig, const uint8_t *data);
/* raw * factor + offset; 0 if the frame is too short (then *ok = 0 when ok given). */
double can_signal_value(const can_signal_t *sig, const uint8_t *data, int len, int *ok);

#ifdef __cplusplus
}
#endif
#endif
