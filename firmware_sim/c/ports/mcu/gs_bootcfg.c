/* The boot configuration block of the MCU images: gs_bootcfg.h. */
#include "gs_bootcfg.h"

__attribute__((section(".bootcfg"), used)) volatile gs_boot_cfg_t gs_boot_cfg;

int gs_boot_cfg_apply(gs_settings_t *cfg) {
    const volatile gs_boot_cfg_t *b = &gs_boot_cfg;
    if (!(b->magic == GS_BOOT_MAGIC &&
          b->check == (b->magic ^ b->lockstep ^ b->rate_hz ^ b->telemetry_rate_hz ^ b->watchdog_ms ^ b->log_frames ^
                       b->bus_protocol ^ b->estop_limp ^ b->boot_checks) &&
          b->bus_protocol <= 1u && b->rate_hz >= 1u && b->rate_hz <= 10000u && 1000000u % b->rate_hz == 0u &&
          b->telemetry_rate_hz >= 1u && b->telemetry_rate_hz <= b->rate_hz && b->watchdog_ms >= 1u))
        return 0;
    cfg->lockstep = (uint8_t)(b->lockstep != 0u);
    cfg->rate_hz = b->rate_hz;
    cfg->telemetry_rate_hz = b->telemetry_rate_hz;
    cfg->watchdog_ms = b->watchdog_ms;
    cfg->log_frames = (uint8_t)(b->log_frames != 0u);
    cfg->bus_protocol = (uint8_t)b->bus_protocol;
    cfg->estop_limp = (uint8_t)(b->estop_limp != 0u);
    cfg->boot_checks = (uint8_t)(b->boot_checks != 0u);
    return 1;
}
