/* The firmware's main loops, written once over a link seam (no include guard: included once per link).
 *
 * core/gs_app.c includes it for the serial link (gs_link.h) and core/can/gs_app_can.c for CAN (gs_can_link.h),
 * so a port that brings up only the serial link (the MCU images) compiles and links no CAN code, and the loops
 * cost nothing extra there (no indirection). Lockstep: tick while the host's frames or ADVANCE cover the next
 * tick (the backlog below SERVE_LOCKSTEP_BACKLOG), else take the next decoded message, in stream order; realtime:
 * ticks paced by hal_now_us with absolute deadlines, catch-up, resync after falling 100 ms behind, messages handled
 * as they arrive (firmware_sim/server.py). Define before including:
 *   SERVE_APP_T                  the app struct (members `board` and `stats_key`)
 *   SERVE_ITEM_T                 the link's decoded item type
 *   SERVE_PUMP(app)              move what the port received into the link (non-blocking)
 *   SERVE_NEXT(app, item)        1 with the next decoded item, 0 when none waits
 *   SERVE_PROCESS(app, item)     hand one item to the board (or count and log an error)
 *   SERVE_FLUSH(app)             hand queued output to the port
 *   SERVE_BACKLOG(app)           bytes of output still queued
 *   SERVE_PENDING(app)           received input not yet decoded or taken
 *   SERVE_WAIT(app, until, wr)   sleep until `until` (hal_now_us), input, or (wr) room to write
 *   SERVE_LOCKSTEP_BACKLOG       lockstep: stop ticking while this much output waits
 *   SERVE_LINK_NAME              a string literal for the banner ("" serial, "CAN, ")
 *   SERVE_AFTER_TICK(app)        optional: link work after each lockstep tick (CAN: read the bus, so a flow
 *                                control is answered between ticks; the serial link defines nothing: no cost) */

#ifndef SERVE_AFTER_TICK
#define SERVE_AFTER_TICK(app) ((void)0)
#endif
#define RESYNC_BEHIND_US 100000 /* realtime: re-anchor the schedule when this far behind */
#define STATS_EVERY_TICKS 500u

static void serve_maybe_stats(SERVE_APP_T *app, int force) {
    const gs_board_t *b = &app->board;
    uint32_t key = b->link_errors * 2654435761u ^ b->late_count * 40503u ^ b->dropped_count * 69069u ^
                   b->watchdog_trips * 1103515245u ^ b->seq_gaps * 134775813u;
    if (force || key != app->stats_key) {
        app->stats_key = key;
        gs_board_log_stats(b);
    }
}

static void serve_tick(SERVE_APP_T *app) {
    gs_board_tick(&app->board);
    if (app->board.ticks % STATS_EVERY_TICKS == 0) serve_maybe_stats(app, 1);
    else if (app->board.ticks % gs_config_telemetry_every(&app->board.cfg) == 0) serve_maybe_stats(app, 0);
}

static void serve_lockstep(SERVE_APP_T *app) {
    gs_board_t *b = &app->board;
    SERVE_ITEM_T item;
    while (!hal_should_stop()) {
        unsigned ran = 0;
        /* (a stop ends the batch: each tick of a stopping board would wait out its bus reads) */
        while (gs_board_can_tick(b) && SERVE_BACKLOG(app) < SERVE_LOCKSTEP_BACKLOG && ran < 256u && !hal_should_stop()) {
            serve_tick(app);
            SERVE_AFTER_TICK(app);
            if (++ran % 16u == 0) SERVE_FLUSH(app);
        }
        unsigned handled = 0;
        int pending = 0;
        while (!gs_board_can_tick(b) && handled < 256u) {
            SERVE_PUMP(app);
            if (!SERVE_NEXT(app, &item)) break;
            SERVE_PROCESS(app, &item);
            handled++;
        }
        SERVE_FLUSH(app);
        SERVE_PUMP(app);
        pending = SERVE_PENDING(app);
        int blocked = (!gs_board_can_tick(b) && !pending) || SERVE_BACKLOG(app) >= SERVE_LOCKSTEP_BACKLOG;
        if (blocked) SERVE_WAIT(app, hal_now_us() + 500000u, SERVE_BACKLOG(app) > 0);
    }
}

static void serve_realtime(SERVE_APP_T *app) {
    gs_board_t *b = &app->board;
    SERVE_ITEM_T item;
    uint64_t start = hal_now_us();
    uint64_t next_tick = 0;
    b->clock_us = hal_now_us;
    b->clock_origin_us = (int64_t)start;
    while (!hal_should_stop()) {
        uint64_t deadline = start + next_tick * b->tick_us;
        if (hal_now_us() < deadline) SERVE_WAIT(app, deadline, SERVE_BACKLOG(app) > 0);
        SERVE_PUMP(app);
        while (SERVE_NEXT(app, &item)) SERVE_PROCESS(app, &item);
        while (start + next_tick * b->tick_us <= hal_now_us() && !hal_should_stop()) {
            uint64_t due = start + next_tick * b->tick_us;
            uint64_t late = hal_now_us() - due;
            uint64_t before = next_tick;
            next_tick++;
            if (late > RESYNC_BEHIND_US) next_tick += late / b->tick_us;
            uint64_t skipped = next_tick - before - 1u;
            serve_tick(app);
            if (skipped) gs_board_skip(b, skipped);
            if (late > b->tick_us) gs_board_note_overrun(b);
            /* another tick due at once: flush first. A board behind real time must not hold its
             * replies and reports until it has caught up: with every tick over its period,
             * re-anchoring does not end this loop, and the silence has no bound */
            if (start + next_tick * b->tick_us <= hal_now_us()) SERVE_FLUSH(app);
            SERVE_PUMP(app);
            while (SERVE_NEXT(app, &item)) SERVE_PROCESS(app, &item);
        }
        SERVE_FLUSH(app);
    }
}

/* The banner line printed when serving starts (SERVE_LINK_NAME: "" serial, "CAN, "). */
static void serve_banner(const gs_settings_t *cfg) {
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
    gs_log_str(" Hz, C firmware, " SERVE_LINK_NAME "jitter buffer ");
    gs_log_u64(GS_BUFFER_DEPTH);
    gs_log_str(" frames, schema ");
    gs_log_hex32(GS_SCHEMA_HASH);
    gs_log_end();
}

#undef RESYNC_BEHIND_US
#undef STATS_EVERY_TICKS
#undef SERVE_AFTER_TICK
