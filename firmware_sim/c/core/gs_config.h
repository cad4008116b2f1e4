/* Compile-time sizes and the run-time settings of the firmware core.
 *
 * Sizes are fixed (no malloc): the jitter buffer holds GS_BUFFER_DEPTH frames, the host UART has
 * an RX ring of GS_RX_RING bytes and a TX ring of GS_TX_RING bytes. The defaults of gs_settings_t
 * are the Python board's (firmware_sim/config.py BoardConfig). */
#ifndef GS_CONFIG_H
#define GS_CONFIG_H

#include <stdint.h>

#include "gs_servo_table.h" /* generated per robot: GS_SERVO_COUNT, gs_servos[], GS_ROBOT_NAME ... */

#ifndef GS_BUFFER_DEPTH
#define GS_BUFFER_DEPTH 32u /* frames; the host keeps ~6 (60 ms lookahead of 10 ms frames) in flight */
#endif
#ifndef GS_RX_RING
#define GS_RX_RING 512u /* host UART receive ring (bytes) */
#endif
#ifndef GS_TX_RING
#define GS_TX_RING 1024u /* host UART transmit ring (bytes): ~5 telemetry reports */
#endif
#define GS_TELEMETRY_BACKLOG 768u /* telemetry is dropped rather than queued past this backlog */
#define GS_LOCKSTEP_BACKLOG 512u /* lockstep: stop ticking while this much waits to go out */
#define GS_GAP_WINDOW 64u /* missing sequence numbers remembered by the gap detector */

typedef struct {
    uint32_t rate_hz;            /* control loop rate (500) */
    uint8_t lockstep;            /* virtual time advanced by frames and ADVANCE */
    uint32_t telemetry_rate_hz;  /* TELEMETRY and SIM_STATE rate (50) */
    uint32_t watchdog_ms;        /* link silence before HOLD (200) */
    uint32_t crouch_after_ms;    /* further silence before CROUCH + latched fault (1000) */
    int64_t max_late_us;         /* frames due earlier than now - this: NACK LATE (20 000) */
    int64_t max_future_us;       /* frames due later than now + this: NACK TOO_FAR_FUTURE (5 000 000) */
    int64_t resume_gap_us;       /* an idle servo starts a new stream from where it is (50 000) */
    int32_t crouch_speed_urad_s; /* speed while crouching (1 rad/s) */
    int32_t resume_speed_urad_s; /* peak speed of the blend after a hold (2.6 rad/s) */
    int64_t resume_blend_min_us; /* shortest blend (40 000) */
    uint8_t log_frames;          /* write every frame in/out to the log channel */
    uint8_t log_bus;             /* write bus statistics to the log channel */
    uint8_t bus_protocol;        /* servo bus: GS_BUS_STS (0, Feetech) or GS_BUS_DXL2 (1, Dynamixel 2.0) */
    uint32_t bus_baud;           /* the servo bus line's baud rate (0: a socket to the plant, no wire time) */
    uint8_t estop_limp;          /* ESTOP: 0 hold where the servos are (torque on), 1 limp (torque off) */
    uint8_t boot_checks;         /* 1: a servo missing, garbled or twice, of another model or outside its range at
                                    boot refuses the start (gs_board_boot returns 2, torque off); 0: the emulator's
                                    injected dead servo (--dead-servo ID@0) and the fuzzers: found as SERVO_FAULT */
} gs_settings_t;

void gs_config_defaults(gs_settings_t *cfg);
uint32_t gs_config_tick_us(const gs_settings_t *cfg);
/* Ticks between telemetry reports: max(1, round-half-even(rate / telemetry rate)), like Python's round(). */
uint32_t gs_config_telemetry_every(const gs_settings_t *cfg);

#endif
