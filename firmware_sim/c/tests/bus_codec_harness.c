/* The servo-bus framing of both protocols on stdin/stdout, for conformance tests against the vendor SDKs
 * (tests/cfirmware/test_c_servo_bus_codec.py): one request per line, one answer per line.
 *   E P ID INST HEX   -> the instruction packet protocol P (0 STS, 1 Dynamixel 2.0) encodes, hex ("-": refused)
 *   P P HEX           -> every status packet parsed from HEX: "ID ERROR HEXPARAMS" separated by ';' ("-": none),
 *                        then " bad=N" (packets refused for their checksum/CRC or length) */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_bus.h"
#include "gs_hal.h"

uint64_t hal_now_us(void) { return 0; }
size_t hal_host_read(uint8_t *buf, size_t cap) { (void)buf; (void)cap; return 0; }
size_t hal_host_write(const uint8_t *buf, size_t n) { (void)buf; return n; }
void hal_bus_write(const uint8_t *buf, size_t n) { (void)buf; (void)n; }
size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) { (void)buf; (void)cap; (void)timeout_us; return 0; }
void hal_bus_drain(void) {}
void hal_wait(uint64_t until_us, int want_write) { (void)until_us; (void)want_write; }
void hal_log_write(const char *s, size_t n) { (void)s; (void)n; }
int hal_should_stop(void) { return 0; }
uint32_t hal_cycles(void) { return 0; }

static size_t unhex(const char *s, uint8_t *out, size_t cap) {
    size_t n = 0;
    while (s[0] && s[1] && n < cap) {
        unsigned v;
        if (sscanf(s, "%2x", &v) != 1) break;
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

int main(void) {
    static char line[65536];
    static uint8_t in[16384], rx[2u * GS_BUS_MAX_PACKET];
    while (fgets(line, sizeof line, stdin)) {
        char hex[32768] = "";
        unsigned p, id, inst;
        if (sscanf(line, "E %u %u %u %32767s", &p, &id, &inst, hex) >= 3) {
            const gs_bus_codec_t *c = p ? &gs_bus_dxl2_codec : &gs_bus_sts_codec;
            size_t n = unhex(hex, in, sizeof in);
            uint8_t pkt[GS_BUS_MAX_PACKET];
            size_t len = c->encode(pkt, sizeof pkt, (uint8_t)id, (uint8_t)inst, in, n);
            if (!len) printf("-");
            for (size_t i = 0; i < len; i++) printf("%02x", pkt[i]);
            printf("\n");
        } else if (sscanf(line, "P %u %32767s", &p, hex) == 2) {
            const gs_bus_codec_t *c = p ? &gs_bus_dxl2_codec : &gs_bus_sts_codec;
            size_t n = unhex(hex, in, sizeof in), at = 0, rx_len = 0;
            uint32_t bad0 = gs_bus_stats.bad_packets;
            int any = 0;
            gs_status_t st;
            for (;;) {
                while (at < n && rx_len < sizeof rx) rx[rx_len++] = in[at++];
                if (c->parse(rx, &rx_len, &st)) {
                    printf("%s%d %u ", any ? ";" : "", st.id, st.error);
                    for (size_t i = 0; i < st.n && i < sizeof st.params; i++) printf("%02x", st.params[i]);
                    any = 1;
                } else if (at >= n) {
                    break;
                }
            }
            printf("%s bad=%u\n", any ? "" : "-", (unsigned)(gs_bus_stats.bad_packets - bad0));
        } else {
            printf("?\n");
        }
        fflush(stdout);
    }
    return 0;
}
