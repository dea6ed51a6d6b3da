/* Processor-in-the-loop firmware for QEMU's mps2-an386: the generated CAN layer, controllers and
 * E2E runtime (the sources the SIL bench compiles) behind an SLCAN adapter on UART 0.
 *
 * SLCAN is the Lawicel serial protocol python-can speaks (interface "slcan"): one ASCII line a
 * frame, `tIIILDD..` (classic), `dIIILDD..`/`bIIIL..` (CAN FD, L a hex DLC code), `T`/`D`/`B`
 * with 8-digit extended ids, each ended by '\r'; adapter commands (O, C, L, S, Y, V, N, F, Z, …)
 * are answered '\r'. Every standard-id frame the bench sends goes to <prefix>_can_rx as a bus
 * frame would. The bench is the sample clock (lock-step with its plant): extended ids in
 * 0x1FFFFFxx, which no DBC frame of the design uses, carry the commands of the harness:
 *   TIME  (data: time_us, LE)  the receive time stamp of the frames that follow;
 *   TICK  (data: time_us, LE)  one sample: <prefix>_can_step, then every frame of <prefix>_can_tx,
 *                              then COMMAND frames (the commanded normal forces as the state holds
 *                              them, raw bytes) and SAMPLE (status, faults, safe state);
 *   RESET (data[0]: law)       <prefix>_can_init and clear the measurements; answered by READY,
 *                              COMMAND and SAMPLE;
 *   QUERY                      answered by COUNTERS (the layer's diagnostic counters) and
 *                              MEASURED (SysTick ticks of every entry point, stack high water);
 *   EXIT  (data[0]: status)    end the emulation with that exit status (semihosting).
 * Built with -DSMARTJOINT_PIL_XCP (bench/pil.py does when the image links the XCP slave), the
 * frames of SMARTJOINT_XCP_ID_MASTER go to smartjoint_xcp_rx, each answered by the slave's frames
 * and XCP_DONE; RESET also runs smartjoint_xcp_init, and TICK smartjoint_xcp_event after the
 * step, the event's DTOs following the layer's frames (docs/xcp.md).
 * Instructions are counted with SysTick under QEMU's -icount shift=0 (board.h); each entry point
 * is called from main's own frame, so the painted stack below main's stack pointer is what the
 * firmware itself used (the SLCAN helpers here are shallower; their buffers are static). */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "board.h"
#include "smartjoint_can.h"

#define PIL_ID_TIME 0x1FFFFF00u
#define PIL_ID_TICK 0x1FFFFF01u
#define PIL_ID_RESET 0x1FFFFF02u
#define PIL_ID_QUERY 0x1FFFFF03u
#define PIL_ID_EXIT 0x1FFFFF04u
#define PIL_ID_READY 0x1FFFFF10u
#define PIL_ID_SAMPLE 0x1FFFFF11u
#define PIL_ID_COUNTERS 0x1FFFFF12u
#define PIL_ID_MEASURED 0x1FFFFF13u
#define PIL_ID_XCP_DONE 0x1FFFFF14u
#define PIL_ID_COMMAND 0x1FFFFF20u /* + chunk index: 64 bytes of the command array each */

#define SLCAN_LINE 160u /* 'D', 8 id digits, DLC, 128 data digits, '\r' */

/* One entry point's measured time: calls, sum and largest of the SysTick ticks per call. */
typedef struct {
    uint32_t calls;
    uint32_t ticks;
    uint32_t largest;
} pil_timing;

#ifdef SMARTJOINT_PIL_XCP
#include "smartjoint_xcp.h"
#define state smartjoint_controller /* the slave's instance: the A2L's measurements point into it */
static smartjoint_xcp_state xcp;
#else
static smartjoint_can_state state;
#endif
static char line[SLCAN_LINE];
static uint8_t frame[64];
static uint8_t reply[64];
static pil_timing rx_timing, step_timing, tx_timing, empty_timing;

static const uint8_t fd_lengths[16] = {0u, 1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u, 12u, 16u, 20u, 24u, 32u, 48u, 64u};

static void record(pil_timing *timing, uint32_t start)
{
    uint32_t ticks = (sj_ticks() - start) & 0x00FFFFFFu;
    timing->calls += 1u;
    timing->ticks += ticks;
    if (ticks > timing->largest) {
        timing->largest = ticks;
    }
}

static int hex_value(char c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    return -1;
}

/* The value of `digits` hex digits at `text`, or -1 when one is not a hex digit. */
static int32_t hex_field(const char *text, unsigned int digits)
{
    uint32_t value = 0u;
    unsigned int k;
    for (k = 0u; k < digits; ++k) {
        int digit = hex_value(text[k]);
        if (digit < 0) {
            return -1;
        }
        value = (value << 4) | (uint32_t)digit;
    }
    return (int32_t)(value & 0x7FFFFFFFu);
}

static void put_hex(uint32_t value, unsigned int digits)
{
    static const char upper[] = "0123456789ABCDEF";
    while (digits > 0u) {
        --digits;
        sj_uart_putc(upper[(value >> (4u * digits)) & 0xFu]);
    }
}

/* One frame out as an SLCAN line: classic up to 8 bytes, CAN FD (DLC code) above. */
static void send_frame(uint32_t id, int extended, const uint8_t *data, uint8_t length)
{
    unsigned int code = length;
    unsigned int k;
    if (length > 8u) {
        for (code = 9u; code < 15u && fd_lengths[code] < length; ++code) {
        }
    }
    sj_uart_putc((char)(length > 8u ? (extended ? 'D' : 'd') : (extended ? 'T' : 't')));
    put_hex(id, extended ? 8u : 3u);
    put_hex(code, 1u);
    for (k = 0u; k < fd_lengths[code]; ++k) {
        put_hex(k < length ? data[k] : 0u, 2u);
    }
    sj_uart_putc('\r');
}

/* The next line up to '\r' into `line`; returns its length (an overlong line is cut). */
static unsigned int read_line(void)
{
    unsigned int n = 0u;
    for (;;) {
        char c = (char)sj_uart_getc();
        if (c == '\r') {
            line[n < SLCAN_LINE ? n : SLCAN_LINE - 1u] = '\0';
            return n < SLCAN_LINE ? n : SLCAN_LINE - 1u;
        }
        if (c != '\n' && n < SLCAN_LINE - 1u) {
            line[n++] = c;
        }
    }
}

/* Parses a frame line into `frame`; returns its length, or -1 when the line is not a frame. */
static int parse_frame(unsigned int n, uint32_t *id, int *extended)
{
    unsigned int digits, code, length, k;
    int32_t value;
    char kind = line[0];
    *extended = (kind == 'T' || kind == 'D' || kind == 'B');
    if (!*extended && kind != 't' && kind != 'd' && kind != 'b') {
        return -1;
    }
    digits = *extended ? 8u : 3u;
    if (n < digits + 2u || (value = hex_field(line + 1, digits)) < 0) {
        return -1;
    }
    *id = (uint32_t)value;
    if ((value = hex_field(line + 1 + digits, 1u)) < 0) {
        return -1;
    }
    code = (uint32_t)value;
    if ((kind == 't' || kind == 'T') && code > 8u) {
        return -1;
    }
    length = fd_lengths[code];
    if (n != digits + 2u + 2u * length) {
        return -1;
    }
    for (k = 0u; k < length; ++k) {
        if ((value = hex_field(line + digits + 2u + 2u * k, 2u)) < 0) {
            return -1;
        }
        frame[k] = (uint8_t)value;
    }
    return (int)length;
}

static void put_u32(uint8_t *at, uint32_t value)
{
    at[0] = (uint8_t)value;
    at[1] = (uint8_t)(value >> 8);
    at[2] = (uint8_t)(value >> 16);
    at[3] = (uint8_t)(value >> 24);
}

static uint32_t get_u32(const uint8_t *at, int length)
{
    return length < 4 ? 0u : (uint32_t)at[0] | (uint32_t)at[1] << 8 | (uint32_t)at[2] << 16 | (uint32_t)at[3] << 24;
}

/* After a sample: the commanded normal forces (raw, as the state holds them), then SAMPLE. */
static void send_sample(unsigned int status, unsigned int frames)
{
    const uint8_t *command = (const uint8_t *)state.command;
    size_t size = sizeof state.command, at;
    uint32_t chunk = 0u;
    for (at = 0u; at < size; at += 64u, ++chunk) {
        size_t part = size - at < 64u ? size - at : 64u;
        memcpy(reply, command + at, part);
        send_frame(PIL_ID_COMMAND + chunk, 1, reply, (uint8_t)part);
    }
    memset(reply, 0, 12u);
    put_u32(reply, (uint32_t)status);
    put_u32(reply + 4, (uint32_t)state.faults);
    reply[8] = (uint8_t)(state.safe != 0);
    reply[9] = (uint8_t)frames;
    reply[10] = (uint8_t)sizeof state.command[0];
    send_frame(PIL_ID_SAMPLE, 1, reply, 12u);
}

#ifdef SMARTJOINT_PIL_XCP
/* Every frame the XCP slave has to send; returns how many. */
static unsigned int send_xcp(void)
{
    uint8_t length = 0u;
    unsigned int sent = 0u;
    while (smartjoint_xcp_tx(&xcp, reply, &length)) {
        send_frame(SMARTJOINT_XCP_ID_SLAVE, 0, reply, length);
        ++sent;
    }
    return sent;
}
#endif

static void send_measurements(uintptr_t mark)
{
    const pil_timing *timings[4] = {&rx_timing, &step_timing, &tx_timing, &empty_timing};
    const uint32_t counters[8] = {state.rx_frames,  state.crc_errors, state.counter_errors,     state.length_errors,
                                  state.unknown_ids, state.timeouts,   state.implausible_frames, state.steps};
    unsigned int k;
    for (k = 0u; k < 8u; ++k) {
        put_u32(reply + 4u * k, counters[k]);
    }
    send_frame(PIL_ID_COUNTERS, 1, reply, 32u);
    for (k = 0u; k < 4u; ++k) {
        put_u32(reply + 12u * k, timings[k]->calls);
        put_u32(reply + 12u * k + 4u, timings[k]->ticks);
        put_u32(reply + 12u * k + 8u, timings[k]->largest);
    }
    put_u32(reply + 48, sj_stack_depth(mark));
    put_u32(reply + 52, sj_stack_size());
    put_u32(reply + 56, SJ_INSTRUCTIONS_PER_TICK);
    put_u32(reply + 60, (uint32_t)sizeof state);
    send_frame(PIL_ID_MEASURED, 1, reply, 64u);
}

int main(void)
{
    uintptr_t mark = sj_stack_pointer();
    uint32_t time_us = 0u, id = 0u, start;
    int extended = 0, length;
    uint8_t out_length = 0u;
    unsigned int status, frames;

    sj_ticks_start();
    (void)smartjoint_can_init(&state, SMARTJOINT_CAN_LAW_NONE);
    for (;;) {
        unsigned int n = read_line();
        if (n == 0u) {
            continue;
        }
        length = parse_frame(n, &id, &extended);
        if (length < 0) {
            sj_uart_putc(strchr("OCLSYVNFZWXMm", line[0]) != NULL ? '\r' : '\a');
            continue;
        }
        if (!extended) {
#ifdef SMARTJOINT_PIL_XCP
            if (id == SMARTJOINT_XCP_ID_MASTER) {
                smartjoint_xcp_rx(&xcp, frame, (uint8_t)length, time_us);
                (void)send_xcp();
                send_frame(PIL_ID_XCP_DONE, 1, reply, 0u);
                continue;
            }
#endif
            start = sj_ticks();
            (void)smartjoint_can_rx(&state, id, frame, (uint8_t)length, time_us);
            record(&rx_timing, start);
        } else if (id == PIL_ID_TIME) {
            time_us = get_u32(frame, length);
        } else if (id == PIL_ID_TICK) {
            time_us = get_u32(frame, length);
            start = sj_ticks();
            status = smartjoint_can_step(&state, time_us);
            record(&step_timing, start);
            for (frames = 0u;; ++frames) {
                int more;
                start = sj_ticks();
                more = smartjoint_can_tx(&state, &id, reply, &out_length);
                if (!more) {
                    break;
                }
                record(&tx_timing, start);
                send_frame(id, 0, reply, out_length);
            }
            start = sj_ticks();
            record(&empty_timing, start); /* the measurement's own overhead */
#ifdef SMARTJOINT_PIL_XCP
            smartjoint_xcp_event(&xcp, time_us);
            frames += send_xcp();
#endif
            send_sample(status, frames);
        } else if (id == PIL_ID_RESET) {
            memset(&rx_timing, 0, sizeof rx_timing);
            memset(&step_timing, 0, sizeof step_timing);
            memset(&tx_timing, 0, sizeof tx_timing);
            memset(&empty_timing, 0, sizeof empty_timing);
            reply[0] = (uint8_t)(smartjoint_can_init(&state, (smartjoint_can_law)(length > 0 ? frame[0] : 0u)) != 0);
#ifdef SMARTJOINT_PIL_XCP
            (void)smartjoint_xcp_init(&xcp, 0u); /* after the layer's init: it points the laws at the page */
#endif
            send_frame(PIL_ID_READY, 1, reply, 1u);
            send_sample(0u, 0u);
        } else if (id == PIL_ID_QUERY) {
            send_measurements(mark);
        } else if (id == PIL_ID_EXIT) {
            return length > 0 ? (int)frame[0] : 0;
        }
    }
}
