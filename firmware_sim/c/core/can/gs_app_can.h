/* The main loops over a CAN link (gs_serve.h with the board's CAN link, gs_can_link.h, on the CAN HAL,
 * gs_can_hal.h): the same lockstep and realtime semantics as the serial link's gs_app.h, messages taken in
 * stream order. The frame log: with cfg.log_frames every frame received and every frame handed to the bus is a
 * log-channel record "C rx|tx T_US ID FLAGS HEX" (hex id, GS_CAN_FLAG_* decimal, data hex; T_US the board time),
 * which the launcher writes as the Python board's CAN frame log (protocol.logfile). */
#ifndef GS_APP_CAN_H
#define GS_APP_CAN_H

#include "gs_board.h"
#include "gs_can_link.h"

typedef struct {
    gs_board_t board;
    gs_can_link_t link;
    uint32_t stats_key; /* checksum of the counters last written as an "S" record */
} gs_app_can_t;

/* Set up (bus devices found and checked) and serve board `node` (1..127) on a classic (fd 0) or CAN FD bus until
 * hal_should_stop(); 0, or 2 when a boot check refused the start (as gs_app_run). */
int gs_app_can_run(gs_app_can_t *app, const gs_settings_t *cfg, unsigned node, int fd);
/* The pieces, for harnesses (the fuzz target c-can). */
int gs_app_can_init(gs_app_can_t *app, const gs_settings_t *cfg, unsigned node, int fd);
void gs_app_can_pump(gs_app_can_t *app);
void gs_app_can_process(gs_app_can_t *app, const gs_can_item_t *item);
void gs_app_can_flush(gs_app_can_t *app);
void gs_app_can_tick(gs_app_can_t *app);

#endif
