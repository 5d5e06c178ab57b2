//! How good a fitted model is: per-point errors under a selection criterion.
//!
//! * [`Criterion::Measured`] (the default): `|FK(θi) − measured_i|`, the distance between where
//!   the model says the tool is for the recorded motor angles and where the instrument saw it.
//!   This is the model's real prediction error; on points outside a fit subset it is a hold-out
//!   error. It is what a model is for: commanding `IK(target)` lands at `target + (this error)`.
//! * [`Criterion::Paper`]: `|FK(θi) − desired_i|`, the paper's "calculated vs desired" (we
//!   reproduce its 93 µm with it, see `docs/design/hidden-robot.md`). Table I's angles are the
//!   nominal model's IK of the desired points, so this measures how far the fitted model *moves
//!   away from the nominal one* at those angles, not how well it predicts the machine: the
//!   nominal model scores 1.8 µm on it while mispredicting Table I by 1.5 mm.
//!
//! Cost: one FK per point. A model that cannot reach a recorded pose gets an infinite error.

use crate::calib::CalibError;
use crate::io::measurement_csv::Measurement;
use kinematics_core::FiveBar;

/// Which position the model's prediction is compared with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Criterion {
    /// `FK(measured angles)` vs the measured position: the model's prediction error.
    Measured,
    /// `FK(measured angles)` vs the desired (target) position: the paper's measure.
    Paper,
}

/// The tool point a model predicts for a measurement's motor angles (no singularity margin:
/// the machine was there).
pub fn predicted_mm(model: &FiveBar<f64>, m: &Measurement) -> Option<[f64; 2]> {
    model.forward(m.theta_rad(), 0.0).ok()
}

/// Checks that the data have what the criterion compares with.
pub fn check_criterion(data: &[Measurement], criterion: Criterion) -> Result<(), CalibError> {
    if criterion == Criterion::Paper {
        if let Some(m) = data.iter().find(|m| m.target_mm.is_none()) {
            return Err(CalibError::MissingTargets { line: m.line });
        }
    }
    Ok(())
}

/// Error vector (µm) `reference − predicted` of every point; `None` where the model cannot
/// reach the pose. `reference` is the measured or the target position per `criterion`.
pub fn error_vectors_um(
    model: &FiveBar<f64>,
    data: &[Measurement],
    criterion: Criterion,
) -> Vec<Option<[f64; 2]>> {
    data.iter()
        .map(|m| {
            let reference = match criterion {
                Criterion::Measured => m.measured_mm,
                Criterion::Paper => m.target_mm?,
            };
            let p = predicted_mm(model, m)?;
            Some([(reference[0] - p[0]) * 1e3, (reference[1] - p[1]) * 1e3])
        })
        .collect()
}

/// Error magnitudes (µm), infinite where the model cannot reach the pose.
pub fn errors_um(model: &FiveBar<f64>, data: &[Measurement], criterion: Criterion) -> Vec<f64> {
    error_vectors_um(model, data, criterion)
        .into_iter()
        .map(|e| e.map_or(f64::INFINITY, |e| e[0].hypot(e[1])))
        .collect()
}

/// Max and RMS of a list of errors (the crate's one: `crate::numeric::stats`).
pub use crate::numeric::{max_rms, MaxRms};
