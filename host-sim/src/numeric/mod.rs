//! Numerical building blocks shared by the calibration fit (`calib::fit`) and the diagnosis
//! (`diagnose`): one of each, so two fits of the same data cannot disagree.
//!
//! * [`lm`]: THE Levenberg–Marquardt least-squares solver, over any [`Residuals`], with its
//!   cost history and the covariance at the solution;
//! * [`finite_difference`]: the central-difference Jacobian every fit uses;
//! * [`svd`]: the column-scaled SVD (identifiability, rank, condition, the pseudo-inverse of
//!   `JᵀJ`);
//! * [`lattice_smoother`]: the 2-D Whittaker smoother of lattice values with its smoothing
//!   chosen by generalised cross-validation (the noise-aware correction grid);
//! * [`rigid`]: planar rigid motions and the best-fitting one between two point sets (the
//!   registration of an instrument's frame);
//! * [`stats`]: max/RMS of error magnitudes and the rounding of reported figures;
//! * [`subspace`]: orthonormal bases, projections and principal angles of column spaces;
//! * [`two_regressors`]: least squares on two regressors by its normal equations.
//!
//! Where a change goes: a new solver behaviour (acceptance, stopping, damping) in `lm.rs` and its
//! module doc, with a test in `tests/lm.rs`; nothing here knows about five-bars or effects.

pub mod finite_difference;
pub mod lattice_smoother;
pub mod lm;
pub mod rigid;
pub mod stats;
pub mod subspace;
pub mod svd;
pub mod two_regressors;

pub use lm::{levenberg_marquardt, LmFit, LmOptions, Neighbours, Residuals, Stop};
pub use rigid::{procrustes, Rigid2};
pub use stats::{max_rms, round3, round6, MaxRms};
pub use svd::{ScaledSvd, RANK_TOL};

/// Why a numerical computation could not run.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum NumericError {
    /// The residuals are not defined at the start (e.g. a measured pose the start model cannot
    /// reach).
    #[error("the start point is outside the model's domain: its residuals cannot be evaluated")]
    StartOutsideDomain,
    /// A finite-difference neighbour of the current point is outside the model's domain.
    #[error("parameter {param}: a finite-difference neighbour is outside the model's domain")]
    JacobianOutsideDomain {
        /// Index of the parameter whose perturbation failed.
        param: usize,
    },
    /// A parameter index beyond the problem's parameter vector.
    #[error("parameter {param} does not exist (the problem has {n_params})")]
    NoSuchParameter {
        /// The index asked for.
        param: usize,
        /// How many parameters the problem has.
        n_params: usize,
    },
}
