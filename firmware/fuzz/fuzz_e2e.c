/* Fuzz harness 3: the E2E protection of firmware/runtime/sj_e2e.c against a bit-wise reference.
 *
 * The reference is written from the protocol's definition, not from the runtime: CRC-8 SAE
 * J1850 (polynomial 0x1D, initial value 0xFF, final XOR 0xFF, MSB first, one bit at a time)
 * over the two identifier bytes (low first), the implicit freshness byte (bits 4..11 of the
 * frame's controller cycle, not sent) and payload bytes 1..n-1, stored in byte 0; the alive
 * counter in the low nibble of byte 1; the receiver accepts a counter 1..3 ahead of the last
 * accepted one, rejects a repeat (0 ahead) and a late frame (8..15 ahead) without following it,
 * and rejects but re-synchronises on a jump (4..7 ahead).
 *
 * Input: a sequence of frames (identifier, length, expected length, payload, the freshness byte
 * of the sender and that of the receiver; optionally protected with a counter first), each
 * checked by the runtime and by the reference with their own receiver memory; the results, the
 * receivers, the CRC and the protected bytes must agree on every input. Besides, per frame: a
 * copy protected with one freshness byte passes a fresh receiver's check with the same byte and
 * fails it with any other (a one-byte difference is a burst a CRC-8 always detects: the replay
 * or hold-back of a frame by 16..4095 cycles), and SJ_E2E_FRESHNESS is bits 4..11 of a cycle. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_support.h"
#include "sj_e2e.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static uint8_t reference_crc8(const uint8_t *bytes, size_t count, uint8_t crc)
{
    size_t k;
    int bit;
    for (k = 0u; k < count; ++k) {
        crc = (uint8_t)(crc ^ bytes[k]);
        for (bit = 0; bit < 8; ++bit) {
            crc = (crc & 0x80u) ? (uint8_t)((uint8_t)(crc << 1) ^ 0x1Du) : (uint8_t)(crc << 1);
        }
    }
    return crc;
}

static uint8_t reference_frame_crc(uint16_t id, const uint8_t *payload, size_t length, uint8_t fresh)
{
    uint8_t crc = 0xFFu;
    const uint8_t id_bytes[2] = {(uint8_t)(id % 256u), (uint8_t)(id / 256u)};
    crc = reference_crc8(id_bytes, 2u, crc);
    crc = reference_crc8(&fresh, 1u, crc);
    if (length > 1u) {
        crc = reference_crc8(payload + 1, length - 1u, crc);
    }
    return (uint8_t)(crc ^ 0xFFu);
}

typedef struct {
    int valid;
    unsigned int last;
} reference_receiver;

static unsigned int reference_check(reference_receiver *receiver, uint16_t id, const uint8_t *payload, size_t length,
                                    size_t expected, uint8_t fresh)
{
    unsigned int counter, ahead;
    if (length != expected || length < 2u) {
        return SJ_E2E_WRONG_LENGTH;
    }
    if (payload[0] != reference_frame_crc(id, payload, length, fresh)) {
        return SJ_E2E_BAD_CRC;
    }
    counter = payload[1] % 16u;
    if (!receiver->valid) {
        receiver->valid = 1;
        receiver->last = counter;
        return SJ_E2E_OK;
    }
    ahead = (counter + 16u - receiver->last) % 16u;
    if (ahead == 0u) {
        return SJ_E2E_COUNTER_REPEATED;
    }
    if (ahead >= 8u) {
        return SJ_E2E_COUNTER_STALE;
    }
    receiver->last = counter;
    return ahead <= 3u ? SJ_E2E_OK : SJ_E2E_COUNTER_JUMP;
}

#define MAX_PAYLOAD 72u

static void protect_and_compare(fuzz_reader *reader, uint16_t id, uint8_t *payload, size_t length, uint8_t fresh)
{
    uint8_t expected[MAX_PAYLOAD];
    const uint8_t counter = fuzz_take_u8(reader);
    memcpy(expected, payload, length);
    if (length >= 2u) {
        expected[1] = (uint8_t)((expected[1] / 16u) * 16u + counter % 16u);
        expected[0] = reference_frame_crc(id, expected, length, fresh);
    }
    sj_e2e_protect(id, payload, length, counter, fresh);
    if (memcmp(expected, payload, length) != 0) {
        fuzz_fail("e2e", "sj_e2e_protect(id 0x%x, length %zu, counter %u, freshness 0x%02x) differs from the reference",
                  id, length, counter, fresh);
    }
}

/* The freshness guarantee: a copy of the frame protected with freshness F passes a fresh
 * receiver's check with F and fails it with every other byte G (a replayed or held-back frame). */
static void check_freshness(fuzz_reader *reader, uint16_t id, const uint8_t *payload, size_t length, uint8_t fresh)
{
    uint8_t copy[MAX_PAYLOAD];
    const uint8_t counter = fuzz_take_u8(reader);
    const uint8_t other = (uint8_t)(fresh + 1u + fuzz_take_u8(reader) % 255u); /* any byte but F */
    sj_e2e_receiver receiver = {0u, 0u};
    unsigned int result;
    if (length < 2u) {
        return;
    }
    memcpy(copy, payload, length);
    sj_e2e_protect(id, copy, length, counter, fresh);
    result = sj_e2e_check(&receiver, id, copy, length, length, fresh);
    if (result != SJ_E2E_OK) {
        fuzz_fail("e2e", "a frame protected with freshness 0x%02x (id 0x%x, length %zu) fails the check with the same "
                         "byte: result %u", fresh, id, length, result);
    }
    receiver.valid = 0u;
    result = sj_e2e_check(&receiver, id, copy, length, length, other);
    if (result != SJ_E2E_BAD_CRC || receiver.valid != 0u) {
        fuzz_fail("e2e", "a frame protected with freshness 0x%02x (id 0x%x, length %zu) checked with 0x%02x: result %u "
                         "(expected a bad CRC), receiver valid %u", fresh, id, length, other, result, receiver.valid);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader reader;
    sj_e2e_receiver receiver = {0u, 0u};
    reference_receiver reference = {0, 0u};
    fuzz_reader_init(&reader, data, size);
    {
        /* The CRC primitive alone, any bytes and any start value. */
        uint8_t bytes[16];
        const uint8_t start = fuzz_take_u8(&reader);
        const size_t count = fuzz_take_u8(&reader) % (sizeof bytes + 1u);
        fuzz_take_bytes(&reader, bytes, count);
        if (sj_crc8_j1850(bytes, count, start) != reference_crc8(bytes, count, start)) {
            fuzz_fail("e2e", "sj_crc8_j1850 of %zu bytes from 0x%02x differs from the reference", count, start);
        }
    }
    {
        /* The freshness byte of a cycle: its bits 4..11. */
        const uint32_t cycle = fuzz_take_u32(&reader);
        if (SJ_E2E_FRESHNESS(cycle) != (uint8_t)((cycle / 16u) % 256u)) {
            fuzz_fail("e2e", "SJ_E2E_FRESHNESS(0x%08x) = 0x%02x, not bits 4..11", (unsigned int)cycle,
                      (unsigned int)SJ_E2E_FRESHNESS(cycle));
        }
    }
    while (fuzz_more(&reader)) {
        const uint8_t control = fuzz_take_u8(&reader);
        const uint16_t frame_id = (control & 1u) ? fuzz_take_u16(&reader) : (uint16_t)0x100u;
        const size_t length = fuzz_take_u8(&reader) % (MAX_PAYLOAD + 1u);
        const size_t expected = (control & 2u) ? length : (size_t)(fuzz_take_u8(&reader) % (MAX_PAYLOAD + 1u));
        /* the sender's freshness byte, and the receiver's: mostly the same, else any */
        const uint8_t fresh = fuzz_take_u8(&reader);
        const uint8_t expected_fresh = (control & 8u) ? fuzz_take_u8(&reader) : fresh;
        uint8_t *payload = malloc(length); /* exactly the frame: any read beyond it is caught */
        unsigned int result, reference_result;
        if (payload == NULL && length > 0u) {
            abort();
        }
        fuzz_take_bytes(&reader, payload, length);
        if (control & 4u) {
            protect_and_compare(&reader, frame_id, payload, length, fresh);
        }
        if (control & 16u) {
            check_freshness(&reader, frame_id, payload, length, fresh);
        }
        if (payload != NULL && sj_e2e_frame_crc(frame_id, payload, length, expected_fresh) !=
                                   reference_frame_crc(frame_id, payload, length, expected_fresh)) {
            fuzz_fail("e2e", "sj_e2e_frame_crc(id 0x%x, length %zu, freshness 0x%02x) differs from the reference",
                      frame_id, length, expected_fresh);
        }
        result = sj_e2e_check(&receiver, frame_id, payload, length, expected, expected_fresh);
        reference_result = reference_check(&reference, frame_id, payload, length, expected, expected_fresh);
        if (result != reference_result) {
            fuzz_fail("e2e", "sj_e2e_check(id 0x%x, length %zu of %zu, freshness 0x%02x, sent with 0x%02x): result %u, "
                             "reference %u", frame_id, length, expected, expected_fresh, fresh, result,
                      reference_result);
        }
        if ((receiver.valid != 0u) != (reference.valid != 0) || (reference.valid && receiver.last_counter != reference.last)) {
            fuzz_fail("e2e", "receiver after id 0x%x: valid %u counter %u, reference valid %d counter %u", frame_id,
                      receiver.valid, receiver.last_counter, reference.valid, reference.last);
        }
        free(payload);
    }
    return 0;
}
