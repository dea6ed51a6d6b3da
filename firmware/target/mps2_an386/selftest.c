/* Target self-test: the generated controllers (float build) on a fixed input sequence, on the
 * target. The sequence comes from selftest_inputs.h, written by the host runner
 * (bench/target.py) as C99 hexadecimal float literals, so the inputs are exact. Over UART 0 it
 * prints every output word in hex (the host compares them bit for bit with its own float build),
 * the SysTick ticks of each law's step loop and of the same loop around an empty step (the
 * difference is the steps' own time), and the stack depth of each law's loop by painting.
 * The cLQG's output phase is timed apart: a loop whose step runs the output phase twice before
 * the update phase (the output phase only reads what the last update left, so its second run
 * computes and stores the same again), less the same loop with an empty call in its place.
 * The program returns 0 (semihosting exit status) when it ran to the end. */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "smartjoint_can.h"
#include "smartjoint_clqg.h"
#include "smartjoint_siso.h"

#include "selftest_inputs.h"

static smartjoint_clqg_state clqg_state;
static smartjoint_siso_state siso_state;
static smartjoint_can_state can_state;
static smartjoint_clqg_output clqg_outputs[SJ_SELFTEST_STEPS];
static smartjoint_siso_output siso_outputs[SJ_SELFTEST_STEPS];
static unsigned int clqg_status[SJ_SELFTEST_STEPS];
static unsigned int siso_status[SJ_SELFTEST_STEPS];

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
        smartjoint_##law##_init(&law##_state);                                                                      \
        start = sj_ticks();                                                                                         \
        for (k = 0; k < SJ_SELFTEST_STEPS; ++k) {                                                                   \
            law##_status[k] = step(&law##_state, &sj_##law##_inputs[k], &law##_outputs[k]);                         \
        }                                                                                                           \
        return sj_ticks() - start;                                                                                  \
    }

SJ_LAW_LOOP(clqg)
SJ_LAW_LOOP(siso)

/* The cLQG step after a second call: of its output phase (which repeats the step's own exactly),
 * or of the empty step. The loops around the two differ by one output phase less one empty call. */
__attribute__((noinline)) static unsigned int clqg_output_twice(smartjoint_clqg_state *state,
                                                                const smartjoint_clqg_input *input,
                                                                smartjoint_clqg_output *output)
{
    (void)smartjoint_clqg_output_phase(state, input, output);
    return smartjoint_clqg_step(state, input, output);
}

__attribute__((noinline)) static unsigned int clqg_empty_then_step(smartjoint_clqg_state *state,
                                                                   const smartjoint_clqg_input *input,
                                                                   smartjoint_clqg_output *output)
{
    (void)clqg_empty(state, input, output);
    return smartjoint_clqg_step(state, input, output);
}

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
    uint32_t clqg_ticks, clqg_empty_ticks, clqg_output_ticks, siso_ticks, siso_empty_ticks, clqg_stack, siso_stack, can_stack, high_water;
    int k;

    sj_ticks_start();
    /* The CAN layer's entry points run once (no valid input yet: it holds the safe state and
     * queues its frames), so the image links what the firmware links; its lock-step run over a
     * transport is processor-in-the-loop's, not this self-test's. */
    sj_stack_paint();
    if (smartjoint_can_init(&can_state, SMARTJOINT_CAN_LAW_CLQG) != 0) {
        return 2;
    }
    (void)smartjoint_can_rx(&can_state, 0u, frame, (uint8_t)sizeof frame, 0u);
    (void)smartjoint_can_step(&can_state, 1000u);
    while (smartjoint_can_tx(&can_state, &frame_id, frame, &frame_length) != 0) {
        ++can_frames;
    }
    can_stack = sj_stack_depth(mark);
    clqg_empty_ticks = clqg_loop(clqg_empty);
    /* Before the plain step's loop, whose outputs are printed. */
    clqg_output_ticks = clqg_loop(clqg_output_twice) - clqg_loop(clqg_empty_then_step);
    sj_stack_paint();
    clqg_ticks = clqg_loop(smartjoint_clqg_step);
    clqg_stack = sj_stack_depth(mark);
    siso_empty_ticks = siso_loop(siso_empty);
    sj_stack_paint();
    siso_ticks = siso_loop(smartjoint_siso_step);
    siso_stack = sj_stack_depth(mark);

    sj_uart_puts("SJ-SELFTEST mps2-an386\n");
    for (k = 0; k < SJ_SELFTEST_STEPS; ++k) {
        sj_uart_puts("clqg ");
        sj_uart_hex32(clqg_status[k]);
        put_words(&clqg_outputs[k], sizeof clqg_outputs[k]);
        sj_uart_puts("\nsiso ");
        sj_uart_hex32(siso_status[k]);
        put_words(&siso_outputs[k], sizeof siso_outputs[k]);
        sj_uart_putc('\n');
    }
    put_figure("steps", (uint32_t)SJ_SELFTEST_STEPS);
    put_figure("can_frames", can_frames);
    put_figure("instructions_per_tick", SJ_INSTRUCTIONS_PER_TICK);
    put_figure("ticks_clqg", clqg_ticks);
    put_figure("ticks_clqg_empty", clqg_empty_ticks);
    put_figure("ticks_clqg_output_phase", clqg_output_ticks);
    put_figure("ticks_siso", siso_ticks);
    put_figure("ticks_siso_empty", siso_empty_ticks);
    put_figure("stack_clqg", clqg_stack);
    put_figure("stack_siso", siso_stack);
    put_figure("stack_can", can_stack);
    /* The whole program: the frames above main (reset handler, main) and the deepest of what ran
     * below it (the CAN entry points, the two loops, the printing after the last paint). */
    high_water = sj_stack_depth(mark);
    high_water = high_water > can_stack ? high_water : can_stack;
    high_water = high_water > clqg_stack ? high_water : clqg_stack;
    high_water = high_water > siso_stack ? high_water : siso_stack;
    put_figure("stack_high_water", high_water + (uint32_t)(sj_stack_top() - mark));
    put_figure("stack_size", sj_stack_size());
    sj_uart_puts("END\n");
    return 0;
}
