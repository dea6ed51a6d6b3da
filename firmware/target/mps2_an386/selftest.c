/* Target self-test: the generated controllers (float build) on a fixed input sequence, on the
 * target. The sequence comes from selftest_inputs.h, written by the host runner
 * (bench/target.py) as C99 hexadecimal float literals, so the inputs are exact. Over UART 0 it
 * prints every output word in hex (the host compares them bit for bit with its own float build),
 * the SysTick ticks of each law's step loop and of the same loop around an empty step (the
 * difference is the steps' own time), and the stack depth of each law's loop by painting.
 * A phased law's output phase (the cLQG's) is timed apart: a loop whose step runs the output phase twice before
 * the update phase (the output phase only reads what the last update left, so its second run
 * computes and stores the same again), less the same loop with an empty call in its place.
 * The program returns 0 (semihosting exit status) when it ran to the end. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "smartjoint_can.h"

/* The sequence, and the laws (SJ_LAWS: every law's name; SJ_PHASED_LAWS: those with an output
 * phase; SJ_CAN_LAW: the CAN layer's law here) with their headers, from the law registry. */
#include "selftest_inputs.h"

/* Per law: its state, the outputs and status of every step, the ticks of its loops, the stack. */
#define SJ_LAW_TABLES(law)                                                                                          \
    static smartjoint_##law##_state law##_state;                                                                    \
    static smartjoint_##law##_output law##_outputs[SJ_SELFTEST_STEPS];                                              \
    static unsigned int law##_status[SJ_SELFTEST_STEPS];                                                            \
    static uint32_t law##_ticks, law##_empty_ticks, law##_stack;
SJ_LAWS(SJ_LAW_TABLES)
static smartjoint_can_state can_state;

/* For each law: an empty step of the step's signature, and the timed loop of a step over the
 * sequence from the initial state (<law>_loop returns SysTick ticks). The loop around the empty
 * step is the overhead that is subtracted from the loop around the real one. */
#define SJ_LAW_LOOP(law)                                                                                            \
    typedef unsigned int (*law##_step_fn)(smartjoint_##law##_state *, const smartjoint_##law##_input *,             \
                                          smartjoint_##law##_output *);                                            \
    __attribute__((noinline)) static unsigned int law##_empty(                                                      \
        smartjoint_##law##_state *state, const smartjoint_##law##_input *input, smartjoint_##law##_output *output)  \
    {                                                                                                               \
        __asm__ volatile("" : : "r"(state), "r"(input), "r"(output) : "memory");                                    \
        return 0u;                                                                                                  \
    }                                                                                                               \
    __attribute__((noinline)) static uint32_t law##_loop(law##_step_fn step)                                        \
    {                                                                                                               \
        uint32_t start;                                                                                             \
        int k;                                                                                                      \
        smartjoint_##law##_init(&law##_state, NULL);                                                                      \
        start = sj_ticks();                                                                                         \
        for (k = 0; k < SJ_SELFTEST_STEPS; ++k) {                                                                   \
            law##_status[k] = step(&law##_state, &sj_##law##_inputs[k], &law##_outputs[k]);                         \
        }                                                                                                           \
        return sj_ticks() - start;                                                                                  \
    }
SJ_LAWS(SJ_LAW_LOOP)

/* A phased law's step after a second call: of its output phase (which repeats the step's own
 * exactly), or of the empty step. The loops around the two differ by one output phase less one
 * empty call. */
#define SJ_OUTPUT_PHASE(law)                                                                                        \
    static uint32_t law##_output_ticks;                                                                             \
    __attribute__((noinline)) static unsigned int law##_output_twice(                                               \
        smartjoint_##law##_state *state, const smartjoint_##law##_input *input, smartjoint_##law##_output *output)  \
    {                                                                                                               \
        (void)smartjoint_##law##_output_phase(state, input, output);                                                \
        return smartjoint_##law##_step(state, input, output);                                                       \
    }                                                                                                               \
    __attribute__((noinline)) static unsigned int law##_empty_then_step(                                            \
        smartjoint_##law##_state *state, const smartjoint_##law##_input *input, smartjoint_##law##_output *output)  \
    {                                                                                                               \
        (void)law##_empty(state, input, output);                                                                    \
        return smartjoint_##law##_step(state, input, output);                                                       \
    }
SJ_PHASED_LAWS(SJ_OUTPUT_PHASE)

static void put_words(const void *data, size_t size)
{
    const unsigned char *bytes = (const unsigned char *)data;
    size_t at;
    for (at = 0u; at + 4u <= size; at += 4u) {
        uint32_t word;
        memcpy(&word, bytes + at, 4u);
        sj_uart_putc(' ');
        sj_uart_hex32(word);
    }
}

static void put_figure(const char *name, uint32_t value)
{
    sj_uart_puts(name);
    sj_uart_putc(' ');
    sj_uart_dec(value);
    sj_uart_putc('\n');
}

int main(void)
{
    uintptr_t mark = sj_stack_pointer();
    uint8_t frame[64] = {0u};
    uint32_t frame_id = 0u, can_frames = 0u;
    uint8_t frame_length = 0u;
    uint32_t can_stack, high_water;
    int k;

    sj_ticks_start();
    /* The CAN layer's entry points run once (no valid input yet: it holds the safe state and
     * queues its frames), so the image links what the firmware links; its lock-step run over a
     * transport is processor-in-the-loop's, not this self-test's. */
    sj_stack_paint();
    if (smartjoint_can_init(&can_state, SJ_CAN_LAW) != 0) {
        return 2;
    }
    (void)smartjoint_can_rx(&can_state, 0u, frame, (uint8_t)sizeof frame, 0u);
    (void)smartjoint_can_step(&can_state, 1000u);
    while (smartjoint_can_tx(&can_state, &frame_id, frame, &frame_length) != 0) {
        ++can_frames;
    }
    can_stack = sj_stack_depth(mark);
    /* Each phased law's output phase before the plain step's loop, whose outputs are printed. */
#define SJ_TIME_OUTPUT_PHASE(law) law##_output_ticks = law##_loop(law##_output_twice) - law##_loop(law##_empty_then_step);
    SJ_PHASED_LAWS(SJ_TIME_OUTPUT_PHASE)
#define SJ_TIME_LAW(law)                                                                                            \
    law##_empty_ticks = law##_loop(law##_empty);                                                                    \
    sj_stack_paint();                                                                                               \
    law##_ticks = law##_loop(smartjoint_##law##_step);                                                              \
    law##_stack = sj_stack_depth(mark);
    SJ_LAWS(SJ_TIME_LAW)

    sj_uart_puts("SJ-SELFTEST mps2-an386\n");
    for (k = 0; k < SJ_SELFTEST_STEPS; ++k) {
#define SJ_PUT_STEP(law)                                                                                            \
    sj_uart_puts(#law " ");                                                                                         \
    sj_uart_hex32(law##_status[k]);                                                                                 \
    put_words(&law##_outputs[k], sizeof law##_outputs[k]);                                                          \
    sj_uart_putc('\n');
        SJ_LAWS(SJ_PUT_STEP)
    }
    put_figure("steps", (uint32_t)SJ_SELFTEST_STEPS);
    put_figure("can_frames", can_frames);
    put_figure("instructions_per_tick", SJ_INSTRUCTIONS_PER_TICK);
#define SJ_PUT_TICKS(law)                                                                                           \
    put_figure("ticks_" #law, law##_ticks);                                                                         \
    put_figure("ticks_" #law "_empty", law##_empty_ticks);                                                          \
    put_figure("stack_" #law, law##_stack);
    SJ_LAWS(SJ_PUT_TICKS)
#define SJ_PUT_OUTPUT_PHASE(law) put_figure("ticks_" #law "_output_phase", law##_output_ticks);
    SJ_PHASED_LAWS(SJ_PUT_OUTPUT_PHASE)
    put_figure("stack_can", can_stack);
    /* The whole program: the frames above main (reset handler, main) and the deepest of what ran
     * below it (the CAN entry points, the laws' loops, the printing after the last paint). */
    high_water = sj_stack_depth(mark);
    high_water = high_water > can_stack ? high_water : can_stack;
#define SJ_HIGH_WATER(law) high_water = high_water > law##_stack ? high_water : law##_stack;
    SJ_LAWS(SJ_HIGH_WATER)
    put_figure("stack_high_water", high_water + (uint32_t)(sj_stack_top() - mark));
    put_figure("stack_size", sj_stack_size());
    sj_uart_puts("END\n");
    return 0;
}
