/* The firmware's main loop, shared by every port: the host link, the board core and the
 * frame log, in lockstep (virtual time: tick while the host's frames or ADVANCE cover the next
 * tick, else take the next message; the same byte stream gives the same telemetry whatever its
 * chunking) or realtime (ticks paced by hal_now_us with absolute deadlines, catch-up and resync
 * after falling 100 ms behind, messages handled as they arrive). As firmware_sim/server.py. */
#ifndef GS_APP_H
#define GS_APP_H

#include "gs_board.h"
#include "gs_link.h"

typedef struct {
    gs_board_t board;
    gs_link_t link;
    uint32_t stats_key; /* checksum of the counters last written as an "S" record */
} gs_app_t;

/* Set up (the bus devices are found and checked here) and run until hal_should_stop(); 0, or 2 when a boot
 * check refused the start (gs_board_boot: one line logged, torque off, nothing served: exit with 2). */
int gs_app_run(gs_app_t *app, const gs_settings_t *cfg);
/* The pieces of the loops, for harnesses that drive the core step by step (the fuzz targets); gs_app_init
 * returns gs_board_boot's status. */
int gs_app_init(gs_app_t *app, const gs_settings_t *cfg);
void gs_app_process(gs_app_t *app, const gs_rx_item_t *item);
void gs_app_tick(gs_app_t *app);

#endif
