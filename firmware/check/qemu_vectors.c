/* Vector table of the check program on QEMU's stm32vldiscovery (an STM32F100, Cortex-M3): the
 * stack top, and newlib's semihosting start-up (rdimon crt0), which sets up memory and argv. */
#include <stdint.h>

extern uint32_t __stack;
void _start(void);
static void fault(void)
{
    for (;;) { /* QEMU stops at its time limit; the missing END line fails the test */
    }
}

typedef void (*vector_t)(void);

__attribute__((section(".isr_vector"), used)) const vector_t vectors[16] = {
    (vector_t)(uintptr_t)&__stack, _start, fault, fault, fault, fault, fault, 0, 0, 0, 0, fault, fault, 0, fault, fault,
};
