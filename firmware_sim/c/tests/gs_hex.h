/* Hex text in and out for the test harnesses (stdin lines -> bytes -> stdout lines), one copy for all of them. */
#ifndef GS_HEX_H
#define GS_HEX_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

/* The hex digits of `s` up to its first space, newline or end, into `out` (at most `cap` bytes); the byte count,
 * or -1 for an odd count, a non-hex digit or more than `cap` bytes. */
static int gs_unhex(const char *s, uint8_t *out, size_t cap) {
    size_t n = 0;
    while (s[n] && s[n] != ' ' && s[n] != '\n' && s[n] != '\r') n++;
    if (n % 2 || n / 2 > cap) return -1;
    for (size_t i = 0; i < n / 2; i++) {
        unsigned v;
        if (sscanf(s + 2 * i, "%2x", &v) != 1) return -1;
        out[i] = (uint8_t)v;
    }
    return (int)(n / 2);
}

/* `n` bytes as lower-case hex to stdout, no separator. */
static void gs_print_hex(const uint8_t *p, size_t n) {
    for (size_t i = 0; i < n; i++) printf("%02x", p[i]);
}

#endif
