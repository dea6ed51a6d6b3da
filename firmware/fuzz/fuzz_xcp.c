/* Fuzz harness 6: the XCP slave of firmware/generated (smartjoint_xcp.c) driven as any master
 * could drive it, against what docs/xcp.md promises and the A2L states (prepare.py's
 * fuzz_xcp_reference.h, not the slave's own tables):
 * - whatever arrives, every value of the working page stays within its A2L limits, and each
 *   law's F_N^min + range within the joint's F_N^max;
 * - a command never writes the controller's state, and the page changes only through a DOWNLOAD
 *   accepted while CAL/PAG is unlocked and the controller runs (not in the safe state);
 * - every answer is one frame of a valid CAN FD length starting with RES (0xFF) or ERR (0xFE)
 *   with a standard error code; every DTO names an allocated ODT and fits 64 bytes.
 *
 * Input: a sequence of operations (one byte each, then their arguments): a raw frame; SET_MTA to
 * the page plus a whole value; a DOWNLOAD of up to 15 floats; GET_SEED and UNLOCK of both
 * resources with the right key (the harness knows the artefact's key function); an event;
 * the controller's safe state on or off; CONNECT; a DAQ list over the controller's state. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_support.h"
#include "fuzz_xcp_reference.h"
#include "smartjoint_xcp.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static smartjoint_xcp_state xcp;
static const uint32_t PAGE = 0x1000u; /* the working page's XCP address: base is page - PAGE */
static const uint8_t fd_lengths[16] = {0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u, 12u, 16u, 20u, 24u, 32u, 48u, 64u};

static int valid_length(uint8_t length)
{
    unsigned int k;
    for (k = 1u; k < 16u; ++k) {
        if (fd_lengths[k] == length) {
            return 1;
        }
    }
    return 0;
}

static int standard_error(uint8_t code)
{
    static const uint8_t codes[] = {0x00u, 0x10u, 0x11u, 0x12u, 0x20u, 0x21u, 0x22u, 0x23u, 0x24u,
                                    0x25u, 0x26u, 0x27u, 0x28u, 0x29u, 0x2Au, 0x30u, 0x31u, 0x32u, 0x33u};
    unsigned int k;
    for (k = 0u; k < sizeof codes; ++k) {
        if (codes[k] == code) {
            return 1;
        }
    }
    return 0;
}

static void check_page(void)
{
    float values[XCP_VALUES];
    unsigned int k;
    if (sizeof smartjoint_calibration_working != sizeof values) {
        fuzz_fail("xcp", "the page holds %u bytes, the A2L %u values", (unsigned int)sizeof smartjoint_calibration_working,
                  (unsigned int)XCP_VALUES);
    }
    memcpy(values, &smartjoint_calibration_working, sizeof values);
    for (k = 0u; k < XCP_VALUES; ++k) {
        if (!((double)values[k] >= xcp_lower[k] && (double)values[k] <= xcp_upper[k])) {
            fuzz_fail("xcp", "page value %u = %g outside its A2L limits [%g, %g]", k, (double)values[k], xcp_lower[k],
                      xcp_upper[k]);
        }
    }
    for (k = 0u; k < XCP_PAIRS; ++k) {
        const float sum = values[xcp_pairs[k][0]] + values[xcp_pairs[k][1]];
        if (!((double)sum <= xcp_sum_limit[k])) {
            fuzz_fail("xcp", "F_N^min + range = %g above F_N^max %g (pair %u)", (double)sum, xcp_sum_limit[k], k);
        }
    }
}

/* One frame to the slave, then every frame it sends: the answer checked, DTOs checked. */
static void exchange(const uint8_t *frame, uint8_t length, uint32_t time_us)
{
    static smartjoint_can_state before;
    static smartjoint_calibration page;
    uint8_t out[64];
    uint8_t out_length = 0u;
    const int locked = (xcp.locked & 0x01u) != 0u;
    const int safe = smartjoint_controller.safe != 0;
    memcpy(&before, &smartjoint_controller, sizeof before);
    memcpy(&page, &smartjoint_calibration_working, sizeof page);
    smartjoint_xcp_rx(&xcp, frame, length, time_us);
    if (memcmp(&before, &smartjoint_controller, sizeof before) != 0) {
        fuzz_fail("xcp", "command 0x%02X wrote the controller's state", length > 0u ? frame[0] : 0u);
    }
    if ((locked || safe || length == 0u || frame[0] != 0xF0u) &&
        memcmp(&page, &smartjoint_calibration_working, sizeof page) != 0) {
        fuzz_fail("xcp", "the page changed (command 0x%02X, locked %d, safe %d)", length > 0u ? frame[0] : 0u, locked,
                  safe);
    }
    check_page();
    while (smartjoint_xcp_tx(&xcp, out, &out_length)) {
        if (!valid_length(out_length)) {
            fuzz_fail("xcp", "a frame of %u bytes", out_length);
        }
        if (out[0] == 0xFEu && !standard_error(out[1])) {
            fuzz_fail("xcp", "error code 0x%02X", out[1]);
        }
        if (out[0] != 0xFFu && out[0] != 0xFEu && out[0] >= xcp.daq.odts) {
            fuzz_fail("xcp", "packet 0x%02X: neither an answer nor an allocated ODT's DTO", out[0]);
        }
    }
}

static void put_dword(uint8_t *p, uint32_t value)
{
    p[0] = (uint8_t)value;
    p[1] = (uint8_t)(value >> 8);
    p[2] = (uint8_t)(value >> 16);
    p[3] = (uint8_t)(value >> 24);
}

static void unlock(uint8_t resource, uint32_t time_us)
{
    uint8_t frame[10] = {0xF8u, 0u, resource};
    uint8_t out[64];
    uint8_t length = 0u;
    smartjoint_xcp_rx(&xcp, frame, 3u, time_us);
    if (!smartjoint_xcp_tx(&xcp, out, &length) || out[0] != 0xFFu || out[1] != 8u) {
        return; /* not connected, or already unlocked */
    }
    frame[0] = 0xF7u;
    frame[1] = 8u;
    smartjoint_xcp_key(&out[2], &frame[2]);
    exchange(frame, 10u, time_us);
}

/* A DAQ list of up to 4 ODTs over the controller's state (entries of 1..8 bytes). */
static void daq_list(fuzz_reader *in, uint32_t controller, uint32_t time_us)
{
    uint8_t frame[8];
    const uint8_t odts = (uint8_t)(1u + fuzz_take_u8(in) % 4u);
    uint8_t odt, k;
    static const uint8_t free_daq[1] = {0xD6u};
    const uint8_t alloc_daq[4] = {0xD5u, 0u, 1u, 0u};
    const uint8_t alloc_odt[5] = {0xD4u, 0u, 0u, 0u, odts};
    exchange(free_daq, 1u, time_us);
    exchange(alloc_daq, 4u, time_us);
    exchange(alloc_odt, 5u, time_us);
    for (odt = 0u; odt < odts; ++odt) {
        const uint8_t entries = (uint8_t)(1u + fuzz_take_u8(in) % 6u);
        const uint8_t alloc_entries[6] = {0xD3u, 0u, 0u, 0u, odt, entries};
        const uint8_t pointer[6] = {0xE2u, 0u, 0u, 0u, odt, 0u};
        exchange(alloc_entries, 6u, time_us);
        exchange(pointer, 6u, time_us);
        for (k = 0u; k < entries; ++k) {
            frame[0] = 0xE1u;
            frame[1] = 0xFFu;
            frame[2] = (uint8_t)(1u + fuzz_take_u8(in) % 8u);
            frame[3] = 0u;
            put_dword(&frame[4], controller + fuzz_take_u8(in));
            exchange(frame, 8u, time_us);
        }
    }
    {
        const uint8_t mode[8] = {0xE0u, 0x10u, 0u, 0u, 0u, 0u, 1u, 0u};
        const uint8_t start[4] = {0xDEu, 1u, 0u, 0u};
        exchange(mode, 8u, time_us);
        exchange(start, 4u, time_us);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_reader in;
    uint8_t frame[64];
    uint32_t time_us = 0u;
    uint32_t mta_value = 0u;
    const uintptr_t base = (uintptr_t)&smartjoint_calibration_working - PAGE;
    const uint32_t controller = (uint32_t)((uintptr_t)&smartjoint_controller - base);
    fuzz_reader_init(&in, data, size);
    memset(&smartjoint_controller, 0, sizeof smartjoint_controller);
    (void)smartjoint_xcp_init(&xcp, base);
    check_page();
    while (fuzz_more(&in)) {
        const uint8_t op = fuzz_take_u8(&in) % 9u;
        uint8_t length;
        time_us += 1000u;
        switch (op) {
        case 0: /* a raw frame */
            length = (uint8_t)(fuzz_take_u8(&in) % 65u);
            fuzz_take_bytes(&in, frame, length);
            exchange(frame, length, time_us);
            break;
        case 1: /* SET_MTA to a whole value of the page, or just past it */
            mta_value = fuzz_take_u8(&in) % (XCP_VALUES + 2u);
            frame[0] = 0xF6u;
            frame[1] = 0u;
            frame[2] = 0u;
            frame[3] = 0u;
            put_dword(&frame[4], PAGE + 4u * mta_value);
            exchange(frame, 8u, time_us);
            break;
        case 2: { /* DOWNLOAD of whole floats at the MTA */
            const uint8_t count = (uint8_t)(1u + fuzz_take_u8(&in) % 15u);
            uint8_t k;
            frame[0] = 0xF0u;
            frame[1] = (uint8_t)(4u * count);
            for (k = 0u; k < count; ++k) {
                const float value = fuzz_take_float(&in);
                memcpy(&frame[2u + 4u * k], &value, 4u);
            }
            exchange(frame, (uint8_t)(2u + 4u * count), time_us);
            break;
        }
        case 3:
            unlock(0x01u, time_us);
            unlock(0x04u, time_us);
            break;
        case 4: { /* the sample boundary: the event and its DTOs */
            uint8_t out[64];
            uint8_t out_length = 0u;
            smartjoint_xcp_event(&xcp, time_us);
            while (smartjoint_xcp_tx(&xcp, out, &out_length)) {
                if (!valid_length(out_length) || (out[0] < 0xFEu && out[0] >= xcp.daq.odts)) {
                    fuzz_fail("xcp", "DTO 0x%02X of %u bytes", out[0], out_length);
                }
            }
            break;
        }
        case 5:
            smartjoint_controller.safe = !smartjoint_controller.safe;
            break;
        case 6: {
            static const uint8_t connect[2] = {0xFFu, 0u};
            exchange(connect, 2u, time_us);
            break;
        }
        case 7:
            daq_list(&in, controller, time_us);
            break;
        default: { /* SET_CAL_PAGE / GET_CAL_PAGE with any mode and page */
            const uint8_t cal[4] = {(uint8_t)(0xEAu + (fuzz_take_u8(&in) & 1u)), fuzz_take_u8(&in), 0u,
                                    (uint8_t)(fuzz_take_u8(&in) % 3u)};
            exchange(cal, 4u, time_us);
            break;
        }
        }
    }
    return 0;
}
