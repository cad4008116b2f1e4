/* ISO-TP: see gs_isotp.h. The structure follows can-isotp 2.0's TransportLayerLogic.process(),
 * _process_rx() and _process_tx() step by step, so both ends emit the same frames in the same order. */
#include "gs_isotp.h"

#include <string.h>

enum { RX_IDLE = 0, RX_WAIT_CF = 1 };
enum { TX_IDLE = 0, TX_WAIT_FC = 1, TX_CF = 2 };
enum { FS_CTS = 0, FS_WAIT = 1, FS_OVERFLOW = 2 };
enum { PDU_SF = 0, PDU_FF = 1, PDU_CF = 2, PDU_FC = 3 };

#define PAD 0xCCu

static uint32_t board_now(const gs_isotp_t *t) { return t->board_now ? t->board_now(t->board_ctx) : 0u; }

static void timer_start_(const gs_isotp_t *t, gs_isotp_timer_t *tm, uint32_t now, uint32_t timeout_us) {
    tm->start_us = now;
    tm->start_board_us = board_now(t);
    tm->timeout_us = timeout_us;
    tm->running = 1;
}
#define timer_start(tm, now, timeout) timer_start_(t, (tm), (now), (timeout))

/* `now` is the time the timeout is judged at: a received frame's arrival, or the poll's now. A frame that arrived
 * before the timer started (it waited in the inbox while the timer was restarted) is never late: signed elapsed. */
static int timed_out_(const gs_isotp_t *t, const gs_isotp_timer_t *tm, uint32_t now, uint32_t board_at) {
    if (!tm->running) return 0;
    if (tm->timeout_us == 0) return 1;
    if (t->board_now) /* lockstep: board time, with the standard's wall-clock N_Bs/N_Cr as the backstop */
        return (int32_t)(board_at - tm->start_board_us) > (int32_t)tm->timeout_us ||
               (int32_t)(now - tm->start_us) > (int32_t)GS_ISOTP_BACKSTOP_US;
    return (int32_t)(now - tm->start_us) > (int32_t)tm->timeout_us;
}
/* judged now (the poll's time, and the board's time now) */
#define timed_out(tm, now) timed_out_(t, (tm), (now), board_now(t))

static void error(gs_isotp_t *t, const char *why) {
    t->errors++;
    t->last_error = why;
}

void gs_isotp_init(gs_isotp_t *t, uint32_t rxid, uint32_t txid, int fd, gs_isotp_emit_fn emit, gs_isotp_unit_fn on_unit,
                   void *ctx) {
    memset(t, 0, sizeof *t);
    t->rxid = rxid;
    t->txid = txid;
    t->fd = fd ? 1u : 0u;
    t->emit = emit;
    t->on_unit = on_unit;
    t->ctx = ctx;
    t->last_error = "";
}

static unsigned tx_dl(const gs_isotp_t *t) { return t->fd ? 64u : 8u; }

int gs_isotp_send(gs_isotp_t *t, const uint8_t *data, size_t n) {
    if (t->txq_n >= GS_ISOTP_TXQ || n > GS_ISOTP_TX_MAX) return -1;
    unsigned slot = (t->txq_head + t->txq_n) % GS_ISOTP_TXQ;
    memcpy(t->txq[slot], data, n);
    t->txq_len[slot] = (uint16_t)n;
    t->txq_n++;
    return 0;
}

void gs_isotp_feed(gs_isotp_t *t, const gs_can_frame_t *f, uint32_t at_us) {
    if (t->inbox_len >= GS_ISOTP_INBOX) {
        t->errors++;
        return;
    }
    unsigned k = (t->inbox_head + t->inbox_len) % GS_ISOTP_INBOX;
    gs_can_frame_t *slot = &t->inbox[k];
    t->inbox_at[k] = at_us;
    t->inbox_board_at[k] = board_now(t);
    *slot = *f;
    if (f->flags & GS_CAN_FLAG_RTR) slot->len = 0; /* a remote frame carries no data */
    if (slot->len > GS_CAN_MAX_DATA) slot->len = GS_CAN_MAX_DATA;
    t->inbox_len++;
}

void gs_isotp_sent(gs_isotp_t *t, const gs_can_frame_t *f, uint32_t now_us) {
    unsigned pci = f->len ? f->data[0] >> 4 : 0xFu;
    if (pci == PDU_FF && t->tx_state == TX_WAIT_FC && t->timer_rx_fc.running) timer_start(&t->timer_rx_fc, now_us, GS_ISOTP_TIMEOUT_US);
    if (pci == PDU_FC && t->rx_state == RX_WAIT_CF && t->timer_rx_cf.running) timer_start(&t->timer_rx_cf, now_us, GS_ISOTP_TIMEOUT_US);
}

int gs_isotp_transmitting(const gs_isotp_t *t) { return t->txq_n > 0 || t->tx_state != TX_IDLE; }
unsigned gs_isotp_queued(const gs_isotp_t *t) { return t->txq_n; }
unsigned gs_isotp_waiting(const gs_isotp_t *t) { return t->txq_n + (gs_isotp_transmitting(t) ? 1u : 0u); }
int gs_isotp_busy(const gs_isotp_t *t) { return gs_isotp_transmitting(t) || t->rx_state != RX_IDLE || t->inbox_len > 0; }

/* Nearest CAN FD data length (can-isotp _get_nearest_can_fd_size). */
static unsigned fd_size(unsigned n) {
    static const unsigned sizes[] = {12, 16, 20, 24, 32, 48, 64};
    if (n <= 8u) return n;
    for (unsigned i = 0; i < sizeof sizes / sizeof sizes[0]; i++)
        if (n <= sizes[i]) return sizes[i];
    return 64u;
}

static void make_tx(const gs_isotp_t *t, const uint8_t *data, unsigned n, gs_can_frame_t *out) {
    unsigned target = t->fd ? (fd_size(n) > 64u ? 64u : fd_size(n)) : 8u;
    if (target < 64u && t->fd) target = 64u; /* tx_data_min_length 64 on FD, 8 on classic */
    memset(out, 0, sizeof *out);
    out->id = t->txid;
    out->flags = t->fd ? GS_CAN_FLAG_FD : 0u;
    memcpy(out->data, data, n);
    for (unsigned i = n; i < target; i++) out->data[i] = PAD;
    out->len = (uint8_t)(n > target ? n : target);
}

static void stop_sending(gs_isotp_t *t) {
    t->active = 0;
    t->tx_state = TX_IDLE;
    t->timer_rx_fc.running = 0;
    t->timer_stmin.running = 0;
    t->remote_bs = 0;
    t->tx_block_counter = 0;
    t->tx_seqnum = 0;
}

static void stop_receiving(gs_isotp_t *t) {
    t->actual_rxdl = 0;
    t->rx_state = RX_IDLE;
    t->rx_count = 0;
    t->pending_fc = 0;
    t->have_fc = 0;
    t->timer_rx_cf.running = 0;
}

static void append_rx(gs_isotp_t *t, const uint8_t *p, size_t n) {
    for (size_t i = 0; i < n; i++, t->rx_count++)
        if (t->rx_count < GS_ISOTP_RX_KEEP) t->rx_buf[t->rx_count] = p[i];
}

static void deliver(gs_isotp_t *t) {
    if (t->on_unit)
        t->on_unit(t->ctx, t->rx_buf, t->rx_count > GS_ISOTP_RX_KEEP ? GS_ISOTP_RX_KEEP : t->rx_count,
                   t->rx_count > GS_ISOTP_RX_KEEP);
}

typedef struct {
    uint8_t type;
    uint8_t escape;
    uint32_t length;
    const uint8_t *data;
    size_t data_len;
    uint8_t seqnum, flow_status, bs, stmin;
    uint32_t stmin_us;
    unsigned can_dl, rx_dl;
} pdu_t;

/* can-isotp's PDU(): 0, or -1 with `why` (the frame is not a valid N_PDU). */
static int parse(const gs_can_frame_t *f, pdu_t *p, const char **why) {
    const uint8_t *d = f->data;
    size_t n = f->len;
    memset(p, 0, sizeof *p);
    p->can_dl = n;
    p->rx_dl = n > 8u ? (unsigned)n : 8u;
    if (n == 0) { *why = "InvalidCanDataError: Received invalid CAN frame. Empty CAN frame"; return -1; }
    unsigned hnb = d[0] >> 4;
    if (hnb > 3u) { *why = "InvalidCanDataError: Received invalid CAN frame. unknown frame type"; return -1; }
    p->type = (uint8_t)hnb;
    if (hnb == PDU_SF) {
        unsigned lp = d[0] & 0xFu;
        if (lp) {
            p->length = lp;
            if (lp > n - 1u) { *why = "InvalidCanDataError: Single Frame longer than its frame"; return -1; }
            p->data = d + 1;
            p->data_len = lp;
        } else {
            if (n < 2u) { *why = "InvalidCanDataError: Single frame with escape sequence too short"; return -1; }
            p->escape = 1;
            p->length = d[1];
            if (p->length == 0) { *why = "InvalidCanDataError: Single Frame with length of 0 bytes"; return -1; }
            if (p->length > n - 2u) { *why = "InvalidCanDataError: Single Frame longer than its frame"; return -1; }
            p->data = d + 2;
            p->data_len = p->length;
        }
    } else if (hnb == PDU_FF) {
        if (n < 2u) { *why = "InvalidCanDataError: First frame too short"; return -1; }
        uint32_t lp = ((uint32_t)(d[0] & 0xFu) << 8) | d[1];
        if (lp) {
            p->length = lp;
            p->data = d + 2;
            p->data_len = lp < n - 2u ? lp : n - 2u;
        } else {
            if (n < 6u) { *why = "InvalidCanDataError: First frame with escape sequence too short"; return -1; }
            p->escape = 1;
            p->length = ((uint32_t)d[2] << 24) | ((uint32_t)d[3] << 16) | ((uint32_t)d[4] << 8) | d[5];
            p->data = d + 6;
            p->data_len = p->length < n - 6u ? p->length : n - 6u;
        }
    } else if (hnb == PDU_CF) {
        p->seqnum = d[0] & 0xFu;
        p->data = d + 1;
        p->data_len = n - 1u;
    } else {
        if (n < 3u) { *why = "InvalidCanDataError: Flow Control frame too short"; return -1; }
        p->flow_status = d[0] & 0xFu;
        if (p->flow_status >= 3u) { *why = "InvalidCanDataError: Unknown flow status"; return -1; }
        p->bs = d[1];
        p->stmin = d[2];
        if (d[2] <= 0x7Fu) p->stmin_us = d[2] * 1000u;
        else if (d[2] >= 0xF1u && d[2] <= 0xF9u) p->stmin_us = (d[2] - 0xF0u) * 100u;
        else { *why = "InvalidCanDataError: Invalid StMin received in Flow Control"; return -1; }
    }
    return 0;
}

static int start_reception(gs_isotp_t *t, const pdu_t *p, uint32_t now) {
    t->rx_count = 0;
    unsigned dl = p->rx_dl;
    if (!(dl == 8u || dl == 12u || dl == 16u || dl == 20u || dl == 24u || dl == 32u || dl == 48u || dl == 64u)) {
        error(t, "InvalidCanFdFirstFrameRXDL: a First Frame with an invalid RX_DL");
        stop_receiving(t);
        return 0;
    }
    t->actual_rxdl = (uint8_t)dl;
    int started = 0;
    if (p->length > GS_ISOTP_MAX_FRAME) {
        error(t, "FrameTooLongError: a First Frame longer than 4095 bytes");
        t->pending_fc = 1;
        t->pending_fc_status = FS_OVERFLOW;
        t->rx_state = RX_IDLE;
    } else {
        t->rx_state = RX_WAIT_CF;
        t->rx_frame_length = p->length;
        append_rx(t, p->data, p->data_len);
        t->pending_fc = 1;
        t->pending_fc_status = FS_CTS;
        timer_start(&t->timer_rx_cf, now, GS_ISOTP_TIMEOUT_US);
        started = 1;
    }
    t->last_seqnum = 0;
    return started;
}

/* _process_rx: 1 when the transmitter must run at once. */
static int process_rx(gs_isotp_t *t, const gs_can_frame_t *f, uint32_t now, uint32_t at) {
    pdu_t p;
    const char *why = "";
    if (parse(f, &p, &why) != 0) {
        error(t, why);
        stop_receiving(t);
        return 0;
    }
    if (p.type == PDU_FC) {
        t->have_fc = 1;
        t->fc_status = p.flow_status;
        t->fc_bs = p.bs;
        t->fc_stmin = p.stmin;
        t->fc_stmin_us = p.stmin_us;
        t->fc_at_us = at; /* N_Bs is judged at the flow control's arrival */
        t->fc_board_at_us = t->rx_board_at;
        return 1;
    }
    if (p.type == PDU_SF && p.can_dl > 8u && !p.escape) {
        error(t, "MissingEscapeSequenceError: a Single Frame longer than 8 bytes without the escape sequence");
        return 0;
    }
    int immediate = 0;
    if (t->rx_state == RX_IDLE) {
        t->rx_frame_length = 0;
        t->timer_rx_cf.running = 0;
        if (p.type == PDU_SF) {
            t->rx_count = 0;
            append_rx(t, p.data, p.data_len);
            deliver(t);
            t->rx_count = 0;
        } else if (p.type == PDU_FF) {
            immediate = start_reception(t, &p, now);
        } else {
            error(t, "UnexpectedConsecutiveFrameError: Received a ConsecutiveFrame while reception was idle. Ignoring");
        }
    } else {
        if (p.type == PDU_SF) {
            uint8_t keep[GS_ISOTP_RX_KEEP];
            uint32_t kept = t->rx_count;
            size_t nk = kept > GS_ISOTP_RX_KEEP ? GS_ISOTP_RX_KEEP : kept;
            memcpy(keep, t->rx_buf, nk);
            t->rx_count = 0;
            append_rx(t, p.data, p.data_len);
            deliver(t);
            /* can-isotp leaves its buffer and the N_Cr timer as they were (a timeout may follow) */
            memcpy(t->rx_buf, keep, nk);
            t->rx_count = kept;
            t->rx_state = RX_IDLE;
            error(t, "ReceptionInterruptedWithSingleFrameError: Reception of IsoTP frame interrupted with a new SingleFrame");
        } else if (p.type == PDU_FF) {
            immediate = start_reception(t, &p, now);
            error(t, "ReceptionInterruptedWithFirstFrameError: Reception of IsoTP frame interrupted with a new FirstFrame");
        } else {
            unsigned expected = (t->last_seqnum + 1u) & 0xFu;
            if (p.seqnum == expected) {
                long to_receive = (long)t->rx_frame_length - (long)t->rx_count;
                if (p.rx_dl != t->actual_rxdl && (long)p.rx_dl < to_receive) {
                    error(t, "ChangingInvalidRXDLError: a ConsecutiveFrame with another RX_DL. Ignoring frame");
                    return 0;
                }
                timer_start(&t->timer_rx_cf, now, GS_ISOTP_TIMEOUT_US);
                t->last_seqnum = p.seqnum;
                /* Python's data[:to_receive]: a negative count drops that many from the end */
                long take = to_receive >= 0 ? (to_receive < (long)p.data_len ? to_receive : (long)p.data_len)
                                            : ((long)p.data_len + to_receive > 0 ? (long)p.data_len + to_receive : 0);
                append_rx(t, p.data, (size_t)take);
                if (t->rx_count >= t->rx_frame_length) {
                    deliver(t);
                    stop_receiving(t);
                }
            } else {
                stop_receiving(t);
                error(t, "WrongSequenceNumberError: Received a ConsecutiveFrame with wrong SequenceNumber");
            }
        }
    }
    if (t->pending_fc) immediate = 1;
    return immediate;
}

/* _process_tx: 1 with `out` filled when a frame is to be sent; *immediate_rx when the receiver must run at once. */
static int process_tx(gs_isotp_t *t, uint32_t now, gs_can_frame_t *out, int *immediate_rx) {
    *immediate_rx = 0;
    if (t->pending_fc) {
        t->pending_fc = 0;
        if (t->pending_fc_status == FS_CTS) timer_start(&t->timer_rx_cf, now, GS_ISOTP_TIMEOUT_US);
        uint8_t fc[3] = {(uint8_t)(0x30u | (t->pending_fc_status & 0xFu)), 0, 0};
        make_tx(t, fc, 3, out);
        *immediate_rx = 1;
        return 1;
    }
    if (t->have_fc) {
        t->have_fc = 0;
        if (t->fc_status == FS_OVERFLOW) {
            stop_sending(t);
            error(t, "OverflowError: Received a FlowControl PDU indicating an Overflow. Stopping transmission.");
            return 0;
        }
        if (t->tx_state == TX_IDLE) {
            error(t, "UnexpectedFlowControlError: Received a FlowControl message while transmission was Idle. Ignoring");
        } else if (t->fc_status == FS_WAIT) {
            error(t, "UnsupportedWaitFrameError: Received a FlowControl requesting to wait, but wftmax is set to 0");
        } else if (!timed_out_(t, &t->timer_rx_fc, t->fc_at_us, t->fc_board_at_us)) {
            t->timer_rx_fc.running = 0;
            t->timer_stmin.timeout_us = t->fc_stmin_us;
            t->remote_bs = t->fc_bs;
            if (t->tx_state == TX_WAIT_FC) {
                t->tx_block_counter = 0;
                timer_start(&t->timer_stmin, now, t->fc_stmin_us);
            }
            t->tx_state = TX_CF;
        }
    }
    if (timed_out(&t->timer_rx_fc, now)) {
        t->errors++;
        t->fc_timeouts++;
        t->last_error = "FlowControlTimeoutError: Reception of FlowControl timed out. Stopping transmission";
        stop_sending(t);
    }
    if (t->tx_state != TX_IDLE && t->active && t->active_pos >= t->active_len) stop_sending(t);
    if (t->tx_state == TX_IDLE) {
        while (t->txq_n > 0) {
            memcpy(t->active_data, t->txq[t->txq_head], t->txq_len[t->txq_head]);
            t->active_len = t->txq_len[t->txq_head];
            t->active_pos = 0;
            t->active = 1;
            t->txq_head = (uint8_t)((t->txq_head + 1u) % GS_ISOTP_TXQ);
            t->txq_n--;
            if (t->active_len == 0) { /* an empty unit: completed at once, read the next */
                t->active = 0;
                continue;
            }
            uint8_t buf[GS_CAN_MAX_DATA];
            unsigned total = t->active_len;
            unsigned offset = total <= 7u ? 1u : 2u;
            if (total <= tx_dl(t) - offset) {
                if (offset == 1u) {
                    buf[0] = (uint8_t)total;
                } else {
                    buf[0] = 0;
                    buf[1] = (uint8_t)total;
                }
                memcpy(buf + offset, t->active_data, total);
                make_tx(t, buf, offset + total, out);
                stop_sending(t);
                return 1;
            }
            unsigned k = tx_dl(t) - 2u;
            buf[0] = (uint8_t)(0x10u | ((total >> 8) & 0xFu));
            buf[1] = (uint8_t)(total & 0xFFu);
            memcpy(buf + 2, t->active_data, k);
            t->active_pos = (uint16_t)k;
            t->tx_seqnum = 1;
            make_tx(t, buf, tx_dl(t), out);
            t->tx_state = TX_WAIT_FC;
            timer_start(&t->timer_rx_fc, now, GS_ISOTP_TIMEOUT_US);
            return 1;
        }
        return 0;
    }
    if (t->tx_state == TX_CF && timed_out(&t->timer_stmin, now)) {
        int sent = 0;
        unsigned room = tx_dl(t) - 1u, left = (unsigned)(t->active_len - t->active_pos);
        unsigned k = left < room ? left : room;
        if (k > 0) {
            uint8_t buf[GS_CAN_MAX_DATA];
            buf[0] = (uint8_t)(0x20u | t->tx_seqnum);
            memcpy(buf + 1, t->active_data + t->active_pos, k);
            t->active_pos = (uint16_t)(t->active_pos + k);
            make_tx(t, buf, k + 1u, out);
            t->tx_seqnum = (uint8_t)((t->tx_seqnum + 1u) & 0xFu);
            timer_start(&t->timer_stmin, now, t->timer_stmin.timeout_us);
            t->tx_block_counter++;
            sent = 1;
        }
        if (t->active_pos >= t->active_len) {
            stop_sending(t);
        } else if (t->remote_bs != 0 && t->tx_block_counter >= t->remote_bs) {
            t->tx_state = TX_WAIT_FC;
            *immediate_rx = 1;
            timer_start(&t->timer_rx_fc, now, GS_ISOTP_TIMEOUT_US);
        }
        return sent;
    }
    return 0;
}

void gs_isotp_poll(gs_isotp_t *t, uint32_t now) {
    int run = 1;
    unsigned rounds = 0;
    while (run && rounds++ < 4u * GS_ISOTP_INBOX + 64u) { /* bounded: each round consumes a frame or sends one */
        run = 0;
        int start_with_tx = t->txq_n > 0 && t->rx_state == RX_IDLE && t->tx_state == TX_IDLE;
        if (start_with_tx) run = 1;
        if (!start_with_tx) {
            for (;;) {
                int have = t->inbox_len > 0;
                gs_can_frame_t f;
                uint32_t at = now; /* a timeout is judged at the frame's arrival (gs_isotp.h) */
                t->rx_board_at = board_now(t);
                if (have) {
                    f = t->inbox[t->inbox_head];
                    at = t->inbox_at[t->inbox_head];
                    t->rx_board_at = t->inbox_board_at[t->inbox_head];
                    t->inbox_head = (uint8_t)((t->inbox_head + 1u) % GS_ISOTP_INBOX);
                    t->inbox_len--;
                }
                if (timed_out_(t, &t->timer_rx_cf, at, t->rx_board_at)) {
                    error(t, "ConsecutiveFrameTimeoutError: Reception of CONSECUTIVE_FRAME timed out.");
                    stop_receiving(t);
                }
                if (!have) break;
                if (process_rx(t, &f, now, at)) break;
            }
        }
        for (unsigned sent = 0; sent < 4096u; sent++) {
            gs_can_frame_t out;
            int immediate_rx = 0;
            int got = process_tx(t, now, &out, &immediate_rx);
            if (got && t->emit) t->emit(t->ctx, &out);
            if (immediate_rx) {
                run = 1;
                break;
            }
            if (!got) break;
        }
    }
}
