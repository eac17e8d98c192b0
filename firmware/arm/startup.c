/* Minimal Cortex-M4F start-up for the firmware's unit tests on qemu-system-arm -M mps2-an386 (semihosting):
 * the vector table, the FPU enabled, then newlib's rdimon crt0 (_start: semihosting heap/stack, main, exit
 * with main's code). SysTick runs at the core clock: under qemu -icount shift=0 one instruction is 1 ns
 * of virtual time, and the AN386's 25 MHz core clock turns that into one SysTick count per 40 instructions. */
#include <stdint.h>

extern void _start(void);
extern uint32_t __stack_top;

#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

void reset_handler(void);
void reset_handler(void)
{
    SCB_CPACR |= (0xFu << 20); /* CP10, CP11: full access (the FPU) */
    __asm volatile("dsb\n\tisb");
    SYST_RVR = 0x00FFFFFFu; /* free-running 24-bit down-counter, core clock, no interrupt */
    SYST_CVR = 0;
    SYST_CSR = 0x5u;
    _start();
    for (;;) {
    }
}

static void fault_handler(void)
{
    for (;;) {
    }
}

unsigned long cost_ticks(void);
unsigned long cost_ticks_per_unit(void);
unsigned long cost_ticks(void) { return SYST_CVR; }
/* instructions per SysTick count, measured on a loop of 2 x 50000 instructions (subs, bne) */
unsigned long cost_ticks_per_unit(void)
{
    uint32_t n = 50000u, t0, t1;
    t0 = SYST_CVR;
    __asm volatile("1: subs %0, %0, #1\n\t bne 1b" : "+r"(n) : : "cc");
    t1 = SYST_CVR;
    return t0 > t1 ? (100000u + (t0 - t1) / 2u) / (t0 - t1) : 0u;
}

__attribute__((section(".isr_vector"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(&__stack_top), reset_handler, fault_handler, fault_handler, fault_handler, fault_handler,
    fault_handler, 0, 0, 0, 0, fault_handler, fault_handler, 0, fault_handler, fault_handler,
};
