//! The diagnosis (`host-sim diagnose`, docs/design/diagnosis.md): find where the model and the measurements
//! disagree, name the missing effect, add it to the model and show the gap shrink.
//!
//! Pipeline, top to bottom in [`diagnose_with_plot_data`], one stage per file: residuals of the
//! current model ([`forward_model`]) → stepwise selection over the effect library with a BIC
//! score ([`selection`], scored by [`scoring`], fits by [`fit`]: the crate's one LM), with
//! out-of-library structures fitted as nuisances ([`nuisance`]) → the shape check: effects named
//! beside one whose library shape misfits must stand on their own against its generalised shape
//! ([`shape`]), and effects named where the library's stretch could have been must stand on their
//! own against a stretch of another law ([`stand_in`]; each effect's standing judged in
//! [`standing`]) → the gap-shrink table
//! ([`gap_shrink`]) → confounding of the chosen effects with the other candidates
//! ([`confounding`]) and the choices the data leave open ([`ambiguity`]) → the verdict on what
//! is left ([`verdict`], structure tests in [`structure`]) → report and table ([`report`]) and
//! plots ([`plots`]). [`diagnose`] is the whole analysis on in-memory
//! measurements, so the tests and studies call it directly. [`crate::synth`] generates test data.
//!
//! Where a change goes: a new effect is a [`crate::effect::PhysicalEffect`] variant, an entry of
//! [`library::LIBRARY`] and its term in `Problem::predict`; a new structure test in
//! `structure.rs`; a new report field in `report.rs` (the contract keys stay).
//!
//! Noise σ: `--noise-um` if given, else estimated from repeated poses (same angles and
//! directions, e.g. several `run`s), else unknown — then scores compare against the residual
//! variance only and "unexplained" rests on the structure tests.
//!
//! Cost: a few dozen LM fits of ≤ 18 parameters; about a second for 650 points (dev profile).

pub mod ambiguity;
pub mod confounding;
pub mod error;
pub mod fit;
pub mod forward_model;
pub mod gap_shrink;
pub mod library;
pub mod misfit_modes;
pub mod model_out;
pub mod moves;
pub mod nuisance;
pub mod plausible;
pub mod plots;
pub mod report;
pub mod scoring;
pub mod selection;
pub mod shape;
pub mod sixbar_modes;
pub mod stand_in;
pub mod standing;
pub mod structure;
pub mod verdict;

use crate::io::measurement_csv::Measurement;
use crate::loop_closure::SixBarDesign;
use fit::Fit;
use forward_model::Problem;
use kinematics_core::FiveBar;
use library::{Effect, LIBRARY};
use report::Report;
use scoring::{sigma2, Fitter};
use std::collections::HashMap;

pub use error::DiagnoseError;
pub use nuisance::{library_residual, NUISANCE_MIN_CYCLES, SUSPECT_DRIFT_Z};
pub use plots::ResidualPlotData;

/// What to diagnose against.
#[derive(Clone, Debug)]
pub struct DiagnoseOptions {
    /// The current model (the start; effects are added to it).
    pub base: FiveBar<f64>,
    /// Measurement noise, one standard deviation per axis (µm); `None`: from repeated poses, if
    /// any.
    pub noise_um: Option<f64>,
    /// The machine's six-bar design, which `link_stretch` and `parallelogram_mismatch` are
    /// derived from (`SixBarDesign::for_model` of the machine's nominal five-bar, or its
    /// drawing).
    pub sixbar: SixBarDesign,
}

impl DiagnoseOptions {
    /// Options for the paper machine's six-bar (the design of its nominal five-bar).
    pub fn paper(base: FiveBar<f64>, noise_um: Option<f64>) -> Self {
        DiagnoseOptions {
            base,
            noise_um,
            sixbar: SixBarDesign::paper(),
        }
    }
}

/// The whole analysis on in-memory measurements.
pub fn diagnose(data: &[Measurement], opts: &DiagnoseOptions) -> Result<Report, DiagnoseError> {
    diagnose_with_plot_data(data, opts).map(|(r, _)| r)
}

/// Pooled standard deviation per axis over groups of repeated poses (same angles to 1e-6° and
/// same directions); `None` without at least 3 degrees of freedom.
pub fn noise_from_repeats_um(data: &[Measurement]) -> Option<(f64, usize)> {
    let mut groups: HashMap<(i64, i64, i8, i8), Vec<[f64; 2]>> = HashMap::new();
    for m in data {
        let key = (
            (m.theta_deg[0] * 1e6).round() as i64,
            (m.theta_deg[1] * 1e6).round() as i64,
            m.dir.map(|d| d[0]).unwrap_or(0),
            m.dir.map(|d| d[1]).unwrap_or(0),
        );
        groups.entry(key).or_default().push(m.measured_mm);
    }
    let (mut ss, mut dof) = (0.0, 0usize);
    for g in groups.values().filter(|g| g.len() >= 2) {
        for axis in 0..2 {
            let mean = g.iter().map(|p| p[axis]).sum::<f64>() / g.len() as f64;
            ss += g.iter().map(|p| (p[axis] - mean).powi(2)).sum::<f64>();
        }
        dof += 2 * (g.len() - 1);
    }
    (dof >= 3).then(|| ((ss / dof as f64).sqrt() * 1e3, dof))
}

/// The data prepared for the selection: the problem, the notes about dropped points, and the
/// noise σ with where it came from.
struct Prepared {
    problem: Problem,
    notes: Vec<String>,
    noise_um: Option<f64>,
    noise_source: String,
}

/// Checks the options, builds the problem (dropping what the base model cannot reach) and
/// decides the noise σ: given, else pooled from repeated poses, else unknown.
fn prepare(data: &[Measurement], opts: &DiagnoseOptions) -> Result<Prepared, DiagnoseError> {
    if let Some(s) = opts.noise_um {
        if !(s.is_finite() && s > 0.0) {
            return Err(DiagnoseError::Invalid(format!(
                "the noise σ must be a positive number of micrometres, not {s}"
            )));
        }
    }
    let problem = Problem::new(opts.base, &opts.sixbar, data);
    let mut notes = Vec::new();
    if !problem.dropped_lines.is_empty() {
        notes.push(format!(
            "{} point(s) have no forward solution with the base model, are at a singularity, or its six-bar has no \
             loop response there, and are excluded: lines {:?}",
            problem.dropped_lines.len(),
            problem.dropped_lines
        ));
    }
    if problem.points.len() < 3 {
        return Err(DiagnoseError::TooFewPoints(problem.points.len()));
    }
    let (noise_um, noise_source) = match opts.noise_um {
        Some(s) => (Some(s), "given (--noise-um)".to_string()),
        None => match noise_from_repeats_um(data) {
            Some((s, dof)) => (
                Some(s),
                format!("estimated from repeated poses ({dof} degrees of freedom)"),
            ),
            None => (
                None,
                "unknown: no --noise-um and no repeated poses".to_string(),
            ),
        },
    };
    Ok(Prepared {
        problem,
        notes,
        noise_um,
        noise_source,
    })
}

/// [`diagnose`], also returning the residual fields for the plots. The stages in order (module
/// doc), then the report.
pub fn diagnose_with_plot_data(
    data: &[Measurement],
    opts: &DiagnoseOptions,
) -> Result<(Report, ResidualPlotData), DiagnoseError> {
    let Prepared {
        mut problem,
        mut notes,
        noise_um,
        noise_source,
    } = prepare(data, opts)?;
    let (sel, nuisance_log) = nuisance::select_with_nuisances(&mut problem, data, noise_um)?;
    let (mut sel, mut shape_misfit, shape_log) = shape::check_shapes(&mut problem, sel, noise_um);
    sel.log.extend(shape_log);
    if shape_misfit.is_none() {
        let (stand_in, log) = stand_in::check_stand_ins(&problem, &sel, noise_um);
        sel.log.extend(log);
        shape_misfit = stand_in;
    }
    notes.extend(sel.skipped.iter().cloned());
    let problem = problem;
    let mut fitter = Fitter::new(&problem);
    let table = gap_shrink::gap_shrink(&problem, &mut fitter, &sel, noise_um)?;
    let last = &table.last;
    let s2_final = sigma2(&problem, noise_um, &[last]);
    let final_params = gap_shrink::params_of(last, &sel.effects, s2_final);
    let candidates: Vec<&'static Effect> = LIBRARY
        .iter()
        .filter(|e| problem.available(e).is_ok())
        .collect();
    let overlaps = confounding::overlaps(&problem, last, &sel.effects, &candidates, s2_final);
    let confounded = confounding::confounded(&overlaps);
    let pose_overlaps = confounding::pose_set_overlaps(&problem, &last.p, &candidates, 0.99);
    let ambiguous = report_ambiguities(&mut fitter, &candidates, &sel.effects, last, noise_um);
    let ambiguous_pairs =
        report_pair_ambiguities(&mut fitter, &candidates, &sel.effects, last, noise_um);
    let not_detected =
        gap_shrink::not_detected(&problem, &mut fitter, &candidates, &sel, last, noise_um);
    let v = verdict::verdict(
        &problem,
        data,
        &sel,
        &table.start_residual,
        &table.last_residual,
        noise_um,
    );
    let last_radial = crate::numeric::stats::max_rms_radial(&table.last_residual);
    let score = format!(
        "BIC = RSS/σ² + k·ln n (n = {} residuals), σ² = max(noise², smaller residual variance of the two models compared); \
         add if ΔBIC < −{}, remove if ΔBIC < 0, swap if ΔBIC < −{}",
        scoring::n_res(&problem),
        selection::ADD_MARGIN,
        selection::SWAP_MARGIN
    );
    let report = Report {
        points: problem.points.len(),
        dropped_lines: problem.dropped_lines.clone(),
        noise_um,
        noise_source,
        score,
        initial_rms_um: table.initial.rms,
        initial_max_um: table.initial.max,
        steps: table.steps,
        final_params,
        confounded,
        ambiguous,
        ambiguous_pairs,
        overlaps,
        not_detected,
        pose_overlaps,
        unexplained: v.unexplained,
        unexplained_description: v.description,
        final_structure: v.final_structure,
        initial_structure: v.initial_structure,
        final_rms_um: last_radial.rms,
        final_max_um: last_radial.max,
        chi2_per_dof: v.chi2_per_dof,
        nuisances: nuisance::nuisance_report(&problem, last, s2_final, nuisance_log),
        shape_misfits: shape_misfit.into_iter().collect(),
        selection_log: sel.log,
        notes,
    };
    let base_mm = problem.points.iter().map(|p| p.measured_mm).collect();
    Ok((
        report,
        ResidualPlotData {
            base_mm,
            fields: table.fields,
            problem,
        },
    ))
}

/// [`ambiguity::ambiguities`] as the report's entries, each with the measurement that separates the pair.
fn report_ambiguities(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Vec<report::Ambiguous> {
    ambiguity::ambiguities(fitter, candidates, set, cur, noise_um)
        .into_iter()
        .map(|a| report::Ambiguous {
            effect: a.effect.name().to_string(),
            alternative: a.alternative.name().to_string(),
            delta_bic: a.delta_bic,
            delta_cv_rss_um2: a.delta_cv_rss_um2,
            separate_by: confounding::separating_measurement(a.effect.name(), a.alternative.name()),
        })
        .collect()
}

/// [`ambiguity::pair_ambiguities`] as the report's entries.
fn report_pair_ambiguities(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Vec<report::AmbiguousPair> {
    ambiguity::pair_ambiguities(fitter, candidates, set, cur, noise_um)
        .into_iter()
        .map(|a| report::AmbiguousPair {
            effects: a.effects.iter().map(|e| e.name().to_string()).collect(),
            alternatives: a
                .alternatives
                .iter()
                .map(|e| e.name().to_string())
                .collect(),
            delta_bic: a.delta_bic,
            delta_cv_rss_um2: a.delta_cv_rss_um2,
        })
        .collect()
}
