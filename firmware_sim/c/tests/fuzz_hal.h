#ifndef FUZZ_HAL_H
#define FUZZ_HAL_H
#include <stddef.h>
#include <stdint.h>
extern const uint8_t *fuzz_in;
extern size_t fuzz_in_len, fuzz_in_pos;
void fuzz_hal_reset(void);
#endif
