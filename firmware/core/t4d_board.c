/* The portable core of a glove motor board (see t4d_board.h for the rules). */
#include "t4d_board.h"

#include <string.h>

const char *const t4d_counter_names[T4D_COUNTERS] = {
    "applied", "nmt", "ignored", "bad_counter", "unknown",
    "bad_length", "bad_frame_type", "bad_command", "error_frame", "watchdog_trips",
};

enum frame_kind { KIND_UNKNOWN, KIND_OTHER, KIND_NMT, KIND_DUTY };

const t4d_board_proto_t *t4d_board_proto(uint8_t node_id)
{
    for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
        if (t4d_board_protos[i].node_id == node_id) {
            return &t4d_board_protos[i];
        }
    }
    return NULL;
}

uint16_t t4d_duty_compare(uint8_t level, uint8_t full_scale, uint16_t period)
{
    if (full_scale == 0u) {
        return 0u;
    }
    if (level > full_scale) {
        level = full_scale;
    }
    return (uint16_t)(((uint32_t)level * period + full_scale / 2u) / full_scale);
}

/* Whether `now` has reached `deadline` (wrap-safe for deadlines less than 2^31 us away). */
static bool reached(uint32_t now, uint32_t deadline)
{
    return (int32_t)(now - deadline) >= 0;
}

/* Set every channel's level and compare value; the output hook hears of any change. */
static void set_levels(t4d_board_t *b, const uint8_t *levels)
{
    bool changed = false;
    for (unsigned c = 0; c < T4D_MAX_CHANNELS; c++) {
        uint8_t level = (b->proto != NULL && c < b->proto->channels) ? levels[c] : 0u;
        uint16_t compare = (b->proto != NULL) ? t4d_duty_compare(level, b->proto->duty_full_scale, b->pwm_period) : 0u;
        changed |= compare != b->compare[c];
        b->levels[c] = level;
        b->compare[c] = compare;
    }
    if (changed && b->output != NULL) {
        b->output(b->output_ctx, b->compare);
    }
}

static void outputs_off(t4d_board_t *b)
{
    static const uint8_t zero[T4D_MAX_CHANNELS];
    set_levels(b, zero);
}

static bool any_on(const t4d_board_t *b)
{
    for (unsigned c = 0; c < T4D_MAX_CHANNELS; c++) {
        if (b->levels[c] != 0u) {
            return true;
        }
    }
    return false;
}

uint8_t t4d_board_output_state(const t4d_board_t *b)
{
    if (b->nmt_state == T4D_NMT_STATE_STOPPED) {
        return T4D_OUTPUT_STOPPED;
    }
    if (b->nmt_state == T4D_NMT_STATE_PRE_OPERATIONAL) {
        return T4D_OUTPUT_PRE_OPERATIONAL;
    }
    if (b->hardware_faults != 0u) {
        return T4D_OUTPUT_FAULT_OFF;
    }
    if (b->watchdog_tripped) {
        return T4D_OUTPUT_WATCHDOG_OFF;
    }
    return any_on(b) ? T4D_OUTPUT_ACTIVE : T4D_OUTPUT_IDLE;
}

void t4d_board_boot(t4d_board_t *b, uint32_t now_us)
{
    outputs_off(b);
    b->nmt_state = T4D_NMT_STATE_PRE_OPERATIONAL;
    b->watchdog_tripped = false;
    b->last_counter = 0u;
    b->counter_sync = true;
    b->last_duty_us = now_us;
    b->bad_since_status = false;
    b->bootup_pending = true;
    b->last_output = t4d_board_output_state(b);
    b->next_status_us = now_us;
    b->next_heartbeat_us = now_us + b->heartbeat_period_us;
}

int t4d_board_init(t4d_board_t *b, uint8_t node_id, uint32_t watchdog_us, uint16_t pwm_period,
                   t4d_output_fn output, void *output_ctx, uint32_t now_us)
{
    memset(b, 0, sizeof *b);
    b->output = output;
    b->output_ctx = output_ctx;
    b->pwm_period = pwm_period;
    b->watchdog_us = watchdog_us;
    b->proto = t4d_board_proto(node_id);
    if (b->output != NULL) {
        b->output(b->output_ctx, b->compare); /* all zero: off, whatever the hardware held */
    }
    if (b->proto == NULL) {
        return -1;
    }
    b->status_period_us = b->proto->status_cycle_ms * 1000u;
    b->heartbeat_period_us = b->proto->heartbeat_cycle_ms * 1000u;
    t4d_board_boot(b, now_us);
    return 0;
}

static void reject(t4d_board_t *b, enum t4d_counter why)
{
    b->counters[why]++;
    b->bad_since_status = true;
}

static enum frame_kind classify(const t4d_board_t *b, uint32_t id)
{
    if (id == b->proto->duty_id) {
        return KIND_DUTY;
    }
    if (id == T4D_NMT_FRAME_ID) {
        return KIND_NMT;
    }
    for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
        const t4d_board_proto_t *p = &t4d_board_protos[i];
        if (id == p->duty_id || id == p->status_id || id == p->heartbeat_id) {
            return KIND_OTHER; /* another board's frame, or a board's answer: not ours to check */
        }
    }
    return KIND_UNKNOWN;
}

static void nmt(t4d_board_t *b, uint8_t command, uint32_t now_us)
{
    b->counters[T4D_COUNT_NMT]++;
    switch (command) {
    case T4D_NMT_START:
        b->nmt_state = T4D_NMT_STATE_OPERATIONAL;
        b->last_duty_us = now_us;
        b->counter_sync = true;
        break;
    case T4D_NMT_STOP:
        b->nmt_state = T4D_NMT_STATE_STOPPED;
        outputs_off(b); /* safety: within this frame, not at the next tick */
        break;
    case T4D_NMT_PRE_OPERATIONAL:
        b->nmt_state = T4D_NMT_STATE_PRE_OPERATIONAL;
        outputs_off(b);
        break;
    default: /* T4D_NMT_RESET_NODE (unknown commands were rejected before) */
        t4d_board_boot(b, now_us);
        break;
    }
}

static void duty(t4d_board_t *b, const t4d_frame_t *f, uint32_t now_us)
{
    uint8_t counter = 0u;
    uint8_t levels[T4D_MAX_CHANNELS] = {0};
    if (b->nmt_state != T4D_NMT_STATE_OPERATIONAL) {
        b->counters[T4D_COUNT_IGNORED]++;
        return;
    }
    if (b->proto->unpack_duty(f->data, f->len, &counter, levels) != 0) {
        reject(b, T4D_COUNT_BAD_LENGTH);
        return;
    }
    uint8_t step = (uint8_t)(counter - b->last_counter);
    if (!b->counter_sync && (step == 0u || step > T4D_COUNTER_WINDOW)) {
        reject(b, T4D_COUNT_BAD_COUNTER); /* a repeat or an old frame must not feed the watchdog */
        return;
    }
    b->counters[T4D_COUNT_APPLIED]++;
    b->last_duty_us = now_us;
    b->watchdog_tripped = false;
    b->counter_sync = false;
    b->last_counter = counter;
    if (b->hardware_faults != 0u) {
        outputs_off(b);
    } else {
        set_levels(b, levels);
    }
}

void t4d_board_receive(t4d_board_t *b, const t4d_frame_t *f, uint32_t now_us)
{
    if (b->proto == NULL) {
        return;
    }
    if (f->flags & T4D_FRAME_ERROR) {
        reject(b, T4D_COUNT_ERROR_FRAME);
        return;
    }
    enum frame_kind kind = (f->flags & T4D_FRAME_EXTENDED) ? KIND_UNKNOWN : classify(b, f->id);
    if (kind == KIND_UNKNOWN) {
        reject(b, T4D_COUNT_UNKNOWN);
        return;
    }
    if (kind == KIND_OTHER) {
        return;
    }
    if (f->flags & (T4D_FRAME_REMOTE | T4D_FRAME_FD)) {
        reject(b, T4D_COUNT_BAD_FRAME_TYPE);
        return;
    }
    if (kind == KIND_DUTY) {
        if (f->len != b->proto->duty_length) {
            reject(b, T4D_COUNT_BAD_LENGTH);
            return;
        }
        duty(b, f, now_us);
        return;
    }
    uint8_t command = 0u, node = 0u;
    if (f->len != T4D_NMT_LENGTH || t4d_unpack_nmt(f->data, f->len, &command, &node) != 0) {
        reject(b, T4D_COUNT_BAD_LENGTH);
        return;
    }
    if (command != T4D_NMT_START && command != T4D_NMT_STOP && command != T4D_NMT_PRE_OPERATIONAL &&
        command != T4D_NMT_RESET_NODE) {
        reject(b, T4D_COUNT_BAD_COMMAND);
        return;
    }
    if (node == 0u || node == b->proto->node_id) {
        nmt(b, command, now_us);
    }
}

static size_t heartbeat(const t4d_board_t *b, uint8_t state, t4d_frame_t *out)
{
    memset(out, 0, sizeof *out);
    out->id = b->proto->heartbeat_id;
    out->len = b->proto->heartbeat_length;
    return b->proto->pack_heartbeat(out->data, state) >= 0 ? 1u : 0u;
}

static uint8_t faults(const t4d_board_t *b)
{
    uint8_t f = b->hardware_faults;
    if (b->watchdog_tripped) {
        f |= T4D_FAULT_WATCHDOG;
    }
    if (b->bad_since_status) {
        f |= T4D_FAULT_BAD_FRAME;
    }
    return f;
}

static uint16_t bad_frames(const t4d_board_t *b)
{
    static const enum t4d_counter bad[] = {
        T4D_COUNT_BAD_LENGTH, T4D_COUNT_BAD_FRAME_TYPE, T4D_COUNT_BAD_COMMAND, T4D_COUNT_ERROR_FRAME,
        T4D_COUNT_UNKNOWN, T4D_COUNT_BAD_COUNTER,
    };
    uint32_t sum = 0u;
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        uint32_t n = b->counters[bad[i]];
        sum = (sum + n < sum) ? UINT32_MAX : sum + n;
    }
    return sum > 0xFFFFu ? 0xFFFFu : (uint16_t)sum;
}

static uint8_t active_mask(const t4d_board_t *b)
{
    uint8_t mask = 0u;
    for (unsigned c = 0; c < T4D_MAX_CHANNELS; c++) {
        if (b->levels[c] != 0u) {
            mask |= (uint8_t)(1u << c);
        }
    }
    return mask;
}

size_t t4d_board_tick(t4d_board_t *b, uint32_t now_us, t4d_frame_t *out)
{
    size_t n = 0;
    if (b->proto == NULL) {
        return 0;
    }
    if (b->nmt_state == T4D_NMT_STATE_OPERATIONAL && !b->watchdog_tripped &&
        now_us - b->last_duty_us > b->watchdog_us) {
        /* Safety: no command within the watchdog time -> every output off. */
        outputs_off(b);
        b->watchdog_tripped = true;
        b->counter_sync = true;
        b->counters[T4D_COUNT_WATCHDOG_TRIPS]++;
    }
    if (b->hardware_faults != 0u && any_on(b)) {
        outputs_off(b);
    }
    if (b->bootup_pending) {
        n += heartbeat(b, T4D_NMT_STATE_BOOTUP, &out[n]);
        b->bootup_pending = false;
    }
    uint8_t state = t4d_board_output_state(b);
    if (state != b->last_output || reached(now_us, b->next_status_us)) {
        t4d_status_t s = {
            .state = state,
            .faults = faults(b),
            .last_counter = b->last_counter,
            .active_mask = active_mask(b),
            .bad_frames = bad_frames(b),
        };
        memset(&out[n], 0, sizeof out[n]);
        out[n].id = b->proto->status_id;
        out[n].len = b->proto->status_length;
        if (b->proto->pack_status(out[n].data, &s) >= 0) {
            n++;
        }
        b->bad_since_status = false;
        b->last_output = state;
        b->next_status_us = now_us + b->status_period_us;
    }
    if (reached(now_us, b->next_heartbeat_us)) {
        n += heartbeat(b, b->nmt_state, &out[n]);
        b->next_heartbeat_us = now_us + b->heartbeat_period_us;
    }
    return n;
}

uint32_t t4d_board_due_in(const t4d_board_t *b, uint32_t now_us)
{
    if (b->proto == NULL) {
        return UINT32_MAX;
    }
    if (b->bootup_pending) {
        return 0u;
    }
    uint32_t wait = UINT32_MAX;
    uint32_t deadlines[3] = {b->next_status_us, b->next_heartbeat_us, 0u};
    size_t count = 2;
    if (b->nmt_state == T4D_NMT_STATE_OPERATIONAL && !b->watchdog_tripped) {
        deadlines[count++] = b->last_duty_us + b->watchdog_us + 1u; /* trips when strictly over */
    }
    for (size_t i = 0; i < count; i++) {
        if (reached(now_us, deadlines[i])) {
            return 0u;
        }
        uint32_t in = deadlines[i] - now_us;
        wait = in < wait ? in : wait;
    }
    return wait;
}

void t4d_board_set_hardware_faults(t4d_board_t *b, uint8_t faults_mask)
{
    b->hardware_faults = faults_mask & (T4D_FAULT_OVERTEMP | T4D_FAULT_OVERCURRENT | T4D_FAULT_UNDERVOLTAGE);
}

void t4d_board_all_off(t4d_board_t *b)
{
    outputs_off(b);
}
