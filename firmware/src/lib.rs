//! Support library of the motion-controller firmware (the RTIC app is `src/main.rs`, the
//! benchmark `src/bin/bench.rs`).
//!
//! * [`settings`]: every run-time setting in one struct, with documented defaults;
//! * [`board`]: the two boards (QEMU MPS2-AN386 with a simulated plant, STM32G474) behind
//!   small traits, selected by the `board-*` feature;
//! * [`calibration`]: finds and validates the correction grid image in its flash region;
//! * [`trajectory`]: the built-in setpoint generator (rest-to-rest quintic moves);
//! * [`monitor`]: the status the servo task publishes, deadline bookkeeping and faults;
//! * [`scenario`]: the QEMU test scenarios (fault injection) and their pass/fail checks.
//!
//! No heap, no panics on runtime data: every failure is a [`monitor::Fault`].
#![no_std]

pub mod board;
pub mod calibration;
pub mod monitor;
pub mod scenario;
pub mod settings;
pub mod trajectory;

/// Sample period of the servo loop (s): 2 kHz.
pub const SAMPLE_PERIOD_S: f32 = 5.0e-4;
/// Servo loop rate (Hz).
pub const SAMPLE_RATE_HZ: u32 = 2_000;
