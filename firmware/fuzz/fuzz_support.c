/* See fuzz_support.h. */
#include "fuzz_support.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_reference.h"

void fuzz_reader_init(fuzz_reader *reader, const uint8_t *data, size_t size)
{
    reader->data = data;
    reader->size = size;
    reader->used = 0u;
}

int fuzz_more(const fuzz_reader *reader)
{
    return reader->used < reader->size;
}

uint8_t fuzz_take_u8(fuzz_reader *reader)
{
    if (reader->used >= reader->size) {
        return 0u;
    }
    return reader->data[reader->used++];
}

void fuzz_take_bytes(fuzz_reader *reader, uint8_t *out, size_t count)
{
    size_t k;
    for (k = 0u; k < count; ++k) {
        out[k] = fuzz_take_u8(reader);
    }
}

uint16_t fuzz_take_u16(fuzz_reader *reader)
{
    const uint16_t low = fuzz_take_u8(reader);
    return (uint16_t)(low | (uint16_t)(fuzz_take_u8(reader) << 8));
}

uint32_t fuzz_take_u32(fuzz_reader *reader)
{
    const uint32_t low = fuzz_take_u16(reader);
    return low | ((uint32_t)fuzz_take_u16(reader) << 16);
}

/* A selector byte below SPECIAL_SELECTORS picks a special value, any other takes raw bytes. */
#define SPECIAL_SELECTORS 48u

/* One value of `size` bytes: a special one of the `count` in `special`, or raw bytes. */
static void take_value(fuzz_reader *reader, void *value, size_t size, const void *special, size_t count)
{
    const uint8_t selector = fuzz_take_u8(reader);
    if (selector < SPECIAL_SELECTORS) {
        memcpy(value, (const uint8_t *)special + (selector % count) * size, size);
    } else {
        fuzz_take_bytes(reader, (uint8_t *)value, size);
    }
}

double fuzz_take_double(fuzz_reader *reader)
{
    static const double special[] = {
        (double)NAN, -(double)NAN, (double)INFINITY, -(double)INFINITY, 0.0, -0.0, DBL_MAX, -DBL_MAX, DBL_MIN,
        -DBL_MIN, 4.9406564584124654e-324, -4.9406564584124654e-324, (double)FLT_MAX, -(double)FLT_MAX, 1e308, -1e308,
        1.0, -1.0, 0.5, -0.5, 2147483648.0, -2147483649.0, 4294967296.0, 9223372036854775808.0,
        -9223372036854775808.0, 18446744073709551616.0, 1e-9, -1e-9, 5e-10, 1e19, -1e19, 1e-300,
    };
    double value;
    take_value(reader, &value, sizeof value, special, sizeof special / sizeof special[0]);
    return value;
}

float fuzz_take_float(fuzz_reader *reader)
{
    static const float special[] = {
        NAN, -NAN, INFINITY, -INFINITY, 0.0f, -0.0f, FLT_MAX, -FLT_MAX, FLT_MIN, -FLT_MIN,
        1.40129846e-45f, -1.40129846e-45f, 1e38f, -1e38f, 1.0f, -1.0f, 0.5f, -0.5f, 1e-9f, -1e-9f,
        3.1622776e-06f, 1e-30f, 1e30f, -1e30f,
    };
    float value;
    take_value(reader, &value, sizeof value, special, sizeof special / sizeof special[0]);
    return value;
}

const fuzz_message *fuzz_find_message(uint32_t id)
{
    unsigned int k;
    for (k = 0u; k < FUZZ_MESSAGE_COUNT; ++k) {
        if (fuzz_bus[k]->id == id) {
            return fuzz_bus[k];
        }
    }
    return NULL;
}

const fuzz_signal *fuzz_find_signal(const fuzz_message *message, const char *name)
{
    unsigned int k;
    for (k = 0u; k < message->count; ++k) {
        if (strcmp(message->signals[k].name, name) == 0) {
            return &message->signals[k];
        }
    }
    fuzz_fail("support", "message %s has no signal %s", message->name, name);
}

uint64_t fuzz_reference_field(const uint8_t *data, const fuzz_signal *signal)
{
    uint64_t raw = 0u;
    unsigned int k;
    for (k = 0u; k < signal->length; ++k) {
        const unsigned int position = signal->start + k;
        const unsigned int byte = position / 8u;
        const unsigned int bit = position % 8u;
        if (data[byte] & (1u << bit)) {
            raw += (uint64_t)1u << k;
        }
    }
    return raw;
}

double fuzz_raw_minimum(const fuzz_signal *signal)
{
    return signal->is_signed ? -ldexp(1.0, (int)signal->length - 1) : 0.0;
}

double fuzz_raw_maximum(const fuzz_signal *signal)
{
    return signal->is_signed ? ldexp(1.0, (int)signal->length - 1) - 1.0 : ldexp(1.0, (int)signal->length) - 1.0;
}

double fuzz_reference_decode(uint64_t raw, const fuzz_signal *signal)
{
    double integer = (double)raw;
    if (signal->is_signed && integer > fuzz_raw_maximum(signal)) {
        integer -= ldexp(1.0, (int)signal->length); /* two's complement */
    }
    return integer * signal->scale + signal->offset;
}

uint64_t fuzz_reference_encode(double value, const fuzz_signal *signal)
{
    const double raw_minimum = fuzz_raw_minimum(signal);
    const double raw_maximum = fuzz_raw_maximum(signal);
    double raw;
    uint64_t bits;
    if (signal->has_range && value < signal->minimum) {
        value = signal->minimum;
    } else if (signal->has_range && value > signal->maximum) {
        value = signal->maximum;
    }
    raw = nearbyint((value - signal->offset) / signal->scale);
    if (raw != raw) {
        raw = 0.0;
    } else if (raw < raw_minimum) {
        raw = raw_minimum;
    } else if (raw > raw_maximum) {
        raw = raw_maximum;
    }
    if (raw < 0.0) {
        bits = (uint64_t)(-raw);
        bits = ~bits + 1u; /* two's complement of the magnitude */
    } else {
        bits = (uint64_t)raw;
    }
    return signal->length >= 64u ? bits : bits & (((uint64_t)1u << signal->length) - 1u);
}

void fuzz_fail(const char *harness, const char *format, ...)
{
    va_list arguments;
    fprintf(stderr, "\nfuzz finding (%s): ", harness);
    va_start(arguments, format);
    vfprintf(stderr, format, arguments);
    va_end(arguments);
    fprintf(stderr, "\n");
    abort();
}

int fuzz_within_half_step(double decoded, double value, const fuzz_signal *signal)
{
    const double magnitude = fabs(decoded) > fabs(value) ? fabs(decoded) : fabs(value);
    const double slack = 8.0 * DBL_EPSILON * (magnitude + fabs(signal->offset));
    return fabs(decoded - value) <= 0.5 * signal->scale + slack;
}
