#include "gs_bus.h"

#include "gs_hal.h"

gs_bus_stats_t gs_bus_stats;
uint32_t gs_bus_answers;

/* received bytes not yet parsed (a status packet may arrive in pieces) */
static uint8_t rx[2u * (GS_BUS_MAX_PARAMS + 6u)];
static size_t rx_len;
/* ids heard late (a bit per id 0..255) since gs_bus_heard_late() last asked */
static uint8_t heard_late[32];

static int parse_status(uint8_t *params, size_t cap, size_t *n_params);

int gs_bus_heard_late(uint8_t id) {
    int heard = heard_late[id >> 3] >> (id & 7u) & 1u;
    heard_late[id >> 3] &= (uint8_t)~(1u << (id & 7u));
    return heard;
}

static void note_late(int id) {
    gs_bus_stats.late_replies++;
    heard_late[(unsigned)id >> 3] |= (uint8_t)(1u << ((unsigned)id & 7u));
}

/* Before a request: whatever is waiting on the bus answered an earlier request after its deadline. Each
 * whole status packet in it is a late reply (counted, its id remembered), so a late answer is never taken
 * for the new request's. A packet still arriving (its header and part of it here: a slow emulated UART
 * delivers byte by byte) stays in rx[]: when it completes, the wait for the new request's answer finds an
 * id or length it did not ask for and counts it late too (gs_bus_sync_read, gs_bus_read, gs_bus_ping). Bounded: at most 64 buffers
 * per call, and the plant sends nothing unasked. */
static void collect_late(void) {
    for (unsigned round = 0; round < 64u; round++) {
        if (rx_len >= sizeof rx) rx_len = 0;
        size_t got = hal_bus_read(&rx[rx_len], sizeof rx - rx_len, 0);
        rx_len += got;
        for (;;) {
            uint8_t p[GS_BUS_MAX_PARAMS];
            size_t np = 0;
            int id = parse_status(p, sizeof p, &np);
            if (id < 0) break;
            note_late(id);
        }
        if (!got) break;
    }
}

static void send_packet(uint8_t id, uint8_t inst, const uint8_t *params, size_t n) {
    uint8_t pkt[GS_BUS_MAX_PARAMS + 6u];
    if (n > GS_BUS_MAX_PARAMS) return;
    pkt[0] = 0xFFu;
    pkt[1] = 0xFFu;
    pkt[2] = id;
    pkt[3] = (uint8_t)(n + 2u);
    pkt[4] = inst;
    unsigned sum = (unsigned)id + pkt[3] + inst;
    for (size_t i = 0; i < n; i++) {
        pkt[5 + i] = params[i];
        sum += params[i];
    }
    pkt[5 + n] = (uint8_t)(~sum & 0xFFu);
    collect_late(); /* a late answer to an earlier request must not be taken for this one's */
    if (rx_len < 2u || rx[0] != 0xFFu || rx[1] != 0xFFu) rx_len = 0; /* keep only a packet still arriving */
    hal_bus_write(pkt, n + 6u);
    gs_bus_stats.packets_out++;
    gs_bus_stats.bytes_out += n + 6u;
}

/* Parse one status packet from rx[]; returns its id (and copies its params), -1 when incomplete. */
static int parse_status(uint8_t *params, size_t cap, size_t *n_params) {
    for (;;) {
        size_t s = 0;
        while (s + 1 < rx_len && !(rx[s] == 0xFFu && rx[s + 1] == 0xFFu)) s++;
        if (s) { /* garbage before a header */
            for (size_t i = s; i < rx_len; i++) rx[i - s] = rx[i];
            rx_len -= s;
        }
        if (rx_len < 4) return -1;
        uint8_t len = rx[3];
        if (rx[2] > 0xFDu || len < 2u || len > GS_BUS_MAX_PARAMS + 2u) { /* not a status header: resync */
            gs_bus_stats.bad_packets++;
            for (size_t i = 1; i < rx_len; i++) rx[i - 1] = rx[i];
            rx_len--;
            continue;
        }
        size_t total = (size_t)len + 4u;
        if (rx_len < total) return -1;
        unsigned sum = 0;
        for (size_t i = 2; i < total - 1; i++) sum += rx[i];
        int id = rx[2];
        int ok = (uint8_t)(~sum & 0xFFu) == rx[total - 1];
        size_t np = (size_t)len - 2u;
        if (ok) {
            if (np > cap) np = cap;
            for (size_t i = 0; i < np; i++) params[i] = rx[5 + i];
            *n_params = np;
        }
        for (size_t i = total; i < rx_len; i++) rx[i - total] = rx[i];
        rx_len -= total;
        if (ok) {
            gs_bus_stats.packets_in++;
            gs_bus_stats.bytes_in += total;
            gs_bus_answers++;
            return id;
        }
        gs_bus_stats.bad_packets++;
    }
}

#define GS_BUS_TIMEOUT (-1)
#define GS_BUS_STOPPING (-2)

/* Wait for the next status packet until `deadline`; its id, GS_BUS_TIMEOUT, or GS_BUS_STOPPING
 * when the port was asked to stop: a stopping board does not wait out its bus timeouts (1 s each
 * in lockstep) for a plant that may already be gone, and a stop is not counted as a timeout.
 * Past the deadline the bus is still read once without waiting: a board process that was itself
 * descheduled past its deadline finds the answer that came meanwhile instead of calling it a miss. */
static int next_status(uint64_t deadline, uint8_t *params, size_t cap, size_t *n_params) {
    for (;;) {
        int id = parse_status(params, cap, n_params);
        if (id >= 0) return id;
        if (hal_should_stop()) return GS_BUS_STOPPING;
        uint64_t now = hal_now_us();
        if (rx_len >= sizeof rx) rx_len = 0; /* cannot happen with sane packets; never overflow */
        size_t got = hal_bus_read(&rx[rx_len], sizeof rx - rx_len, now >= deadline ? 0u : (uint32_t)(deadline - now));
        rx_len += got;
        if (!got && now >= deadline) return GS_BUS_TIMEOUT;
    }
}

void gs_bus_sync_write(uint8_t addr, uint8_t len, const uint8_t *ids, size_t n, const uint8_t *data) {
    uint8_t params[GS_BUS_MAX_PARAMS];
    size_t k = 0;
    if (2u + n * (1u + len) > GS_BUS_MAX_PARAMS) return;
    params[k++] = addr;
    params[k++] = len;
    for (size_t i = 0; i < n; i++) {
        params[k++] = ids[i];
        for (size_t j = 0; j < len; j++) params[k++] = data[i * len + j];
    }
    send_packet(GS_BUS_BROADCAST, GS_INST_SYNC_WRITE, params, k);
}

uint32_t gs_bus_sync_read(uint8_t addr, uint8_t len, const uint8_t *ids, size_t n, uint8_t *data, uint32_t timeout_us) {
    uint8_t params[GS_BUS_MAX_PARAMS];
    uint32_t got = 0, want = n >= 32u ? 0xFFFFFFFFu : ((1u << n) - 1u);
    if (2u + n > GS_BUS_MAX_PARAMS || len > GS_BUS_MAX_PARAMS) return 0;
    params[0] = addr;
    params[1] = len;
    for (size_t i = 0; i < n; i++) params[2 + i] = ids[i];
    send_packet(GS_BUS_BROADCAST, GS_INST_SYNC_READ, params, 2u + n);
    uint64_t deadline = hal_now_us() + timeout_us;
    while (got != want) {
        uint8_t p[GS_BUS_MAX_PARAMS];
        size_t np = 0;
        int id = next_status(deadline, p, sizeof p, &np);
        if (id < 0) {
            if (id == GS_BUS_TIMEOUT) gs_bus_stats.timeouts++;
            break;
        }
        int ours = 0;
        for (size_t i = 0; i < n; i++) {
            if (ids[i] == (uint8_t)id && np == len) {
                for (size_t j = 0; j < len; j++) data[i * len + j] = p[j];
                got |= 1u << i;
                ours = 1;
            }
        }
        if (!ours) note_late(id); /* an earlier request's answer, completed only now */
    }
    return got;
}

int gs_bus_read(uint8_t id, uint8_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us) {
    uint8_t params[2] = {addr, len};
    send_packet(id, GS_INST_READ, params, 2);
    uint64_t deadline = hal_now_us() + timeout_us;
    for (;;) {
        uint8_t p[GS_BUS_MAX_PARAMS];
        size_t np = 0;
        int got = next_status(deadline, p, sizeof p, &np);
        if (got < 0) {
            if (got == GS_BUS_TIMEOUT) gs_bus_stats.timeouts++;
            return 0;
        }
        if (got == id && np == len) {
            for (size_t j = 0; j < len; j++) data[j] = p[j];
            return 1;
        }
        note_late(got);
    }
}

int gs_bus_ping(uint8_t id, uint32_t timeout_us) {
    send_packet(id, GS_INST_PING, 0, 0);
    uint64_t deadline = hal_now_us() + timeout_us;
    for (;;) {
        uint8_t p[4];
        size_t np = 0;
        int got = next_status(deadline, p, sizeof p, &np);
        if (got < 0) {
            if (got == GS_BUS_TIMEOUT) gs_bus_stats.timeouts++;
            return 0;
        }
        if (got == id) return 1;
        note_late(got);
    }
}
