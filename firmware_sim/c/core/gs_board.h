/* The board core: message handling and the control tick (firmware_sim/board.py, safety.py,
 * servo_model.py ported), driving the servos over the bus (gs_bus.h) instead of MuJoCo.
 *
 * gs_board_handle() consumes one decoded host message and sends the replies; gs_board_tick() runs
 * one control period at board time now_us: safety update, due frames, interpolation (or the
 * minimum-jerk blend after a hold), the servo table's range and speed clamps, the goal positions
 * to the bus (SYNC WRITE every tick), one scheduled bus read, and TELEMETRY (+ SIM_STATE when the
 * emulator's probe answers) every telemetry period. Reply policy as the Python board's docstring,
 * except CAMERA_CAPTURE -> NACK NO_RENDERER (an MCU has no renderer) and CAMERA_RESEND -> NACK
 * BAD_VALUE; a servo that stops answering, or reports a hardware error (overload, overheating, input
 * voltage ...: the STS status error byte, the Dynamixel alert bit and register 70), latches SERVO_FAULT
 * (one unsolicited NACK SERVO_FAULT naming it, frames refused with SERVO_FAULT, every servo holds; a
 * servo with an error is also torqued off) until ESTOP_CLEAR. Torque: at boot the present positions are
 * read first and each command starts there, then torque goes on; ESTOP holds (default) or goes limp
 * (gs_settings_t.estop_limp: torque off, on again at ESTOP_CLEAR from where the servos are then);
 * gs_board_shutdown() turns the whole bus's torque off.
 *
 * Units inside: angles in micro-radians (int32), times in microseconds (int64), the jitter
 * buffer keeps the wire's q16 codes. No floating point. */
#ifndef GS_BOARD_H
#define GS_BOARD_H

#include <stdint.h>

#include "gs_config.h"
#include "gs_bus.h"
#include "gs_jitter.h"
#include "gs_proto.h"

#define GS_NO_TIME INT64_MIN

typedef enum { GS_MODE_RUN = 0, GS_MODE_HOLD, GS_MODE_CROUCH, GS_MODE_ESTOP, GS_MODE_SERVO_FAULT } gs_mode_t;

typedef struct gs_board gs_board_t;
/* Where replies and reports go: `periodic` for TELEMETRY/SIM_STATE (droppable first). */
typedef void (*gs_send_fn)(void *ctx, const gs_msg_t *msg, int periodic);

struct gs_board {
    gs_settings_t cfg;
    uint32_t tick_us;
    uint32_t bus_timeout_us;
    gs_send_fn send;
    void *send_ctx;
    /* time */
    int64_t now_us;       /* board time of the next tick */
    uint64_t ticks;
    int64_t advance_until; /* lockstep: ticks run while now_us < this */
    int64_t covered_until; /* lockstep: latest accepted frame apply-at */
    uint64_t (*clock_us)(void); /* realtime fine clock (NULL in lockstep) */
    int64_t clock_origin_us;
    uint16_t last_applied_seq;
    uint16_t last_rx_seq;
    gs_jb_t buf;
    /* safety (firmware_sim/safety.py) */
    uint8_t armed, fault_latched, estopped;
    int64_t last_feed_us, hold_since_us; /* GS_NO_TIME: not holding */
    int64_t watchdog_us, crouch_after_us;
    uint32_t watchdog_trips;
    gs_mode_t mode;
    int64_t estop_rx_us;
    /* servo model and interpolation */
    int32_t cmd[GS_SERVO_COUNT];       /* last speed-limited command (urad) */
    int64_t anchor_t[GS_SERVO_COUNT];
    int32_t anchor_v[GS_SERVO_COUNT];
    int32_t hold_q[GS_SERVO_COUNT];
    int32_t desired[GS_SERVO_COUNT];
    uint16_t goal[GS_SERVO_COUNT];     /* goal position register (steps) written this tick */
    int64_t resume_t;
    uint8_t resume_pending[GS_SERVO_COUNT];
    int32_t resume_from[GS_SERVO_COUNT];
    int64_t blend_t0[GS_SERVO_COUNT], blend_len[GS_SERVO_COUNT];
    int32_t blend_off[GS_SERVO_COUNT];
    uint8_t blending;
    /* counters */
    uint32_t late_count, dropped_count, link_errors, clamped_ticks;
    uint16_t flags_since;
    /* sequence gaps of what the host sent (protocol.faults.GapDetector) */
    uint8_t gap_started;
    uint16_t gap_highest;
    uint32_t seq_gaps;
    uint16_t gap_missing[GS_GAP_WINDOW];
    uint16_t gap_n, gap_head;
    /* measured (bus) */
    int32_t pos_urad[GS_SERVO_COUNT];
    int32_t vel_urad_s[GS_SERVO_COUNT];
    int32_t eff_mnm[GS_SERVO_COUNT];
    int16_t imu[3];
    uint8_t imu_present, probe_present, probe_fresh;
    uint8_t probe[GS_PROBE_LEN];
    int64_t probe_t_us;
    /* servo-bus health: a read a servo missed counts towards its loss (miss_limit in a row) only when the
     * plant demonstrably ran meanwhile: another device answered since that servo's previous counted miss
     * (gs_bus_answers moved past miss_epoch), or the whole bus has been silent for GS_BUS_SILENT_LIMIT_US
     * of board clock (5 s). A read nobody answered is a stall (the plant or this board was descheduled:
     * lateness, counted in bus_stalls); a late answer (gs_bus_heard_late) clears the servo's misses. */
    uint8_t miss[GS_SERVO_COUNT];
    uint8_t miss_limit;
    uint32_t miss_epoch[GS_SERVO_COUNT];
    uint32_t answers_seen;   /* gs_bus_answers at the last read */
    uint64_t last_answer_clock_us; /* hal_now_us when a read last found new answers */
    uint64_t silent_max_us;  /* longest bus silence seen (hal clock) */
    uint32_t bus_stalls;     /* servo reads nobody answered, not counted as misses */
    uint8_t bus_stalled;     /* the last read got no answer at all (realtime: the next reads wait less) */
    uint32_t ticks_skipped, overruns; /* realtime: ticks skipped to catch up, ticks started a period late */
    gs_mask_t answering;   /* servos included in reads */
    uint8_t servo_fault;   /* latched */
    uint8_t fault_servo;   /* index of the first servo that stopped answering or reported an error */
    uint8_t fault_errors;  /* its GS_SERVO_ERR_* (0: it stopped answering) */
    /* torque: a servo's torque goes on only once its present position is known and its command starts
     * there (never a jump to a first frame or to neutral), after the goal write of the next tick */
    gs_mask_t pos_known;     /* servos whose present position was read at least once */
    gs_mask_t torque_off;    /* servos whose torque is off (not yet on, a hardware error, a limp ESTOP) */
    gs_mask_t torque_due;    /* torque on after the next goal write */
    gs_mask_t err_latched;   /* servos whose hardware error was reported (until ESTOP_CLEAR) */
    uint8_t servo_errors[GS_SERVO_COUNT]; /* GS_SERVO_ERR_* last reported per servo */
    uint16_t model[GS_SERVO_COUNT];       /* model number each servo reported at boot (0: unknown) */
    /* the bus period: goals written and one read job run every `bus_every` control ticks (the bus cycle's
     * wire time with a 20 % margin, chosen at boot; 1 in lockstep, where the plant steps on each goal write) */
    uint32_t bus_every;
    int32_t raw_pos[GS_SERVO_COUNT]; /* the last present position read (register steps) */
    uint32_t bus_cycle_us;     /* one bus cycle's wire time + return delays (0 on a socket) */
    uint32_t return_delay_us;  /* the servos' return delay found at boot (the largest) */
    int64_t servo_fault_t;
    /* peripherals (none on this board's bus): the last command per screen target and the speaker's last
     * action are ACKed and kept (speech text is not kept: it is the host's to synthesise) */
    gs_screen_command_t screen_last[3];
    uint8_t speaker_action, speaker_kind;
    uint64_t speaker_start_us;
    /* tick cost (hal_cycles) */
    uint32_t tick_cycles_last, tick_cycles_max;
    uint64_t tick_cycles_sum, tick_cycles_n;
};

void gs_board_init(gs_board_t *b, const gs_settings_t *cfg, gs_send_fn send, void *ctx);
/* Find the devices on the bus, check them (cfg.boot_checks), set their return delay to 0, choose the bus
 * period, read the first positions; 0, or 2 when a check refused the start (one "board: servo N (name) ..."
 * line logged, torque off for the whole bus: the caller exits with status 2). */
int gs_board_boot(gs_board_t *b);
int64_t gs_board_time_us(const gs_board_t *b);
int gs_board_can_tick(const gs_board_t *b);
void gs_board_handle(gs_board_t *b, const gs_msg_t *msg, uint16_t seq, int64_t rx_us);
void gs_board_tick(gs_board_t *b);
void gs_board_skip(gs_board_t *b, uint64_t n_ticks);
void gs_board_note_overrun(gs_board_t *b);
void gs_board_on_link_error(gs_board_t *b);
/* A serial frame whose COBS, CRC, version, length and type checked but whose payload did not decode
 * (`body`: the decoded frame, header first): a CONFIG of 5 payload bytes whose key is no ConfigKey is
 * handled as a CONFIG (NACK BAD_VALUE; board.py answerable() does the same). 1 when handled, 0 when it
 * is no such frame (the caller counts a link error). */
int gs_board_unknown_config(gs_board_t *b, const uint8_t *body, uint16_t seq, int64_t rx);
/* Stopping: torque off for every servo on the bus (a broadcast WRITE), one log line. */
void gs_board_shutdown(gs_board_t *b);
/* One "S ..." statistics record on the log channel (counters the launcher reports at exit). */
void gs_board_log_stats(const gs_board_t *b);

#endif
