/* End-to-end protection of CAN frames: CRC-8 SAE J1850 and a 4-bit alive counter.
 * With an implicit freshness byte. The C twin of bench/e2e.py (same layout, same vectors):
 * byte 0 holds the CRC over the two identifier bytes (low first), the freshness byte (bits 4-11 of the controller cycle
 * the frame belongs to; not sent: both ends know it) and payload bytes 1..n-1; the low nibble of
 * byte 1 holds the alive counter. Hand-written runtime, C99, no heap, no global mutable state. */
#ifndef SJ_E2E_H
#define SJ_E2E_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define SJ_E2E_COUNTER_MODULO 16u
#define SJ_E2E_MAX_COUNTER_STEP 3u /* accept up to two lost frames in between */

/* Result bits of sj_e2e_check. */
#define SJ_E2E_OK 0u
#define SJ_E2E_WRONG_LENGTH 1u
#define SJ_E2E_BAD_CRC 2u
#define SJ_E2E_COUNTER_REPEATED 4u
#define SJ_E2E_COUNTER_JUMP 8u   /* 4..7 ahead: frames lost; re-synchronises on this counter */
#define SJ_E2E_COUNTER_STALE 32u /* 8..15 ahead, i.e. behind: a late frame; no re-synchronisation */

/* Receiver memory of one frame identifier. */
typedef struct {
    uint8_t last_counter;
    uint8_t valid; /* 0 until a frame was accepted */
} sj_e2e_receiver;

uint8_t sj_crc8_j1850(const uint8_t *data, size_t length, uint8_t crc);
uint8_t sj_e2e_frame_crc(uint16_t frame_id, const uint8_t *payload, size_t length, uint8_t freshness);
/* Writes counter (mod 16) into byte 1 and the CRC into byte 0; length >= 2. */
void sj_e2e_protect(uint16_t frame_id, uint8_t *payload, size_t length, uint8_t counter, uint8_t freshness);
/* Checks a received frame of the expected length against the freshness byte the receiver expects.
 * The receiver follows every frame except a repeat or a stale one, so a late frame cannot make the
 * next genuine frame fail. */
unsigned int sj_e2e_check(sj_e2e_receiver *receiver, uint16_t frame_id, const uint8_t *payload, size_t length,
                          size_t expected_length, uint8_t freshness);
/* The freshness byte of a frame of the frame's cycle: bits 4..11 (the counter carries bits 0..3). */
#define SJ_E2E_FRESHNESS(cycle) ((uint8_t)(((cycle) >> 4) & 0xFFu))

#ifdef __cplusplus
}
#endif

#endif /* SJ_E2E_H */
