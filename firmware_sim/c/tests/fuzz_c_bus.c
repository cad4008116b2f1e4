/* libFuzzer target c-bus: fuzzed servo-bus answers into the C firmware's bus layer and board core, both
 * protocols (Feetech STS, Dynamixel Protocol 2.0).
 *
 * Input: byte 0 chooses the protocol (bit 0: 0 STS, 1 Dynamixel 2.0) and the ESTOP torque (bit 1: limp);
 * bytes 1..16 are the host's script (every 20 ticks one action: a SERVO_FRAME with every target at a value
 * the byte picks anywhere in the wire's range, an ESTOP or an ESTOP_CLEAR); the rest are the bus's ops,
 * one taken per packet the firmware sends:
 *   op % 8 = 0, 1, 2  answer as the devices would (every id the request names, the right length, correct
 *                     checksum/CRC and stuffing) with the error byte and the data taken from the input;
 *   3                 the same, then one byte of the answers flipped (checksum/CRC failures, resync);
 *   4                 raw: the next byte's count of input bytes as the bus's answer (garbage, half packets);
 *   5, 6, 7           silence (timeouts, lost servos).
 * Answers reach the firmware in chunks whose sizes vary. The clock is virtual (every reading advances it
 * 50 us; a wait on a bus with nothing more to come advances it by the wait: timeouts end at once). Lockstep, at most 600 ticks per input.
 *
 * Invariants (abort on failure, plus AddressSanitizer and UBSan): every goal the firmware writes is inside
 * its servo's step range (checked on the wire, in the goal SYNC WRITE as sent), every command inside the
 * servo's joint range, the bus's receive buffer and the jitter buffer within their sizes, torque never goes
 * on for a servo whose present position was never read, and an ESTOP holds (desired = hold pose). */
#include <stdlib.h>
#include <string.h>

#include "gs_app.h"
#include "gs_bus.h"
#include "gs_hal.h"

#define CHECK(c) do { if (!(c)) abort(); } while (0)

static gs_app_t app;
static const uint8_t *ops;
static size_t ops_len, ops_pos;
static uint8_t proto;
static uint64_t vclock;
static uint8_t bus_out[4096];
static size_t bus_out_len, bus_out_pos;
static unsigned chunk_turn;
static uint16_t goals_seen[256];

static uint8_t next_op(void) { return ops_pos < ops_len ? ops[ops_pos++] : 5u; /* out of input: silence */ }

uint64_t hal_now_us(void) { return vclock += 50; }
size_t hal_host_read(uint8_t *buf, size_t cap) {
    (void)buf;
    (void)cap;
    return 0;
}
size_t hal_host_write(const uint8_t *buf, size_t n) {
    (void)buf;
    return n;
}
void hal_wait(uint64_t until_us, int want_write) {
    (void)want_write;
    if (until_us > vclock) vclock = until_us;
}
void hal_log_write(const char *s, size_t n) {
    (void)s;
    (void)n;
}
int hal_should_stop(void) { return 0; }
uint32_t hal_cycles(void) { return 0; }
void hal_bus_drain(void) { bus_out_len = bus_out_pos = 0; }

size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) {
    size_t n = bus_out_len - bus_out_pos;
    if (!n) { /* nothing will come: the wait ends at its timeout, at once */
        vclock += timeout_us;
        return 0;
    }
    size_t chunk = 1u + (chunk_turn++ * 7u) % 40u;
    if (n > chunk) n = chunk;
    if (n > cap) n = cap;
    memcpy(buf, bus_out + bus_out_pos, n);
    bus_out_pos += n;
    if (bus_out_pos == bus_out_len) bus_out_pos = bus_out_len = 0;
    return n;
}

/* One device's status packet with `n` data bytes from the input (and an error byte from it), encoded by the
 * protocol's own framing: an STS status is an instruction-shaped packet whose "instruction" is the error
 * byte; a Dynamixel status is one whose instruction is 0x55 and whose first parameter is the error byte. */
static void answer(uint8_t id, size_t n, const uint8_t *fixed) {
    uint8_t params[GS_BUS_MAX_PARAMS + 1];
    uint8_t err = next_op();
    err = (err & 0xF0u) == 0xF0u ? err : 0u; /* mostly no error; sometimes any */
    size_t k = 0;
    if (proto) params[k++] = err;
    for (size_t i = 0; i < n && k < sizeof params; i++) params[k++] = fixed ? fixed[i] : next_op();
    if (bus_out_len + GS_BUS_MAX_PACKET > sizeof bus_out) return;
    const gs_bus_codec_t *c = proto ? &gs_bus_dxl2_codec : &gs_bus_sts_codec;
    size_t len = c->encode(&bus_out[bus_out_len], sizeof bus_out - bus_out_len, id, proto ? 0x55u : err, params, k);
    bus_out_len += len;
}

/* What the firmware asked (its own packet, parsed here) and the answers the op chooses. */
void hal_bus_write(const uint8_t *buf, size_t n) {
    uint8_t id, inst;
    const uint8_t *p;
    size_t np;
    if (proto) {
        if (n < 10 || buf[0] != 0xFFu || buf[1] != 0xFFu || buf[2] != 0xFDu) abort(); /* the firmware's own packet */
        id = buf[4];
        inst = buf[7];
        p = &buf[8];
        np = n - 10u;
    } else {
        if (n < 6 || buf[0] != 0xFFu || buf[1] != 0xFFu) abort();
        id = buf[2];
        inst = buf[4];
        p = &buf[5];
        np = n - 6u;
    }
    /* the goal SYNC WRITE as sent: each goal inside its servo's step range */
    unsigned goal_addr = proto ? GS_DXL_GOAL_POSITION : GS_REG_GOAL_POSITION;
    if (inst == GS_INST_SYNC_WRITE) {
        size_t hdr = proto ? 4u : 2u, len = proto ? p[2] : p[1];
        unsigned addr = proto ? (unsigned)(p[0] | p[1] << 8) : p[0];
        CHECK(np >= hdr && len >= 1u && (np - hdr) % (1u + len) == 0u);
        if (addr == goal_addr) {
            for (size_t k = hdr; k + len < np + 1u; k += 1u + len) {
                uint8_t sid = p[k];
                uint16_t g = (uint16_t)(p[k + 1] | p[k + 2] << 8);
                CHECK(sid >= 1u && sid <= GS_SERVO_COUNT);
                CHECK(g >= gs_servos[sid - 1].step_lo && g <= gs_servos[sid - 1].step_hi);
                if (proto) CHECK(p[k + 3] == 0u && p[k + 4] == 0u);
                goals_seen[sid] = g;
            }
        }
        return;
    }
    if (id == GS_BUS_BROADCAST && inst != GS_INST_SYNC_READ) return; /* broadcast WRITE: no answer */
    uint8_t op = next_op();
    switch (op % 8u) {
    case 4: {
        size_t k = next_op();
        while (k-- && ops_pos < ops_len && bus_out_len < sizeof bus_out) bus_out[bus_out_len++] = next_op();
        return;
    }
    case 5: case 6: case 7:
        return;
    default:
        break;
    }
    size_t before = bus_out_len;
    if (inst == GS_INST_PING) {
        static const uint8_t dxl_ping[3] = {0xB0u, 0x04u, 0x2Eu}; /* model 1200, firmware 46 */
        answer(id, proto ? 3u : 0u, proto ? dxl_ping : 0);
    } else if (inst == GS_INST_READ) {
        size_t len = proto ? (np >= 4u ? (size_t)(p[2] | p[3] << 8) : 0u) : (np >= 2u ? p[1] : 0u);
        answer(id, len, 0);
    } else if (inst == GS_INST_SYNC_READ) {
        size_t hdr = proto ? 4u : 2u, len = proto ? (size_t)(p[2] | p[3] << 8) : p[1];
        for (size_t k = hdr; k < np; k++) answer(p[k], len, 0);
    }
    if (op % 8u == 3u && bus_out_len > before) {
        size_t at = before + next_op() % (bus_out_len - before);
        bus_out[at] ^= (uint8_t)(1u + next_op() % 255u);
    }
}

static void invariants(void) {
    const gs_board_t *b = &app.board;
    CHECK(b->buf.n <= GS_BUFFER_DEPTH);
    CHECK(bus_out_pos <= bus_out_len && bus_out_len <= sizeof bus_out);
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        CHECK(b->cmd[i] >= gs_servos[i].min_urad && b->cmd[i] <= gs_servos[i].max_urad);
        CHECK(b->goal[i] >= gs_servos[i].step_lo && b->goal[i] <= gs_servos[i].step_hi);
        if (b->mode == GS_MODE_ESTOP) CHECK(b->desired[i] == b->hold_q[i]);
        /* torque is on only for a servo whose present position was read (its command started there) */
        if (!(b->torque_off >> i & 1u) || (b->torque_due >> i & 1u)) CHECK(b->pos_known >> i & 1u);
    }
    CHECK((b->torque_due & b->torque_off) == b->torque_due);
}

static void host(gs_app_t *a, uint8_t action, uint16_t *seq) {
    gs_board_t *b = &a->board;
    gs_msg_t m;
    memset(&m, 0, sizeof m);
    if (action < 200u) {
        m.type = GS_MSG_TYPE_SERVO_FRAME;
        m.u.servo_frame.apply_at_us = (uint32_t)(b->now_us + 10000);
        m.u.servo_frame.mask = (gs_mask_t)((1ull << GS_SERVO_COUNT) - 1u);
        m.u.servo_frame.targets_n = GS_SERVO_COUNT;
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
            int32_t v = ((int32_t)action - 100) * 327 + (int32_t)i * 1000 * ((action & 1u) ? 1 : -1);
            m.u.servo_frame.targets[i] = (int16_t)(v > 32767 ? 32767 : v < -32767 ? -32767 : v);
        }
    } else if (action < 220u) {
        m.type = GS_MSG_TYPE_ESTOP;
    } else if (action < 240u) {
        m.type = GS_MSG_TYPE_ESTOP_CLEAR;
    } else {
        return;
    }
    gs_board_handle(b, &m, (*seq)++, b->now_us);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    if (size < 17) return 0;
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    cfg.lockstep = 1;
    cfg.bus_protocol = (uint8_t)(data[0] & 1u);
    cfg.estop_limp = (uint8_t)(data[0] >> 1 & 1u);
    proto = cfg.bus_protocol;
    const uint8_t *script = &data[1];
    ops = data + 17;
    ops_len = size - 17;
    ops_pos = 0;
    vclock = 0;
    bus_out_len = bus_out_pos = 0;
    chunk_turn = 0;
    memset(goals_seen, 0, sizeof goals_seen);
    cfg.boot_checks = 0; /* fuzzed answers: found as faults mid-run, never a refused start */
    (void)gs_app_init(&app, &cfg);
    invariants();
    uint16_t seq = 0;
    gs_msg_t adv;
    memset(&adv, 0, sizeof adv);
    adv.type = GS_MSG_TYPE_ADVANCE;
    adv.u.advance.until_us = 600u * 2000u;
    gs_board_handle(&app.board, &adv, seq++, 0);
    for (unsigned t = 0; t < 600u && gs_board_can_tick(&app.board); t++) {
        if (t % 20u == 0u) host(&app, script[(t / 20u) % 16u], &seq);
        gs_app_tick(&app);
        invariants();
        if (ops_pos >= ops_len && t > 40u) break; /* the bus has nothing more to say: only silence follows */
    }
    return 0;
}
