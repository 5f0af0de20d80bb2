/* pb_candump: one line of a `candump -l` log file, parsed strictly.
 *
 * Line layout (can-utils lib.h conventions):
 *   (SECONDS.USEC) IFACE FRAME [T|R]
 * FRAME is one of
 *   III#DD..           classic CAN, 11-bit id (3 hex digits), 0-8 data bytes
 *   IIIIIIII#DD..      classic CAN, 29-bit id (8 hex digits)
 *   IIIIIIII#DD..      with CAN_ERR_FLAG (0x20000000) set: an error frame; the
 *                      id carries the error class, data the error details
 *   III#R[L]           remote frame requesting L (0-8, default 0) bytes
 *   III#DD.._X         classic frame of 8 bytes whose DLC X is 9-F (ignored)
 *   III##FDD..         CAN FD: F is the flags hex digit (BRS 1, ESI 2), then
 *                      0-64 data bytes (a valid FD length: 0-8,12,16,...,64)
 * Data bytes are hex pairs, optionally separated by '.'. The optional trailing
 * T/R is the direction flag newer candump versions add; it is ignored.
 * CAN XL (III###...) is refused.
 *
 * The timestamp is parsed as a decimal string into integer microseconds, so it
 * is exact (no float rounding); 1-6 fractional digits are accepted.
 *
 * Fuzz-friendly: pb_candump_parse takes any bytes with an explicit length (NUL
 * bytes included, no terminator needed), reads nothing outside [line, line+len)
 * and never allocates. */
#ifndef PB_CANDUMP_H
#define PB_CANDUMP_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define PB_CANDUMP_IFACE_MAX 16     /* IFNAMSIZ, NUL included */

/* CAN id flag bits as in linux/can.h (not exposed in pb_candump_frame_t.id). */
#define PB_CAN_EFF_FLAG 0x80000000u
#define PB_CAN_RTR_FLAG 0x40000000u
#define PB_CAN_ERR_FLAG 0x20000000u

typedef struct {
    int64_t utime;                      /* us since UNIX epoch, exact */
    char iface[PB_CANDUMP_IFACE_MAX];   /* interface name, NUL-terminated */
    uint32_t id;                        /* 11- or 29-bit id; error class for error frames */
    uint8_t extended;                   /* 29-bit id */
    uint8_t rtr;                        /* remote frame: len is the requested length, data zero */
    uint8_t error;                      /* error frame (8-digit id with CAN_ERR_FLAG) */
    uint8_t fd;                         /* CAN FD frame */
    uint8_t fd_flags;                   /* CAN FD flags digit (BRS 0x1, ESI 0x2); 0 otherwise */
    uint8_t len8_dlc;                   /* 9-15 if given as _X on an 8-byte classic frame, else 0 */
    uint8_t len;                        /* payload bytes */
    uint8_t data[64];                   /* payload; bytes past len are zero */
} pb_candump_frame_t;

/* Return codes of pb_candump_parse. */
enum {
    PB_CANDUMP_FRAME    =  1,   /* *out holds a frame */
    PB_CANDUMP_BLANK    =  0,   /* empty or whitespace-only line: no frame, not an error */
    PB_CANDUMP_E_TIME   = -1,   /* missing or malformed "(SECONDS.USEC)" */
    PB_CANDUMP_E_IFACE  = -2,   /* missing, empty or too long interface name */
    PB_CANDUMP_E_ID     = -3,   /* id not 3 or 8 hex digits followed by '#' */
    PB_CANDUMP_E_DATA   = -4,   /* bad hex pair, odd digit count or bad separator */
    PB_CANDUMP_E_LEN    = -5,   /* too many bytes (8 classic, 64 FD), invalid FD length,
                                   bad remote length or len8_dlc */
    PB_CANDUMP_E_TRAIL  = -6,   /* unexpected text after the frame */
    PB_CANDUMP_E_XL     = -7,   /* CAN XL frame (not supported) */
};

/* Parses one line (without or with its trailing "\n" / "\r\n").
 * Returns PB_CANDUMP_FRAME with *out filled, PB_CANDUMP_BLANK, or a negative
 * PB_CANDUMP_E_* code; then, if col is not NULL, *col is the 1-based column of
 * the offending byte. *out is unspecified unless a frame was returned. */
int pb_candump_parse(const char *line, size_t len, pb_candump_frame_t *out, size_t *col);

/* A static, human-readable description of a return code (never NULL). */
const char *pb_candump_strerror(int code);

/* N for an interface named "canN" (N decimal, 0..32767), else -1. */
int pb_candump_can_index(const char *iface);

/* Bus numbers of a log's interfaces: N for canN; other names get
 * PB_CANDUMP_NAMED_BUS_BASE, +1, ... in order of first appearance. */
#define PB_CANDUMP_NAMED_BUS_BASE 1000
#define PB_CANDUMP_MAX_NAMED 64
typedef struct {
    char names[PB_CANDUMP_MAX_NAMED][PB_CANDUMP_IFACE_MAX];
    int n;
} pb_candump_buses_t;

/* The bus of iface, or -1 for a name past the first PB_CANDUMP_MAX_NAMED. *added (if
 * not NULL) is 1 when iface is a name met for the first time. */
int pb_candump_bus(pb_candump_buses_t *b, const char *iface, int *added);

#ifdef __cplusplus
}
#endif
#endif
