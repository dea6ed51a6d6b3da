/* Board support for QEMU's mps2-an386 (Cortex-M4F): CMSDK UART 0 (polled), SysTick as an
 * instruction counter under `-icount shift=0`, stack painting and semihosting exit. */
#ifndef SJ_BOARD_H
#define SJ_BOARD_H

#include <stdint.h>

/* UART 0 of the board (CMSDK APB UART at 0x40004000), polled, no interrupts. */
void sj_uart_init(void);
void sj_uart_putc(char c);
int sj_uart_getc(void); /* the next received byte, waiting for it */
void sj_uart_puts(const char *text);
void sj_uart_hex32(uint32_t value); /* eight lower-case hex digits */
void sj_uart_dec(uint32_t value);
uint32_t sj_uart_get_u32(void);      /* four received bytes, little-endian */
void sj_uart_put_u32(uint32_t value); /* four bytes, little-endian */

/* SysTick on the processor clock (the board's 25 MHz SYSCLK), counting down from 2^24 - 1. With
 * QEMU's `-icount shift=0` one instruction is 1 ns of virtual time, so one tick is
 * SJ_INSTRUCTIONS_PER_TICK instructions. */
#define SJ_INSTRUCTIONS_PER_TICK 40u
void sj_ticks_start(void);
uint32_t sj_ticks(void); /* ticks since sj_ticks_start (wraps after 2^24) */

/* Stack painting: sj_stack_paint fills the stack below the caller's frame with a pattern;
 * sj_stack_depth gives how far below `mark` (an address in the caller's frame) it was used. */
uintptr_t sj_stack_pointer(void);
void sj_stack_paint(void);
uint32_t sj_stack_depth(uintptr_t mark);
uint32_t sj_stack_size(void);
uintptr_t sj_stack_top(void);

/* Ends the emulation through semihosting (SYS_EXIT_EXTENDED) with `code` as QEMU's exit status. */
void sj_exit(int code);

#endif /* SJ_BOARD_H */
