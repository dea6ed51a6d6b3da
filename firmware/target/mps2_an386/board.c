/* Board support for QEMU's mps2-an386; see board.h. Register layouts: the CMSDK APB UART
 * (ARM DDI 0479) and the ARMv7-M system control space (SysTick, CPACR). */
#include "board.h"

#define REG(address) (*(volatile uint32_t *)(address))

#define UART0_BASE 0x40004000u
#define UART_DATA REG(UART0_BASE + 0x000u)
#define UART_STATE REG(UART0_BASE + 0x004u) /* bit 0: TX buffer full, bit 1: RX buffer full */
#define UART_CTRL REG(UART0_BASE + 0x008u)  /* bit 0: TX enable, bit 1: RX enable */
#define UART_INTSTATUS REG(UART0_BASE + 0x00Cu) /* bit 1: RX interrupt; write 1 to clear */
#define UART_BAUDDIV REG(UART0_BASE + 0x010u)
#define UART_RX_INTERRUPT 2u
#define NVIC_ISER0 REG(0xE000E100u)
#define NVIC_ICPR0 REG(0xE000E280u)
#define UART0_RX_IRQ 0u /* mps2-an386: UART n's RX interrupt is IRQ 2n */
#define UART_TX_FULL 1u
#define UART_RX_FULL 2u

#define SYST_CSR REG(0xE000E010u) /* bit 0 enable, bit 2 processor clock */
#define SYST_RVR REG(0xE000E014u)
#define SYST_CVR REG(0xE000E018u)
#define SYST_MAX 0x00FFFFFFu

#define STACK_PATTERN 0xC5AC5AC5u

extern uint32_t __sj_stack_bottom[];
extern uint32_t __sj_stack_top[];

void sj_uart_init(void)
{
    UART_BAUDDIV = 16u; /* the smallest divider the UART accepts; the emulator ignores the rate */
    /* TX and RX enabled, and the RX interrupt: not to be taken (PRIMASK stays set, no handler),
     * only to wake sj_uart_getc from WFI, so a waiting target leaves the host's cores free. */
    UART_CTRL = 3u | (1u << 3);
    __asm__ volatile("cpsid i" ::: "memory");
    NVIC_ISER0 = 1u << UART0_RX_IRQ;
}

void sj_uart_putc(char c)
{
    while (UART_STATE & UART_TX_FULL) {
    }
    UART_DATA = (uint32_t)(unsigned char)c;
}

int sj_uart_getc(void)
{
    int c;
    while (!(UART_STATE & UART_RX_FULL)) {
        __asm__ volatile("wfi" ::: "memory"); /* wakes on the pending RX interrupt (masked) */
    }
    c = (int)(UART_DATA & 0xFFu);
    UART_INTSTATUS = UART_RX_INTERRUPT;
    NVIC_ICPR0 = 1u << UART0_RX_IRQ;
    return c;
}

void sj_uart_puts(const char *text)
{
    while (*text != '\0') {
        sj_uart_putc(*text++);
    }
}

void sj_uart_hex32(uint32_t value)
{
    static const char digits[] = "0123456789abcdef";
    int shift;
    for (shift = 28; shift >= 0; shift -= 4) {
        sj_uart_putc(digits[(value >> (unsigned int)shift) & 0xFu]);
    }
}

void sj_uart_dec(uint32_t value)
{
    char text[11];
    int n = 0;
    do {
        text[n++] = (char)('0' + (int)(value % 10u));
        value /= 10u;
    } while (value != 0u);
    while (n > 0) {
        sj_uart_putc(text[--n]);
    }
}

uint32_t sj_uart_get_u32(void)
{
    uint32_t value = 0u;
    unsigned int k;
    for (k = 0u; k < 4u; ++k) {
        value |= (uint32_t)sj_uart_getc() << (8u * k);
    }
    return value;
}

void sj_uart_put_u32(uint32_t value)
{
    unsigned int k;
    for (k = 0u; k < 4u; ++k) {
        sj_uart_putc((char)(value >> (8u * k)));
    }
}

void sj_ticks_start(void)
{
    SYST_CSR = 0u;
    SYST_RVR = SYST_MAX;
    SYST_CVR = 0u; /* any write clears the counter; it reloads on the next tick */
    SYST_CSR = 5u; /* enabled, processor clock, no interrupt */
}

uint32_t sj_ticks(void)
{
    return (SYST_MAX - SYST_CVR) & SYST_MAX;
}

uintptr_t sj_stack_pointer(void)
{
    uintptr_t sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    return sp;
}

void sj_stack_paint(void)
{
    /* Below this function's own frame, with a margin for the words the loop itself pushes. */
    volatile uint32_t *word = __sj_stack_bottom;
    uintptr_t end = sj_stack_pointer() - 64u;
    while ((uintptr_t)word < end) {
        *word++ = STACK_PATTERN;
    }
}

uint32_t sj_stack_depth(uintptr_t mark)
{
    const volatile uint32_t *word = __sj_stack_bottom;
    while ((uintptr_t)word < mark && *word == STACK_PATTERN) {
        ++word;
    }
    return (uint32_t)(mark - (uintptr_t)word);
}

uint32_t sj_stack_size(void)
{
    return (uint32_t)((uintptr_t)__sj_stack_top - (uintptr_t)__sj_stack_bottom);
}

uintptr_t sj_stack_top(void)
{
    return (uintptr_t)__sj_stack_top;
}

void sj_exit(int code)
{
    /* SYS_EXIT_EXTENDED (0x20) with the block {ADP_Stopped_ApplicationExit, code}: the
     * emulator ends with `code` as its exit status (plain SYS_EXIT on 32-bit Arm cannot carry it). */
    volatile uint32_t block[2];
    block[0] = 0x20026u;
    block[1] = (uint32_t)code;
    {
        register uint32_t r0 __asm__("r0") = 0x20u;
        register volatile uint32_t *r1 __asm__("r1") = block;
        __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    }
    for (;;) {
    }
}
