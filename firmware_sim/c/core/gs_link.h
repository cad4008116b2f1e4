/* The host link: the serial framing of protocol/framing.py (COBS frames ended by 0x00; header
 * version u8, type u8, seq u16 LE, length u8; payload; CRC-16/X-25 LE) on byte rings.
 *
 * Receive: bytes go into a ring as the UART delivers them (the ring's free space is the flow
 * control: a full ring is not read, so the host's writes block); gs_link_next() takes bytes out
 * only when the core wants the next message, so in lockstep messages take effect in stream order
 * whatever the chunking. Decoding follows protocol.framing.FrameDecoder: an undelimited run of
 * more than GS_MAX_FRAME_BYTES is one OVERSIZE error and is skipped to the next 0x00; every other
 * block is one frame or one error (COBS, LENGTH, CRC, VERSION, UNKNOWN_TYPE, PAYLOAD).
 * Transmit: gs_link_send() encodes a message into the TX ring (or reports no room). */
#ifndef GS_LINK_H
#define GS_LINK_H

#include <stddef.h>
#include <stdint.h>

#include "gs_config.h"
#include "gs_proto.h"

typedef enum {
    GS_RX_FRAME = 0,
    GS_RX_COBS,
    GS_RX_LENGTH,
    GS_RX_CRC,
    GS_RX_VERSION,
    GS_RX_UNKNOWN_TYPE,
    GS_RX_PAYLOAD,
    GS_RX_OVERSIZE,
    GS_RX_KINDS
} gs_rx_kind_t;

typedef struct {
    gs_rx_kind_t kind;
    uint16_t seq;
    gs_msg_t msg;            /* valid when kind == GS_RX_FRAME */
    size_t raw_len;          /* bytes of the block, without the delimiter */
    const char *why;         /* static reason text for errors */
} gs_rx_item_t;

typedef struct {
    uint8_t rx_ring[GS_RX_RING];
    uint16_t rx_head, rx_len;
    uint8_t block[GS_MAX_FRAME_BYTES]; /* the undelimited run being collected */
    uint16_t block_len;
    uint8_t skipping;                  /* after OVERSIZE: discard up to the next 0x00 */
    /* called with each block as received, before it is decoded in place (the frame log) */
    void (*on_raw)(void *ctx, const uint8_t *raw, size_t n);
    void *on_raw_ctx;
    uint32_t errors[GS_RX_KINDS];
    uint8_t tx_ring[GS_TX_RING];
    uint16_t tx_head, tx_len;
    uint16_t tx_seq;
    uint32_t tx_dropped;
} gs_link_t;

void gs_link_init(gs_link_t *l);
/* Move bytes from the host UART into the RX ring while it has room; returns the count. */
size_t gs_link_pump_rx(gs_link_t *l);
/* Decode buffered bytes up to the next complete frame or error; 1 with `item` filled, 0 if none. */
int gs_link_next(gs_link_t *l, gs_rx_item_t *item);
/* Encode `msg` with the next sequence number into the TX ring. Returns 1, or 0 (dropped, counted)
 * when fewer than `limit` bytes would be queued after it. */
int gs_link_send(gs_link_t *l, const gs_msg_t *msg, size_t limit);
/* Hand queued bytes to the host UART; returns the count still queued. */
size_t gs_link_flush(gs_link_t *l);
size_t gs_link_backlog(const gs_link_t *l);
const char *gs_rx_kind_name(gs_rx_kind_t k);
/* Wire bytes of the last frame gs_link_send queued (for the frame log). */
const uint8_t *gs_link_last_tx(const gs_link_t *l, size_t *n);

#endif
