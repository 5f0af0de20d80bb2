/* can_kernel: a frame as a Linux raw CAN socket delivers it -> can_rx_t.
 *
 * recvmsg on a CAN_RAW socket gives the frame bytes (struct can_frame, CAN_MTU =
 * 16 bytes, or struct canfd_frame, CANFD_MTU = 72 bytes, with CAN_RAW_FD_FRAMES
 * on) and a control buffer of cmsgs: the kernel receive time (SCM_TIMESTAMPNS, a
 * struct timespec, or SCM_TIMESTAMPING, three timespecs of which [0] is the
 * software CLOCK_REALTIME stamp) and, with SO_RXQ_OVFL on, the socket's running
 * count of frames the kernel dropped because the receive queue was full.
 * This is the whole conversion the socket path does (can_socket.c only opens the
 * socket and calls recvmsg), so it is tested with real frames packed exactly as
 * the kernel lays them out, and fuzzed.
 *
 * Pure: no I/O; reads only [frame, frame+n) and [control, control+controllen). */
#ifndef CAN_KERNEL_H
#define CAN_KERNEL_H

#include <stddef.h>
#include <stdint.h>
#include "can_speed.h"

#ifdef __cplusplus
extern "C" {
#endif

enum {
    CAN_K_OK            =  0,
    CAN_K_NO_TIMESTAMP  =  1,   /* frame good, no kernel timestamp cmsg: out->utime = 0 */
    CAN_K_E_SIZE        = -1,   /* frame bytes are neither CAN_MTU nor CANFD_MTU */
    CAN_K_E_LEN         = -2,   /* payload length over 8 (classic) or not a CAN FD length */
    CAN_K_E_CONTROL     = -3,   /* malformed control buffer, or a timestamp out of range */
};

typedef struct {
    int has_dropped;            /* an SO_RXQ_OVFL cmsg was present */
    uint32_t dropped;           /* its value: frames dropped on this socket so far */
} can_kernel_extra_t;

/* Converts one received frame for bus `bus`. Returns CAN_K_OK or
 * CAN_K_NO_TIMESTAMP with *out filled, or a negative CAN_K_E_* code.
 * extra may be NULL. */
int can_kernel_frame(const void *frame, size_t n, const void *control, size_t controllen,
                     int bus, can_rx_t *out, can_kernel_extra_t *extra);

const char *can_kernel_strerror(int code);

#ifdef __cplusplus
}
#endif
#endif
