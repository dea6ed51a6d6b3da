/* Fuzz harness 4: the generated controller steps (SISO and clipped LQG) with arbitrary bit
 * patterns as inputs; built once per scalar type (float: firmware/generated, double: the double
 * build of the same artefact).
 *
 * Input: the law, then one input struct per step, every scalar an arbitrary bit pattern (NaN,
 * infinities, denormals and huge values included); a control byte per step may restart the
 * controller. The contract, as smartjoint_types.h and the headers state it:
 * - every output normal force, on every step, is a number within [F^min, F^max] of its joint;
 * - the status holds only the documented bits; INPUT_INVALID is set exactly when an input is
 *   NaN or infinite (SISO: then that joint is at F^min exactly);
 * - clipped LQG: a non-zero status (invalid input, or ESTIMATE_RESET when the estimate left the
 *   finite numbers) puts every joint at F^min with u_d = 0; a zero status gives finite u_d.
 * UBSan and ASan abort on any undefined behaviour or out-of-bounds access in the step. */
#include <math.h>
#include <stdint.h>

#include "fuzz_reference.h"
#include "smartjoint_clqg.h"
#include "smartjoint_siso.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define MAX_STEPS 4096

/* The bus table and the controllers come from the same artefact. */
typedef char joints_agree[(FUZZ_JOINTS == SMARTJOINT_SISO_JOINTS && FUZZ_JOINTS == SMARTJOINT_CLQG_JOINTS) ? 1 : -1];

#ifdef FUZZ_REAL_DOUBLE
#define take_real fuzz_take_double
#define BUILD "double"
#else
#define take_real fuzz_take_float
#define BUILD "float"
#endif

static smartjoint_real lowest(unsigned int joint)
{
    return (smartjoint_real)fuzz_normal_force_min[joint];
}

static smartjoint_real highest(unsigned int joint)
{
    return (smartjoint_real)fuzz_normal_force_max[joint];
}

static void check_bounds(const char *law, const smartjoint_real *normal_force, int step)
{
    unsigned int j;
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        if (!(normal_force[j] >= lowest(j) && normal_force[j] <= highest(j))) {
            fuzz_fail("controllers_" BUILD, "%s step %d: F_N of joint %u is %.9g, outside [%.9g, %.9g]", law, step, j,
                      (double)normal_force[j], (double)lowest(j), (double)highest(j));
        }
    }
}

static void fuzz_siso(fuzz_reader *reader)
{
    smartjoint_siso_state state;
    int step;
    smartjoint_siso_init(&state);
    for (step = 0; step < MAX_STEPS && fuzz_more(reader); ++step) {
        smartjoint_siso_input input;
        smartjoint_siso_output output;
        unsigned int status, j, invalid = 0u;
        if (fuzz_take_u8(reader) == 0xFFu) {
            smartjoint_siso_init(&state);
        }
        for (j = 0u; j < FUZZ_JOINTS; ++j) {
            input.sliding_velocity[j] = take_real(reader);
            input.friction_force[j] = take_real(reader);
            input.normal_force[j] = take_real(reader);
        }
        status = smartjoint_siso_step(&state, &input, &output);
        if (status & ~SMARTJOINT_STATUS_INPUT_INVALID) {
            fuzz_fail("controllers_" BUILD, "siso step %d: undocumented status bits 0x%x", step, status);
        }
        check_bounds("siso", output.normal_force, step);
        for (j = 0u; j < FUZZ_JOINTS; ++j) {
            const int finite = isfinite(input.sliding_velocity[j]) && isfinite(input.friction_force[j]) &&
                               isfinite(input.normal_force[j]);
            if (!finite) {
                invalid = 1u;
                if (output.normal_force[j] != lowest(j)) {
                    fuzz_fail("controllers_" BUILD, "siso step %d: joint %u with a non-finite input is at %.9g, not F^min",
                              step, j, (double)output.normal_force[j]);
                }
            }
        }
        if ((status != 0u) != (invalid != 0u)) {
            fuzz_fail("controllers_" BUILD, "siso step %d: status 0x%x for %s inputs", step, status,
                      invalid ? "non-finite" : "finite");
        }
    }
}

static void fuzz_clqg(fuzz_reader *reader)
{
    smartjoint_clqg_state state;
    int step;
    smartjoint_clqg_init(&state);
    for (step = 0; step < MAX_STEPS && fuzz_more(reader); ++step) {
        smartjoint_clqg_input input;
        smartjoint_clqg_output output;
        unsigned int status, j, r;
        int invalid = 0;
        if (fuzz_take_u8(reader) == 0xFFu) {
            smartjoint_clqg_init(&state);
        }
        for (r = 0u; r < SMARTJOINT_CLQG_SENSORS; ++r) {
            input.sensors[r] = take_real(reader);
            invalid |= !isfinite(input.sensors[r]);
        }
        for (j = 0u; j < FUZZ_JOINTS; ++j) {
            input.friction_force[j] = take_real(reader);
            input.normal_force[j] = take_real(reader);
            invalid |= !isfinite(input.friction_force[j]) || !isfinite(input.normal_force[j]);
        }
        status = smartjoint_clqg_step(&state, &input, &output);
        if (status & ~(SMARTJOINT_STATUS_INPUT_INVALID | SMARTJOINT_STATUS_ESTIMATE_RESET)) {
            fuzz_fail("controllers_" BUILD, "clqg step %d: undocumented status bits 0x%x", step, status);
        }
        check_bounds("clqg", output.normal_force, step);
        if (((status & SMARTJOINT_STATUS_INPUT_INVALID) != 0u) != (invalid != 0)) {
            fuzz_fail("controllers_" BUILD, "clqg step %d: status 0x%x for %s inputs", step, status,
                      invalid ? "non-finite" : "finite");
        }
        for (j = 0u; j < FUZZ_JOINTS; ++j) {
            if (status != 0u && (output.normal_force[j] != lowest(j) || output.desired_force[j] != 0)) {
                fuzz_fail("controllers_" BUILD, "clqg step %d: status 0x%x but joint %u at %.9g N, u_d %.9g", step,
                          status, j, (double)output.normal_force[j], (double)output.desired_force[j]);
            }
            if (status == 0u && !isfinite(output.desired_force[j])) {
                fuzz_fail("controllers_" BUILD, "clqg step %d: status 0 with a non-finite u_d of joint %u", step, j);
            }
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    fuzz_reader_init(&reader, data, size);
    if (fuzz_take_u8(&reader) & 1u) {
        fuzz_clqg(&reader);
    } else {
        fuzz_siso(&reader);
    }
    return 0;
}
