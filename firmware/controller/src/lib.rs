//! The motion controller's application logic, without hardware: what the firmware decides.
//!
//! The RTIC app (`firmware/src/main.rs`) wires this crate to a board (`firmware/src/board/`):
//! it reads the encoders, hands them to [`servo_loop::ServoLoop::step`], writes the torques
//! the step decided, and publishes the [`status::Status`]. Everything here is plain `no_std`
//! Rust that runs the same on the MCU and on the host, and `cargo test` tests it on the host.
//!
//! One module per concept; where a change goes:
//! * [`settings`]: every run-time setting, with documented defaults;
//! * [`servo_loop`]: one servo sample: the mode machine (running / stopping / holding / safe
//!   state), setpoint intake with underrun handling, the workspace check, fault latching, what
//!   torque and drive enable result;
//! * [`setpoints`]: the setpoint queue between a source and the servo, and the
//!   [`setpoints::SetpointSource`] trait (the built-in [`waypoint_moves`] are one, the host
//!   link's [`motion_stream`] another);
//! * [`waypoint_moves`]: the built-in setpoint generator (rest-to-rest moves through waypoints,
//!   quintic or jerk-limited);
//! * [`fault`]: why the machine stops ([`fault::Fault`], latched) and how: its stop category
//!   (0: torque off at once; 1: controlled stop, then torque off; 2: controlled stop, then
//!   hold), with the table of faults and reactions;
//! * [`stop`]: the controlled stop: a jerk-limited deceleration along the current velocity, its
//!   stopping distance, the workspace its end must lie in;
//! * [`encoder_check`]: encoder plausibility (speed, acceleration, glitches, a reading that
//!   does not move under torque);
//! * [`deadline`]: the servo task's deadline bookkeeping;
//! * [`status`]: what the servo task publishes every sample;
//! * [`calibration`]: the policy for the calibration image found in flash, and what "built for
//!   this machine" means;
//! * [`plausibility`]: whether an image of this machine carries only what a calibration of it
//!   can need (corrections, their neighbours and slope, dynamics, backlash, workspace);
//! * [`calibration_slots`]: the two slots of the calibration region, the upload into the
//!   inactive one and the atomic switch (power-cut safe);
//! * [`drive`]: torque-mode amplifiers commanded by PWM duty (torque <-> duty);
//! * [`homing`]: the homing procedure (index search, reference, move to home) and the check
//!   that its sweeps keep away from the five-bar's singularities;
//! * [`encoder`]: quadrature encoders (per-axis counts -> joint angle, the homing hook);
//! * [`watchdog`]: when the independent watchdog is fed, its timeout, and what a watchdog
//!   reset means at the next boot;
//! * `scenario` (feature `qemu-harness`, and in host tests): the QEMU test scenarios, their
//!   fault injection and their checks.
//!
//! * [`host_link`]: the host link's command handler (requests in, one reply out; posts
//!   [`servo_loop::ServoRequest`]s, feeds the [`motion_stream`]); the wire format is the
//!   `link-protocol` crate;
//! * [`motion_stream`]: the link's motion source: planned moves and streamed knots validated
//!   whole, interpolated at 2 kHz (a [`setpoints::SetpointSource`]).
//!
//! The link reaches [`homing`] and [`calibration_slots`] through the handler's `Homing` and
//! `CalibrationStore` traits: the firmware implements them over the servo task's homing and the
//! flash's two slots (`firmware/src/link.rs`); the host tests, over doubles.
//!
//! No heap, no panic on runtime data: every failure is a [`fault::Fault`].
#![cfg_attr(not(test), no_std)]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(missing_docs)]
// `!(x >= lo)` instead of `x < lo` is deliberate throughout: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod calibration;
pub mod calibration_slots;
pub mod deadline;
pub mod drive;
pub mod encoder;
pub mod encoder_check;
pub mod fault;
pub mod homing;
pub mod host_link;
pub mod motion_stream;
pub mod plausibility;
#[cfg(any(test, feature = "qemu-harness"))]
pub mod scenario;
pub mod servo_loop;
pub mod setpoints;
pub mod settings;
pub mod status;
pub mod stop;
pub mod watchdog;
pub mod waypoint_moves;

/// Sample period of the servo loop (s): 2 kHz.
pub const SAMPLE_PERIOD_S: f32 = 5.0e-4;
/// Servo loop rate (Hz).
pub const SAMPLE_RATE_HZ: u32 = 2_000;
