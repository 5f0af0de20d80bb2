/* Kernel frame layout and control messages -> can_rx_t (see can_kernel.h). */
#include "can_kernel.h"

#include <time.h>
#include <string.h>
#include <sys/socket.h>
#include <linux/can.h>
#include <linux/errqueue.h>

static int fd_length_ok(unsigned len)
{
    return len <= 8 || len == 12 || len == 16 || len == 20 || len == 24 || len == 32 || len == 48 || len == 64;
}

/* A kernel timestamp in us, or -1 if it is no valid CLOCK_REALTIME time. */
static int64_t ts_utime(struct timespec ts)
{
    if (ts.tv_sec < 0 || ts.tv_sec > 100000000000LL || ts.tv_nsec < 0 || ts.tv_nsec > 999999999) return -1;
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

/* Walks the cmsgs by hand with bounds checks on every header: the glibc macros
 * trust cmsg_len more than a fuzzer's bytes deserve. */
static int parse_control(const uint8_t *c, size_t n, int64_t *utime, can_kernel_extra_t *extra)
{
    size_t pos = 0;
    int have = 0;
    while (pos + sizeof(struct cmsghdr) <= n) {
        struct cmsghdr h;
        memcpy(&h, c + pos, sizeof h);
        if (h.cmsg_len < sizeof h || h.cmsg_len > n - pos) return CAN_K_E_CONTROL;
        const uint8_t *payload = c + pos + CMSG_LEN(0);
        size_t plen = h.cmsg_len - CMSG_LEN(0);
        if (h.cmsg_level == SOL_SOCKET) {
            if (h.cmsg_type == SCM_TIMESTAMPNS && plen >= sizeof(struct timespec) && have < 2) {
                struct timespec ts;
                memcpy(&ts, payload, sizeof ts);
                if ((*utime = ts_utime(ts)) < 0) return CAN_K_E_CONTROL;
                have = 2;
            } else if (h.cmsg_type == SCM_TIMESTAMPING && plen >= sizeof(struct scm_timestamping) && have < 1) {
                struct scm_timestamping t;
                memcpy(&t, payload, sizeof t);
                if (t.ts[0].tv_sec || t.ts[0].tv_nsec) {
                    if ((*utime = ts_utime(t.ts[0])) < 0) return CAN_K_E_CONTROL;
                    have = 1;
                }
            } else if (h.cmsg_type == SO_RXQ_OVFL && plen >= sizeof(uint32_t)) {
                uint32_t d;
                memcpy(&d, payload, sizeof d);
                extra->has_dropped = 1;
                extra->dropped = d;
            }
        }
        size_t step = CMSG_ALIGN(h.cmsg_len);
        if (step > n - pos) break;      /* last cmsg without padding */
        pos += step;
    }
    return have ? CAN_K_OK : CAN_K_NO_TIMESTAMP;
}

int can_kernel_frame(const void *frame, size_t n, const void *control, size_t controllen,
                     int bus, can_rx_t *out, can_kernel_extra_t *extra)
{
    can_kernel_extra_t ex_local;
    if (!extra) extra = &ex_local;
    memset(extra, 0, sizeof *extra);
    memset(out, 0, sizeof *out);
    uint32_t can_id;
    if (n == CAN_MTU) {
        struct can_frame f;
        memcpy(&f, frame, sizeof f);
        if (f.len > CAN_MAX_DLEN) return CAN_K_E_LEN;
        can_id = f.can_id;
        out->len = f.len;
        memcpy(out->data, f.data, f.len);
    } else if (n == CANFD_MTU) {
        struct canfd_frame f;
        memcpy(&f, frame, sizeof f);
        if (f.len > CANFD_MAX_DLEN || !fd_length_ok(f.len)) return CAN_K_E_LEN;
        can_id = f.can_id;
        out->fd = 1;
        out->len = f.len;
        memcpy(out->data, f.data, f.len);
    } else {
        return CAN_K_E_SIZE;
    }
    out->bus = bus;
    out->error = (can_id & CAN_ERR_FLAG) != 0;
    out->rtr = (can_id & CAN_RTR_FLAG) != 0;
    out->extended = (can_id & CAN_EFF_FLAG) != 0;
    if (out->error) out->id = can_id & CAN_ERR_MASK;
    else out->id = can_id & (out->extended ? CAN_EFF_MASK : CAN_SFF_MASK);
    if (out->rtr) memset(out->data, 0, sizeof out->data);   /* a remote frame carries no data */
    if (!control || controllen == 0) return CAN_K_NO_TIMESTAMP;
    return parse_control(control, controllen, &out->utime, extra);
}

const char *can_kernel_strerror(int code)
{
    switch (code) {
    case CAN_K_OK: return "ok";
    case CAN_K_NO_TIMESTAMP: return "no kernel timestamp";
    case CAN_K_E_SIZE: return "frame size is neither CAN_MTU (16) nor CANFD_MTU (72)";
    case CAN_K_E_LEN: return "payload length invalid for the frame type";
    case CAN_K_E_CONTROL: return "malformed control message buffer or timestamp";
    default: return "unknown error";
    }
}
