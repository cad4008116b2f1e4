/* The native port's CAN controller: a SocketCAN raw socket (Linux), gs_can_hal.h.
 *
 * native_open_can(ifname, node, fd) binds a CAN_RAW socket to the interface with two filters, as the Python board's
 * bus (firmware_sim/transports/can.py): the node's identifiers (id & 0x7F == node) and the broadcast ESTOP 0x000,
 * standard frames only; with `fd` it enables CAN_RAW_FD_FRAMES (frames of up to 64 bytes both ways). The socket
 * is non-blocking: a full interface transmit queue returns ENOBUFS (or EAGAIN), which hal_can_send reports as 0
 * (the link keeps the frame at the head of its queue and retries after its backoff: nothing lost or reordered). */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <linux/can.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>

#include "gs_can_hal.h"
#include "gs_hal.h"
#include "hal_native.h"

static int can_fd = -1;
static int can_fd_frames;

int native_open_can(const char *ifname, unsigned node, int fd, char *why, size_t cap) {
    struct ifreq ifr;
    struct sockaddr_can addr;
    if (strlen(ifname) >= IFNAMSIZ) {
        snprintf(why, cap, "interface name too long");
        return -1;
    }
    can_fd = socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
    if (can_fd < 0) {
        snprintf(why, cap, "no CAN sockets here (%s)", strerror(errno));
        return -1;
    }
    memset(&ifr, 0, sizeof ifr);
    snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "%s", ifname);
    if (ioctl(can_fd, SIOCGIFINDEX, &ifr) < 0) {
        snprintf(why, cap, "%s", strerror(errno));
        return -1;
    }
    struct can_filter filters[2] = {
        {(canid_t)node, (canid_t)(0x7Fu | CAN_EFF_FLAG)},   /* this node's identifiers, standard frames */
        {0x000u, (canid_t)(CAN_SFF_MASK | CAN_EFF_FLAG)}, /* the broadcast ESTOP */
    };
    if (setsockopt(can_fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters, sizeof filters) < 0) {
        snprintf(why, cap, "filters refused (%s)", strerror(errno));
        return -1;
    }
    if (fd) {
        int on = 1;
        if (setsockopt(can_fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) < 0) {
            snprintf(why, cap, "CAN FD refused (%s)", strerror(errno));
            return -1;
        }
        can_fd_frames = 1;
    }
    memset(&addr, 0, sizeof addr);
    addr.can_family = AF_CAN;
    addr.can_ifindex = ifr.ifr_ifindex;
    if (bind(can_fd, (struct sockaddr *)&addr, sizeof addr) < 0) {
        snprintf(why, cap, "%s", strerror(errno));
        return -1;
    }
    return 0;
}

void native_close_can(void) {
    if (can_fd >= 0) close(can_fd);
    can_fd = -1;
}

int hal_can_recv(gs_can_frame_t *f) {
    struct canfd_frame cf;
    for (;;) {
        ssize_t n = read(can_fd, &cf, sizeof cf);
        if (n < 0 && errno == EINTR) continue;
        if (n != (ssize_t)CAN_MTU && n != (ssize_t)CANFD_MTU) return 0;
        if (cf.can_id & CAN_ERR_FLAG) continue; /* error frames are not subscribed; skip one anyway */
        memset(f, 0, sizeof *f);
        f->flags = (uint8_t)((n == (ssize_t)CANFD_MTU ? GS_CAN_FLAG_FD : 0u) | ((cf.can_id & CAN_EFF_FLAG) ? GS_CAN_FLAG_EXT : 0u) |
                             ((cf.can_id & CAN_RTR_FLAG) ? GS_CAN_FLAG_RTR : 0u));
        f->id = cf.can_id & ((cf.can_id & CAN_EFF_FLAG) ? CAN_EFF_MASK : CAN_SFF_MASK);
        f->len = cf.len > (n == (ssize_t)CANFD_MTU ? 64u : 8u) ? (uint8_t)(n == (ssize_t)CANFD_MTU ? 64u : 8u) : cf.len;
        if (!(f->flags & GS_CAN_FLAG_RTR)) memcpy(f->data, cf.data, f->len);
        return 1;
    }
}

int hal_can_send(const gs_can_frame_t *f) {
    struct canfd_frame cf;
    int is_fd = (f->flags & GS_CAN_FLAG_FD) != 0;
    if ((is_fd && !can_fd_frames) || f->len > (is_fd ? 64u : 8u)) return -1;
    memset(&cf, 0, sizeof cf);
    cf.can_id = f->id | ((f->flags & GS_CAN_FLAG_EXT) ? CAN_EFF_FLAG : 0u);
    cf.len = f->len;
    memcpy(cf.data, f->data, f->len);
    size_t mtu = is_fd ? CANFD_MTU : CAN_MTU;
    for (;;) {
        ssize_t n = write(can_fd, &cf, mtu);
        if (n == (ssize_t)mtu) return 1;
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && (errno == ENOBUFS || errno == EAGAIN)) return 0;
        return 0; /* another error (the interface went down): retried after the backoff, as the Python board does */
    }
}

/* The log channel (stderr) is fully buffered on a CAN link (main_native.c: a frame record per CAN frame, one
 * write each when line-buffered, was a large share of a lockstep tick's system calls under UML): what the board
 * said goes out before it sleeps. */
void hal_can_wait(uint64_t until_us, int want_write) {
    fflush(stderr);
    native_wait_fd(can_fd, want_write, until_us);
}
