/* Fuzz harness 4: the generated controller steps (SISO and clipped LQG) with arbitrary bit
 * patterns as inputs; built once per scalar type (float: firmware/generated, double: the double
 * build of the same artefact).
 *
 * Input: the law, then one input struct per step, every scalar an arbitrary bit pattern (NaN,
 * infinities, denormals and huge values included); a control byte per step may restart the
 * controller. The contract, as smartjoint_types.h and the headers state it, with the safe force
 * and the plausible ranges taken from the artefact (fuzz_reference.c), not from the C:
 * - the status holds only the documented bits; INPUT_INVALID is set exactly when an input is
 *   NaN or infinite, INPUT_IMPLAUSIBLE exactly when a finite input lies outside its range
 *   (|v|, |u_R|, |y| up to their limits, the measured F_N within its range, limits included);
 * - either bit (and, for the clipped LQG, ESTIMATE_RESET) puts EVERY joint at the safe normal
 *   force exactly, with u_d = 0 for the clipped LQG;
 * - otherwise every output normal force is a number within [F^min, F^max] of its joint, and the
 *   clipped LQG's u_d is finite.
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
typedef char sensors_agree[(FUZZ_SENSORS == SMARTJOINT_CLQG_SENSORS) ? 1 : -1];

#ifdef FUZZ_REAL_DOUBLE
#define take_real fuzz_take_double
#define BUILD "double"
#else
#define take_real fuzz_take_float
#define BUILD "float"
#endif

/* Every limit in the build's type, as the generated tables hold it: a float input is compared
 * with the float the literal of the limit parses to. */
static smartjoint_real in_build(double value)
{
    return (smartjoint_real)value;
}

/* The reference classification of one input: INPUT_INVALID for NaN/Inf, INPUT_IMPLAUSIBLE for
 * a finite value outside [low, high], else 0. */
static unsigned int classify(smartjoint_real value, double low, double high)
{
    if (!isfinite(value)) {
        return SMARTJOINT_STATUS_INPUT_INVALID;
    }
    return (value >= in_build(low) && value <= in_build(high)) ? 0u : SMARTJOINT_STATUS_INPUT_IMPLAUSIBLE;
}

static void check_bounds(const char *law, const smartjoint_real *normal_force, int step)
{
    unsigned int j;
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        if (!(normal_force[j] >= in_build(fuzz_normal_force_min[j]) &&
              normal_force[j] <= in_build(fuzz_normal_force_max[j]))) {
            fuzz_fail("controllers_" BUILD, "%s step %d: F_N of joint %u is %.9g, outside [%.9g, %.9g]", law, step, j,
                      (double)normal_force[j], fuzz_normal_force_min[j], fuzz_normal_force_max[j]);
        }
    }
}

static void check_safe(const char *law, const smartjoint_real *normal_force, unsigned int status, int step)
{
    unsigned int j;
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        if (normal_force[j] != in_build(fuzz_safe_normal_force[j])) {
            fuzz_fail("controllers_" BUILD, "%s step %d: status 0x%x but joint %u at %.9g N, not the safe %.9g N", law,
                      step, status, j, (double)normal_force[j], fuzz_safe_normal_force[j]);
        }
    }
}

/* The status a step returned against the one its inputs call for, then the force bounds and, on
 * any fault, the safe force. Usable inputs may still drive the cLQG estimate beyond its bound (the
 * update phase's test, reported by the next step): ESTIMATE_RESET is then allowed, with the bits of
 * every input of the failing step (`failing`) besides. */
static void check_step(const char *law, unsigned int status, unsigned int expected, unsigned int failing,
                       int may_reset, const smartjoint_real *normal_force, int step)
{
    const int reset = may_reset && (status & SMARTJOINT_STATUS_ESTIMATE_RESET) != 0u &&
                      (status & ~SMARTJOINT_STATUS_ESTIMATE_RESET) == (failing & ~SMARTJOINT_STATUS_ESTIMATE_RESET);
    if (status != expected && !reset) {
        fuzz_fail("controllers_" BUILD, "%s step %d: status 0x%x, the inputs give 0x%x", law, step, status, expected);
    }
    check_bounds(law, normal_force, step);
    if (status != 0u) {
        check_safe(law, normal_force, status, step);
    }
}

/* The friction force and the measured normal force of joint j, which both laws read: taken from
 * the fuzz input in that order, and the reference classification of the friction force; the
 * measured normal force's goes to *normal_status. */
static unsigned int take_joint_forces(fuzz_reader *reader, smartjoint_real *friction_force,
                                      smartjoint_real *normal_force, unsigned int j, unsigned int *normal_status)
{
    *friction_force = take_real(reader);
    *normal_force = take_real(reader);
    *normal_status |= classify(*normal_force, fuzz_measured_normal_force_min[j], fuzz_measured_normal_force_max[j]);
    return classify(*friction_force, -fuzz_friction_force_limit[j], fuzz_friction_force_limit[j]);
}

/* One SISO step (after a restart, if asked) on inputs taken from the fuzz input, checked. */
static void fuzz_siso_step(smartjoint_siso_state *state, int restart, fuzz_reader *reader, int step)
{
    smartjoint_siso_input input;
    smartjoint_siso_output output;
    unsigned int status, j, expected = 0u, normal = 0u;
    if (restart) {
        smartjoint_siso_init(state, NULL);
    }
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        input.sliding_velocity[j] = take_real(reader);
        expected |= classify(input.sliding_velocity[j], -fuzz_sliding_velocity_limit[j],
                             fuzz_sliding_velocity_limit[j]);
        expected |= take_joint_forces(reader, &input.friction_force[j], &input.normal_force[j], j, &normal);
    }
    expected |= normal; /* the SISO law checks every input at once */
    status = smartjoint_siso_step(state, &input, &output);
    check_step("siso", status, expected, expected, 0, output.normal_force, step);
}

/* One clipped-LQG step (after a restart, if asked) on inputs taken from the fuzz input, checked,
 * u_d included. The cLQG checks each input where it uses it: the sensors and friction forces at
 * once; the measured normal forces in the update phase, whose fault (*carried, from the step
 * before) is this step's status, with every input's bits, since the step then fails. */
static void fuzz_clqg_step(smartjoint_clqg_state *state, int restart, fuzz_reader *reader, int step,
                           unsigned int *carried)
{
    smartjoint_clqg_input input;
    smartjoint_clqg_output output;
    unsigned int status, j, r, used = 0u, normal = 0u, expected;
    if (restart) {
        smartjoint_clqg_init(state, NULL);
        *carried = 0u;
    }
    for (r = 0u; r < FUZZ_SENSORS; ++r) {
        input.sensors[r] = take_real(reader);
        used |= classify(input.sensors[r], -fuzz_sensor_limit[r], fuzz_sensor_limit[r]);
    }
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        used |= take_joint_forces(reader, &input.friction_force[j], &input.normal_force[j], j, &normal);
    }
    expected = (*carried != 0u || used != 0u) ? (*carried | used | normal) : 0u;
    status = smartjoint_clqg_step(state, &input, &output);
    check_step("clqg", status, expected, *carried | used | normal, 1, output.normal_force, step);
    *carried = status == 0u ? normal : 0u; /* only a successful step's update phase ran */
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        if (status != 0u && output.desired_force[j] != 0) {
            fuzz_fail("controllers_" BUILD, "clqg step %d: status 0x%x but u_d of joint %u is %.9g", step, status, j,
                      (double)output.desired_force[j]);
        }
        if (status == 0u && !isfinite(output.desired_force[j])) {
            fuzz_fail("controllers_" BUILD, "clqg step %d: status 0 with a non-finite u_d of joint %u", step, j);
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    smartjoint_siso_state siso;
    smartjoint_clqg_state clqg;
    unsigned int use_clqg, carried = 0u;
    int step;
    fuzz_reader_init(&reader, data, size);
    use_clqg = fuzz_take_u8(&reader) & 1u;
    for (step = 0; step < MAX_STEPS && fuzz_more(&reader); ++step) {
        /* The control byte is read at every step: 0xFF restarts the controller, started at step 0. */
        const int restart = fuzz_take_u8(&reader) == 0xFFu || step == 0;
        if (use_clqg) {
            fuzz_clqg_step(&clqg, restart, &reader, step, &carried);
        } else {
            fuzz_siso_step(&siso, restart, &reader, step);
        }
    }
    return 0;
}
