//! The diagnosis (`host-sim diagnose`, issue 7): find where the model and the measurements
//! disagree, name the missing effect, add it to the model and show the gap shrink.
//!
//! Pipeline, top to bottom in [`diagnose_with_history`]: residuals of the current model
//! ([`forward_model`]) → stepwise selection over the effect library with a BIC score ([`selection`],
//! fits by [`fit`]: the crate's one LM) → confounding of the chosen effects with the other
//! candidates ([`confounding`]) → structure of what is left ([`structure`]) → report and table
//! ([`report`]) and plots ([`plots`]). [`diagnose`] is the whole analysis on in-memory
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

pub mod confounding;
pub mod fit;
pub mod forward_model;
pub mod library;
pub mod model_out;
pub mod plots;
pub mod report;
pub mod selection;
pub mod sixbar_modes;
pub mod structure;

use crate::io::measurement_csv::Measurement;
use crate::io::IoError;
use crate::loop_closure::SixBarDesign;
use crate::numeric::stats::max_rms_radial;
use fit::Fit;
use forward_model::Problem;
use kinematics_core::FiveBar;
use library::{Effect, LIBRARY, N_PARAMS, PARAM_NAMES};
use report::{Param, Report, Step};
use selection::Fitter;
use std::collections::{BTreeMap, HashMap};

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

/// Residual fields of the start and after each step, for the plots.
pub struct History {
    pub base_mm: Vec<[f64; 2]>,
    /// (label, residual µm per point): "start", then one per step.
    pub fields: Vec<(String, Vec<[f64; 2]>)>,
    pub problem: Problem,
}

/// The whole analysis on in-memory measurements.
pub fn diagnose(data: &[Measurement], opts: &DiagnoseOptions) -> Result<Report, DiagnoseError> {
    diagnose_with_history(data, opts).map(|(r, _)| r)
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

fn params_of(fit: &Fit, effects: &[&'static Effect], s2: f64) -> BTreeMap<String, Param> {
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

fn pairs(r: &[f64]) -> Vec<[f64; 2]> {
    r.chunks(2).map(|c| [c[0], c[1]]).collect()
}

/// [`diagnose`], also returning the residual fields for plotting.
pub fn diagnose_with_history(
    data: &[Measurement],
    opts: &DiagnoseOptions,
) -> Result<(Report, History), DiagnoseError> {
    let noise_um_arg = opts.noise_um;
    if let Some(s) = noise_um_arg {
        if !(s.is_finite() && s > 0.0) {
            return Err(DiagnoseError::Invalid(format!(
                "the noise σ must be a positive number of micrometres, not {s}"
            )));
        }
    }
    let mut problem = Problem::new(opts.base, &opts.sixbar, data);
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
    let (noise_um, noise_source) = match noise_um_arg {
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
    let n = (2 * problem.points.len()) as f64;
    // Select; if the residual then shows a structure outside the library (a gear tooth's
    // periodic error, a drift in time), fit it as a nuisance in every model and select again, so
    // that no library effect is named on its account.
    let mut sel = selection::select(&problem, noise_um);
    let mut nuisance_log = Vec::new();
    for _ in 0..3 {
        let residual =
            library_residual(&problem, &sel.fit.p).ok_or(DiagnoseError::NoForwardSolution)?;
        let found = structure::analyse(&problem, data, &residual);
        let next = nuisance_for(&problem, &found);
        if next == problem.nuisance {
            // A trend in time below the drift test's threshold: the selection may have named a
            // library effect on account of the drift's mean (a constant offset that a frame
            // translation, encoder offsets or link lengths reproduce; what is left, a ramp about
            // its mean, is then too weak for |z| > DRIFT_Z). Decide by the model comparison.
            if let Some((with_drift, line)) =
                suspected_drift(&mut problem, data, &residual, &sel, noise_um)
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
        sel = selection::select(&problem, noise_um);
    }
    notes.extend(sel.skipped.iter().cloned());
    // Cumulative fits in the order the final effects were added: the gap-shrink table. Every
    // residual reported is the library model's: a nuisance fitted alongside stays in it
    // (unexplained).
    let mut fitter = Fitter::new(&problem);
    let zero = [0.0; N_PARAMS];
    let start_residual = problem
        .residuals_um(&zero)
        .ok_or(DiagnoseError::NoForwardSolution)?;
    let start = fitter
        .fit(&[], &zero)
        .ok_or(DiagnoseError::NoForwardSolution)?;
    let initial = max_rms_radial(&start_residual);
    let base_mm: Vec<[f64; 2]> = problem.points.iter().map(|p| p.measured_mm).collect();
    let mut fields = vec![("start".to_string(), pairs(&start_residual))];
    let mut steps = Vec::new();
    let mut prev_residual = start_residual.clone();
    let mut last = start.clone();
    for k in 0..sel.effects.len() {
        let set = &sel.effects[..=k];
        let f = fitter
            .fit(set, &sel.fit.p)
            .ok_or(DiagnoseError::Refit(k + 1))?;
        let residual = library_residual(&problem, &f.p).ok_or(DiagnoseError::Refit(k + 1))?;
        let s2 = (f.cost / (n - f.free.len() as f64).max(1.0))
            .max(noise_um.map(|s| s * s).unwrap_or(0.0));
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
    let last_residual = prev_residual;
    let last_cost: f64 = last_residual.iter().map(|v| v * v).sum();
    let k_final = last.free.len() as f64;
    let dof = (n - k_final).max(1.0);
    let s2_final = (last.cost / dof).max(noise_um.map(|s| s * s).unwrap_or(0.0));
    let final_params = params_of(&last, &sel.effects, s2_final);
    let last_radial = max_rms_radial(&last_residual);
    // The library model's own degrees of freedom (the nuisances' part is in its residual).
    let dof_library =
        (n - sel.effects.iter().map(|e| e.params.len()).sum::<usize>() as f64).max(1.0);
    // Confounding with every available candidate.
    let candidates: Vec<&'static Effect> = LIBRARY
        .iter()
        .filter(|e| problem.available(e).is_ok())
        .collect();
    let overlaps = confounding::overlaps(&problem, &last, &sel.effects, &candidates, s2_final);
    let confounded = confounding::confounded(&overlaps);
    let pose_overlaps = confounding::pose_set_overlaps(&problem, &last.p, &candidates, 0.99);
    // Named effects a library twin could replace at less cost than adding an effect needs, or
    // that the twin predicts held-out points better than.
    let ambiguous = selection::ambiguities(&mut fitter, &candidates, &sel.effects, &last, noise_um)
        .into_iter()
        .map(|a| report::Ambiguous {
            effect: a.effect.name().to_string(),
            alternative: a.alternative.name().to_string(),
            delta_bic: a.delta_bic,
            delta_cv_rss_um2: a.delta_cv_rss_um2,
            separate_by: confounding::separating_measurement(a.effect.name(), a.alternative.name()),
        })
        .collect();
    let ambiguous_pairs =
        selection::pair_ambiguities(&mut fitter, &candidates, &sel.effects, &last, noise_um)
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
            .collect();
    // What the data cannot rule out: every candidate left out, fitted on top of the final model.
    let mut not_detected = Vec::new();
    for &c in candidates.iter().filter(|c| !sel.effects.contains(c)) {
        let mut set = sel.effects.clone();
        set.push(c);
        if set.iter().map(|e| e.params.len()).sum::<usize>() as f64 >= n {
            continue;
        }
        if let Some(f) = fitter.fit(&set, &last.p) {
            let s2 = (f.cost / (n - f.free.len() as f64).max(1.0))
                .max(noise_um.map(|s| s * s).unwrap_or(0.0));
            // Column-normalised Jacobian singular below 1e-6: some direction of the candidate is
            // exactly what the final model already does (no bound exists).
            let identifiable = f.svd.min() > 1e-6;
            let mut params = params_of(&f, &[c], s2);
            if !identifiable {
                params.values_mut().for_each(|p| p.std_dev = f64::INFINITY);
            }
            not_detected.push(report::NotDetected {
                effect: c.name().to_string(),
                identifiable,
                params,
                delta_bic: selection::delta_bic(&problem, noise_um, &last, &f),
            });
        }
    }
    // Is anything left above the noise, and what does it look like?
    let initial_structure = structure::analyse(&problem, data, &start_residual);
    let final_structure = structure::analyse(&problem, data, &last_residual);
    let significant: Vec<&structure::Finding> =
        final_structure.iter().filter(|f| f.significant).collect();
    let chi2_per_dof = noise_um.map(|s| last_cost / dof_library / (s * s));
    let (unexplained, mut unexplained_description) = match chi2_per_dof {
        Some(_) if !problem.nuisance.is_empty() => (
            true,
            format!("a structure outside the library is in the data ({}); no library effect is named on its account", describe_nuisance(&problem.nuisance)),
        ),
        Some(c) => {
            // χ² test at ~4σ of the χ² distribution, and a practical floor of 10 % over the noise
            // (a slightly misjudged noise figure must not read as a missing effect).
            let limit = (1.0 + 4.0 * (2.0 / dof_library).sqrt()).max(1.21);
            if c > limit {
                (true, format!("residual is {:.2}× the noise variance (limit {:.2}) and no further library effect is significant", c, limit))
            } else {
                (false, format!("residual at the noise level (χ²/dof {:.2} ≤ {:.2})", c, limit))
            }
        }
        None if final_structure.iter().any(|f| f.kind == "too_few_points") => (
            false,
            "UNDECIDED: noise unknown (no --noise-um, no repeats) and too few points to test the residual's structure; \
             give --noise-um to decide"
                .to_string(),
        ),
        None => {
            if significant.is_empty() {
                (false, "noise unknown; no significant structure left in the residual".to_string())
            } else {
                (true, "noise unknown; the residual has significant structure no library effect explains".to_string())
            }
        }
    };
    if !significant.is_empty() {
        let d: Vec<String> = significant
            .iter()
            .map(|f| format!("[{}] {}", f.kind, f.description))
            .collect();
        unexplained_description.push_str(&format!(". Structure of the residual: {}", d.join("; ")));
    } else if unexplained && final_structure.iter().any(|f| f.kind == "too_few_points") {
        unexplained_description.push_str(&format!(
            ". Too few points ({}) to describe its structure; largest radial residuals: {}",
            problem.points.len(),
            largest_points(data, &problem, &last_residual)
        ));
    } else if unexplained {
        unexplained_description.push_str(&format!(
            ". No test found a structure (not periodic in a motor angle, not direction-dependent, no drift, not smooth over \
             the workspace): looks like extra noise or isolated outliers; largest radial residuals: {}",
            largest_points(data, &problem, &last_residual)
        ));
    }
    let score = format!(
        "BIC = RSS/σ² + k·ln n (n = {} residuals), σ² = max(noise², smaller residual variance of the two models compared); \
         add if ΔBIC < −{}, remove if ΔBIC < 0, swap if ΔBIC < −{}",
        n,
        selection::ADD_MARGIN,
        selection::SWAP_MARGIN
    );
    let report = Report {
        points: problem.points.len(),
        dropped_lines: problem.dropped_lines.clone(),
        noise_um,
        noise_source,
        score,
        initial_rms_um: initial.rms,
        initial_max_um: initial.max,
        steps,
        final_params,
        confounded,
        ambiguous,
        ambiguous_pairs,
        overlaps,
        not_detected,
        pose_overlaps,
        unexplained,
        unexplained_description,
        final_structure,
        initial_structure,
        final_rms_um: last_radial.rms,
        final_max_um: last_radial.max,
        chi2_per_dof,
        nuisances: nuisance_report(&problem, &last, s2_final, nuisance_log),
        selection_log: sel.log,
        notes,
    };
    Ok((
        report,
        History {
            base_mm,
            fields,
            problem,
        },
    ))
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
    sel: &selection::Selection,
    noise_um: Option<f64>,
) -> Option<(selection::Selection, String)> {
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
    let n = (2 * problem.points.len()) as f64;
    let s2 = (sel.fit.cost / (n - sel.fit.free.len() as f64).max(1.0))
        .min(with.fit.cost / (n - with.fit.free.len() as f64).max(1.0))
        .max(noise_um.map(|s| s * s).unwrap_or(0.0));
    let margin = 2.0 * s2;
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
fn nuisance_for(problem: &Problem, found: &[structure::Finding]) -> library::Nuisance {
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

fn describe_nuisance(n: &library::Nuisance) -> String {
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
    parts.join(", ")
}

/// The fitted nuisances, for the report (with how they were found).
fn nuisance_report(problem: &Problem, fit: &Fit, s2: f64, mut log: Vec<String>) -> Vec<String> {
    let sd = |k: usize| {
        fit.free
            .iter()
            .position(|&c| c == k)
            .map(|c| (fit.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
            .unwrap_or(f64::NAN)
    };
    for (j, c) in problem.nuisance.cyclic_cycles.iter().enumerate() {
        if let Some(c) = c {
            let (a, b) = (
                fit.p[library::idx::CYCLIC + 2 * j],
                fit.p[library::idx::CYCLIC + 2 * j + 1],
            );
            log.push(format!(
                "motor {}: {c} cycles/rev, amplitude {:.1} µrad (cos {a:.1} ± {:.1}, sin {b:.1} ± {:.1})",
                j + 1,
                a.hypot(b),
                sd(library::idx::CYCLIC + 2 * j),
                sd(library::idx::CYCLIC + 2 * j + 1)
            ));
        }
    }
    if problem.nuisance.drift {
        let k = library::idx::DRIFT;
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

/// The three largest radial residuals, with their file line (or index) and position.
fn largest_points(data: &[Measurement], problem: &Problem, residual_um: &[f64]) -> String {
    let kept: Vec<&Measurement> = problem
        .points
        .iter()
        .filter_map(|p| data.get(p.index))
        .collect();
    let mut idx: Vec<usize> = (0..problem.points.len()).collect();
    let mag = |i: usize| residual_um[2 * i].hypot(residual_um[2 * i + 1]);
    idx.sort_by(|&a, &b| mag(b).total_cmp(&mag(a)));
    idx.iter()
        .take(3)
        .map(|&i| {
            let p = problem.points[i].measured_mm;
            let line = kept.get(i).map(|m| m.line).unwrap_or(0);
            format!(
                "{:.0} µm at line {line} ({:.1}, {:.1}) mm",
                mag(i),
                p[0],
                p[1]
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}
