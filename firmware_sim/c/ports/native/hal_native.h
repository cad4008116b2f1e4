#ifndef HAL_NATIVE_H
#define HAL_NATIVE_H
#include <stddef.h>
#include <stdint.h>
void native_init(void);
/* "pty": create a pty pair (name = the slave to connect to); else open that device path. 0 on success. */
int native_open_host(const char *spec, char *name, size_t cap);
int native_open_bus(const char *path);
/* A real servo bus: `path` raw 8N1 at `baud`; -1 with the reason in `why` (the device is missing, refuses the rate). */
int native_open_bus_tty(const char *path, unsigned long baud, char *why, size_t cap);
void native_close(void);
/* The host link on SocketCAN (can_native.c): bind a raw CAN socket to `ifname` for board `node` (classic, or CAN FD
 * with `fd`); -1 with the reason in `why`. */
int native_open_can(const char *ifname, unsigned node, int fd, char *why, size_t cap);
void native_close_can(void);
/* Wait on `fd` (readable, or writable with `want_write`) and the stop signal until `until_us` (hal_now_us clock). */
void native_wait_fd(int fd, int want_write, uint64_t until_us);
#endif
