//! The gap-shrink table: the final model's effects refitted cumulatively in the order they were
//! added, each step's parameters and the residual before and after it; and what the data cannot
//! rule out, every candidate left out fitted on top of the final model.
//!
//! Every residual reported is the library model's: a nuisance fitted alongside stays in it
//! (`nuisance::library_residual`). Cost: one LM fit per step and per left-out candidate
//! (cached by the fitter).

use super::error::DiagnoseError;
use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{Effect, N_PARAMS, PARAM_NAMES};
use super::nuisance::library_residual;
use super::report::{NotDetected, Param, Step};
use super::scoring::{delta_bic, n_res, sigma2, Fitter};
use super::selection::Selection;
use crate::numeric::stats::{max_rms_radial, MaxRms};
use std::collections::BTreeMap;

/// The table and what goes with it.
pub struct GapShrink {
    pub steps: Vec<Step>,
    /// Residual (µm, x,y interleaved) of the base model.
    pub start_residual: Vec<f64>,
    /// Max and RMS of the radial residual of the base model.
    pub initial: MaxRms,
    /// (label, residual per point): "start", then one per step (for the plots).
    pub fields: Vec<(String, Vec<[f64; 2]>)>,
    /// The final model's fit (the last step's) and its library residual.
    pub last: Fit,
    pub last_residual: Vec<f64>,
}

/// Refits the selection's effects cumulatively (module doc).
pub fn gap_shrink(
    problem: &Problem,
    fitter: &mut Fitter<'_>,
    sel: &Selection,
    noise_um: Option<f64>,
) -> Result<GapShrink, DiagnoseError> {
    let zero = [0.0; N_PARAMS];
    let start_residual = problem
        .residuals_um(&zero)
        .ok_or(DiagnoseError::NoForwardSolution)?;
    let start = fitter
        .fit(&[], &zero)
        .ok_or(DiagnoseError::NoForwardSolution)?;
    let initial = max_rms_radial(&start_residual);
    let mut fields = vec![("start".to_string(), pairs(&start_residual))];
    let mut steps = Vec::new();
    let mut prev_residual = start_residual.clone();
    let mut last = start;
    for k in 0..sel.effects.len() {
        let set = &sel.effects[..=k];
        let f = fitter
            .fit(set, &sel.fit.p)
            .ok_or(DiagnoseError::Refit(k + 1))?;
        let residual = library_residual(problem, &f.p).ok_or(DiagnoseError::Refit(k + 1))?;
        let s2 = sigma2(problem, noise_um, &[&f]);
        let (before, after) = (max_rms_radial(&prev_residual), max_rms_radial(&residual));
        steps.push(Step {
            effect: set[k].name().to_string(),
            params: params_of(&f, &set[k..=k], s2),
            rms_before_um: before.rms,
            rms_after_um: after.rms,
            max_before_um: before.max,
            max_after_um: after.max,
        });
        fields.push((format!("after {}", set[k].name()), pairs(&residual)));
        prev_residual = residual;
        last = f;
    }
    Ok(GapShrink {
        steps,
        start_residual,
        initial,
        fields,
        last,
        last_residual: prev_residual,
    })
}

/// What the data cannot rule out: every candidate left out, fitted on top of the final model
/// (`last`), with its parameters ± 1σ and the BIC change had it been added.
pub fn not_detected(
    problem: &Problem,
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    sel: &Selection,
    last: &Fit,
    noise_um: Option<f64>,
) -> Vec<NotDetected> {
    let n = n_res(problem);
    let mut out = Vec::new();
    for &c in candidates.iter().filter(|c| !sel.effects.contains(c)) {
        let mut set = sel.effects.clone();
        set.push(c);
        if set.iter().map(|e| e.params.len()).sum::<usize>() as f64 >= n {
            continue;
        }
        if let Some(f) = fitter.fit(&set, &last.p) {
            let s2 = sigma2(problem, noise_um, &[&f]);
            // Column-normalised Jacobian singular below 1e-6: some direction of the candidate is
            // exactly what the final model already does (no bound exists).
            let identifiable = f.svd.min() > 1e-6;
            let mut params = params_of(&f, &[c], s2);
            if !identifiable {
                params.values_mut().for_each(|p| p.std_dev = f64::INFINITY);
            }
            out.push(NotDetected {
                effect: c.name().to_string(),
                identifiable,
                params,
                delta_bic: delta_bic(problem, noise_um, last, &f),
            });
        }
    }
    out
}

/// The fitted values of `effects`' parameters with their standard deviations (σ² = `s2`).
pub fn params_of(fit: &Fit, effects: &[&'static Effect], s2: f64) -> BTreeMap<String, Param> {
    let mut out = BTreeMap::new();
    for e in effects {
        for &k in e.params {
            let col = fit.free.iter().position(|&f| f == k);
            let sd = col
                .map(|c| (fit.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
                .unwrap_or(f64::NAN);
            out.insert(
                PARAM_NAMES[k].to_string(),
                Param {
                    value: fit.p[k],
                    std_dev: sd,
                },
            );
        }
    }
    out
}

/// A residual vector (x,y interleaved) as one pair per point.
fn pairs(r: &[f64]) -> Vec<[f64; 2]> {
    r.chunks(2).map(|c| [c[0], c[1]]).collect()
}
