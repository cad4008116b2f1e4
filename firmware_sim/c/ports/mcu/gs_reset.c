/* The reset handler every Cortex-M port starts in (ARMv7-M: the vector table's second word; the first is the
 * initial main stack pointer, _estack): copy .data from its load address in flash, zero .bss, run main. And the
 * handler of every exception or interrupt a port does not use: stop there (a port's watchdog, once started, resets
 * the part). The symbols are the linker script's (ports/mps2/mps2_an385.ld, ports/stm32f4/stm32f4.ld). */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss;
int main(void);
void reset_handler(void);
void default_handler(void);

void default_handler(void) {
    for (;;) {
    }
}

void reset_handler(void) {
    uint32_t *src = &_sidata, *dst = &_sdata;
    while (dst < &_edata) *dst++ = *src++;
    for (dst = &_sbss; dst < &_ebss;) *dst++ = 0;
    main();
    for (;;) {
    }
}
