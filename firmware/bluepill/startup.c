/* Reset and fault entry of the STM32F103: the vector table, memory set-up, and the fail-safe
 * handlers. Every output goes off before anything else runs, and on any fault. */
#include <stdint.h>

#include "board.h"
#include "stm32f103.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);

/* Any fault or unexpected interrupt: outputs off (as GPIO, not trusting the timers), then a
 * system reset; the board boots with its outputs off and the controller sees the boot-up. */
void fault_handler(void)
{
    board_outputs_off_gpio();
    SCB_AIRCR = SCB_AIRCR_SYSRESET;
    for (;;) {
    }
}

void reset_handler(void)
{
    board_outputs_off_gpio(); /* first: the gate pull-downs held them off until now */
    uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0u;
    }
    (void)main();
    fault_handler(); /* main never returns */
}

void systick_handler(void);

#define F1 fault_handler
#define F4 F1, F1, F1, F1
#define F16 F4, F4, F4, F4

typedef void (*vector_t)(void);

/* 16 system vectors, then the 43 interrupts of a medium-density STM32F103: only SysTick is used;
 * NMI, every fault and any unexpected interrupt lead to fault_handler. */
__attribute__((section(".isr_vector"), used)) const vector_t vectors[16 + 43] = {
    (vector_t)(uintptr_t)&_estack, reset_handler,
    F1, F1, F1, F1, F1, 0, 0, 0, 0, F1, F1, 0, F1, systick_handler, /* NMI .. PendSV, SysTick */
    F16, F16, F4, F4, F1, F1, F1,                              /* IRQ 0 .. 42 */
};
