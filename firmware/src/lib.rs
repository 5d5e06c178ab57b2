//! Board support of the motion-controller firmware: what touches hardware. The RTIC app is
//! `src/main.rs`, the benchmark `src/bin/bench.rs`, the same-core check `src/bin/golden.rs`;
//! the hardware-independent logic is the `controller` crate (`firmware/controller/`).
//!
//! * [`board`]: the [`board::Board`] trait and the two boards (QEMU MPS2-AN386 with a
//!   simulated plant and the test harness, STM32G474), selected by the `board-*` feature;
//! * [`calibration`]: the calibration image's flash region, read by address;
//! * [`link`]: the host link's port trait and the handler's view of the app's resources (the
//!   servo task's homing, the calibration slots).
#![no_std]
#![warn(missing_docs)]

pub mod board;
pub mod calibration;
pub mod link;
