/* The boot configuration block of the MCU images (mps2, stm32f4): ten 32-bit words at the start of RAM
 * (section .bootcfg, NOLOAD: never zeroed by the startup code), written before reset by the launcher through
 * QEMU's generic loader (-device loader,addr=...,data=...; firmware_sim/cfirmware/launcher.py
 * boot_config_words). Layout, in words: magic 'GSCF' (0x47534346), lockstep, rate_hz, telemetry_rate_hz,
 * watchdog_ms, log_frames, bus_protocol (0 STS, 1 Dynamixel 2.0), estop_limp (0 hold, 1 limp), boot_checks
 * (0: the emulator's dead servo at boot is a fault, not a refused start), check (the XOR of the nine words
 * before it). A block whose magic, check word or values are wrong is ignored: the defaults apply (a real
 * board's RAM after power-on holds no valid block). */
#ifndef GS_BOOTCFG_H
#define GS_BOOTCFG_H

#include <stdint.h>

#include "gs_config.h"

typedef struct {
    uint32_t magic, lockstep, rate_hz, telemetry_rate_hz, watchdog_ms, log_frames, bus_protocol, estop_limp,
        boot_checks, check;
} gs_boot_cfg_t;

#define GS_BOOT_MAGIC 0x47534346u

/* The block (defined in gs_bootcfg.c, placed by the port's linker script). */
extern volatile gs_boot_cfg_t gs_boot_cfg;

/* Apply a valid block to `cfg` (1) or leave `cfg` as it is (0: no block, a bad check word or a value out of
 * range). */
int gs_boot_cfg_apply(gs_settings_t *cfg);

#endif
