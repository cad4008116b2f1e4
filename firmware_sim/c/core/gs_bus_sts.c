/* The Feetech SCS/STS packet protocol (STS byte order: little-endian words), master side.
 *
 * Instruction packet: 0xFF 0xFF ID LENGTH INSTRUCTION PARAM... CHECKSUM, LENGTH = params + 2,
 * CHECKSUM = ~(ID + LENGTH + INSTRUCTION + params) & 0xFF. Status packet: 0xFF 0xFF ID LENGTH
 * ERROR PARAM... CHECKSUM. SYNC WRITE (0x83) to the broadcast id 0xFE has no reply; SYNC READ
 * (0x82) is answered by each listed servo in turn. Written by hand: the vendor SDK
 * (feetech-servo-sdk) is Python for a host computer; tests drive the emulated servos with it.
 * The status packet's error byte: 0x01 voltage, 0x02 angle limit, 0x04 overheat, 0x08 overcurrent,
 * 0x20 overload (scservo_sdk ERRBIT_*). */
#include "gs_bus.h"

/* the longest STS instruction: the goal SYNC WRITE (2 + 3 N), at least a status packet's 64 */
#define STS_GOAL_SYNC_PARAMS (2u + 3u * GS_SERVO_COUNT)
#define STS_MAX_PARAMS (STS_GOAL_SYNC_PARAMS > 64u ? STS_GOAL_SYNC_PARAMS : 64u)

static size_t sts_encode(uint8_t *pkt, size_t cap, uint8_t id, uint8_t inst, const uint8_t *params, size_t n) {
    if (n > STS_MAX_PARAMS || n + 6u > cap) return 0;
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
    return n + 6u;
}

static int sts_starts_header(const uint8_t *rx, size_t n) { return n >= 2u && rx[0] == 0xFFu && rx[1] == 0xFFu; }

/* Parse one status packet from rx[]; 1 with `st` filled, 0 when incomplete. */
static int sts_parse(uint8_t *rx, size_t *rx_len_p, gs_status_t *st) {
    size_t rx_len = *rx_len_p;
    int found = 0;
    for (;;) {
        size_t s = 0;
        while (s + 1 < rx_len && !(rx[s] == 0xFFu && rx[s + 1] == 0xFFu)) s++;
        if (s) { /* garbage before a header */
            for (size_t i = s; i < rx_len; i++) rx[i - s] = rx[i];
            rx_len -= s;
        }
        if (rx_len < 4) break;
        uint8_t len = rx[3];
        if (rx[2] > 0xFDu || len < 2u || len > STS_MAX_PARAMS + 2u) { /* not a status header: resync */
            gs_bus_stats.bad_packets++;
            for (size_t i = 1; i < rx_len; i++) rx[i - 1] = rx[i];
            rx_len--;
            continue;
        }
        size_t total = (size_t)len + 4u;
        if (rx_len < total) break;
        unsigned sum = 0;
        for (size_t i = 2; i < total - 1; i++) sum += rx[i];
        int ok = (uint8_t)(~sum & 0xFFu) == rx[total - 1];
        if (ok) {
            size_t np = (size_t)len - 2u;
            if (np > sizeof st->params) np = sizeof st->params;
            st->id = rx[2];
            st->error = rx[4];
            for (size_t i = 0; i < np; i++) st->params[i] = rx[5 + i];
            st->n = np;
        }
        for (size_t i = total; i < rx_len; i++) rx[i - total] = rx[i];
        rx_len -= total;
        if (ok) {
            gs_bus_stats.packets_in++;
            gs_bus_stats.bytes_in += total;
            gs_bus_answers++;
            found = 1;
            break;
        }
        gs_bus_stats.bad_packets++;
    }
    *rx_len_p = rx_len;
    return found;
}

const gs_bus_codec_t gs_bus_sts_codec = {sts_encode, sts_parse, sts_starts_header};

static uint8_t sts_errors(uint8_t raw) { /* STS status error byte -> GS_SERVO_ERR_* */
    return (uint8_t)((raw & (GS_SERVO_ERR_VOLTAGE | GS_SERVO_ERR_OVERHEAT | GS_SERVO_ERR_OVERLOAD)) |
                     (raw & 0x08u ? GS_SERVO_ERR_OVERCURRENT : 0u));
}

static int32_t sign_mag(uint16_t raw, unsigned bit) { /* Feetech sign-magnitude register */
    int32_t mag = (int32_t)(raw & ((1u << bit) - 1u));
    return (raw >> bit & 1u) ? -mag : mag;
}

/* SYNC WRITE `len` bytes at `addr` to each of `n` ids (`data`: n * len bytes, id order). */
static void sync_write(uint8_t addr, uint8_t len, const uint8_t *ids, size_t n, const uint8_t *data) {
    uint8_t params[STS_MAX_PARAMS];
    size_t k = 0;
    if (2u + n * (1u + len) > STS_MAX_PARAMS) return;
    params[k++] = addr;
    params[k++] = len;
    for (size_t i = 0; i < n; i++) {
        params[k++] = ids[i];
        for (size_t j = 0; j < len; j++) params[k++] = data[i * len + j];
    }
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_SYNC_WRITE, params, k);
}

void gs_sts_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps) {
    uint8_t data[2u * GS_SERVO_COUNT];
    if (n > GS_SERVO_COUNT) return;
    for (size_t i = 0; i < n; i++) {
        data[2 * i] = (uint8_t)(steps[i] & 0xFFu);
        data[2 * i + 1] = (uint8_t)(steps[i] >> 8);
    }
    sync_write(GS_REG_GOAL_POSITION, 2, ids, n, data);
}

void gs_sts_torque(const uint8_t *ids, size_t n, int on) {
    uint8_t data[GS_SERVO_COUNT];
    if (n > GS_SERVO_COUNT) return;
    for (size_t i = 0; i < n; i++) data[i] = on ? 1u : 0u;
    sync_write(GS_REG_TORQUE_ENABLE, 1, ids, n, data);
}

void gs_sts_torque_off_all(void) {
    uint8_t params[2] = {GS_REG_TORQUE_ENABLE, 0};
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_WRITE, params, 2);
}

typedef struct {
    gs_present_t *out;
} present_ctx_t;

static void on_present(size_t k, const gs_status_t *st, void *ctx) {
    gs_present_t *p = &((present_ctx_t *)ctx)->out[k];
    const uint8_t *d = st->params;
    p->pos = sign_mag((uint16_t)(d[0] | d[1] << 8), 15);
    p->speed = sign_mag((uint16_t)(d[2] | d[3] << 8), 15);
    p->load = sign_mag((uint16_t)(d[4] | d[5] << 8), 10);
    p->error = sts_errors(st->error);
    p->valid = 1;
}

uint32_t gs_sts_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us) {
    uint8_t params[STS_MAX_PARAMS];
    if (2u + n > STS_MAX_PARAMS) return 0;
    params[0] = GS_REG_PRESENT;
    params[1] = GS_PRESENT_LEN;
    for (size_t i = 0; i < n; i++) params[2 + i] = ids[i];
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_SYNC_READ, params, 2u + n);
    present_ctx_t ctx = {out};
    return gs_bus_collect(ids, n, GS_PRESENT_LEN, gs_bus_deadline(timeout_us, n * (6u + GS_PRESENT_LEN)), on_present, &ctx);
}

int gs_sts_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us) {
    uint8_t params[2] = {(uint8_t)addr, len};
    gs_status_t st;
    if (addr > 0xFFu) return 0;
    gs_bus_send(id, GS_INST_READ, params, 2);
    if (!gs_bus_await(id, len, gs_bus_deadline(timeout_us, 6u + len), &st)) return 0;
    for (size_t j = 0; j < len; j++) data[j] = st.params[j];
    return 1;
}

static int ping(uint8_t id, uint32_t timeout_us, uint8_t *error) {
    gs_status_t st;
    gs_bus_send(id, GS_INST_PING, 0, 0);
    if (!gs_bus_await(id, -1, gs_bus_deadline(timeout_us, 6u), &st)) return 0;
    *error = st.error;
    return 1;
}

int gs_sts_ping(uint8_t id, uint32_t timeout_us, uint16_t *model) {
    uint8_t error;
    if (model) *model = 0;
    if (!ping(id, timeout_us, &error)) return 0;
    if (model) {
        uint8_t d[2];
        if (gs_sts_read(id, GS_REG_MODEL, 2, d, timeout_us)) *model = (uint16_t)(d[0] | d[1] << 8);
    }
    return 1;
}

int gs_sts_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us) {
    uint8_t error;
    if (!ping(id, timeout_us, &error)) return 0;
    *errors = sts_errors(error);
    return 1;
}
