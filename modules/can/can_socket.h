/* can_socket: the thin SocketCAN layer (raw socket, kernel timestamps, listen-only).
 *
 * Listen-only: the module never writes to the socket (there is no send path in
 * this code). Whether the controller itself stays silent on the bus (no ACKs) is
 * a property of the interface, set outside the module:
 *   ip link set can0 type can bitrate 500000 listen-only on
 * Frame conversion lives in can_kernel.c (tested); this file only makes system
 * calls, and is not exercised on a kernel without AF_CAN (see docs/can.md).
 * Ownership: can_socket_open returns an fd the caller closes. */
#ifndef CAN_SOCKET_H
#define CAN_SOCKET_H

#include "core/can_kernel.h"
#include "pb_err.h"

/* Opens a CAN_RAW socket bound to iface with CAN FD frames, error frames,
 * SO_TIMESTAMPNS and SO_RXQ_OVFL on. Returns the fd, or -1 with err. */
int can_socket_open(const char *iface, pb_err_t *err);

/* Waits up to timeout_ms for one frame and converts it (can_kernel_frame).
 * Returns a CAN_K_* code, 2 on timeout / EINTR (nothing read), or -100 on a
 * socket error (err set). */
int can_socket_read(int fd, int bus, int timeout_ms, can_rx_t *out, can_kernel_extra_t *extra, pb_err_t *err);

#endif
