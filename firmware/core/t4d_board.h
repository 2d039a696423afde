/* The portable core of a glove motor board: CAN frames and the time in, outputs and frames out.
 *
 * No hardware access: the board layer (bluepill/ on the STM32F103, host/ for the Python bus, the
 * check program under QEMU) feeds received frames and a microsecond clock in, sends the frames
 * `t4d_board_tick` returns, and drives its PWM compare registers from the output hook. The
 * behaviour is the reference board emulator's (touch4d/boards/emulator.py), frame for frame:
 *
 * - boot: every output off, boot-up heartbeat, PRE_OPERATIONAL (duty frames ignored);
 * - NMT (to node 0 or this node): START -> OPERATIONAL, STOP -> STOPPED and every output off at
 *   once, PRE_OPERATIONAL -> every output off, RESET_NODE -> boot again (counters are kept);
 * - a duty frame in OPERATIONAL sets every channel, if its Counter is newer than the last applied
 *   one (serial-number arithmetic: 1..T4D_COUNTER_WINDOW ahead); after boot, START or a watchdog
 *   trip any Counter is accepted, so a restarted controller is followed;
 * - no accepted duty frame for more than the watchdog time -> every output off (WATCHDOG_OFF)
 *   until the next one;
 * - a hardware fault (set by the board layer) -> every output off (FAULT_OFF);
 * - status every status period (the DBC's cycle time) and at once on a change of output state;
 *   heartbeat every heartbeat period;
 * - every rejected frame is counted by reason (enum t4d_counter); the status frame's BadFrames is
 *   malformed + unknown + out-of-sequence frames.
 *
 * Times are uint32 microseconds and may wrap (every 71.6 min): only differences are used, so the
 * tick must run at least every 35 minutes (it runs continuously).
 */
#ifndef T4D_BOARD_H
#define T4D_BOARD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "t4d_protocol.h"

/* A duty frame is accepted when its Counter is 1..T4D_COUNTER_WINDOW ahead of the last applied:
 * a repeat (0) or an older frame (128..255 behind) is rejected. */
#define T4D_COUNTER_WINDOW 127u
#define T4D_TICK_MAX_FRAMES 3u /* boot-up heartbeat, status, heartbeat */

enum t4d_frame_flags {
    T4D_FRAME_EXTENDED = 1u,
    T4D_FRAME_REMOTE = 2u,
    T4D_FRAME_ERROR = 4u, /* an error frame reported by the host's CAN stack */
    T4D_FRAME_FD = 8u,
};

typedef struct {
    uint32_t id;
    uint8_t flags; /* enum t4d_frame_flags */
    uint8_t len;   /* data length as received (may exceed 8 for a host FD frame) */
    uint8_t data[8];
} t4d_frame_t;

/* What the board counts; the names are t4d_counter_names[]. */
enum t4d_counter {
    T4D_COUNT_APPLIED,        /* duty frames applied */
    T4D_COUNT_NMT,            /* NMT commands addressed to this board */
    T4D_COUNT_IGNORED,        /* duty frames received while not OPERATIONAL */
    T4D_COUNT_BAD_COUNTER,    /* rejected: Counter not newer than the last applied */
    T4D_COUNT_UNKNOWN,        /* rejected: an id the glove does not use, or an extended id */
    T4D_COUNT_BAD_LENGTH,     /* rejected (malformed): a glove id with the wrong data length */
    T4D_COUNT_BAD_FRAME_TYPE, /* rejected (malformed): a remote or FD frame at a glove id */
    T4D_COUNT_BAD_COMMAND,    /* rejected (malformed): an NMT frame with an unknown command */
    T4D_COUNT_ERROR_FRAME,    /* rejected (malformed): an error frame */
    T4D_COUNT_WATCHDOG_TRIPS, /* communication watchdog turned the outputs off */
    T4D_COUNTERS
};

extern const char *const t4d_counter_names[T4D_COUNTERS];

/* Called with every channel's compare value whenever the outputs change (NULL: none). */
typedef void (*t4d_output_fn)(void *ctx, const uint16_t compare[T4D_MAX_CHANNELS]);

typedef struct {
    const t4d_board_proto_t *proto; /* NULL: the node id is not a board of the glove */
    t4d_output_fn output;
    void *output_ctx;
    uint32_t watchdog_us, status_period_us, heartbeat_period_us;
    uint32_t last_duty_us, next_status_us, next_heartbeat_us;
    uint16_t pwm_period;
    uint8_t nmt_state;       /* T4D_NMT_STATE_* */
    uint8_t hardware_faults; /* T4D_FAULT_* bits set by the board layer */
    uint8_t last_counter;
    uint8_t last_output;     /* output state of the last status sent */
    bool counter_sync;       /* the next duty frame may carry any Counter */
    bool watchdog_tripped;
    bool bad_since_status;
    bool bootup_pending;
    uint8_t levels[T4D_MAX_CHANNELS];
    uint16_t compare[T4D_MAX_CHANNELS];
    uint32_t counters[T4D_COUNTERS];
} t4d_board_t;

/* Set up and boot a board; its outputs are off. Returns -1 (the board stays off and silent) if
 * the glove has no board `node_id`. */
int t4d_board_init(t4d_board_t *b, uint8_t node_id, uint32_t watchdog_us, uint16_t pwm_period,
                   t4d_output_fn output, void *output_ctx, uint32_t now_us);

/* Power-up state again (as after RESET_NODE); the counters are kept. */
void t4d_board_boot(t4d_board_t *b, uint32_t now_us);

/* One frame from the bus. */
void t4d_board_receive(t4d_board_t *b, const t4d_frame_t *frame, uint32_t now_us);

/* Watchdog, hardware faults and the frames to send now (at most T4D_TICK_MAX_FRAMES into out). */
size_t t4d_board_tick(t4d_board_t *b, uint32_t now_us, t4d_frame_t *out);

/* Microseconds until `t4d_board_tick` has work without a frame arriving (0: now). */
uint32_t t4d_board_due_in(const t4d_board_t *b, uint32_t now_us);

/* Hardware faults seen by the board layer (T4D_FAULT_OVERTEMP | ...); any -> outputs off. */
void t4d_board_set_hardware_faults(t4d_board_t *b, uint8_t faults);

/* Every output off now (the board layer's reaction to an internal fault). */
void t4d_board_all_off(t4d_board_t *b);

uint8_t t4d_board_output_state(const t4d_board_t *b); /* T4D_OUTPUT_* */

/* Duty level (0..full_scale, the DBC's 7-bit Duty_ChK) -> timer compare value 0..period, rounded
 * to nearest: 0 is always off, full scale always on. */
uint16_t t4d_duty_compare(uint8_t level, uint8_t full_scale, uint16_t period);

#endif
