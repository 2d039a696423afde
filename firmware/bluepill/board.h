/* The Blue Pill (STM32F103C8) board layer: what main.c uses of clock.c, outputs.c, can.c and
 * supply.c. Pins:
 *   channels 0..7   PA0 PA1 PA2 PA3 (TIM2 CH1..4), PA6 PA7 PB0 PB1 (TIM3 CH1..4), active high
 *   CAN             PB8 = CAN_RX, PB9 = CAN_TX (remapped; PA11/PA12 stay free for USB)
 *   node id straps  PB12..PB15: a jumper to GND sets bit 0..3, node id = 1 + bits
 *   motor supply    PA4 = VM / 2 (optional divider, SUPPLY_SENSE=1)
 *   LED             PC13 (on the Blue Pill, active low)
 */
#ifndef BOARD_H
#define BOARD_H

#include <stdbool.h>
#include <stdint.h>

#include "t4d_board.h"

/* clock.c: 72 MHz from the 8 MHz crystal, a microsecond clock from SysTick */
bool clock_init(void);
uint32_t clock_micros(void);

/* outputs.c: the eight PWM channels */
void board_outputs_off_gpio(void); /* every output pin a low GPIO: no timer needed */
void outputs_init(void);
void outputs_write(void *ctx, const uint16_t compare[T4D_MAX_CHANNELS]); /* the core's output hook */

/* can.c: bxCAN at 500 kbit/s, every frame received (the core counts unknown ones) */
bool can_init(void);
bool can_receive(t4d_frame_t *frame); /* false when the receive FIFO is empty */
bool can_send(const t4d_frame_t *frame); /* false when no transmit mailbox is free */
bool can_bus_off(void);
extern uint32_t can_rx_overruns, can_tx_dropped;

/* supply.c: motor supply undervoltage (only with SUPPLY_SENSE=1) */
void supply_init(void);
bool supply_low(void);

#endif
