/* libFuzzer target c-wire: bytes into the C link decoder and the board session (lockstep).
 *
 * Input: 4 bytes seed the chunking (as the serial-decoder target's seeds: 4 bytes + wire bytes,
 * so the frame-log corpora seed it), the rest is the host's byte stream, delivered in pseudo-random
 * chunks; between chunks the board ticks while it may (at most 800 ticks, 1.6 s, per input: past the watchdog's crouch) and handles
 * messages when it cannot, as the firmware's lockstep loop does. Invariants (abort on failure, plus
 * AddressSanitizer and UBSan): the jitter buffer and the TX ring stay within their sizes, every
 * command stays inside its servo's range and every goal register inside its step range, ESTOP holds
 * (while estopped the desired targets are the hold pose), the decoder's collected block never
 * exceeds GS_MAX_FRAME_BYTES. */
#include <stdlib.h>
#include <string.h>

#include "fuzz_hal.h"
#include "gs_app.h"

static gs_app_t app;

#define CHECK(c) do { if (!(c)) abort(); } while (0)

static void invariants(void) {
    const gs_board_t *b = &app.board;
    CHECK(b->buf.n <= GS_BUFFER_DEPTH);
    CHECK(app.link.tx_len <= GS_TX_RING && app.link.rx_len <= GS_RX_RING);
    CHECK(app.link.block_len <= GS_MAX_FRAME_BYTES);
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        CHECK(b->cmd[i] >= gs_servos[i].min_urad && b->cmd[i] <= gs_servos[i].max_urad);
        CHECK(b->goal[i] >= gs_servos[i].step_lo && b->goal[i] <= gs_servos[i].step_hi);
        if (b->mode == GS_MODE_ESTOP) CHECK(b->desired[i] == b->hold_q[i]);
    }
}

static void run(unsigned *ticks) {
    gs_rx_item_t item;
    for (;;) {
        if (gs_board_can_tick(&app.board) && *ticks < 800u) {
            gs_app_tick(&app);
            (*ticks)++;
        } else {
            gs_link_pump_rx(&app.link);
            if (!gs_link_next(&app.link, &item)) return;
            gs_app_process(&app, &item);
        }
        gs_link_flush(&app.link);
        invariants();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    if (size < 4) return 0;
    uint32_t seed = (uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 | (uint32_t)data[3] << 24;
    data += 4;
    size -= 4;
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    cfg.lockstep = 1;
    fuzz_hal_reset();
    fuzz_in = data;
    fuzz_in_len = 0;
    fuzz_in_pos = 0;
    cfg.boot_checks = 0; /* fuzzed answers: found as faults mid-run, never a refused start */
    (void)gs_app_init(&app, &cfg);
    unsigned ticks = 0;
    size_t at = 0;
    while (at < size) {
        seed = seed * 1103515245u + 12345u;
        size_t n = (seed >> 16) % 301u;
        if (n > size - at) n = size - at;
        fuzz_in_len = at + n; /* the HAL hands out bytes up to here */
        run(&ticks);
        at += n;
    }
    fuzz_in_len = size;
    run(&ticks);
    invariants();
    return 0;
}
