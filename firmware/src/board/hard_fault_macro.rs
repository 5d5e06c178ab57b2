//! The HardFault entry both boards use, instead of cortex-m-rt's trampoline: it moves the stack
//! pointer back to the top of the stack (`_stack_start`) before any Rust code runs, then
//! branches to the board's handler with the faulting stack pointer in r0.
//!
//! Why: with flip-link (the STM32G474 build) the stack sits at the bottom of RAM, so an
//! overflow faults below RAM instead of overwriting the servo's state; but the fault is then
//! taken with SP still below RAM, where a handler that pushes anything would fault again and
//! lock the core up, drives enabled, until the watchdog resets it. Starting afresh lets the
//! safe state run at once. Nothing returns from a HardFault here, so the old stack is not
//! needed. (On QEMU the memory below RAM ignores writes, so an overflow cannot be shown there;
//! the `hard-fault` self-test runs through this entry.)
//!
//! ```ignore
//! hard_fault_on_fresh_stack!(handler); // unsafe extern "C" fn handler(faulting_sp: u32) -> !
//! ```

/// Defines the `HardFault` symbol (see the module doc).
macro_rules! hard_fault_on_fresh_stack {
    ($handler:path) => {
        core::arch::global_asm!(
            ".section .HardFault.user, \"ax\"",
            ".global HardFault",
            ".type HardFault,%function",
            ".thumb_func",
            "HardFault:",
            "mrs r0, MSP",
            "ldr r1, =_stack_start",
            "msr MSP, r1",
            "b {handler}",
            ".ltorg",
            ".size HardFault, . - HardFault",
            handler = sym $handler,
        );
    };
}
