//! `full`: Levenberg–Marquardt over the identifiable parameters of the five-bar, minimising the
//! position residual `Σ |FK(θi; p) − measured_i|²`, with a standard deviation per parameter.
//!
//! Why: the paper's dyad fits minimise an algebraic residual, one arm at a time, over four link
//! lengths only. The quantity that matters is the distance between where the model puts the tool
//! and where it is; this fits exactly that, and can also fit the encoder offsets and the base
//! offset B0 when the data identify them (see [`super::identifiability`]).
//!
//! Method: the crate's one Levenberg–Marquardt (`crate::numeric::lm`, whose module doc states
//! its acceptance, stopping and damping rules) on [`params::PositionResiduals`], over the
//! parameters the identifiability check leaves free. Covariance `σ²·(JᵀJ)⁺` at the solution with
//! `σ² = SSR / (2N − k)` (k free parameters): the textbook estimate assuming independent
//! equal-variance errors on x and y, first-order in the errors; a solution whose Jacobian has
//! lost rank is refused. Cost: a few to ~20 iterations of 2·k FK sweeps over the data each.

use super::identifiability::{self, Identifiability};
use super::params::{self, PositionResiduals, NAMES, N_PARAMS};
use crate::io::measurement_csv::Measurement;
use crate::numeric::{levenberg_marquardt, LmFit, LmOptions, NumericError};
use crate::calib::{invalid, CalibError};
use kinematics_core::FiveBar;
use nalgebra::DVector;

/// A converged fit.
#[derive(Clone, Debug)]
pub struct FullFit {
    pub model: FiveBar<f64>,
    /// One standard deviation per parameter (code units); `None` for fixed parameters.
    pub std_dev: [Option<f64>; N_PARAMS],
    pub identifiability: Identifiability,
    /// Residual standard deviation per coordinate (mm), `sqrt(SSR / (2N − k))`.
    pub sigma_mm: f64,
    pub iterations: usize,
    /// The solver's record: cost history, stop reason, Jacobian and covariance at the solution.
    pub lm: LmFit,
}

/// What an LM failure means for a five-bar fit.
fn unreachable(e: NumericError) -> String {
    match e {
        NumericError::JacobianOutsideDomain { param } => {
            format!("a measured pose is unreachable by the model near {}", NAMES.get(param).unwrap_or(&"?"))
        }
        _ => "the start model cannot reach every measured pose".into(),
    }
}

/// Fits `data` starting from `start`; parameters in `fixed_by_user` stay at their start value,
/// and so do those the identifiability check fixes.
pub fn fit_full(data: &[Measurement], start: &FiveBar<f64>, fixed_by_user: &[usize]) -> Result<FullFit, CalibError> {
    let requested = N_PARAMS - fixed_by_user.len();
    if 2 * data.len() <= requested {
        return Err(invalid!(
            "{} points give {} equations, not more than the {requested} parameters to fit: need at least {} points (or --fix some)",
            data.len(),
            2 * data.len(),
            requested / 2 + 1
        ));
    }
    let j0 = params::jacobian(start, data).map_err(|e| invalid!("at the start model: {}", unreachable(e)))?;
    let ident = identifiability::check(&j0, fixed_by_user);
    let free = ident.free.clone();
    let k = free.len();
    let n_eq = 2 * data.len();
    if n_eq <= k {
        return Err(invalid!(
            "{} points give {n_eq} equations, not more than the {k} identifiable parameters ({}): need at least {} points",
            data.len(),
            free.iter().map(|&i| NAMES[i]).collect::<Vec<_>>().join(", "),
            k / 2 + 1
        ));
    }
    let problem = PositionResiduals { data, like: *start };
    let lm = levenberg_marquardt(&problem, &params::to_vector(start), &free, &LmOptions::default())
        .map_err(|e| invalid!("{}", unreachable(e)))?;
    if lm.rank() < k {
        return Err(invalid!("JᵀJ is singular at the solution: the data do not identify the parameters"));
    }
    let p: [f64; N_PARAMS] = lm.p.as_slice().try_into().expect("the problem has N_PARAMS parameters");
    let model = params::from_vector(&p, start);
    let sigma2 = lm.residual_variance();
    let mut std_dev = [None; N_PARAMS];
    for &i in &free {
        std_dev[i] = lm.std_dev(i, sigma2);
    }
    Ok(FullFit { model, std_dev, identifiability: ident, sigma_mm: sigma2.sqrt(), iterations: lm.iterations, lm })
}

/// Leave-one-out: for each point, fit on the others (same start and fixed set) and return the
/// distance (µm) between the left-out point's prediction and its measurement. `None` where the
/// fit on the rest failed.
pub fn leave_one_out_um(data: &[Measurement], start: &FiveBar<f64>, fixed_by_user: &[usize]) -> Vec<Option<f64>> {
    (0..data.len())
        .map(|i| {
            let rest: Vec<Measurement> = data.iter().enumerate().filter(|(k, _)| *k != i).map(|(_, m)| m.clone()).collect();
            let fit = fit_full(&rest, start, fixed_by_user).ok()?;
            let r: DVector<f64> = params::residuals_mm(&fit.model, std::slice::from_ref(&data[i]))?;
            Some(r.norm() * 1e3)
        })
        .collect()
}
