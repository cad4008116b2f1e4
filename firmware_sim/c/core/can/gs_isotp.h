/* ISO 15765-2 (ISO-TP) over CAN frames, sans-I/O: the state machine of can-isotp 2.x's TransportLayerLogic
 * with the exact parameters of protocol/can/isotp_link.py (both ends of the GhostShell link use those):
 * normal 11-bit addressing (receive on `rxid`, transmit on `txid`), block size 0 and STmin 0 in the flow
 * controls it sends, frames padded with 0xCC to 8 bytes (classic) or 64 (CAN FD: tx_data_length 64), a First
 * Frame announcing more than 4095 bytes answered with an Overflow flow control, wait frames refused
 * (wftmax 0), N_Bs (flow-control wait) and N_Cr (next consecutive frame) GS_ISOTP_TIMEOUT_US = 200 ms
 * (ISOTP_TIMEOUT_MS). Frame formats (ISO 15765-2:2016 clause 9.6): single frame 0x0L (FD beyond 7 bytes:
 * 0x00 LL), first frame 0x1L LL (0x10 00 + 32-bit length beyond 4095), consecutive frame 0x2N, flow control
 * 0x3S BS STmin.
 *
 * gs_isotp_feed() queues a received frame (id == rxid, standard); gs_isotp_poll(now_us) runs the state machine
 * as can-isotp's process() does: frames to send go to `emit` in order, each completed unit to `on_unit`.
 * Errors are counted (`errors`, `fc_timeouts` of them) with the last one's text. Bounded: GS_ISOTP_TXQ units
 * waiting to be sent, GS_ISOTP_INBOX received frames, a received unit kept up to GS_ISOTP_RX_KEEP bytes (a
 * longer one is still received to its end, as can-isotp accepts 4095 bytes, and handed on as truncated). */
#ifndef GS_ISOTP_H
#define GS_ISOTP_H

#include <stddef.h>
#include <stdint.h>

#include "gs_can.h"

#define GS_ISOTP_TIMEOUT_US 200000u
/* ISO 15765-2's N_Bs/N_Cr (1 000 ms, ISOTP_BACKSTOP_MS): in board clock mode, the wall-clock limit */
#define GS_ISOTP_BACKSTOP_US 1000000u
#define GS_ISOTP_MAX_FRAME 4095u
#ifndef GS_ISOTP_TXQ
#define GS_ISOTP_TXQ 16u
#endif
#define GS_ISOTP_TX_MAX GS_CAN_BULK_MAX
#define GS_ISOTP_INBOX 32u
#define GS_ISOTP_RX_KEEP 512u

typedef void (*gs_isotp_emit_fn)(void *ctx, const gs_can_frame_t *f);
/* `truncated`: the unit was longer than GS_ISOTP_RX_KEEP (only its start is in `data`). */
typedef void (*gs_isotp_unit_fn)(void *ctx, const uint8_t *data, size_t n, int truncated);

typedef struct {
    uint32_t start_us, start_board_us; /* start_board_us: board time at the start (board clock mode) */
    uint32_t timeout_us;
    uint8_t running;
} gs_isotp_timer_t;

/* Board time now (us), for a lockstep board's timers (gs_isotp_t.board_now). */
typedef uint32_t (*gs_isotp_clock_fn)(void *ctx);

typedef struct {
    uint32_t rxid, txid;
    uint8_t fd;
    gs_isotp_emit_fn emit;
    gs_isotp_unit_fn on_unit;
    void *ctx;
    /* receive */
    uint8_t rx_state; /* 0 idle, 1 waiting for consecutive frames */
    uint8_t last_seqnum;
    uint8_t actual_rxdl;
    uint32_t rx_frame_length, rx_count;
    uint8_t rx_buf[GS_ISOTP_RX_KEEP];
    gs_isotp_timer_t timer_rx_cf;
    uint8_t pending_fc, pending_fc_status;
    uint8_t have_fc, fc_status, fc_bs, fc_stmin; /* the last flow control received, for the transmitter */
    uint32_t fc_stmin_us, fc_at_us, fc_board_at_us; /* fc_at_us: the flow control's arrival (fc_board_at_us: board time) */
    gs_can_frame_t inbox[GS_ISOTP_INBOX];
    uint32_t inbox_at[GS_ISOTP_INBOX]; /* each waiting frame's arrival (us, the poll's clock) */
    uint32_t inbox_board_at[GS_ISOTP_INBOX]; /* and the board time then (board clock mode) */
    uint32_t rx_board_at; /* the board-time arrival of the frame in hand */
    /* Board clock mode (a lockstep board; NULL: off): N_Bs and N_Cr count board time from board_now(board_ctx),
     * with GS_ISOTP_BACKSTOP_US of the poll's clock as a backstop for a host that went away (isotp_link.py). */
    gs_isotp_clock_fn board_now;
    void *board_ctx;
    uint8_t inbox_head, inbox_len;
    /* transmit */
    uint8_t tx_state; /* 0 idle, 1 waiting for a flow control, 2 sending consecutive frames */
    uint8_t tx_seqnum;
    uint8_t remote_bs, tx_block_counter;
    gs_isotp_timer_t timer_rx_fc, timer_stmin;
    uint8_t active;
    uint16_t active_len, active_pos;
    uint8_t active_data[GS_ISOTP_TX_MAX];
    uint8_t txq[GS_ISOTP_TXQ][GS_ISOTP_TX_MAX];
    uint16_t txq_len[GS_ISOTP_TXQ];
    uint8_t txq_head, txq_n;
    /* errors */
    uint32_t errors, fc_timeouts;
    const char *last_error;
} gs_isotp_t;

void gs_isotp_init(gs_isotp_t *t, uint32_t rxid, uint32_t txid, int fd, gs_isotp_emit_fn emit, gs_isotp_unit_fn on_unit,
                   void *ctx);
/* Queue one unit to send (1..GS_ISOTP_TX_MAX bytes); 0, or -1 when GS_ISOTP_TXQ units already wait. */
int gs_isotp_send(gs_isotp_t *t, const uint8_t *data, size_t n);
/* A received frame on rxid that arrived at `at_us` (the poll's clock; a full inbox drops it, counted as an error).
 * Its timeouts are judged at `at_us`, not when a later poll reaches it: a loop that read the bus late (a long
 * lockstep batch) loses no transfer whose frames came in time (protocol/can/isotp_link.py does the same). */
void gs_isotp_feed(gs_isotp_t *t, const gs_can_frame_t *f, uint32_t at_us);
/* Advance the state machine at `now_us` (any monotonic microsecond clock). */
void gs_isotp_poll(gs_isotp_t *t, uint32_t now_us);
/* A frame this link emitted has gone on the bus at `now_us` (the transmit confirmation, ISO 15765-2 clause 9.7:
 * N_Bs runs from a First Frame's, N_Cr from a flow control's): the waiting timer restarts there, so a frame that
 * queued behind others on its way out does not eat into the peer's time to answer. */
void gs_isotp_sent(gs_isotp_t *t, const gs_can_frame_t *f, uint32_t now_us);
/* A transfer is under way either way (poll again within a few ms: its timers). */
int gs_isotp_busy(const gs_isotp_t *t);
/* Units queued or being sent (protocol.can.engine.CanEngine.bulk_waiting). */
unsigned gs_isotp_waiting(const gs_isotp_t *t);
/* Sending: queued units or a transfer under way (can-isotp's transmitting()). */
int gs_isotp_transmitting(const gs_isotp_t *t);
unsigned gs_isotp_queued(const gs_isotp_t *t);

#endif
