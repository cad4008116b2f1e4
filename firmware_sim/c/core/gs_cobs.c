/* COBS by hand: an MCU has no `cobs` package. The decoder follows cobs.cobs.decode exactly (same
 * blocks accepted, same output), which tests/cfirmware check against the Python package. */
#include "gs_cobs.h"

size_t gs_cobs_encode(const uint8_t *in, size_t n, uint8_t *out) {
    size_t code_at = 0, o = 1;
    uint8_t code = 1;
    for (size_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            code++;
            if (code == 0xFFu) {
                out[code_at] = code;
                code_at = o++;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    return o;
}

long gs_cobs_decode(uint8_t *buf, size_t n) {
    size_t idx = 0, o = 0;
    if (n == 0) return 0;
    for (;;) {
        uint8_t len = buf[idx];
        if (len == 0) return -1;
        idx++;
        size_t end = idx + len - 1u;
        if (end > n) return -1; /* not enough input bytes for the length code */
        for (size_t k = idx; k < end; k++) {
            if (buf[k] == 0) return -1;
            buf[o++] = buf[k];
        }
        idx = end;
        if (idx < n) {
            if (len < 0xFFu) buf[o++] = 0;
        } else {
            break;
        }
    }
    return (long)o;
}
