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

/* One law behind one set of signatures, so that a single loop replays either. */
typedef unsigned int (*step_function)(void *state, const void *input, void *output);

struct law {
    void (*init)(void *state);
    step_function step;
    void *state;
    size_t input_size;
    size_t output_size;
};

static void siso_init(void *state)
{
    smartjoint_siso_init(state, NULL);
}

static void clqg_init(void *state)
{
    smartjoint_clqg_init(state, NULL);
}

static unsigned int siso_step(void *state, const void *input, void *output)
{
    return smartjoint_siso_step(state, input, output);
}

static unsigned int clqg_step(void *state, const void *input, void *output)
{
    return smartjoint_clqg_step(state, input, output);
}

static int replay(int32_t count, const struct law *law)
{
    /* Room for either law's structs; each law reads and writes only its own size. */
    union {
        smartjoint_siso_input siso;
        smartjoint_clqg_input clqg;
    } input;
    union {
        smartjoint_siso_output siso;
        smartjoint_clqg_output clqg;
    } output;
    int32_t k;
    law->init(law->state);
    for (k = 0; k < count; ++k) {
        uint32_t status;
        if (fread(&input, law->input_size, 1, stdin) != 1) {
            return 3;
        }
        status = (uint32_t)law->step(law->state, &input, &output);
        if (fwrite(&output, law->output_size, 1, stdout) != 1 || fwrite(&status, sizeof status, 1, stdout) != 1) {
            return 4;
        }
    }
    return 0;
}

int main(void)
{
    static smartjoint_siso_state siso_state;
    static smartjoint_clqg_state clqg_state;
    /* Indexed by the law number of the header. */
    static const struct law laws[2] = {
        {siso_init, siso_step, &siso_state, sizeof(smartjoint_siso_input), sizeof(smartjoint_siso_output)},
        {clqg_init, clqg_step, &clqg_state, sizeof(smartjoint_clqg_input), sizeof(smartjoint_clqg_output)},
    };
    int32_t header[2];
    if (fread(header, sizeof header, 1, stdin) != 1 || header[1] < 0 || header[0] < 0 || header[0] > 1) {
        return 2;
    }
    return replay(header[1], &laws[header[0]]);
}
