//! The moving machine, from what the controller reports: the excitation motion, the telemetry
//! it returns, the dynamic parameters identified from it, and the diagnosis of what the
//! controller's dynamics model is missing.
//!
//! | module | job |
//! |---|---|
//! | [`telemetry`] | the telemetry log's checks: the machine it belongs to, gaps, built from the link's samples or the host loop's |
//! | [`excitation`] | the excitation motion as knots: every dynamic parameter and every effect of the library moved, within the machine's limits and workspace |
//! | [`samples`] | a log matched with the knots that made it: the joint motion and the torque of each sample |
//! | [`identify`] | the hidden robot's dynamic parameters fitted to the samples (linear least squares, `kinematics_core::dynamics::regressor`) |
//! | [`session`] | the excitation streamed to a controller over its link, its telemetry recorded |
//! | [`effects`] | the library of dynamic effects a model can miss, each a set of torque columns |
//! | [`model_plant`] | the controller's dynamics model as a plant, with the effects, for the closed-loop prediction |
//! | [`predict`] | the closed loop (the core's servo) around that plant, on the log's reference: the following error it predicts |
//! | [`diagnose`] | where prediction and telemetry disagree: the effects named, added, the residual shrinking |
//! | [`torque_fit`] | the diagnosis' least squares on the torques: candidates, BIC, the cogging scan |
//! | [`block`] | how the named effects go into the image's dynamics block |
//! | [`report`] | the diagnosis report (the same contract as the static diagnosis') and its table |
//! | [`tuning`] | the servo's gains designed for the identified inertia |
//!
//! The layers import downwards: `sim`, `link` and `io` below; `calib::dynamics` (the
//! closed-loop identification on a simulated plant) shares its least-squares solve.
//!
//! The controller's telemetry comes at most every 20 servo samples (100 Hz, the link's limit):
//! too sparse to differentiate the encoders. The motion of each sample is taken from the
//! reference instead: the knots the host streamed are the reference exactly (the controller
//! interpolates them, `sim::knots`), so its velocity and acceleration are known at every
//! sample; the machine follows it within micro-radians.

pub mod block;
pub mod diagnose;
pub mod effects;
pub mod excitation;
pub mod identify;
pub mod model_plant;
pub mod predict;
pub mod report;
pub mod samples;
pub mod session;
pub mod telemetry;
pub mod torque_fit;
pub mod tuning;

/// Why the moving machine could not be identified or diagnosed; every message says what is
/// missing and what to do.
#[derive(Debug, thiserror::Error)]
pub enum DynError {
    /// The telemetry log is not usable (too short, gaps, faults, another machine, not of these
    /// knots); the message says which and what to do.
    #[error("{0}")]
    Telemetry(String),
    /// The data cannot separate what is asked (a parameter or effect not excited).
    #[error("{0}")]
    NotIdentifiable(String),
    /// Options that make no run.
    #[error("{0}")]
    Invalid(String),
    /// The controller refused or did not answer.
    #[error("controller: {0}")]
    Link(#[from] crate::link::ClientError),
    /// A simulation failed.
    #[error(transparent)]
    Sim(#[from] crate::sim::SimError),
    /// The least-squares fit failed.
    #[error(transparent)]
    Fit(#[from] crate::calib::CalibError),
}

#[cfg(test)]
mod tests;
