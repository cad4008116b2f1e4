/* The main loops over a CAN link: see gs_app_can.h. */
#include "gs_app_can.h"

#include "gs_can_hal.h"
#include "gs_hal.h"
#include "gs_log.h"

#define PUMP_MAX_FRAMES 512u /* frames read per pump (then the loop runs on) */

static uint32_t now32(void) { return (uint32_t)hal_now_us(); }

static void log_frame(void *ctx, const gs_can_frame_t *f, int is_tx) {
    gs_app_can_t *app = (gs_app_can_t *)ctx;
    if (!app->board.cfg.log_frames) return;
    static const char digits[] = "0123456789abcdef";
    char id[9];
    int k = 0;
    for (int shift = 28; shift >= 0; shift -= 4) {
        unsigned nib = (f->id >> shift) & 15u;
        if (nib || k || shift == 0) id[k++] = digits[nib];
    }
    id[k] = 0;
    gs_log_str(is_tx ? "C tx " : "C rx ");
    gs_log_i64(gs_board_time_us(&app->board));
    gs_log_str(" ");
    gs_log_str(id);
    gs_log_str(" ");
    gs_log_u64(f->flags);
    gs_log_str(" ");
    gs_log_hex(f->data, f->len);
    gs_log_end();
}

static int write_frame(void *ctx, const gs_can_frame_t *f) {
    (void)ctx;
    return hal_can_send(f);
}

static void on_send(void *ctx, const gs_msg_t *m, int periodic) {
    gs_app_can_t *app = (gs_app_can_t *)ctx;
    const char *why = "";
    if (!gs_can_link_send(&app->link, m, periodic, now32(), &why) && why[0]) {
        gs_log_str("board: cannot send ");
        gs_log_str(gs_msg_type_name(m->type));
        gs_log_str(" on CAN: ");
        gs_log_str(why);
        gs_log_end();
    }
}

/* The serial link's error kind a CAN error is reported as (protocol/can/decoder.py _SEAM_KIND). */
static const char *seam_kind(gs_can_item_kind_t k) {
    switch (k) {
    case GS_CAN_E_PAYLOAD:
    case GS_CAN_E_BULK: return "PAYLOAD";
    case GS_CAN_E_CRC: return "CRC";
    case GS_CAN_E_REMOTE:
    case GS_CAN_E_EXTENDED_ID: return "UNKNOWN_TYPE";
    default: return "LENGTH";
    }
}

void gs_app_can_process(gs_app_can_t *app, const gs_can_item_t *it) {
    gs_board_t *b = &app->board;
    if (it->kind != GS_CAN_ITEM_MESSAGE) {
        gs_board_on_link_error(b);
        gs_log_str("board: link error ");
        gs_log_str(seam_kind(it->kind));
        gs_log_str(": CAN ");
        gs_log_str(gs_can_item_kind_name(it->kind));
        gs_log_str(": ");
        gs_log_str(it->why ? it->why : "");
        gs_log_end();
        return;
    }
    gs_board_handle(b, &it->msg, it->seq, gs_board_time_us(b));
}

void gs_app_can_pump(gs_app_can_t *app) {
    gs_can_frame_t f;
    for (unsigned i = 0; i < PUMP_MAX_FRAMES && gs_can_link_can_take(&app->link) && hal_can_recv(&f); i++)
        gs_can_link_rx(&app->link, &f, now32());
}

void gs_app_can_flush(gs_app_can_t *app) { gs_can_link_flush(&app->link, now32()); }

/* After each lockstep tick: read what the bus brought (decoded into the item ring, taken in stream order later:
 * lockstep semantics unchanged) and, while an ISO-TP transfer is under way, send at once what it made. A flow
 * control left unread while the board ticked on (up to 256 ticks a batch, each with its plant round trip: ~2 ms in
 * UML) timed out transfers the host had answered in time, and the host's N_Cr ran out waiting for frames the
 * board held. One non-blocking read per tick while a transfer is under way, every 4th tick otherwise. */
static void after_tick(gs_app_can_t *app) {
    int busy = gs_isotp_busy(&app->link.isotp);
    if (!busy && app->board.ticks % 4u != 0) return; /* idle ISO-TP: a host's First Frame is answered within 4 ticks */
    gs_app_can_pump(app);
    if (busy || gs_isotp_busy(&app->link.isotp)) gs_can_link_flush(&app->link, now32());
}

static void wait_io(gs_app_can_t *app, uint64_t until, int want_write) {
    long io = gs_can_link_next_io_us(&app->link, now32());
    if (io >= 0) {
        uint64_t due = hal_now_us() + (uint64_t)io;
        if (due < until) until = due;
    }
    hal_can_wait(until, want_write);
}

#define SERVE_APP_T gs_app_can_t
#define SERVE_ITEM_T gs_can_item_t
#define SERVE_PUMP(app) gs_app_can_pump(app)
#define SERVE_NEXT(app, item) gs_can_link_next(&(app)->link, (item))
#define SERVE_PROCESS(app, item) gs_app_can_process((app), (item))
#define SERVE_FLUSH(app) gs_app_can_flush(app)
#define SERVE_BACKLOG(app) gs_can_link_backlog(&(app)->link)
#define SERVE_PENDING(app) gs_can_link_pending(&(app)->link)
#define SERVE_WAIT(app, until, wr) wait_io((app), (until), (wr))
#define SERVE_LOCKSTEP_BACKLOG GS_CAN_LOCKSTEP_BACKLOG
#define SERVE_LINK_NAME "CAN, "
#define SERVE_AFTER_TICK(app) after_tick(app)
#include "gs_serve.h"

void gs_app_can_tick(gs_app_can_t *app) { serve_tick(app); }

/* A lockstep board's ISO-TP timers count board time (gs_isotp.h board clock mode): the host answers a First Frame
 * before it lets the board run further (board time never passes a frame the host has not sent, and the host reads
 * the board's frames in order), so a host that is slow in wall time (a collection, a starved process in UML)
 * times out no transfer, and the run's bytes do not depend on it. */
static uint32_t board_time32(void *ctx) { return (uint32_t)gs_board_time_us(&((gs_app_can_t *)ctx)->board); }

int gs_app_can_init(gs_app_can_t *app, const gs_settings_t *cfg, unsigned node, int fd) {
    gs_can_link_init(&app->link, node, fd, write_frame, log_frame, app);
    if (cfg->lockstep) {
        app->link.isotp.board_now = board_time32;
        app->link.isotp.board_ctx = app;
    }
    gs_board_init(&app->board, cfg, on_send, app);
    app->stats_key = 0;
    return gs_board_boot(&app->board);
}

int gs_app_can_run(gs_app_can_t *app, const gs_settings_t *cfg, unsigned node, int fd) {
    int refused = gs_app_can_init(app, cfg, node, fd);
    if (refused) return refused; /* a boot check failed: its line is logged, torque is off; nothing is served */
    serve_banner(cfg);
    if (cfg->lockstep) serve_lockstep(app);
    else serve_realtime(app);
    gs_board_shutdown(&app->board); /* a stop (SIGTERM/SIGINT natively) leaves no servo under torque */
    gs_can_link_flush(&app->link, now32());
    serve_maybe_stats(app, 1);
    return 0;
}
