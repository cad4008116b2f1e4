/* ROBOTIS Dynamixel Protocol 2.0, master side, for X-series servos (XL330, XM430 ...).
 *
 * Instruction packet: 0xFF 0xFF 0xFD 0x00 ID LEN_L LEN_H INST PARAM... CRC_L CRC_H, LEN = the bytes after
 * it (instruction, stuffed params, CRC). Status packet: ... ID LEN_L LEN_H 0x55 ERROR PARAM... CRC. The CRC
 * is CRC-16 (polynomial 0x8005, initial 0, not reflected: ROBOTIS's updateCRC) over every byte from the
 * header to the last parameter as sent (stuffed). Byte stuffing: wherever 0xFF 0xFF 0xFD occurs from the
 * instruction on, a 0xFD is inserted after it (and removed again on receive). Addresses and lengths are
 * little-endian u16. ERROR: bit 7 = alert (a hardware error: register 70 says which), bits 0..6 an error
 * number (1 result fail, 2 instruction, 3 CRC, 4 data range, 5 data length, 6 data limit, 7 access): a
 * status with an error number carries no data that is used. SYNC READ (0x82: addr, len, ids) is answered
 * by each id in turn; SYNC WRITE (0x83: addr, len, then id + data per servo) and a WRITE to the broadcast
 * id have no reply. Written by hand after the ROBOTIS e-Manual; tests check it against the dynamixel-sdk.
 *
 * Units (X series): present current mA (GS_DXL_STALL_MA = a 100 % load), present velocity 0.229 rpm,
 * positions 4096 steps a turn (GS_STEP_CENTRE = the horn centre, as on STS). */
#include "gs_bus.h"

#define DXL_STATUS 0x55u
#define DXL_MAX_ID 0xFCu

static const uint16_t crc_table[256] = {
    0x0000u, 0x8005u, 0x800Fu, 0x000Au, 0x801Bu, 0x001Eu, 0x0014u, 0x8011u,
    0x8033u, 0x0036u, 0x003Cu, 0x8039u, 0x0028u, 0x802Du, 0x8027u, 0x0022u,
    0x8063u, 0x0066u, 0x006Cu, 0x8069u, 0x0078u, 0x807Du, 0x8077u, 0x0072u,
    0x0050u, 0x8055u, 0x805Fu, 0x005Au, 0x804Bu, 0x004Eu, 0x0044u, 0x8041u,
    0x80C3u, 0x00C6u, 0x00CCu, 0x80C9u, 0x00D8u, 0x80DDu, 0x80D7u, 0x00D2u,
    0x00F0u, 0x80F5u, 0x80FFu, 0x00FAu, 0x80EBu, 0x00EEu, 0x00E4u, 0x80E1u,
    0x00A0u, 0x80A5u, 0x80AFu, 0x00AAu, 0x80BBu, 0x00BEu, 0x00B4u, 0x80B1u,
    0x8093u, 0x0096u, 0x009Cu, 0x8099u, 0x0088u, 0x808Du, 0x8087u, 0x0082u,
    0x8183u, 0x0186u, 0x018Cu, 0x8189u, 0x0198u, 0x819Du, 0x8197u, 0x0192u,
    0x01B0u, 0x81B5u, 0x81BFu, 0x01BAu, 0x81ABu, 0x01AEu, 0x01A4u, 0x81A1u,
    0x01E0u, 0x81E5u, 0x81EFu, 0x01EAu, 0x81FBu, 0x01FEu, 0x01F4u, 0x81F1u,
    0x81D3u, 0x01D6u, 0x01DCu, 0x81D9u, 0x01C8u, 0x81CDu, 0x81C7u, 0x01C2u,
    0x0140u, 0x8145u, 0x814Fu, 0x014Au, 0x815Bu, 0x015Eu, 0x0154u, 0x8151u,
    0x8173u, 0x0176u, 0x017Cu, 0x8179u, 0x0168u, 0x816Du, 0x8167u, 0x0162u,
    0x8123u, 0x0126u, 0x012Cu, 0x8129u, 0x0138u, 0x813Du, 0x8137u, 0x0132u,
    0x0110u, 0x8115u, 0x811Fu, 0x011Au, 0x810Bu, 0x010Eu, 0x0104u, 0x8101u,
    0x8303u, 0x0306u, 0x030Cu, 0x8309u, 0x0318u, 0x831Du, 0x8317u, 0x0312u,
    0x0330u, 0x8335u, 0x833Fu, 0x033Au, 0x832Bu, 0x032Eu, 0x0324u, 0x8321u,
    0x0360u, 0x8365u, 0x836Fu, 0x036Au, 0x837Bu, 0x037Eu, 0x0374u, 0x8371u,
    0x8353u, 0x0356u, 0x035Cu, 0x8359u, 0x0348u, 0x834Du, 0x8347u, 0x0342u,
    0x03C0u, 0x83C5u, 0x83CFu, 0x03CAu, 0x83DBu, 0x03DEu, 0x03D4u, 0x83D1u,
    0x83F3u, 0x03F6u, 0x03FCu, 0x83F9u, 0x03E8u, 0x83EDu, 0x83E7u, 0x03E2u,
    0x83A3u, 0x03A6u, 0x03ACu, 0x83A9u, 0x03B8u, 0x83BDu, 0x83B7u, 0x03B2u,
    0x0390u, 0x8395u, 0x839Fu, 0x039Au, 0x838Bu, 0x038Eu, 0x0384u, 0x8381u,
    0x0280u, 0x8285u, 0x828Fu, 0x028Au, 0x829Bu, 0x029Eu, 0x0294u, 0x8291u,
    0x82B3u, 0x02B6u, 0x02BCu, 0x82B9u, 0x02A8u, 0x82ADu, 0x82A7u, 0x02A2u,
    0x82E3u, 0x02E6u, 0x02ECu, 0x82E9u, 0x02F8u, 0x82FDu, 0x82F7u, 0x02F2u,
    0x02D0u, 0x82D5u, 0x82DFu, 0x02DAu, 0x82CBu, 0x02CEu, 0x02C4u, 0x82C1u,
    0x8243u, 0x0246u, 0x024Cu, 0x8249u, 0x0258u, 0x825Du, 0x8257u, 0x0252u,
    0x0270u, 0x8275u, 0x827Fu, 0x027Au, 0x826Bu, 0x026Eu, 0x0264u, 0x8261u,
    0x0220u, 0x8225u, 0x822Fu, 0x022Au, 0x823Bu, 0x023Eu, 0x0234u, 0x8231u,
    0x8213u, 0x0216u, 0x021Cu, 0x8219u, 0x0208u, 0x820Du, 0x8207u, 0x0202u,
};

static uint16_t crc16(uint16_t crc, const uint8_t *d, size_t n) {
    for (size_t i = 0; i < n; i++) crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ d[i]) & 0xFFu]);
    return crc;
}

static size_t dxl_encode(uint8_t *pkt, size_t cap, uint8_t id, uint8_t inst, const uint8_t *params, size_t n) {
    size_t k = 7;
    if (n > GS_BUS_MAX_PARAMS || cap < 10u) return 0;
    pkt[0] = 0xFFu;
    pkt[1] = 0xFFu;
    pkt[2] = 0xFDu;
    pkt[3] = 0x00u;
    pkt[4] = id;
    pkt[k++] = inst;
    for (size_t i = 0; i < n; i++) {
        if (k + 4u > cap) return 0; /* room for a stuffing byte and the CRC */
        pkt[k++] = params[i];
        /* FF FF FD from the instruction on (the instruction is never 0xFF) gets a 0xFD after it */
        if (params[i] == 0xFDu && k >= 10u && pkt[k - 2] == 0xFFu && pkt[k - 3] == 0xFFu) pkt[k++] = 0xFDu;
    }
    size_t len = k - 7u + 2u;
    pkt[5] = (uint8_t)(len & 0xFFu);
    pkt[6] = (uint8_t)(len >> 8);
    uint16_t crc = crc16(0, pkt, k);
    pkt[k++] = (uint8_t)(crc & 0xFFu);
    pkt[k++] = (uint8_t)(crc >> 8);
    return k;
}

static int dxl_starts_header(const uint8_t *rx, size_t n) {
    return n >= 4u && rx[0] == 0xFFu && rx[1] == 0xFFu && rx[2] == 0xFDu && rx[3] == 0x00u;
}

static void drop(uint8_t *rx, size_t *rx_len, size_t k) {
    for (size_t i = k; i < *rx_len; i++) rx[i - k] = rx[i];
    *rx_len -= k;
}

/* Parse one status packet from rx[]; 1 with `st` filled, 0 when incomplete. An instruction packet (an
 * adapter that echoes what it sends) is skipped whole; a packet with a bad CRC or an impossible length
 * counts in bad_packets and the search resumes one byte further. */
static int dxl_parse(uint8_t *rx, size_t *rx_len, gs_status_t *st) {
    for (;;) {
        size_t s = 0;
        while (s + 3u < *rx_len && !dxl_starts_header(&rx[s], 4u)) s++;
        if (s + 3u >= *rx_len) { /* no whole header: keep the last 3 bytes (a header may start there) */
            if (*rx_len > 3u) drop(rx, rx_len, *rx_len - 3u);
            return 0;
        }
        if (s) drop(rx, rx_len, s);
        if (*rx_len < 7u) return 0;
        size_t len = (size_t)rx[5] | (size_t)rx[6] << 8;
        /* LEN: instruction + error (status) + params (stuffed) + CRC; never more than the buffer holds */
        if (rx[4] > DXL_MAX_ID || len < 3u || len + 7u > GS_BUS_MAX_PACKET) {
            gs_bus_stats.bad_packets++;
            drop(rx, rx_len, 1);
            continue;
        }
        size_t total = len + 7u;
        if (*rx_len < total) return 0;
        uint16_t crc = crc16(0, rx, total - 2u);
        if ((uint8_t)(crc & 0xFFu) != rx[total - 2u] || (uint8_t)(crc >> 8) != rx[total - 1u]) {
            gs_bus_stats.bad_packets++;
            drop(rx, rx_len, 1);
            continue;
        }
        if (rx[7] != DXL_STATUS || len < 4u) { /* an instruction (an echo): not an answer */
            drop(rx, rx_len, total);
            continue;
        }
        /* unstuff instruction .. last param (rx[7] .. rx[total - 3]): FF FF FD FD -> FF FF FD */
        size_t np = 0, body = 0;
        for (size_t i = 7; i + 2u < total; i++) {
            if (rx[i] == 0xFDu && i >= 10u && rx[i - 1] == 0xFDu && rx[i - 2] == 0xFFu && rx[i - 3] == 0xFFu) continue;
            if (body >= 2u) { /* after the instruction and the error byte */
                if (np < sizeof st->params) st->params[np] = rx[i];
                np++;
            }
            body++;
        }
        st->id = rx[4];
        st->error = rx[8];
        st->n = np <= sizeof st->params ? np : sizeof st->params + 1u; /* too long: matches no request */
        drop(rx, rx_len, total);
        gs_bus_stats.packets_in++;
        gs_bus_stats.bytes_in += total;
        gs_bus_answers++;
        return 1;
    }
}

const gs_bus_codec_t gs_bus_dxl2_codec = {dxl_encode, dxl_parse, dxl_starts_header};

/* --- requests ---------------------------------------------------------------------------------------- */

static uint8_t hw_errors(uint8_t reg70) { /* register 70 -> GS_SERVO_ERR_* (the same bits) */
    return (uint8_t)(reg70 & (GS_SERVO_ERR_VOLTAGE | GS_SERVO_ERR_OVERHEAT | GS_SERVO_ERR_ENCODER | GS_SERVO_ERR_SHOCK |
                              GS_SERVO_ERR_OVERLOAD));
}

static int32_t le32(const uint8_t *d) {
    return (int32_t)((uint32_t)d[0] | (uint32_t)d[1] << 8 | (uint32_t)d[2] << 16 | (uint32_t)d[3] << 24);
}

/* SYNC WRITE `len` bytes at `addr` to each of `n` ids (`data`: n * len bytes, id order). */
static void sync_write(uint16_t addr, uint8_t len, const uint8_t *ids, size_t n, const uint8_t *data) {
    uint8_t params[GS_BUS_MAX_PARAMS];
    size_t k = 0;
    if (4u + n * (1u + len) > GS_BUS_MAX_PARAMS) return;
    params[k++] = (uint8_t)(addr & 0xFFu);
    params[k++] = (uint8_t)(addr >> 8);
    params[k++] = len;
    params[k++] = 0;
    for (size_t i = 0; i < n; i++) {
        params[k++] = ids[i];
        for (size_t j = 0; j < len; j++) params[k++] = data[i * len + j];
    }
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_SYNC_WRITE, params, k);
}

void gs_dxl2_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps) {
    uint8_t data[4u * GS_SERVO_COUNT];
    if (n > GS_SERVO_COUNT) return;
    for (size_t i = 0; i < n; i++) {
        data[4 * i] = (uint8_t)(steps[i] & 0xFFu);
        data[4 * i + 1] = (uint8_t)(steps[i] >> 8);
        data[4 * i + 2] = 0;
        data[4 * i + 3] = 0;
    }
    sync_write(GS_DXL_GOAL_POSITION, 4, ids, n, data);
}

void gs_dxl2_torque(const uint8_t *ids, size_t n, int on) {
    uint8_t data[GS_SERVO_COUNT];
    if (n > GS_SERVO_COUNT) return;
    for (size_t i = 0; i < n; i++) data[i] = on ? 1u : 0u;
    sync_write(GS_DXL_TORQUE_ENABLE, 1, ids, n, data);
}

void gs_dxl2_torque_off_all(void) {
    uint8_t params[3] = {GS_DXL_TORQUE_ENABLE, 0, 0};
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_WRITE, params, 3);
}

static void on_present(size_t k, const gs_status_t *st, void *ctx) {
    gs_present_t *p = &((gs_present_t *)ctx)[k];
    const uint8_t *d = st->params;
    int32_t current = (int16_t)(uint16_t)(d[0] | d[1] << 8); /* mA */
    int64_t vel = le32(&d[2]);                                 /* 0.229 rpm */
    p->pos = le32(&d[6]);
    p->speed = (int32_t)(vel * 229 * 4096 / 60000);
    p->load = (int32_t)((int64_t)current * 1000 / GS_DXL_STALL_MA);
    p->error = st->error & 0x80u ? GS_SERVO_ERR_ALERT : 0u;
    p->valid = (st->error & 0x7Fu) == 0u;
}

uint32_t gs_dxl2_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us) {
    uint8_t params[GS_BUS_MAX_PARAMS];
    if (4u + n > GS_BUS_MAX_PARAMS) return 0;
    params[0] = GS_DXL_PRESENT;
    params[1] = 0;
    params[2] = GS_DXL_PRESENT_LEN;
    params[3] = 0;
    for (size_t i = 0; i < n; i++) params[4 + i] = ids[i];
    gs_bus_send(GS_BUS_BROADCAST, GS_INST_SYNC_READ, params, 4u + n);
    return gs_bus_collect(ids, n, GS_DXL_PRESENT_LEN, gs_bus_deadline(timeout_us, n * (11u + GS_DXL_PRESENT_LEN)),
                          on_present, out);
}

int gs_dxl2_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us) {
    uint8_t params[4] = {(uint8_t)(addr & 0xFFu), (uint8_t)(addr >> 8), len, 0};
    gs_status_t st;
    gs_bus_send(id, GS_INST_READ, params, 4);
    if (!gs_bus_await(id, len, gs_bus_deadline(timeout_us, 11u + len), &st) || (st.error & 0x7Fu)) return 0;
    for (size_t j = 0; j < len; j++) data[j] = st.params[j];
    return 1;
}

int gs_dxl2_ping(uint8_t id, uint32_t timeout_us, uint16_t *model) {
    gs_status_t st;
    if (model) *model = 0;
    gs_bus_send(id, GS_INST_PING, 0, 0);
    if (!gs_bus_await(id, -1, gs_bus_deadline(timeout_us, 14u), &st)) return 0;
    if (model && st.n >= 2u) *model = (uint16_t)(st.params[0] | st.params[1] << 8);
    return 1;
}

int gs_dxl2_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us) {
    uint8_t reg;
    if (!gs_dxl2_read(id, GS_DXL_HW_ERROR, 1, &reg, timeout_us)) return 0;
    *errors = hw_errors(reg);
    return 1;
}
