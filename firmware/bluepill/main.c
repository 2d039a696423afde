/* A glove motor board on an STM32F103 "Blue Pill": the portable core on bxCAN and timer PWM.
 *
 * One loop, no interrupt but the 1 ms SysTick: receive every waiting frame (the core applies a
 * duty frame to the compare registers at once, through outputs_write), tick the core, send what it
 * returns, feed the independent watchdog. A stalled loop stops feeding it, and the reset that
 * follows turns every output off (see startup.c).
 */
#include "board.h"
#include "stm32f103.h"
#include "pwm_config.h"

#ifndef NODE_ID
#define NODE_ID 0 /* 0: read the strap pins */
#endif
#ifndef WATCHDOG_US
#define WATCHDOG_US 100000u /* the glove's can.board_watchdog_s */
#endif
/* Independent watchdog: LSI (30..60 kHz, 40 typical) / 4, reload 250 -> 25 ms (17..33 ms),
 * well inside the 100 ms communication watchdog. */
#define IWDG_PRESCALER_DIV4 0u
#define IWDG_RELOAD 250u
#define LED_PIN 13u

static t4d_board_t board;

static void iwdg_start(void)
{
    IWDG_KR = IWDG_KEY_ENABLE;
    IWDG_KR = IWDG_KEY_UNLOCK;
    IWDG_PR = IWDG_PRESCALER_DIV4;
    IWDG_RLR = IWDG_RELOAD;
    while (IWDG_SR != 0u) { /* the new values reach the LSI domain */
    }
    IWDG_KR = IWDG_KEY_RELOAD;
}

static void led_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_IOPCEN;
    GPIO_CRH(GPIOC_BASE) = (GPIO_CRH(GPIOC_BASE) & ~(0xFu << 20)) | (GPIO_OUTPUT_2MHZ << 20);
    GPIO_BSRR(GPIOC_BASE) = 1u << LED_PIN; /* off (active low) */
}

static void led(bool on)
{
    GPIO_BSRR(GPIOC_BASE) = on ? 1u << (LED_PIN + 16u) : 1u << LED_PIN;
}

/* The node id: the NODE_ID build flag, else 1 + the strap jumpers on PB12..PB15 (to GND = 1). */
static uint8_t node_id(void)
{
    if (NODE_ID != 0) {
        return (uint8_t)NODE_ID;
    }
    RCC_APB2ENR |= RCC_APB2ENR_IOPBEN;
    GPIO_CRH(GPIOB_BASE) = (GPIO_CRH(GPIOB_BASE) & ~(0xFFFFu << 16)) | 0x8888u << 16; /* pull-ups */
    GPIO_BSRR(GPIOB_BASE) = 0xFu << 12;
    for (volatile uint32_t n = 0; n < 1000u; n++) { /* let the pull-ups charge the pins */
    }
    return (uint8_t)(1u + ((~GPIO_IDR(GPIOB_BASE) >> 12) & 0xFu));
}

/* A board that cannot run safely (no crystal, a node id the glove lacks, CAN not starting):
 * outputs off, silent on the bus, the LED blinking fast; the watchdog is fed so it stays here. */
static void halt(void)
{
    board_outputs_off_gpio();
    for (uint32_t n = 0;; n++) {
        IWDG_KR = IWDG_KEY_RELOAD;
        led((n >> 19) & 1u); /* ~10 Hz at 72 MHz, ~1 Hz on the 8 MHz RC */
    }
}

int main(void)
{
    led_init();
    if (!clock_init()) {
        halt();
    }
    iwdg_start();
    outputs_init();
    supply_init();
    uint32_t now = clock_micros();
    if (t4d_board_init(&board, node_id(), WATCHDOG_US, BLUEPILL_PWM_PERIOD, outputs_write, NULL, now) != 0) {
        halt();
    }
    if (!can_init()) {
        halt();
    }
    bool was_bus_off = false;
    t4d_frame_t frame, out[T4D_TICK_MAX_FRAMES];
    for (;;) {
        now = clock_micros();
        while (can_receive(&frame)) {
            t4d_board_receive(&board, &frame, now);
        }
        bool bus_off = can_bus_off();
        if (bus_off && !was_bus_off) {
            t4d_board_all_off(&board); /* deaf to the controller until recovery: off now */
        }
        was_bus_off = bus_off;
        t4d_board_set_hardware_faults(&board, supply_low() ? T4D_FAULT_UNDERVOLTAGE : 0u);
        size_t n = t4d_board_tick(&board, clock_micros(), out);
        for (size_t i = 0; i < n; i++) {
            (void)can_send(&out[i]);
        }
        led(t4d_board_output_state(&board) == T4D_OUTPUT_ACTIVE || ((now >> 19) & 1u)); /* ~1 Hz blink idle */
        IWDG_KR = IWDG_KEY_RELOAD;
    }
}
