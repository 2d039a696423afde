/* System clock (72 MHz from the 8 MHz crystal through the PLL) and a microsecond clock. */
#include "board.h"
#include "pwm_config.h"
#include "stm32f103.h"

#define SYSTICK_RELOAD (BLUEPILL_CPU_HZ / 1000u - 1u) /* 1 ms */
#define HSE_TIMEOUT 50000u /* loop turns on the 8 MHz RC: ~30 ms; a crystal starts in ~2 ms */

static volatile uint32_t tick_us; /* microseconds at the last SysTick, wraps every 71.6 min */

void systick_handler(void)
{
    tick_us += 1000u;
}

/* Whether the crystal runs; CAN needs its accuracy (the 8 MHz RC is +-2 %: too coarse). */
bool clock_init(void)
{
    RCC_CR |= RCC_CR_HSEON;
    uint32_t n = 0;
    while (!(RCC_CR & RCC_CR_HSERDY)) {
        if (++n > HSE_TIMEOUT) {
            return false;
        }
    }
    FLASH_ACR = FLASH_ACR_PRFTBE | FLASH_ACR_LATENCY_2;
    RCC_CFGR = RCC_CFGR_PLLMUL9 | RCC_CFGR_PLLSRC_HSE | RCC_CFGR_PPRE1_DIV2 | RCC_CFGR_ADCPRE_DIV6;
    RCC_CR |= RCC_CR_PLLON;
    while (!(RCC_CR & RCC_CR_PLLRDY)) {
    }
    RCC_CFGR |= RCC_CFGR_SW_PLL;
    while ((RCC_CFGR & RCC_CFGR_SWS_MASK) != RCC_CFGR_SWS_PLL) {
    }
    SYST_RVR = SYSTICK_RELOAD;
    SYST_CVR = 0u;
    SYST_CSR = SYST_CSR_ENABLE_TICKINT_CPU;
    return true;
}

uint32_t clock_micros(void)
{
    uint32_t base, count;
    do { /* a SysTick between the two reads changes tick_us: read again */
        base = tick_us;
        count = SYST_CVR;
    } while (base != tick_us);
    return base + (SYSTICK_RELOAD - count) / (BLUEPILL_CPU_HZ / 1000000u);
}
