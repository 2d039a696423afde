/* The STM32F103 registers this board layer uses (RM0008), at register level: no vendor library. */
#ifndef STM32F103_H
#define STM32F103_H

#include <stdint.h>

#define REG(addr) (*(volatile uint32_t *)(addr))

/* RCC: reset and clock control */
#define RCC_BASE 0x40021000u
#define RCC_CR REG(RCC_BASE + 0x00u)
#define RCC_CFGR REG(RCC_BASE + 0x04u)
#define RCC_APB2ENR REG(RCC_BASE + 0x18u)
#define RCC_APB1ENR REG(RCC_BASE + 0x1Cu)
#define RCC_CSR REG(RCC_BASE + 0x24u)
#define RCC_CR_HSEON (1u << 16)
#define RCC_CR_HSERDY (1u << 17)
#define RCC_CR_PLLON (1u << 24)
#define RCC_CR_PLLRDY (1u << 25)
#define RCC_CFGR_SW_PLL (2u << 0)
#define RCC_CFGR_SWS_MASK (3u << 2)
#define RCC_CFGR_SWS_PLL (2u << 2)
#define RCC_CFGR_PPRE1_DIV2 (4u << 8)
#define RCC_CFGR_ADCPRE_DIV6 (2u << 14)
#define RCC_CFGR_PLLSRC_HSE (1u << 16)
#define RCC_CFGR_PLLMUL9 (7u << 18)
#define RCC_APB2ENR_AFIOEN (1u << 0)
#define RCC_APB2ENR_IOPAEN (1u << 2)
#define RCC_APB2ENR_IOPBEN (1u << 3)
#define RCC_APB2ENR_IOPCEN (1u << 4)
#define RCC_APB2ENR_ADC1EN (1u << 9)
#define RCC_APB1ENR_TIM2EN (1u << 0)
#define RCC_APB1ENR_TIM3EN (1u << 1)
#define RCC_APB1ENR_CANEN (1u << 25)
#define RCC_CSR_RMVF (1u << 24)
#define RCC_CSR_IWDGRSTF (1u << 29)

/* FLASH: wait states for 72 MHz */
#define FLASH_ACR REG(0x40022000u)
#define FLASH_ACR_LATENCY_2 2u
#define FLASH_ACR_PRFTBE (1u << 4)

/* GPIO: one CRL/CRH nibble per pin (MODE[1:0], CNF[1:0]) */
#define GPIOA_BASE 0x40010800u
#define GPIOB_BASE 0x40010C00u
#define GPIOC_BASE 0x40011000u
#define GPIO_CRL(base) REG((base) + 0x00u)
#define GPIO_CRH(base) REG((base) + 0x04u)
#define GPIO_IDR(base) REG((base) + 0x08u)
#define GPIO_ODR(base) REG((base) + 0x0Cu)
#define GPIO_BSRR(base) REG((base) + 0x10u)
#define GPIO_BRR(base) REG((base) + 0x14u)
#define GPIO_ANALOG 0x0u         /* input, analog */
#define GPIO_INPUT_PULL 0x8u     /* input with pull-up (ODR bit 1) or pull-down (0) */
#define GPIO_OUTPUT_2MHZ 0x2u    /* general purpose push-pull output */
#define GPIO_AF_OUTPUT_50MHZ 0xBu /* alternate function push-pull output */

/* AFIO: pin remapping */
#define AFIO_MAPR REG(0x40010004u)
#define AFIO_MAPR_CAN_REMAP_MASK (3u << 13)
#define AFIO_MAPR_CAN_REMAP_PB8_PB9 (2u << 13)

/* TIM2, TIM3: general purpose timers (PWM) */
#define TIM2_BASE 0x40000000u
#define TIM3_BASE 0x40000400u
#define TIM_CR1(base) REG((base) + 0x00u)
#define TIM_EGR(base) REG((base) + 0x14u)
#define TIM_CCMR1(base) REG((base) + 0x18u)
#define TIM_CCMR2(base) REG((base) + 0x1Cu)
#define TIM_CCER(base) REG((base) + 0x20u)
#define TIM_PSC(base) REG((base) + 0x28u)
#define TIM_ARR(base) REG((base) + 0x2Cu)
#define TIM_CCR(base, n) REG((base) + 0x34u + 4u * ((n) - 1u)) /* n = 1..4 */
#define TIM_CR1_CEN (1u << 0)
#define TIM_CR1_ARPE (1u << 7)
#define TIM_EGR_UG (1u << 0)
#define TIM_CCMR_PWM1_PRELOAD(ch) ((6u << 4 | 1u << 3) << (8u * (ch))) /* ch 0/1 of the register */
#define TIM_CCER_ALL (1u << 0 | 1u << 4 | 1u << 8 | 1u << 12)

/* bxCAN */
#define CAN_BASE 0x40006400u
#define CAN_MCR REG(CAN_BASE + 0x000u)
#define CAN_MSR REG(CAN_BASE + 0x004u)
#define CAN_TSR REG(CAN_BASE + 0x008u)
#define CAN_RF0R REG(CAN_BASE + 0x00Cu)
#define CAN_ESR REG(CAN_BASE + 0x018u)
#define CAN_BTR REG(CAN_BASE + 0x01Cu)
#define CAN_TIR(n) REG(CAN_BASE + 0x180u + 0x10u * (n))
#define CAN_TDTR(n) REG(CAN_BASE + 0x184u + 0x10u * (n))
#define CAN_TDLR(n) REG(CAN_BASE + 0x188u + 0x10u * (n))
#define CAN_TDHR(n) REG(CAN_BASE + 0x18Cu + 0x10u * (n))
#define CAN_RI0R REG(CAN_BASE + 0x1B0u)
#define CAN_RDT0R REG(CAN_BASE + 0x1B4u)
#define CAN_RDL0R REG(CAN_BASE + 0x1B8u)
#define CAN_RDH0R REG(CAN_BASE + 0x1BCu)
#define CAN_FMR REG(CAN_BASE + 0x200u)
#define CAN_FM1R REG(CAN_BASE + 0x204u)
#define CAN_FS1R REG(CAN_BASE + 0x20Cu)
#define CAN_FFA1R REG(CAN_BASE + 0x214u)
#define CAN_FA1R REG(CAN_BASE + 0x21Cu)
#define CAN_F0R1 REG(CAN_BASE + 0x240u)
#define CAN_F0R2 REG(CAN_BASE + 0x244u)
#define CAN_MCR_INRQ (1u << 0)
#define CAN_MCR_SLEEP (1u << 1)
#define CAN_MCR_TXFP (1u << 2)
#define CAN_MCR_ABOM (1u << 6)
#define CAN_MSR_INAK (1u << 0)
#define CAN_MSR_SLAK (1u << 1)
#define CAN_TSR_TME0 (1u << 26)
#define CAN_RF0R_FMP0 (3u << 0)
#define CAN_RF0R_FOVR0 (1u << 4)
#define CAN_RF0R_RFOM0 (1u << 5)
#define CAN_ESR_BOFF (1u << 2)
#define CAN_RIR_RTR (1u << 1)
#define CAN_RIR_IDE (1u << 2)
#define CAN_TIR_TXRQ (1u << 0)
#define CAN_FMR_FINIT (1u << 0)
/* 500 kbit/s from APB1 = 36 MHz: prescaler 9 -> 8 time quanta per bit (1 sync + 6 + 1),
 * sample point 87.5 % (CiA 301), resynchronisation jump width 1. */
#define CAN_BTR_500K ((0u << 24) | ((1u - 1u) << 20) | ((6u - 1u) << 16) | (9u - 1u))

/* IWDG: independent watchdog on the ~40 kHz LSI */
#define IWDG_KR REG(0x40003000u)
#define IWDG_PR REG(0x40003004u)
#define IWDG_RLR REG(0x40003008u)
#define IWDG_SR REG(0x4000300Cu)
#define IWDG_KEY_RELOAD 0xAAAAu
#define IWDG_KEY_ENABLE 0xCCCCu
#define IWDG_KEY_UNLOCK 0x5555u

/* ADC1 (motor supply sense) */
#define ADC1_BASE 0x40012400u
#define ADC1_SR REG(ADC1_BASE + 0x00u)
#define ADC1_CR2 REG(ADC1_BASE + 0x08u)
#define ADC1_SMPR2 REG(ADC1_BASE + 0x10u)
#define ADC1_SQR1 REG(ADC1_BASE + 0x2Cu)
#define ADC1_SQR3 REG(ADC1_BASE + 0x34u)
#define ADC1_DR REG(ADC1_BASE + 0x4Cu)
#define ADC_CR2_ADON (1u << 0)
#define ADC_CR2_CONT (1u << 1)
#define ADC_CR2_CAL (1u << 2)
#define ADC_CR2_RSTCAL (1u << 3)

/* Cortex-M3 core peripherals */
#define SYST_CSR REG(0xE000E010u)
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define SYST_CSR_ENABLE_TICKINT_CPU 7u
#define SCB_AIRCR REG(0xE000ED0Cu)
#define SCB_AIRCR_SYSRESET (0x05FAu << 16 | 1u << 2)

#endif
