/* The core's self-test and conformance-script runner, built for the host and for the Cortex-M3
 * (run under qemu-system-arm with semihosting, so the same code is checked on the MCU's ISA).
 *
 *   t4d_check            self-test: prints "FAIL ..." lines, and "MEASURE name instructions"
 *                        on the Cortex-M3 (instructions counted by SysTick under `-icount`)
 *   t4d_check SCRIPT     also runs a conformance script written by tests/test_boards_conformance.py
 *                        and prints what every board answered (the format is in run_script)
 *
 * The last line is "END <failures>".
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "t4d_board.h"
#include "../bluepill/pwm_config.h"

static int failures;

#define CHECK(cond, ...)                                     \
    do {                                                     \
        if (!(cond)) {                                       \
            failures++;                                      \
            printf("FAIL %s:%d: ", __FILE__, __LINE__);      \
            printf(__VA_ARGS__);                             \
            printf("\n");                                    \
        }                                                    \
    } while (0)

/* ---- instruction counts (Cortex-M3 under qemu -icount: SysTick advances per instruction) ---- */

#if defined(__arm__)
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

static void ticks_start(void)
{
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 5u; /* enabled, processor clock, no interrupt */
    while (SYST_CVR == 0u) { /* the first reload comes with the first count */
    }
}

static uint32_t ticks(void) { return 0xFFFFFFu - SYST_CVR; } /* counts down */

#define MEASURE(result, stmt)             \
    do {                                  \
        uint32_t t0_ = ticks();           \
        stmt;                             \
        (result) = ticks() - t0_;         \
    } while (0)

static uint32_t ticks_empty, ticks_100;

static void calibrate(void)
{
    ticks_start();
    MEASURE(ticks_empty, (void)0);
    MEASURE(ticks_100, __asm volatile(".rept 100\n nop\n .endr"));
}

/* Instructions between the two SysTick reads of MEASURE, less the reads' own. */
static uint32_t instructions(uint32_t t)
{
    uint32_t per_100 = ticks_100 - ticks_empty;
    return per_100 ? (uint32_t)(((uint64_t)(t - ticks_empty) * 100u + per_100 / 2u) / per_100) : 0u;
}
#endif

/* ---- frames built here with plain shifts: independent of the generated code under test ---- */

static t4d_frame_t duty_frame(const t4d_board_proto_t *p, uint8_t counter, const uint8_t *levels)
{
    t4d_frame_t f = {.id = p->duty_id, .len = p->duty_length};
    uint64_t bits = counter;
    for (unsigned c = 0; c < p->channels; c++) {
        bits |= (uint64_t)(levels[c] & 0x7Fu) << (8u + 7u * c);
    }
    for (unsigned i = 0; i < 8u; i++) {
        f.data[i] = (uint8_t)(bits >> (8u * i));
    }
    return f;
}

static t4d_frame_t nmt_frame(uint8_t command, uint8_t node)
{
    t4d_frame_t f = {.id = T4D_NMT_FRAME_ID, .len = 2, .data = {command, node}};
    return f;
}

static uint16_t hook_compare[T4D_MAX_CHANNELS];
static unsigned hook_calls;

static void hook(void *ctx, const uint16_t compare[T4D_MAX_CHANNELS])
{
    (void)ctx;
    memcpy(hook_compare, compare, sizeof hook_compare);
    hook_calls++;
}

static void test_duty_compare(void)
{
    const uint16_t periods[] = {BLUEPILL_PWM_PERIOD, 1000u, 255u, 65535u};
    for (size_t i = 0; i < sizeof periods / sizeof periods[0]; i++) {
        uint16_t period = periods[i], previous = 0;
        CHECK(t4d_duty_compare(0, 127, period) == 0u, "level 0 is off");
        CHECK(t4d_duty_compare(127, 127, period) == period, "full scale is always on");
        CHECK(t4d_duty_compare(200, 127, period) == period, "over full scale clamps");
        for (unsigned level = 0; level <= 127u; level++) {
            uint16_t c = t4d_duty_compare((uint8_t)level, 127, period);
            int64_t err = (int64_t)c * 127 - (int64_t)level * period; /* 127 x rounding error */
            CHECK(err >= -63 && err <= 63, "level %u period %u -> %u is not the nearest", level, period, c);
            CHECK(c >= previous, "compare decreases at level %u", level);
            previous = c;
        }
    }
}

static void test_unknown_node_stays_off_and_silent(void)
{
    t4d_board_t b;
    t4d_frame_t out[T4D_TICK_MAX_FRAMES];
    hook_calls = 0;
    CHECK(t4d_board_init(&b, 0, 100000u, 100u, hook, NULL, 0u) == -1, "node 0 is no board");
    CHECK(hook_calls == 1u && hook_compare[0] == 0u, "init writes every output off");
    t4d_frame_t start = nmt_frame(T4D_NMT_START, 0);
    t4d_board_receive(&b, &start, 10u);
    CHECK(t4d_board_tick(&b, 1000000u, out) == 0u, "an unknown node sends nothing");
}

/* Every board of the table: the duty frame lands on its channels and in the output hook. */
static void test_every_board_applies_its_own_duty_frame(void)
{
    for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
        const t4d_board_proto_t *p = &t4d_board_protos[i];
        t4d_board_t b;
        uint8_t levels[T4D_MAX_CHANNELS];
        CHECK(t4d_board_init(&b, p->node_id, 100000u, BLUEPILL_PWM_PERIOD, hook, NULL, 0u) == 0, "init %u", p->node_id);
        t4d_frame_t start = nmt_frame(T4D_NMT_START, p->node_id);
        t4d_board_receive(&b, &start, 0u);
        for (unsigned c = 0; c < T4D_MAX_CHANNELS; c++) {
            levels[c] = (uint8_t)(1u + 15u * c + p->node_id);
        }
        t4d_frame_t f = duty_frame(p, 9, levels);
        t4d_board_receive(&b, &f, 1000u);
        for (unsigned c = 0; c < p->channels; c++) {
            uint32_t want = ((uint32_t)levels[c] * BLUEPILL_PWM_PERIOD + 63u) / 127u;
            CHECK(b.levels[c] == levels[c] && hook_compare[c] == want, "board %u channel %u: level %u compare %u",
                  p->node_id, c, b.levels[c], hook_compare[c]);
        }
    }
}

/* The microsecond clock wraps every 71.6 minutes: the watchdog must not care. */
static void test_watchdog_across_the_clock_wrap(void)
{
    const t4d_board_proto_t *p = &t4d_board_protos[0];
    t4d_board_t b;
    t4d_frame_t out[T4D_TICK_MAX_FRAMES];
    uint8_t levels[T4D_MAX_CHANNELS] = {100, 100, 100, 100, 100, 100, 100, 100};
    uint32_t t0 = UINT32_MAX - 50000u;
    t4d_board_init(&b, p->node_id, 100000u, BLUEPILL_PWM_PERIOD, NULL, NULL, t0);
    t4d_frame_t start = nmt_frame(T4D_NMT_START, 0), f = duty_frame(p, 1, levels);
    t4d_board_receive(&b, &start, t0);
    t4d_board_receive(&b, &f, t0);
    t4d_board_tick(&b, t0 + 99000u, out);
    CHECK(b.levels[0] == 100u && t4d_board_output_state(&b) == T4D_OUTPUT_ACTIVE, "on 99 ms after, across the wrap");
    t4d_board_tick(&b, t0 + 101000u, out);
    CHECK(b.levels[0] == 0u && t4d_board_output_state(&b) == T4D_OUTPUT_WATCHDOG_OFF, "off 101 ms after, across the wrap");
}

#if defined(__arm__)
/* Instruction counts of the paths between a duty frame's arrival and the compare registers. */
static void measure(void)
{
    const t4d_board_proto_t *p = &t4d_board_protos[T4D_BOARD_COUNT - 1u];
    t4d_board_t b;
    t4d_frame_t out[T4D_TICK_MAX_FRAMES];
    uint8_t levels[T4D_MAX_CHANNELS] = {127, 126, 125, 124, 123, 122, 121, 120};
    uint32_t n;
    calibrate();
    printf("MEASURE calibration_ticks_per_100 %" PRIu32 "\n", ticks_100 - ticks_empty);
    t4d_board_init(&b, p->node_id, 100000u, BLUEPILL_PWM_PERIOD, hook, NULL, 0u);
    t4d_frame_t start = nmt_frame(T4D_NMT_START, 0);
    t4d_board_receive(&b, &start, 0u);
    t4d_frame_t f = duty_frame(p, 1, levels);
    MEASURE(n, t4d_board_receive(&b, &f, 10u));
    CHECK(hook_compare[0] == BLUEPILL_PWM_PERIOD, "the measured frame was applied");
    printf("MEASURE receive_duty_all_channels_change %" PRIu32 "\n", instructions(n));
    uint8_t counter, unpacked[T4D_MAX_CHANNELS];
    MEASURE(n, (void)p->unpack_duty(f.data, f.len, &counter, unpacked));
    printf("MEASURE baseline_generated_unpack %" PRIu32 "\n", instructions(n));
    t4d_frame_t unknown = {.id = 0x7FFu, .len = 8};
    MEASURE(n, t4d_board_receive(&b, &unknown, 20u));
    printf("MEASURE receive_unknown_id %" PRIu32 "\n", instructions(n));
    t4d_frame_t other = {.id = p->heartbeat_id, .len = 1}; /* its own heartbeat id: the last one scanned */
    MEASURE(n, t4d_board_receive(&b, &other, 25u));
    printf("MEASURE receive_other_board_frame %" PRIu32 "\n", instructions(n));
    t4d_board_boot(&b, 0u); /* tick with a boot-up heartbeat, a status and a heartbeat due */
    b.next_heartbeat_us = 0u;
    size_t sent;
    MEASURE(n, sent = t4d_board_tick(&b, 30u, out));
    CHECK(sent == 3u, "the worst tick sends three frames (%u)", (unsigned)sent);
    printf("MEASURE tick_three_frames %" PRIu32 "\n", instructions(n));
    MEASURE(n, sent = t4d_board_tick(&b, 40u, out));
    printf("MEASURE tick_idle %" PRIu32 "\n", instructions(n));
}
#endif

/* ---- conformance scripts: one command a line, times in microseconds ----
 *   W us                      communication watchdog for the next boot
 *   B t                       boot every board of the glove (a fresh scenario: counters zero) -> "B"
 *   F t id flags len hexdata  a frame from the bus to every board
 *   T t                       tick every board -> "T id:hexdata ..." (frames in board order)
 *   H node mask               hardware faults of one board
 *   P node                    -> "P node nmt output levels compares counters" (comma lists)
 */
static t4d_board_t glove[T4D_BOARD_COUNT];

static t4d_board_t *board_of(unsigned node)
{
    for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
        if (t4d_board_protos[i].node_id == node) {
            return &glove[i];
        }
    }
    return NULL;
}

static void print_list8(const char *sep, const uint8_t *v, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        printf("%s%u", i ? "," : sep, v[i]);
    }
}

static int run_script(const char *path)
{
    FILE *in = fopen(path, "r");
    if (in == NULL) {
        printf("FAIL cannot open %s\n", path);
        return 1;
    }
    char line[160];
    uint32_t watchdog_us = 100000u;
    while (fgets(line, sizeof line, in) != NULL) {
        char *s = line + 1;
        unsigned long a = strtoul(s, &s, 0);
        switch (line[0]) {
        case 'W':
            watchdog_us = (uint32_t)a;
            break;
        case 'B':
            printf("B\n");
            for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
                t4d_board_init(&glove[i], t4d_board_protos[i].node_id, watchdog_us, BLUEPILL_PWM_PERIOD, NULL, NULL,
                               (uint32_t)a);
            }
            break;
        case 'F': {
            t4d_frame_t f = {0};
            f.id = (uint32_t)strtoul(s, &s, 16);
            f.flags = (uint8_t)strtoul(s, &s, 10);
            f.len = (uint8_t)strtoul(s, &s, 10);
            while (*s == ' ') {
                s++;
            }
            for (unsigned i = 0; i < f.len && i < 8u && s[0] && s[1] && s[0] != '\n'; i++, s += 2) {
                char hex[3] = {s[0], s[1], 0};
                f.data[i] = (uint8_t)strtoul(hex, NULL, 16);
            }
            for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
                t4d_board_receive(&glove[i], &f, (uint32_t)a);
            }
            break;
        }
        case 'T':
            printf("T");
            for (size_t i = 0; i < T4D_BOARD_COUNT; i++) {
                t4d_frame_t out[T4D_TICK_MAX_FRAMES];
                size_t n = t4d_board_tick(&glove[i], (uint32_t)a, out);
                for (size_t k = 0; k < n; k++) {
                    printf(" %" PRIx32 ":", out[k].id);
                    for (unsigned j = 0; j < out[k].len; j++) {
                        printf("%02x", out[k].data[j]);
                    }
                }
            }
            printf("\n");
            break;
        case 'H': {
            t4d_board_t *b = board_of((unsigned)a);
            if (b != NULL) {
                t4d_board_set_hardware_faults(b, (uint8_t)strtoul(s, NULL, 0));
            }
            break;
        }
        case 'P': {
            t4d_board_t *b = board_of((unsigned)a);
            if (b == NULL) {
                printf("FAIL no board %lu\n", a);
                failures++;
                break;
            }
            printf("P %lu %u %u", a, b->nmt_state, t4d_board_output_state(b));
            print_list8(" ", b->levels, T4D_MAX_CHANNELS);
            for (size_t i = 0; i < T4D_MAX_CHANNELS; i++) {
                printf("%s%u", i ? "," : " ", b->compare[i]);
            }
            for (size_t i = 0; i < T4D_COUNTERS; i++) {
                printf("%s%" PRIu32, i ? "," : " ", b->counters[i]);
            }
            printf("\n");
            break;
        }
        default:
            break;
        }
    }
    fclose(in);
    return 0;
}

int main(int argc, char **argv)
{
    test_duty_compare();
    test_unknown_node_stays_off_and_silent();
    test_every_board_applies_its_own_duty_frame();
    test_watchdog_across_the_clock_wrap();
#if defined(__arm__)
    measure();
#endif
    if (argc > 1) {
        failures += run_script(argv[1]);
    }
    printf("END %d\n", failures);
    return failures != 0;
}
