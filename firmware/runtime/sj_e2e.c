/* CRC-8 SAE J1850 and alive counter, see sj_e2e.h (with the implicit freshness byte). */
#include "sj_e2e.h"

/* Polynomial 0x1D, MSB first, four bits at a time: the CRC of each nibble n (n << 4 shifted
 * through four steps). Half-byte tables cost 16 bytes of flash instead of 256 for a byte table,
 * at two lookups a byte (AUTOSAR's Crc library offers both; the product image's flash is the
 * scarcer resource). */
static const uint8_t crc_nibbles[16] = {
    0x00u, 0x1Du, 0x3Au, 0x27u, 0x74u, 0x69u, 0x4Eu, 0x53u,
    0xE8u, 0xF5u, 0xD2u, 0xCFu, 0x9Cu, 0x81u, 0xA6u, 0xBBu,
};

uint8_t sj_crc8_j1850(const uint8_t *data, size_t length, uint8_t crc)
{
    size_t k;
    for (k = 0; k < length; ++k) {
        crc = (uint8_t)(crc ^ data[k]);
        crc = (uint8_t)((uint8_t)(crc << 4) ^ crc_nibbles[crc >> 4]);
        crc = (uint8_t)((uint8_t)(crc << 4) ^ crc_nibbles[crc >> 4]);
    }
    return crc;
}

uint8_t sj_e2e_frame_crc(uint16_t frame_id, const uint8_t *payload, size_t length, uint8_t freshness)
{
    /* The data ID and the freshness byte: a frame under another identifier, or of a cycle 16 to
     * 4095 cycles away, fails (a one-byte difference is a burst a CRC-8 always detects). */
    const uint8_t implicit[3] = {(uint8_t)(frame_id & 0xFFu), (uint8_t)(frame_id >> 8), freshness};
    uint8_t crc = sj_crc8_j1850(implicit, 3u, 0xFFu);
    if (length > 1u) {
        crc = sj_crc8_j1850(payload + 1, length - 1u, crc);
    }
    return (uint8_t)(crc ^ 0xFFu);
}

void sj_e2e_protect(uint16_t frame_id, uint8_t *payload, size_t length, uint8_t counter, uint8_t freshness)
{
    if (payload == NULL || length < 2u) {
        return;
    }
    payload[1] = (uint8_t)((payload[1] & 0xF0u) | (counter % SJ_E2E_COUNTER_MODULO));
    payload[0] = sj_e2e_frame_crc(frame_id, payload, length, freshness);
}

unsigned int sj_e2e_check(sj_e2e_receiver *receiver, uint16_t frame_id, const uint8_t *payload, size_t length,
                          size_t expected_length, uint8_t freshness)
{
    unsigned int result = SJ_E2E_OK;
    uint8_t counter;
    if (receiver == NULL || payload == NULL || length != expected_length || length < 2u) {
        return SJ_E2E_WRONG_LENGTH;
    }
    if (payload[0] != sj_e2e_frame_crc(frame_id, payload, length, freshness)) {
        return SJ_E2E_BAD_CRC;
    }
    counter = (uint8_t)(payload[1] & 0x0Fu);
    if (receiver->valid) {
        const uint8_t step = (uint8_t)((uint8_t)(counter - receiver->last_counter) % SJ_E2E_COUNTER_MODULO);
        if (step == 0u) {
            return SJ_E2E_COUNTER_REPEATED;
        }
        if (step >= SJ_E2E_COUNTER_MODULO / 2u) {
            return SJ_E2E_COUNTER_STALE;
        }
        if (step > SJ_E2E_MAX_COUNTER_STEP) {
            result = SJ_E2E_COUNTER_JUMP; /* the frame is rejected; the sequence restarts here */
        }
    }
    receiver->last_counter = counter;
    receiver->valid = 1u;
    return result;
}
