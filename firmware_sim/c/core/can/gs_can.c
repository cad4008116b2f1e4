/* The CAN form of the protocol: see gs_can.h. Mirrors protocol/can/codec.py and protocol/can/decoder.py;
 * the layouts are the generated table (gs_can_layouts.h, protocol.can.cgen). */
#include "gs_can.h"

#include <string.h>

#include "gs_can_layouts.h"
#include "gs_crc.h"

#define SEQ_MASK 0x7FFu
#define Q16_NAN (-32768)

unsigned gs_can_servo_count(void) { return GS_CAN_SERVOS; }

const gs_can_layout_t *gs_can_layout(unsigned fn, int fd) {
    for (unsigned i = 0; i < GS_CAN_LAYOUT_COUNT; i++)
        if (gs_can_layouts[i].fn == fn && gs_can_layouts[i].fd == (fd ? 1u : 0u)) return &gs_can_layouts[i];
    return NULL;
}

static const gs_can_message_t *message_of(uint8_t type) {
    for (unsigned i = 0; i < GS_CAN_MESSAGE_COUNT; i++)
        if (gs_can_messages[i].msg_type == type) return &gs_can_messages[i];
    return NULL;
}

/* The function code a fixed-layout message type travels with (HEARTBEAT: by sender); -1: none. */
static int fn_of(uint8_t type, int sender) {
    switch (type) {
    case GS_MSG_TYPE_ESTOP: return GS_CAN_FN_ESTOP;
    case GS_MSG_TYPE_SERVO_FRAME: return GS_CAN_FN_SERVO_FRAME;
    case GS_MSG_TYPE_TIME_SYNC_REQUEST: return GS_CAN_FN_TIME_SYNC_REQUEST;
    case GS_MSG_TYPE_TIME_SYNC_REPLY: return GS_CAN_FN_TIME_SYNC_REPLY;
    case GS_MSG_TYPE_FLUSH: return GS_CAN_FN_FLUSH;
    case GS_MSG_TYPE_ADVANCE: return GS_CAN_FN_ADVANCE;
    case GS_MSG_TYPE_ESTOP_CLEAR: return GS_CAN_FN_ESTOP_CLEAR;
    case GS_MSG_TYPE_ACK: return GS_CAN_FN_ACK;
    case GS_MSG_TYPE_NACK: return GS_CAN_FN_NACK;
    case GS_MSG_TYPE_TELEMETRY: return GS_CAN_FN_TELEMETRY;
    case GS_MSG_TYPE_HEARTBEAT: return sender == GS_CAN_SENDER_BOARD ? GS_CAN_FN_HEARTBEAT_BOARD : GS_CAN_FN_HEARTBEAT_HOST;
    default: return -1;
    }
}

/* ---- member access by the table's offsets ---- */

static uint64_t get_u(const gs_msg_t *m, uint16_t off, unsigned size) {
    const uint8_t *p = (const uint8_t *)m + off;
    switch (size) {
    case 1: return *p;
    case 2: { uint16_t v; memcpy(&v, p, 2); return v; }
    case 4: { uint32_t v; memcpy(&v, p, 4); return v; }
    default: { uint64_t v; memcpy(&v, p, 8); return v; }
    }
}

static int64_t get_s(const gs_msg_t *m, uint16_t off, unsigned size) {
    const uint8_t *p = (const uint8_t *)m + off;
    switch (size) {
    case 1: { int8_t v; memcpy(&v, p, 1); return v; }
    case 2: { int16_t v; memcpy(&v, p, 2); return v; }
    case 4: { int32_t v; memcpy(&v, p, 4); return v; }
    default: { int64_t v; memcpy(&v, p, 8); return v; }
    }
}

static void put_u(gs_msg_t *m, uint16_t off, unsigned size, uint64_t v) {
    uint8_t *p = (uint8_t *)m + off;
    switch (size) {
    case 1: *p = (uint8_t)v; break;
    case 2: { uint16_t x = (uint16_t)v; memcpy(p, &x, 2); break; }
    case 4: { uint32_t x = (uint32_t)v; memcpy(p, &x, 4); break; }
    default: memcpy(p, &v, 8); break;
    }
}

static int16_t get_q16(const gs_msg_t *m, uint16_t off, unsigned i) {
    int16_t v;
    memcpy(&v, (const uint8_t *)m + off + 2u * i, 2);
    return v;
}

static void put_q16(gs_msg_t *m, uint16_t off, unsigned i, int64_t v) {
    int16_t x = (int16_t)v;
    memcpy((uint8_t *)m + off + 2u * i, &x, 2);
}

static unsigned popcount32(uint64_t v) {
    unsigned n = 0;
    for (; v; v &= v - 1) n++;
    return n;
}

static int enum_ok(const uint8_t *members, uint64_t v) {
    return v < 256u && (members[v >> 3] >> (v & 7u)) & 1u;
}

/* ---- bits ---- */

static void put_bits(uint8_t *buf, unsigned start, unsigned bits, uint64_t v) {
    for (unsigned i = 0; i < bits; i++) {
        unsigned b = start + i;
        if ((v >> i) & 1u) buf[b >> 3] |= (uint8_t)(1u << (b & 7u));
    }
}

static uint64_t get_bits(const uint8_t *buf, unsigned start, unsigned bits) {
    uint64_t v = 0;
    for (unsigned i = 0; i < bits; i++) {
        unsigned b = start + i;
        v |= (uint64_t)((buf[b >> 3] >> (b & 7u)) & 1u) << i;
    }
    return v;
}

static uint64_t bits_mask(unsigned bits) { return bits >= 64 ? ~(uint64_t)0 : (((uint64_t)1 << bits) - 1u); }

/* ---- message -> raw signal values (protocol.can.codec.message_to_raw) ---- */

static int has_omitted_content(const gs_msg_t *m, const gs_can_message_t *md) {
    for (unsigned i = 0; i < md->nfields; i++)
        if (md->fields[i].kind == GS_CAN_K_OMITTED && get_u(m, md->fields[i].count_offset, 1)) return 1;
    return 0;
}

int gs_can_is_fixed(const gs_msg_t *m, int fd) {
    const gs_can_message_t *md = message_of(m->type);
    if (!md || has_omitted_content(m, md)) return 0;
    int fn = fn_of(m->type, GS_CAN_SENDER_HOST);
    return fn >= 0 && gs_can_layout((unsigned)fn, fd) != NULL;
}

/* raw[] in signal order; 0 or GS_E_VALUE with `why`. */
static int to_raw(const gs_msg_t *m, const gs_can_message_t *md, int64_t *raw, unsigned *nraw, const char **why) {
    unsigned k = 0;
    unsigned first[32];
    for (unsigned i = 0; i < md->nfields && i < 32u; i++) {
        const gs_can_field_t *f = &md->fields[i];
        first[i] = k;
        uint64_t hi = bits_mask(f->bits);
        switch (f->kind) {
        case GS_CAN_K_UINT: {
            uint64_t v = get_u(m, f->offset, f->size);
            raw[k++] = (int64_t)((f->flags & GS_CAN_F_WRAP) ? (v & hi) : (v > hi ? hi : v));
            break;
        }
        case GS_CAN_K_SINT: {
            int64_t v = get_s(m, f->offset, f->size);
            int64_t smax = (int64_t)(hi >> 1), smin = -smax - 1;
            raw[k++] = v > smax ? smax : v < smin ? smin : v;
            break;
        }
        case GS_CAN_K_BOOL: raw[k++] = get_u(m, f->offset, 1) ? 1 : 0; break;
        case GS_CAN_K_ENUM: {
            uint64_t v = get_u(m, f->offset, 1);
            if (!enum_ok(f->enum_members, v)) { *why = "enum value is not a member"; return GS_E_VALUE; }
            raw[k++] = (int64_t)v;
            break;
        }
        case GS_CAN_K_FLAGS: raw[k++] = (int64_t)get_u(m, f->offset, 2); break;
        case GS_CAN_K_MASK: {
            uint64_t v = get_u(m, f->offset, f->size);
            if ((f->flags & GS_CAN_F_DRIVES) && (v >> GS_CAN_SERVOS)) { *why = "mask has bits outside the CAN servos"; return GS_E_VALUE; }
            if (v > hi) { *why = "mask does not fit its signal"; return GS_E_VALUE; }
            raw[k++] = (int64_t)v;
            break;
        }
        case GS_CAN_K_Q16_FIXED:
            for (unsigned j = 0; j < f->nsig; j++) raw[k++] = get_q16(m, f->offset, j);
            break;
        case GS_CAN_K_Q16_MASKED: {
            uint64_t mask = (uint64_t)raw[first[f->mask_field]];
            unsigned n = (unsigned)get_u(m, f->count_offset, 1);
            if (n != popcount32(mask)) { *why = "array length is not popcount(mask)"; return GS_E_VALUE; }
            unsigned j = 0;
            for (unsigned s = 0; s < f->nsig; s++) {
                int64_t code = Q16_NAN;
                if ((mask >> s) & 1u) {
                    code = get_q16(m, f->offset, j++);
                    if ((f->flags & GS_CAN_F_NONAN) && code == Q16_NAN) { *why = "NaN is not allowed here"; return GS_E_VALUE; }
                }
                raw[k++] = code;
            }
            break;
        }
        case GS_CAN_K_Q16_COUNTED: {
            unsigned n = (unsigned)get_u(m, f->count_offset, 1);
            if (n > f->nsig) { *why = "more values than the CAN layout carries"; return GS_E_VALUE; }
            for (unsigned s = 0; s < f->nsig; s++) raw[k++] = s < n ? get_q16(m, f->offset, s) : Q16_NAN;
            break;
        }
        case GS_CAN_K_OMITTED: break;
        default: *why = "no CAN rule for this field"; return GS_E_VALUE;
        }
    }
    *nraw = k;
    return GS_OK;
}

/* raw[] -> message (protocol.can.codec.raw_to_message); 0 or GS_E_VALUE with `why`. */
static int from_raw(gs_msg_t *m, uint8_t type, const gs_can_message_t *md, const int64_t *raw, const char **why) {
    unsigned k = 0;
    unsigned first[32];
    memset(m, 0, sizeof *m);
    m->type = type;
    for (unsigned i = 0; i < md->nfields && i < 32u; i++) {
        const gs_can_field_t *f = &md->fields[i];
        first[i] = k;
        switch (f->kind) {
        case GS_CAN_K_UINT:
        case GS_CAN_K_FLAGS: put_u(m, f->offset, f->size, (uint64_t)raw[k++]); break;
        case GS_CAN_K_SINT: put_u(m, f->offset, f->size, (uint64_t)raw[k++]); break;
        case GS_CAN_K_BOOL:
            if (raw[k] > 1) { *why = "boolean must be 0 or 1"; return GS_E_VALUE; }
            put_u(m, f->offset, 1, (uint64_t)raw[k++]);
            break;
        case GS_CAN_K_ENUM:
            if (!enum_ok(f->enum_members, (uint64_t)raw[k])) { *why = "unknown enum value"; return GS_E_VALUE; }
            put_u(m, f->offset, 1, (uint64_t)raw[k++]);
            break;
        case GS_CAN_K_MASK:
            if ((f->flags & GS_CAN_F_DRIVES) && ((uint64_t)raw[k] >> GS_CAN_SERVOS)) {
                *why = "mask has bits outside the CAN servos";
                return GS_E_VALUE;
            }
            put_u(m, f->offset, f->size, (uint64_t)raw[k++]);
            break;
        case GS_CAN_K_Q16_FIXED:
            for (unsigned j = 0; j < f->nsig; j++) put_q16(m, f->offset, j, raw[k++]);
            break;
        case GS_CAN_K_Q16_MASKED: {
            uint64_t mask = (uint64_t)raw[first[f->mask_field]];
            unsigned j = 0;
            for (unsigned s = 0; s < f->nsig; s++, k++) {
                if (!((mask >> s) & 1u)) continue;
                if ((f->flags & GS_CAN_F_NONAN) && raw[k] == Q16_NAN) {
                    *why = "reserved code -32768 (NaN) is not allowed here";
                    return GS_E_VALUE;
                }
                put_q16(m, f->offset, j++, raw[k]);
            }
            put_u(m, f->count_offset, 1, j);
            break;
        }
        case GS_CAN_K_Q16_COUNTED:
            for (unsigned s = 0; s < f->nsig; s++) put_q16(m, f->offset, s, raw[k++]);
            put_u(m, f->count_offset, 1, f->nsig);
            break;
        case GS_CAN_K_OMITTED: put_u(m, f->count_offset, 1, 0); break;
        default: *why = "no CAN rule for this field"; return GS_E_VALUE;
        }
    }
    return GS_OK;
}

/* ---- frames ---- */

static void pack_part(const gs_can_layout_t *l, unsigned part, unsigned seq11, const int64_t *raw, uint8_t *out) {
    memset(out, 0, l->length);
    uint64_t header = (part & 0x1Fu) | ((uint64_t)(seq11 & SEQ_MASK) << 5);
    put_bits(out, 0, 16, header);
    for (unsigned s = 0; s < l->nsig; s++)
        if (l->sig[s].part == part) put_bits(out, l->sig[s].start, l->sig[s].bits, (uint64_t)raw[s] & bits_mask(l->sig[s].bits));
}

/* CRC-16/X-25 over every part packed with crc16 = 0 (protocol.can.codec.fixed_crc). */
static uint16_t fixed_crc(const gs_can_layout_t *l, unsigned seq11, int64_t *raw) {
    int64_t saved = raw[l->nsig - 1u];
    raw[l->nsig - 1u] = 0;
    uint8_t all[GS_CAN_MAX_PARTS * GS_CAN_MAX_DATA];
    for (unsigned k = 0; k < l->parts; k++) pack_part(l, k, seq11, raw, all + (size_t)k * l->length);
    raw[l->nsig - 1u] = saved;
    return gs_crc16_x25(all, (size_t)l->parts * l->length);
}

int gs_can_encode_fixed(const gs_msg_t *m, uint16_t seq, unsigned node, int fd, int sender, gs_can_frame_t *out,
                        size_t cap, const char **why) {
    const gs_can_message_t *md = message_of(m->type);
    int fn = fn_of(m->type, sender);
    if (!md || fn < 0) { *why = "no fixed CAN layout (it goes as ISO-TP bulk)"; return GS_E_TYPE; }
    if (has_omitted_content(m, md)) { *why = "a message with omitted content goes as bulk"; return GS_E_TYPE; }
    const gs_can_layout_t *l = gs_can_layout((unsigned)fn, fd);
    if (!l) { *why = "no fixed CAN layout in this frame kind (it goes as ISO-TP bulk)"; return GS_E_TYPE; }
    if (cap < l->parts) { *why = "no room for the frames"; return GS_E_SPACE; }
    int64_t raw[GS_CAN_MAX_SIGNALS + 1u];
    unsigned nraw = 0;
    int rc = to_raw(m, md, raw, &nraw, why);
    if (rc != GS_OK) return rc;
    if (l->has_crc) {
        raw[l->nsig - 1u] = 0;
        raw[l->nsig - 1u] = fixed_crc(l, seq & SEQ_MASK, raw);
    }
    uint32_t id = (fn == GS_CAN_FN_ESTOP && node == 0) ? 0u : GS_CAN_ID(fn, node);
    for (unsigned k = 0; k < l->parts; k++) {
        out[k].id = id;
        out[k].len = l->length;
        out[k].flags = fd ? GS_CAN_FLAG_FD : 0u;
        memset(out[k].data, 0, sizeof out[k].data);
        pack_part(l, k, seq & SEQ_MASK, raw, out[k].data);
    }
    return (int)l->parts;
}

/* ---- bulk ---- */

int gs_can_encode_bulk(const gs_msg_t *m, uint16_t seq, uint8_t *out, size_t cap) {
    if (cap < 5u) return GS_E_SPACE;
    int n = gs_encode_payload(m, out + 3, cap - 5u);
    if (n < 0) return n;
    out[0] = m->type;
    out[1] = (uint8_t)(seq & 0xFFu);
    out[2] = (uint8_t)(seq >> 8);
    uint16_t crc = gs_crc16_x25(out, 3u + (size_t)n);
    out[3 + n] = (uint8_t)(crc & 0xFFu);
    out[4 + n] = (uint8_t)(crc >> 8);
    return n + 5;
}

int gs_can_decode_bulk(const uint8_t *sdu, size_t n, uint16_t *seq, gs_msg_t *m, const char **why) {
    if (n < 5u) { *why = "bulk message shorter than its 3-byte header and 2-byte CRC"; return GS_E_TRUNCATED; }
    uint16_t crc = (uint16_t)(sdu[n - 2u] | (sdu[n - 1u] << 8));
    if (gs_crc16_x25(sdu, n - 2u) != crc) { *why = "bulk message: CRC mismatch"; return GS_E_VALUE; }
    if (!gs_is_msg_type(sdu[0])) { *why = "bulk message: unknown message type"; return GS_E_TYPE; }
    *seq = (uint16_t)(sdu[1] | (sdu[2] << 8));
    return gs_decode_payload(sdu[0], sdu + 3, n - 5u, m, why);
}

uint16_t gs_can_unwrap_seq(unsigned seq11, uint16_t reference) {
    int delta = (int)((seq11 - reference) & SEQ_MASK);
    if (delta >= 1024) delta -= 2048;
    return (uint16_t)(reference + delta);
}

/* ---- the receiver ---- */

static const uint8_t BOARD_FNS[] = {GS_CAN_FN_ESTOP, GS_CAN_FN_SERVO_FRAME, GS_CAN_FN_TIME_SYNC_REQUEST, GS_CAN_FN_FLUSH,
                                    GS_CAN_FN_ADVANCE, GS_CAN_FN_ESTOP_CLEAR, GS_CAN_FN_HEARTBEAT_HOST};
static const uint8_t HOST_FNS[] = {GS_CAN_FN_TIME_SYNC_REPLY, GS_CAN_FN_ACK, GS_CAN_FN_NACK, GS_CAN_FN_TELEMETRY,
                                   GS_CAN_FN_HEARTBEAT_BOARD};

void gs_can_decoder_init(gs_can_decoder_t *d, unsigned node, int receiver_board) {
    memset(d, 0, sizeof *d);
    d->node = (uint8_t)node;
    d->receiver_board = receiver_board ? 1u : 0u;
    const uint8_t *fns = receiver_board ? BOARD_FNS : HOST_FNS;
    unsigned n = receiver_board ? sizeof BOARD_FNS : sizeof HOST_FNS;
    for (unsigned i = 0; i < GS_CAN_RX_FNS; i++) d->fns[i].fn = i < n ? fns[i] : 0xFFu;
}

static gs_can_rx_fn_t *rx_fn(gs_can_decoder_t *d, unsigned fn) {
    for (unsigned i = 0; i < GS_CAN_RX_FNS; i++)
        if (d->fns[i].fn == fn) return &d->fns[i];
    return NULL;
}

const char *gs_can_item_kind_name(gs_can_item_kind_t k) {
    static const char *const names[GS_CAN_ITEM_KINDS] = {"MESSAGE", "EXTENDED_ID", "REMOTE", "LENGTH", "PART", "PAYLOAD",
                                                         "INCOMPLETE", "MIXED", "BULK", "CRC"};
    return (unsigned)k < GS_CAN_ITEM_KINDS ? names[k] : "?";
}

static void error_item(gs_can_decoder_t *d, gs_can_item_t *it, gs_can_item_kind_t kind, const char *why, size_t raw_len) {
    d->errors[kind]++;
    it->kind = kind;
    it->seq = 0;
    it->bulk = 0;
    it->why = why;
    it->raw_len = raw_len;
    it->msg.type = 0;
}

static void remove_asm(gs_can_rx_fn_t *r, unsigned i) {
    for (unsigned j = i; j + 1u < r->nasm; j++) r->asm_[j] = r->asm_[j + 1u];
    r->nasm--;
}

static void done_push(gs_can_rx_fn_t *r, uint16_t seq11, uint32_t at) {
    unsigned slot = (r->done_head + r->ndone) % GS_CAN_DONE_KEPT;
    if (r->ndone == GS_CAN_DONE_KEPT) {
        slot = r->done_head;
        r->done_head = (uint8_t)((r->done_head + 1u) % GS_CAN_DONE_KEPT);
    } else {
        r->ndone++;
    }
    r->done_seq[slot] = seq11;
    r->done_at[slot] = at;
}

/* Assemblies of earlier sequences than `seq11` will not complete any more (decoder._drop_older). */
static size_t drop_older(gs_can_decoder_t *d, gs_can_rx_fn_t *r, unsigned seq11, gs_can_item_t *items, size_t n, size_t raw_len) {
    for (unsigned i = 0; i < r->nasm;) {
        unsigned back = (seq11 - r->asm_[i].seq11) & SEQ_MASK;
        if (back > 0u && back <= SEQ_MASK / 2u) {
            remove_asm(r, i);
            error_item(d, &items[n++], GS_CAN_E_INCOMPLETE, "parts of an earlier message (dropped)", raw_len);
        } else {
            i++;
        }
    }
    return n;
}

/* A whole message's raw values: check its CRC, build the message. */
static size_t surface(gs_can_decoder_t *d, const gs_can_layout_t *l, unsigned seq11, int64_t *raw, gs_can_item_t *items,
                      size_t n, size_t raw_len) {
    if (l->has_crc && fixed_crc(l, seq11, raw) != (uint16_t)raw[l->nsig - 1u]) {
        error_item(d, &items[n], GS_CAN_E_CRC, "the message's crc16 does not match its parts (dropped)", raw_len);
        return n + 1u;
    }
    const gs_can_message_t *md = message_of(l->msg_type);
    const char *why = "";
    gs_can_item_t *it = &items[n];
    if (!md || from_raw(&it->msg, l->msg_type, md, raw, &why) != GS_OK) {
        error_item(d, it, GS_CAN_E_PAYLOAD, why, raw_len);
        return n + 1u;
    }
    d->last_seq = gs_can_unwrap_seq(seq11, d->last_seq);
    it->kind = GS_CAN_ITEM_MESSAGE;
    it->seq = d->last_seq;
    it->bulk = 0;
    it->why = "";
    it->raw_len = raw_len;
    return n + 1u;
}

static void unpack_part(const gs_can_layout_t *l, unsigned part, const uint8_t *data, int64_t *raw) {
    for (unsigned s = 0; s < l->nsig; s++) {
        const gs_can_place_t *p = &l->sig[s];
        if (p->part != part) continue;
        uint64_t v = get_bits(data, p->start, p->bits);
        if (p->is_signed && p->bits < 64 && ((v >> (p->bits - 1u)) & 1u)) raw[s] = (int64_t)v - ((int64_t)1 << p->bits);
        else raw[s] = (int64_t)v;
    }
}

static int is_mine(const gs_can_decoder_t *d, uint32_t id) {
    unsigned fn = id >> 7, node = id & 0x7Fu;
    if (d->receiver_board && fn == GS_CAN_FN_ESTOP && node == 0) return 1;
    if (node != d->node) return 0;
    const uint8_t *fns = d->receiver_board ? BOARD_FNS : HOST_FNS;
    unsigned n = d->receiver_board ? sizeof BOARD_FNS : sizeof HOST_FNS;
    for (unsigned i = 0; i < n; i++)
        if (fns[i] == fn) return 1;
    return 0;
}

size_t gs_can_decoder_feed(gs_can_decoder_t *d, const gs_can_frame_t *f, gs_can_item_t *items) {
    size_t n = 0;
    d->frames++;
    uint32_t aid = f->id;
    size_t len = f->len > GS_CAN_MAX_DATA ? GS_CAN_MAX_DATA : f->len;
    if ((f->flags & GS_CAN_FLAG_EXT) || (aid >> 11)) {
        /* another protocol's frame may share the bus: an error only if it would have been ours as a standard frame */
        unsigned fn = (aid & 0x7FFu) >> 7;
        int accepted = 0;
        if (aid <= 0x7FFu && (aid & 0x7Fu) == d->node) {
            if (d->receiver_board) accepted = fn == GS_CAN_FN_BULK_TO_BOARD;
            else accepted = fn == GS_CAN_FN_BULK_TO_HOST;
            accepted = accepted || is_mine(d, aid);
        }
        if (accepted) {
            error_item(d, &items[n++], GS_CAN_E_EXTENDED_ID, "29-bit identifier", len);
        } else {
            d->foreign++;
        }
        return n;
    }
    if (!is_mine(d, aid)) {
        d->foreign++;
        return 0;
    }
    unsigned fn = aid >> 7;
    if (f->flags & GS_CAN_FLAG_RTR) {
        error_item(d, &items[n++], GS_CAN_E_REMOTE, "remote frame", len);
        return n;
    }
    int fd = (f->flags & GS_CAN_FLAG_FD) != 0;
    if (fn == GS_CAN_FN_ESTOP && len < 2u) {
        /* honoured whatever its length; a sequence 1024 behind the last one seen (no request in flight has it) */
        gs_can_item_t *it = &items[n++];
        memset(&it->msg, 0, sizeof it->msg);
        it->msg.type = GS_MSG_TYPE_ESTOP;
        it->kind = GS_CAN_ITEM_MESSAGE;
        it->seq = (uint16_t)(d->last_seq - 1024u);
        it->bulk = 0;
        it->why = "";
        it->raw_len = len;
        return n;
    }
    if (len < 2u) {
        error_item(d, &items[n++], GS_CAN_E_LENGTH, "no header", len);
        return n;
    }
    const gs_can_layout_t *l = gs_can_layout(fn, fd);
    if (!l) {
        error_item(d, &items[n++], GS_CAN_E_PAYLOAD, "no fixed layout in this frame kind (it travels as ISO-TP)", len);
        return n;
    }
    unsigned header = (unsigned)(f->data[0] | (f->data[1] << 8));
    unsigned part = header & 0x1Fu, seq11 = (header >> 5) & SEQ_MASK;
    if (part >= l->parts) {
        error_item(d, &items[n++], GS_CAN_E_PART, "part index beyond the message's parts", len);
        return n;
    }
    if (len < l->part_bytes[part]) {
        error_item(d, &items[n++], GS_CAN_E_LENGTH, "part shorter than its layout", len);
        return n;
    }
    gs_can_rx_fn_t *r = rx_fn(d, fn);
    if (!r) return n; /* unreachable: is_mine */
    for (unsigned i = 0; i < r->ndone; i++) {
        unsigned slot = (r->done_head + i) % GS_CAN_DONE_KEPT;
        if (r->done_seq[slot] == seq11 && d->frames - r->done_at[slot] <= GS_CAN_STALE_FRAMES) {
            d->duplicates++; /* double reception of a message already surfaced */
            return n;
        }
    }
    for (unsigned i = 0; i < r->nasm;) {
        if (d->frames - r->asm_[i].born > GS_CAN_STALE_FRAMES) {
            remove_asm(r, i);
            error_item(d, &items[n++], GS_CAN_E_INCOMPLETE, "a message's parts never all came (dropped)", len);
        } else {
            i++;
        }
    }
    int ai = -1;
    for (unsigned i = 0; i < r->nasm; i++)
        if (r->asm_[i].seq11 == seq11) ai = (int)i;
    if (ai >= 0 && r->asm_[ai].fd != (uint8_t)fd) {
        remove_asm(r, (unsigned)ai);
        error_item(d, &items[n++], GS_CAN_E_MIXED, "classic and FD parts mixed", len);
        ai = -1;
    }
    int64_t raw[GS_CAN_MAX_SIGNALS + 1u];
    if (l->parts == 1u) {
        n = drop_older(d, r, seq11, items, n, len);
        done_push(r, (uint16_t)seq11, d->frames);
        unpack_part(l, 0, f->data, raw);
        return surface(d, l, seq11, raw, items, n, len);
    }
    if (ai < 0) {
        while (r->nasm >= GS_CAN_MAX_ASSEMBLIES) { /* a third sequence: the oldest cannot complete any more */
            remove_asm(r, 0);
            error_item(d, &items[n++], GS_CAN_E_INCOMPLETE, "a third message started (oldest dropped)", len);
        }
        gs_can_assembly_t *a = &r->asm_[r->nasm];
        a->used = 1;
        a->fd = (uint8_t)fd;
        a->seq11 = (uint16_t)seq11;
        a->born = d->frames;
        a->have = 0;
        a->nparts = 0;
        ai = (int)r->nasm++;
    }
    gs_can_assembly_t *a = &r->asm_[ai];
    if ((a->have >> part) & 1u) {
        if (a->len[part] == len && memcmp(a->data[part], f->data, len) == 0) {
            d->duplicates++; /* double reception: same part, same content */
            return n;
        }
        remove_asm(r, (unsigned)ai);
        error_item(d, &items[n++], GS_CAN_E_MIXED, "a part with two contents (dropped)", len);
        return n;
    }
    a->have |= 1u << part;
    a->len[part] = (uint8_t)len;
    memcpy(a->data[part], f->data, len);
    a->nparts++;
    if (a->nparts == l->parts) {
        size_t total = 0;
        for (unsigned k = 0; k < l->parts; k++) {
            unpack_part(l, k, a->data[k], raw);
            total += a->len[k];
        }
        remove_asm(r, (unsigned)ai);
        n = drop_older(d, r, seq11, items, n, len);
        done_push(r, (uint16_t)seq11, d->frames);
        return surface(d, l, seq11, raw, items, n, total);
    }
    return n;
}

void gs_can_decoder_feed_bulk(gs_can_decoder_t *d, const uint8_t *sdu, size_t n, gs_can_item_t *item) {
    const char *why = "";
    uint16_t seq = 0;
    if (gs_can_decode_bulk(sdu, n, &seq, &item->msg, &why) != GS_OK) {
        error_item(d, item, GS_CAN_E_BULK, why, n);
        return;
    }
    d->last_seq = seq;
    item->kind = GS_CAN_ITEM_MESSAGE;
    item->seq = seq;
    item->bulk = 1;
    item->why = "";
    item->raw_len = n;
}
