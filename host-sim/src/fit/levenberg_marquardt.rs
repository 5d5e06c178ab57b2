//! `full`: Levenberg–Marquardt over the identifiable parameters of the five-bar, minimising the
//! position residual `Σ |FK(θi; p) − measured_i|²`, with a standard deviation per parameter.
//!
//! Why: the paper's dyad fits minimise an algebraic residual, one arm at a time, over four link
//! lengths only. The quantity that matters is the distance between where the model puts the tool
//! and where it is; this fits exactly that, and can also fit the encoder offsets and the base
//! offset B0 when the data identify them (see [`super::identifiability`]).
//!
//! Method: damped Gauss–Newton with Marquardt's diagonal scaling,
//! `(JᵀJ + λ·diag(JᵀJ)) δ = −Jᵀr`, λ divided by 10 on success and multiplied by 10 on failure;
//! stops when the cost changes by less than 1e-14 relative or the step is below 1e-12 (mm/rad).
//! Covariance `σ²·(JᵀJ)⁻¹` at the solution with `σ² = SSR / (2N − k)` (k free parameters): the
//! textbook estimate assuming independent equal-variance errors on x and y, first-order in the
//! errors. Cost: a few to ~20 iterations of 2·8 FK sweeps over the data each.

use super::identifiability::{self, Identifiability};
use super::params::{self, NAMES, N_PARAMS};
use crate::measurement_csv::Measurement;
use anyhow::{bail, Context, Result};
use kinematics_core::FiveBar;
use nalgebra::{DMatrix, DVector};

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
}

fn cost(m: &FiveBar<f64>, data: &[Measurement]) -> f64 {
    params::residuals_mm(m, data).map_or(f64::INFINITY, |r| r.norm_squared())
}

/// Fits `data` starting from `start`; parameters in `fixed_by_user` stay at their start value,
/// and so do those the identifiability check fixes.
pub fn fit_full(data: &[Measurement], start: &FiveBar<f64>, fixed_by_user: &[usize]) -> Result<FullFit> {
    let requested = N_PARAMS - fixed_by_user.len();
    if 2 * data.len() <= requested {
        bail!(
            "{} points give {} equations, not more than the {requested} parameters to fit: need at least {} points (or --fix some)",
            data.len(),
            2 * data.len(),
            requested / 2 + 1
        );
    }
    let j0 = params::jacobian(start, data).context("at the start model")?;
    let ident = identifiability::check(&j0, fixed_by_user);
    let free = ident.free.clone();
    let k = free.len();
    let n_eq = 2 * data.len();
    if n_eq <= k {
        bail!(
            "{} points give {n_eq} equations, not more than the {k} identifiable parameters ({}): need at least {} points",
            data.len(),
            free.iter().map(|&i| NAMES[i]).collect::<Vec<_>>().join(", "),
            k / 2 + 1
        );
    }
    let mut model = *start;
    let mut c = cost(&model, data);
    if !c.is_finite() {
        bail!("the start model cannot reach every measured pose");
    }
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for it in 0..200 {
        iterations = it + 1;
        let j_all = params::jacobian(&model, data)?;
        let j = j_all.select_columns(&free);
        let r = params::residuals_mm(&model, data).expect("cost was finite");
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut accepted = false;
        let mut step_norm = 0.0;
        for _ in 0..30 {
            let mut a = jtj.clone();
            for d in 0..k {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-30);
            }
            let Some(delta) = a.cholesky().map(|ch| ch.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let mut p = params::to_vector(&model);
            for (d, &i) in free.iter().enumerate() {
                p[i] += delta[d];
            }
            let trial = params::from_vector(&p, &model);
            let c_trial = if trial.validate().is_ok() { cost(&trial, data) } else { f64::INFINITY };
            if c_trial < c {
                step_norm = delta.norm();
                let rel = (c - c_trial) / c.max(f64::MIN_POSITIVE);
                model = trial;
                c = c_trial;
                lambda = (lambda / 10.0).max(1e-12);
                accepted = true;
                if rel < 1e-14 {
                    step_norm = 0.0;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !accepted || step_norm < 1e-12 {
            break;
        }
    }
    // Covariance at the solution.
    let j = params::jacobian(&model, data)?.select_columns(&free);
    let dof = (n_eq - k) as f64;
    let sigma2 = c / dof;
    let cov: DMatrix<f64> = (j.transpose() * &j)
        .try_inverse()
        .context("JᵀJ is singular at the solution: the data do not identify the parameters")?
        * sigma2;
    let mut std_dev = [None; N_PARAMS];
    for (d, &i) in free.iter().enumerate() {
        std_dev[i] = Some(cov[(d, d)].max(0.0).sqrt());
    }
    Ok(FullFit { model, std_dev, identifiability: ident, sigma_mm: sigma2.sqrt(), iterations })
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
