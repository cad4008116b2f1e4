#include "gs_config.h"

void gs_config_defaults(gs_settings_t *c) {
    c->rate_hz = 500;
    c->lockstep = 0;
    c->telemetry_rate_hz = 50;
    c->watchdog_ms = 200;
    c->crouch_after_ms = 1000;
    c->max_late_us = 20000;
    c->max_future_us = 5000000;
    c->resume_gap_us = 50000;
    c->crouch_speed_urad_s = 1000000;
    c->resume_speed_urad_s = 2600000;
    c->resume_blend_min_us = 40000;
    c->log_frames = 0;
    c->log_bus = 0;
    c->bus_protocol = 0;
    c->bus_baud = 0;
    c->estop_limp = 0;
    c->boot_checks = 1;
}

uint32_t gs_config_tick_us(const gs_settings_t *c) { return 1000000u / c->rate_hz; }

uint32_t gs_config_telemetry_every(const gs_settings_t *c) {
    uint32_t q = c->rate_hz / c->telemetry_rate_hz, r = c->rate_hz % c->telemetry_rate_hz;
    if (2u * r > c->telemetry_rate_hz || (2u * r == c->telemetry_rate_hz && (q & 1u))) q++;
    return q ? q : 1u;
}
