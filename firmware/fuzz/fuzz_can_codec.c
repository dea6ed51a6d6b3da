/* Fuzz harness 1: the generated pack/unpack functions of every CAN frame.
 *
 * Input: a frame selector, a payload of the frame's length, one arbitrary double per signal.
 * Checks, for every frame of the bus:
 * - unpack reads only the frame's bytes (the payload sits in a buffer of exactly that size)
 *   and gives, for every signal, the value the bit-wise reference decodes from bus.dbc;
 * - pack writes only the frame's bytes, each field holds the reference encoding of the value
 *   (clamped to the signal's range, rounded half to even, NaN as 0) for any double — NaN,
 *   infinities and huge values included — and every bit outside the signals is 0;
 * - the round trip: a value within its signal's range comes back within half a scale step,
 *   and pack(unpack(frame)) reproduces every field whose value lies within its range.
 * UBSan aborts on any undefined behaviour on the way (e.g. an out-of-range float to integer
 * conversion, an oversized shift). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_reference.h"
#include "smartjoint_can.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Typed adaptors: the generated structs hold one double per signal, in start-bit order. */
#define CODEC(lower)                                                                         \
    static void pack_##lower(const double *values, uint8_t *frame)                           \
    {                                                                                        \
        smartjoint_can_##lower##_t signals;                                                  \
        memcpy(&signals, values, sizeof signals);                                            \
        smartjoint_can_pack_##lower(&signals, frame);                                        \
    }                                                                                        \
    static void unpack_##lower(const uint8_t *frame, double *values)                         \
    {                                                                                        \
        smartjoint_can_##lower##_t signals;                                                  \
        smartjoint_can_unpack_##lower(frame, &signals);                                      \
        memcpy(values, &signals, sizeof signals);                                            \
    }
FUZZ_MESSAGES(CODEC)

typedef struct {
    const fuzz_message *message;
    void (*pack)(const double *values, uint8_t *frame);
    void (*unpack)(const uint8_t *frame, double *values);
    size_t struct_size;
} codec;

#define ENTRY(lower) {&fuzz_message_##lower, pack_##lower, unpack_##lower, sizeof(smartjoint_can_##lower##_t)},
static const codec codecs[] = {FUZZ_MESSAGES(ENTRY)};
#define CODECS (sizeof codecs / sizeof codecs[0])

static int is_covered(const fuzz_message *message, unsigned int bit)
{
    unsigned int k;
    for (k = 0u; k < message->count; ++k) {
        if (bit >= message->signals[k].start && bit < message->signals[k].start + message->signals[k].length) {
            return 1;
        }
    }
    return 0;
}

static int within_range(const fuzz_signal *signal, double value)
{
    return !signal->has_range || (value >= signal->minimum && value <= signal->maximum);
}

/* The packed frame holds the reference encoding of every value and nothing else. */
static void check_packed(const fuzz_message *message, const double *values, const uint8_t *frame)
{
    unsigned int k;
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        const uint64_t expected = fuzz_reference_encode(values[k], signal);
        const uint64_t field = fuzz_reference_field(frame, signal);
        if (field != expected) {
            fuzz_fail("can_codec", "pack %s.%s(%.17g): field 0x%llx, reference 0x%llx", message->name, signal->name,
                      values[k], (unsigned long long)field, (unsigned long long)expected);
        }
    }
    for (k = 0u; k < 8u * message->length; ++k) {
        if (!is_covered(message, k) && ((frame[k / 8u] >> (k % 8u)) & 1u)) {
            fuzz_fail("can_codec", "pack %s: bit %u outside every signal is set", message->name, k);
        }
    }
}

static void check_codec(const codec *c, fuzz_reader *reader)
{
    const fuzz_message *message = c->message;
    const size_t length = message->length;
    uint8_t *frame = malloc(length);
    uint8_t *packed = malloc(length);
    double decoded[FUZZ_MAX_SIGNALS];
    double values[FUZZ_MAX_SIGNALS];
    double again[FUZZ_MAX_SIGNALS];
    unsigned int k;
    if (frame == NULL || packed == NULL) {
        abort();
    }
    if (c->struct_size != message->count * sizeof(double)) {
        fuzz_fail("can_codec", "%s: the generated struct does not hold one double per signal of bus.dbc",
                  message->name);
    }

    /* Arbitrary bytes -> unpack, against the reference decoder. */
    fuzz_take_bytes(reader, frame, length);
    c->unpack(frame, decoded);
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        const double expected = fuzz_reference_decode(fuzz_reference_field(frame, signal), signal);
        if (!(decoded[k] == expected)) {
            fuzz_fail("can_codec", "unpack %s.%s: %.17g, reference %.17g", message->name, signal->name, decoded[k],
                      expected);
        }
    }
    /* ... and back: a decoded value within its range is reproduced bit for bit. */
    c->pack(decoded, packed);
    check_packed(message, decoded, packed);
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        if (within_range(signal, decoded[k]) &&
            fuzz_reference_field(packed, signal) != fuzz_reference_field(frame, signal)) {
            fuzz_fail("can_codec", "%s.%s: pack(unpack(frame)) changed the field", message->name, signal->name);
        }
    }

    /* Arbitrary doubles -> pack, against the reference encoder; then the round trip. */
    for (k = 0u; k < message->count; ++k) {
        values[k] = fuzz_take_double(reader);
    }
    c->pack(values, packed);
    check_packed(message, values, packed);
    c->unpack(packed, again);
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        const double lowest = fuzz_raw_minimum(signal) * signal->scale + signal->offset;
        const double highest = fuzz_raw_maximum(signal) * signal->scale + signal->offset;
        if (!isfinite(again[k])) {
            fuzz_fail("can_codec", "%s.%s: %.17g packs to a non-finite value", message->name, signal->name, values[k]);
        }
        if (isfinite(values[k]) && within_range(signal, values[k]) && values[k] >= lowest && values[k] <= highest &&
            !fuzz_within_half_step(again[k], values[k], signal)) {
            fuzz_fail("can_codec", "%s.%s: %.17g comes back as %.17g (scale %g)", message->name, signal->name,
                      values[k], again[k], signal->scale);
        }
    }
    free(frame);
    free(packed);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    fuzz_reader_init(&reader, data, size);
    check_codec(&codecs[fuzz_take_u8(&reader) % CODECS], &reader);
    return 0;
}
