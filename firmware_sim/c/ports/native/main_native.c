/* The native firmware executable:
 *   gs_firmware --bus tty:PATH:BAUD|TTY|fd:N [--protocol sts|dxl2] [--estop-torque hold|limp]
 *               [--host pty|PATH] [--lockstep|--realtime] [--rate HZ] [--telemetry-rate HZ]
 *               [--watchdog-ms MS] [--log-frames] [--no-boot-checks] [--can IFNAME [--node N] [--fd]]
 * --bus tty:PATH:BAUD is a real servo bus (a USB adapter: raw 8N1 at BAUD, e.g. 57600 or 1000000); TTY
 * (the plant's pty, its settings untouched) and fd:N (an inherited socket) are the emulator's.
 * Prints "board: listening on PTY" on stdout once the bus devices are found, then serves until
 * SIGTERM/SIGINT (then torque off for the whole bus); log channel on stderr. Exit 2 for bad arguments or a
 * port that cannot open (one line naming it); exit 2 too when a boot check refuses the start (a servo missing,
 * answering garbled or twice, of another model than hardware.toml's, outside its step range: one line naming
 * it, torque off for the whole bus). --no-boot-checks (the launcher, for the emulator's --dead-servo ID@0):
 * a servo silent at boot latches SERVO_FAULT instead.
 * --can IFNAME serves the host link on SocketCAN instead of a pty (core/can: the CAN engine; a raw socket on IFNAME
 * filtered on node N, 1..127, default 1; --fd: CAN FD frames), printing "board: listening on can:socketcan:IFNAME
 * (node N)"; an interface that cannot be opened is one line and exit 2. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_app.h"
#include "gs_app_can.h"
#include "gs_hal.h"
#include "gs_log.h"
#include "hal_native.h"

static gs_app_t app;
static gs_app_can_t can_app;

static int num(const char *s, long lo, long hi, long *out) {
    char *end;
    long v = strtol(s, &end, 10);
    if (!*s || *end || v < lo || v > hi) return 0;
    *out = v;
    return 1;
}

static int usage(const char *why) {
    fprintf(stderr, "board: %s\nusage: gs_firmware --bus tty:PATH:BAUD|TTY|fd:N [--protocol sts|dxl2] "
                    "[--estop-torque hold|limp] [--host pty|PATH] [--lockstep|--realtime] [--rate HZ] "
                    "[--telemetry-rate HZ] [--watchdog-ms MS] [--log-frames] [--no-boot-checks] [--can IFNAME [--node N] [--fd]]\n",
            why);
    return 2;
}

int main(int argc, char **argv) {
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    const char *host = "pty", *bus = NULL, *can = NULL;
    long node = 1;
    int can_fd_frames = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        long v;
        int has = i + 1 < argc;
        if (!strcmp(a, "--bus") && has) bus = argv[++i];
        else if (!strcmp(a, "--host") && has) host = argv[++i];
        else if (!strcmp(a, "--can") && has) can = argv[++i];
        else if (!strcmp(a, "--node") && has && num(argv[i + 1], 1, 127, &node)) i++;
        else if (!strcmp(a, "--fd")) can_fd_frames = 1;
        else if (!strcmp(a, "--lockstep")) cfg.lockstep = 1;
        else if (!strcmp(a, "--realtime")) cfg.lockstep = 0;
        else if (!strcmp(a, "--log-frames")) cfg.log_frames = 1;
        else if (!strcmp(a, "--no-boot-checks")) cfg.boot_checks = 0;
        else if (!strcmp(a, "--protocol") && has && !strcmp(argv[i + 1], "sts")) { cfg.bus_protocol = GS_BUS_STS; i++; }
        else if (!strcmp(a, "--protocol") && has && !strcmp(argv[i + 1], "dxl2")) { cfg.bus_protocol = GS_BUS_DXL2; i++; }
        else if (!strcmp(a, "--estop-torque") && has && !strcmp(argv[i + 1], "hold")) { cfg.estop_limp = 0; i++; }
        else if (!strcmp(a, "--estop-torque") && has && !strcmp(argv[i + 1], "limp")) { cfg.estop_limp = 1; i++; }
        else if (!strcmp(a, "--rate") && has && num(argv[i + 1], 1, 10000, &v) && 1000000 % v == 0) { cfg.rate_hz = (uint32_t)v; i++; }
        else if (!strcmp(a, "--telemetry-rate") && has && num(argv[i + 1], 1, 10000, &v)) { cfg.telemetry_rate_hz = (uint32_t)v; i++; }
        else if (!strcmp(a, "--watchdog-ms") && has && num(argv[i + 1], 1, 3600000, &v)) { cfg.watchdog_ms = (uint32_t)v; i++; }
        else return usage("bad or unknown argument");
    }
    if (!bus) return usage("--bus TTY is required");
    if (cfg.telemetry_rate_hz > cfg.rate_hz) return usage("telemetry rate must be at most the control rate");
    native_init();
    char name[256];
    if (!strncmp(bus, "tty:", 4)) { /* tty:PATH:BAUD (PATH may hold colons: the baud is after the last) */
        const char *colon = strrchr(bus + 4, ':');
        long baud;
        char path[512], why[160];
        if (!colon || colon == bus + 4 || (size_t)(colon - (bus + 4)) >= sizeof path || !num(colon + 1, 1, 100000000, &baud))
            return usage("--bus tty:PATH:BAUD needs a device path and a baud rate, e.g. tty:/dev/ttyUSB0:1000000");
        memcpy(path, bus + 4, (size_t)(colon - (bus + 4)));
        path[colon - (bus + 4)] = 0;
        if (native_open_bus_tty(path, (unsigned long)baud, why, sizeof why) != 0) {
            fprintf(stderr, "board: cannot open the servo bus %s at %ld baud: %s\n", path, baud, why);
            return 2;
        }
        cfg.bus_baud = (uint32_t)baud;
    } else if (native_open_bus(bus) != 0) {
        fprintf(stderr, "board: cannot open the servo bus %s\n", bus);
        return 2;
    }
    if (can) {
        char why[160];
        if (native_open_can(can, (unsigned)node, can_fd_frames, why, sizeof why) != 0) {
            fprintf(stderr, "board: cannot open CAN interface %s: %s\n", can, why);
            return 2;
        }
        setvbuf(stderr, NULL, _IOFBF, 1u << 16); /* flushed whenever the board waits (can_native.c) */
        printf("board: listening on can:socketcan:%s (node %ld)\n", can, node);
        fflush(stdout);
        int st = gs_app_can_run(&can_app, &cfg, (unsigned)node, can_fd_frames);
        native_close_can();
        native_close();
        return st;
    }
    if (native_open_host(host, name, sizeof name) != 0) {
        fprintf(stderr, "board: cannot open link %s\n", host);
        return 2;
    }
    printf("board: listening on %s\n", name);
    fflush(stdout);
    int status = gs_app_run(&app, &cfg);
    native_close();
    return status;
}
