/* Shared library for the differential target c-diff (firmware_sim/cfirmware/fuzz_diff.py): the C
 * frame decoder (gs_link) over a byte string, one text line per frame or error, in wire order:
 *   "F <seq> <raw hex> <gs_dump_msg>"  or  "E <KIND>"
 * (the Python side prints the same from protocol.framing.FrameDecoder). */
#include <stdio.h>
#include <string.h>

#include "gs_hal.h"
#include "gs_link.h"

static const uint8_t *in;
static size_t in_len, in_pos;
static gs_link_t link_;
static char *out_;
static size_t out_cap, out_len;
static uint8_t raw_[GS_MAX_FRAME_BYTES];
static size_t raw_len;

uint64_t hal_now_us(void) { return 0; }
size_t hal_host_read(uint8_t *buf, size_t cap) {
    size_t n = in_len - in_pos;
    if (n > cap) n = cap;
    memcpy(buf, in + in_pos, n);
    in_pos += n;
    return n;
}
size_t hal_host_write(const uint8_t *buf, size_t n) { (void)buf; return n; }
void hal_bus_write(const uint8_t *buf, size_t n) { (void)buf; (void)n; }
size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t t) { (void)buf; (void)cap; (void)t; return 0; }
void hal_bus_drain(void) {}
void hal_wait(uint64_t u, int w) { (void)u; (void)w; }
void hal_log_write(const char *s, size_t n) { (void)s; (void)n; }
int hal_should_stop(void) { return 0; }
uint32_t hal_cycles(void) { return 0; }

static void emit(const char *s) {
    size_t n = strlen(s);
    if (out_len + n < out_cap) {
        memcpy(out_ + out_len, s, n);
        out_len += n;
        out_[out_len] = 0;
    }
}

static void on_raw(void *ctx, const uint8_t *raw, size_t n) {
    (void)ctx;
    memcpy(raw_, raw, n);
    raw_len = n;
}

size_t gs_diff_decode(const uint8_t *data, size_t n, char *out, size_t cap) {
    static char line[4 * GS_MAX_FRAME_BYTES + 1024];
    gs_rx_item_t item;
    in = data;
    in_len = n;
    in_pos = 0;
    out_ = out;
    out_cap = cap;
    out_len = 0;
    if (cap) out[0] = 0;
    gs_link_init(&link_);
    link_.on_raw = on_raw;
    for (;;) {
        gs_link_pump_rx(&link_);
        if (!gs_link_next(&link_, &item)) {
            if (in_pos >= in_len && link_.rx_len == 0) break;
            continue;
        }
        if (item.kind == GS_RX_FRAME) {
            int k = snprintf(line, sizeof line, "F %u ", (unsigned)item.seq);
            for (size_t i = 0; i < raw_len; i++) k += snprintf(line + k, sizeof line - (size_t)k, "%02x", raw_[i]);
            k += snprintf(line + k, sizeof line - (size_t)k, "00 ");
            gs_dump_msg(&item.msg, line + k, sizeof line - (size_t)k);
            emit(line);
            emit("\n");
        } else {
            snprintf(line, sizeof line, "E %s\n", gs_rx_kind_name(item.kind));
            emit(line);
        }
    }
    return out_len;
}
