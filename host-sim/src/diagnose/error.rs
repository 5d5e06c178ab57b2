//! Why a diagnosis could not run (one error type for every stage of `diagnose`).

use crate::io::IoError;

/// Why a diagnosis could not run.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error(transparent)]
    Io(#[from] IoError),
    /// Fewer than 3 points the base model reaches.
    #[error("only {0} usable point(s): the diagnosis needs at least 3")]
    TooFewPoints(usize),
    /// The base model cannot predict the kept points (should not happen: they were kept because
    /// it can).
    #[error("the base model has no forward solution")]
    NoForwardSolution,
    /// A refit of the chosen effects left the model's workspace.
    #[error("refitting step {0}: a point left the model's workspace")]
    Refit(usize),
    /// Options that make no diagnosis (the message says which).
    #[error("{0}")]
    Invalid(String),
}
