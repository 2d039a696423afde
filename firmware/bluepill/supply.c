/* Motor supply undervoltage: ADC1 channel 4 (PA4) reads VM through a 10k/10k divider, in
 * continuous conversion. Built only with SUPPLY_SENSE=1: an unconnected PA4 would float. */
#include "board.h"
#include "stm32f103.h"

#ifndef SUPPLY_SENSE
#define SUPPLY_SENSE 0
#endif
#ifndef SUPPLY_LOW_MV
#define SUPPLY_LOW_MV 3000u /* below this the coin motors stall: report, and stay off */
#endif
#define SUPPLY_HYSTERESIS_MV 150u
#define ADC_FULL_SCALE_MV 3300u
#define DIVIDER 2u

static bool low;

void supply_init(void)
{
#if SUPPLY_SENSE
    RCC_APB2ENR |= RCC_APB2ENR_ADC1EN | RCC_APB2ENR_IOPAEN;
    GPIO_CRL(GPIOA_BASE) &= ~(0xFu << 16); /* PA4 analog input */
    ADC1_CR2 = ADC_CR2_ADON;               /* power up, then wait t_STAB (1 us) */
    for (volatile uint32_t n = 0; n < 100u; n++) {
    }
    ADC1_CR2 |= ADC_CR2_RSTCAL;
    while (ADC1_CR2 & ADC_CR2_RSTCAL) {
    }
    ADC1_CR2 |= ADC_CR2_CAL;
    while (ADC1_CR2 & ADC_CR2_CAL) {
    }
    ADC1_SMPR2 = 7u << 12; /* channel 4: 239.5 cycles, for the divider's impedance */
    ADC1_SQR1 = 0u;        /* one conversion in the sequence */
    ADC1_SQR3 = 4u;        /* channel 4 */
    ADC1_CR2 = ADC_CR2_ADON | ADC_CR2_CONT;
    ADC1_CR2 = ADC_CR2_ADON | ADC_CR2_CONT; /* ADON again starts the conversions */
#endif
}

bool supply_low(void)
{
#if SUPPLY_SENSE
    uint32_t mv = (ADC1_DR & 0xFFFu) * ADC_FULL_SCALE_MV * DIVIDER / 4095u;
    low = low ? mv < SUPPLY_LOW_MV + SUPPLY_HYSTERESIS_MV : mv < SUPPLY_LOW_MV;
#endif
    return low;
}
