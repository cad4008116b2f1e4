#include "gs_app.h"

#include "gs_hal.h"
#include "gs_log.h"

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
    /* link.block still holds the frame gs_link_next decoded in place: a well-formed CONFIG with an unknown
       key is answered (NACK BAD_VALUE), not counted as a link error */
    if (it->kind == GS_RX_PAYLOAD && gs_board_unknown_config(b, app->link.block, it->seq, gs_board_time_us(b))) return;
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

#define SERVE_APP_T gs_app_t
#define SERVE_ITEM_T gs_rx_item_t
#define SERVE_PUMP(app) gs_link_pump_rx(&(app)->link)
#define SERVE_NEXT(app, item) gs_link_next(&(app)->link, (item))
#define SERVE_PROCESS(app, item) gs_app_process((app), (item))
#define SERVE_FLUSH(app) gs_link_flush(&(app)->link)
#define SERVE_BACKLOG(app) gs_link_backlog(&(app)->link)
#define SERVE_PENDING(app) ((app)->link.rx_len > 0)
#define SERVE_WAIT(app, until, wr) hal_wait((until), (wr))
#define SERVE_LOCKSTEP_BACKLOG GS_LOCKSTEP_BACKLOG
#define SERVE_LINK_NAME ""
#include "gs_serve.h"

void gs_app_tick(gs_app_t *app) { serve_tick(app); }

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
    serve_banner(cfg);
    if (cfg->lockstep) serve_lockstep(app);
    else serve_realtime(app);
    gs_board_shutdown(&app->board); /* a stop (SIGTERM/SIGINT natively) leaves no servo under torque */
    serve_maybe_stats(app, 1);
    return 0;
}
