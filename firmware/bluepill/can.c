/* bxCAN at 500 kbit/s on PB8/PB9: every frame to receive FIFO 0 (the core decides what is
 * unknown and counts it), three transmit mailboxes sent in request order. Polled, no interrupt. */
#include "board.h"
#include "stm32f103.h"

/* Loop turns, < 8 ms at 72 MHz: inside the independent watchdog's 17 ms. Leaving initialisation
 * needs 11 recessive bits on the bus: a bus held dominant gives up here (halt, LED blinking). */
#define INIT_TIMEOUT 50000u

uint32_t can_rx_overruns, can_tx_dropped;

static bool wait_msr(uint32_t mask, uint32_t want)
{
    for (uint32_t n = 0; n < INIT_TIMEOUT; n++) {
        if ((CAN_MSR & mask) == want) {
            return true;
        }
    }
    return false;
}

bool can_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_AFIOEN | RCC_APB2ENR_IOPBEN;
    RCC_APB1ENR |= RCC_APB1ENR_CANEN;
    AFIO_MAPR = (AFIO_MAPR & ~AFIO_MAPR_CAN_REMAP_MASK) | AFIO_MAPR_CAN_REMAP_PB8_PB9;
    /* PB8 = CAN_RX: input with pull-up; PB9 = CAN_TX: alternate function push-pull */
    GPIO_CRH(GPIOB_BASE) = (GPIO_CRH(GPIOB_BASE) & ~0xFFu) | GPIO_INPUT_PULL | (GPIO_AF_OUTPUT_50MHZ << 4);
    GPIO_BSRR(GPIOB_BASE) = 1u << 8;

    CAN_MCR = CAN_MCR_INRQ; /* leave sleep, enter initialisation */
    if (!wait_msr(CAN_MSR_INAK | CAN_MSR_SLAK, CAN_MSR_INAK)) {
        return false;
    }
    /* automatic bus-off recovery; transmit in request order; retransmit until acknowledged */
    CAN_MCR = CAN_MCR_INRQ | CAN_MCR_ABOM | CAN_MCR_TXFP;
    CAN_BTR = CAN_BTR_500K;

    CAN_FMR |= CAN_FMR_FINIT; /* filter bank 0: 32-bit mask 0, i.e. every frame, to FIFO 0 */
    CAN_FA1R &= ~1u;
    CAN_FS1R |= 1u;
    CAN_FM1R &= ~1u;
    CAN_FFA1R &= ~1u;
    CAN_F0R1 = 0u;
    CAN_F0R2 = 0u;
    CAN_FA1R |= 1u;
    CAN_FMR &= ~CAN_FMR_FINIT;

    CAN_MCR &= ~CAN_MCR_INRQ;
    return wait_msr(CAN_MSR_INAK, 0u);
}

bool can_receive(t4d_frame_t *f)
{
    uint32_t rf = CAN_RF0R;
    if (rf & CAN_RF0R_FOVR0) {
        can_rx_overruns++;
        CAN_RF0R = CAN_RF0R_FOVR0;
    }
    if ((rf & CAN_RF0R_FMP0) == 0u) {
        return false;
    }
    uint32_t rir = CAN_RI0R, rdtr = CAN_RDT0R, lo = CAN_RDL0R, hi = CAN_RDH0R;
    CAN_RF0R = CAN_RF0R_RFOM0; /* release the mailbox */
    f->flags = (uint8_t)(((rir & CAN_RIR_IDE) ? T4D_FRAME_EXTENDED : 0u) | ((rir & CAN_RIR_RTR) ? T4D_FRAME_REMOTE : 0u));
    f->id = (rir & CAN_RIR_IDE) ? (rir >> 3) : (rir >> 21);
    f->len = (uint8_t)(rdtr & 0xFu);
    if (f->len > 8u) {
        f->len = 8u; /* DLC 9..15 means 8 bytes in classic CAN */
    }
    for (unsigned i = 0; i < 4u; i++) {
        f->data[i] = (uint8_t)(lo >> (8u * i));
        f->data[4u + i] = (uint8_t)(hi >> (8u * i));
    }
    return true;
}

bool can_send(const t4d_frame_t *f)
{
    uint32_t tsr = CAN_TSR;
    for (uint32_t box = 0; box < 3u; box++) {
        if (tsr & (CAN_TSR_TME0 << box)) {
            CAN_TDTR(box) = f->len;
            CAN_TDLR(box) = (uint32_t)f->data[0] | (uint32_t)f->data[1] << 8 | (uint32_t)f->data[2] << 16 |
                            (uint32_t)f->data[3] << 24;
            CAN_TDHR(box) = (uint32_t)f->data[4] | (uint32_t)f->data[5] << 8 | (uint32_t)f->data[6] << 16 |
                            (uint32_t)f->data[7] << 24;
            CAN_TIR(box) = (f->id << 21) | CAN_TIR_TXRQ;
            return true;
        }
    }
    can_tx_dropped++;
    return false;
}

bool can_bus_off(void)
{
    return (CAN_ESR & CAN_ESR_BOFF) != 0u;
}
