/* The servo bus's shared part: received bytes, late replies, statistics, the transactions, and the
 * protocol-neutral requests dispatched to gs_bus_sts.c or gs_bus_dxl2.c (gs_bus.h). */
#include "gs_bus.h"

#include "gs_hal.h"

gs_bus_stats_t gs_bus_stats;
uint32_t gs_bus_answers;
uint32_t gs_bus_rx_bytes;

static gs_bus_protocol_t proto = GS_BUS_STS;
static const gs_bus_codec_t *codec = &gs_bus_sts_codec;
static uint32_t line_baud;
/* received bytes not yet parsed (a status packet may arrive in pieces) */
static uint8_t rx[2u * GS_BUS_MAX_PACKET];
static size_t rx_len;
/* ids heard late (a bit per id 0..255) since gs_bus_heard_late() last asked */
static uint8_t heard_late[32];

void gs_bus_init(gs_bus_protocol_t protocol, uint32_t baud) {
    proto = protocol == GS_BUS_DXL2 ? GS_BUS_DXL2 : GS_BUS_STS;
    codec = proto == GS_BUS_DXL2 ? &gs_bus_dxl2_codec : &gs_bus_sts_codec;
    line_baud = baud;
    rx_len = 0;
    for (unsigned i = 0; i < sizeof heard_late; i++) heard_late[i] = 0;
}

gs_bus_protocol_t gs_bus_protocol(void) { return proto; }

const char *gs_bus_protocol_name(gs_bus_protocol_t p) { return p == GS_BUS_DXL2 ? "dxl2" : "sts"; }

int gs_bus_heard_late(uint8_t id) {
    int heard = heard_late[id >> 3] >> (id & 7u) & 1u;
    heard_late[id >> 3] &= (uint8_t)~(1u << (id & 7u));
    return heard;
}

static void note_late(int id) {
    gs_bus_stats.late_replies++;
    heard_late[(unsigned)id >> 3 & 31u] |= (uint8_t)(1u << ((unsigned)id & 7u));
}

static int parse_status(gs_status_t *st) {
    if (!codec->parse(rx, &rx_len, st)) return -1;
    return st->id;
}

/* Before a request: whatever is waiting on the bus answered an earlier request after its deadline. Each
 * whole status packet in it is a late reply (counted, its id remembered), so a late answer is never taken
 * for the new request's. A packet still arriving (its header and part of it here: a slow emulated UART
 * delivers byte by byte) stays in rx[]: when it completes, the wait for the new request's answer finds an
 * id or length it did not ask for and counts it late too. Bounded: at most 64 buffers per call, and the
 * plant sends nothing unasked. */
static void collect_late(void) {
    for (unsigned round = 0; round < 64u; round++) {
        if (rx_len >= sizeof rx) rx_len = 0;
        size_t got = hal_bus_read(&rx[rx_len], sizeof rx - rx_len, 0);
        rx_len += got;
        gs_bus_rx_bytes += (uint32_t)got;
        for (;;) {
            gs_status_t st;
            int id = parse_status(&st);
            if (id < 0) break;
            note_late(id);
        }
        if (!got) break;
    }
}

void gs_bus_send(uint8_t id, uint8_t inst, const uint8_t *params, size_t n) {
    uint8_t pkt[GS_BUS_MAX_PACKET];
    size_t len = codec->encode(pkt, sizeof pkt, id, inst, params, n);
    if (!len) return;
    collect_late(); /* a late answer to an earlier request must not be taken for this one's */
    if (!codec->starts_header(rx, rx_len)) rx_len = 0; /* keep only a packet still arriving */
    hal_bus_write(pkt, len);
    gs_bus_stats.packets_out++;
    gs_bus_stats.bytes_out += len;
}

uint64_t gs_bus_deadline(uint32_t timeout_us, size_t reply_bytes) {
    uint64_t wire = line_baud ? (uint64_t)reply_bytes * 10000000u / line_baud : 0u;
    return hal_now_us() + timeout_us + wire;
}

#define GS_BUS_TIMEOUT (-1)
#define GS_BUS_STOPPING (-2)

/* Wait for the next status packet until `deadline`; its id, GS_BUS_TIMEOUT, or GS_BUS_STOPPING
 * when the port was asked to stop: a stopping board does not wait out its bus timeouts (1 s each
 * in lockstep) for a plant that may already be gone, and a stop is not counted as a timeout.
 * Past the deadline the bus is still read once without waiting: a board process that was itself
 * descheduled past its deadline finds the answer that came meanwhile instead of calling it a miss. */
static int next_status(uint64_t deadline, gs_status_t *st) {
    for (;;) {
        int id = parse_status(st);
        if (id >= 0) return id;
        if (hal_should_stop()) return GS_BUS_STOPPING;
        uint64_t now = hal_now_us();
        if (rx_len >= sizeof rx) rx_len = 0; /* cannot happen with sane packets; never overflow */
        size_t got = hal_bus_read(&rx[rx_len], sizeof rx - rx_len, now >= deadline ? 0u : (uint32_t)(deadline - now));
        rx_len += got;
        gs_bus_rx_bytes += (uint32_t)got;
        if (!got && now >= deadline) return GS_BUS_TIMEOUT;
    }
}

int gs_bus_await(uint8_t id, int len, uint64_t deadline, gs_status_t *st) {
    for (;;) {
        int got = next_status(deadline, st);
        if (got < 0) {
            if (got == GS_BUS_TIMEOUT) gs_bus_stats.timeouts++;
            return 0;
        }
        if (got == id && (len < 0 || st->n == (size_t)len)) return 1;
        note_late(got); /* an earlier request's answer, completed only now */
    }
}

uint32_t gs_bus_collect(const uint8_t *ids, size_t n, size_t len, uint64_t deadline,
                        void (*on_status)(size_t k, const gs_status_t *st, void *ctx), void *ctx) {
    uint32_t got = 0, want = n >= 32u ? 0xFFFFFFFFu : ((1u << n) - 1u);
    while (got != want) {
        gs_status_t st;
        int id = next_status(deadline, &st);
        if (id < 0) {
            if (id == GS_BUS_TIMEOUT) gs_bus_stats.timeouts++;
            break;
        }
        int ours = 0;
        for (size_t i = 0; i < n && i < 32u; i++) {
            if (ids[i] == (uint8_t)id && st.n == len) {
                on_status(i, &st, ctx);
                got |= 1u << i;
                ours = 1;
            }
        }
        if (!ours) note_late(id); /* an earlier request's answer, completed only now */
    }
    return got;
}

size_t gs_bus_listen(uint32_t wait_us) {
    uint64_t deadline = hal_now_us() + wait_us;
    size_t total = rx_len;
    rx_len = 0;
    while (!hal_should_stop()) {
        uint8_t junk[64];
        uint64_t now = hal_now_us();
        size_t got = hal_bus_read(junk, sizeof junk, now >= deadline ? 0u : (uint32_t)(deadline - now));
        gs_bus_rx_bytes += (uint32_t)got;
        total += got;
        if (!got && hal_now_us() >= deadline) break;
    }
    return total;
}

uint32_t gs_bus_wire_us(size_t bytes) { return line_baud ? (uint32_t)((uint64_t)bytes * 10000000u / line_baud) : 0u; }

/* --- the neutral requests ------------------------------------------------------------------------ */

int gs_bus_ping(uint8_t id, uint32_t timeout_us, uint16_t *model) {
    return proto == GS_BUS_DXL2 ? gs_dxl2_ping(id, timeout_us, model) : gs_sts_ping(id, timeout_us, model);
}

void gs_bus_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps) {
    if (proto == GS_BUS_DXL2) gs_dxl2_write_goals(ids, n, steps);
    else gs_sts_write_goals(ids, n, steps);
}

void gs_bus_torque(const uint8_t *ids, size_t n, int on) {
    if (proto == GS_BUS_DXL2) gs_dxl2_torque(ids, n, on);
    else gs_sts_torque(ids, n, on);
}

void gs_bus_torque_off_all(void) {
    if (proto == GS_BUS_DXL2) gs_dxl2_torque_off_all();
    else gs_sts_torque_off_all();
}

uint32_t gs_bus_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us) {
    return proto == GS_BUS_DXL2 ? gs_dxl2_read_present(ids, n, out, timeout_us)
                                : gs_sts_read_present(ids, n, out, timeout_us);
}

int gs_bus_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us) {
    return proto == GS_BUS_DXL2 ? gs_dxl2_read_errors(id, errors, timeout_us) : gs_sts_read_errors(id, errors, timeout_us);
}

int gs_bus_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us) {
    return proto == GS_BUS_DXL2 ? gs_dxl2_read(id, addr, len, data, timeout_us) : gs_sts_read(id, addr, len, data, timeout_us);
}

int gs_bus_write_reg(uint8_t id, uint16_t addr, const uint8_t *data, uint8_t len, uint32_t timeout_us) {
    uint8_t params[4u + 8u];
    size_t k = 0;
    gs_status_t st;
    if (len > 8u) return 0;
    params[k++] = (uint8_t)(addr & 0xFFu);
    if (proto == GS_BUS_DXL2) params[k++] = (uint8_t)(addr >> 8);
    else if (addr > 0xFFu) return 0;
    for (size_t j = 0; j < len; j++) params[k++] = data[j];
    gs_bus_send(id, GS_INST_WRITE, params, k);
    if (!gs_bus_await(id, 0, gs_bus_deadline(timeout_us, proto == GS_BUS_DXL2 ? 11u : 6u), &st)) return 0;
    return proto == GS_BUS_DXL2 ? !(st.error & 0x7Fu) : 1;
}
