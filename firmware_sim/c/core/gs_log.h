/* The log channel: human lines ("board: ...", which the launcher passes to stderr as the Python
 * board prints them) and machine records ("F rx|tx T_US HEX" frame records for the frame log,
 * "S key=value ..." statistics). Streamed piece by piece (no line buffer, no printf: an MCU
 * build has neither the RAM nor the float formatting for it). */
#ifndef GS_LOG_H
#define GS_LOG_H

#include <stddef.h>
#include <stdint.h>

void gs_log_str(const char *s);
void gs_log_u64(uint64_t v);
void gs_log_i64(int64_t v);
void gs_log_hex(const uint8_t *p, size_t n);
void gs_log_hex32(uint32_t v); /* 0x%08x */
/* Seconds with six decimals from microseconds ("1.234000"). */
void gs_log_secs(int64_t us);
void gs_log_end(void);

#endif
