/* The board's end of a CAN link: see gs_can_link.h (firmware_sim/transports/can.py CanBoardTransport). */
#include "gs_can_link.h"

#include <string.h>

/* ---- transmit heap: lowest identifier first, then queue order ---- */

static int before(const gs_can_link_t *l, uint32_t a, uint32_t b) {
    if (l->txq[a].id != l->txq[b].id) return l->txq[a].id < l->txq[b].id;
    return l->txq_order[a] < l->txq_order[b];
}

static void swap(gs_can_link_t *l, uint32_t a, uint32_t b) {
    gs_can_frame_t f = l->txq[a];
    uint32_t o = l->txq_order[a];
    l->txq[a] = l->txq[b];
    l->txq_order[a] = l->txq_order[b];
    l->txq[b] = f;
    l->txq_order[b] = o;
}

static void enqueue(void *ctx, const gs_can_frame_t *f) {
    gs_can_link_t *l = (gs_can_link_t *)ctx;
    if (l->txq_n >= GS_CAN_TXQ) {
        l->tx_dropped++;
        return;
    }
    uint32_t i = l->txq_n++;
    l->txq[i] = *f;
    l->txq_order[i] = l->order++;
    while (i > 0) {
        uint32_t p = (i - 1u) / 2u;
        if (!before(l, i, p)) break;
        swap(l, i, p);
        i = p;
    }
}

static void pop(gs_can_link_t *l) {
    if (!l->txq_n) return;
    l->txq_n--;
    if (!l->txq_n) return;
    l->txq[0] = l->txq[l->txq_n];
    l->txq_order[0] = l->txq_order[l->txq_n];
    uint32_t i = 0;
    for (;;) {
        uint32_t a = 2u * i + 1u, b = a + 1u, m = i;
        if (a < l->txq_n && before(l, a, m)) m = a;
        if (b < l->txq_n && before(l, b, m)) m = b;
        if (m == i) break;
        swap(l, i, m);
        i = m;
    }
}

/* ---- items ---- */

static gs_can_item_t *item_slot(gs_can_link_t *l) {
    if (l->items_n >= GS_CAN_ITEMS) return NULL;
    return &l->items[(l->items_head + l->items_n) % GS_CAN_ITEMS];
}

static void on_unit(void *ctx, const uint8_t *data, size_t n, int truncated) {
    gs_can_link_t *l = (gs_can_link_t *)ctx;
    gs_can_item_t *it = item_slot(l);
    if (!it) {
        l->items_dropped++;
        return;
    }
    if (truncated) {
        l->dec.errors[GS_CAN_E_BULK]++;
        it->kind = GS_CAN_E_BULK;
        it->why = "ISO-TP unit longer than any message";
        it->raw_len = n;
        it->seq = 0;
    } else {
        gs_can_decoder_feed_bulk(&l->dec, data, n, it);
    }
    l->items_n++;
}

void gs_can_link_init(gs_can_link_t *l, unsigned node, int fd, gs_can_write_fn write, gs_can_log_fn log, void *ctx) {
    memset(l, 0, sizeof *l);
    l->node = (uint8_t)node;
    l->fd = fd ? 1u : 0u;
    gs_can_decoder_init(&l->dec, node, 1);
    /* the board receives ISO-TP on BULK_TO_BOARD and sends on BULK_TO_HOST */
    gs_isotp_init(&l->isotp, GS_CAN_ID(GS_CAN_FN_BULK_TO_BOARD, node), GS_CAN_ID(GS_CAN_FN_BULK_TO_HOST, node), fd, enqueue,
                  on_unit, l);
    l->write = write;
    l->log = log;
    l->ctx = ctx;
    l->backoff_us = GS_CAN_BACKOFF_MIN_US;
}

/* ISO-TP advanced: a flow-control timeout of a periodic report nobody answered is excused (no host listens);
 * any other new ISO-TP error becomes one BULK error item (protocol/can/engine.py poll). */
static void poll_isotp(gs_can_link_t *l) {
    uint32_t timeouts = l->isotp.fc_timeouts;
    gs_isotp_poll(&l->isotp, l->now_us);
    uint32_t fresh = l->isotp.fc_timeouts - timeouts;
    if (fresh && l->periodic_in_flight) {
        l->periodic_unanswered += fresh;
        l->host_heard = 0;
        l->bulk_errors_reported += fresh;
    }
    if (l->isotp.errors > l->bulk_errors_reported) {
        l->bulk_errors_reported = l->isotp.errors;
        gs_can_item_t *it = item_slot(l);
        if (it) {
            l->dec.errors[GS_CAN_E_BULK]++;
            it->kind = GS_CAN_E_BULK;
            it->why = l->isotp.last_error; /* "ISO-TP: ..." as protocol/can/engine.py */
            it->raw_len = 0;
            it->seq = 0;
            l->items_n++;
        } else {
            l->items_dropped++;
        }
    }
    if (l->periodic_in_flight && !gs_isotp_transmitting(&l->isotp)) l->periodic_in_flight = 0;
}

int gs_can_link_can_take(const gs_can_link_t *l) { return l->items_n + GS_CAN_MAX_ITEMS_PER_FRAME + 2u <= GS_CAN_ITEMS; }

void gs_can_link_rx(gs_can_link_t *l, const gs_can_frame_t *f, uint32_t now_us) {
    l->now_us = now_us;
    l->rx_frames++;
    l->host_heard = 1;
    if (l->log) l->log(l->ctx, f, 0);
    if (f->id == l->isotp.rxid && !(f->flags & GS_CAN_FLAG_EXT)) {
        gs_isotp_feed(&l->isotp, f, now_us);
        poll_isotp(l);
        return;
    }
    gs_can_item_t tmp[GS_CAN_MAX_ITEMS_PER_FRAME];
    size_t n = gs_can_decoder_feed(&l->dec, f, tmp);
    for (size_t i = 0; i < n; i++) {
        gs_can_item_t *it = item_slot(l);
        if (!it) {
            l->items_dropped++;
            continue;
        }
        *it = tmp[i];
        l->items_n++;
    }
}

int gs_can_link_next(gs_can_link_t *l, gs_can_item_t *item) {
    if (!l->items_n) return 0;
    *item = l->items[l->items_head];
    l->items_head = (uint16_t)((l->items_head + 1u) % GS_CAN_ITEMS);
    l->items_n--;
    return 1;
}

int gs_can_link_pending(const gs_can_link_t *l) { return l->items_n > 0; }

size_t gs_can_link_backlog(const gs_can_link_t *l) {
    return GS_CAN_FRAME_COST * ((size_t)l->txq_n + 8u * gs_isotp_waiting(&l->isotp));
}

static void start_periodic(gs_can_link_t *l) {
    int any = l->periodic[0].used || l->periodic[1].used;
    if (any && !l->host_heard) {
        /* a multi-frame transfer needs a receiver's flow control: with no host heard it could only time out */
        for (unsigned i = 0; i < 2u; i++)
            if (l->periodic[i].used) {
                l->periodic_unheard++;
                l->periodic[i].used = 0;
            }
        return;
    }
    if (any && !gs_isotp_transmitting(&l->isotp)) {
        gs_can_periodic_t *p = &l->periodic[0];
        if (!p->used) p = &l->periodic[1];
        (void)gs_isotp_send(&l->isotp, p->unit, p->len);
        p->used = 0;
        if (p == &l->periodic[0] && l->periodic[1].used) { /* keep oldest-first order */
            l->periodic[0] = l->periodic[1];
            l->periodic[1].used = 0;
        }
        l->periodic_in_flight = 1;
        poll_isotp(l);
    }
}

static int is_periodic_type(uint8_t type) { return type == GS_MSG_TYPE_TELEMETRY || type == GS_MSG_TYPE_SIM_STATE; }

int gs_can_link_send(gs_can_link_t *l, const gs_msg_t *m_in, int periodic, uint32_t now_us, const char **why) {
    l->now_us = now_us;
    *why = "";
    size_t backlog = gs_can_link_backlog(l);
    if (backlog > (periodic ? GS_CAN_TELEMETRY_BACKLOG : GS_CAN_MAX_BACKLOG)) return 0; /* dropped (the server's rule) */
    const gs_msg_t *m = m_in;
    gs_msg_t trimmed;
    if (m->type == GS_MSG_TYPE_NACK && m->u.nack.detail_len &&
        (m->u.nack.msg_type == GS_MSG_TYPE_SERVO_FRAME || gs_isotp_queued(&l->isotp) >= GS_CAN_NACK_BULK_BACKLOG)) {
        trimmed = *m;
        trimmed.u.nack.detail_len = 0;
        m = &trimmed;
        l->nack_details_dropped++;
    }
    uint16_t seq = l->tx_seq;
    if (gs_can_is_fixed(m, l->fd)) {
        gs_can_frame_t frames[GS_CAN_MAX_PARTS];
        int n = gs_can_encode_fixed(m, seq, l->node, l->fd, GS_CAN_SENDER_BOARD, frames, GS_CAN_MAX_PARTS, why);
        if (n < 0) {
            l->send_refused++;
            return 0;
        }
        for (int i = 0; i < n; i++) enqueue(l, &frames[i]);
        l->tx_seq++;
        return 1;
    }
    if (is_periodic_type(m->type)) {
        /* newest wins, under the sequence number of the one it replaces; waits until ISO-TP is idle */
        gs_can_periodic_t *slot = NULL;
        int replaced = 0;
        for (unsigned i = 0; i < 2u; i++)
            if (l->periodic[i].used && l->periodic[i].type == m->type) slot = &l->periodic[i];
        if (slot) {
            l->periodic_replaced++;
            seq = slot->seq;
            replaced = 1;
        } else {
            slot = !l->periodic[0].used ? &l->periodic[0] : &l->periodic[1];
        }
        int k = gs_can_encode_bulk(m, seq, slot->unit, sizeof slot->unit);
        if (k < 0) {
            *why = "the payload codec refuses it";
            l->send_refused++;
            return 0;
        }
        slot->used = 1;
        slot->type = m->type;
        slot->seq = seq;
        slot->len = (uint16_t)k;
        start_periodic(l);
        if (!replaced) l->tx_seq++;
        return 1;
    }
    uint8_t unit[GS_CAN_BULK_MAX];
    int k = gs_can_encode_bulk(m, seq, unit, sizeof unit);
    if (k < 0) {
        *why = "the payload codec refuses it";
        l->send_refused++;
        return 0;
    }
    if (gs_isotp_send(&l->isotp, unit, (size_t)k) != 0) {
        *why = "ISO-TP: bulk messages already waiting";
        l->send_refused++;
        return 0;
    }
    poll_isotp(l);
    l->tx_seq++;
    return 1;
}

void gs_can_link_flush(gs_can_link_t *l, uint32_t now_us) {
    l->now_us = now_us;
    if (gs_isotp_busy(&l->isotp)) poll_isotp(l);
    start_periodic(l);
    if (l->retry_pending && (int32_t)(now_us - l->retry_at_us) < 0) return;
    l->retry_pending = 0;
    while (l->txq_n) {
        const gs_can_frame_t *f = &l->txq[0];
        int sent = l->write ? l->write(l->ctx, f) : 1;
        if (sent == 0) {
            l->tx_retries++;
            l->retry_pending = 1;
            l->retry_at_us = now_us + l->backoff_us;
            l->backoff_us = l->backoff_us * 2u > GS_CAN_BACKOFF_MAX_US ? GS_CAN_BACKOFF_MAX_US : l->backoff_us * 2u;
            return;
        }
        if (sent > 0) {
            l->tx_frames++;
            if (f->id == l->isotp.txid && f->len) gs_isotp_sent(&l->isotp, f, now_us);
            if (l->log) l->log(l->ctx, f, 1);
        } else {
            l->tx_dropped++;
        }
        pop(l);
        l->backoff_us = GS_CAN_BACKOFF_MIN_US;
    }
}

long gs_can_link_next_io_us(const gs_can_link_t *l, uint32_t now_us) {
    long due = -1;
    if (l->retry_pending) {
        int32_t d = (int32_t)(l->retry_at_us - now_us);
        due = d > 0 ? d : 0;
    }
    if (gs_isotp_busy(&l->isotp) || l->periodic[0].used || l->periodic[1].used) {
        if (due < 0 || due > 2000) due = 2000;
    }
    return due;
}
