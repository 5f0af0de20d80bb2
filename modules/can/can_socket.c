/* SocketCAN system calls only (see can_socket.h). */
#include "can_socket.h"

#include <errno.h>
#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

int can_socket_open(const char *iface, pb_err_t *err)
{
    int fd = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (fd < 0)
        return pb_err_set(err, "%s: cannot open a raw CAN socket: %s%s", iface, strerror(errno),
                          errno == EAFNOSUPPORT ? " (this kernel has no AF_CAN: load the can and can_raw modules)" : "");
    int on = 1;
    can_err_mask_t errmask = CAN_ERR_MASK;
    struct ifreq ifr;
    memset(&ifr, 0, sizeof ifr);
    if (strlen(iface) >= sizeof ifr.ifr_name) { close(fd); return pb_err_set(err, "%s: interface name too long", iface); }
    strcpy(ifr.ifr_name, iface);
    if (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) != 0 ||
        setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errmask, sizeof errmask) != 0 ||
        setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof on) != 0 ||
        setsockopt(fd, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on) != 0) {
        int e = errno;
        close(fd);
        return pb_err_set(err, "%s: setsockopt: %s", iface, strerror(e));
    }
    if (ioctl(fd, SIOCGIFINDEX, &ifr) != 0) {
        int e = errno;
        close(fd);
        return pb_err_set(err, "%s: no such CAN interface: %s", iface, strerror(e));
    }
    struct sockaddr_can addr;
    memset(&addr, 0, sizeof addr);
    addr.can_family = AF_CAN;
    addr.can_ifindex = ifr.ifr_ifindex;
    if (bind(fd, (struct sockaddr *)&addr, sizeof addr) != 0) {
        int e = errno;
        close(fd);
        return pb_err_set(err, "%s: bind: %s", iface, strerror(e));
    }
    return fd;
}

int can_socket_read(int fd, int bus, int timeout_ms, can_rx_t *out, can_kernel_extra_t *extra, pb_err_t *err)
{
    struct pollfd p = { .fd = fd, .events = POLLIN };
    int r = poll(&p, 1, timeout_ms);
    if (r == 0 || (r < 0 && errno == EINTR)) return 2;
    if (r < 0) { pb_err_set(err, "poll: %s", strerror(errno)); return -100; }
    struct canfd_frame frame;
    _Alignas(struct cmsghdr) uint8_t control[256];
    struct iovec iov = { .iov_base = &frame, .iov_len = sizeof frame };
    struct msghdr msg = { .msg_iov = &iov, .msg_iovlen = 1, .msg_control = control, .msg_controllen = sizeof control };
    ssize_t n = recvmsg(fd, &msg, 0);
    if (n < 0 && errno == EINTR) return 2;
    if (n < 0) { pb_err_set(err, "recvmsg: %s", strerror(errno)); return -100; }
    return can_kernel_frame(&frame, (size_t)n, control, msg.msg_controllen, bus, out, extra);
}
