/* The eight motor outputs: TIM2 and TIM3 in PWM mode 1 at 20 kHz, and a timer-free way off. */
#include "board.h"
#include "pwm_config.h"
#include "stm32f103.h"

#define PA_PINS ((1u << 0) | (1u << 1) | (1u << 2) | (1u << 3) | (1u << 6) | (1u << 7))
#define PB_PINS ((1u << 0) | (1u << 1))

/* A CRL value with the nibble of every pin in `pins` (0..7) set to `mode`. */
static uint32_t crl_with(uint32_t crl, uint32_t pins, uint32_t mode)
{
    for (uint32_t pin = 0; pin < 8u; pin++) {
        if (pins & (1u << pin)) {
            crl = (crl & ~(0xFu << (4u * pin))) | (mode << (4u * pin));
        }
    }
    return crl;
}

void board_outputs_off_gpio(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_IOPAEN | RCC_APB2ENR_IOPBEN;
    GPIO_BRR(GPIOA_BASE) = PA_PINS;
    GPIO_BRR(GPIOB_BASE) = PB_PINS;
    GPIO_CRL(GPIOA_BASE) = crl_with(GPIO_CRL(GPIOA_BASE), PA_PINS, GPIO_OUTPUT_2MHZ);
    GPIO_CRL(GPIOB_BASE) = crl_with(GPIO_CRL(GPIOB_BASE), PB_PINS, GPIO_OUTPUT_2MHZ);
}

static void timer_init(uint32_t tim)
{
    TIM_PSC(tim) = 0u;
    TIM_ARR(tim) = BLUEPILL_PWM_PERIOD - 1u;
    for (uint32_t ch = 1; ch <= 4u; ch++) {
        TIM_CCR(tim, ch) = 0u; /* PWM mode 1: compare 0 is always low, PERIOD always high */
    }
    TIM_CCMR1(tim) = TIM_CCMR_PWM1_PRELOAD(0) | TIM_CCMR_PWM1_PRELOAD(1);
    TIM_CCMR2(tim) = TIM_CCMR_PWM1_PRELOAD(0) | TIM_CCMR_PWM1_PRELOAD(1);
    TIM_CCER(tim) = TIM_CCER_ALL;
    TIM_CR1(tim) = TIM_CR1_ARPE;
    TIM_EGR(tim) = TIM_EGR_UG; /* load the zero compare values before the pins are handed over */
    TIM_CR1(tim) = TIM_CR1_ARPE | TIM_CR1_CEN;
}

void outputs_init(void)
{
    RCC_APB1ENR |= RCC_APB1ENR_TIM2EN | RCC_APB1ENR_TIM3EN;
    timer_init(TIM2_BASE);
    timer_init(TIM3_BASE);
    GPIO_CRL(GPIOA_BASE) = crl_with(GPIO_CRL(GPIOA_BASE), PA_PINS, GPIO_AF_OUTPUT_50MHZ);
    GPIO_CRL(GPIOB_BASE) = crl_with(GPIO_CRL(GPIOB_BASE), PB_PINS, GPIO_AF_OUTPUT_50MHZ);
}

/* New compare values take effect at the next timer update (within one 50 us PWM period):
 * preloaded, so a period is never cut short. */
void outputs_write(void *ctx, const uint16_t compare[T4D_MAX_CHANNELS])
{
    (void)ctx;
    TIM_CCR(TIM2_BASE, 1) = compare[0];
    TIM_CCR(TIM2_BASE, 2) = compare[1];
    TIM_CCR(TIM2_BASE, 3) = compare[2];
    TIM_CCR(TIM2_BASE, 4) = compare[3];
    TIM_CCR(TIM3_BASE, 1) = compare[4];
    TIM_CCR(TIM3_BASE, 2) = compare[5];
    TIM_CCR(TIM3_BASE, 3) = compare[6];
    TIM_CCR(TIM3_BASE, 4) = compare[7];
}
