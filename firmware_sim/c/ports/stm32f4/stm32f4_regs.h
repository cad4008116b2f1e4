/* The STM32F405/F407 registers the port uses, written from ST's reference manual RM0090 (Rev 19; section
 * numbers below) and, for the core peripherals (SysTick, NVIC, SCB), ARM's Cortex-M4 programming manual
 * PM0214. No vendor headers: addresses and bit positions only, as the manual tables them. */
#ifndef STM32F4_REGS_H
#define STM32F4_REGS_H

#include <stdint.h>

#define REG32(a) (*(volatile uint32_t *)(a))

/* --- RCC, RM0090 7.3 (base 0x4002 3800, memory map 2.3) ----------------------------------------------- */
#define RCC_BASE 0x40023800u
#define RCC_CR REG32(RCC_BASE + 0x00u)       /* 7.3.1 clock control */
#define RCC_PLLCFGR REG32(RCC_BASE + 0x04u)  /* 7.3.2 PLL configuration */
#define RCC_CFGR REG32(RCC_BASE + 0x08u)     /* 7.3.3 clock configuration */
#define RCC_AHB1ENR REG32(RCC_BASE + 0x30u)  /* 7.3.10 AHB1 peripheral clock enable */
#define RCC_APB1ENR REG32(RCC_BASE + 0x40u)  /* 7.3.13 APB1 peripheral clock enable */
#define RCC_APB2ENR REG32(RCC_BASE + 0x44u)  /* 7.3.14 APB2 peripheral clock enable */
#define RCC_CSR REG32(RCC_BASE + 0x74u)      /* 7.3.21 clock control & status (reset flags) */

#define RCC_CR_HSION (1u << 0)
#define RCC_CR_HSIRDY (1u << 1)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)

#define RCC_PLLCFGR_PLLM_POS 0u  /* [5:0] VCO input = PLL source / M (1..2 MHz) */
#define RCC_PLLCFGR_PLLN_POS 6u  /* [14:6] VCO output = VCO input x N (100..432 MHz) */
#define RCC_PLLCFGR_PLLP_POS 16u /* [17:16] SYSCLK = VCO / P, 00 = /2 */
#define RCC_PLLCFGR_PLLSRC_HSE (1u << 22)
#define RCC_PLLCFGR_PLLQ_POS 24u /* [27:24] USB/SDIO/RNG clock = VCO / Q (48 MHz) */

#define RCC_CFGR_SW_MASK (3u << 0) /* system clock switch: 00 HSI, 01 HSE, 10 PLL */
#define RCC_CFGR_SW_HSI (0u << 0)
#define RCC_CFGR_SW_PLL (2u << 0)
#define RCC_CFGR_SWS_MASK (3u << 2) /* its status, same coding */
#define RCC_CFGR_SWS_HSI (0u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_HPRE_MASK (15u << 4)   /* AHB prescaler, 0xxx = /1 */
#define RCC_CFGR_PPRE1_MASK (7u << 10)  /* APB1 prescaler: 0xx /1, 100 /2, 101 /4 */
#define RCC_CFGR_PPRE1_DIV4 (5u << 10)
#define RCC_CFGR_PPRE2_MASK (7u << 13)  /* APB2 prescaler, same coding */
#define RCC_CFGR_PPRE2_DIV2 (4u << 13)

#define RCC_AHB1ENR_GPIOAEN (1u << 0)
#define RCC_AHB1ENR_GPIOBEN (1u << 1)
#define RCC_AHB1ENR_GPIOCEN (1u << 2)
#define RCC_APB1ENR_TIM2EN (1u << 0)
#define RCC_APB1ENR_USART2EN (1u << 17)
#define RCC_APB1ENR_USART3EN (1u << 18)
#define RCC_APB1ENR_PWREN (1u << 28)
#define RCC_APB2ENR_USART6EN (1u << 5)
#define RCC_CSR_RMVF (1u << 24)     /* write 1: clear the reset flags */
#define RCC_CSR_IWDGRSTF (1u << 29) /* the last reset was the independent watchdog's */

/* --- PWR, RM0090 5.4.1 (base 0x4000 7000) ------------------------------------------------------------------ */
#define PWR_CR REG32(0x40007000u)
#define PWR_CR_VOS (1u << 14) /* regulator scale 1: needed for 168 MHz (F405/F407) */

/* --- Flash interface, RM0090 3.9.1 (base 0x4002 3C00): access control; wait states from table 10 -------- */
#define FLASH_ACR REG32(0x40023C00u)
#define FLASH_ACR_LATENCY_MASK 7u
#define FLASH_ACR_PRFTEN (1u << 8)
#define FLASH_ACR_ICEN (1u << 9)
#define FLASH_ACR_DCEN (1u << 10)

/* --- GPIO, RM0090 8.4 (ports A 0x4002 0000, B 0x4002 0400, C 0x4002 0800) ---------------------------------- */
#define GPIOA 0x40020000u
#define GPIOB 0x40020400u
#define GPIOC 0x40020800u
#define GPIO_MODER(p) REG32((p) + 0x00u)   /* 2 bits a pin: 10 = alternate function */
#define GPIO_OTYPER(p) REG32((p) + 0x04u)  /* 1 bit: 0 push-pull, 1 open-drain */
#define GPIO_OSPEEDR(p) REG32((p) + 0x08u) /* 2 bits: 10 = fast */
#define GPIO_PUPDR(p) REG32((p) + 0x0Cu)   /* 2 bits: 01 = pull-up */
#define GPIO_AFR(p, pin) REG32((p) + ((pin) < 8u ? 0x20u : 0x24u)) /* AFRL/AFRH, 4 bits a pin */

/* --- USART, RM0090 30.6 (USART2 0x4000 4400, USART3 0x4000 4800, USART1 0x4001 1000, USART6 0x4001 1400) --- */
#define USART1 0x40011000u
#define USART2 0x40004400u
#define USART3 0x40004800u
#define USART6 0x40011400u
#define USART_SR(u) REG32((u) + 0x00u)
#define USART_DR(u) REG32((u) + 0x04u)
#define USART_BRR(u) REG32((u) + 0x08u) /* [15:4] mantissa, [3:0] fraction of USARTDIV (OVER8 = 0) */
#define USART_CR1(u) REG32((u) + 0x0Cu)
#define USART_CR2(u) REG32((u) + 0x10u)
#define USART_CR3(u) REG32((u) + 0x14u)

#define USART_SR_ORE (1u << 3)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TC (1u << 6)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_RE (1u << 2)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RXNEIE (1u << 5)
#define USART_CR1_TXEIE (1u << 7)
#define USART_CR1_UE (1u << 13)
#define USART_CR3_HDSEL (1u << 3) /* single-wire half-duplex: RX internally on TX, the TX pin released when idle */

/* --- TIM2, RM0090 18.4 (base 0x4000 0000): a 32-bit general-purpose timer ----------------------------------- */
#define TIM2_CR1 REG32(0x40000000u)
#define TIM2_EGR REG32(0x40000014u)
#define TIM2_CNT REG32(0x40000024u)
#define TIM2_PSC REG32(0x40000028u)
#define TIM2_ARR REG32(0x4000002Cu)
#define TIM_CR1_CEN (1u << 0)
#define TIM_EGR_UG (1u << 0) /* update event: loads the buffered prescaler */

/* --- IWDG, RM0090 19.4 (base 0x4000 3000): key, prescaler, reload, status -------------------------------- */
#define IWDG_KR REG32(0x40003000u)
#define IWDG_PR REG32(0x40003004u)
#define IWDG_RLR REG32(0x40003008u)
#define IWDG_SR REG32(0x4000300Cu)
#define IWDG_KEY_RELOAD 0xAAAAu
#define IWDG_KEY_ACCESS 0x5555u
#define IWDG_KEY_START 0xCCCCu
#define IWDG_SR_BUSY 3u /* PVU | RVU: a prescaler/reload update in progress */

/* --- Cortex-M4 core peripherals, PM0214 4.3-4.5 ---------------------------------------------------------- */
#define SYST_CSR REG32(0xE000E010u) /* ENABLE bit 0, TICKINT bit 1, CLKSOURCE bit 2 (1 = processor clock) */
#define SYST_RVR REG32(0xE000E014u)
#define SYST_CVR REG32(0xE000E018u)
#define NVIC_ISER(n) REG32(0xE000E100u + 4u * (n)) /* write 1: enable interrupt 32n + bit */
#define NVIC_ICER(n) REG32(0xE000E180u + 4u * (n)) /* write 1: disable it */
#define SCB_ICSR REG32(0xE000ED04u)
#define SCB_ICSR_PENDSTSET (1u << 26)

/* --- interrupt numbers, RM0090 12.2 table 61 ---------------------------------------------------------------- */
#define IRQ_USART1 37u
#define IRQ_USART2 38u
#define IRQ_USART3 39u
#define IRQ_USART6 71u
#define IRQ_COUNT 82u /* F405/F407: positions 0..81 */

#endif
