/* The CAN form of the protocol (protocol/can/): fixed-layout frames, the bulk (ISO-TP) unit, reassembly.
 *
 * Identifiers (protocol/can/ids.py, CiA 301 COB-ID layout): id = function code << 7 | node (node 1..127;
 * 0x000 = the broadcast ESTOP). Fixed-layout frames (protocol/can/layouts.py): every frame starts with a
 * 16-bit little-endian header, bits 0..4 the part index, bits 5..15 the sequence modulo 2^11; signals follow
 * little-endian at the start bits of the layout table, which is GENERATED per robot from
 * protocol.can.layouts.can_layouts(N) (protocol.can.cgen -> gs_can_layouts.h in the build folder): no layout is
 * written by hand here. A message with signals ends with crc16 = CRC-16/X-25 over the data bytes of all its
 * parts packed with crc16 = 0. Bulk units (protocol/can/codec.py encode_bulk): type u8 | seq u16 LE |
 * gs_proto payload | CRC-16/X-25 u16 LE, carried by ISO-TP (gs_isotp.h).
 *
 * The decoder is protocol.can.decoder.CanDecoder: any frame in (any id, length, FD flag, remote,
 * extended), whole messages and counted errors out; parts in any order, two sequences per function code at
 * once, duplicates ignored, a message whose CRC fails dropped, an assembly older than GS_CAN_STALE_FRAMES
 * frames dropped. State is bounded (no malloc). */
#ifndef GS_CAN_H
#define GS_CAN_H

#include <stddef.h>
#include <stdint.h>

#include "gs_proto.h"

#define GS_CAN_FLAG_FD 0x1u  /* a CAN FD frame (data 0..64 bytes) */
#define GS_CAN_FLAG_EXT 0x2u /* a 29-bit identifier */
#define GS_CAN_FLAG_RTR 0x4u /* a remote frame */
#define GS_CAN_MAX_DATA 64u

typedef struct {
    uint32_t id;    /* 11-bit (or 29-bit with GS_CAN_FLAG_EXT) identifier */
    uint8_t len;    /* data bytes: 0..8 classic, an FD length 0..64 */
    uint8_t flags;  /* GS_CAN_FLAG_* */
    uint8_t data[GS_CAN_MAX_DATA];
} gs_can_frame_t;

/* Function codes (bits 10..7 of the id; protocol.can.ids.FunctionCode): lower = higher bus priority. */
enum {
    GS_CAN_FN_ESTOP = 0x0, GS_CAN_FN_SERVO_FRAME, GS_CAN_FN_TIME_SYNC_REQUEST, GS_CAN_FN_TIME_SYNC_REPLY,
    GS_CAN_FN_FLUSH, GS_CAN_FN_ADVANCE, GS_CAN_FN_ESTOP_CLEAR, GS_CAN_FN_ACK, GS_CAN_FN_NACK, GS_CAN_FN_TELEMETRY,
    GS_CAN_FN_HEARTBEAT_HOST, GS_CAN_FN_HEARTBEAT_BOARD, GS_CAN_FN_BULK_TO_BOARD, GS_CAN_FN_BULK_TO_HOST
};
#define GS_CAN_ID(fn, node) ((uint32_t)(fn) << 7 | (uint32_t)(node))

/* ---- the generated layout table's types (gs_can_layouts.h) ---- */
enum {
    GS_CAN_K_UINT = 1, GS_CAN_K_SINT, GS_CAN_K_BOOL, GS_CAN_K_ENUM, GS_CAN_K_FLAGS, GS_CAN_K_MASK,
    GS_CAN_K_Q16_FIXED, GS_CAN_K_Q16_MASKED, GS_CAN_K_Q16_COUNTED, GS_CAN_K_OMITTED
};
#define GS_CAN_F_WRAP 0x1u   /* an integer that wraps modulo its width (else it clamps) */
#define GS_CAN_F_NONAN 0x2u  /* a q16 array that refuses the -32768 code */
#define GS_CAN_F_DRIVES 0x4u /* a mask driving a per-servo array: bits only below the robot's servo count */

typedef struct {
    uint8_t kind;       /* GS_CAN_K_* */
    uint8_t flags;      /* GS_CAN_F_* */
    uint8_t size;       /* bytes of the C member (array: of one element) */
    uint8_t bits;       /* bits of each of its signals */
    uint8_t nsig;       /* its signals (0: omitted on CAN) */
    uint8_t mask_field; /* masked array: index of the mask field in the message's fields */
    uint16_t offset;    /* offsetof(gs_msg_t, member) */
    uint16_t count_offset; /* counted/masked array: offsetof its uint8_t _n; omitted: its _len */
    const uint8_t *enum_members; /* enum: bitmap of the allowed values */
} gs_can_field_t;

typedef struct {
    uint8_t msg_type;
    uint8_t nfields;
    const gs_can_field_t *fields;
} gs_can_message_t;

typedef struct {
    uint8_t part;
    uint16_t start; /* little-endian bit of the frame's data */
    uint8_t bits;
    uint8_t is_signed;
} gs_can_place_t;

typedef struct {
    uint8_t msg_type;
    uint8_t fn;
    uint8_t fd;
    uint8_t parts;
    uint8_t length; /* data bytes of every frame of the message */
    uint8_t nsig;   /* the fields' signals, then crc16 when has_crc */
    uint8_t has_crc;
    const uint8_t *part_bytes; /* bytes each part needs (header included) */
    const gs_can_place_t *sig;
} gs_can_layout_t;

/* ---- fixed layouts ---- */
#define GS_CAN_SENDER_HOST 0
#define GS_CAN_SENDER_BOARD 1

/* The robot's servo count the table was generated for. */
unsigned gs_can_servo_count(void);
/* The layout of function code `fn` in this frame kind (NULL: that message travels as ISO-TP bulk there). */
const gs_can_layout_t *gs_can_layout(unsigned fn, int fd);
/* 1 when `m` travels as fixed-layout frames of this frame kind (protocol.can.codec.is_fixed), 0: bulk. */
int gs_can_is_fixed(const gs_msg_t *m, int fd);
/* The frames carrying `m` with sequence `seq` to/from board `node`, in part order, into `out` (at most
 * `cap`); `sender` only matters for HEARTBEAT. The frame count, or GS_E_VALUE / GS_E_TYPE / GS_E_SPACE
 * with `why` (a value it cannot carry, no fixed layout, `cap` too small). */
int gs_can_encode_fixed(const gs_msg_t *m, uint16_t seq, unsigned node, int fd, int sender, gs_can_frame_t *out,
                        size_t cap, const char **why);

/* ---- bulk units ---- */
#define GS_CAN_BULK_MAX (3u + GS_MAX_PAYLOAD + 2u) /* type, seq, payload, crc */
/* `m` as a bulk unit into `out`: its length, or GS_E_* (a message the codec refuses, `cap` too small). */
int gs_can_encode_bulk(const gs_msg_t *m, uint16_t seq, uint8_t *out, size_t cap);
/* A bulk unit: 0 with `seq` and `m`, or GS_E_* with `why` (short, CRC, unknown type, payload). */
int gs_can_decode_bulk(const uint8_t *sdu, size_t n, uint16_t *seq, gs_msg_t *m, const char **why);

/* 16-bit sequence nearest to `reference` whose low 11 bits are `seq11` (protocol.can.layouts.unwrap_seq). */
uint16_t gs_can_unwrap_seq(unsigned seq11, uint16_t reference);

/* ---- the receiver (protocol.can.decoder.CanDecoder) ---- */
typedef enum {
    GS_CAN_ITEM_MESSAGE = 0,
    GS_CAN_E_EXTENDED_ID, GS_CAN_E_REMOTE, GS_CAN_E_LENGTH, GS_CAN_E_PART, GS_CAN_E_PAYLOAD,
    GS_CAN_E_INCOMPLETE, GS_CAN_E_MIXED, GS_CAN_E_BULK, GS_CAN_E_CRC,
    GS_CAN_ITEM_KINDS
} gs_can_item_kind_t;

typedef struct {
    gs_can_item_kind_t kind;
    uint16_t seq;
    uint8_t bulk;       /* the message came as an ISO-TP unit */
    gs_msg_t msg;       /* kind == GS_CAN_ITEM_MESSAGE */
    const char *why;    /* static text for errors */
    size_t raw_len;     /* bytes of the frames it came in (errors: of the frame) */
} gs_can_item_t;

#define GS_CAN_MAX_ASSEMBLIES 2u  /* sequences of one function code assembled at once */
#define GS_CAN_STALE_FRAMES 512u  /* frames after which an unfinished assembly (a surfaced sequence) is forgotten */
#define GS_CAN_DONE_KEPT (2u * GS_CAN_MAX_ASSEMBLIES)
#define GS_CAN_RX_FNS 8u          /* function codes one receiver assembles (7 per direction) */
#define GS_CAN_MAX_PARTS 32u
/* Most items one frame can produce (stale and displaced assemblies, a mixed part, the message). */
#define GS_CAN_MAX_ITEMS_PER_FRAME 8u

typedef struct {
    uint8_t used;
    uint8_t fd;
    uint16_t seq11;
    uint32_t born;     /* the decoder's frame count at its first part */
    uint32_t have;     /* bit k: part k arrived */
    uint8_t order[GS_CAN_MAX_PARTS]; /* parts in arrival order */
    uint8_t nparts;
    uint8_t len[GS_CAN_MAX_PARTS];
    uint8_t data[GS_CAN_MAX_PARTS][GS_CAN_MAX_DATA];
} gs_can_assembly_t;

typedef struct {
    uint8_t fn;        /* 0xFF: unused slot */
    gs_can_assembly_t asm_[GS_CAN_MAX_ASSEMBLIES]; /* oldest first */
    uint8_t nasm;
    uint16_t done_seq[GS_CAN_DONE_KEPT];
    uint32_t done_at[GS_CAN_DONE_KEPT];
    uint8_t ndone, done_head;
} gs_can_rx_fn_t;

typedef struct {
    uint8_t node;
    uint8_t receiver_board; /* 1: the board receives (host->board function codes), 0: the host */
    uint16_t last_seq;
    uint32_t frames, foreign, duplicates;
    uint32_t errors[GS_CAN_ITEM_KINDS];
    gs_can_rx_fn_t fns[GS_CAN_RX_FNS];
} gs_can_decoder_t;

void gs_can_decoder_init(gs_can_decoder_t *d, unsigned node, int receiver_board);
/* Consume one frame; writes the messages it completes and the errors it causes to `items` (room for
 * GS_CAN_MAX_ITEMS_PER_FRAME) and returns their count. Never fails. */
size_t gs_can_decoder_feed(gs_can_decoder_t *d, const gs_can_frame_t *f, gs_can_item_t *items);
/* One reassembled ISO-TP unit -> one item (its sequence re-anchors the unwrapping). */
void gs_can_decoder_feed_bulk(gs_can_decoder_t *d, const uint8_t *sdu, size_t n, gs_can_item_t *item);
const char *gs_can_item_kind_name(gs_can_item_kind_t k);

#endif
