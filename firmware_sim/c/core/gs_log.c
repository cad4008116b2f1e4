#include "gs_log.h"

#include "gs_hal.h"

static size_t slen(const char *s) {
    size_t n = 0;
    while (s[n]) n++;
    return n;
}

void gs_log_str(const char *s) { hal_log_write(s, slen(s)); }

void gs_log_u64(uint64_t v) {
    char buf[21];
    size_t i = sizeof buf;
    do {
        buf[--i] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v);
    hal_log_write(&buf[i], sizeof buf - i);
}

void gs_log_i64(int64_t v) {
    if (v < 0) {
        hal_log_write("-", 1);
        gs_log_u64((uint64_t)0 - (uint64_t)v);
    } else {
        gs_log_u64((uint64_t)v);
    }
}

void gs_log_hex(const uint8_t *p, size_t n) {
    static const char digits[] = "0123456789abcdef";
    char buf[32];
    size_t k = 0;
    for (size_t i = 0; i < n; i++) {
        buf[k++] = digits[p[i] >> 4];
        buf[k++] = digits[p[i] & 15u];
        if (k == sizeof buf) {
            hal_log_write(buf, k);
            k = 0;
        }
    }
    if (k) hal_log_write(buf, k);
}

void gs_log_hex32(uint32_t v) {
    uint8_t b[4] = {(uint8_t)(v >> 24), (uint8_t)(v >> 16), (uint8_t)(v >> 8), (uint8_t)v};
    gs_log_str("0x");
    gs_log_hex(b, 4);
}

void gs_log_secs(int64_t us) {
    if (us < 0) {
        gs_log_str("-");
        us = -us;
    }
    gs_log_u64((uint64_t)us / 1000000u);
    char frac[7];
    uint64_t f = (uint64_t)us % 1000000u;
    frac[0] = '.';
    for (int i = 6; i >= 1; i--) {
        frac[i] = (char)('0' + (int)(f % 10u));
        f /= 10u;
    }
    hal_log_write(frac, 7);
}

void gs_log_end(void) { hal_log_write("\n", 1); }
