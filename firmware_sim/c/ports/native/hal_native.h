#ifndef HAL_NATIVE_H
#define HAL_NATIVE_H
#include <stddef.h>
void native_init(void);
/* "pty": create a pty pair (name = the slave to connect to); else open that device path. 0 on success. */
int native_open_host(const char *spec, char *name, size_t cap);
int native_open_bus(const char *path);
/* A real servo bus: `path` raw 8N1 at `baud`; -1 with the reason in `why` (the device is missing, refuses the rate). */
int native_open_bus_tty(const char *path, unsigned long baud, char *why, size_t cap);
void native_close(void);
#endif
