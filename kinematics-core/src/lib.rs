//! Kinematics core of the hidden-robot micro-mechanism: the only place the math lives.
//!
//! The real machine is an overconstrained six-bar with no closed-form inverse kinematics. Control
//! and calibration use its *hidden robot*, a plain five-bar whose end point moves like the
//! six-bar's tool point (Kiper et al., "Use of hidden robot concept for calibration of an
//! over-constrained mechanism"). This crate is that five-bar and what the 2 kHz loop does with it:
//!
//! * [`model`]: the five-bar's parameters (links a, b, c, d, base offset, encoder offsets,
//!   working mode);
//! * [`inverse`], [`forward`], [`jacobian`]: closed-form IK, FK and the Jacobian and its inverse,
//!   returning a [`Pose`] whose transmission margins give the singularity checks;
//! * [`valid_model`]: a model checked once ([`ValidFiveBar`]) and an IK margin raised to its
//!   floor once ([`IkMargin`]), so the servo's IK per sample repeats neither check;
//! * [`grid`], [`bilinear`]: the correction grid image read from flash (validated header, CRC),
//!   interpolated with the paper's Eq. 7, and the chain of extension blocks after it (the
//!   machine's workspace limits, the identified dynamics, the backlash, the machine record);
//! * [`machine`]: the machine record (nominal model, encoder convention, workspace, home,
//!   plausibility limits; its digest names the machine) and the judgements of an image against
//!   it: built for this machine, and a plausible calibration of it;
//! * [`workspace`]: the machine's convex workspace and the check that a point lies inside it
//!   with a margin (host tools and firmware share it);
//! * [`pid`], [`disturbance_observer`], [`servo`]: position control per axis (with an observer of
//!   the torque the feed-forward lacks) and the servo step, with [`gain_design`] the gains for
//!   the identified dynamics
//!   (setpoint → IK → correction → torque), with validated settings; a refused setpoint leaves
//!   the servo engaged (the firmware brakes the machine with it), a feedback fault latches;
//! * [`jerk_profile`], [`path`], [`setpoint`], [`trajectory`]: jerk-limited tool motions (time-optimal
//!   rest-to-rest profile, lines, circles, figure-eights, tours through waypoints) with exact
//!   velocity, acceleration and jerk at every sample;
//! * [`joint_motion`], [`dynamics`], [`feed_forward`], [`joint_limits`]: the joint motion for a
//!   tool motion, the hidden robot's inverse dynamics (linear in identified parameters), the
//!   servo's feed-forward over a sample, and the motors' speed and torque limits met by
//!   slowing a trajectory down;
//! * [`hermite`]: the cubic that joins two streamed knots (the controller's motion stream and
//!   the host loop play the same one);
//! * [`sixbar`]: the real six-bar's layout as built (its pins, bars and equivalent five-bar),
//!   which host-sim's plant and the firmware's benchmark of its solve both start from.
//!
//! Everything is generic over [`Real`] where the host tools need f64 and the MCU f32; the grid and
//! the servo are f32, exactly as the MCU runs them. `no_std`, no heap, no panic on any input:
//! every failure is a typed error.
#![no_std]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(missing_docs)]
// `!(x >= lo)` instead of `x < lo` is deliberate throughout: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod atan2;
pub mod backlash;
pub mod bilinear;
pub mod disturbance_observer;
pub mod dynamics;
pub mod error;
pub mod feed_forward;
pub mod forward;
pub mod gain_design;
pub mod grid;
pub mod hermite;
pub mod inverse;
pub mod jacobian;
pub mod jerk_profile;
pub mod joint_limits;
pub mod joint_motion;
mod le_bytes;
pub mod machine;
pub mod model;
pub mod paper;
pub mod path;
pub mod pid;
pub mod pose;
pub mod real;
pub mod servo;
pub mod setpoint;
pub mod sin_cos;
pub mod sixbar;
pub mod trajectory;
pub mod valid_model;
pub mod workspace;

pub use backlash::{Backlash, InvalidBacklash};
pub use dynamics::{DynamicsError, FiveBarDynamics};
pub use error::{KinematicsError, Singularity};
pub use grid::{CorrectionGrid, GridError, GridGeometry};
pub use jacobian::Mat2;
pub use joint_motion::JointMotion;
pub use machine::{judge_image, ImageRefusal, MachineRecord};
pub use model::{Branch, FiveBar, ModelError, WorkingMode};
pub use pid::{AxisController, AxisGains, AxisReference, InvalidGain};
pub use pose::Pose;
pub use real::{wrap_angle_rad, Real};
pub use servo::{
    AcceptedSetpoint, Calibration, ConfigError, EngageError, Servo, ServoCalibration, ServoConfig,
    ServoFault, ServoOutput, SetpointRefusal, StepError, ValidCalibration,
};
pub use trajectory::{MotionSetpoint, PathMotion, TaskLimits, Tour, TrajectoryError};
pub use valid_model::{IkMargin, ValidFiveBar};
pub use workspace::{ConvexWorkspace, WorkspaceError, WorkspaceLimits, MAX_WORKSPACE_VERTICES};

/// The default singularity margin: the smallest `|sin|` of a transmission angle accepted
/// (0.05 is about 2.9° from a singular configuration).
pub const DEFAULT_MIN_TRANSMISSION: f64 = 0.05;
