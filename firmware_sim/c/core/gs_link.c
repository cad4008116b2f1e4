#include "gs_link.h"

#include "gs_cobs.h"
#include "gs_crc.h"
#include "gs_hal.h"

static uint8_t last_tx[GS_MAX_WIRE_FRAME + 2];
static size_t last_tx_len;

void gs_link_init(gs_link_t *l) {
    l->rx_head = l->rx_len = 0;
    l->block_len = 0;
    l->skipping = 0;
    for (int k = 0; k < GS_RX_KINDS; k++) l->errors[k] = 0;
    l->tx_head = l->tx_len = 0;
    l->tx_seq = 0;
    l->tx_dropped = 0;
    l->on_raw = 0;
    l->on_raw_ctx = 0;
}

const char *gs_rx_kind_name(gs_rx_kind_t k) {
    static const char *names[GS_RX_KINDS] = {"FRAME", "COBS", "LENGTH", "CRC", "VERSION",
                                             "UNKNOWN_TYPE", "PAYLOAD", "OVERSIZE"};
    return (unsigned)k < GS_RX_KINDS ? names[k] : "?";
}

size_t gs_link_pump_rx(gs_link_t *l) {
    size_t total = 0;
    while (l->rx_len < GS_RX_RING) {
        size_t tail = (size_t)(l->rx_head + l->rx_len) % GS_RX_RING;
        size_t room = GS_RX_RING - l->rx_len;
        if (room > GS_RX_RING - tail) room = GS_RX_RING - tail; /* contiguous part */
        size_t got = hal_host_read(&l->rx_ring[tail], room);
        if (got == 0) break;
        l->rx_len = (uint16_t)(l->rx_len + got);
        total += got;
    }
    return total;
}

/* Decode one delimited block (protocol.framing._decode_block, same checks in the same order). */
static void decode_block(gs_link_t *l, gs_rx_item_t *it) {
    size_t n = l->block_len;
    it->raw_len = n;
    it->seq = 0;
    if (l->on_raw) l->on_raw(l->on_raw_ctx, l->block, n);
    uint8_t *body = l->block; /* decoded in place: COBS output is never longer than its input */
    long m = gs_cobs_decode(body, n);
    if (m < 0) {
        it->kind = GS_RX_COBS;
        it->why = "invalid COBS";
        return;
    }
    size_t len = (size_t)m;
    if (len < GS_FRAME_HEADER_SIZE + GS_FRAME_CRC_SIZE) {
        it->kind = GS_RX_LENGTH;
        it->why = "too short for a frame";
        return;
    }
    uint16_t crc_rx = (uint16_t)(body[len - 2] | (body[len - 1] << 8));
    if (crc_rx != gs_crc16_x25(body, len - 2)) {
        it->kind = GS_RX_CRC;
        it->why = "CRC mismatch";
        return;
    }
    uint8_t version = body[0], type = body[1], length = body[4];
    it->seq = (uint16_t)(body[2] | (body[3] << 8));
    if (version != GS_PROTOCOL_VERSION) {
        it->kind = GS_RX_VERSION;
        it->why = "another protocol version";
        return;
    }
    size_t n_payload = len - GS_FRAME_HEADER_SIZE - GS_FRAME_CRC_SIZE;
    if (length != n_payload) {
        it->kind = GS_RX_LENGTH;
        it->why = "length field does not match the payload";
        return;
    }
    if (!gs_is_msg_type(type)) {
        it->kind = GS_RX_UNKNOWN_TYPE;
        it->why = "unknown message type";
        return;
    }
    if (gs_decode_payload(type, &body[GS_FRAME_HEADER_SIZE], n_payload, &it->msg, &it->why) != GS_OK) {
        it->kind = GS_RX_PAYLOAD;
        return;
    }
    it->kind = GS_RX_FRAME;
}

int gs_link_next(gs_link_t *l, gs_rx_item_t *it) {
    while (l->rx_len) {
        uint8_t b = l->rx_ring[l->rx_head];
        l->rx_head = (uint16_t)((l->rx_head + 1u) % GS_RX_RING);
        l->rx_len--;
        if (l->skipping) {
            if (b == 0) l->skipping = 0;
            continue;
        }
        if (b == 0) {
            if (l->block_len == 0) continue; /* idle delimiter */
            decode_block(l, it);
            l->block_len = 0;
            if (it->kind != GS_RX_FRAME) l->errors[it->kind]++;
            return 1;
        }
        if (l->block_len < GS_MAX_FRAME_BYTES) {
            l->block[l->block_len++] = b;
            continue;
        }
        /* more than GS_MAX_FRAME_BYTES without a delimiter: one OVERSIZE, then skip to the next 0x00 */
        it->kind = GS_RX_OVERSIZE;
        it->why = "no delimiter within the frame limit; skipping to the next 0x00";
        it->raw_len = l->block_len;
        if (l->on_raw) l->on_raw(l->on_raw_ctx, l->block, l->block_len);
        it->seq = 0;
        l->block_len = 0;
        l->skipping = 1;
        l->errors[GS_RX_OVERSIZE]++;
        return 1;
    }
    return 0;
}

size_t gs_link_backlog(const gs_link_t *l) { return l->tx_len; }

int gs_link_send(gs_link_t *l, const gs_msg_t *msg, size_t limit) {
    uint8_t raw[GS_FRAME_HEADER_SIZE + GS_MAX_PAYLOAD + GS_FRAME_CRC_SIZE];
    int n = gs_encode_payload(msg, &raw[GS_FRAME_HEADER_SIZE], GS_MAX_PAYLOAD);
    if (n < 0) {
        l->tx_dropped++;
        return 0;
    }
    raw[0] = GS_PROTOCOL_VERSION;
    raw[1] = msg->type;
    raw[2] = (uint8_t)(l->tx_seq & 0xFFu);
    raw[3] = (uint8_t)(l->tx_seq >> 8);
    raw[4] = (uint8_t)n;
    size_t len = GS_FRAME_HEADER_SIZE + (size_t)n;
    uint16_t crc = gs_crc16_x25(raw, len);
    raw[len++] = (uint8_t)(crc & 0xFFu);
    raw[len++] = (uint8_t)(crc >> 8);
    size_t w = gs_cobs_encode(raw, len, last_tx);
    last_tx[w++] = 0;
    if (limit > GS_TX_RING) limit = GS_TX_RING;
    if (l->tx_len + w > limit) {
        l->tx_dropped++;
        return 0;
    }
    for (size_t i = 0; i < w; i++) l->tx_ring[(l->tx_head + l->tx_len + i) % GS_TX_RING] = last_tx[i];
    l->tx_len = (uint16_t)(l->tx_len + w);
    last_tx_len = w;
    l->tx_seq++;
    return 1;
}

const uint8_t *gs_link_last_tx(const gs_link_t *l, size_t *n) {
    (void)l;
    *n = last_tx_len;
    return last_tx;
}

size_t gs_link_flush(gs_link_t *l) {
    while (l->tx_len) {
        size_t chunk = GS_TX_RING - l->tx_head;
        if (chunk > l->tx_len) chunk = l->tx_len;
        size_t put = hal_host_write(&l->tx_ring[l->tx_head], chunk);
        if (put == 0) break;
        l->tx_head = (uint16_t)((l->tx_head + put) % GS_TX_RING);
        l->tx_len = (uint16_t)(l->tx_len - put);
    }
    return l->tx_len;
}
