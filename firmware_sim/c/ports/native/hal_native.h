#ifndef HAL_NATIVE_H
#define HAL_NATIVE_H
#include <stddef.h>
void native_init(void);
/* "pty": create a pty pair (name = the slave to connect to); else open that device path. 0 on success. */
int native_open_host(const char *spec, char *name, size_t cap);
int native_open_bus(const char *path);
void native_close(void);
#endif
