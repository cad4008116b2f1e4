/* The CAN controller a port brings up when it serves the host link over CAN (its own HAL, next to gs_hal.h:
 * a port with only the serial link implements nothing here and links no CAN code). Non-blocking; no allocation.
 * The port filters what it receives on the node id (id & 0x7F == node, standard frames) and the broadcast ESTOP
 * 0x000, as firmware_sim/transports/can.py's bus filter. */
#ifndef GS_CAN_HAL_H
#define GS_CAN_HAL_H

#include <stdint.h>

#include "gs_can.h"

/* One received frame: 1 with `f` filled, 0 when none waits. */
int hal_can_recv(gs_can_frame_t *f);
/* Hand one frame to the controller: 1 queued for the bus, 0 its transmit queue is full now (SocketCAN ENOBUFS:
 * retried later, in order), -1 it cannot carry this frame (an FD frame on a classic controller: dropped). */
int hal_can_send(const gs_can_frame_t *f);
/* Sleep until `until_us` (hal_now_us clock), a received frame, or (want_write) room in the transmit queue. */
void hal_can_wait(uint64_t until_us, int want_write);

#endif
