/* Servo-bus master: the Feetech SCS/STS packet protocol (STS byte order: little-endian words).
 *
 * Instruction packet: 0xFF 0xFF ID LENGTH INSTRUCTION PARAM... CHECKSUM, LENGTH = params + 2,
 * CHECKSUM = ~(ID + LENGTH + INSTRUCTION + params) & 0xFF. Status packet: 0xFF 0xFF ID LENGTH
 * ERROR PARAM... CHECKSUM. SYNC WRITE (0x83) to the broadcast id 0xFE has no reply; SYNC READ
 * (0x82) is answered by each listed servo in turn. Written by hand: the vendor SDK
 * (feetech-servo-sdk) is Python for a host computer; tests drive the emulated servos with it.
 *
 * Devices on the bus: servos id 1..N (the servo table), an IMU at GS_IMU_ID and, in the emulator
 * only, a ground-truth probe at GS_PROBE_ID (firmware_sim/plant documents their registers). */
#ifndef GS_BUS_H
#define GS_BUS_H

#include <stddef.h>
#include <stdint.h>

#include "gs_servo_table.h" /* generated per robot: GS_SERVO_COUNT sizes the longest packet */

#define GS_BUS_BROADCAST 0xFEu
#define GS_INST_PING 0x01u
#define GS_INST_READ 0x02u
#define GS_INST_WRITE 0x03u
#define GS_INST_SYNC_READ 0x82u
#define GS_INST_SYNC_WRITE 0x83u

#define GS_REG_MODEL 3u            /* u16 model number */
#define GS_REG_TORQUE_ENABLE 40u   /* u8 */
#define GS_REG_GOAL_POSITION 42u   /* u16 steps (bit 15 = sign) */
#define GS_REG_PRESENT 56u         /* position u16, speed u16 (bit 15 sign, steps/s), load u16 (bit 10 sign, 0.1 %) */
#define GS_PRESENT_LEN 6u

#define GS_IMU_ID 0xF0u            /* roll, pitch, yaw: i16 x 1e-4 rad at GS_REG_PRESENT */
#define GS_IMU_LEN 6u
#define GS_PROBE_ID 0xF1u          /* emulator only: base pos f32 x3, quat f32 x4, objects u8, toppled u8 */
#define GS_PROBE_LEN 30u

/* Parameters of the longest instruction: the goal-position SYNC WRITE to every servo (address,
 * length, then id + u16 per servo: 2 + 3 N; 98 for 32 servos, LENGTH 100 of 255), at least 64
 * (a status packet's room: the probe's 30-byte READ reply). Sized per robot, so no goal write is
 * ever too long to send. */
#define GS_BUS_GOAL_SYNC_PARAMS (2u + 3u * GS_SERVO_COUNT)
#define GS_BUS_MAX_PARAMS (GS_BUS_GOAL_SYNC_PARAMS > 64u ? GS_BUS_GOAL_SYNC_PARAMS : 64u)
#if GS_BUS_MAX_PARAMS + 2u > 255u
#error "the goal SYNC WRITE does not fit a Feetech packet (LENGTH is one byte)"
#endif

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
/* 1 when a late status packet from `id` was seen since the last call for that id (and forgets it). */
int gs_bus_heard_late(uint8_t id);

/* SYNC WRITE `len` bytes at `addr` to each of `n` ids (`data`: n * len bytes, id order). */
void gs_bus_sync_write(uint8_t addr, uint8_t len, const uint8_t *ids, size_t n, const uint8_t *data);
/* SYNC READ `len` bytes at `addr` from `n` ids into `data` (n * len); returns the bit mask of the
 * ids (by position in `ids`) that answered within `timeout_us`. */
uint32_t gs_bus_sync_read(uint8_t addr, uint8_t len, const uint8_t *ids, size_t n, uint8_t *data, uint32_t timeout_us);
/* READ `len` bytes at `addr` of one device; 1 when it answered. */
int gs_bus_read(uint8_t id, uint8_t addr, uint8_t len, uint8_t *data, uint32_t timeout_us);
/* PING one device; 1 when it answered. */
int gs_bus_ping(uint8_t id, uint32_t timeout_us);

#endif
