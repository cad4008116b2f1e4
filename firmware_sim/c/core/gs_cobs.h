/* COBS (Consistent Overhead Byte Stuffing), as the Python `cobs` package does it. */
#ifndef GS_COBS_H
#define GS_COBS_H
#include <stddef.h>
#include <stdint.h>
/* Encode `n` bytes into `out` (room for n + n/254 + 1 bytes); returns the length. No delimiter. */
size_t gs_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* Decode in place (the output is never longer than the input); returns the length, or -1 when the
 * block is not valid COBS (a zero byte, or a code byte pointing past the end). */
long gs_cobs_decode(uint8_t *buf, size_t n);
#endif
