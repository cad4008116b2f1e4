/* The vector table of the Cortex-M3 image (reset: ports/mcu/gs_reset.c: copy .data, zero .bss, run main). */
#include <stdint.h>

extern uint32_t _estack;
void reset_handler(void);   /* ports/mcu/gs_reset.c */
void default_handler(void); /* ports/mcu/gs_reset.c */
void systick_handler(void);
void uart0_rx_handler(void);
void uart1_rx_handler(void);

typedef void (*vector_t)(void);

__attribute__((section(".vectors"), used)) const vector_t vectors[16 + 3] = {
    (vector_t)(uintptr_t)&_estack, /* initial main stack pointer */
    reset_handler,
    default_handler, /* NMI */
    default_handler, /* HardFault */
    default_handler, /* MemManage */
    default_handler, /* BusFault */
    default_handler, /* UsageFault */
    0, 0, 0, 0,
    default_handler, /* SVCall */
    default_handler, /* DebugMonitor */
    0,
    default_handler, /* PendSV */
    systick_handler,
    uart0_rx_handler, /* IRQ 0: UART0 RX */
    default_handler,  /* IRQ 1: UART0 TX (not enabled) */
    uart1_rx_handler, /* IRQ 2: UART1 RX (the servo bus) */
};
