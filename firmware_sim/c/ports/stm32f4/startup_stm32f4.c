/* The vector table of the STM32F405/F407 image (RM0090 12.2 table 61: 16 system exceptions then
 * 82 interrupt positions; USART1 37, USART2 38, USART3 39, USART6 71). The
 * table sits first in flash (0x0800 0000, aliased at 0 when booting from main flash: BOOT0 low). Soft-float
 * image: the FPU stays off (no CPACR write), exceptions stack no FP context. Reset: ports/mcu/gs_reset.c. */
#include <stdint.h>

#include "stm32f4_regs.h"

extern uint32_t _estack;
void reset_handler(void);   /* ports/mcu/gs_reset.c */
void default_handler(void); /* ports/mcu/gs_reset.c: an unexpected exception or fault stops there; the
                               independent watchdog (once started) resets the part */
void systick_handler(void);
void usart2_handler(void);
void usart3_handler(void);
void usart6_handler(void);

typedef void (*vector_t)(void);

#define D1 default_handler /* an interrupt that is never enabled */
#define D5 D1, D1, D1, D1, D1
#define D10 D5, D5

__attribute__((section(".vectors"), used)) const vector_t vectors[16u + IRQ_COUNT] = {
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
    D10, D10, D10, D5, D1, D1, /* IRQ 0..36 */
    D1,                        /* IRQ 37: USART1 (unused) */
    usart2_handler,            /* IRQ 38: USART2, the host link */
    usart3_handler,            /* IRQ 39: USART3, the log channel */
    D10, D10, D10, D1,         /* IRQ 40..70 */
    usart6_handler,            /* IRQ 71: USART6, the servo bus */
    D10,                       /* IRQ 72..81 */
};
