/* The native (POSIX) port: the host UART is a pty this program creates (or a serial device path),
 * the servo-bus UART is a tty path (the plant's pty) or an inherited descriptor `fd:N` (the launcher
 * passes one end of a socketpair: a pty moves its bytes through a kernel worker at normal priority, and
 * every read of an empty tty waits for that worker, which on a loaded machine stalled the board's ticks
 * for 100 ms and more), the tick timer is CLOCK_MONOTONIC and the log channel is stderr. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE
#endif
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>
#ifdef __linux__
#include <linux/serial.h>
#include <sys/ioctl.h>
#endif

#include "gs_bus.h"
#include "gs_hal.h"
#include "hal_native.h"

static int host_fd = -1, host_slave_fd = -1, bus_fd = -1;
static volatile sig_atomic_t stop_flag;
static uint64_t t0_ns;
/* The self-pipe: SIGTERM/SIGINT write a byte here and every wait polls its read end, so a signal that
 * lands after a hal_should_stop() check but before ppoll still ends that wait at once (without it the
 * wait ran to its timeout: up to 1 s of a lockstep bus read). Never drained: once stopping, every
 * later wait returns at once too. */
static int wake_fd[2] = {-1, -1};

static uint64_t mono_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void on_signal(int sig) {
    (void)sig;
    int saved = errno;
    stop_flag = 1;
    if (wake_fd[1] >= 0 && write(wake_fd[1], "", 1) < 0) {
        /* full (a stop is already signalled) or closed: nothing more to say */
    }
    errno = saved;
}

/* ppoll on `fd` for `events` and on the self-pipe, for at most `timeout_us`; 1 when `fd` is ready. */
static int wait_fd(int fd, short events, uint64_t timeout_us) {
    struct pollfd p[2] = {{fd, events, 0}, {wake_fd[0], POLLIN, 0}};
    struct timespec ts = {(time_t)(timeout_us / 1000000u), (long)(timeout_us % 1000000u) * 1000L};
    if (stop_flag || ppoll(p, wake_fd[0] >= 0 ? 2 : 1, &ts, NULL) <= 0) return 0;
    return (p[0].revents & (events | POLLERR | POLLHUP)) != 0;
}

static int make_raw(int fd) {
    struct termios t;
    if (tcgetattr(fd, &t) != 0) return -1;
    cfmakeraw(&t);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    return tcsetattr(fd, TCSANOW, &t);
}

int native_open_host(const char *spec, char *name, size_t cap) {
    if (strcmp(spec, "pty") == 0) {
        int m = posix_openpt(O_RDWR | O_NOCTTY);
        if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0) return -1;
        const char *slave = ptsname(m);
        if (!slave) return -1;
        snprintf(name, cap, "%s", slave);
        int s = open(slave, O_RDWR | O_NOCTTY); /* kept open: the pty survives the host closing it */
        if (s < 0 || make_raw(s) != 0) return -1;
        host_fd = m;
        host_slave_fd = s;
    } else {
        host_fd = open(spec, O_RDWR | O_NOCTTY);
        if (host_fd < 0) return -1;
        if (isatty(host_fd)) make_raw(host_fd);
        snprintf(name, cap, "%s", spec);
    }
    return fcntl(host_fd, F_SETFL, fcntl(host_fd, F_GETFL) | O_NONBLOCK);
}

/* The termios speed constant of `baud` (0: none: a rate this port cannot ask a tty for). */
static speed_t speed_of(unsigned long baud) {
    switch (baud) {
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
#ifdef B460800
    case 460800: return B460800;
#endif
#ifdef B500000
    case 500000: return B500000;
#endif
#ifdef B576000
    case 576000: return B576000;
#endif
#ifdef B921600
    case 921600: return B921600;
#endif
#ifdef B1000000
    case 1000000: return B1000000;
#endif
#ifdef B2000000
    case 2000000: return B2000000;
#endif
#ifdef B3000000
    case 3000000: return B3000000;
#endif
#ifdef B4000000
    case 4000000: return B4000000;
#endif
    default: return 0;
    }
}

/* A real servo bus (a USB adapter's tty): raw, 8N1, no flow control, `baud` both ways; the device must
 * take the rate (read back after setting it). 0, or -1 with `why` (one line's worth). */
int native_open_bus_tty(const char *path, unsigned long baud, char *why, size_t cap) {
    speed_t sp = speed_of(baud);
    if (!sp) {
        snprintf(why, cap, "%lu baud is not a rate a tty can be set to here (9600 ... 4000000, e.g. 57600 or 1000000)", baud);
        return -1;
    }
    bus_fd = open(path, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (bus_fd < 0) {
        snprintf(why, cap, "%s", strerror(errno));
        return -1;
    }
    struct termios t;
    if (tcgetattr(bus_fd, &t) != 0) {
        snprintf(why, cap, "not a tty (%s)", strerror(errno));
        return -1;
    }
    cfmakeraw(&t);
    t.c_cflag &= (tcflag_t)~(CSIZE | PARENB | CSTOPB | CRTSCTS);
    t.c_cflag |= CS8 | CLOCAL | CREAD;
    t.c_iflag &= (tcflag_t)~(IXON | IXOFF | IXANY);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    struct termios got;
    if (cfsetispeed(&t, sp) != 0 || cfsetospeed(&t, sp) != 0 || tcsetattr(bus_fd, TCSANOW, &t) != 0 ||
        tcgetattr(bus_fd, &got) != 0 || cfgetospeed(&got) != sp || cfgetispeed(&got) != sp) {
        snprintf(why, cap, "the device refuses %lu baud", baud);
        return -1;
    }
    tcflush(bus_fd, TCIOFLUSH);
#ifdef __linux__
    /* a USB adapter hands received bytes on after its latency timer (FTDI: 16 ms by default, longer than a
       tick); low latency asks the driver for 1 ms. Not every device has it (a pty does not): best effort */
    struct serial_struct ss;
    if (ioctl(bus_fd, TIOCGSERIAL, &ss) == 0) {
        ss.flags |= ASYNC_LOW_LATENCY;
        (void)ioctl(bus_fd, TIOCSSERIAL, &ss);
    }
#endif
    return 0;
}

int native_open_bus(const char *path) {
    if (strncmp(path, "fd:", 3) == 0) { /* an inherited descriptor (the launcher's socketpair: no tty layer) */
        char *end = NULL;
        long fd = strtol(path + 3, &end, 10);
        if (!end || *end || fd < 0 || fcntl((int)fd, F_GETFD) < 0) return -1;
        bus_fd = (int)fd;
        return fcntl(bus_fd, F_SETFL, fcntl(bus_fd, F_GETFL) | O_NONBLOCK);
    }
    bus_fd = open(path, O_RDWR | O_NOCTTY);
    if (bus_fd < 0) return -1;
    if (isatty(bus_fd)) make_raw(bus_fd);
    return fcntl(bus_fd, F_SETFL, fcntl(bus_fd, F_GETFL) | O_NONBLOCK);
}

void native_init(void) {
    t0_ns = mono_ns();
    if (pipe2(wake_fd, O_NONBLOCK | O_CLOEXEC) != 0) wake_fd[0] = wake_fd[1] = -1; /* then EINTR alone */
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    setvbuf(stderr, NULL, _IOLBF, 8192);
}

void native_close(void) {
    if (host_fd >= 0) close(host_fd);
    if (host_slave_fd >= 0) close(host_slave_fd);
    if (bus_fd >= 0) close(bus_fd);
    /* the self-pipe stays open: a late signal's handler may still write to it */
}

uint64_t hal_now_us(void) { return (mono_ns() - t0_ns) / 1000u; }

size_t hal_host_read(uint8_t *buf, size_t cap) {
    ssize_t n = read(host_fd, buf, cap);
    return n > 0 ? (size_t)n : 0;
}

size_t hal_host_write(const uint8_t *buf, size_t n) {
    ssize_t k = write(host_fd, buf, n);
    return k > 0 ? (size_t)k : 0;
}

/* A UART sends whether or not anyone listens: a plant that stopped reading (descheduled, SIGSTOPped) must
 * not stop the board. A packet the bus cannot take within BUS_TX_WAIT_US is dropped (the rest of it;
 * counted in gs_bus_stats.tx_dropped) and the board keeps its time. */
#define BUS_TX_WAIT_US 2000u

void hal_bus_write(const uint8_t *buf, size_t n) {
    size_t done = 0;
    uint64_t give_up = hal_now_us() + BUS_TX_WAIT_US;
    /* also while stopping: the last packet (torque off for the whole bus) must go out; BUS_TX_WAIT_US bounds it */
    while (done < n) {
        ssize_t k = write(bus_fd, buf + done, n - done);
        if (k > 0) {
            done += (size_t)k;
        } else if (k < 0 && errno != EAGAIN && errno != EINTR) {
            return;
        } else {
            uint64_t now = hal_now_us();
            if (now >= give_up) {
                gs_bus_stats.tx_dropped += (uint32_t)(n - done);
                return;
            }
            if (stop_flag) { /* the self-pipe is readable now: wait on the bus alone */
                struct pollfd p = {bus_fd, POLLOUT, 0};
                poll(&p, 1, (int)((give_up - now + 999u) / 1000u));
            } else {
                wait_fd(bus_fd, POLLOUT, give_up - now);
            }
        }
    }
}

size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) {
    ssize_t n = read(bus_fd, buf, cap);
    if (n > 0) return (size_t)n;
    if (!wait_fd(bus_fd, POLLIN, timeout_us)) return 0;
    n = read(bus_fd, buf, cap);
    return n > 0 ? (size_t)n : 0;
}

void hal_bus_drain(void) {
    uint8_t junk[256];
    while (read(bus_fd, junk, sizeof junk) > 0) {
    }
}

void native_wait_fd(int fd, int want_write, uint64_t until_us) {
    uint64_t now = hal_now_us();
    if (until_us <= now || stop_flag) return;
    wait_fd(fd, (short)(POLLIN | (want_write ? POLLOUT : 0)), until_us - now);
}

void hal_wait(uint64_t until_us, int want_write) { native_wait_fd(host_fd, want_write, until_us); }

void hal_log_write(const char *s, size_t n) { fwrite(s, 1, n, stderr); }

int hal_should_stop(void) { return stop_flag != 0; }

uint32_t hal_cycles(void) { return 0; }
