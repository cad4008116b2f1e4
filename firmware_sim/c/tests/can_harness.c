/* CAN harness for tests/cfirmware/test_can_equivalence.py: one request per stdin line, one answer per line.
 * Frames are written ID:FLAGS:HEX (hex id, GS_CAN_FLAG_* decimal, data hex); messages as TYPE:SEQ:PAYLOADHEX
 * (the serial payload codec's bytes, which the Python side compares with protocol.codec's).
 *   E FD SENDER SEQ NODE TYPE HEX  encode a message fixed      -> "= frame ..." or "ERR why"
 *   X FD TYPE HEX                  is it fixed in this kind?   -> "1" / "0"
 *   B SEQ TYPE HEX                 its bulk unit               -> "= HEX" or "ERR"
 *   R NODE BOARD                   new decoder (BOARD 1: the board receives, 0: the host)
 *   D ID FLAGS HEX                 feed the decoder            -> "= item ..." (M:TYPE:SEQ:HEX or X:KIND)
 *   I RXID TXID FD                 new ISO-TP link
 *   S HEX                          queue a unit                -> "OK" / "FULL"
 *   T ID FLAGS HEX [AT_US]         a received ISO-TP frame that arrived at AT_US (default: the last poll's NOW) -> "OK"
 *   P NOW_US                       poll                        -> "= frame ... | unit ... | ERRORS FC_TIMEOUTS"
 *   C BOARD_US                     board clock mode from now on (a lockstep board's), board time BOARD_US -> "OK"
 *   L NODE FD                      new board CAN link (gs_can_link)
 *   Q PERIODIC NOW TYPE HEX        the board sends             -> "= 1|0"
 *   K NOW ID FLAGS HEX             a frame from the bus        -> "OK"
 *   N                              take every decoded item     -> "= item ..."
 *   W NOW REFUSE                   flush, the bus refusing the first REFUSE writes -> "= frame ..."
 *   G                              backlog and counters        -> "= backlog tx_retries periodic_replaced ..."
 * Built with ASan/UBSan (firmware_sim.cfirmware.build kind "can-harness"). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_can.h"
#include "gs_can_link.h"
#include "gs_isotp.h"
#include "gs_hex.h"

static void frame(const gs_can_frame_t *f) {
    printf(" %x:%u:", (unsigned)f->id, (unsigned)f->flags);
    gs_print_hex(f->data, f->len);
}

/* The `k`-th space-separated word of `line` (0-based), or "". */
static const char *word(const char *line, int k) {
    const char *p = line;
    for (int i = 0; i < k; i++) {
        p = strchr(p, ' ');
        if (!p) return "";
        p++;
    }
    return p;
}

static int parse_msg(unsigned type, const char *hexs, gs_msg_t *m) {
    static uint8_t buf[512];
    int n = gs_unhex(hexs, buf, sizeof buf);
    const char *why = "";
    if (n < 0) return -1;
    return gs_decode_payload((uint8_t)type, buf, (size_t)n, m, &why) == GS_OK ? 0 : -1;
}

static void item(const gs_can_item_t *it) {
    if (it->kind == GS_CAN_ITEM_MESSAGE) {
        static uint8_t buf[512];
        int n = gs_encode_payload(&it->msg, buf, sizeof buf);
        printf(" M:%u:%u:", (unsigned)it->msg.type, (unsigned)it->seq);
        if (n >= 0) gs_print_hex(buf, (size_t)n);
        else printf("ENC%d", n);
    } else {
        printf(" X:%s", gs_can_item_kind_name(it->kind));
    }
}

static int parse_frame(const char *s, gs_can_frame_t *f) {
    unsigned id, flags;
    memset(f, 0, sizeof *f);
    if (sscanf(s, "%x %u", &id, &flags) != 2) return -1;
    int n = gs_unhex(word(s, 2), f->data, sizeof f->data);
    if (n < 0) return -1;
    f->id = id;
    f->flags = (uint8_t)flags;
    f->len = (uint8_t)n;
    return 0;
}

static gs_can_decoder_t dec;
static gs_isotp_t tp;
static gs_can_link_t link_;
static gs_can_frame_t emitted[4096];
static size_t n_emitted;
static uint32_t last_poll_us; /* the last P NOW: a T frame's default arrival */
static uint32_t board_us;     /* C: the board time of board clock mode */
static uint32_t harness_board_now(void *ctx) { (void)ctx; return board_us; }
static char units[8192];
static size_t units_len;
static int refuse_left;

static void on_emit(void *ctx, const gs_can_frame_t *f) {
    (void)ctx;
    if (n_emitted < sizeof emitted / sizeof emitted[0]) emitted[n_emitted++] = *f;
}

static void on_unit(void *ctx, const uint8_t *d, size_t n, int truncated) {
    (void)ctx;
    if (units_len + 2 * n + 8 >= sizeof units) return;
    units[units_len++] = ' ';
    if (truncated) units[units_len++] = '!';
    for (size_t i = 0; i < n; i++) units_len += (size_t)sprintf(units + units_len, "%02x", d[i]);
}

static int on_write(void *ctx, const gs_can_frame_t *f) {
    (void)ctx;
    if (refuse_left > 0) {
        refuse_left--;
        return 0;
    }
    on_emit(NULL, f);
    return 1;
}

int main(void) {
    static char line[16384];
    gs_can_decoder_init(&dec, 1, 1);
    gs_isotp_init(&tp, 0x601, 0x681, 0, on_emit, on_unit, NULL);
    gs_can_link_init(&link_, 1, 0, on_write, NULL, NULL);
    while (fgets(line, sizeof line, stdin)) {
        unsigned a, b, c, d, e;
        gs_msg_t m;
        gs_can_frame_t f;
        const char *why = "";
        switch (line[0]) {
        case 'E': {
            if (sscanf(line + 2, "%u %u %u %u %u", &a, &b, &c, &d, &e) != 5 || parse_msg(e, word(line, 6), &m) != 0) {
                printf("BAD\n");
                break;
            }
            static gs_can_frame_t out[GS_CAN_MAX_PARTS];
            int n = gs_can_encode_fixed(&m, (uint16_t)c, d, (int)a, (int)b, out, GS_CAN_MAX_PARTS, &why);
            if (n < 0) {
                printf("ERR %s\n", why);
                break;
            }
            printf("=");
            for (int i = 0; i < n; i++) frame(&out[i]);
            printf("\n");
            break;
        }
        case 'X':
            if (sscanf(line + 2, "%u %u", &a, &b) != 2 || parse_msg(b, word(line, 3), &m) != 0) printf("BAD\n");
            else printf("%d\n", gs_can_is_fixed(&m, (int)a));
            break;
        case 'B': {
            static uint8_t unit[GS_CAN_BULK_MAX];
            if (sscanf(line + 2, "%u %u", &a, &b) != 2 || parse_msg(b, word(line, 3), &m) != 0) {
                printf("BAD\n");
                break;
            }
            int n = gs_can_encode_bulk(&m, (uint16_t)a, unit, sizeof unit);
            if (n < 0) printf("ERR\n");
            else { printf("= "); gs_print_hex(unit, (size_t)n); printf("\n"); }
            break;
        }
        case 'R':
            if (sscanf(line + 2, "%u %u", &a, &b) != 2) { printf("BAD\n"); break; }
            gs_can_decoder_init(&dec, a, (int)b);
            printf("OK\n");
            break;
        case 'D': {
            gs_can_item_t items[GS_CAN_MAX_ITEMS_PER_FRAME];
            if (parse_frame(line + 2, &f) != 0) { printf("BAD\n"); break; }
            size_t n = gs_can_decoder_feed(&dec, &f, items);
            printf("=");
            for (size_t i = 0; i < n; i++) item(&items[i]);
            printf("\n");
            break;
        }
        case 'I':
            if (sscanf(line + 2, "%x %x %u", &a, &b, &c) != 3) { printf("BAD\n"); break; }
            gs_isotp_init(&tp, a, b, (int)c, on_emit, on_unit, NULL);
            printf("OK\n");
            break;
        case 'S': {
            static uint8_t buf[4096];
            int n = gs_unhex(line + 2, buf, sizeof buf);
            printf("%s\n", n < 0 ? "BAD" : gs_isotp_send(&tp, buf, (size_t)n) == 0 ? "OK" : "FULL");
            break;
        }
        case 'T':
            if (parse_frame(line + 2, &f) != 0) { printf("BAD\n"); break; }
            {
                const char *at = word(line, 4);
                gs_isotp_feed(&tp, &f, *at ? (uint32_t)strtoul(at, NULL, 10) : last_poll_us);
            }
            printf("OK\n");
            break;
        case 'C':
            if (sscanf(line + 2, "%u", &a) != 1) { printf("BAD\n"); break; }
            board_us = a;
            tp.board_now = harness_board_now;
            printf("OK\n");
            break;
        case 'P':
            if (sscanf(line + 2, "%u", &a) != 1) { printf("BAD\n"); break; }
            n_emitted = 0;
            units_len = 0;
            last_poll_us = a;
            gs_isotp_poll(&tp, a);
            printf("=");
            for (size_t i = 0; i < n_emitted; i++) frame(&emitted[i]);
            units[units_len] = 0;
            printf(" |%s | %u %u\n", units, (unsigned)tp.errors, (unsigned)tp.fc_timeouts);
            break;
        case 'L':
            if (sscanf(line + 2, "%u %u", &a, &b) != 2) { printf("BAD\n"); break; }
            gs_can_link_init(&link_, a, (int)b, on_write, NULL, NULL);
            printf("OK\n");
            break;
        case 'Q':
            if (sscanf(line + 2, "%u %u %u", &a, &b, &c) != 3 || parse_msg(c, word(line, 4), &m) != 0) {
                printf("BAD\n");
                break;
            }
            printf("= %d\n", gs_can_link_send(&link_, &m, (int)a, b, &why));
            break;
        case 'K':
            if (sscanf(line + 2, "%u", &a) != 1 || parse_frame(word(line, 2), &f) != 0) { printf("BAD\n"); break; }
            gs_can_link_rx(&link_, &f, a);
            printf("OK\n");
            break;
        case 'N': {
            gs_can_item_t it;
            printf("=");
            while (gs_can_link_next(&link_, &it)) item(&it);
            printf("\n");
            break;
        }
        case 'W': {
            int refuse;
            if (sscanf(line + 2, "%u %d", &a, &refuse) != 2) { printf("BAD\n"); break; }
            n_emitted = 0;
            refuse_left = refuse;
            gs_can_link_flush(&link_, a);
            printf("=");
            for (size_t i = 0; i < n_emitted; i++) frame(&emitted[i]);
            printf("\n");
            break;
        }
        case 'G':
            printf("= %u %u %u %u %u %u\n", (unsigned)gs_can_link_backlog(&link_), (unsigned)link_.tx_retries,
                   (unsigned)link_.periodic_replaced, (unsigned)link_.periodic_unheard, (unsigned)link_.nack_details_dropped,
                   (unsigned)link_.tx_seq);
            break;
        default:
            printf("BAD\n");
        }
        fflush(stdout);
    }
    return 0;
}
