/* Shared pieces of the fuzz harnesses: reading typed values from libFuzzer's byte string, the
 * bus table that prepare.py writes from bus.dbc, a bit-wise reference of the DBC codec, and the
 * one way a harness reports a finding (a message, then abort()). */
#ifndef FUZZ_SUPPORT_H
#define FUZZ_SUPPORT_H

#include <stddef.h>
#include <stdint.h>

/* The fuzz input, consumed front to back; reads past the end give zero bytes. */
typedef struct {
    const uint8_t *data;
    size_t size;
    size_t used;
} fuzz_reader;

void fuzz_reader_init(fuzz_reader *reader, const uint8_t *data, size_t size);
int fuzz_more(const fuzz_reader *reader);
uint8_t fuzz_take_u8(fuzz_reader *reader);
uint16_t fuzz_take_u16(fuzz_reader *reader);
uint32_t fuzz_take_u32(fuzz_reader *reader);
void fuzz_take_bytes(fuzz_reader *reader, uint8_t *out, size_t count);
/* An arbitrary double: mostly its 8 raw bytes (any bit pattern), sometimes a special value
 * (NaN, infinities, extremes, denormals, zeros) so those are reached from the first run. */
double fuzz_take_double(fuzz_reader *reader);
/* The same for float, from 4 raw bytes. */
float fuzz_take_float(fuzz_reader *reader);

/* One signal of a frame, as the DBC defines it (little-endian integer field). */
typedef struct {
    const char *name;
    unsigned int start;
    unsigned int length;
    int is_signed;
    int has_range; /* both minimum and maximum given: the physical value is clamped to them */
    double scale;
    double offset;
    double minimum;
    double maximum;
} fuzz_signal;

typedef struct {
    const char *name;
    uint32_t id;
    unsigned int length;
    unsigned int count;
    const fuzz_signal *signals;
} fuzz_message;

const fuzz_message *fuzz_find_message(uint32_t id);
const fuzz_signal *fuzz_find_signal(const fuzz_message *message, const char *name);

/* Bit-wise reference codec (DBC "@1": bit k of a field is bit (start + k) mod 8 of byte
 * (start + k) / 8). Fields are returned as the unsigned raw bits. */
uint64_t fuzz_reference_field(const uint8_t *data, const fuzz_signal *signal);
double fuzz_reference_decode(uint64_t raw, const fuzz_signal *signal);
/* cantools' encoding: clamp to [minimum, maximum] when given, raw = round half to even of
 * (value - offset) / scale, NaN as 0, kept within the field; the raw bits of the field. */
uint64_t fuzz_reference_encode(double value, const fuzz_signal *signal);
double fuzz_raw_minimum(const fuzz_signal *signal);
/* Whether DECODED is VALUE quantised by SIGNAL: within half a scale step, plus the few ulps by
 * which raw * scale + offset misses the exact grid point in double (a value exactly halfway
 * between two raw steps decodes to either neighbour, a hair more than half a step away). */
int fuzz_within_half_step(double decoded, double value, const fuzz_signal *signal);
double fuzz_raw_maximum(const fuzz_signal *signal);

/* Reports a finding of HARNESS and aborts (libFuzzer keeps the input as a crash file). */
void fuzz_fail(const char *harness, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3), noreturn))
#endif
    ;

#endif /* FUZZ_SUPPORT_H */
