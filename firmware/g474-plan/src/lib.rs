//! The STM32G474 board's register plan: what the firmware writes to which register, in which
//! order and why, as data.
//!
//! The board (`firmware/src/board/g474.rs`) applies these plans with volatile accesses
//! ([`apply`] over its [`Bus`]); `cargo test` applies them to a simulated register file and
//! checks the result against the reference manual, RM0440, each test naming the section it
//! relies on (`tests/rm0440.rs`). So the clock tree, the timers, the break input, the watchdog
//! and the debug freeze are read as facts on the host, not only compiled.
//!
//! * [`map`]: register addresses and the bit fields used (RM0440's register maps);
//! * [`plan`]: the plans: [`plan::BOOT`] (first [`plan::SAFE_OUTPUTS`] at the reset clock:
//!   drive enable driven low; [`plan::CLOCK`]: 170 MHz; debug and power; TIM1 PWM with break,
//!   encoders, TIM6 tick, pins), [`plan::START_WATCHDOG`] (IWDG),
//!   [`plan::SAFE_STATE`] / [`plan::ENABLE_OUTPUTS`] (what the fault handlers and the drive
//!   enable do), and the board's figures (clock, PWM period, watchdog reload);
//! * [`reset`]: the reset cause from `RCC_CSR`;
//! * [`link_uart`]: the host link's byte port on LPUART1 (receive ring, overrun handling,
//!   bounded transmit), over [`Bus`] so that the host tests run it against a simulated LPUART.
//!
//! A wait that times out stops the plan there ([`apply`] returns the step): a clock that does
//! not start leaves the board in what the earlier steps set, the drive-enable line driven low.
#![cfg_attr(not(test), no_std)]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(missing_docs)]

pub mod link_uart;
pub mod map;
pub mod plan;
pub mod reset;

/// A memory-mapped register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Register {
    /// Peripheral name as in RM0440 (`"RCC"`, `"TIM1"`, ...).
    pub peripheral: &'static str,
    /// Register name without the peripheral prefix (`"PLLCFGR"`).
    pub name: &'static str,
    /// Address.
    pub address: u32,
}

/// What a step does to its register.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Write the whole register.
    Write(u32),
    /// Read, clear the bits of `clear`, set the bits of `set`, write back.
    Modify {
        /// Bits cleared.
        clear: u32,
        /// Bits set (after clearing).
        set: u32,
    },
    /// Read until `register & mask == value`, at most `polls` times; otherwise the plan stops
    /// here with an error.
    WaitFor {
        /// Bits compared.
        mask: u32,
        /// Their expected value.
        value: u32,
        /// Reads before giving up.
        polls: u32,
    },
    /// Busy-wait at least this many core cycles (at the clock in force) after the previous
    /// access to the register.
    Delay {
        /// Core cycles.
        cycles: u32,
    },
}

/// One step of a plan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    /// The register.
    pub register: Register,
    /// What is done to it.
    pub action: Action,
    /// Why (with the RM0440 section where it matters).
    pub why: &'static str,
}

/// Register access: volatile MMIO on the board, a simulated register file in the tests.
pub trait Bus {
    /// Reads a register.
    fn read(&mut self, address: u32) -> u32;
    /// Writes a register.
    fn write(&mut self, address: u32, value: u32);
    /// Busy-waits at least `cycles` core cycles.
    fn delay(&mut self, cycles: u32);
}

/// Applies `plan` in order. A [`Action::WaitFor`] that times out stops it and returns that step;
/// the steps after it are not applied.
pub fn apply<B: Bus>(plan: &'static [Step], bus: &mut B) -> Result<(), &'static Step> {
    for step in plan {
        let address = step.register.address;
        match step.action {
            Action::Write(value) => bus.write(address, value),
            Action::Modify { clear, set } => {
                let value = (bus.read(address) & !clear) | set;
                bus.write(address, value);
            }
            Action::WaitFor { mask, value, polls } => {
                let mut left = polls;
                while bus.read(address) & mask != value {
                    if left == 0 {
                        return Err(step);
                    }
                    left -= 1;
                }
            }
            Action::Delay { cycles } => bus.delay(cycles),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const R: Register = Register {
        peripheral: "X",
        name: "R",
        address: 0x10,
    };
    static PLAN: [Step; 4] = [
        Step {
            register: R,
            action: Action::Write(0xF0),
            why: "",
        },
        Step {
            register: R,
            action: Action::Modify {
                clear: 0x30,
                set: 0x01,
            },
            why: "",
        },
        Step {
            register: R,
            action: Action::WaitFor {
                mask: 0x100,
                value: 0x100,
                polls: 5,
            },
            why: "never",
        },
        Step {
            register: R,
            action: Action::Write(0),
            why: "not reached",
        },
    ];

    #[derive(Default)]
    struct Log {
        value: u32,
        reads: u32,
        writes: Vec<u32>,
    }
    impl Bus for Log {
        fn read(&mut self, _: u32) -> u32 {
            self.reads += 1;
            self.value
        }
        fn write(&mut self, _: u32, v: u32) {
            self.value = v;
            self.writes.push(v);
        }
        fn delay(&mut self, _: u32) {}
    }

    #[test]
    fn a_wait_that_times_out_stops_the_plan_at_its_step() {
        let mut bus = Log::default();
        let failed = apply(&PLAN, &mut bus).unwrap_err();
        assert_eq!(failed.why, "never");
        assert_eq!(
            bus.writes,
            [0xF0, 0xC1],
            "write, then read-modify-write; nothing after the wait"
        );
        assert_eq!(
            bus.reads,
            1 + 6,
            "the modify's read, then the first read and 5 polls"
        );
        // The same plan up to the wait succeeds.
        let mut bus = Log::default();
        assert_eq!(apply(&PLAN[..2], &mut bus), Ok(()));
    }
}
