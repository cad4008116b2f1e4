#include "gs_app.h"

#include "gs_hal.h"
#include "gs_log.h"

#define RESYNC_BEHIND_US 100000 /* realtime: re-anchor the schedule when this far behind */
#define STATS_EVERY_TICKS 500u

static void on_send(void *ctx, const gs_msg_t *m, int periodic) {
    gs_app_t *app = (gs_app_t *)ctx;
    size_t limit = periodic ? GS_TELEMETRY_BACKLOG : GS_TX_RING;
    if (gs_link_send(&app->link, m, limit) && app->board.cfg.log_frames) {
        size_t n;
        const uint8_t *raw = gs_link_last_tx(&app->link, &n);
        gs_log_str("F tx ");
        gs_log_i64(gs_board_time_us(&app->board));
        gs_log_str(" ");
        gs_log_hex(raw, n);
        gs_log_end();
    }
}

static void on_raw(void *ctx, const uint8_t *raw, size_t n) {
    gs_app_t *app = (gs_app_t *)ctx;
    static const uint8_t delim = 0;
    gs_log_str("F rx ");
    gs_log_i64(gs_board_time_us(&app->board));
    gs_log_str(" ");
    gs_log_hex(raw, n);
    gs_log_hex(&delim, 1);
    gs_log_end();
}

void gs_app_process(gs_app_t *app, const gs_rx_item_t *it) {
    gs_board_t *b = &app->board;
    if (it->kind != GS_RX_FRAME) {
        gs_board_on_link_error(b);
        gs_log_str("board: link error ");
        gs_log_str(gs_rx_kind_name(it->kind));
        gs_log_str(": ");
        gs_log_str(it->why ? it->why : "");
        gs_log_str(" (");
        gs_log_u64(it->raw_len + 1u);
        gs_log_str(" bytes)");
        gs_log_end();
        return;
    }
    gs_board_handle(b, &it->msg, it->seq, gs_board_time_us(b));
}

static void maybe_stats(gs_app_t *app, int force) {
    const gs_board_t *b = &app->board;
    uint32_t key = b->link_errors * 2654435761u ^ b->late_count * 40503u ^ b->dropped_count * 69069u ^
                   b->watchdog_trips * 1103515245u ^ b->seq_gaps * 134775813u;
    if (force || key != app->stats_key) {
        app->stats_key = key;
        gs_board_log_stats(b);
    }
}

void gs_app_tick(gs_app_t *app) {
    gs_board_tick(&app->board);
    if (app->board.ticks % STATS_EVERY_TICKS == 0) maybe_stats(app, 1);
    else if (app->board.ticks % gs_config_telemetry_every(&app->board.cfg) == 0) maybe_stats(app, 0);
}

static void serve_lockstep(gs_app_t *app) {
    gs_board_t *b = &app->board;
    gs_link_t *l = &app->link;
    gs_rx_item_t item;
    while (!hal_should_stop()) {
        unsigned ran = 0;
        /* (a stop ends the batch: each tick of a stopping board would wait out its bus reads) */
        while (gs_board_can_tick(b) && gs_link_backlog(l) < GS_LOCKSTEP_BACKLOG && ran < 256u && !hal_should_stop()) {
            gs_app_tick(app);
            if (++ran % 16u == 0) gs_link_flush(l);
        }
        unsigned handled = 0;
        int pending = 0;
        while (!gs_board_can_tick(b) && handled < 256u) {
            gs_link_pump_rx(l);
            if (!gs_link_next(l, &item)) break;
            gs_app_process(app, &item);
            handled++;
        }
        gs_link_flush(l);
        gs_link_pump_rx(l);
        pending = l->rx_len > 0;
        int blocked = (!gs_board_can_tick(b) && !pending) || gs_link_backlog(l) >= GS_LOCKSTEP_BACKLOG;
        if (blocked) hal_wait(hal_now_us() + 500000u, gs_link_backlog(l) > 0);
    }
}

static void serve_realtime(gs_app_t *app) {
    gs_board_t *b = &app->board;
    gs_link_t *l = &app->link;
    gs_rx_item_t item;
    uint64_t start = hal_now_us();
    uint64_t next_tick = 0;
    b->clock_us = hal_now_us;
    b->clock_origin_us = (int64_t)start;
    while (!hal_should_stop()) {
        uint64_t deadline = start + next_tick * b->tick_us;
        if (hal_now_us() < deadline) hal_wait(deadline, gs_link_backlog(l) > 0);
        gs_link_pump_rx(l);
        while (gs_link_next(l, &item)) gs_app_process(app, &item);
        while (start + next_tick * b->tick_us <= hal_now_us() && !hal_should_stop()) {
            uint64_t due = start + next_tick * b->tick_us;
            uint64_t late = hal_now_us() - due;
            uint64_t before = next_tick;
            next_tick++;
            if (late > RESYNC_BEHIND_US) next_tick += late / b->tick_us;
            uint64_t skipped = next_tick - before - 1u;
            gs_app_tick(app);
            if (skipped) gs_board_skip(b, skipped);
            if (late > b->tick_us) gs_board_note_overrun(b);
            /* another tick due at once: flush first. A board behind real time must not hold its
             * replies and reports until it has caught up: with every tick over its period,
             * re-anchoring does not end this loop, and the silence has no bound */
            if (start + next_tick * b->tick_us <= hal_now_us()) gs_link_flush(l);
            gs_link_pump_rx(l);
            while (gs_link_next(l, &item)) gs_app_process(app, &item);
        }
        gs_link_flush(l);
    }
}

int gs_app_init(gs_app_t *app, const gs_settings_t *cfg) {
    gs_link_init(&app->link);
    gs_board_init(&app->board, cfg, on_send, app);
    if (cfg->log_frames) {
        app->link.on_raw = on_raw;
        app->link.on_raw_ctx = app;
    }
    app->stats_key = 0;
    return gs_board_boot(&app->board);
}

int gs_app_run(gs_app_t *app, const gs_settings_t *cfg) {
    int refused = gs_app_init(app, cfg);
    if (refused) return refused; /* a boot check failed: its line is logged, torque is off; nothing is served */
    gs_log_str("board: ");
    gs_log_str(GS_ROBOT_NAME);
    gs_log_str(" (");
    gs_log_u64(GS_SERVO_COUNT);
    gs_log_str(" servos), ");
    gs_log_str(cfg->lockstep ? "lockstep" : "realtime");
    gs_log_str(", ");
    gs_log_u64(cfg->rate_hz);
    gs_log_str(" Hz, telemetry ");
    gs_log_u64(cfg->telemetry_rate_hz);
    gs_log_str(" Hz, C firmware, jitter buffer ");
    gs_log_u64(GS_BUFFER_DEPTH);
    gs_log_str(" frames, schema ");
    gs_log_hex32(GS_SCHEMA_HASH);
    gs_log_end();
    if (cfg->lockstep) serve_lockstep(app);
    else serve_realtime(app);
    gs_board_shutdown(&app->board); /* a stop (SIGTERM/SIGINT natively) leaves no servo under torque */
    maybe_stats(app, 1);
    return 0;
}
