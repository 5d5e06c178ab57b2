//! Structures outside the library (a gear tooth's periodic error, an instrument drift), fitted
//! as nuisances so that no library effect is named on their account: the selection is run, the
//! residual's structure tested, a nuisance added for what it shows, the selection run again
//! ([`select_with_nuisances`]); a trend in time too weak for the drift test is decided by model
//! comparison ([`suspected_drift`]). What a nuisance fits stays in every residual the report
//! prints ([`library_residual`]) and makes it `unexplained`.
//!
//! Cost: up to four selections (each a few dozen LM fits) and a structure analysis per round.

use super::error::DiagnoseError;
use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{idx, Nuisance, N_PARAMS};
use super::scoring::{sigma2, Fitter};
use super::selection::{self, Selection};
use super::structure;
use crate::io::measurement_csv::Measurement;

/// The selection with the nuisances the residual calls for: the selection is run, the structure
/// of its residual tested, a nuisance added for each significant out-of-library structure, and
/// the selection run again (at most three rounds). Returns the selection (with
/// `problem.nuisance` set) and a log of what was fitted and why.
pub fn select_with_nuisances(
    problem: &mut Problem,
    data: &[Measurement],
    noise_um: Option<f64>,
) -> Result<(Selection, Vec<String>), DiagnoseError> {
    let mut sel = selection::select(problem, noise_um);
    let mut nuisance_log = Vec::new();
    for _ in 0..3 {
        let residual =
            library_residual(problem, &sel.fit.p).ok_or(DiagnoseError::NoForwardSolution)?;
        let found = structure::analyse(problem, data, &residual);
        let next = nuisance_for(problem, &found);
        if next == problem.nuisance {
            // A trend in time below the drift test's threshold: the selection may have named a
            // library effect on account of the drift's mean (a constant offset that a frame
            // translation, encoder offsets or link lengths reproduce; what is left, a ramp about
            // its mean, is then too weak for |z| > DRIFT_Z). Decide by the model comparison.
            if let Some((with_drift, line)) =
                suspected_drift(problem, data, &residual, &sel, noise_um)
            {
                nuisance_log.push(line);
                sel = with_drift;
                continue;
            }
            break;
        }
        nuisance_log.push(format!(
            "out-of-library structure in the residual of [{}]: {}; fitted as a nuisance in every model and selected again",
            sel.effects.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
            describe_nuisance(&next)
        ));
        problem.nuisance = next;
        sel = selection::select(problem, noise_um);
    }
    Ok((sel, nuisance_log))
}

/// The residual (µm) of the library part of a fitted parameter vector: the nuisances' terms
/// zeroed, so what they fit stays in it.
pub fn library_residual(problem: &Problem, p: &[f64]) -> Option<Vec<f64>> {
    let mut x: [f64; N_PARAMS] = p.try_into().ok()?;
    for k in problem.nuisance.params() {
        x[k] = 0.0;
    }
    problem.residuals_um(&x)
}

/// Shortest period (cycles per motor revolution) fitted as a nuisance: a gear tooth. Slower
/// structure may be a library effect's (the six-bar's is smooth, 2–7 cycles/rev) and is left to
/// the library and the report.
pub const NUISANCE_MIN_CYCLES: f64 = 11.0;

/// |z| of a residual trend in time from which a drift is tried as a nuisance although the
/// drift test does not call it significant ([`suspected_drift`]).
pub const SUSPECT_DRIFT_Z: f64 = 2.0;

/// The model comparison for a drift the structure test cannot see on the final residual. The
/// data may carry a drift whose mean the selection credited to a library effect: the nuisance's
/// drift starts at zero at the first reading, so a library effect with a translation takes the
/// drift's mean and leaves only the ramp about it, which a short run (120 points at 1 µm) does
/// not show at |z| > 5. When the final residual's trend in time has |z| >
/// [`SUSPECT_DRIFT_Z`], the selection is run again with the drift fitted in every model, and
/// that outcome replaces the first only when it passes the tests an effect must pass: its final
/// model's BIC (the drift's two parameters counted) lower by more than
/// [`selection::ADD_MARGIN`], and its cross-validated RSS lower by more than the drift's
/// parameters cost (2·σ²). Returns the new selection (with `problem.nuisance` set) and a log
/// line; `problem` is left unchanged otherwise.
fn suspected_drift(
    problem: &mut Problem,
    data: &[Measurement],
    residual: &[f64],
    sel: &Selection,
    noise_um: Option<f64>,
) -> Option<(Selection, String)> {
    if !problem.has_time || problem.nuisance.drift {
        return None;
    }
    let z = structure::drift_time_z(problem, data, residual)?;
    if z <= SUSPECT_DRIFT_Z {
        return None;
    }
    let cv_without = Fitter::new(problem).cv_rss(&sel.effects, &sel.fit.p)?;
    let without = problem.nuisance;
    problem.nuisance.drift = true;
    let with = selection::select(problem, noise_um);
    let d = selection::delta_bic(problem, noise_um, &sel.fit, &with.fit);
    let cv_with = Fitter::new(problem).cv_rss(&with.effects, &with.fit.p);
    let margin = 2.0 * sigma2(problem, noise_um, &[&sel.fit, &with.fit]);
    match cv_with {
        Some(cv) if d < -selection::ADD_MARGIN && cv < cv_without - margin => {
            let line = format!(
                "a trend in time below the drift test's threshold (|z| = {z:.1} ≤ {}) in the residual of [{}]: the selection \
                 with a drift fitted in every model names [{}], ΔBIC {d:.1} (< −{}), cross-validated RSS {cv_without:.1} → \
                 {cv:.1} µm² (needs a drop > {margin:.1}): drift of the readings in time fitted as a nuisance",
                structure::DRIFT_Z,
                sel.effects.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
                with.effects.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
                selection::ADD_MARGIN
            );
            Some((with, line))
        }
        _ => {
            problem.nuisance = without;
            None
        }
    }
}

/// The nuisances the residual's significant structure calls for (the current ones kept).
fn nuisance_for(problem: &Problem, found: &[structure::Finding]) -> Nuisance {
    let mut next = problem.nuisance;
    for f in found.iter().filter(|f| f.significant) {
        match (f.kind.as_str(), f.cycles_per_rev) {
            ("periodic_theta1", Some(c))
                if c >= NUISANCE_MIN_CYCLES && next.cyclic_cycles[0].is_none() =>
            {
                next.cyclic_cycles[0] = Some(c)
            }
            ("periodic_theta2", Some(c))
                if c >= NUISANCE_MIN_CYCLES && next.cyclic_cycles[1].is_none() =>
            {
                next.cyclic_cycles[1] = Some(c)
            }
            ("drift_time", _) if problem.has_time => next.drift = true,
            _ => {}
        }
    }
    next
}

pub fn describe_nuisance(n: &Nuisance) -> String {
    let mut parts = Vec::new();
    for (j, c) in n.cyclic_cycles.iter().enumerate() {
        if let Some(c) = c {
            parts.push(format!(
                "periodic error of motor {} at {c} cycles/rev",
                j + 1
            ));
        }
    }
    if n.drift {
        parts.push("drift of the readings in time".to_string());
    }
    if let Some((effect, modes)) = n.shape {
        parts.push(format!(
            "a shape misfit of {effect}: {modes} modes of its generalised shape beyond the library's"
        ));
    }
    parts.join(", ")
}

/// The fitted nuisances, for the report (with how they were found).
pub fn nuisance_report(problem: &Problem, fit: &Fit, s2: f64, mut log: Vec<String>) -> Vec<String> {
    let sd = |k: usize| {
        fit.free
            .iter()
            .position(|&c| c == k)
            .map(|c| (fit.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
            .unwrap_or(f64::NAN)
    };
    for (j, c) in problem.nuisance.cyclic_cycles.iter().enumerate() {
        if let Some(c) = c {
            let (a, b) = (fit.p[idx::CYCLIC + 2 * j], fit.p[idx::CYCLIC + 2 * j + 1]);
            log.push(format!(
                "motor {}: {c} cycles/rev, amplitude {:.1} µrad (cos {a:.1} ± {:.1}, sin {b:.1} ± {:.1})",
                j + 1,
                a.hypot(b),
                sd(idx::CYCLIC + 2 * j),
                sd(idx::CYCLIC + 2 * j + 1)
            ));
        }
    }
    if problem.nuisance.drift {
        let k = idx::DRIFT;
        log.push(format!(
            "drift since the first reading: x {:.2} ± {:.2}, y {:.2} ± {:.2} µm per 1000 s",
            fit.p[k],
            sd(k),
            fit.p[k + 1],
            sd(k + 1)
        ));
    }
    log
}
