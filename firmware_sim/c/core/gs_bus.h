/* Servo-bus master, protocol-neutral: what the board core asks of its servos (ping + model number, the
 * goal positions, the present position/speed/load with the servo's error flags, torque enable, one
 * device's registers for the IMU and the probe), over one of two wire protocols chosen at boot
 * (gs_settings_t.bus_protocol):
 *
 *   GS_BUS_STS   Feetech SCS/STS (gs_bus_sts.c): 0xFF 0xFF ID LEN INST|ERR PARAM... ~SUM, 1-byte
 *                addresses, STS3215 registers (torque 40, goal 42, present 56..61, error = the status byte);
 *   GS_BUS_DXL2  ROBOTIS Dynamixel Protocol 2.0 (gs_bus_dxl2.c): 0xFF 0xFF 0xFD 0x00 ID LEN16 INST PARAM...
 *                CRC16, byte stuffing, X-series registers (torque 64, hardware error status 70, goal 116,
 *                present current/velocity/position 126..135: one SYNC READ per group; the status packet's
 *                alert bit -> register 70).
 *
 * gs_bus.c holds what both share: the received bytes, the late-reply bookkeeping, the statistics and the
 * transactions (send, wait for the status packets asked for); the protocol files encode instructions and
 * parse status packets. Devices on the bus: servos id 1..N (the servo table), an IMU at GS_IMU_ID and, in
 * the emulator only, a ground-truth probe at GS_PROBE_ID (firmware_sim/plant documents their registers,
 * the same register file under both protocols). Positions are raw register steps (GS_STEP_CENTRE = the
 * horn centre, both protocols); speeds steps/s; loads per mille of full torque (signed). */
#ifndef GS_BUS_H
#define GS_BUS_H

#include <stddef.h>
#include <stdint.h>

#include "gs_servo_table.h" /* generated per robot: GS_SERVO_COUNT sizes the longest packet */

typedef enum { GS_BUS_STS = 0, GS_BUS_DXL2 = 1 } gs_bus_protocol_t;

#define GS_BUS_BROADCAST 0xFEu
#define GS_INST_PING 0x01u
#define GS_INST_READ 0x02u
#define GS_INST_WRITE 0x03u
#define GS_INST_SYNC_READ 0x82u
#define GS_INST_SYNC_WRITE 0x83u

/* Feetech STS register map (gs_bus_sts.c) */
#define GS_REG_MODEL 3u            /* u16 model number */
#define GS_REG_TORQUE_ENABLE 40u   /* u8 */
#define GS_REG_GOAL_POSITION 42u   /* u16 steps (bit 15 = sign) */
#define GS_REG_PRESENT 56u         /* position u16, speed u16 (bit 15 sign, steps/s), load u16 (bit 10 sign, 0.1 %) */
#define GS_PRESENT_LEN 6u

/* Dynamixel X-series control table (gs_bus_dxl2.c) */
#define GS_DXL_MODEL 0u              /* u16 model number (also in the PING status) */
#define GS_DXL_TORQUE_ENABLE 64u     /* u8 */
#define GS_DXL_HW_ERROR 70u          /* u8 hardware error status */
#define GS_DXL_GOAL_POSITION 116u    /* i32 steps */
#define GS_DXL_PRESENT 126u          /* current i16 (mA), velocity i32 (0.229 rpm), position i32 (steps) */
#define GS_DXL_PRESENT_LEN 10u
#define GS_DXL_STALL_MA 1750         /* the current of a 100 % load reading (XL330: its current limit, as the plant models it) */

/* The IMU and the probe: the same register file under both protocols (firmware_sim/plant/devices.py) */
#define GS_DEV_PRESENT 56u
#define GS_IMU_ID 0xF0u            /* roll, pitch, yaw: i16 x 1e-4 rad at GS_DEV_PRESENT */
#define GS_IMU_LEN 6u
#define GS_PROBE_ID 0xF1u          /* emulator only: base pos f32 x3, quat f32 x4, objects u8, toppled u8 */
#define GS_PROBE_LEN 30u

/* Parameters of the longest instruction: the goal-position SYNC WRITE to every servo (STS: address, length,
 * then id + u16 per servo: 2 + 3 N; Dynamixel: address u16, length u16, id + i32 per servo: 4 + 5 N), at
 * least 64 (a status packet's room: the probe's 30-byte READ reply). Sized per robot, so no goal write is
 * ever too long to send. */
#define GS_BUS_GOAL_SYNC_PARAMS (4u + 5u * GS_SERVO_COUNT)
#define GS_BUS_MAX_PARAMS (GS_BUS_GOAL_SYNC_PARAMS > 64u ? GS_BUS_GOAL_SYNC_PARAMS : 64u)
#if 2u + 3u * GS_SERVO_COUNT + 2u > 255u
#error "the goal SYNC WRITE does not fit a Feetech packet (LENGTH is one byte)"
#endif
/* the longest packet on the wire: a Dynamixel one with every third byte stuffed */
#define GS_BUS_MAX_PACKET (10u + GS_BUS_MAX_PARAMS + GS_BUS_MAX_PARAMS / 3u + 2u)

/* Servo error flags (gs_present_t.error, gs_bus_read_errors): the Dynamixel hardware error status bits,
 * STS status error bits mapped onto them (voltage 0x01, overheat 0x04, overload 0x20; its overcurrent 0x08
 * is GS_SERVO_ERR_OVERCURRENT; its angle-limit bit 0x02 is no hardware fault and is dropped). */
#define GS_SERVO_ERR_VOLTAGE 0x01u
#define GS_SERVO_ERR_OVERHEAT 0x04u
#define GS_SERVO_ERR_ENCODER 0x08u
#define GS_SERVO_ERR_SHOCK 0x10u
#define GS_SERVO_ERR_OVERLOAD 0x20u
#define GS_SERVO_ERR_OVERCURRENT 0x40u
#define GS_SERVO_ERR_ALERT 0x80u /* Dynamixel: the status packet's alert bit; gs_bus_read_errors says which */

typedef struct {
    int32_t pos;   /* steps */
    int32_t speed; /* steps/s */
    int32_t load;  /* per mille of full torque */
    uint8_t error; /* GS_SERVO_ERR_* */
    uint8_t valid; /* 0: the servo answered with an error number instead of data (Dynamixel) */
} gs_present_t;

typedef struct {
    uint32_t packets_out, packets_in, timeouts, bad_packets;
    uint32_t late_replies; /* status packets that came after their request's deadline (found before the next send) */
    uint32_t tx_dropped;   /* bytes the port could not hand to a bus nobody read (native: 2 ms) */
    uint64_t bytes_out, bytes_in;
} gs_bus_stats_t;

extern gs_bus_stats_t gs_bus_stats;

/* Lateness versus silence. A status packet that arrives after its request's deadline (the plant, or this
 * board's own process, was descheduled) is not thrown away unread: before each new request the bytes
 * waiting on the bus are parsed, every whole status packet among them counts in `late_replies`, and its
 * id is remembered until gs_bus_heard_late() asks for it. `gs_bus_answers` counts every status packet
 * received, on time or late: a caller compares it between two reads to tell "this device stayed silent
 * while others answered" (a device gone) from "nothing answered at all" (the plant is not running). */
extern uint32_t gs_bus_answers;
/* Every byte read from the bus (valid packets or not): beside gs_bus_stats.bytes_in (the bytes of valid status
 * packets) it tells "garbled bytes came" (two servos with one id, noise) from "nothing came" (boot checks). */
extern uint32_t gs_bus_rx_bytes;
/* Boot: listen `wait_us` for anything more on the bus (a second servo answering with the same id); the bytes
 * heard, also any not yet parsed, which are dropped. */
size_t gs_bus_listen(uint32_t wait_us);
/* Microseconds the line needs for `bytes` at its baud (0 on a socket). */
uint32_t gs_bus_wire_us(size_t bytes);
/* WRITE `len` (<= 8) bytes at `addr` of one servo, which answers; 1 when it answered and (Dynamixel) did not
 * refuse with an error number. */
int gs_bus_write_reg(uint8_t id, uint16_t addr, const uint8_t *data, uint8_t len, uint32_t timeout_us);
/* 1 when a late status packet from `id` was seen since the last call for that id (and forgets it). */
int gs_bus_heard_late(uint8_t id);

/* Select the protocol and forget every received byte (boot). `baud`: the line's rate, which lengthens the
 * reply deadlines by the expected answers' wire time (0: a socket to the plant, no wire time). */
void gs_bus_init(gs_bus_protocol_t protocol, uint32_t baud);
gs_bus_protocol_t gs_bus_protocol(void);
const char *gs_bus_protocol_name(gs_bus_protocol_t protocol);

/* PING one device; 1 when it answered. `model` (may be NULL): its model number (Dynamixel: from the PING
 * status; STS: a READ of register 3 after the PING), 0 when unknown. */
int gs_bus_ping(uint8_t id, uint32_t timeout_us, uint16_t *model);
/* The goal positions (steps) of `n` servos: one SYNC WRITE (no reply). */
void gs_bus_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps);
/* Torque enable of `n` servos: one SYNC WRITE (no reply). */
void gs_bus_torque(const uint8_t *ids, size_t n, int on);
/* Torque off for every servo on the bus: a WRITE to the broadcast id (no reply). */
void gs_bus_torque_off_all(void);
/* One SYNC READ of present position, speed and load of `n` servos (`out[i]` for `ids[i]`); returns the bit
 * mask (by position in `ids`) of the servos whose answer came within `timeout_us`. */
uint32_t gs_bus_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us);
/* The servo's hardware error flags (GS_SERVO_ERR_*: Dynamixel register 70; STS: a PING's status error byte);
 * 1 when it answered. */
int gs_bus_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us);
/* READ `len` bytes at `addr` of one device's register file (the IMU, the probe); 1 when it answered. */
int gs_bus_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us);

/* --- between gs_bus.c and the protocol files ----------------------------------------------------------- */

typedef struct {
    int id;              /* the answering device */
    uint8_t error;       /* the status packet's error byte, as on the wire */
    size_t n;            /* parameter bytes (unstuffed) */
    uint8_t params[GS_BUS_MAX_PARAMS];
} gs_status_t;

/* One protocol's framing: encode an instruction packet into `out` (returns its length, 0 when it does not
 * fit); parse one status packet from the head of `rx` (returns 1 with `st` filled and the packet consumed,
 * 0 when no whole packet is there yet: garbage before a header is dropped, a packet with a bad checksum is
 * consumed and counted in bad_packets); whether `rx` starts with (a prefix of) a header. */
typedef struct {
    size_t (*encode)(uint8_t *out, size_t cap, uint8_t id, uint8_t inst, const uint8_t *params, size_t n);
    int (*parse)(uint8_t *rx, size_t *rx_len, gs_status_t *st);
    int (*starts_header)(const uint8_t *rx, size_t n);
} gs_bus_codec_t;

extern const gs_bus_codec_t gs_bus_sts_codec, gs_bus_dxl2_codec;

/* shared transactions (gs_bus.c) for the protocol files */
void gs_bus_send(uint8_t id, uint8_t inst, const uint8_t *params, size_t n);
/* Wait for the status packet of `id` with `len` parameter bytes (or any length when len < 0) until the
 * deadline; 1 with `st` filled, 0 on timeout or stop. Other packets meanwhile count as late. */
int gs_bus_await(uint8_t id, int len, uint64_t deadline, gs_status_t *st);
/* SYNC READ answers: each of `ids` in turn; `on_status(k, st, ctx)` for the k-th id's packet whose length
 * is `len`; returns the mask of ids that answered. */
uint32_t gs_bus_collect(const uint8_t *ids, size_t n, size_t len, uint64_t deadline,
                        void (*on_status)(size_t k, const gs_status_t *st, void *ctx), void *ctx);
/* Microseconds the line needs for `bytes` (0 on a socket), and the deadline of a request whose answers
 * are `reply_bytes` long. */
uint64_t gs_bus_deadline(uint32_t timeout_us, size_t reply_bytes);

/* the protocol files' request functions (gs_bus.c dispatches) */
int gs_sts_ping(uint8_t id, uint32_t timeout_us, uint16_t *model);
void gs_sts_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps);
void gs_sts_torque(const uint8_t *ids, size_t n, int on);
void gs_sts_torque_off_all(void);
uint32_t gs_sts_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us);
int gs_sts_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us);
int gs_sts_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us);
int gs_dxl2_ping(uint8_t id, uint32_t timeout_us, uint16_t *model);
void gs_dxl2_write_goals(const uint8_t *ids, size_t n, const uint16_t *steps);
void gs_dxl2_torque(const uint8_t *ids, size_t n, int on);
void gs_dxl2_torque_off_all(void);
uint32_t gs_dxl2_read_present(const uint8_t *ids, size_t n, gs_present_t *out, uint32_t timeout_us);
int gs_dxl2_read_errors(uint8_t id, uint8_t *errors, uint32_t timeout_us);
int gs_dxl2_read(uint8_t id, uint16_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us);

#endif
