/* The STM32F405/F407 port (Cortex-M4, registers from RM0090: stm32f4_regs.h). Boards and pins:
 * docs/guides/stm32f4.md.
 *
 *   host link   USART2  PA2 TX / PA3 RX (AF7)               GS_HOST_BAUD, default 115200, 8N1
 *   servo bus   USART6  PC6 single wire (AF8, open-drain)    half-duplex (CR3.HDSEL), 1 Mbaud
 *   log         USART3  PB10 TX (AF7)                        GS_LOG_BAUD, default 460800
 *
 * Clocks (RM0090 6.2, 7.3): HSE (GS_HSE_HZ, a whole number of MHz, 4..26) -> PLL (M = HSE in MHz: 1 MHz VCO
 * input, N 336, P 2, Q 7) -> SYSCLK = HCLK 168 MHz, APB1 /4 = 42 MHz, APB2 /2 = 84 MHz, flash 5 wait states
 * (table 10, 2.7..3.6 V). Every ready-bit poll is bounded: a crystal that does not start, a PLL that does not
 * lock or a switch that does not happen leaves the part on the 16 MHz HSI (everything /1) with one log line.
 * QEMU's netduinoplus2 has no RCC (its registers read 0: no ready bit ever comes, and RCC_CR = 0 is
 * impossible on silicon, which runs on some clock whose ready bit is set): the line says so and the core
 * clock is then taken as that machine's fixed 168 MHz (GS_NO_RCC_HCLK_HZ), which its SysTick counts.
 * USART baud registers are computed from the APB clocks actually running (BRR = round(f_pclk / baud),
 * 30.3.4 with OVER8 = 0); the second log line gives each USART's rate as set.
 *
 * Receive on every USART into a ring by the RXNE interrupt (a byte at 1 Mbaud every 10 us would overrun the
 * one-byte data register while the core is busy); a full ring disables that interrupt in the NVIC and leaves
 * the byte in DR (QEMU then holds the rest back, as the mps2 port relies on; on hardware the next byte would
 * overrun); taking bytes from the ring enables it again. Host and log transmit from rings: the writer puts
 * into the data register while TXE is set, the TXE interrupt sends the rest (QEMU 7.2's USART raises no TXE
 * interrupt but sends each byte at once, so the writer empties the ring there). The servo bus transmits polled
 * and takes its own echo out of the receive ring (hal_bus_write). The CPU sleeps in WFI with interrupts masked
 * around the test (a byte that lands between the test and the WFI still wakes it). SysTick at 4 kHz from the
 * processor clock wakes it and counts core cycles (the tick cost);
 * the time base (hal_now_us) is TIM2 free-running at 1 MHz, 32 bits extended in software: a count of SysTick
 * interrupts would lose a period whenever one is taken more than a period late, as QEMU does when its main loop
 * is busy (two expiries before the first is taken are one interrupt): the board clock then ran up to 5 % slow
 * against the wall clock (0.947 board s a wall second over 5 s at 4 kHz; the host's frames piled up in the
 * jitter buffer, BUFFER_FULL). TIM2's counter is read, never interrupted on.
 *
 * The independent watchdog (IWDG, RM0090 19: LSI ~32 kHz / 64, reload GS_IWDG_MS, default 500 ms) starts
 * before the core runs and is refreshed in every wait loop (hal_wait, bus reads and writes, a full log ring)
 * and nowhere else: a hung loop resets the part. It can never be stopped once started. QEMU does not model
 * the IWDG (its registers are an unimplemented device there: writes ignored), so no test sees it fire.
 *
 * Boot settings: the configuration block at the start of RAM (ports/mcu/gs_bootcfg.h), written by the
 * launcher; a valid block means the servo bus is the emulator's plant (a socket: no wire time, bus_baud 0);
 * without one (a real board) the defaults apply and the bus is a real 1 Mbaud line. */
#include <stddef.h>
#include <stdint.h>

#include "gs_app.h"
#include "gs_bootcfg.h"
#include "gs_hal.h"
#include "gs_log.h"
#include "stm32f4_regs.h"

#ifndef GS_HSE_HZ
/* the crystal: STM32F4-Discovery, Olimex STM32-H405 8 MHz; pyboard v1.1 12 MHz; Netduino Plus 2 25 MHz */
#define GS_HSE_HZ 8000000u
#endif
#ifndef GS_HOST_BAUD
#define GS_HOST_BAUD 115200u
#endif
#ifndef GS_BUS_BAUD
#define GS_BUS_BAUD 1000000u /* Feetech STS / Dynamixel X default */
#endif
#ifndef GS_LOG_BAUD
#define GS_LOG_BAUD 460800u
#endif
#ifndef GS_IWDG_MS
#define GS_IWDG_MS 500u
#endif
#ifndef GS_NO_RCC_HCLK_HZ
#define GS_NO_RCC_HCLK_HZ 168000000u /* QEMU netduinoplus2's fixed system clock (hw/arm/netduinoplus2.c) */
#endif
#ifndef GS_NO_RCC_TIM_HZ
#define GS_NO_RCC_TIM_HZ 1000000000u /* QEMU 7.2's STM32F405 timers (TIM2..5 "clock-frequency", stm32f405_soc.c) */
#endif

#if GS_HSE_HZ % 1000000u != 0u || GS_HSE_HZ < 4000000u || GS_HSE_HZ > 26000000u
#error "GS_HSE_HZ must be a whole number of MHz in 4..26 MHz (RM0090 6.2.1; PLL M = HSE in MHz)"
#endif

#define HSI_HZ 16000000u
#define PLL_HCLK_HZ 168000000u
#define PLL_N 336u
#define PLL_P 2u
#define PLL_Q 7u
#define FLASH_WAIT_STATES 5u
#define CLOCK_POLLS 65536u /* a ready bit is polled this often: >= 16 ms at 16 MHz (>= 4 cycles a poll) */
#define SYSTICK_HZ 4000u /* a WFI wakes at least this often; core clock counts for the tick cost */

#define HOST USART2
#define BUS USART6
#define LOG USART3

/* --- rings: one producer, one consumer (main code / an interrupt handler); sizes are powers of two ------ */
typedef struct {
    volatile uint32_t head, tail; /* free-running counts of bytes put / taken */
    uint8_t *buf;
    uint32_t mask;
} ring_t;

static uint8_t host_rx_buf[1024], host_tx_buf[1024], bus_rx_buf[256], log_tx_buf[4096];
static ring_t host_rx = {0, 0, host_rx_buf, sizeof host_rx_buf - 1u};
static ring_t host_tx = {0, 0, host_tx_buf, sizeof host_tx_buf - 1u};
static ring_t bus_rx = {0, 0, bus_rx_buf, sizeof bus_rx_buf - 1u};
static ring_t log_tx = {0, 0, log_tx_buf, sizeof log_tx_buf - 1u};

static uint32_t ring_count(const ring_t *r) { return r->head - r->tail; }
static int ring_full(const ring_t *r) { return ring_count(r) > r->mask; }

static inline void irq_off(void) { __asm volatile("cpsid i" ::: "memory"); }
static inline void irq_on(void) { __asm volatile("cpsie i" ::: "memory"); }
static inline void iwdg_refresh(void) { IWDG_KR = IWDG_KEY_RELOAD; }

/* Sleep until an interrupt is pending unless `ready` (tested with interrupts masked: WFI wakes on a pending
 * interrupt even while PRIMASK holds it back, PM0214 3.12.11; the handler runs after irq_on). */
static void sleep_unless(int (*ready)(void)) {
    irq_off();
    if (!ready()) __asm volatile("wfi");
    irq_on();
}

/* --- interrupt handlers (startup_stm32f4.c vectors) ------------------------------------------------------- */
static volatile uint32_t systicks; /* SysTick interrupts since boot */

void systick_handler(void) { systicks++; }

/* A full ring: the interrupt off in the NVIC (not RXNEIE: QEMU 7.2 lowers its line only when DR is read, so a
 * handler returning with the byte in DR would be re-entered forever); rx_take turns it on again. */
static void rx_irq(uint32_t u, ring_t *r, uint32_t irq) {
    if (!(USART_SR(u) & (USART_SR_RXNE | USART_SR_ORE))) return;
    if (ring_full(r)) {
        NVIC_ICER(irq / 32u) = 1u << (irq % 32u);
        return;
    }
    r->buf[r->head & r->mask] = (uint8_t)USART_DR(u); /* SR then DR also clears ORE/FE/NE (30.6.1) */
    r->head++;
}

/* Up to `cap` bytes from a receive ring; its interrupt on again (room now). */
static size_t rx_take(ring_t *r, uint32_t irq, uint8_t *buf, size_t cap) {
    size_t n = 0;
    while (n < cap && ring_count(r)) {
        buf[n++] = r->buf[r->tail & r->mask];
        r->tail++;
    }
    NVIC_ISER(irq / 32u) = 1u << (irq % 32u);
    return n;
}

/* No RCC answers (clock_init: RCC_CR reads 0, impossible on silicon): QEMU's netduinoplus2. Three things are
 * done differently there, and never on a part:
 * - the core clock is taken as the machine's fixed 168 MHz (GS_NO_RCC_HCLK_HZ), which its SysTick counts;
 * - its USART sends every byte at once (TXE and TC always set) and each status read wakes QEMU's main loop
 *   (stm32f2xx_usart_read -> qemu_chr_fe_accept_input -> qemu_notify_event: the CPU thread and the I/O thread
 *   then trade QEMU's global lock byte by byte): the transmit status polls are skipped, there is no echo
 *   (measured, realtime task 1: 56 000 -> 33 000 cycles of wall time per tick outside the bus waits);
 * - TIM2 counts QEMU's fixed timer clock (GS_NO_RCC_TIM_HZ), not the APB1 timer clock. */
static int emulated;

/* Send from a transmit ring while TXE is set; what is left goes by the TXE interrupt (TXEIE on until empty). */
static void tx_send(uint32_t u, ring_t *r) {
    while ((emulated || (USART_SR(u) & USART_SR_TXE)) && ring_count(r)) {
        USART_DR(u) = r->buf[r->tail & r->mask];
        r->tail++;
    }
    USART_CR1(u) = ring_count(r) ? USART_CR1(u) | USART_CR1_TXEIE : USART_CR1(u) & ~USART_CR1_TXEIE;
}

static void tx_irq(uint32_t u, ring_t *r) {
    if (USART_CR1(u) & USART_CR1_TXEIE) tx_send(u, r);
}

/* The writer's side: interrupts masked (the handler sends from the same ring). */
static void tx_kick(uint32_t u, ring_t *r) {
    irq_off();
    tx_send(u, r);
    irq_on();
}

void usart2_handler(void) { /* host link */
    rx_irq(HOST, &host_rx, IRQ_USART2);
    tx_irq(HOST, &host_tx);
}
void usart3_handler(void) { tx_irq(LOG, &log_tx); } /* log channel */
void usart6_handler(void) { rx_irq(BUS, &bus_rx, IRQ_USART6); } /* servo bus */

/* --- clocks -------------------------------------------------------------------------------------------------- */
static uint32_t hclk_hz = HSI_HZ, pclk1_hz = HSI_HZ, pclk2_hz = HSI_HZ;
static uint32_t counts_per_tick = HSI_HZ / SYSTICK_HZ, counts_per_us = HSI_HZ / 1000000u;

static int poll(volatile uint32_t *reg, uint32_t mask, uint32_t want) {
    for (uint32_t k = 0; k < CLOCK_POLLS; k++)
        if ((*reg & mask) == want) return 1;
    return 0;
}

/* HSE -> PLL -> 168 MHz, or the HSI with the reason; logs one line. RM0090 7.3.1-7.3.3, 3.5.1. */
static void clock_init(void) {
    int no_rcc = RCC_CR == 0u;
    const char *failed = 0;
    if ((RCC_CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_HSI) { /* a boot loader left another clock: back to HSI */
        RCC_CR |= RCC_CR_HSION;
        (void)poll(&RCC_CR, RCC_CR_HSIRDY, RCC_CR_HSIRDY);
        RCC_CFGR &= ~RCC_CFGR_SW_MASK;
        (void)poll(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_HSI);
        RCC_CFGR &= ~(RCC_CFGR_HPRE_MASK | RCC_CFGR_PPRE1_MASK | RCC_CFGR_PPRE2_MASK);
    }
    RCC_CR &= ~RCC_CR_PLLON; /* PLLCFGR may change only while the PLL is off */
    RCC_CR |= RCC_CR_HSEON;
    if (!poll(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY)) {
        failed = "not ready";
    } else {
        RCC_APB1ENR |= RCC_APB1ENR_PWREN;
        (void)RCC_APB1ENR;
        PWR_CR |= PWR_CR_VOS;
        RCC_PLLCFGR = (GS_HSE_HZ / 1000000u) << RCC_PLLCFGR_PLLM_POS | PLL_N << RCC_PLLCFGR_PLLN_POS |
                      (PLL_P / 2u - 1u) << RCC_PLLCFGR_PLLP_POS | RCC_PLLCFGR_PLLSRC_HSE |
                      PLL_Q << RCC_PLLCFGR_PLLQ_POS;
        RCC_CR |= RCC_CR_PLLON;
        if (!poll(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) {
            failed = "PLL did not lock";
        } else {
            /* wait states before the clock goes up; read back to be sure they hold (3.5.1) */
            FLASH_ACR = FLASH_WAIT_STATES | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
            if ((FLASH_ACR & FLASH_ACR_LATENCY_MASK) != FLASH_WAIT_STATES) {
                failed = "flash wait states not taken";
            } else {
                RCC_CFGR = (RCC_CFGR & ~(RCC_CFGR_HPRE_MASK | RCC_CFGR_PPRE1_MASK | RCC_CFGR_PPRE2_MASK)) |
                           RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2;
                RCC_CFGR = (RCC_CFGR & ~RCC_CFGR_SW_MASK) | RCC_CFGR_SW_PLL;
                if (!poll(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL)) {
                    failed = "switch to the PLL not seen";
                    RCC_CFGR &= ~(RCC_CFGR_SW_MASK | RCC_CFGR_PPRE1_MASK | RCC_CFGR_PPRE2_MASK);
                }
            }
        }
    }
    if (failed) { /* stay on the HSI, everything /1; the PLL and the crystal off */
        RCC_CR &= ~(RCC_CR_PLLON | RCC_CR_HSEON);
        FLASH_ACR = FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN; /* 0 wait states <= 30 MHz */
        hclk_hz = pclk1_hz = pclk2_hz = no_rcc ? GS_NO_RCC_HCLK_HZ : HSI_HZ;
        emulated = no_rcc;
    } else {
        hclk_hz = PLL_HCLK_HZ;
        pclk1_hz = PLL_HCLK_HZ / 4u;
        pclk2_hz = PLL_HCLK_HZ / 2u;
    }
    counts_per_tick = hclk_hz / SYSTICK_HZ;
    counts_per_us = hclk_hz / 1000000u;
    gs_log_str("board: clock: ");
    if (!failed) {
        gs_log_str("HSE ");
        gs_log_u64(GS_HSE_HZ / 1000000u);
        gs_log_str(" MHz -> PLL -> SYSCLK 168 MHz (APB1 42, APB2 84 MHz), flash 5 wait states");
    } else {
        gs_log_str("HSE ");
        gs_log_u64(GS_HSE_HZ / 1000000u);
        gs_log_str(" MHz: ");
        gs_log_str(failed);
        gs_log_str(" (");
        gs_log_u64(CLOCK_POLLS);
        gs_log_str(" polls): running on the 16 MHz HSI");
        if (no_rcc) {
            gs_log_str("; no RCC answers (RCC_CR reads 0: an emulator), its core clock taken as ");
            gs_log_u64(hclk_hz / 1000000u);
            gs_log_str(" MHz, its USARTs as sending at once");
        }
    }
    gs_log_end();
}

/* --- time: SysTick (as the mps2 port) -------------------------------------------------------------------- */
static uint64_t last_counts;
static uint32_t waited_counts; /* core clock counts spent waiting for bus bytes */

/* Monotonic core-clock counts: SysTick periods counted by its interrupt plus the counter; a reload seen before
 * its interrupt was taken is moved on by one period (never a step back). */
static uint64_t now_counts(void) {
    for (;;) {
        uint32_t t = systicks;
        uint32_t v = SYST_CVR;
        uint32_t pending = SCB_ICSR & SCB_ICSR_PENDSTSET;
        if (t != systicks) continue;
        if (pending) {
            v = SYST_CVR;
            t++;
        }
        uint64_t c = (uint64_t)t * counts_per_tick + (counts_per_tick - 1u - v);
        if (c < last_counts) c += counts_per_tick;
        if (c < last_counts) c = last_counts;
        last_counts = c;
        return c;
    }
}

/* --- the time base: TIM2 at 1 MHz (RM0090 18: 32-bit up-counter, PSC divides its input by PSC + 1) ------ */
static uint32_t tim2_last, tim2_wraps, tim2_mhz;

/* TIM2's input clock in MHz: on a part 2 x PCLK1 when APB1 is divided, else PCLK1 (RM0090 6.2, figure 21);
 * under emulation QEMU's fixed timer clock (GS_NO_RCC_TIM_HZ). */
static uint32_t tim2_input_mhz(void) {
    if (emulated) return GS_NO_RCC_TIM_HZ / 1000000u;
    return (pclk1_hz == hclk_hz ? pclk1_hz : 2u * pclk1_hz) / 1000000u;
}

static void tim2_start(void) {
    RCC_APB1ENR |= RCC_APB1ENR_TIM2EN;
    (void)RCC_APB1ENR;
    TIM2_ARR = 0xFFFFFFFFu;
    TIM2_CR1 = TIM_CR1_CEN;
    tim2_mhz = tim2_input_mhz();
    TIM2_PSC = tim2_mhz - 1u; /* 1 MHz */
    TIM2_EGR = TIM_EGR_UG;    /* load the prescaler now (it is buffered until an update event) */
    tim2_last = TIM2_CNT;
}

uint64_t hal_now_us(void) { /* main code only (not from an interrupt handler): one reader extends the count */
    uint32_t v = TIM2_CNT;
    if (v < tim2_last) tim2_wraps++; /* read at least once every 71 minutes (every wait loop reads it) */
    tim2_last = v;
    return (uint64_t)tim2_wraps << 32 | v;
}

uint32_t hal_cycles(void) { return (uint32_t)now_counts() - waited_counts; }

/* --- host link --------------------------------------------------------------------------------------------- */
size_t hal_host_read(uint8_t *buf, size_t cap) { return rx_take(&host_rx, IRQ_USART2, buf, cap); }

size_t hal_host_write(const uint8_t *buf, size_t n) {
    size_t k = 0;
    while (k < n && !ring_full(&host_tx)) {
        host_tx.buf[host_tx.head & host_tx.mask] = buf[k++];
        host_tx.head++;
    }
    if (k) tx_kick(HOST, &host_tx);
    return k;
}

/* --- servo bus ----------------------------------------------------------------------------------------------- */
/* One wire (CR3.HDSEL): the receiver hears our own bytes, each about when it has left (the last one about
 * with TC). After TC, and at most ECHO_GRACE_BITS bit times more for that last byte, the n bytes received since
 * the write began are taken out of the ring if they are exactly what was sent: the echo. QEMU has no echo (its
 * USART sends into the socket), so nothing matches there and nothing is taken: an answer that came that soon
 * is left alone (a servo's answer differs from the request in its instruction/error byte and checksum).
 * (Switching the receiver off while sending would lose, in QEMU, an answer that lands before it is on again.) */
#define ECHO_GRACE_BITS 20u

static int echo_at(uint32_t from, const uint8_t *buf, size_t n) {
    for (size_t k = 0; k < n; k++)
        if (bus_rx.buf[(from + k) & bus_rx.mask] != buf[k]) return 0;
    return 1;
}

void hal_bus_write(const uint8_t *buf, size_t n) {
    if (emulated) { /* QEMU: no status to wait for, no echo */
        for (size_t k = 0; k < n; k++) USART_DR(BUS) = buf[k];
        return;
    }
    uint32_t from = bus_rx.head; /* bytes before this are not our echo */
    for (size_t k = 0; k < n; k++) {
        while (!(USART_SR(BUS) & USART_SR_TXE)) iwdg_refresh();
        USART_DR(BUS) = buf[k];
    }
    while (!(USART_SR(BUS) & USART_SR_TC)) iwdg_refresh(); /* the stop bit of the last byte is out */
    uint64_t t0 = now_counts(), grace = (uint64_t)ECHO_GRACE_BITS * hclk_hz / GS_BUS_BAUD;
    while (bus_rx.head - from < n && now_counts() - t0 < grace) iwdg_refresh();
    waited_counts += (uint32_t)(now_counts() - t0); /* a wait for bus bytes, as in hal_bus_read */
    irq_off();
    uint32_t head = bus_rx.head;
    if (n && n <= bus_rx.mask && head - from >= n && echo_at(from, buf, n)) { /* drop it; what followed moves up */
        for (uint32_t k = from; k + n != head; k++) bus_rx.buf[k & bus_rx.mask] = bus_rx.buf[(k + n) & bus_rx.mask];
        bus_rx.head = head - (uint32_t)n;
    }
    irq_on();
}

static int bus_ready(void) { return ring_count(&bus_rx) != 0u; }

size_t hal_bus_read(uint8_t *buf, size_t cap, uint32_t timeout_us) {
    uint64_t start = now_counts(), start_us = hal_now_us();
    while (!bus_ready()) {
        iwdg_refresh();
        if (hal_now_us() - start_us >= timeout_us) break;
        sleep_unless(bus_ready); /* woken by the bus's RXNE interrupt or SysTick */
    }
    size_t n = rx_take(&bus_rx, IRQ_USART6, buf, cap);
    waited_counts += (uint32_t)(now_counts() - start);
    return n;
}

void hal_bus_drain(void) {
    irq_off();
    bus_rx.tail = bus_rx.head;
    while (USART_SR(BUS) & (USART_SR_RXNE | USART_SR_ORE)) (void)USART_DR(BUS);
    irq_on();
    NVIC_ISER(IRQ_USART6 / 32u) = 1u << (IRQ_USART6 % 32u);
}

/* --- waiting, log ------------------------------------------------------------------------------------------- */
static int wait_want_write;
static int host_ready(void) { return ring_count(&host_rx) != 0u || (wait_want_write && !ring_full(&host_tx)); }

void hal_wait(uint64_t until_us, int want_write) {
    wait_want_write = want_write;
    while (hal_now_us() < until_us) {
        iwdg_refresh();
        if (host_ready()) return;
        sleep_unless(host_ready);
    }
}

static int log_on; /* the log USART runs (before: lines wait in the ring) */
static int log_room(void) { return !ring_full(&log_tx); }

void hal_log_write(const char *s, size_t n) {
    for (size_t k = 0; k < n; k++) {
        if (ring_full(&log_tx) && log_on) tx_kick(LOG, &log_tx);
        while (ring_full(&log_tx)) { /* the TXE interrupt empties it */
            if (!log_on) return; /* before the USART runs: the rest of the line is lost */
            iwdg_refresh();
            sleep_unless(log_room);
        }
        log_tx.buf[log_tx.head & log_tx.mask] = (uint8_t)s[k];
        log_tx.head++;
    }
    if (log_on) tx_kick(LOG, &log_tx);
}

int hal_should_stop(void) { return 0; }

/* --- set-up ----------------------------------------------------------------------------------------------- */
/* One pin to alternate function `af` (RM0090 8.3.7, 8.4.1-8.4.10): fast, pull-up, push-pull or open-drain. */
static void pin_af(uint32_t port, uint32_t pin, uint32_t af, int open_drain) {
    GPIO_MODER(port) = (GPIO_MODER(port) & ~(3u << 2u * pin)) | 2u << 2u * pin;
    GPIO_OTYPER(port) = (GPIO_OTYPER(port) & ~(1u << pin)) | (uint32_t)(open_drain != 0) << pin;
    GPIO_OSPEEDR(port) = (GPIO_OSPEEDR(port) & ~(3u << 2u * pin)) | 2u << 2u * pin;
    GPIO_PUPDR(port) = (GPIO_PUPDR(port) & ~(3u << 2u * pin)) | 1u << 2u * pin;
    uint32_t shift = 4u * (pin & 7u);
    GPIO_AFR(port, pin) = (GPIO_AFR(port, pin) & ~(15u << shift)) | af << shift;
}

/* USARTDIV x 16 = f_pclk / baud with OVER8 = 0 (30.3.4): mantissa and 4-bit fraction in one rounding */
static uint32_t brr_for(uint32_t pclk, uint32_t baud) { return (pclk + baud / 2u) / baud; }

static void usart_init(uint32_t u, uint32_t pclk, uint32_t baud, uint32_t cr1, uint32_t cr3) {
    USART_CR1(u) = 0;
    USART_BRR(u) = brr_for(pclk, baud);
    USART_CR2(u) = 0; /* 1 stop bit */
    USART_CR3(u) = cr3;
    USART_CR1(u) = USART_CR1_UE | cr1; /* 8 data bits, no parity */
}

static void log_rate(const char *name, uint32_t pclk, uint32_t baud) {
    uint32_t brr = brr_for(pclk, baud);
    gs_log_str(name);
    gs_log_u64(baud);
    gs_log_str(" (BRR ");
    gs_log_u64(brr);
    gs_log_str(": ");
    gs_log_u64(pclk / brr);
    gs_log_str(")");
}

static void iwdg_start(void) { /* RM0090 19.3.2: start, unlock, prescaler /64, reload, wait for the update */
    IWDG_KR = IWDG_KEY_START;
    IWDG_KR = IWDG_KEY_ACCESS;
    IWDG_PR = 4u;                           /* /64: 500 Hz from the nominal 32 kHz LSI */
    IWDG_RLR = GS_IWDG_MS / 2u - 1u;        /* 2 ms a count; 12 bits (<= 8 s) */
    (void)poll(&IWDG_SR, IWDG_SR_BUSY, 0u); /* bounded as every poll here */
    iwdg_refresh();
}

#if GS_IWDG_MS < 4u || GS_IWDG_MS > 8190u
#error "GS_IWDG_MS must be 4..8190 (IWDG /64 prescaler: 2 ms a count, 12-bit reload)"
#endif

static gs_app_t app;

int main(void) {
    int iwdg_reset = (RCC_CSR & RCC_CSR_IWDGRSTF) != 0u;
    RCC_CSR |= RCC_CSR_RMVF;
    /* the log first (HSI clocks), so that the clock line can go out; re-timed after the switch */
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOAEN | RCC_AHB1ENR_GPIOBEN | RCC_AHB1ENR_GPIOCEN;
    RCC_APB1ENR |= RCC_APB1ENR_USART2EN | RCC_APB1ENR_USART3EN;
    RCC_APB2ENR |= RCC_APB2ENR_USART6EN;
    (void)RCC_APB2ENR; /* two cycles before the peripherals are clocked (errata ES0182 2.1.13) */
    pin_af(GPIOB, 10u, 7u, 0);  /* USART3_TX: log */
    pin_af(GPIOA, 2u, 7u, 0);   /* USART2_TX: host */
    pin_af(GPIOA, 3u, 7u, 0);   /* USART2_RX: host */
    pin_af(GPIOC, 6u, 8u, 1);   /* USART6_TX: the servo bus's one wire, open-drain with pull-up */
    NVIC_ISER(IRQ_USART2 / 32u) = 1u << (IRQ_USART2 % 32u);
    NVIC_ISER(IRQ_USART3 / 32u) = 1u << (IRQ_USART3 % 32u);
    NVIC_ISER(IRQ_USART6 / 32u) = 1u << (IRQ_USART6 % 32u);
    clock_init(); /* its line waits in the log ring until the log USART runs at the final clock */
    usart_init(LOG, pclk1_hz, GS_LOG_BAUD, USART_CR1_TE, 0u);
    usart_init(HOST, pclk1_hz, GS_HOST_BAUD, USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE, 0u);
    usart_init(BUS, pclk2_hz, GS_BUS_BAUD, USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE, USART_CR3_HDSEL);
    tim2_start();
    SYST_RVR = counts_per_tick - 1u;
    SYST_CVR = 0;
    SYST_CSR = 7u; /* processor clock, interrupt, enable */
    log_on = 1;
    tx_kick(LOG, &log_tx); /* the clock line */
    gs_log_str("board: uarts: ");
    log_rate("host USART2 PA2/PA3 ", pclk1_hz, GS_HOST_BAUD);
    log_rate(", servo bus USART6 PC6 half-duplex ", pclk2_hz, GS_BUS_BAUD);
    log_rate(", log USART3 PB10 ", pclk1_hz, GS_LOG_BAUD);
    gs_log_str(" baud; time base TIM2 from ");
    gs_log_u64(tim2_mhz);
    gs_log_str(" MHz");
    gs_log_str("; watchdog IWDG ");
    gs_log_u64(GS_IWDG_MS);
    gs_log_str(" ms");
    if (iwdg_reset) gs_log_str("; the last reset was the watchdog's");
    gs_log_end();
    iwdg_start();
    gs_settings_t cfg;
    gs_config_defaults(&cfg);
    if (gs_boot_cfg_apply(&cfg)) {
        gs_log_str("board: boot settings: the configuration block's (the servo bus is the emulator's plant)");
    } else { /* no block: a real board on a real line */
        cfg.bus_baud = GS_BUS_BAUD;
        gs_log_str("board: boot settings: the defaults (no valid configuration block)");
    }
    gs_log_end();
    (void)gs_app_run(&app, &cfg); /* a refused boot: its line is out, torque off; idle (the watchdog fed) */
    for (;;) {
        iwdg_refresh();
        __asm volatile("wfi");
    }
}
