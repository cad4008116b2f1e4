/* The board's end of a CAN link, sans-I/O: the engine (fixed-layout frames and ISO-TP in the robot's
 * generated layout table, protocol/can/engine.py CanEngine role "board") and the board's policy of
 * firmware_sim/transports/can.py CanBoardTransport:
 *
 * - transmit priority as a CAN controller's: the lowest identifier first, frames of one identifier (the parts
 *   of a message, the frames of an ISO-TP unit) in order (a heap keyed by identifier, then queue order);
 * - periodic bulk reports (SIM_STATE; TELEMETRY where the table has no fixed layout: classic CAN above 27
 *   servos) newest-wins under the sequence number of the one they replace, handed to ISO-TP only while it is
 *   idle and only while a host is heard (a First Frame nobody answers costs N_Bs and is excused, not an error);
 * - a NACK to a SERVO_FRAME, or any NACK while GS_CAN_NACK_BULK_BACKLOG units wait, goes fixed without its
 *   detail text;
 * - a refused write (SocketCAN's ENOBUFS: the interface's tx queue is full) keeps the frame at the head and
 *   retries after 1 ms doubling to 20 ms: nothing is lost or reordered.
 *
 * Received frames are decoded as they are read (ISO-TP answers at once, as the Python board does) into a
 * bounded item ring that the main loop takes messages from in stream order; the port stops reading while
 * that ring is nearly full (the socket's receive queue holds the rest). Everything is bounded, no malloc. */
#ifndef GS_CAN_LINK_H
#define GS_CAN_LINK_H

#include <stddef.h>
#include <stdint.h>

#include "gs_can.h"
#include "gs_isotp.h"

#ifndef GS_CAN_TXQ
#define GS_CAN_TXQ 1536u /* frames waiting for the bus (> LOCKSTEP backlog + a telemetry burst) */
#endif
#ifndef GS_CAN_ITEMS
#define GS_CAN_ITEMS 64u /* decoded items waiting for the core */
#endif
#define GS_CAN_FRAME_COST 16u        /* backlog bytes per queued frame (firmware_sim/transports/can.py FRAME_COST) */
#define GS_CAN_NACK_BULK_BACKLOG 8u  /* bulk units waiting beyond which a NACK goes fixed without its text */
#define GS_CAN_BACKOFF_MIN_US 1000u
#define GS_CAN_BACKOFF_MAX_US 20000u
/* firmware_sim/server.py: reports dropped past this backlog, replies past MAX, lockstep stops ticking at LOCKSTEP */
#define GS_CAN_TELEMETRY_BACKLOG (16u * 1024u)
#define GS_CAN_MAX_BACKLOG (GS_CAN_TXQ * GS_CAN_FRAME_COST - 64u * GS_CAN_FRAME_COST)
#define GS_CAN_LOCKSTEP_BACKLOG (8u * 1024u)

/* Hand one frame to the bus: 1 sent, 0 refused now (retried later, in order), -1 the bus cannot carry it (dropped). */
typedef int (*gs_can_write_fn)(void *ctx, const gs_can_frame_t *f);
/* A frame received (is_tx 0) or handed to the bus (is_tx 1): the frame log. */
typedef void (*gs_can_log_fn)(void *ctx, const gs_can_frame_t *f, int is_tx);

typedef struct {
    uint8_t used;
    uint8_t type;
    uint16_t seq;
    uint16_t len;
    uint8_t unit[GS_CAN_BULK_MAX];
} gs_can_periodic_t;

typedef struct {
    uint8_t node, fd;
    gs_can_decoder_t dec;
    gs_isotp_t isotp;
    uint32_t now_us;             /* the clock of the current call (ISO-TP timers) */
    uint32_t bulk_errors_reported;
    /* items for the core */
    gs_can_item_t items[GS_CAN_ITEMS];
    uint16_t items_head, items_n;
    uint32_t items_dropped;
    /* transmit heap: (id, order) */
    gs_can_frame_t txq[GS_CAN_TXQ];
    uint32_t txq_order[GS_CAN_TXQ];
    uint32_t txq_n, order;
    uint8_t retry_pending;
    uint32_t retry_at_us, backoff_us;
    gs_can_write_fn write;
    gs_can_log_fn log;
    void *ctx;
    /* periodic bulk reports: at most one per type, oldest first */
    gs_can_periodic_t periodic[2];
    uint8_t periodic_in_flight;
    uint8_t host_heard;
    uint16_t tx_seq;
    /* counters (firmware_sim/transports/can.py's names) */
    uint32_t tx_frames, tx_retries, tx_dropped, rx_frames;
    uint32_t periodic_replaced, periodic_unheard, periodic_unanswered, nack_details_dropped, send_refused;
} gs_can_link_t;

void gs_can_link_init(gs_can_link_t *l, unsigned node, int fd, gs_can_write_fn write, gs_can_log_fn log, void *ctx);
/* Room for the items one more received frame can make (the port reads a frame only then). */
int gs_can_link_can_take(const gs_can_link_t *l);
/* One frame from the bus (after the port's node filter), decoded at once. */
void gs_can_link_rx(gs_can_link_t *l, const gs_can_frame_t *f, uint32_t now_us);
/* The next decoded item, in stream order: 1 with `item`, 0 when none waits. */
int gs_can_link_next(gs_can_link_t *l, gs_can_item_t *item);
int gs_can_link_pending(const gs_can_link_t *l);
/* Queue a reply or report with the next sequence number (the board's policy above; the server's backlog limits:
 * a report past GS_CAN_TELEMETRY_BACKLOG, a reply past GS_CAN_MAX_BACKLOG is dropped). 1 queued (or replaced a
 * waiting report), 0 dropped or refused (one line logged by the caller for a refusal: `why`). */
int gs_can_link_send(gs_can_link_t *l, const gs_msg_t *m, int periodic, uint32_t now_us, const char **why);
/* Advance ISO-TP and hand queued frames to `write` by priority (until it refuses: backoff). */
void gs_can_link_flush(gs_can_link_t *l, uint32_t now_us);
/* Backlog in bytes as firmware_sim/transports/can.py counts it (FRAME_COST per frame, 8 frames per waiting unit). */
size_t gs_can_link_backlog(const gs_can_link_t *l);
/* Microseconds from `now_us` until the link needs a flush/poll again (ISO-TP timers, a backoff), or -1: none. */
long gs_can_link_next_io_us(const gs_can_link_t *l, uint32_t now_us);

#endif
