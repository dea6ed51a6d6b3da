/* Reset and vector table for QEMU's mps2-an386 (Cortex-M4F), in C: the table is a struct placed
 * in .vectors (linker script mps2_an386.ld), the reset handler copies .data, clears .bss, enables
 * the FPU, paints the stack and runs main; its return value ends the emulation (semihosting). */
#include <stdint.h>

#include "board.h"

extern uint32_t __sj_stack_top[];
extern uint32_t __sj_data_start[];
extern uint32_t __sj_data_end[];
extern uint32_t __sj_data_load[];
extern uint32_t __sj_bss_start[];
extern uint32_t __sj_bss_end[];

int main(void);
void sj_reset_handler(void);
void sj_fault_handler(void);

#define CPACR (*(volatile uint32_t *)0xE000ED88u)

typedef void (*sj_handler)(void);

typedef struct {
    uint32_t *initial_stack;
    sj_handler handlers[15]; /* reset, NMI, HardFault, MemManage, BusFault, UsageFault, 4 reserved,
                                SVCall, DebugMonitor, reserved, PendSV, SysTick */
} sj_vector_table;

__attribute__((section(".vectors"), used)) const sj_vector_table sj_vectors = {
    __sj_stack_top,
    {sj_reset_handler, sj_fault_handler, sj_fault_handler, sj_fault_handler, sj_fault_handler, sj_fault_handler, 0, 0,
     0, 0, sj_fault_handler, sj_fault_handler, 0, sj_fault_handler, sj_fault_handler},
};

void sj_fault_handler(void)
{
    sj_uart_puts("\nFAULT\n");
    sj_exit(3);
}

void sj_reset_handler(void)
{
    /* Volatile stores keep the copy and clear loops loops: the compiler would otherwise call
     * newlib's memcpy, 308 B of flash for a .data section that is empty. */
    const uint32_t *from = __sj_data_load;
    volatile uint32_t *to = __sj_data_start;
    while (to < __sj_data_end) {
        *to++ = *from++;
    }
    for (to = __sj_bss_start; to < __sj_bss_end; ++to) {
        *to = 0u;
    }
    CPACR |= 0xFu << 20; /* CP10 and CP11 (the FPU): full access */
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    sj_stack_paint();
    sj_uart_init();
    sj_exit(main());
}
