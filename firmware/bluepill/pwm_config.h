/* The Blue Pill's motor PWM: TIM2 and TIM3 at 72 MHz, 20 kHz (above hearing, within the input
 * range of PWM-input haptic drivers such as the DRV2603). Shared with the host build so the
 * Python side sees the compare values this board would write. */
#ifndef BLUEPILL_PWM_CONFIG_H
#define BLUEPILL_PWM_CONFIG_H

#define BLUEPILL_CPU_HZ 72000000u
#define BLUEPILL_PWM_HZ 20000u
#define BLUEPILL_PWM_PERIOD (BLUEPILL_CPU_HZ / BLUEPILL_PWM_HZ) /* 3600 timer counts */

#endif
