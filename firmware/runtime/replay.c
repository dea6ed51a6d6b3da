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

static int replay_siso(int32_t count)
{
    static smartjoint_siso_state state;
    smartjoint_siso_input input;
    smartjoint_siso_output output;
    int32_t k;
    smartjoint_siso_init(&state);
    for (k = 0; k < count; ++k) {
        uint32_t status;
        if (fread(&input, sizeof input, 1, stdin) != 1) {
            return 3;
        }
        status = (uint32_t)smartjoint_siso_step(&state, &input, &output);
        if (fwrite(&output, sizeof output, 1, stdout) != 1 || fwrite(&status, sizeof status, 1, stdout) != 1) {
            return 4;
        }
    }
    return 0;
}

static int replay_clqg(int32_t count)
{
    static smartjoint_clqg_state state;
    smartjoint_clqg_input input;
    smartjoint_clqg_output output;
    int32_t k;
    smartjoint_clqg_init(&state);
    for (k = 0; k < count; ++k) {
        uint32_t status;
        if (fread(&input, sizeof input, 1, stdin) != 1) {
            return 3;
        }
        status = (uint32_t)smartjoint_clqg_step(&state, &input, &output);
        if (fwrite(&output, sizeof output, 1, stdout) != 1 || fwrite(&status, sizeof status, 1, stdout) != 1) {
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
        return replay_siso(header[1]);
    }
    if (header[0] == 1) {
        return replay_clqg(header[1]);
    }
    return 2;
}
