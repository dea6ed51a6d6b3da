/* Fuzz harness 2: the whole CAN layer of firmware/generated — receive, controller step, transmit.
 *
 * Input: the law, a start time, then a sequence of events: a received frame (identifier — mostly
 * one the controller listens to —, length, payload, optionally given a valid E2E CRC and
 * counter and the heartbeat echo of a healthy node so the fuzzer gets past the checks, and the
 * time since the last event), 1..8 steps each followed by draining the transmit queue, a healthy bus
 * cycle (every input frame with any payload, valid E2E, the right echo) followed by a step, or
 * a replay: the frame an input's node sent `age` (1..64) cycles ago, byte for byte as it was
 * sent (the valid CRC of its time). Times wrap around uint32.
 * A node protects its frame as the nodes do: the counter of the last heartbeat it saw in byte 1's
 * high nibble (the signal `sync`) and the CRC over that heartbeat's freshness byte, its
 * `cycle_high` (bits 4-11 of the controller cycle, docs/can.md, E2E), both read from the
 * heartbeat frame the layer sent. The harness keeps, per input, the frames its nodes sent over
 * the last HISTORY_CYCLES cycles with the cycle each echoes (static storage).
 * Checks after every event (the policy of docs/safety.md):
 * - smartjoint_can_rx returns only its documented result bits;
 * - smartjoint_can_step returns only documented status bits; in the safe state the status has
 *   SAFE_STATE and every command is the artefact's safe normal force, else every command lies
 *   within [F^min, F^max];
 * - the newest accepted amplifier status frame of any joint with a fault bit or its own safe
 *   state means the safe state, whatever the layer remembers itself;
 * - smartjoint_can_tx sends the setpoint frames in order (one SETPOINT_<j> per joint, or
 *   SETPOINTS_<J> frames of several), then the heartbeat, then nothing; each frame has its length,
 *   a valid CRC over the freshness byte of the step's cycle (step n: SJ_E2E_FRESHNESS(n + 1)),
 *   and every frame of a step the step's alive counter (step n sends n + 1, mod 16);
 *   each joint's setpoint decodes (bit-wise reference, bus.dbc) to the command over the amplifier
 *   gain, within the amplifier's range; the heartbeat's mode is 3 in
 *   the safe state, else the law, and it carries the step status, the fault bits, the failed
 *   joints (signals failed_<joint>) and cycle_high, bits 4-11 of the cycle n + 1;
 * - freshness: a replayed frame whose echoed cycle is 16 or more cycles old is never accepted
 *   (rx OK); an accepted frame of an input resets its silence, and the step after it the frame
 *   is 0..15 cycles old;
 * - ageing, at every step and for every input: the layer's age of an input is the cycles since
 *   the cycle its newest accepted frame echoes, saturated at 255 (0 before the first heartbeat);
 *   the input is late (timed_out) exactly when that age or its silence is TIMEOUT_CYCLES or
 *   more, and then, if the law needs it, FAULT_TIMEOUT and the safe state; an input never
 *   accepted is never timed_out.
 * Every frame sits in a buffer of exactly its size; ASan and UBSan abort on any bad access or
 * undefined behaviour. */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_reference.h"
#include "smartjoint_can.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define MAX_EVENTS 2048
#define STEPS_PER_EVENT 8u /* the most steps one event makes */
#define MAX_STEPS (MAX_EVENTS * STEPS_PER_EVENT)
/* The layer keeps each echoed cycle mod 2^16 and ages it in uint16: exact while a run is shorter. */
typedef char no_echo_wrap[MAX_STEPS < 65536u ? 1 : -1];
#define TX_LENGTH 64u /* the longest CAN FD frame */
#define HISTORY_CYCLES 128u /* a power of two above the oldest replay (64 cycles) */
#define MAX_REPLAY_AGE 64u
#define FRESH_WINDOW 16u /* the 4-bit echo: a frame up to 15 cycles old passes E2E, an older one fails */

/* The frames the controller receives, then two it sends itself (which it must ignore). */
static const uint32_t frame_ids[] = {
    SMARTJOINT_CAN_JOINT_A1_ID,      SMARTJOINT_CAN_JOINT_A2_ID,      SMARTJOINT_CAN_JOINT_A3_ID,
    SMARTJOINT_CAN_TIP_SENSORS_ID,   SMARTJOINT_CAN_AMP_STATUS_A1_ID, SMARTJOINT_CAN_AMP_STATUS_A2_ID,
    SMARTJOINT_CAN_AMP_STATUS_A3_ID, FUZZ_FIRST_SETPOINT_ID,          SMARTJOINT_CAN_CONTROLLER_STATUS_ID,
};
#define FRAME_IDS (sizeof frame_ids / sizeof frame_ids[0])
#define INPUT_IDS 7u
typedef char inputs_agree[SMARTJOINT_CAN_INPUTS == INPUT_IDS ? 1 : -1];
typedef char one_bus[SMARTJOINT_CAN_BUSES == 1 ? 1 : -1]; /* a late input makes the whole layer safe */

typedef struct {
    smartjoint_can_state can;
    uint32_t time;
    uint8_t rx_counter[FRAME_IDS]; /* alive counters the harness sends with */
    /* The last heartbeat the nodes saw, as the layer sent it: its alive counter (what they echo)
     * and cycle_high (the freshness byte they protect with); and its true cycle (the steps). */
    uint8_t heartbeat;
    uint8_t heartbeat_high;
    uint32_t heartbeat_cycle;
    uint8_t amplifier_alarm[FUZZ_JOINTS]; /* the newest accepted status frame had a fault or safe bit */
    /* Per input the newest accepted frame: the cycle it echoes, and the step count then. */
    uint8_t accepted[INPUT_IDS];
    uint32_t accepted_echo[INPUT_IDS];
    uint32_t accepted_at[INPUT_IDS];
    uint32_t steps;
} bench;

/* A frame a node sent: byte for byte, the harness cycle it was sent in and the cycle it echoes. */
typedef struct {
    uint8_t valid;
    uint8_t length;
    uint32_t cycle;
    uint32_t echoed;
    uint8_t frame[FUZZ_MAX_LENGTH];
} sent_frame;

/* Per input the newest frame its node sent in each of the last HISTORY_CYCLES cycles (cleared
 * for every fuzz input). */
static sent_frame history[INPUT_IDS][HISTORY_CYCLES];

static double field_value(const fuzz_message *message, const char *name, const uint8_t *frame)
{
    const fuzz_signal *signal = fuzz_find_signal(message, name);
    return fuzz_reference_decode(fuzz_reference_field(frame, signal), signal);
}

/* Writes the raw bits of SIGNAL into FRAME (DBC "@1"). */
static void put_field(uint8_t *frame, const fuzz_signal *signal, uint64_t raw)
{
    unsigned int k;
    for (k = 0u; k < signal->length; ++k) {
        const unsigned int bit = signal->start + k;
        const uint8_t mask = (uint8_t)(1u << (bit & 7u));
        frame[bit >> 3] = (uint8_t)(((raw >> k) & 1u) ? (frame[bit >> 3] | mask) : (frame[bit >> 3] & ~mask));
    }
}

/* The input slot of an identifier, or INPUT_IDS. */
static unsigned int input_slot(uint32_t id)
{
    unsigned int slot;
    for (slot = 0u; slot < INPUT_IDS && frame_ids[slot] != id; ++slot) {
    }
    return slot;
}

/* The cycle a frame echoing ECHO (0..15) is read as at step count NOW: the latest cycle up to NOW
 * with those low bits (bench/e2e.py echoed_cycle), i.e. taken 0..15 cycles old. */
static uint32_t echoed_cycle(uint32_t now, unsigned int echo)
{
    return now - ((now - echo) & 15u);
}

/* Delivers a frame; ECHOED is the cycle a node frame truly echoes (KNOWN), else the harness
 * takes the reading any receiver must take of it. Returns the rx result. */
static unsigned int deliver(bench *b, uint32_t id, const uint8_t *frame, uint8_t length, int known, uint32_t echoed)
{
    const unsigned int result = smartjoint_can_rx(&b->can, id, frame, length, b->time);
    const unsigned int slot = input_slot(id);
    unsigned int j;
    if (result & ~(SMARTJOINT_CAN_RX_WRONG_LENGTH | SMARTJOINT_CAN_RX_BAD_CRC | SMARTJOINT_CAN_RX_COUNTER_REPEATED |
                   SMARTJOINT_CAN_RX_COUNTER_JUMP | SMARTJOINT_CAN_RX_UNKNOWN_ID | SMARTJOINT_CAN_RX_COUNTER_STALE)) {
        fuzz_fail("can_layer", "rx of id 0x%x, length %u: undocumented result 0x%x", id, length, result);
    }
    if (result == SMARTJOINT_CAN_RX_OK && slot < INPUT_IDS) {
        /* An accepted frame is the input's newest: its silence ends (input k of the layer is
         * frame_ids[k], the order of bus.dbc's inputs). */
        if (!b->can.seen[slot] || b->can.silent_steps[slot] != 0u || !b->can.healthy[slot]) {
            fuzz_fail("can_layer", "rx of id 0x%x accepted, but input %u is not seen, healthy and heard this cycle", id,
                      slot);
        }
        b->accepted[slot] = 1u;
        b->accepted_echo[slot] = known ? echoed : echoed_cycle(b->steps, frame[1] >> 4);
        b->accepted_at[slot] = b->steps;
    }
    for (j = 0u; j < FUZZ_JOINTS && result == SMARTJOINT_CAN_RX_OK; ++j) {
        if (id == frame_ids[FUZZ_JOINTS + 1u + j]) {
            const fuzz_message *m = fuzz_find_message(id);
            b->amplifier_alarm[j] = (uint8_t)(field_value(m, "over_temperature", frame) != 0.0 ||
                                              field_value(m, "no_response", frame) != 0.0 ||
                                              field_value(m, "stuck_output", frame) != 0.0 ||
                                              field_value(m, "over_current", frame) != 0.0 ||
                                              field_value(m, "safe_state", frame) != 0.0);
        }
    }
    return result;
}

/* Keeps a frame a node of input SLOT sent in this cycle (the newest of the cycle wins). */
static void remember(bench *b, unsigned int slot, const uint8_t *frame, uint8_t length)
{
    sent_frame *entry;
    if (slot >= INPUT_IDS || length > FUZZ_MAX_LENGTH) {
        return;
    }
    entry = &history[slot][b->steps % HISTORY_CYCLES];
    entry->valid = 1u;
    entry->length = length;
    entry->cycle = b->steps;
    entry->echoed = b->heartbeat_cycle;
    memcpy(entry->frame, frame, length);
}

/* A healthy node echoes the last heartbeat it saw (its counter, in `sync`: byte 1's high nibble)
 * and protects the frame with that heartbeat's freshness byte (its cycle_high). */
static void protect_as_node(bench *b, uint32_t id, uint8_t *frame, uint8_t length, uint8_t counter)
{
    const fuzz_message *message = fuzz_find_message(id);
    unsigned int k;
    for (k = 0u; message != NULL && length == message->length && k < message->count; ++k) {
        if (strcmp(message->signals[k].name, "sync") == 0) { /* the frames the controller reads */
            const fuzz_signal *sync = &message->signals[k];
            if (sync->start != 12u || sync->length != 4u) {
                fuzz_fail("can_layer", "bus.dbc: %s.sync at bit %u, %u bits — the E2E echo is byte 1's high nibble",
                          message->name, sync->start, sync->length);
            }
            put_field(frame, sync, b->heartbeat);
        }
    }
    sj_e2e_protect((uint16_t)id, frame, length, counter, b->heartbeat_high);
}

static void receive(bench *b, fuzz_reader *reader)
{
    const uint8_t control = fuzz_take_u8(reader);
    const uint8_t choice = fuzz_take_u8(reader);
    const uint32_t id = choice < 224u ? frame_ids[choice % FRAME_IDS] : fuzz_take_u32(reader);
    const fuzz_message *message = fuzz_find_message(id);
    const uint8_t length = (control & 1u) && message != NULL ? (uint8_t)message->length : fuzz_take_u8(reader);
    uint8_t *frame = malloc(length);
    if (frame == NULL && length > 0u) {
        abort();
    }
    fuzz_take_bytes(reader, frame, length);
    if (control & 2u) {
        /* A frame a healthy node would send: next counter, or a few ahead, valid CRC. */
        const unsigned int slot = choice < 224u ? choice % FRAME_IDS : 0u;
        b->rx_counter[slot] = (uint8_t)(b->rx_counter[slot] + 1u + ((control >> 4) & 3u));
        protect_as_node(b, id, frame, length, b->rx_counter[slot]);
        if (message != NULL && length == message->length) {
            remember(b, input_slot(id), frame, length);
        }
    }
    b->time += (control & 4u) ? fuzz_take_u32(reader) : fuzz_take_u8(reader);
    (void)deliver(b, id, frame, length, (control & 2u) != 0u, b->heartbeat_cycle);
    free(frame);
}

/* A replay: the frame the node of an input sent AGE cycles ago (else the newest before that
 * still kept), byte for byte. Whatever its counter, a frame echoing a cycle 16 or more cycles
 * old must fail its CRC (its freshness byte is another), so the layer never takes it. */
static void replay(bench *b, fuzz_reader *reader)
{
    const unsigned int slot = fuzz_take_u8(reader) % INPUT_IDS;
    const uint32_t age = 1u + fuzz_take_u8(reader) % MAX_REPLAY_AGE;
    const sent_frame *entry = NULL;
    uint32_t back;
    uint8_t *frame;
    unsigned int result;
    b->time += fuzz_take_u8(reader);
    for (back = age; back <= b->steps && back < HISTORY_CYCLES; ++back) {
        const sent_frame *candidate = &history[slot][(b->steps - back) % HISTORY_CYCLES];
        if (candidate->valid && candidate->cycle == b->steps - back) {
            entry = candidate;
            break;
        }
    }
    if (entry == NULL) {
        return;
    }
    frame = malloc(entry->length); /* exactly the frame, as every frame here */
    if (frame == NULL) {
        abort();
    }
    memcpy(frame, entry->frame, entry->length);
    result = deliver(b, frame_ids[slot], frame, entry->length, 1, entry->echoed);
    if (result == SMARTJOINT_CAN_RX_OK && b->steps - entry->echoed >= FRESH_WINDOW) {
        fuzz_fail("can_layer", "replay of id 0x%x sent in cycle %u, echoing cycle %u, accepted in cycle %u: a frame %u "
                               "cycles old passed E2E",
                  frame_ids[slot], (unsigned int)entry->cycle, (unsigned int)entry->echoed, (unsigned int)b->steps,
                  (unsigned int)(b->steps - entry->echoed));
    }
    free(frame);
}

/* A value within [-limit, limit] (or [0, limit] when non-negative) chosen by one byte. */
static double within_limit(fuzz_reader *reader, double limit, int non_negative)
{
    const double fraction = (double)fuzz_take_u8(reader) / 255.0;
    return non_negative ? fraction * limit : (2.0 * fraction - 1.0) * limit;
}

/* The physical value a healthy node sends in signal K of input SLOT, mostly within the design's
 * ranges, sometimes at a fault bit. */
static double healthy_value(const bench *b, unsigned int slot, const fuzz_message *message, unsigned int k,
                            fuzz_reader *reader)
{
    const char *name = message->signals[k].name;
    const unsigned int j = slot < FUZZ_JOINTS ? slot : (slot > FUZZ_JOINTS ? slot - FUZZ_JOINTS - 1u : 0u);
    if (slot < FUZZ_JOINTS) {
        if (strcmp(name, "sliding_velocity") == 0) {
            return within_limit(reader, fuzz_sliding_velocity_limit[j], 0);
        }
        if (strcmp(name, "friction_force") == 0) {
            return within_limit(reader, fuzz_friction_force_limit[j], 0);
        }
        return within_limit(reader, fuzz_measured_normal_force_max[j], 1);
    }
    if (slot == FUZZ_JOINTS) { /* crc, counter, sync, then the sensors in order */
        return within_limit(reader, fuzz_sensor_limit[(k - 3u) % FUZZ_SENSORS], 0);
    }
    if (strcmp(name, "monitor_voltage") == 0) { /* the last setpoint, within half the tolerance */
        const fuzz_signal *voltage = fuzz_find_signal(fuzz_find_message(fuzz_setpoint_ids[j]), fuzz_setpoint_signals[j]);
        return fuzz_reference_decode(b->can.setpoint[j], voltage) + within_limit(reader, 0.5 * fuzz_tracking_tolerance, 0);
    }
    if (strcmp(name, "current") == 0) {
        return within_limit(reader, fuzz_amplifier_current_limit, 0);
    }
    if (strcmp(name, "temperature") == 0) {
        return within_limit(reader, fuzz_amplifier_temperature_limit, 1);
    }
    return (fuzz_take_u8(reader) & 15u) == 0u ? 1.0 : 0.0; /* a fault or safe-state bit, now and then */
}

/* One sample of a bus: every input node sends its frame with the next alive counter, the
 * heartbeat echo and a valid CRC, 10 us apart; the payload is mostly what a healthy node sends
 * (values within the design's ranges), else any bytes. */
static void bus_cycle(bench *b, fuzz_reader *reader)
{
    unsigned int slot;
    for (slot = 0u; slot < INPUT_IDS; ++slot) {
        const fuzz_message *message = fuzz_find_message(frame_ids[slot]);
        uint8_t *frame = malloc(message->length);
        unsigned int k;
        if (frame == NULL) {
            abort();
        }
        memset(frame, 0, message->length);
        if (fuzz_take_u8(reader) < 224u) {
            for (k = 0u; k < message->count; ++k) {
                const fuzz_signal *signal = &message->signals[k];
                if (strcmp(signal->name, "crc") != 0 && strcmp(signal->name, "counter") != 0 &&
                    strcmp(signal->name, "sync") != 0) {
                    put_field(frame, signal, fuzz_reference_encode(healthy_value(b, slot, message, k, reader), signal));
                }
            }
        } else {
            fuzz_take_bytes(reader, frame, message->length);
        }
        protect_as_node(b, message->id, frame, (uint8_t)message->length, ++b->rx_counter[slot]);
        remember(b, slot, frame, (uint8_t)message->length);
        b->time += 10u;
        (void)deliver(b, message->id, frame, (uint8_t)message->length, 1, b->heartbeat_cycle);
        free(frame);
    }
}

static void check_setpoint(const bench *b, unsigned int joint, const uint8_t *frame)
{
    const fuzz_message *message = fuzz_find_message(fuzz_setpoint_ids[joint]);
    const fuzz_signal *voltage = fuzz_find_signal(message, fuzz_setpoint_signals[joint]);
    const double sent = field_value(message, fuzz_setpoint_signals[joint], frame);
    const double command = (double)b->can.command[joint];
    double expected = (command - fuzz_preload) / fuzz_force_per_volt;
    expected = expected < voltage->minimum ? voltage->minimum : (expected > voltage->maximum ? voltage->maximum : expected);
    /* The float build computes the voltage and its raw value in float: a few float roundings
     * beyond the half step of the quantisation. */
    if (!(fabs(sent - expected) <= 0.5 * voltage->scale + 4.0 * (double)FLT_EPSILON * fabs(expected))) {
        fuzz_fail("can_layer", "setpoint of joint %u: %.9g V sent for a command of %.9g N", joint, sent, command);
    }
}

static void check_status_frame(const bench *b, unsigned int status, const uint8_t *frame)
{
    unsigned int j, k;
    unsigned int named = 0u;
    int any = 0;
    const fuzz_message *message = fuzz_find_message(SMARTJOINT_CAN_CONTROLLER_STATUS_ID);
    const double mode = field_value(message, "mode", frame);
    const double expected = b->can.safe ? 3.0 : (double)b->can.law;
    if (mode != expected || field_value(message, "step_status", frame) != (double)(status & 0xFFu) ||
        field_value(message, "faults", frame) != (double)b->can.faults) {
        fuzz_fail("can_layer", "status frame: mode %g (expected %g), step status %g (expected %u), faults %g (%u)", mode,
                  expected, field_value(message, "step_status", frame), status & 0xFFu,
                  field_value(message, "faults", frame), (unsigned int)b->can.faults);
    }
    /* The actuation check: the heartbeat names exactly the joints the layer holds failed (the
     * signals failed_<joint> of bus.dbc in joint order, docs/safety.md), and its fault bit stands
     * for any of them; it makes nothing safe. */
    j = 0u;
    for (k = 0u; k < message->count; ++k) {
        if (strncmp(message->signals[k].name, "failed_", 7u) == 0 && j < FUZZ_JOINTS) {
            const double failed = fuzz_reference_decode(fuzz_reference_field(frame, &message->signals[k]),
                                                        &message->signals[k]);
            named |= (unsigned int)(failed != 0.0) != (b->can.failed[j] != 0u);
            any |= b->can.failed[j] != 0u;
            j++;
        }
    }
    if (j != FUZZ_JOINTS || named || any != ((b->can.faults & SMARTJOINT_CAN_FAULT_ACTUATION) != 0u)) {
        fuzz_fail("can_layer", "status frame: failed joints (%u signals) differ from the layer's, or the actuation bit "
                               "(0x%x)", j, (unsigned int)b->can.faults);
    }
    /* The freshness byte the nodes learn: bits 4-11 of the cycle, step n + 1. */
    if (field_value(message, "cycle_high", frame) != (double)SJ_E2E_FRESHNESS(b->steps + 1u)) {
        fuzz_fail("can_layer", "status frame of step %u: cycle_high %g, expected 0x%02x", (unsigned int)b->steps,
                  field_value(message, "cycle_high", frame), (unsigned int)SJ_E2E_FRESHNESS(b->steps + 1u));
    }
}

static void check_commands(const bench *b, unsigned int status)
{
    unsigned int j;
    int fault = 0;
    if (status & ~(SMARTJOINT_STATUS_INPUT_INVALID | SMARTJOINT_STATUS_ESTIMATE_RESET |
                   SMARTJOINT_STATUS_INPUT_IMPLAUSIBLE | SMARTJOINT_CAN_STATUS_SAFE_STATE)) {
        fuzz_fail("can_layer", "step: undocumented status 0x%x", status);
    }
    if (!b->can.safe && status != 0u) {
        fuzz_fail("can_layer", "step: status 0x%x outside the safe state", status);
    }
    for (j = 0u; j < FUZZ_JOINTS; ++j) {
        const double command = (double)b->can.command[j];
        fault |= b->amplifier_alarm[j] != 0u;
        if (b->can.safe) {
            /* the float build holds the safe force as a float */
            if (command != (double)(float)fuzz_safe_normal_force[j] || !(status & SMARTJOINT_CAN_STATUS_SAFE_STATE)) {
                fuzz_fail("can_layer", "safe state: joint %u commanded %.9g N, status 0x%x", j, command, status);
            }
        } else if (!(command >= fuzz_normal_force_min[j] && command <= fuzz_normal_force_max[j])) {
            fuzz_fail("can_layer", "step: joint %u commanded %.9g N, outside [%g, %g]", j, command,
                      fuzz_normal_force_min[j], fuzz_normal_force_max[j]);
        }
    }
    if (fault && !b->can.safe) {
        fuzz_fail("can_layer", "step: an amplifier reports a fault or its own safe state but the controller is not "
                               "in the safe state");
    }
}

/* After the step of cycle count b->steps, for every input (the layer's check_inputs): one with an
 * accepted frame has the age of its newest, the cycles since the cycle it echoes (truly, for a
 * node's frame; else as read on receipt), saturated at 255 — 0 before the first heartbeat went
 * out; a frame is exactly 0..15 cycles old the step after its acceptance. It is late
 * (timed_out) exactly when that age or its silence (steps since the acceptance) is
 * TIMEOUT_CYCLES or more; a late input the law needs (the tip sensors only the cLQG) sets
 * FAULT_TIMEOUT and the safe state (the reference has one bus). An input never accepted is
 * missing but never timed_out. The layer keeps the echoed cycle mod 2^16; a run is at most
 * MAX_STEPS steps, so the true age (uint32) and the layer's never differ by a wrap. */
static void check_ages(const bench *b)
{
    unsigned int slot;
    for (slot = 0u; slot < INPUT_IDS; ++slot) {
        const uint32_t age = b->steps - b->accepted_echo[slot];
        const uint32_t silent = b->steps - b->accepted_at[slot];
        const unsigned int reported = b->heartbeat_cycle == 0u ? 0u : (age > 255u ? 255u : (unsigned int)age);
        const int late = reported >= SMARTJOINT_CAN_TIMEOUT_CYCLES || silent >= SMARTJOINT_CAN_TIMEOUT_CYCLES;
        const int needed = slot != FUZZ_JOINTS || b->can.law == SMARTJOINT_CAN_LAW_CLQG;
        if (!b->accepted[slot]) {
            if (b->can.timed_out[slot]) {
                fuzz_fail("can_layer", "step %u: input 0x%x never accepted a frame but is timed out",
                          (unsigned int)b->steps, frame_ids[slot]);
            }
            continue;
        }
        if (b->accepted_at[slot] == b->steps && b->heartbeat_cycle != 0u && age >= FRESH_WINDOW) {
            fuzz_fail("can_layer", "input 0x%x: the frame accepted in cycle %u echoes cycle %u, %u cycles old",
                      frame_ids[slot], (unsigned int)b->steps, (unsigned int)b->accepted_echo[slot],
                      (unsigned int)age);
        }
        if (b->can.age[slot] != reported || late != (b->can.timed_out[slot] != 0u)) {
            fuzz_fail("can_layer", "step %u: input 0x%x's newest frame, accepted in cycle %u, echoes cycle %u (age %u, "
                                   "silent %u steps), the layer ages it %u and has it %s",
                      (unsigned int)b->steps, frame_ids[slot], (unsigned int)b->accepted_at[slot],
                      (unsigned int)b->accepted_echo[slot], reported, (unsigned int)silent, b->can.age[slot],
                      b->can.timed_out[slot] ? "late" : "in time");
        }
        if (late && needed && (!(b->can.faults & SMARTJOINT_CAN_FAULT_TIMEOUT) || !b->can.safe)) {
            fuzz_fail("can_layer", "step %u: input 0x%x is late (age %u, silent %u steps), but faults 0x%x, %s",
                      (unsigned int)b->steps, frame_ids[slot], reported, (unsigned int)silent,
                      (unsigned int)b->can.faults, b->can.safe ? "safe" : "not in the safe state");
        }
    }
}

static void step_and_send(bench *b, fuzz_reader *reader)
{
    const uint8_t control = fuzz_take_u8(reader);
    uint8_t *frame = malloc(TX_LENGTH);
    unsigned int status, sent = 0u, expected_frames;
    uint32_t id = 0u;
    uint8_t length = 0u;
    if (frame == NULL) {
        abort();
    }
    b->time += (control & 1u) ? fuzz_take_u32(reader) : (uint32_t)SMARTJOINT_CAN_CYCLE_US * (control >> 6);
    if (b->can.steps != b->steps) {
        fuzz_fail("can_layer", "the layer counts %u steps, the harness %u", (unsigned int)b->can.steps,
                  (unsigned int)b->steps);
    }
    status = smartjoint_can_step(&b->can, b->time);
    check_commands(b, status);
    check_ages(b);
    expected_frames = FUZZ_SETPOINT_FRAMES + 1u; /* the setpoints and the heartbeat, every step */
    while (smartjoint_can_tx(&b->can, &id, frame, &length)) {
        const uint32_t expected_id =
            sent < FUZZ_SETPOINT_FRAMES ? fuzz_setpoint_frames[sent] : SMARTJOINT_CAN_CONTROLLER_STATUS_ID;
        const fuzz_message *message = fuzz_find_message(expected_id);
        if (sent >= expected_frames || id != expected_id || length != message->length) {
            fuzz_fail("can_layer", "tx frame %u of step %u: id 0x%x length %u (expected id 0x%x length %u, %u frames)",
                      sent, b->steps, id, length, expected_id, message->length, expected_frames);
        }
        if (frame[0] != sj_e2e_frame_crc((uint16_t)id, frame, length, SJ_E2E_FRESHNESS(b->steps + 1u)) ||
            (frame[1] & 0x0Fu) != (b->steps + 1u) % 16u) {
            fuzz_fail("can_layer", "tx frame 0x%x of step %u: CRC 0x%02x (freshness 0x%02x) or counter %u wrong (expected "
                                   "counter %u)", id, (unsigned int)b->steps, frame[0],
                      (unsigned int)SJ_E2E_FRESHNESS(b->steps + 1u), frame[1] & 0x0Fu, (b->steps + 1u) % 16u);
        }
        if (sent < FUZZ_SETPOINT_FRAMES) {
            unsigned int j;
            for (j = 0u; j < FUZZ_JOINTS; ++j) {
                if (fuzz_setpoint_ids[j] == id) {
                    check_setpoint(b, j, frame);
                }
            }
        } else {
            check_status_frame(b, status, frame);
            /* what the nodes see of it: its counter and cycle_high */
            b->heartbeat = (uint8_t)(frame[1] & 0x0Fu);
            b->heartbeat_high = (uint8_t)field_value(message, "cycle_high", frame);
            b->heartbeat_cycle = b->steps + 1u;
        }
        sent++;
    }
    if (sent != expected_frames) {
        fuzz_fail("can_layer", "step %u sent %u frames, expected %u", b->steps, sent, expected_frames);
    }
    b->steps++;
    free(frame);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    bench b;
    int event;
    fuzz_reader_init(&reader, data, size);
    memset(&b, 0, sizeof b);
    memset(history, 0, sizeof history);
    smartjoint_can_init(&b.can, (fuzz_take_u8(&reader) & 1u) ? SMARTJOINT_CAN_LAW_CLQG : SMARTJOINT_CAN_LAW_SISO);
    b.time = fuzz_take_u32(&reader);
    for (event = 0; event < MAX_EVENTS && fuzz_more(&reader); ++event) {
        const uint8_t kind = fuzz_take_u8(&reader);
        unsigned int repeat;
        switch (kind % 5u) {
        case 0u:
            receive(&b, &reader);
            break;
        case 1u:
            /* 1..8 steps without frames in between: many cycles (the replays' history) cheaply */
            for (repeat = 0u; repeat <= (kind / 5u) % STEPS_PER_EVENT && fuzz_more(&reader); ++repeat) {
                step_and_send(&b, &reader);
            }
            break;
        case 2u:
            replay(&b, &reader);
            break;
        default:
            bus_cycle(&b, &reader);
            step_and_send(&b, &reader);
            break;
        }
    }
    return 0;
}
