/* libFuzzer target c-can: CAN frames into the C firmware's CAN link (fixed-layout reassembly, ISO-TP both ways,
 * the board's transmit policy) and the board core, lockstep, node 5, the emulated servo bus of fuzz_hal.c.
 *
 * Input: byte 0 = options (bit 0: a CAN FD link; bits 1..3: how many of the board's writes in a row the bus
 * refuses, as SocketCAN's ENOBUFS, before it takes one), then frame records in the can-decoder target's
 * layout (host/tools/fuzz/can_decoder.py, so its corpus seeds this one):
 *     flags u8   bit0 FD, bit1 29-bit id, bit2 remote, bit3/bit4 pick the id:
 *                bit3: u8 -> function code (mod 14) of node 5 (with bit4: node 0 for ESTOP, else node 6)
 *                bit4 alone: the board's ISO-TP receive id; neither: u16 raw id (u32 when 29-bit)
 *     len u8     data length (clipped to 8 classic / 64 FD, FD rounded up to a valid FD length)
 *     data
 * plus one record of its own, so fuzzed messages get past the CRCs to the board core: flags bit5 -> type u8,
 * len u8, a serial payload; a message the payload codec accepts is sent as the host would (its fixed frames, or an
 * ISO-TP unit through a C ISO-TP link as the host's end, which also answers the board's First Frames).
 * Frames reach the board in chunks; between chunks the board ticks while it may (at most 800 ticks per input) and
 * handles messages when it cannot, as the lockstep loop. Invariants (abort, plus ASan/UBSan): commands inside each
 * servo's range, goals inside the step range, ESTOP holds, every bounded queue within its size, at most
 * GS_CAN_MAX_ASSEMBLIES assemblies per function code, every frame the board hands to the bus a standard frame of
 * node 5 in the board->host direction with a valid length. */
#include <stdlib.h>
#include <string.h>

#include "fuzz_hal.h"
#include "gs_app_can.h"
#include "gs_can_hal.h"
#include "gs_hal.h"

#define NODE 5u
#define MAX_PENDING 256u

static gs_app_can_t app;
static gs_can_frame_t pending[MAX_PENDING]; /* frames "on the bus" for the board, not yet read */
static unsigned pending_head, pending_n;
static unsigned refuse_every, refused_run;
static gs_isotp_t host_tp; /* the host's ISO-TP sender for bulk messages */

#define CHECK(c) do { if (!(c)) abort(); } while (0)

static const uint8_t FD_UP[65] = {0,  1,  2,  3,  4,  5,  6,  7,  8,  12, 12, 12, 12, 16, 16, 16, 16, 20, 20, 20, 20, 24,
                                  24, 24, 24, 32, 32, 32, 32, 32, 32, 32, 32, 48, 48, 48, 48, 48, 48, 48, 48, 48, 48, 48,
                                  48, 48, 48, 48, 48, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64, 64};

static void push(const gs_can_frame_t *f) {
    if (pending_n >= MAX_PENDING) return; /* a full socket queue drops (as SocketCAN's receive queue) */
    pending[(pending_head + pending_n) % MAX_PENDING] = *f;
    pending_n++;
}

int hal_can_recv(gs_can_frame_t *f) {
    if (!pending_n) return 0;
    *f = pending[pending_head];
    pending_head = (pending_head + 1u) % MAX_PENDING;
    pending_n--;
    return 1;
}

static int valid_length(const gs_can_frame_t *f) {
    if (!(f->flags & GS_CAN_FLAG_FD)) return f->len <= 8u;
    return f->len <= 64u && FD_UP[f->len] == f->len;
}

int hal_can_send(const gs_can_frame_t *f) {
    unsigned fn = f->id >> 7;
    CHECK(!(f->flags & (GS_CAN_FLAG_EXT | GS_CAN_FLAG_RTR)) && f->id <= 0x7FFu && (f->id & 0x7Fu) == NODE);
    CHECK(fn == GS_CAN_FN_TIME_SYNC_REPLY || fn == GS_CAN_FN_ACK || fn == GS_CAN_FN_NACK || fn == GS_CAN_FN_TELEMETRY ||
          fn == GS_CAN_FN_HEARTBEAT_BOARD || fn == GS_CAN_FN_BULK_TO_HOST);
    CHECK(valid_length(f));
    if (refuse_every && refused_run < refuse_every) {
        refused_run++;
        return 0;
    }
    refused_run = 0;
    /* the host's ISO-TP end hears the board's bulk frames: it answers a First Frame with its flow control and
     * takes the board's flow control for its own units */
    if (fn == GS_CAN_FN_BULK_TO_HOST) gs_isotp_feed(&host_tp, f, (uint32_t)hal_now_us());
    return 1;
}

void hal_can_wait(uint64_t until_us, int want_write) {
    (void)until_us;
    (void)want_write;
}

static void host_emit(void *ctx, const gs_can_frame_t *f) {
    (void)ctx;
    push(f);
}

static void invariants(void) {
    const gs_board_t *b = &app.board;
    const gs_can_link_t *l = &app.link;
    CHECK(b->buf.n <= GS_BUFFER_DEPTH);
    CHECK(l->items_n <= GS_CAN_ITEMS && l->txq_n <= GS_CAN_TXQ);
    CHECK(l->isotp.inbox_len <= GS_ISOTP_INBOX && l->isotp.txq_n <= GS_ISOTP_TXQ);
    CHECK(l->isotp.active_pos <= l->isotp.active_len);
    for (unsigned i = 0; i < GS_CAN_RX_FNS; i++) CHECK(l->dec.fns[i].nasm <= GS_CAN_MAX_ASSEMBLIES);
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        CHECK(b->cmd[i] >= gs_servos[i].min_urad && b->cmd[i] <= gs_servos[i].max_urad);
        CHECK(b->goal[i] >= gs_servos[i].step_lo && b->goal[i] <= gs_servos[i].step_hi);
        if (b->mode == GS_MODE_ESTOP) CHECK(b->desired[i] == b->hold_q[i]);
    }
}

static void run(unsigned *ticks) {
    gs_can_item_t item;
    for (unsigned guard = 0; guard < 100000u; guard++) {
        if (gs_board_can_tick(&app.board) && *ticks < 800u) {
            gs_app_can_tick(&app);
            (*ticks)++;
        } else {
            gs_app_can_pump(&app);
            if (!gs_can_link_next(&app.link, &item)) {
                gs_app_can_flush(&app);
                gs_isotp_poll(&host_tp, (uint32_t)hal_now_us());
                if (!pending_n || !gs_can_link_can_take(&app.link)) return;
                continue;
            }
            gs_app_can_process(&app, &item);
        }
        gs_app_can_flush(&app);
        gs_isotp_poll(&host_tp, (uint32_t)hal_now_us());
        invariants();
    }
}

/* One record at data[*i]; 0 at the end of the input. */
static int record(const uint8_t *data, size_t n, size_t *i, int fd_link, uint16_t *seq) {
    if (*i >= n) return 0;
    uint8_t flags = data[(*i)++];
    gs_can_frame_t f;
    memset(&f, 0, sizeof f);
    if (flags & 32u) { /* a message, sent as the host would */
        if (*i + 2u > n) return 0;
        uint8_t type = data[*i], len = data[*i + 1u];
        *i += 2u;
        if (len > n - *i) len = (uint8_t)(n - *i);
        gs_msg_t m;
        const char *why = "";
        int ok = gs_decode_payload(type, data + *i, len, &m, &why) == GS_OK;
        *i += len;
        if (!ok) return 1;
        (*seq)++;
        gs_can_frame_t frames[GS_CAN_MAX_PARTS];
        if (gs_can_is_fixed(&m, fd_link)) {
            int k = gs_can_encode_fixed(&m, *seq, NODE, fd_link, GS_CAN_SENDER_HOST, frames, GS_CAN_MAX_PARTS, &why);
            for (int j = 0; j < k; j++) push(&frames[j]);
        } else {
            uint8_t unit[GS_CAN_BULK_MAX];
            int k = gs_can_encode_bulk(&m, *seq, unit, sizeof unit);
            if (k > 0) (void)gs_isotp_send(&host_tp, unit, (size_t)k);
            gs_isotp_poll(&host_tp, (uint32_t)hal_now_us());
        }
        return 1;
    }
    int fd = flags & 1u, ext = (flags >> 1) & 1u, rtr = (flags >> 2) & 1u;
    if (flags & 8u) {
        if (*i >= n) return 0;
        unsigned fn = data[(*i)++] % 14u;
        unsigned node = (flags & 16u) ? (fn == GS_CAN_FN_ESTOP ? 0u : 6u) : NODE;
        f.id = node ? GS_CAN_ID(fn, node) : 0u;
    } else if (flags & 16u) {
        f.id = GS_CAN_ID(GS_CAN_FN_BULK_TO_BOARD, NODE);
    } else {
        size_t size = ext ? 4u : 2u;
        if (*i + size > n) return 0;
        uint32_t v = 0;
        for (size_t k = 0; k < size; k++) v |= (uint32_t)data[*i + k] << (8u * k);
        f.id = v & (ext ? 0x1FFFFFFFu : 0x7FFu);
        *i += size;
    }
    if (*i >= n) return 0;
    unsigned len = data[(*i)++];
    if (len > (fd ? 64u : 8u)) len = fd ? 64u : 8u;
    if (fd) len = FD_UP[len];
    for (unsigned k = 0; k < len; k++) f.data[k] = *i + k < n ? data[*i + k] : 0u;
    *i += len;
    f.len = (uint8_t)len;
    f.flags = (uint8_t)((fd ? GS_CAN_FLAG_FD : 0u) | (ext ? GS_CAN_FLAG_EXT : 0u) | (rtr ? GS_CAN_FLAG_RTR : 0u));
    /* the port's filter: this node's standard identifiers and the broadcast ESTOP */
    if (!ext && ((f.id & 0x7Fu) == NODE || f.id == 0u)) push(&f);
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    if (size < 1) return 0;
    int fd_link = data[0] & 1u;
    refuse_every = (data[0] >> 1) & 7u;
    refused_run = 0;
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    cfg.lockstep = 1;
    cfg.boot_checks = 0; /* the emulated bus: a fault mid-run, never a refused start */
    fuzz_hal_reset();
    fuzz_in = data;
    fuzz_in_len = fuzz_in_pos = 0;
    pending_head = pending_n = 0;
    (void)gs_app_can_init(&app, &cfg, NODE, fd_link);
    gs_isotp_init(&host_tp, GS_CAN_ID(GS_CAN_FN_BULK_TO_HOST, NODE), GS_CAN_ID(GS_CAN_FN_BULK_TO_BOARD, NODE), fd_link,
                  host_emit, NULL, NULL);
    unsigned ticks = 0;
    uint16_t seq = 0;
    size_t i = 1;
    uint32_t chunk = 0;
    while (record(data, size, &i, fd_link, &seq)) {
        if (++chunk % 4u == 0) run(&ticks); /* frames reach the board in chunks */
    }
    run(&ticks);
    invariants();
    return 0;
}
