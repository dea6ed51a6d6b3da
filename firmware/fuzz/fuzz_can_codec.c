/* Fuzz harness 1: the generated codec of every CAN frame (double build; the raw pack/unpack is
 * the same text in the float build).
 *
 * Input: a frame selector, a payload of the frame's length, one arbitrary double per signal.
 * Checks, for every frame of the bus:
 * - unpack reads only the frame's bytes (the payload sits in a buffer of exactly that size) and
 *   gives every raw field the reference reads from bus.dbc; decode gives the reference's value;
 *   is_in_range says whether that value lies within the signal's DBC range (else true);
 * - pack writes only the frame's bytes, reproduces the payload's fields and leaves every bit
 *   outside the signals 0;
 * - encode gives the reference encoding of any double (clamped to the signal's range, rounded
 *   half to even, NaN as 0, kept within the field) — NaN, infinities and huge values included;
 *   the round trip: a value within its range decodes back within half a scale step;
 * - pack and unpack refuse a buffer one byte short (-EINVAL), without touching it.
 * UBSan aborts on any undefined behaviour on the way (e.g. an out-of-range float to integer
 * conversion, an oversized shift). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_codec.h"
#include "fuzz_reference.h"
#include "smartjoint_can.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

typedef struct {
    const fuzz_message *message;
    const fuzz_codec *codec;
} frame_codec;

#define ENTRY(lower) {&fuzz_message_##lower, &fuzz_codec_##lower},
static const frame_codec codecs[] = {FUZZ_MESSAGES(ENTRY)};
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

/* The raw bits of a field as the codec's raw value: sign-extended for signed signals. */
static int64_t as_raw(uint64_t field, const fuzz_signal *signal)
{
    if (signal->is_signed && ((field >> (signal->length - 1u)) & 1u)) {
        return (int64_t)(field | ~((UINT64_C(1) << signal->length) - 1u));
    }
    return (int64_t)field;
}

static uint64_t as_field(int64_t raw, const fuzz_signal *signal)
{
    return (uint64_t)raw & ((UINT64_C(1) << signal->length) - 1u);
}

/* Every bit outside the signals is 0. */
static void check_padding(const fuzz_message *message, const uint8_t *frame)
{
    unsigned int k;
    for (k = 0u; k < 8u * message->length; ++k) {
        if (!is_covered(message, k) && ((frame[k / 8u] >> (k % 8u)) & 1u)) {
            fuzz_fail("can_codec", "pack %s: bit %u outside every signal is set", message->name, k);
        }
    }
}

/* Arbitrary bytes -> unpack, decode and is_in_range against the reference; pack back. */
static void check_unpack(const frame_codec *c, const uint8_t *frame, uint8_t *packed)
{
    const fuzz_message *message = c->message;
    int64_t raw[FUZZ_MAX_SIGNALS];
    double decoded[FUZZ_MAX_SIGNALS];
    int in_range[FUZZ_MAX_SIGNALS];
    unsigned int k;
    if (c->codec->unpack(frame, message->length, raw) != (int)message->length) {
        fuzz_fail("can_codec", "unpack %s: did not return the frame length", message->name);
    }
    c->codec->decode(raw, decoded);
    c->codec->is_in_range(raw, in_range);
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        const uint64_t field = fuzz_reference_field(frame, signal);
        const double expected = fuzz_reference_decode(field, signal);
        const int within = !signal->has_range || (expected >= signal->minimum && expected <= signal->maximum);
        if (raw[k] != as_raw(field, signal) || !(decoded[k] == expected) || (in_range[k] != 0) != within) {
            fuzz_fail("can_codec", "unpack %s.%s: raw %lld decoded %.17g in range %d; reference 0x%llx, %.17g, %d",
                      message->name, signal->name, (long long)raw[k], decoded[k], in_range[k],
                      (unsigned long long)field, expected, within);
        }
    }
    if (c->codec->pack(raw, packed, message->length) != (int)message->length) {
        fuzz_fail("can_codec", "pack %s: did not return the frame length", message->name);
    }
    check_padding(message, packed);
    for (k = 0u; k < message->count; ++k) {
        if (fuzz_reference_field(packed, &message->signals[k]) != fuzz_reference_field(frame, &message->signals[k])) {
            fuzz_fail("can_codec", "%s.%s: pack(unpack(frame)) changed the field", message->name,
                      message->signals[k].name);
        }
    }
}

/* Arbitrary doubles -> encode against the reference, pack, and back. */
static void check_encode(const frame_codec *c, fuzz_reader *reader, uint8_t *packed)
{
    const fuzz_message *message = c->message;
    double values[FUZZ_MAX_SIGNALS];
    double again[FUZZ_MAX_SIGNALS];
    int64_t raw[FUZZ_MAX_SIGNALS];
    unsigned int k;
    for (k = 0u; k < message->count; ++k) {
        values[k] = fuzz_take_double(reader);
    }
    c->codec->encode(values, raw);
    (void)c->codec->pack(raw, packed, message->length);
    check_padding(message, packed);
    c->codec->decode(raw, again);
    for (k = 0u; k < message->count; ++k) {
        const fuzz_signal *signal = &message->signals[k];
        const uint64_t expected = fuzz_reference_encode(values[k], signal);
        const double lowest = fuzz_raw_minimum(signal) * signal->scale + signal->offset;
        const double highest = fuzz_raw_maximum(signal) * signal->scale + signal->offset;
        const int ranged = !signal->has_range || (values[k] >= signal->minimum && values[k] <= signal->maximum);
        if (as_field(raw[k], signal) != expected || as_raw(expected, signal) != raw[k] ||
            fuzz_reference_field(packed, signal) != expected) {
            fuzz_fail("can_codec", "encode %s.%s(%.17g): raw %lld, reference 0x%llx", message->name, signal->name,
                      values[k], (long long)raw[k], (unsigned long long)expected);
        }
        if (isfinite(values[k]) && ranged && values[k] >= lowest && values[k] <= highest &&
            !fuzz_within_half_step(again[k], values[k], signal)) {
            fuzz_fail("can_codec", "%s.%s: %.17g comes back as %.17g (scale %g)", message->name, signal->name,
                      values[k], again[k], signal->scale);
        }
    }
}

/* One byte short: -EINVAL, and the buffers (exactly that short) untouched. */
static void check_short(const frame_codec *c, const uint8_t *frame)
{
    const fuzz_message *message = c->message;
    const size_t length = message->length - 1u;
    uint8_t *shorter = malloc(length);
    int64_t raw[FUZZ_MAX_SIGNALS] = {0};
    if (shorter == NULL) {
        abort();
    }
    memcpy(shorter, frame, length);
    if (c->codec->pack(raw, shorter, length) != -SMARTJOINT_CAN_EINVAL ||
        c->codec->unpack(shorter, length, raw) != -SMARTJOINT_CAN_EINVAL || memcmp(shorter, frame, length) != 0) {
        fuzz_fail("can_codec", "%s: a %u-byte buffer was not refused untouched", message->name, (unsigned int)length);
    }
    free(shorter);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    const frame_codec *c;
    uint8_t *frame;
    uint8_t *packed;
    fuzz_reader_init(&reader, data, size);
    c = &codecs[fuzz_take_u8(&reader) % CODECS];
    frame = malloc(c->message->length);
    packed = malloc(c->message->length);
    if (frame == NULL || packed == NULL) {
        abort();
    }
    fuzz_take_bytes(&reader, frame, c->message->length);
    check_unpack(c, frame, packed);
    check_encode(c, &reader, packed);
    check_short(c, frame);
    free(frame);
    free(packed);
    return 0;
}
