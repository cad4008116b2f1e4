#include "gs_board.h"

#include "gs_bus.h"
#include "gs_hal.h"
#include "gs_log.h"

#if GS_SERVO_COUNT > GS_MAX_SERVOS
#error "this wire schema carries at most GS_MAX_SERVOS servos"
#endif

#define MISS_LIMIT_LOCKSTEP 3u
#define MISS_LIMIT_REALTIME 5u
/* a bus on which nothing answers for this long (board clock) loses its silent servos even without
 * another device's answer to prove the plant runs: a cut bus or a dead plant, not a descheduled one
 * (2 s was seen as a QEMU board's plant's lag on a machine at load 11 on 2 cores) */
#define GS_BUS_SILENT_LIMIT_US 5000000u
#define BOOT_PING_ROUNDS_REALTIME 5u /* realtime: a servo silent at boot is asked again (a slow plant) */
#define GS_BOOT_WAIT_US 10000000u     /* how long boot waits for a silent bus to answer at all */
#define READ_GROUP 6u /* servos per SYNC READ: one read job fits a 2 ms tick at 1 Mbaud */

static const gs_mask_t ALL = (gs_mask_t)((1ull << GS_SERVO_COUNT) - 1u);

/* --- small helpers ----------------------------------------------------------------------- */

static int64_t div_round(int64_t a, int64_t b) { /* b > 0; halves away from zero */
    return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b);
}

static int32_t clamp32(int64_t v, int64_t lo, int64_t hi) { return (int32_t)(v < lo ? lo : v > hi ? hi : v); }

static int16_t q16_of(int64_t v, int64_t per_count) { /* units -> q16 code, clamped to +-32767 */
    return (int16_t)clamp32(div_round(v, per_count), -32767, 32767);
}

static int32_t steps_to_urad(unsigned i, int32_t steps) {
    const gs_servo_t *s = &gs_servos[i];
    int64_t st = steps < -1048576 ? -1048576 : steps > 1048576 ? 1048576 : steps; /* a sane register value */
    return clamp32(s->neutral_urad + div_round((int64_t)s->direction * (st - GS_STEP_CENTRE - s->offset_steps) * GS_STEP_NRAD, 1000),
                   INT32_MIN / 2, INT32_MAX / 2);
}

static uint16_t urad_to_goal(unsigned i, int32_t q) {
    const gs_servo_t *s = &gs_servos[i];
    int64_t rel = div_round(((int64_t)q - s->neutral_urad) * 1000, GS_STEP_NRAD);
    int64_t steps = GS_STEP_CENTRE + s->offset_steps + s->direction * rel;
    return (uint16_t)clamp32(steps, s->step_lo, s->step_hi);
}

static uint64_t unwrap32(uint32_t wrapped, int64_t ref) { /* protocol.codec.unwrap_time_us */
    int64_t delta = (int64_t)(((uint64_t)wrapped - (uint64_t)ref) & 0xFFFFFFFFu);
    if (delta >= 0x80000000ll) delta -= 0x100000000ll;
    return (uint64_t)(ref + delta);
}

static int64_t clamp_u64(uint64_t v) { return v > (uint64_t)INT64_MAX ? INT64_MAX : (int64_t)v; }

/* --- output -------------------------------------------------------------------------------- */

static void send(gs_board_t *b, const gs_msg_t *m, int periodic) { b->send(b->send_ctx, m, periodic); }

static void set_str(uint8_t *dst, uint8_t *len, size_t cap, const char *s) {
    size_t n = 0;
    while (s[n] && n < cap) {
        dst[n] = (uint8_t)s[n];
        n++;
    }
    *len = (uint8_t)n;
}

static void ack(gs_board_t *b, uint16_t seq, uint8_t type) {
    gs_msg_t m;
    m.type = GS_MSG_TYPE_ACK;
    m.u.ack.ack_seq = seq;
    m.u.ack.msg_type = type;
    send(b, &m, 0);
}

/* NACK with a detail assembled from up to three text parts and one number. */
static void nack(gs_board_t *b, uint16_t seq, uint8_t type, uint8_t reason, const char *a, const char *c) {
    gs_msg_t m;
    m.type = GS_MSG_TYPE_NACK;
    m.u.nack.ack_seq = seq;
    m.u.nack.msg_type = type;
    m.u.nack.reason = reason;
    char text[GS_MAX_NACK_DETAIL_BYTES + 1];
    size_t n = 0;
    for (const char *p = a; p && *p && n < GS_MAX_NACK_DETAIL_BYTES; p++) text[n++] = *p;
    for (const char *p = c; p && *p && n < GS_MAX_NACK_DETAIL_BYTES; p++) text[n++] = *p;
    text[n] = 0;
    set_str(m.u.nack.detail, &m.u.nack.detail_len, GS_MAX_NACK_DETAIL_BYTES, text);
    send(b, &m, 0);
}

static void fmt_u64(char *out, size_t cap, uint64_t v) { /* decimal into a small buffer */
    char tmp[21];
    size_t i = sizeof tmp, k = 0;
    do {
        tmp[--i] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v);
    while (i < sizeof tmp && k + 1 < cap) out[k++] = tmp[i++];
    out[k] = 0;
}

/* --- safety (firmware_sim/safety.py) -------------------------------------------------------- */

static int safety_feed(gs_board_t *b, int64_t t) {
    b->armed = 1;
    if (t > b->last_feed_us) b->last_feed_us = t;
    if (b->hold_since_us != GS_NO_TIME && !b->fault_latched) {
        b->hold_since_us = GS_NO_TIME;
        return 1;
    }
    return 0;
}

static gs_mode_t safety_mode(const gs_board_t *b) {
    if (b->estopped) return GS_MODE_ESTOP;
    if (b->fault_latched) return GS_MODE_CROUCH;
    if (b->servo_fault) return GS_MODE_SERVO_FAULT;
    if (b->hold_since_us != GS_NO_TIME) return GS_MODE_HOLD;
    return GS_MODE_RUN;
}

static gs_mode_t safety_update(gs_board_t *b, int64_t t, int *entered) {
    gs_mode_t before = safety_mode(b);
    if (b->armed && !b->estopped && !b->fault_latched) {
        if (b->hold_since_us == GS_NO_TIME && t - b->last_feed_us > b->watchdog_us) {
            b->hold_since_us = t;
            b->watchdog_trips++;
        }
        if (b->hold_since_us != GS_NO_TIME && t - b->hold_since_us >= b->crouch_after_us) b->fault_latched = 1;
    }
    gs_mode_t after = safety_mode(b);
    *entered = after != before;
    return after;
}

static uint16_t safety_flags(const gs_board_t *b) {
    uint16_t f = 0;
    if (b->estopped) f |= GS_FAULT_FLAGS_ESTOP;
    if (b->hold_since_us != GS_NO_TIME && !b->fault_latched) f |= GS_FAULT_FLAGS_WATCHDOG_HOLD;
    if (b->fault_latched) f |= GS_FAULT_FLAGS_WATCHDOG_FAULT;
    if (b->servo_fault) f |= GS_FAULT_FLAGS_SERVO_FAULT;
    return f;
}

static void log_event(const char *what, int64_t t, int64_t ref) {
    gs_log_str("board: ");
    gs_log_str(what);
    gs_log_str(" at board time ");
    gs_log_secs(t);
    gs_log_str(" s, ");
    gs_log_secs(t - ref);
}

/* --- sequence gaps (protocol.faults.GapDetector) ------------------------------------------ */

static void gaps_reset(gs_board_t *b) {
    b->gap_started = 0;
    b->gap_n = b->gap_head = 0;
}

static void gaps_feed(gs_board_t *b, uint16_t seq) {
    if (!b->gap_started) {
        b->gap_started = 1;
        b->gap_highest = seq;
        return;
    }
    uint16_t ahead = (uint16_t)(seq - b->gap_highest);
    if (ahead == 0 || ahead >= 0x8000u) { /* a duplicate or a late (reordered) one */
        for (uint16_t k = 0; k < b->gap_n; k++) {
            uint16_t at = (uint16_t)((b->gap_head + k) % GS_GAP_WINDOW);
            if (b->gap_missing[at] == seq) { /* it filled a gap: remove it */
                for (uint16_t j = k; j + 1 < b->gap_n; j++)
                    b->gap_missing[(b->gap_head + j) % GS_GAP_WINDOW] = b->gap_missing[(b->gap_head + j + 1) % GS_GAP_WINDOW];
                b->gap_n--;
                b->seq_gaps--;
                break;
            }
        }
        return;
    }
    uint16_t gap = (uint16_t)(ahead - 1u);
    for (uint16_t k = gap > GS_GAP_WINDOW ? (uint16_t)(gap - GS_GAP_WINDOW) : 0; k < gap; k++) {
        uint16_t missing = (uint16_t)(b->gap_highest + 1u + k);
        if (b->gap_n == GS_GAP_WINDOW) { /* forget the oldest */
            b->gap_head = (uint16_t)((b->gap_head + 1u) % GS_GAP_WINDOW);
            b->gap_n--;
        }
        b->gap_missing[(b->gap_head + b->gap_n) % GS_GAP_WINDOW] = missing;
        b->gap_n++;
    }
    b->seq_gaps += gap;
    b->gap_highest = seq;
}

/* --- bus jobs ------------------------------------------------------------------------------- */

/* "servo id N (name) <what>" for NACK details (static buffer, at most the detail's 64 bytes). */
static const char *servo_text(unsigned i, const char *what) {
    static char text[GS_MAX_NACK_DETAIL_BYTES + 1];
    char id[4];
    size_t n = 0;
    const char *parts[5] = {"servo id ", id, " (", gs_servos[i].name, ") "};
    fmt_u64(id, sizeof id, gs_servos[i].id);
    for (unsigned k = 0; k < 5; k++)
        for (const char *p = parts[k]; *p && n < GS_MAX_NACK_DETAIL_BYTES; p++) text[n++] = *p;
    for (const char *p = what; *p && n < GS_MAX_NACK_DETAIL_BYTES; p++) text[n++] = *p;
    text[n] = 0;
    return text;
}

static void servo_lost(gs_board_t *b, unsigned i) {
    if (hal_should_stop()) return; /* a stop ends the bus waits (gs_bus.c): no servo was lost */
    b->answering &= ~((gs_mask_t)1 << i);
    if (b->servo_fault) return;
    b->servo_fault = 1;
    b->fault_servo = (uint8_t)i;
    b->fault_errors = 0;
    b->servo_fault_t = b->now_us;
    gs_log_str("board: servo id ");
    gs_log_u64(gs_servos[i].id);
    gs_log_str(" (");
    gs_log_str(gs_servos[i].name);
    gs_log_str(") stopped answering on the servo bus at board time ");
    gs_log_secs(b->now_us);
    gs_log_str(" s; every servo holds; fault latched until ESTOP_CLEAR");
    gs_log_end();
    nack(b, b->last_rx_seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_SERVO_FAULT, servo_text(i, "stopped answering on the servo bus"), 0);
}

/* Realtime: while the bus is stalled (the last read got no answer at all: the plant is not running), reads
 * wait only STALLED_TIMEOUT_US, so a descheduled plant costs the board half a tick per read instead of 10 ms
 * (which made the board itself fall behind and skip ticks). Nothing is lost: late answers are still
 * collected (gs_bus.c), and a stalled read never counts towards a dead servo. */
#define STALLED_TIMEOUT_US 1000u

static uint32_t read_timeout(const gs_board_t *b) {
    return b->bus_stalled && !b->cfg.lockstep ? STALLED_TIMEOUT_US : b->bus_timeout_us;
}

/* A servo's first present position: its command starts there (no jump to neutral or to a first frame),
 * and its torque goes on after the next goal write (unless a limp ESTOP or a hardware error keeps it off). */
static void first_position(gs_board_t *b, unsigned i) {
    const gs_servo_t *s = &gs_servos[i];
    gs_mask_t bit = (gs_mask_t)1 << i;
    int32_t q = clamp32(b->pos_urad[i], s->min_urad, s->max_urad);
    b->pos_known |= bit;
    b->cmd[i] = b->anchor_v[i] = b->hold_q[i] = b->desired[i] = q;
    b->anchor_t[i] = b->now_us;
    b->goal[i] = urad_to_goal(i, q);
    b->resume_pending[i] = 0;
    b->blend_off[i] = 0;
    if ((b->torque_off & bit) && !(b->err_latched & bit) && !(b->estopped && b->cfg.estop_limp)) b->torque_due |= bit;
}

static const char *const ERR_NAMES[8] = {"input voltage", "angle limit", "overheating", "motor encoder",
                                         "electrical shock", "overload", "overcurrent", "hardware alert"};

/* "overload" / "overheating, overload" (GS_SERVO_ERR_* bits, low first) into `out`. */
static void err_text(uint8_t err, char *out, size_t cap) {
    size_t n = 0;
    for (unsigned k = 0; k < 8u; k++) {
        if (!(err >> k & 1u)) continue;
        if (n && n + 2u < cap) {
            out[n++] = ',';
            out[n++] = ' ';
        }
        for (const char *p = ERR_NAMES[k]; *p && n + 1u < cap; p++) out[n++] = *p;
    }
    out[n] = 0;
}

/* A servo reported a hardware error (GS_SERVO_ERR_*; the Dynamixel alert bit is resolved here by reading its
 * hardware error status): its torque goes off, one log line names it, and SERVO_FAULT latches (every servo
 * holds) until ESTOP_CLEAR, which turns its torque on again (a persisting error latches anew). */
static void servo_error(gs_board_t *b, unsigned i, uint8_t err) {
    gs_mask_t bit = (gs_mask_t)1 << i;
    uint8_t id = gs_servos[i].id;
    if (b->err_latched & bit) return;
    if (err & GS_SERVO_ERR_ALERT) {
        uint8_t hw = 0;
        if (gs_bus_read_errors(id, &hw, read_timeout(b))) err = hw; /* unanswered: "hardware alert" */
        if (!err) return;                                            /* an alert with no hardware error */
    }
    b->err_latched |= bit;
    b->servo_errors[i] = err;
    gs_bus_torque(&id, 1, 0);
    b->torque_off |= bit;
    b->torque_due &= ~bit;
    char what[GS_MAX_NACK_DETAIL_BYTES + 1];
    err_text(err, what, sizeof what);
    gs_log_str("board: servo ");
    gs_log_u64(id);
    gs_log_str(" (");
    gs_log_str(gs_servos[i].name);
    gs_log_str("): ");
    gs_log_str(what);
    gs_log_str("; its torque is off at board time ");
    gs_log_secs(b->now_us);
    gs_log_str(" s; every servo holds; fault latched until ESTOP_CLEAR");
    gs_log_end();
    if (b->servo_fault) return;
    b->servo_fault = 1;
    b->fault_servo = (uint8_t)i;
    b->fault_errors = err;
    b->servo_fault_t = b->now_us;
    size_t n = 0;
    while (what[n]) n++;
    const char *tail = "; torque off";
    for (const char *p = tail; *p && n + 1u < sizeof what; p++) what[n++] = *p;
    what[n] = 0;
    nack(b, b->last_rx_seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_SERVO_FAULT, servo_text(i, what), 0);
}

/* SYNC READ of present position, speed and load of servos [first, first + n). */
static void read_group(gs_board_t *b, unsigned first, unsigned n, int all) {
    uint8_t ids[READ_GROUP];
    gs_present_t pr[READ_GROUP];
    unsigned idx[READ_GROUP], k = 0;
    for (unsigned i = first; i < first + n && i < GS_SERVO_COUNT; i++) {
        if (!all && !(b->answering >> i & 1u)) continue;
        idx[k] = i;
        ids[k++] = gs_servos[i].id;
    }
    if (!k) return;
    uint32_t before = gs_bus_answers;
    uint32_t ok = gs_bus_read_present(ids, k, pr, read_timeout(b));
    b->bus_stalled = gs_bus_answers == before;
    uint64_t clock = hal_now_us();
    if (gs_bus_answers != b->answers_seen) {
        b->answers_seen = gs_bus_answers;
        b->last_answer_clock_us = clock;
    }
    uint64_t silent = clock - b->last_answer_clock_us;
    if (silent > b->silent_max_us) b->silent_max_us = silent;
    for (unsigned j = 0; j < k; j++) {
        unsigned i = idx[j];
        if (!(ok >> j & 1u)) {
            if (gs_bus_heard_late(ids[j])) { /* it answered an earlier read late: alive, behind (late_replies) */
                b->miss[i] = 0;
                continue;
            }
            if (b->miss_epoch[i] == gs_bus_answers && silent < GS_BUS_SILENT_LIMIT_US) {
                b->bus_stalls++; /* nothing answered since its last miss: the plant is not running, not proof */
                continue;
            }
            b->miss_epoch[i] = gs_bus_answers;
            if (++b->miss[i] >= b->miss_limit) servo_lost(b, i);
            continue;
        }
        b->miss[i] = 0;
        if (!pr[j].valid) continue; /* it answered, with an error number instead of data */
        const gs_servo_t *s = &gs_servos[i];
        int64_t spd = pr[j].speed, load = pr[j].load;
        spd = spd < -16777216 ? -16777216 : spd > 16777216 ? 16777216 : spd;
        load = load < -1000000 ? -1000000 : load > 1000000 ? 1000000 : load;
        b->raw_pos[i] = pr[j].pos;
        b->pos_urad[i] = steps_to_urad(i, pr[j].pos);
        b->vel_urad_s[i] = clamp32(div_round((int64_t)s->direction * spd * GS_STEP_NRAD, 1000), INT32_MIN, INT32_MAX);
        b->eff_mnm[i] = clamp32(div_round((int64_t)s->direction * load * s->load_full_mnm, 1000), INT32_MIN, INT32_MAX);
        if (!(b->pos_known >> i & 1u)) first_position(b, i);
        if (pr[j].error) servo_error(b, i, pr[j].error);
    }
}

static void read_imu(gs_board_t *b) {
    uint8_t d[GS_IMU_LEN];
    if (!b->imu_present) return;
    uint32_t before = gs_bus_answers;
    int ok = gs_bus_read(GS_IMU_ID, GS_DEV_PRESENT, GS_IMU_LEN, d, read_timeout(b));
    b->bus_stalled = gs_bus_answers == before;
    if (!ok) return;
    for (unsigned k = 0; k < 3; k++) b->imu[k] = (int16_t)(uint16_t)(d[2 * k] | d[2 * k + 1] << 8);
}

static void read_probe(gs_board_t *b) {
    if (!b->probe_present) return;
    uint32_t before = gs_bus_answers;
    int ok = gs_bus_read(GS_PROBE_ID, GS_DEV_PRESENT, GS_PROBE_LEN, b->probe, read_timeout(b));
    b->bus_stalled = gs_bus_answers == before;
    if (ok) {
        b->probe_fresh = 1;
        b->probe_t_us = b->now_us;
    }
}

#define N_GROUPS ((GS_SERVO_COUNT + READ_GROUP - 1u) / READ_GROUP)

/* The read schedule: one job per tick, so that every job of a telemetry period has run by its
 * telemetry tick, the servo groups last: [probe, IMU, group 0, group 1, ...]. */
static void bus_read_job(gs_board_t *b) {
    unsigned jobs = 2u + N_GROUPS;
    uint32_t k = b->bus_every ? b->bus_every : 1u;
    uint32_t every = gs_config_telemetry_every(&b->cfg) / k; /* in bus ticks */
    uint64_t n = (b->ticks - 1u) / k + 1u;                   /* this bus tick's number (b->ticks when k = 1) */
    unsigned job;
    if (!every) every = 1u;
    if (every >= jobs) {
        uint32_t r = (uint32_t)((every - n % every) % every); /* bus ticks to the next telemetry */
        if (r >= jobs) return;
        job = jobs - 1u - r;
    } else {
        job = (unsigned)(n % jobs);
    }
    if (!b->imu_present && gs_bus_heard_late(GS_IMU_ID)) b->imu_present = 1; /* answered its boot ping late */
    if (!b->probe_present && gs_bus_heard_late(GS_PROBE_ID)) b->probe_present = 1;
    if (job == 0) read_probe(b);
    else if (job == 1) read_imu(b);
    else read_group(b, (job - 2u) * READ_GROUP, READ_GROUP, 0);
}

static void read_all_positions(gs_board_t *b) {
    for (unsigned g = 0; g < N_GROUPS; g++) read_group(b, g * READ_GROUP, READ_GROUP, 0);
}

/* The goals of every servo, each limited to its servo table's step range right here, whatever computed it
 * (the last line of defence: a goal outside it could drive a joint into its stop); then the torque of the
 * servos whose command now starts from their present position. */
static void write_goals(gs_board_t *b) {
    uint8_t ids[GS_SERVO_COUNT];
    uint16_t steps[GS_SERVO_COUNT];
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        const gs_servo_t *s = &gs_servos[i];
        uint16_t g = b->goal[i];
        ids[i] = s->id;
        steps[i] = g < s->step_lo ? s->step_lo : g > s->step_hi ? s->step_hi : g;
    }
    gs_bus_write_goals(ids, GS_SERVO_COUNT, steps);
    if (b->torque_due) {
        uint8_t on[GS_SERVO_COUNT];
        size_t n = 0;
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++)
            if (b->torque_due >> i & 1u) on[n++] = gs_servos[i].id;
        gs_bus_torque(on, n, 1);
        b->torque_off &= ~b->torque_due;
        b->torque_due = 0;
    }
}

/* --- init ------------------------------------------------------------------------------------ */

void gs_board_init(gs_board_t *b, const gs_settings_t *cfg, gs_send_fn sendfn, void *ctx) {
    b->cfg = *cfg;
    gs_bus_init(cfg->bus_protocol == GS_BUS_DXL2 ? GS_BUS_DXL2 : GS_BUS_STS, cfg->bus_baud);
    b->tick_us = gs_config_tick_us(cfg);
    b->bus_timeout_us = cfg->lockstep ? 1000000u : 10000u; /* lockstep: no deadline, only a dead servo waits */
    b->miss_limit = cfg->lockstep ? MISS_LIMIT_LOCKSTEP : MISS_LIMIT_REALTIME;
    b->send = sendfn;
    b->send_ctx = ctx;
    b->now_us = 0;
    b->ticks = 0;
    b->advance_until = 0;
    b->covered_until = -1;
    b->clock_us = 0;
    b->clock_origin_us = 0;
    b->last_applied_seq = 0;
    b->last_rx_seq = 0;
    gs_jb_init(&b->buf);
    b->armed = b->fault_latched = b->estopped = 0;
    b->last_feed_us = 0;
    b->hold_since_us = GS_NO_TIME;
    b->watchdog_us = (int64_t)cfg->watchdog_ms * 1000;
    b->crouch_after_us = (int64_t)cfg->crouch_after_ms * 1000;
    b->watchdog_trips = 0;
    b->mode = GS_MODE_RUN;
    b->estop_rx_us = GS_NO_TIME;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        const gs_servo_t *s = &gs_servos[i];
        b->cmd[i] = clamp32(s->neutral_urad, s->min_urad, s->max_urad);
        b->anchor_t[i] = 0;
        b->anchor_v[i] = s->neutral_urad;
        b->hold_q[i] = s->neutral_urad;
        b->desired[i] = s->neutral_urad;
        b->goal[i] = urad_to_goal(i, b->cmd[i]);
        b->resume_pending[i] = 0;
        b->blend_off[i] = 0;
        b->pos_urad[i] = s->neutral_urad;
        b->vel_urad_s[i] = 0;
        b->eff_mnm[i] = 0;
        b->miss[i] = 0;
    }
    b->resume_t = 0;
    b->blending = 0;
    b->late_count = b->dropped_count = b->link_errors = b->clamped_ticks = 0;
    b->flags_since = 0;
    gaps_reset(b);
    b->seq_gaps = 0;
    b->imu[0] = b->imu[1] = b->imu[2] = 0;
    b->imu_present = b->probe_present = b->probe_fresh = 0;
    b->probe_t_us = 0;
    b->answering = ALL;
    b->servo_fault = 0;
    b->fault_servo = 0;
    b->fault_errors = 0;
    b->servo_fault_t = 0;
    b->pos_known = 0;
    b->torque_off = ALL; /* on only from a known present position */
    b->torque_due = 0;
    b->err_latched = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        b->servo_errors[i] = 0;
        b->model[i] = 0;
    }
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->miss_epoch[i] = 0;
    b->answers_seen = gs_bus_answers;
    b->last_answer_clock_us = hal_now_us();
    b->silent_max_us = 0;
    b->bus_stalls = b->ticks_skipped = b->overruns = 0;
    b->bus_stalled = 0;
    for (unsigned k = 0; k < 3; k++) b->screen_last[k].name_len = 0;
    b->speaker_action = b->speaker_kind = 0;
    b->speaker_start_us = 0;
    b->tick_cycles_last = b->tick_cycles_max = 0;
    b->tick_cycles_sum = b->tick_cycles_n = 0;
    b->bus_every = 1;
    b->bus_cycle_us = b->return_delay_us = 0;
}

/* Ping `id` until it answers (on time or late) or `rounds` pings went unanswered while the bus
 * was answering: after each unanswered ping another device is pinged (`*ref`, the last one that answered;
 * before any did, the servos and the IMU in turn), and only when something answered meanwhile does the
 * miss count. Pings into a silent bus count only after `give_up_us` (GS_BOOT_WAIT_US) of board clock. */
static int boot_ping(gs_board_t *b, uint8_t id, unsigned rounds, uint64_t give_up_us, uint8_t *ref, uint16_t *model) {
    unsigned unanswered = 0, probe = 0;
    while (!hal_should_stop()) {
        uint32_t answers = gs_bus_answers;
        if (gs_bus_ping(id, b->bus_timeout_us, model) || gs_bus_heard_late(id)) {
            *ref = id;
            return 1;
        }
        uint8_t other = *ref;
        if (!other || other == id) { /* no device known to answer yet: try the others in turn */
            unsigned k = probe++ % (GS_SERVO_COUNT + 1u);
            other = k < GS_SERVO_COUNT ? gs_servos[k].id : (uint8_t)GS_IMU_ID;
        }
        if (other != id && gs_bus_ping(other, b->bus_timeout_us, 0)) *ref = other;
        if (gs_bus_heard_late(id)) return 1;
        if (gs_bus_answers != answers || hal_now_us() >= give_up_us) unanswered++;
        if (unanswered >= rounds) return 0;
    }
    return 0;
}

/* --- boot checks (the Python board's start-up, firmware_sim/servobus/driver.py, and its wording) ---------- */

/* The servo bus's line rate (0: a socket to the emulator's plant, no wire time). A port whose bus is always
 * that socket (mps2: QEMU has no tty to open) builds with GS_BUS_SOCKET_ONLY: the line-rate code (a second
 * answer listened for, the bus cycle's wire time) is left out of its image. */
#ifdef GS_BUS_SOCKET_ONLY
#define LINE_BAUD(b) ((void)(b), 0u)
#else
#define LINE_BAUD(b) ((b)->cfg.bus_baud)
#endif

#define START_TRIES 5u            /* a servo is asked this often (ping, first read) before it is missing or garbled */
#define START_TOLERANCE_STEPS 12  /* about 1 degree outside its step range at boot refuses the start */
#define BUS_MARGIN_PCT 120u       /* the bus period holds the bus cycle with 20 % to spare */

static uint16_t expected_model(unsigned i) {
    return gs_bus_protocol() == GS_BUS_DXL2 ? gs_servos[i].model_dxl2 : gs_servos[i].model_sts;
}

static void log_servo(unsigned i) { /* "board: servo 4 (wrist_flex) " */
    gs_log_str("board: servo ");
    gs_log_u64(gs_servos[i].id);
    gs_log_str(" (");
    gs_log_str(gs_servos[i].name);
    gs_log_str(") ");
}

/* The end of a refusal line; torque off for the whole bus (twice: a broadcast WRITE has no answer). */
static int refuse_end(const char *tail) {
    gs_log_str(tail ? tail : "; torque left off");
    gs_log_end();
    gs_bus_torque_off_all();
    gs_bus_torque_off_all();
    return 2;
}

/* v / 10 with one decimal (tenths), or v as it is */
static void log_fixed(int64_t v, int tenths) {
    if (v < 0) {
        gs_log_str("-");
        v = -v;
    }
    gs_log_u64((uint64_t)(tenths ? v / 10 : v));
    if (!tenths) return;
    gs_log_str(".");
    gs_log_u64((uint64_t)(v % 10));
}

enum { PING_OK, PING_SILENT, PING_GARBLED, PING_TWICE, PING_NO_MODEL, PING_STOPPED };

/* Ping servo i until it answers with its model number (START_TRIES for garbled answers; realtime: boot_ping's
 * rounds for silence); with a line rate, then listen for a second answer (two servos with this id; a plant's
 * collided answers are garbled instead). */
static int check_ping(gs_board_t *b, unsigned i, unsigned rounds, uint64_t give_up, uint8_t *ref) {
    uint8_t id = gs_servos[i].id;
    for (unsigned tries = 1;; tries++) {
        uint32_t rx0 = gs_bus_rx_bytes, timeouts0 = gs_bus_stats.timeouts;
        uint64_t in0 = gs_bus_stats.bytes_in;
        uint16_t model = 0;
        int ok = boot_ping(b, id, rounds, give_up, ref, &model);
        int garbled = (uint64_t)(uint32_t)(gs_bus_rx_bytes - rx0) > gs_bus_stats.bytes_in - in0;
        b->model[i] = model;
        if (hal_should_stop()) return PING_STOPPED;
        if (ok && model) {
            /* only when every request was answered in time: an answer that was late (a busy plant) is no twin */
            if (LINE_BAUD(b) && gs_bus_stats.timeouts == timeouts0) {
                size_t status = gs_bus_protocol() == GS_BUS_DXL2 ? 14u : 8u;
                if (gs_bus_listen(2u * gs_bus_wire_us(status) + 5000u)) return PING_TWICE;
            }
            return PING_OK;
        }
        if (tries >= START_TRIES || (!ok && !garbled)) return ok ? PING_NO_MODEL : garbled ? PING_GARBLED : PING_SILENT;
    }
}

static const char *const PING_WHY[] = {
    "", "does not answer a ping (missing, unpowered, or another id or baud)",
    "answers a ping garbled (two servos with this id, or noise on the bus)",
    "answers a ping twice (two servos with this id)", "does not tell its model number (garbled answer)", ""};

/* Each servo's return delay to 0 (STS register 7; Dynamixel address 9, EEPROM: with torque off), as LeRobot
 * sets its servos up; a servo that refuses keeps its own. Returns the largest delay read back (us). */
static uint32_t set_return_delay(gs_board_t *b) {
    int dxl = gs_bus_protocol() == GS_BUS_DXL2;
    uint16_t reg = dxl ? 9u : 7u;
    uint8_t ids[GS_SERVO_COUNT], zero = 0;
    size_t n = 0;
    uint32_t worst = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++)
        if (b->answering >> i & 1u) ids[n++] = gs_servos[i].id;
    if (!n) return 0;
    if (dxl) gs_bus_torque(ids, n, 0);
    for (size_t j = 0; j < n && !hal_should_stop(); j++) (void)gs_bus_write_reg(ids[j], reg, &zero, 1, b->bus_timeout_us);
    for (size_t j = 0; j < n && !hal_should_stop(); j++) {
        uint8_t v = dxl ? 250u : 0u; /* unread: the factory default (Dynamixel X 500 us, STS 0) */
        (void)gs_bus_read(ids[j], reg, 1, &v, b->bus_timeout_us);
        if (2u * v > worst) worst = 2u * v;
    }
    return worst;
}

/* The present positions at boot: every servo answers (START_TRIES reads; no miss counts towards a lost servo
 * here) and stands inside its step range (START_TOLERANCE_STEPS to spare), else one line and 2. */
static int check_positions(gs_board_t *b) {
    uint8_t limit = b->miss_limit;
    int garbled = 0;
    uint64_t give_up = hal_now_us() + GS_BOOT_WAIT_US;
    b->miss_limit = 255u;
    for (unsigned tries = 0; tries < START_TRIES && b->pos_known != ALL && !hal_should_stop();) {
        uint32_t rx0 = gs_bus_rx_bytes, answers = gs_bus_answers;
        uint64_t in0 = gs_bus_stats.bytes_in;
        read_all_positions(b);
        garbled = (uint64_t)(uint32_t)(gs_bus_rx_bytes - rx0) > gs_bus_stats.bytes_in - in0;
        /* realtime: a read nothing answered (a plant descheduled) counts only after GS_BOOT_WAIT_US, as at the pings */
        if (b->cfg.lockstep || gs_bus_answers != answers || hal_now_us() >= give_up) tries++;
    }
    b->miss_limit = limit;
    if (hal_should_stop()) return 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        const gs_servo_t *s = &gs_servos[i];
        int32_t pos = b->raw_pos[i];
        b->miss[i] = 0;
        if (!(b->pos_known >> i & 1u) || pos < 0 || pos > 4095) {
            log_servo(i);
            gs_log_str(b->pos_known >> i & 1u || garbled ? "answers garbled" : "does not answer");
            return refuse_end(" when its position is read; torque left off");
        }
        if (pos < (int32_t)s->step_lo - START_TOLERANCE_STEPS || pos > (int32_t)s->step_hi + START_TOLERANCE_STEPS) {
            log_servo(i);
            gs_log_str("is at ");
            log_fixed(div_round((int64_t)b->pos_urad[i] * 180000, 314159265), 1);
            gs_log_str(" deg, outside its range ");
            log_fixed(div_round((int64_t)s->min_urad * 18000, 314159265), 0);
            gs_log_str("..");
            log_fixed(div_round((int64_t)s->max_urad * 18000, 314159265), 0);
            gs_log_str(" deg (steps ");
            gs_log_u64((uint64_t)pos);
            gs_log_str(", limits ");
            gs_log_u64(s->step_lo);
            gs_log_str("..");
            gs_log_u64(s->step_hi);
            return refuse_end("); torque left off: move it into its range by hand and start again");
        }
    }
    return 0;
}

/* The bus period: one bus cycle (the goal SYNC WRITE, a SYNC READ of every servo's present state and the
 * answers, 10 bits a byte, each answer after the servos' return delay) with a 20 % margin, in whole control
 * periods; one boot line says it. Lockstep writes goals every tick: the plant steps its world on each. */
static void choose_bus_period(gs_board_t *b) {
    size_t n = GS_SERVO_COUNT, bytes;
    if (gs_bus_protocol() == GS_BUS_DXL2) bytes = (10u + 4u + 5u * n) + (10u + 4u + n) + n * (11u + GS_DXL_PRESENT_LEN);
    else bytes = (6u + 2u + 3u * n) + (6u + 2u + n) + n * (6u + GS_PRESENT_LEN);
    uint32_t every = 1;
    b->bus_cycle_us = LINE_BAUD(b) ? gs_bus_wire_us(bytes) + (uint32_t)n * b->return_delay_us : 0u;
    if (!b->cfg.lockstep && b->bus_cycle_us) {
        uint64_t need = (uint64_t)b->bus_cycle_us * BUS_MARGIN_PCT / 100u;
        every = (uint32_t)((need + b->tick_us - 1u) / b->tick_us);
        if (every < 1u) every = 1u;
    }
    b->bus_every = every;
    gs_log_str("board: servo bus: ");
    gs_log_u64(n);
    if (!LINE_BAUD(b)) {
        gs_log_str(" servos on a socket to the emulator's plant (no wire time)");
    } else {
        gs_log_str(" servos need ");
        log_fixed(((int64_t)b->bus_cycle_us + 50) / 100, 1);
        gs_log_str(" ms a cycle at ");
        gs_log_u64(LINE_BAUD(b));
        gs_log_str(" baud");
        if (b->return_delay_us) {
            gs_log_str(" (return delay ");
            gs_log_u64(b->return_delay_us);
            gs_log_str(" us each)");
        }
    }
    if (b->cfg.lockstep) {
        gs_log_str(": goals every tick (lockstep: the plant steps on each goal write)");
    } else {
        gs_log_str(": goals every ");
        if (every == 1u) {
            gs_log_str("tick");
        } else {
            gs_log_u64(every);
            gs_log_str(" ticks");
        }
        gs_log_str(" (");
        uint32_t hz10 = (uint32_t)(((uint64_t)b->cfg.rate_hz * 10u + every / 2u) / every);
        log_fixed(hz10 % 10u ? hz10 : hz10 / 10u, hz10 % 10u != 0u);
        gs_log_str(" Hz)");
    }
    gs_log_end();
}

int gs_board_boot(gs_board_t *b) {
    /* the plant may still be starting or be descheduled (in lockstep too: a plant in User-Mode Linux on a loaded
     * machine took over a second to answer its first ping, and servo 1 was reported dead); a device is absent only
     * after BOOT_PING_ROUNDS_REALTIME pings (lockstep: 1, its 1 s timeout is one round's worth) it left unanswered
     * while the rest of the bus answered, or after GS_BOOT_WAIT_US of a silent bus. */
    gs_mask_t silent = 0;
    unsigned rounds = b->cfg.lockstep ? 1u : BOOT_PING_ROUNDS_REALTIME;
    uint64_t give_up = hal_now_us() + GS_BOOT_WAIT_US;
    uint8_t ref = 0; /* a device that answered (0: none yet) */
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        if (!b->cfg.boot_checks) {
            int ok = boot_ping(b, gs_servos[i].id, rounds, give_up, &ref, &b->model[i]);
            if (!ok) silent |= (gs_mask_t)1 << i;
            continue;
        }
        int r = check_ping(b, i, rounds, give_up, &ref);
        if (r == PING_STOPPED) return 0;
        if (r == PING_SILENT && i == 0u) { /* nothing answered yet: does any servo answer at all? */
            int any = 0;
            for (unsigned j = 1; j < GS_SERVO_COUNT && !any && !hal_should_stop(); j++)
                any = gs_bus_ping(gs_servos[j].id, b->bus_timeout_us, 0);
            if (!any) {
                gs_log_str("board: no servo answers a ping (");
                gs_log_u64(GS_SERVO_COUNT);
                gs_log_str(" servos, ids ");
                for (unsigned j = 0; j < GS_SERVO_COUNT; j++) {
                    if (j) gs_log_str(", ");
                    gs_log_u64(gs_servos[j].id);
                }
                gs_log_str(") in ");
                gs_log_str(gs_bus_protocol_name(gs_bus_protocol()));
                if (LINE_BAUD(b)) {
                    gs_log_str(" at ");
                    gs_log_u64(LINE_BAUD(b));
                    gs_log_str(" baud");
                }
                return refuse_end(": check the protocol (--bus-protocol or the robot's hardware.toml), the baud and "
                                  "the servos' power; torque left off");
            }
        }
        if (r != PING_OK) {
            log_servo(i);
            gs_log_str(PING_WHY[r]);
            return refuse_end(0);
        }
        if (b->model[i] != expected_model(i)) {
            log_servo(i);
            gs_log_str("reports model number ");
            gs_log_u64(b->model[i]);
            gs_log_str(", the robot's hardware.toml says ");
            gs_log_u64(expected_model(i));
            return refuse_end(0);
        }
    }
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        if (silent >> i & 1u) {
            b->miss[i] = b->miss_limit;
            servo_lost(b, i);
        }
    }
    if (hal_should_stop()) return 0; /* stopped while it looked for its bus: no "absent" devices to report */
    b->return_delay_us = set_return_delay(b);
    if (b->cfg.boot_checks) {
        int r = check_positions(b);
        if (r) return r;
    }
    b->answers_seen = gs_bus_answers;
    b->last_answer_clock_us = hal_now_us();
    if (hal_should_stop()) return 0;
    b->imu_present = (uint8_t)(b->cfg.lockstep ? gs_bus_ping(GS_IMU_ID, b->bus_timeout_us, 0)
                                               : boot_ping(b, GS_IMU_ID, rounds, give_up, &ref, 0));
    b->probe_present = (uint8_t)(b->cfg.lockstep ? gs_bus_ping(GS_PROBE_ID, b->bus_timeout_us, 0)
                                                 : boot_ping(b, GS_PROBE_ID, rounds, give_up, &ref, 0));
    /* the present positions first: each command starts there, and torque goes on with the first tick's goal
       write (write_goals), so no servo jumps to neutral or to the first frame */
    read_all_positions(b);
    read_imu(b);
    read_probe(b);
    uint16_t model = b->model[0];
    for (unsigned i = 1; i < GS_SERVO_COUNT; i++)
        if (b->model[i] != model) model = 0;
    gs_log_str("board: servo bus (");
    gs_log_str(gs_bus_protocol_name(gs_bus_protocol()));
    if (LINE_BAUD(b)) {
        gs_log_str(", ");
        gs_log_u64(LINE_BAUD(b));
        gs_log_str(" baud");
    }
    gs_log_str("): ");
    gs_log_u64(GS_SERVO_COUNT);
    gs_log_str(" servos");
    if (model) {
        gs_log_str(" (model ");
        gs_log_u64(model);
        gs_log_str(")");
    }
    gs_log_str(", IMU ");
    gs_log_str(b->imu_present ? "present" : "absent");
    gs_log_str(", ground-truth probe ");
    gs_log_str(b->probe_present ? "present (emulator: SIM_STATE forwarded)" : "absent (no SIM_STATE)");
    gs_log_end();
    choose_bus_period(b);
    return 0;
}

/* --- time ------------------------------------------------------------------------------------ */

int64_t gs_board_time_us(const gs_board_t *b) {
    if (b->cfg.lockstep || !b->clock_us) return b->now_us;
    return (int64_t)b->clock_us() - b->clock_origin_us;
}

int gs_board_can_tick(const gs_board_t *b) {
    if (!b->cfg.lockstep) return 1;
    return b->now_us < b->advance_until || b->now_us <= b->covered_until;
}

void gs_board_skip(gs_board_t *b, uint64_t n) {
    b->now_us += (int64_t)n * b->tick_us;
    b->ticks += n;
    b->ticks_skipped += (uint32_t)n;
}

void gs_board_note_overrun(gs_board_t *b) {
    b->flags_since |= GS_FAULT_FLAGS_TICK_OVERRUN;
    b->overruns++;
}

void gs_board_on_link_error(gs_board_t *b) {
    b->link_errors++;
    b->flags_since |= GS_FAULT_FLAGS_LINK_ERRORS;
}

static void recompute_cover(gs_board_t *b) {
    int64_t latest;
    int64_t bound = gs_jb_latest(&b->buf, &latest) ? latest : b->now_us - b->tick_us;
    if (bound < b->covered_until) b->covered_until = bound;
}

/* Leaving a hold: each servo continues from its command, blending into the stream (see blend). */
static void resume(gs_board_t *b) {
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        b->anchor_t[i] = b->now_us;
        b->anchor_v[i] = b->cmd[i];
        b->resume_pending[i] = 1;
        b->resume_from[i] = b->cmd[i];
        b->blend_off[i] = 0;
    }
    b->resume_t = b->now_us;
    b->blending = 1;
    recompute_cover(b);
}

/* --- messages ---------------------------------------------------------------------------- */

/* A refused HELLO's schema detail is the Python board's, byte for byte (firmware_sim/board.py _hello:
   "host schema 0x%08x != board 0x%08x"), so the host's refusal line is the same whichever board refused
   (tests/cfirmware/test_handshake_refusal.py). */
static void hello(gs_board_t *b, const gs_hello_t *h, uint16_t seq) {
    if (h->protocol_version != GS_PROTOCOL_VERSION) {
        nack(b, seq, GS_MSG_TYPE_HELLO, GS_NACK_REASON_VERSION_MISMATCH, "host protocol version differs; board speaks v1", 0);
        return;
    }
    if (h->schema_hash != GS_SCHEMA_HASH) {
        static const char form[] = "host schema 0x........ != board 0x........";
        char d[sizeof form];
        uint32_t v = h->schema_hash;
        int shift = 28;
        for (unsigned i = 0; i < sizeof form; i++) {
            char ch = form[i];
            if (ch == '.') {  /* the next hex digit: the host's hash, then the board's */
                unsigned nib = (v >> shift) & 15u;
                ch = (char)(nib < 10u ? '0' + nib : 'a' - 10u + nib);
                shift -= 4;
                if (shift < 0) {
                    shift = 28;
                    v = GS_SCHEMA_HASH;
                }
            }
            d[i] = ch;
        }
        nack(b, seq, GS_MSG_TYPE_HELLO, GS_NACK_REASON_SCHEMA_MISMATCH, d, 0);
        return;
    }
    gs_msg_t m;
    gs_caps_t *c = &m.u.caps;
    m.type = GS_MSG_TYPE_CAPS;
    c->protocol_version = GS_PROTOCOL_VERSION;
    c->schema_hash = GS_SCHEMA_HASH;
    c->servo_count = GS_SERVO_COUNT;
    c->control_rate_hz = (uint16_t)b->cfg.rate_hz;
    c->buffer_depth = GS_BUFFER_DEPTH;
    c->telemetry_rate_hz = (uint16_t)b->cfg.telemetry_rate_hz;
    c->board_time_us = (uint64_t)gs_board_time_us(b);
    c->lockstep = b->cfg.lockstep ? 1u : 0u;
    set_str(c->robot, &c->robot_len, GS_MAX_NAME_BYTES, GS_ROBOT_NAME);
    c->servo_table_hash = GS_SERVO_TABLE_HASH;
    send(b, &m, 0);
}

static void servo_frame(gs_board_t *b, const gs_servo_frame_t *f, uint16_t seq) {
    gs_mask_t mask = f->mask;
    if (!mask || (mask & ~ALL)) {
        b->dropped_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_BAD_VALUE, "mask must cover the board's servos only", 0);
        return;
    }
    if (b->estopped) {
        b->dropped_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_ESTOPPED, "estop active; send ESTOP_CLEAR", 0);
        return;
    }
    if (b->fault_latched) {
        b->dropped_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_FAULT_LATCHED, "watchdog fault latched; send ESTOP_CLEAR", 0);
        return;
    }
    if (b->servo_fault) {
        b->dropped_count++;
        char what[GS_MAX_NACK_DETAIL_BYTES + 1] = "is not answering";
        if (b->fault_errors) err_text(b->fault_errors, what, sizeof what - 20u);
        size_t n = 0;
        while (what[n]) n++;
        for (const char *p = "; send ESTOP_CLEAR"; *p && n + 1u < sizeof what; p++) what[n++] = *p;
        what[n] = 0;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_SERVO_FAULT, servo_text(b->fault_servo, what), 0);
        return;
    }
    int64_t now = b->now_us;
    int64_t t = (int64_t)unwrap32(f->apply_at_us, now);
    if (t < now - b->cfg.max_late_us) {
        char late[24];
        fmt_u64(late, sizeof late, (uint64_t)(now - t));
        b->late_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_LATE, "late by us: ", late);
        return;
    }
    if (t > now + b->cfg.max_future_us) {
        b->dropped_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_TOO_FAR_FUTURE, "due too far ahead of the board clock", 0);
        return;
    }
    int16_t q[GS_SERVO_COUNT];
    gs_mask_t resume_mask = 0;
    unsigned k = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        q[i] = 0;
        if (!(mask >> i & 1u)) continue;
        q[i] = f->targets[k++];
        if (!gs_jb_pending_for(&b->buf, i) && now - b->anchor_t[i] > b->cfg.resume_gap_us) resume_mask |= (gs_mask_t)1 << i;
    }
    if (!gs_jb_push(&b->buf, t, seq, mask, q)) {
        b->dropped_count++;
        nack(b, seq, GS_MSG_TYPE_SERVO_FRAME, GS_NACK_REASON_BUFFER_FULL, "jitter buffer full", 0);
        return;
    }
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) { /* an idle servo starts the new stream from where it is */
        if (resume_mask >> i & 1u) {
            b->anchor_t[i] = now;
            b->anchor_v[i] = b->cmd[i];
        }
    }
    if (t > b->covered_until) b->covered_until = t;
}

static void config(gs_board_t *b, const gs_msg_t *m, uint16_t seq) {
    int32_t v = m->u.config.value;
    switch (m->u.config.key) {
    case GS_CONFIG_KEY_TELEMETRY_RATE_HZ:
        if (v >= 1 && (uint32_t)v <= b->cfg.rate_hz) { b->cfg.telemetry_rate_hz = (uint32_t)v; break; }
        goto bad;
    case GS_CONFIG_KEY_WATCHDOG_MS:
        if (v > 0) { b->cfg.watchdog_ms = (uint32_t)v; b->watchdog_us = (int64_t)v * 1000; break; }
        goto bad;
    case GS_CONFIG_KEY_CROUCH_AFTER_MS:
        if (v >= 0) { b->cfg.crouch_after_ms = (uint32_t)v; b->crouch_after_us = (int64_t)v * 1000; break; }
        goto bad;
    case GS_CONFIG_KEY_MAX_LATE_US:
        if (v >= 0) { b->cfg.max_late_us = v; break; }
        goto bad;
    case GS_CONFIG_KEY_MAX_FUTURE_US:
        if (v > 0) { b->cfg.max_future_us = v; break; }
        goto bad;
    default: { /* a well-formed CONFIG with an unknown key (gs_board_unknown_config) */
        char key[4];
        fmt_u64(key, sizeof key, m->u.config.key);
        nack(b, seq, GS_MSG_TYPE_CONFIG, GS_NACK_REASON_BAD_VALUE, "unknown CONFIG key ", key);
        return;
    }
    }
    ack(b, seq, GS_MSG_TYPE_CONFIG);
    return;
bad:
    nack(b, seq, GS_MSG_TYPE_CONFIG, GS_NACK_REASON_BAD_VALUE, "config value out of range", 0);
}

int gs_board_unknown_config(gs_board_t *b, const uint8_t *body, uint16_t seq, int64_t rx) {
    if (body[1] != GS_MSG_TYPE_CONFIG || body[4] != 5u) return 0;
    uint8_t key = body[GS_FRAME_HEADER_SIZE];
    if (key >= GS_CONFIG_KEY_TELEMETRY_RATE_HZ && key <= GS_CONFIG_KEY_CROUCH_AFTER_MS) return 0;
    gs_msg_t m;
    m.type = GS_MSG_TYPE_CONFIG;
    m.u.config.key = key;
    const uint8_t *v = &body[GS_FRAME_HEADER_SIZE + 1];
    m.u.config.value = (int32_t)((uint32_t)v[0] | (uint32_t)v[1] << 8 | (uint32_t)v[2] << 16 | (uint32_t)v[3] << 24);
    gs_board_handle(b, &m, seq, rx); /* config(): not a known key -> NACK BAD_VALUE */
    return 1;
}

void gs_board_handle(gs_board_t *b, const gs_msg_t *m, uint16_t seq, int64_t rx) {
    uint8_t t = m->type;
    if (GS_MSG_BOARD_SENT(t)) {
        nack(b, seq, t, GS_NACK_REASON_UNSUPPORTED, "board does not accept ", gs_msg_type_name(t));
        return;
    }
    /* a new host numbers its messages from 0; a re-sent HELLO (seq > 0) continues its sender's
       numbering, and a HELLO lost before it is a gap like any other (board.py does the same) */
    if (t == GS_MSG_TYPE_HELLO && seq == 0) gaps_reset(b);
    gaps_feed(b, seq);
    b->last_rx_seq = seq;
    int64_t held_since = b->hold_since_us;
    if (safety_feed(b, b->now_us)) {
        resume(b);
        gs_log_str("board: watchdog resume at board time ");
        gs_log_secs(b->now_us);
        gs_log_str(" s, a valid message ended the hold after ");
        gs_log_secs(b->now_us - (held_since != GS_NO_TIME ? held_since : b->now_us));
        gs_log_str(" s");
        gs_log_end();
    }
    switch (t) {
    case GS_MSG_TYPE_SERVO_FRAME:
        servo_frame(b, &m->u.servo_frame, seq);
        return;
    case GS_MSG_TYPE_HEARTBEAT:
        return;
    case GS_MSG_TYPE_TIME_SYNC_REQUEST: {
        gs_msg_t r;
        r.type = GS_MSG_TYPE_TIME_SYNC_REPLY;
        r.u.time_sync_reply.t1_host_us = m->u.time_sync_request.t1_host_us;
        r.u.time_sync_reply.t2_board_us = (uint64_t)rx;
        r.u.time_sync_reply.t3_board_us = (uint64_t)gs_board_time_us(b);
        send(b, &r, 0);
        return;
    }
    case GS_MSG_TYPE_HELLO:
        hello(b, &m->u.hello, seq);
        return;
    case GS_MSG_TYPE_ADVANCE: {
        if (!b->cfg.lockstep) {
            nack(b, seq, t, GS_NACK_REASON_NOT_LOCKSTEP, "ADVANCE needs a --lockstep board", 0);
            return;
        }
        int64_t until = clamp_u64(m->u.advance.until_us);
        if (until > b->advance_until) b->advance_until = until;
        ack(b, seq, t);
        return;
    }
    case GS_MSG_TYPE_FLUSH: {
        gs_mask_t touched = gs_jb_flush(&b->buf, clamp_u64(m->u.flush.from_us), m->u.flush.mask);
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
            if (!(touched >> i & 1u)) continue;
            b->anchor_t[i] = b->now_us;
            b->anchor_v[i] = b->cmd[i];
            b->resume_pending[i] = 0; /* the new stream starts from the command */
            b->blend_off[i] = 0;
        }
        recompute_cover(b);
        ack(b, seq, t);
        return;
    }
    case GS_MSG_TYPE_ESTOP:
        if (b->estop_rx_us == GS_NO_TIME && !b->estopped) b->estop_rx_us = rx;
        b->estopped = 1;
        gs_jb_clear(&b->buf);
        read_all_positions(b); /* hold where the servos are now */
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
            b->hold_q[i] = b->pos_urad[i];
            b->cmd[i] = clamp32(b->hold_q[i], gs_servos[i].min_urad, gs_servos[i].max_urad);
        }
        if (b->cfg.estop_limp) { /* limp: every servo's torque off until ESTOP_CLEAR */
            uint8_t ids[GS_SERVO_COUNT];
            for (unsigned i = 0; i < GS_SERVO_COUNT; i++) ids[i] = gs_servos[i].id;
            gs_bus_torque(ids, GS_SERVO_COUNT, 0);
            b->torque_off = ALL;
            b->torque_due = 0;
        }
        ack(b, seq, t);
        return;
    case GS_MSG_TYPE_ESTOP_CLEAR:
        b->estopped = 0;
        b->fault_latched = 0;
        b->hold_since_us = GS_NO_TIME;
        b->last_feed_us = b->now_us;
        if (b->servo_fault) { /* try the servos again; one still silent or failing latches the fault anew */
            b->servo_fault = 0;
            b->fault_errors = 0;
            b->answering = ALL;
            for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->miss[i] = 0;
        }
        b->err_latched = 0;
        if (b->torque_off) { /* torque on again (after the next goal write) from where those servos are now */
            read_all_positions(b);
            for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
                if (!(b->torque_off >> i & 1u) || !(b->pos_known >> i & 1u)) continue;
                b->cmd[i] = b->hold_q[i] = clamp32(b->pos_urad[i], gs_servos[i].min_urad, gs_servos[i].max_urad);
                b->goal[i] = urad_to_goal(i, b->cmd[i]);
                b->torque_due |= (gs_mask_t)1 << i;
            }
        }
        resume(b);
        ack(b, seq, t);
        return;
    case GS_MSG_TYPE_CONFIG:
        config(b, m, seq);
        return;
    case GS_MSG_TYPE_SCREEN:
        if (m->u.screen.target < 3u) b->screen_last[m->u.screen.target] = m->u.screen;
        ack(b, seq, t);
        return;
    case GS_MSG_TYPE_SPEAKER:
        b->speaker_action = m->u.speaker.action;
        b->speaker_kind = m->u.speaker.kind;
        b->speaker_start_us = m->u.speaker.start_at_us;
        ack(b, seq, t);
        return;
    case GS_MSG_TYPE_CAMERA_CAPTURE:
        nack(b, seq, t, GS_NACK_REASON_NO_RENDERER, "this board has no camera renderer (an MCU)", 0);
        return;
    case GS_MSG_TYPE_CAMERA_RESEND:
        nack(b, seq, t, GS_NACK_REASON_BAD_VALUE, "no image kept (this board has no camera renderer)", 0);
        return;
    default:
        nack(b, seq, t, GS_NACK_REASON_UNSUPPORTED, "board does not accept ", gs_msg_type_name(t));
        return;
    }
}

/* --- control tick -------------------------------------------------------------------------- */

/* Per servo: linear from its anchor (last applied keyframe) to its next buffered keyframe. */
static void interpolate(gs_board_t *b, int64_t t, int32_t *out) {
    gs_jb_next_all(&b->buf);
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        out[i] = b->anchor_v[i];
        if (!b->buf.has_next[i]) continue;
        int64_t t1 = b->buf.next_t[i], t0 = b->anchor_t[i];
        if (t1 > t0) {
            int64_t a = b->anchor_v[i], v1 = (int64_t)b->buf.next_q[i] * 100;
            out[i] = (int32_t)(a + (v1 - a) * (t - t0) / (t1 - t0));
        }
    }
}

/* 1 - min_jerk(s) in Q16 for s = num/den in [0, 1) (robots.motion.min_jerk: 10s^3 - 15s^4 + 6s^5). */
static int64_t fade_q16(int64_t num, int64_t den) {
    int64_t s = num * 65536 / den;
    int64_t s2 = s * s >> 16, s3 = s2 * s >> 16;
    int64_t poly = 10 * 65536 - 15 * s + 6 * s2;
    return 65536 - (s3 * poly >> 16);
}

/* Interpolated targets plus, per servo after a resume, the offset from the held command to the
 * stream fading with a minimum-jerk profile over 1.875 |offset| / resume_speed (board_stream.py TargetStream.blend). */
static void blend(gs_board_t *b, int64_t t, int32_t *out) {
    gs_jb_next_all(&b->buf);
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        if (!b->resume_pending[i]) continue;
        int32_t held = b->resume_from[i], v1;
        if (b->buf.has_next[i]) {
            v1 = (int32_t)b->buf.next_q[i] * 100;
            b->anchor_t[i] = t; /* flat at the first target until it is due */
            b->anchor_v[i] = v1;
        } else if (b->anchor_t[i] != b->resume_t || b->anchor_v[i] != held) {
            v1 = b->anchor_v[i]; /* a frame was applied at once */
        } else {
            continue;
        }
        b->resume_pending[i] = 0;
        int32_t off = held - v1;
        b->blend_t0[i] = t;
        b->blend_off[i] = off;
        int64_t len = (int64_t)(off < 0 ? -off : off) * 1875 / (b->cfg.resume_speed_urad_s / 1000);
        b->blend_len[i] = len > b->cfg.resume_blend_min_us ? len : b->cfg.resume_blend_min_us;
    }
    interpolate(b, t, out);
    int active = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        if (b->resume_pending[i]) active = 1;
        if (!b->blend_off[i]) continue;
        int64_t el = t - b->blend_t0[i];
        if (el >= b->blend_len[i]) {
            b->blend_off[i] = 0;
            continue;
        }
        out[i] = (int32_t)(out[i] + ((int64_t)b->blend_off[i] * fade_q16(el, b->blend_len[i]) >> 16));
        active = 1;
    }
    if (!active) b->blending = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++)
        if (b->resume_pending[i]) out[i] = b->resume_from[i];
}

/* The servo table's clamps per tick: joint range, then speed (servo_model.py; quantisation and
 * deadband happen in the servo itself). Returns 1 when any target was clamped. */
static int servo_step(gs_board_t *b, const int32_t *desired, int32_t speed_cap_urad_s) {
    int hit = 0;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        const gs_servo_t *s = &gs_servos[i];
        int32_t x = desired[i];
        int32_t tg = x > s->max_urad ? s->max_urad : (x < s->min_urad ? s->min_urad : x);
        if (tg != x) hit = 1;
        int64_t speed = s->max_speed_urad_s;
        if (speed_cap_urad_s > 0 && speed_cap_urad_s < speed) speed = speed_cap_urad_s;
        int64_t step = speed * b->tick_us / 1000000;
        int64_t delta = (int64_t)tg - b->cmd[i];
        if (delta > step || delta < -step) hit = 1;
        b->cmd[i] = (int32_t)(b->cmd[i] + (delta > step ? step : (delta < -step ? -step : delta)));
        b->goal[i] = urad_to_goal(i, b->cmd[i]);
    }
    return hit;
}

static void telemetry(gs_board_t *b) {
    gs_msg_t m;
    gs_telemetry_t *x = &m.u.telemetry;
    m.type = GS_MSG_TYPE_TELEMETRY;
    x->board_time_us = (uint64_t)b->now_us;
    x->positions_n = x->velocities_n = x->efforts_n = GS_SERVO_COUNT;
    for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
        x->positions[i] = q16_of(b->pos_urad[i], 100);
        x->velocities[i] = q16_of(b->vel_urad_s[i], 1000);
        x->efforts[i] = (int16_t)clamp32(b->eff_mnm[i], -32767, 32767);
    }
    for (unsigned k = 0; k < 3; k++) x->imu_rpy[k] = b->imu[k];
    x->faults = (uint16_t)(safety_flags(b) | b->flags_since);
    b->flags_since = 0;
    x->buffer_fill = b->buf.n;
    x->last_applied_seq = b->last_applied_seq;
    x->late_count = b->late_count;
    x->dropped_count = b->dropped_count;
    x->link_errors = b->link_errors;
    send(b, &m, 1);
    if (b->probe_present && b->probe_fresh) {
        gs_msg_t s;
        gs_sim_state_t *y = &s.u.sim_state;
        s.type = GS_MSG_TYPE_SIM_STATE;
        y->board_time_us = (uint64_t)b->probe_t_us;
        for (unsigned k = 0; k < 3; k++)
            y->base_pos[k] = (uint32_t)(b->probe[4 * k] | b->probe[4 * k + 1] << 8 | b->probe[4 * k + 2] << 16 | (uint32_t)b->probe[4 * k + 3] << 24);
        for (unsigned k = 0; k < 4; k++) {
            const uint8_t *p = &b->probe[12 + 4 * k];
            y->base_quat[k] = (uint32_t)(p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24);
        }
        y->objects = b->probe[28];
        y->toppled = b->probe[29];
        send(b, &s, 1);
    }
}

void gs_board_tick(gs_board_t *b) {
    uint32_t c0 = hal_cycles();
    int64_t t = b->now_us;
    int entered = 0;
    gs_mode_t mode = safety_update(b, t, &entered);
    int32_t speed_cap = 0;
    if (b->estop_rx_us != GS_NO_TIME && mode == GS_MODE_ESTOP) {
        /* on the clock the arrival was stamped on (a realtime board catching up runs ticks whose t is
           before the arrival: t would give a negative latency) */
        log_event("estop in effect", gs_board_time_us(b), b->estop_rx_us);
        gs_log_str(" s after it arrived");
        gs_log_end();
        b->estop_rx_us = GS_NO_TIME;
    }
    if (entered && (mode == GS_MODE_HOLD || mode == GS_MODE_CROUCH || mode == GS_MODE_SERVO_FAULT)) {
        gs_jb_clear(&b->buf);
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->hold_q[i] = b->cmd[i];
        if (mode != GS_MODE_SERVO_FAULT) {
            log_event(mode == GS_MODE_HOLD ? "watchdog hold" : "watchdog crouch", t, b->last_feed_us);
            gs_log_str(" s after the last valid message");
            if (mode == GS_MODE_CROUCH) gs_log_str("; fault latched until ESTOP_CLEAR");
            gs_log_end();
        }
    }
    b->mode = mode;
    if (mode == GS_MODE_RUN) {
        uint16_t k = gs_jb_due(&b->buf, t);
        for (uint16_t j = 0; j < k; j++) {
            const gs_jframe_t *f = &b->buf.f[j];
            for (unsigned i = 0; i < GS_SERVO_COUNT; i++) {
                if (!(f->mask >> i & 1u)) continue;
                b->anchor_t[i] = f->apply_at_us;
                b->anchor_v[i] = (int32_t)f->q[i] * 100;
            }
            b->last_applied_seq = f->seq;
            if (b->cfg.lockstep) safety_feed(b, f->apply_at_us);
        }
        gs_jb_drop_front(&b->buf, k);
        if (b->blending) blend(b, t, b->desired);
        else interpolate(b, t, b->desired);
    } else if (mode == GS_MODE_CROUCH) {
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->desired[i] = gs_servos[i].safe_urad;
        speed_cap = b->cfg.crouch_speed_urad_s;
    } else {
        for (unsigned i = 0; i < GS_SERVO_COUNT; i++) b->desired[i] = b->hold_q[i];
    }
    if (servo_step(b, b->desired, speed_cap) && mode == GS_MODE_RUN) {
        b->flags_since |= GS_FAULT_FLAGS_CLAMPED;
        b->clamped_ticks++;
    }
    /* the bus period (choose_bus_period): goals and one read job every bus_every ticks, the command of this
       tick; the control loop, interpolation and watchdog above run every tick */
    int bus_tick = b->ticks % b->bus_every == 0u;
    if (bus_tick) write_goals(b); /* one SYNC WRITE per bus tick: in lockstep (every tick) the plant steps on it */
    b->now_us = t + b->tick_us;
    b->ticks++;
    if (bus_tick) bus_read_job(b);
    uint32_t every = gs_config_telemetry_every(&b->cfg);
    if (b->ticks % every == 0) telemetry(b);
    uint32_t dc = hal_cycles() - c0;
    if (c0 || dc) {
        b->tick_cycles_last = dc;
        if (dc > b->tick_cycles_max) b->tick_cycles_max = dc;
        b->tick_cycles_sum += dc;
        b->tick_cycles_n++;
#ifdef GS_TICK_TRACE /* every tick's cost as a "K CYCLES" record (the bench's median/p99; a trace build only) */
        gs_log_str("K ");
        gs_log_u64(dc);
        gs_log_end();
#endif
    }
}

void gs_board_shutdown(gs_board_t *b) {
    (void)b;
    gs_bus_torque_off_all();
    gs_log_str("board: stopping: torque off for every servo on the bus");
    gs_log_end();
}

void gs_board_log_stats(const gs_board_t *b) {
    gs_log_str("S link_errors=");
    gs_log_u64(b->link_errors);
    gs_log_str(" late_frames=");
    gs_log_u64(b->late_count);
    gs_log_str(" dropped_frames=");
    gs_log_u64(b->dropped_count);
    gs_log_str(" watchdog_trips=");
    gs_log_u64(b->watchdog_trips);
    gs_log_str(" seq_gaps=");
    gs_log_u64(b->seq_gaps);
    gs_log_str(" ticks=");
    gs_log_u64(b->ticks);
    gs_log_str(" bus_out=");
    gs_log_u64(gs_bus_stats.bytes_out);
    gs_log_str(" bus_in=");
    gs_log_u64(gs_bus_stats.bytes_in);
    gs_log_str(" bus_timeouts=");
    gs_log_u64(gs_bus_stats.timeouts);
    gs_log_str(" bus_late_replies=");
    gs_log_u64(gs_bus_stats.late_replies);
    gs_log_str(" bus_tx_dropped=");
    gs_log_u64(gs_bus_stats.tx_dropped);
    gs_log_str(" bus_stalls=");
    gs_log_u64(b->bus_stalls);
    gs_log_str(" bus_silent_max_us=");
    gs_log_u64(b->silent_max_us);
    gs_log_str(" ticks_skipped=");
    gs_log_u64(b->ticks_skipped);
    gs_log_str(" overruns=");
    gs_log_u64(b->overruns);
    if (b->tick_cycles_n) {
        gs_log_str(" tick_cycles_mean=");
        gs_log_u64(b->tick_cycles_sum / b->tick_cycles_n);
        gs_log_str(" tick_cycles_max=");
        gs_log_u64(b->tick_cycles_max);
        gs_log_str(" tick_cycles_n=");
        gs_log_u64(b->tick_cycles_n);
    }
    gs_log_end();
}
