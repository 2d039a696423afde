/* The host build of the core as a shared library, for Python's ctypes (touch4d/boards/firmware.py).
 *
 * Flat wrappers around the core's API, so the Python side mirrors no C struct: a board is an
 * opaque buffer of t4d_host_board_size() bytes. Also exposes the generated protocol table and
 * pack/unpack functions, so tests can check the generated code against the DBC with cantools.
 */
#include <string.h>

#include "t4d_board.h"
#include "../bluepill/pwm_config.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT size_t t4d_host_board_size(void) { return sizeof(t4d_board_t); }
EXPORT unsigned t4d_host_counter_count(void) { return T4D_COUNTERS; }
EXPORT const char *t4d_host_counter_name(unsigned i) { return i < T4D_COUNTERS ? t4d_counter_names[i] : NULL; }
EXPORT uint16_t t4d_host_pwm_period(void) { return BLUEPILL_PWM_PERIOD; }
EXPORT unsigned t4d_host_max_channels(void) { return T4D_MAX_CHANNELS; }
EXPORT uint32_t t4d_host_counter_window(void) { return T4D_COUNTER_WINDOW; }

EXPORT int t4d_host_init(t4d_board_t *b, uint8_t node_id, uint32_t watchdog_us, uint16_t pwm_period, uint32_t now_us)
{
    return t4d_board_init(b, node_id, watchdog_us, pwm_period, NULL, NULL, now_us);
}

EXPORT void t4d_host_boot(t4d_board_t *b, uint32_t now_us) { t4d_board_boot(b, now_us); }

EXPORT void t4d_host_receive(t4d_board_t *b, uint32_t id, uint8_t flags, uint8_t len, const uint8_t *data,
                             uint32_t now_us)
{
    t4d_frame_t f = {.id = id, .flags = flags, .len = len};
    memcpy(f.data, data, len < sizeof f.data ? len : sizeof f.data);
    t4d_board_receive(b, &f, now_us);
}

/* The same frame to `n` boards (a whole glove on one bus): one call from Python instead of n. */
EXPORT void t4d_host_receive_many(t4d_board_t **boards, size_t n, uint32_t id, uint8_t flags, uint8_t len,
                                  const uint8_t *data, uint32_t now_us)
{
    t4d_frame_t f = {.id = id, .flags = flags, .len = len};
    memcpy(f.data, data, len < sizeof f.data ? len : sizeof f.data);
    for (size_t i = 0; i < n; i++) {
        t4d_board_receive(boards[i], &f, now_us);
    }
}

/* Frames to send now: ids[i], lens[i], data[8 * i ...]; returns how many (<= 3). */
EXPORT size_t t4d_host_tick(t4d_board_t *b, uint32_t now_us, uint32_t *ids, uint8_t *lens, uint8_t *data)
{
    t4d_frame_t out[T4D_TICK_MAX_FRAMES];
    size_t n = t4d_board_tick(b, now_us, out);
    for (size_t i = 0; i < n; i++) {
        ids[i] = out[i].id;
        lens[i] = out[i].len;
        memcpy(&data[8 * i], out[i].data, 8);
    }
    return n;
}

EXPORT uint32_t t4d_host_due_in(const t4d_board_t *b, uint32_t now_us) { return t4d_board_due_in(b, now_us); }
EXPORT void t4d_host_set_hardware_faults(t4d_board_t *b, uint8_t faults) { t4d_board_set_hardware_faults(b, faults); }
EXPORT void t4d_host_all_off(t4d_board_t *b) { t4d_board_all_off(b); }
EXPORT uint8_t t4d_host_output_state(const t4d_board_t *b) { return t4d_board_output_state(b); }
EXPORT uint8_t t4d_host_nmt_state(const t4d_board_t *b) { return b->nmt_state; }
EXPORT int t4d_host_watchdog_tripped(const t4d_board_t *b) { return b->watchdog_tripped; }

/* levels[8], compare[8], counters[T4D_COUNTERS] of a board. */
EXPORT void t4d_host_outputs(const t4d_board_t *b, uint8_t *levels, uint16_t *compare)
{
    memcpy(levels, b->levels, sizeof b->levels);
    memcpy(compare, b->compare, sizeof b->compare);
}

EXPORT void t4d_host_counters(const t4d_board_t *b, uint32_t *counters)
{
    memcpy(counters, b->counters, sizeof b->counters);
}

/* The generated protocol table: boards, and per board its frames (values[10], see below). */
EXPORT size_t t4d_host_board_count(void) { return T4D_BOARD_COUNT; }

EXPORT void t4d_host_board_proto(size_t i, uint32_t *values)
{
    const t4d_board_proto_t *p = &t4d_board_protos[i];
    uint32_t v[] = {p->node_id, p->channels, p->duty_id, p->duty_length, p->duty_full_scale, p->status_id,
                    p->status_length, p->status_cycle_ms, p->heartbeat_id, p->heartbeat_length,
                    p->heartbeat_cycle_ms};
    memcpy(values, v, sizeof v);
}

EXPORT void t4d_host_nmt_codes(uint32_t *values)
{
    uint32_t v[] = {T4D_NMT_FRAME_ID, T4D_NMT_LENGTH, T4D_NMT_START, T4D_NMT_STOP, T4D_NMT_PRE_OPERATIONAL,
                    T4D_NMT_RESET_NODE};
    memcpy(values, v, sizeof v);
}

EXPORT int t4d_host_unpack_duty(size_t i, const uint8_t *data, size_t size, uint8_t *counter, uint8_t *levels)
{
    return t4d_board_protos[i].unpack_duty(data, size, counter, levels);
}

EXPORT int t4d_host_pack_status(size_t i, uint8_t *data, uint8_t state, uint8_t faults, uint8_t last_counter,
                                uint8_t active_mask, uint16_t bad_frames)
{
    t4d_status_t s = {state, faults, last_counter, active_mask, bad_frames};
    return t4d_board_protos[i].pack_status(data, &s);
}

EXPORT int t4d_host_pack_heartbeat(size_t i, uint8_t *data, uint8_t state)
{
    return t4d_board_protos[i].pack_heartbeat(data, state);
}

EXPORT int t4d_host_unpack_nmt(const uint8_t *data, size_t size, uint8_t *command, uint8_t *node)
{
    return t4d_unpack_nmt(data, size, command, node);
}
