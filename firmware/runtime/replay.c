/* Replay harness for the generated controllers (tests and sanitizer runs, not firmware).
 *
 * stdin:  int32 law (0: SISO, 1: clipped LQG), int32 count, then count input structs as raw
 *         bytes of the build's scalar type;
 * stdout: per input, the output struct as raw bytes followed by the uint32 status.
 * Built against one generated folder with the default prefix `smartjoint`. */
#include <stdint.h>
#include <stdio.h>

#include "smartjoint_clqg.h"
#include "smartjoint_siso.h"

/* One law behind one signature, so that a single loop replays either. */
typedef unsigned int (*step_function)(void *state, const void *input, void *output);

static unsigned int siso_step(void *state, const void *input, void *output)
{
    return smartjoint_siso_step(state, input, output);
}

static unsigned int clqg_step(void *state, const void *input, void *output)
{
    return smartjoint_clqg_step(state, input, output);
}

static int replay(int32_t count, step_function step, void *state, void *input, size_t input_size, void *output,
                  size_t output_size)
{
    int32_t k;
    for (k = 0; k < count; ++k) {
        uint32_t status;
        if (fread(input, input_size, 1, stdin) != 1) {
            return 3;
        }
        status = (uint32_t)step(state, input, output);
        if (fwrite(output, output_size, 1, stdout) != 1 || fwrite(&status, sizeof status, 1, stdout) != 1) {
            return 4;
        }
    }
    return 0;
}

int main(void)
{
    int32_t header[2];
    if (fread(header, sizeof header, 1, stdin) != 1 || header[1] < 0) {
        return 2;
    }
    if (header[0] == 0) {
        static smartjoint_siso_state state;
        smartjoint_siso_input input;
        smartjoint_siso_output output;
        smartjoint_siso_init(&state);
        return replay(header[1], siso_step, &state, &input, sizeof input, &output, sizeof output);
    }
    if (header[0] == 1) {
        static smartjoint_clqg_state state;
        smartjoint_clqg_input input;
        smartjoint_clqg_output output;
        smartjoint_clqg_init(&state);
        return replay(header[1], clqg_step, &state, &input, sizeof input, &output, sizeof output);
    }
    return 2;
}
