//! The closed 2 kHz loop on the simulated plant: setpoint trajectories ([`motions`]), the
//! loop itself ([`closed_loop`]: `kinematics-core`'s servo step exactly as the firmware runs it,
//! drives integrated between samples, linkage solved every sample) and the `simulate` run with
//! its log ([`simulate`]); streamed knots played as the controller plays them ([`knots`]).
//!
//! Where a change goes: a new test motion in `motions.rs`; a new loop statistic in
//! `closed_loop.rs` (`LoopSummary`, printed as JSON by `host-sim simulate`); the servo itself is
//! `kinematics_core::servo`, not here.

pub mod closed_loop;
pub mod knots;
pub mod motions;
pub mod simulate;

use crate::plant::PlantError;

/// Why a simulation could not run.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// Not a built-in trajectory nor an existing file.
    #[error("unknown trajectory '{0}': not circle, figure8, p2p or an existing CSV file")]
    UnknownTrajectory(String),
    /// A trajectory file that is not `t_s,x_mm,y_mm` with increasing times (the message names
    /// the file and line).
    #[error("{0}")]
    TrajectoryFile(String),
    /// The trajectory's first setpoint cannot be commanded.
    #[error("trajectory start ({:.3}, {:.3}) mm: {reason}", start_mm[0], start_mm[1])]
    Start { start_mm: [f64; 2], reason: String },
    /// The servo refused to engage at the start.
    #[error("servo refused to engage: {0}")]
    ServoRefused(String),
    /// Options that make no run (the message says which).
    #[error("{0}")]
    Invalid(String),
}
