/* The native firmware executable:
 *   gs_firmware --bus TTY|fd:N [--host pty|PATH] [--lockstep|--realtime] [--rate HZ]
 *               [--telemetry-rate HZ] [--watchdog-ms MS] [--log-frames]
 * Prints "board: listening on PTY" on stdout once the bus devices are found, then serves until
 * SIGTERM/SIGINT; log channel on stderr. Exit 2 for bad arguments or a port that cannot open. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_app.h"
#include "gs_hal.h"
#include "gs_log.h"
#include "hal_native.h"

static gs_app_t app;

static int num(const char *s, long lo, long hi, long *out) {
    char *end;
    long v = strtol(s, &end, 10);
    if (!*s || *end || v < lo || v > hi) return 0;
    *out = v;
    return 1;
}

static int usage(const char *why) {
    fprintf(stderr, "board: %s\nusage: gs_firmware --bus TTY|fd:N [--host pty|PATH] [--lockstep|--realtime] [--rate HZ] "
                    "[--telemetry-rate HZ] [--watchdog-ms MS] [--log-frames]\n", why);
    return 2;
}

int main(int argc, char **argv) {
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    const char *host = "pty", *bus = NULL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        long v;
        int has = i + 1 < argc;
        if (!strcmp(a, "--bus") && has) bus = argv[++i];
        else if (!strcmp(a, "--host") && has) host = argv[++i];
        else if (!strcmp(a, "--lockstep")) cfg.lockstep = 1;
        else if (!strcmp(a, "--realtime")) cfg.lockstep = 0;
        else if (!strcmp(a, "--log-frames")) cfg.log_frames = 1;
        else if (!strcmp(a, "--rate") && has && num(argv[i + 1], 1, 10000, &v) && 1000000 % v == 0) { cfg.rate_hz = (uint32_t)v; i++; }
        else if (!strcmp(a, "--telemetry-rate") && has && num(argv[i + 1], 1, 10000, &v)) { cfg.telemetry_rate_hz = (uint32_t)v; i++; }
        else if (!strcmp(a, "--watchdog-ms") && has && num(argv[i + 1], 1, 3600000, &v)) { cfg.watchdog_ms = (uint32_t)v; i++; }
        else return usage("bad or unknown argument");
    }
    if (!bus) return usage("--bus TTY is required");
    if (cfg.telemetry_rate_hz > cfg.rate_hz) return usage("telemetry rate must be at most the control rate");
    native_init();
    char name[256];
    if (native_open_bus(bus) != 0) {
        fprintf(stderr, "board: cannot open the servo bus %s\n", bus);
        return 2;
    }
    if (native_open_host(host, name, sizeof name) != 0) {
        fprintf(stderr, "board: cannot open link %s\n", host);
        return 2;
    }
    printf("board: listening on %s\n", name);
    fflush(stdout);
    gs_app_run(&app, &cfg);
    native_close();
    return 0;
}
