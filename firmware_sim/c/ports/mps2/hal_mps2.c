/* The Cortex-M3 port for QEMU's mps2-an385: CMSDK APB UART0 = host link, UART1 = servo bus,
 * UART2 = log channel; CMSDK timer 0 at 25 MHz is the time base, SysTick at 4 kHz wakes the waits; the CPU
 * sleeps in WFI between events (UART0 and UART1 receive interrupts, SysTick). Polled UART data registers
 * (one byte deep in QEMU's model, which holds further bytes back until the register is read: the
 * receive side never overruns). Boot settings come from the configuration block the launcher
 * writes with QEMU's generic loader (-device loader,addr=...,data=...): lockstep, rates, watchdog, frame
 * log, the servo-bus protocol (0 STS, 1 Dynamixel 2.0) and the ESTOP torque (0 hold, 1 limp): ports/mcu/gs_bootcfg.h. */
#include <stdint.h>

#include "gs_app.h"
#include "gs_bootcfg.h"
#include "gs_hal.h"

#define REG32(a) (*(volatile uint32_t *)(a))

#define UART_BASE(i) (0x40004000u + 0x1000u * (i))
#define UART_DATA(i) REG32(UART_BASE(i) + 0x00u)
#define UART_STATE(i) REG32(UART_BASE(i) + 0x04u)
#define UART_CTRL(i) REG32(UART_BASE(i) + 0x08u)
#define UART_INT(i) REG32(UART_BASE(i) + 0x0Cu)
#define UART_BAUDDIV(i) REG32(UART_BASE(i) + 0x10u)
#define ST_TXFULL 1u
#define ST_RXFULL 2u

#define SYST_CSR REG32(0xE000E010u)
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define NVIC_ISER0 REG32(0xE000E100u)

#define SYSCLK_HZ 25000000u
#define SYSTICK_HZ 4000u
#define COUNTS_PER_TICK (SYSCLK_HZ / SYSTICK_HZ) /* 6250 */

#define HOST 0u
#define BUS 1u
#define LOG 2u

static uint32_t waited_counts;       /* system clock counts spent waiting for bus bytes */

void systick_handler(void) {} /* wakes the WFI waits */
void uart0_rx_handler(void) { UART_INT(HOST) = 2u; } /* wake from WFI; main loop reads DATA */
void uart1_rx_handler(void) { UART_INT(BUS) = 2u; }  /* the same for the servo bus's answers */

/* The time base: CMSDK APB timer 0 (0x40000000; ARM DDI 0479 "APB timer": a 32-bit down-counter at PCLK =
 * 25 MHz, reloading from RELOAD) free-running from 0xFFFFFFFF, read and extended to 64 bits in software (one
 * reader, main code; it wraps every 172 s and is read far more often). Not a count of SysTick interrupts: QEMU
 * takes those late under load and a count of them lost periods (the board clock ran at 0.947 of the wall
 * clock over 5 s, so the host's frames filled the jitter buffer: BUFFER_FULL); the counter is computed from
 * QEMU's clock whenever it is read. SysTick only wakes the WFI waits. */
#define TIMER0_CTRL REG32(0x40000000u)
#define TIMER0_VALUE REG32(0x40000004u)
#define TIMER0_RELOAD REG32(0x40000008u)

static uint32_t timer_last;
static uint64_t timer_counts;

static uint64_t now_counts(void) {
    uint32_t v = TIMER0_VALUE;
    timer_counts += (uint32_t)(timer_last - v); /* down-counter: elapsed counts modulo 2^32 */
    timer_last = v;
    return timer_counts;
}

uint64_t hal_now_us(void) { return now_counts() / (SYSCLK_HZ / 1000000u); }

uint32_t hal_cycles(void) { return (uint32_t)now_counts() - waited_counts; }

size_t hal_host_read(uint8_t *buf, size_t cap) {
    size_t n = 0;
    while (n < cap && (UART_STATE(HOST) & ST_RXFULL)) buf[n++] = (uint8_t)UART_DATA(HOST);
    return n;
}

size_t hal_host_write(const uint8_t *buf, size_t n) {
    size_t k = 0;
    while (k < n && !(UART_STATE(HOST) & ST_TXFULL)) UART_DATA(HOST) = buf[k++];
    return k;
}

void hal_bus_write(const uint8_t *buf, size_t n) {
    for (size_t k = 0; k < n; k++) {
        while (UART_STATE(BUS) & ST_TXFULL) {
        }
        UART_DATA(BUS) = buf[k];
    }
}

/* Waits in WFI, woken by the bus UART's receive interrupt or SysTick (so a byte that lands between the
 * check and the WFI waits at most one SysTick period, 250 us): a busy loop of MMIO reads would keep QEMU's
 * vCPU thread spinning on its global lock while its I/O thread is the one delivering the bytes, which on
 * a loaded machine made every answer late. */
size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) {
    uint64_t start = now_counts();
    uint64_t limit = (uint64_t)timeout_us * (SYSCLK_HZ / 1000000u);
    size_t n = 0;
    while (!(UART_STATE(BUS) & ST_RXFULL)) {
        if (now_counts() - start >= limit) break;
        __asm volatile("wfi");
    }
    while (n < cap && (UART_STATE(BUS) & ST_RXFULL)) buf[n++] = (uint8_t)UART_DATA(BUS);
    waited_counts += (uint32_t)(now_counts() - start);
    return n;
}

void hal_bus_drain(void) {
    while (UART_STATE(BUS) & ST_RXFULL) (void)UART_DATA(BUS);
}

void hal_wait(uint64_t until_us, int want_write) {
    while (hal_now_us() < until_us) {
        if (UART_STATE(HOST) & ST_RXFULL) return;
        if (want_write && !(UART_STATE(HOST) & ST_TXFULL)) return;
        __asm volatile("wfi");
    }
}

void hal_log_write(const char *s, size_t n) {
    for (size_t k = 0; k < n; k++) {
        while (UART_STATE(LOG) & ST_TXFULL) {
        }
        UART_DATA(LOG) = (uint8_t)s[k];
    }
}

int hal_should_stop(void) { return 0; }

static gs_app_t app;

int main(void) {
    for (unsigned i = 0; i < 3u; i++) {
        UART_BAUDDIV(i) = i == BUS ? SYSCLK_HZ / 1000000u : SYSCLK_HZ / 115200u;
        UART_CTRL(i) = 3u; /* TX and RX enabled */
    }
    UART_CTRL(HOST) = 3u | 8u; /* + RX interrupt: wakes the WFI */
    UART_CTRL(BUS) = 3u | 8u;  /* the same: hal_bus_read waits in WFI */
    NVIC_ISER0 = 1u << 0 | 1u << 2; /* UART0 RX is IRQ 0, UART1 RX IRQ 2 on AN385 */
    TIMER0_RELOAD = 0xFFFFFFFFu;
    TIMER0_VALUE = 0xFFFFFFFFu;
    TIMER0_CTRL = 1u; /* enable, PCLK, no interrupt */
    timer_last = TIMER0_VALUE;
    SYST_RVR = COUNTS_PER_TICK - 1u;
    SYST_CVR = 0;
    SYST_CSR = 7u; /* processor clock, interrupt, enable */
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    (void)gs_boot_cfg_apply(&cfg); /* the servo bus is the plant's socket: no baud to model */
    (void)gs_app_run(&app, &cfg); /* a refused boot: its line is out, torque off; the guest idles (the launcher
                                     stops it on that line) */
    for (;;) {
        __asm volatile("wfi");
    }
}
