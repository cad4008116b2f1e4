/* The hardware abstraction the firmware core runs on (one implementation per port).
 *
 * Three peripherals: the host UART (the GhostShell wire), the servo-bus UART (Feetech SCS/STS or
 * Dynamixel Protocol 2.0 packets, gs_bus.h; 1 Mbaud or what the port opened it at), a microsecond tick timer; plus a log channel (stderr natively, a third UART
 * on the MCU) and an idle wait. Nothing here allocates. */
#ifndef GS_HAL_H
#define GS_HAL_H

#include <stddef.h>
#include <stdint.h>

/* Monotonic microseconds since boot (the realtime board clock). */
uint64_t hal_now_us(void);

/* Host UART, non-blocking: bytes available now (0 when none); bytes accepted for sending. */
size_t hal_host_read(uint8_t *buf, size_t cap);
size_t hal_host_write(const uint8_t *buf, size_t n);

/* Servo-bus UART: write a whole packet (blocks until it is handed to the line); read what arrives
 * within `timeout_us` (returns as soon as at least one byte came; 0 on timeout; 0 us: only what is
 * there now); drop stale input. */
void hal_bus_write(const uint8_t *buf, size_t n);
size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us);
void hal_bus_drain(void);

/* Sleep until `until_us` (hal_now_us clock) or until host input arrives, whichever is first; with
 * `want_write` also return when the host UART can take more bytes. */
void hal_wait(uint64_t until_us, int want_write);

/* Log channel: append bytes (lines end with '\n', written by the core). */
void hal_log_write(const char *s, size_t n);

/* Non-zero when the port was asked to stop (native: SIGTERM/SIGINT; an MCU never stops). */
int hal_should_stop(void);

/* Optional cycle counter for the tick-cost figure (0 when the port has none). */
uint32_t hal_cycles(void);

#endif
