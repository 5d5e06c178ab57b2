//! The `device` module RTIC needs, for any board: interrupt numbers, priority bits and the
//! external-interrupt vector table, with the board-neutral interrupt names the app binds
//! (`SERVO_TICK`, `LINK_RX` for the host link, and `DISPATCH_1`/`DISPATCH_2` for the software
//! tasks), so that one app file
//! serves every board. A board states its numbers once:
//!
//! ```ignore
//! device! {
//!     nvic_prio_bits: 3,
//!     external_interrupts: 32,
//!     /// UART2 RX (IRQ 4), unused: dispatcher of the priority-1 software tasks.
//!     DISPATCH_1 = 4,
//!     ...
//! }
//! ```
//! Every other vector points at `DefaultHandler`; `firmware/device.x` provides weak defaults for
//! the four names (RTIC defines them). A PAC's own vector table (its `rt` feature) is not used.

/// Defines `pub mod device` for a board (see the module doc).
macro_rules! device {
    (
        nvic_prio_bits: $bits:expr,
        external_interrupts: $n:expr,
        $( $(#[$doc:meta])* $name:ident = $irq:expr ),+ $(,)?
    ) => {
        /// The device module RTIC needs: interrupt numbers, priority bits and the vector table.
        pub mod device {
            /// Priority bits the NVIC implements.
            pub const NVIC_PRIO_BITS: u8 = $bits;

            /// The interrupts this firmware uses, by board-neutral name.
            #[derive(Clone, Copy, Debug, PartialEq, Eq)]
            #[allow(non_camel_case_types)]
            #[repr(u16)]
            pub enum Interrupt {
                $( $(#[$doc])* $name = $irq, )+
            }
            pub use Interrupt as interrupt;

            // SAFETY: every number is one of the board's external interrupt lines (below
            // `external_interrupts`: the vector table below would not compile otherwise).
            unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
                #[inline]
                fn number(self) -> u16 {
                    self as u16
                }
            }

            extern "C" {
                $( fn $name(); )+
                fn DefaultHandler();
            }

            #[doc(hidden)]
            pub union Vector {
                handler: unsafe extern "C" fn(),
                _reserved: usize,
            }

            const D: Vector = Vector { handler: DefaultHandler };

            /// The external interrupt vectors (cortex-m-rt places them after the exceptions).
            #[doc(hidden)]
            #[link_section = ".vector_table.interrupts"]
            #[no_mangle]
            pub static __INTERRUPTS: [Vector; $n] = {
                let mut v = [D; $n];
                $( v[$irq] = Vector { handler: $name }; )+
                v
            };
        }
    };
}
