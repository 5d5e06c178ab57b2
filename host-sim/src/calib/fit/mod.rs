//! The hidden-robot fits: the paper's `poly` and `ls` (with its subset search) and the full
//! nonlinear fit `full`. See `docs/reference/calibration-tools.md` for the commands and
//! `docs/design/hidden-robot.md` for the Table I story.
//!
//! One algorithm per file: [`poly`] (Eqs. 1–3), [`least_squares`] (Eqs. 4–6), [`subset_search`],
//! [`evaluate`] (the error criteria), [`params`] (the parameter vector, residual and std-dev
//! names), [`identifiability`], [`full`] (the LM fit). This file is the flow, top to bottom:
//! check the data ([`check_data`]), fit by the method ([`fit`]: dyad synthesis on the chosen
//! points, or `full`), and summarise ([`FitSummary`], what `fit` prints and stores in the model
//! file's `fit` record).
//!
//! Where a change goes: a new method is a [`Method`] variant, its algorithm in its own file and
//! its arm in [`fit`]; a new figure of a fit is a field of [`FitSummary`] (keys are the JSON's).

pub mod blunders;
pub mod evaluate;
pub mod full;
pub mod identifiability;
pub mod least_squares;
pub mod params;
pub mod plausibility;
pub mod poly;
pub mod registration;
pub mod subset_search;

use super::frame::{FrameSummary, InstrumentFrame};
use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::MachineSpec;
use crate::numeric::{max_rms, round6, MaxRms};
use blunders::{fit_full_robust, BlunderReport, RejectOptions, RobustFit};
use evaluate::Criterion;
use full::{leave_one_out_um, FullFit, LooMethod};
use identifiability::WARN_CONDITION;
use kinematics_core::FiveBar;
use poly::DyadPoint;
pub use registration::FrameMode;
use serde::Serialize;
use std::collections::BTreeMap;
use subset_search::{Best, Progress, Stage};

/// Which synthesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Precision points, 2 per dyad (paper Sec. III-A).
    Poly,
    /// Least squares per dyad on the algebraic residual (paper Sec. III-B).
    Ls,
    /// Levenberg–Marquardt on the position residual over all identifiable parameters.
    Full,
}

/// Which points the dyad syntheses (`poly`, `ls`) use.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Points {
    /// Every point (`ls`; `poly` only with exactly two).
    All,
    /// These points (0-based).
    Chosen(Vec<usize>),
    /// The subset, of any of these sizes, whose largest error (by the criterion) over all points
    /// is smallest (the paper's Sec. III-C).
    Search { sizes: Vec<usize> },
}

/// How to fit.
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub method: Method,
    /// The error measure of the subset search and of the reported max/RMS.
    pub criterion: Criterion,
    /// `poly`, `ls`: the points used.
    pub points: Points,
    /// `full`: parameters held at nominal (indices into [`params::NAMES`]).
    pub fixed: Vec<usize>,
    /// `full`: predict every point from a fit on the others (N extra fits).
    pub leave_one_out: bool,
    /// `full`: the blunder test's `k` (σ units, see [`blunders`]); 0 fits every row.
    pub reject_sigma: f64,
    /// Whether the instrument's frame is registered with the model ([`registration`]).
    pub frame: FrameMode,
    /// The machine (its nominal model is the start and the base).
    pub spec: MachineSpec,
}

/// Max and RMS (µm), as reported.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MaxRmsUm {
    pub max_um: f64,
    pub rms_um: f64,
}

impl From<MaxRms> for MaxRmsUm {
    fn from(m: MaxRms) -> Self {
        MaxRmsUm {
            max_um: round6(m.max),
            rms_um: round6(m.rms),
        }
    }
}

/// Both error measures of a model.
#[derive(Clone, Debug, Serialize)]
pub struct Errors {
    /// `|FK(angles) − measured|`.
    pub vs_measured: MaxRmsUm,
    /// `|FK(angles) − target|`, when every row has a target.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_target: Option<MaxRmsUm>,
}

/// Each point predicted by a fit on the others.
#[derive(Clone, Debug, Serialize)]
pub struct LeaveOneOut {
    pub what: &'static str,
    /// Exact refits, or the linearised (hat-matrix) update.
    pub method: LooMethod,
    /// Over the points that could be predicted; `null` when none could.
    pub max_um: Option<f64>,
    pub rms_um: Option<f64>,
    /// Points the others could not predict (their fit failed).
    pub failed: usize,
    /// Per point (0.1 µm), `null` where the fit on the rest failed.
    pub per_point_um: Vec<Option<f64>>,
}

/// A parameter `full` held at its nominal value, and why.
#[derive(Clone, Debug, Serialize)]
pub struct Held {
    pub param: &'static str,
    pub held_at: &'static str,
    /// The confounded combination it was part of, or "fixed by --fix".
    pub confounded: String,
}

/// What the identifiability check found (`full`).
#[derive(Clone, Debug, Serialize)]
pub struct IdentifiabilitySummary {
    pub rank_all_params: usize,
    pub condition_number_free: f64,
    pub singular_values_rel: Vec<f64>,
    pub poorly_conditioned: bool,
}

/// A model's parameters as reports list them (mm, degrees; 6 decimals).
#[derive(Clone, Debug, Serialize)]
pub struct ModelFigures {
    pub a_mm: f64,
    pub b_mm: f64,
    pub c_mm: f64,
    pub d_mm: f64,
    pub base_a0_mm: [f64; 2],
    pub base_b0_mm: [f64; 2],
    pub encoder_offset_deg: [f64; 2],
}

impl ModelFigures {
    /// The figures of `m`.
    pub fn of(m: &FiveBar<f64>) -> Self {
        ModelFigures {
            a_mm: round6(m.a_mm),
            b_mm: round6(m.b_mm),
            c_mm: round6(m.c_mm),
            d_mm: round6(m.d_mm),
            base_a0_mm: m.base_a0_mm.map(round6),
            base_b0_mm: m.base_b0_mm.map(round6),
            encoder_offset_deg: m.encoder_offset_rad.map(|v| round6(v.to_degrees())),
        }
    }
}

/// A fitted model's summary: what `host-sim fit` prints and stores in the model file.
#[derive(Clone, Debug, Serialize)]
pub struct FitSummary {
    pub method: Method,
    pub criterion: Criterion,
    pub n_points: usize,
    #[serde(flatten)]
    pub model: ModelFigures,
    /// The points used (1-based), when not all.
    pub subset: Option<Vec<usize>>,
    /// By the criterion.
    pub max_err_um: f64,
    pub rms_err_um: f64,
    pub point_err_um: Vec<f64>,
    pub errors: Errors,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub leave_one_out: Option<LeaveOneOut>,
    /// `full`: one standard deviation per fitted parameter (offsets in degrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub std_dev: Option<BTreeMap<String, f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fixed: Option<Vec<Held>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub identifiability: Option<IdentifiabilitySummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma_um: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
    /// `full`: the blunder test and the rows it rejected (the summary's other figures are over
    /// the kept rows).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blunders: Option<BlunderReport>,
    /// The instrument's frame registered with the model (`calib::frame`); the errors above are
    /// of the readings mapped into the machine frame by it. Absent with `FrameMode::Machine`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instrument_frame: Option<FrameSummary>,
}

/// A fit's result.
#[derive(Clone, Debug)]
pub struct FitOutcome {
    /// The model, in the machine frame when `frame` is given.
    pub model: FiveBar<f64>,
    /// The registered instrument frame (`None` with `FrameMode::Machine`): what `model.json`
    /// stores and later readings of the set-up are mapped by.
    pub frame: Option<InstrumentFrame>,
    pub summary: FitSummary,
    /// Standard deviations as `model.json` stores them (unrounded; empty for `poly`, `ls`).
    pub std_dev: BTreeMap<String, f64>,
    /// `full`: the fit with its identifiability and solver record (`model` and `std_dev` in
    /// the machine frame as above; `lm` is the solver's record, made on the readings in the
    /// first registration's frame).
    pub full: Option<FullFit>,
    /// The subset search's counts, if one ran.
    pub search: Option<SearchCounts>,
}

/// How a subset search went.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SearchCounts {
    pub tried: u64,
    pub valid: u64,
    pub elapsed_s: f64,
    pub best_max_um: f64,
}

/// The dyad observations of a subset: arm 1 about A0, arm 2 about B0, geometric angles.
fn dyad_points(
    data: &[Measurement],
    subset: &[usize],
    base: &FiveBar<f64>,
) -> (Vec<DyadPoint>, Vec<DyadPoint>) {
    let mut arm1 = Vec::with_capacity(subset.len());
    let mut arm2 = Vec::with_capacity(subset.len());
    for &i in subset {
        let m = &data[i];
        let th = m.theta_rad();
        let [x, y] = m.measured_mm;
        let a0 = base.base_a0_mm;
        arm1.push(DyadPoint {
            theta_rad: th[0] + base.encoder_offset_rad[0],
            x_mm: x - a0[0],
            y_mm: y - a0[1],
        });
        arm2.push(DyadPoint {
            theta_rad: th[1] + base.encoder_offset_rad[1],
            x_mm: x - a0[0] - base.base_b0_mm[0],
            y_mm: y - a0[1] - base.base_b0_mm[1],
        });
    }
    (arm1, arm2)
}

/// The paper's synthesis on the points `subset` (0-based): links a, b (arm 1) and d, c (arm 2);
/// base offset, encoder offsets and working mode are kept from `base`.
pub fn synthesize(
    data: &[Measurement],
    subset: &[usize],
    method: Method,
    base: &FiveBar<f64>,
) -> Result<FiveBar<f64>, CalibError> {
    if let Some(&i) = subset.iter().find(|&&i| i >= data.len()) {
        return Err(invalid!(
            "point {} does not exist (the data have {} points)",
            i + 1,
            data.len()
        ));
    }
    let (arm1, arm2) = dyad_points(data, subset, base);
    let arm = |name: &str, r: Result<(f64, f64), CalibError>| r.map_err(|e| e.context(name));
    let ((a, b), (d, c)) = match method {
        Method::Poly => {
            if subset.len() != 2 {
                return Err(invalid!(
                    "poly uses exactly 2 precision points, got {}",
                    subset.len()
                ));
            }
            (
                arm(
                    "arm 1 (a, b)",
                    poly::precision_point_dyad([arm1[0], arm1[1]]),
                )?,
                arm(
                    "arm 2 (d, c)",
                    poly::precision_point_dyad([arm2[0], arm2[1]]),
                )?,
            )
        }
        Method::Ls => (
            arm("arm 1 (a, b)", least_squares::least_squares_dyad(&arm1))?,
            arm("arm 2 (d, c)", least_squares::least_squares_dyad(&arm2))?,
        ),
        Method::Full => return Err(invalid!("synthesize: full is not a dyad synthesis")),
    };
    let m = FiveBar {
        a_mm: a,
        b_mm: b,
        c_mm: c,
        d_mm: d,
        ..*base
    };
    m.validate()
        .map_err(|e| invalid!("fitted model invalid: {e}"))?;
    Ok(m)
}

/// Refuses two rows with the same motor angles (the same pose measured twice would weigh
/// double and, in a precision-point pair, make the system singular). Cost: one sort,
/// O(N log N) (100,000 rows in milliseconds).
pub fn check_duplicates(data: &[Measurement]) -> Result<(), CalibError> {
    // Bit patterns compare equal exactly when the numbers do (every value is finite; -0 and 0
    // are made one).
    let key = |m: &Measurement| (m.theta_deg.map(|t| (t + 0.0).to_bits()), m.run);
    let mut order: Vec<usize> = (0..data.len()).collect();
    order.sort_by_key(|&i| (key(&data[i]), i));
    let mut first: Option<(usize, usize)> = None;
    for w in order.windows(2) {
        let (i, j) = (w[0], w[1]);
        if key(&data[i]) == key(&data[j]) {
            // The first duplicate in file order: the later row of the pair, the earlier row it repeats.
            let pair = (j, i);
            if first.is_none_or(|f| data[pair.0].line < data[f.0].line) {
                first = Some(pair);
            }
        }
    }
    match first {
        Some((later, earlier)) => Err(invalid!(
            "line {}: duplicate point, same motor angles as line {}",
            data[later].line,
            data[earlier].line
        )),
        None => Ok(()),
    }
}

/// What every fit needs of the data: the criterion's reference on every row, no pose twice.
pub fn check_data(data: &[Measurement], criterion: Criterion) -> Result<(), CalibError> {
    evaluate::check_criterion(data, criterion)?;
    check_duplicates(data)
}

fn model_errors(model: &FiveBar<f64>, data: &[Measurement]) -> Errors {
    let vs_target = data
        .iter()
        .all(|m| m.target_mm.is_some())
        .then(|| max_rms(&evaluate::errors_um(model, data, Criterion::Paper)).into());
    Errors {
        vs_measured: max_rms(&evaluate::errors_um(model, data, Criterion::Measured)).into(),
        vs_target,
    }
}

/// The summary of a fitted model (the method-specific parts empty).
fn summary(
    method: Method,
    criterion: Criterion,
    model: &FiveBar<f64>,
    data: &[Measurement],
    subset: Option<&[usize]>,
) -> FitSummary {
    let errors = evaluate::errors_um(model, data, criterion);
    let MaxRms { max, rms } = max_rms(&errors);
    FitSummary {
        method,
        criterion,
        n_points: data.len(),
        model: ModelFigures::of(model),
        subset: subset.map(|s| s.iter().map(|i| i + 1).collect()),
        max_err_um: round6(max),
        rms_err_um: round6(rms),
        point_err_um: errors.iter().map(|&e| (e * 10.0).round() / 10.0).collect(),
        errors: model_errors(model, data),
        leave_one_out: None,
        std_dev: None,
        fixed: None,
        identifiability: None,
        sigma_um: None,
        iterations: None,
        blunders: None,
        instrument_frame: None,
    }
}

fn leave_one_out(method: LooMethod, per_point_um: &[Option<f64>]) -> LeaveOneOut {
    let ok: Vec<f64> = per_point_um.iter().flatten().copied().collect();
    let figures = (!ok.is_empty()).then(|| max_rms(&ok));
    LeaveOneOut {
        what: "each point predicted by a fit on the other points: |FK(angles) - measured|",
        method,
        max_um: figures.map(|f| round6(f.max)),
        rms_um: figures.map(|f| round6(f.rms)),
        failed: per_point_um.len() - ok.len(),
        per_point_um: per_point_um
            .iter()
            .map(|e| e.map(|v| (v * 10.0).round() / 10.0))
            .collect(),
    }
}

/// `(done, total)` of a long step as [`Progress`], about once a second.
fn throttled<'a>(
    progress: &'a mut dyn FnMut(Progress),
    stage: Stage,
) -> impl FnMut(usize, usize) + 'a {
    let mut last = std::time::Instant::now();
    move |done, total| {
        if last.elapsed() > std::time::Duration::from_secs(1) {
            last = std::time::Instant::now();
            progress(Progress {
                stage,
                tried: done as u64,
                total: total as u128,
                best_max_um: f64::NAN,
            });
        }
    }
}

/// Leave-one-out of the `ls` fit on every point: each point predicted by the fit on the others,
/// computed from the normal equations' sums less the point (exact, O(N)). `None` where the rest
/// give no dyad.
pub fn ls_leave_one_out_um(data: &[Measurement], nominal: &FiveBar<f64>) -> Vec<Option<f64>> {
    let all: Vec<usize> = (0..data.len()).collect();
    let (arm1, arm2) = dyad_points(data, &all, nominal);
    let (s1, s2) = (
        least_squares::DyadSums::of(&arm1),
        least_squares::DyadSums::of(&arm2),
    );
    (0..data.len())
        .map(|i| {
            let (a, b) = s1.without(&arm1[i]).solve().ok()?;
            let (d, c) = s2.without(&arm2[i]).solve().ok()?;
            let m = FiveBar {
                a_mm: a,
                b_mm: b,
                c_mm: c,
                d_mm: d,
                ..*nominal
            };
            m.validate().ok()?;
            let e = evaluate::errors_um(&m, &data[i..=i], Criterion::Measured)[0];
            e.is_finite().then_some(e)
        })
        .collect()
}

/// The dyad synthesis (`poly`, `ls`) of `data` (readings in the machine frame) by `opts`, with
/// the subset search when asked: the model, the subset fitted (when not all) and the search's
/// counts.
type DyadFit = (FiveBar<f64>, Option<Vec<usize>>, Option<SearchCounts>);

fn dyad_fit(
    data: &[Measurement],
    opts: &FitOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<DyadFit, CalibError> {
    let nominal = opts.spec.nominal;
    let n = data.len();
    match &opts.points {
        Points::Search { sizes } => {
            if n < 2 {
                return Err(invalid!("the data have {n} point; a fit needs at least 2"));
            }
            let Best {
                model,
                subset,
                tried,
                valid,
                elapsed_s,
                max_err_um,
                ..
            } = subset_search::search(
                n,
                sizes,
                |s| synthesize(data, s, opts.method, &nominal),
                |m| evaluate::errors_um(m, data, opts.criterion),
                progress,
            )?;
            Ok((
                model,
                Some(subset),
                Some(SearchCounts {
                    tried,
                    valid,
                    elapsed_s,
                    best_max_um: max_err_um,
                }),
            ))
        }
        Points::All | Points::Chosen(_) => {
            let subset: Vec<usize> = match &opts.points {
                Points::Chosen(p) => p.clone(),
                _ => (0..n).collect(),
            };
            if subset.len() < 2 {
                return Err(invalid!(
                    "a dyad fit needs at least 2 points, got {}",
                    subset.len()
                ));
            }
            let m = synthesize(data, &subset, opts.method, &nominal)?;
            Ok((
                m,
                matches!(opts.points, Points::Chosen(_)).then_some(subset),
                None,
            ))
        }
    }
}

/// Fits the hidden robot to `data` (see [`FitOptions`]); `progress` hears from a subset search
/// and from leave-one-out refits. With [`FrameMode::Register`] the instrument's frame is
/// estimated with the model ([`registration`]) and the model and every error reported are in
/// the machine frame.
pub fn fit(
    data: &[Measurement],
    opts: &FitOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<FitOutcome, CalibError> {
    check_data(data, opts.criterion)?;
    let nominal = opts.spec.nominal;
    plausibility::check_units(&nominal, data)?;
    let n = data.len();
    // The first frame (nominal model): the readings brought near the machine, where the fits
    // start from the nominal model.
    let first = match opts.frame {
        FrameMode::Register => Some(registration::register_with(&nominal, data)?),
        FrameMode::Machine => None,
    };
    let frame_of = |t: crate::numeric::Rigid2| InstrumentFrame {
        to_instrument: t,
        std_dev: None,
    };
    let near: Vec<Measurement> = match first {
        Some(t) => frame_of(t).register(data),
        None => data.to_vec(),
    };
    match opts.method {
        Method::Poly | Method::Ls => {
            if !opts.fixed.is_empty() {
                return Err(invalid!("holding parameters applies to the full fit only (poly and ls fit the four links)"));
            }
            let (model, subset, search) = dyad_fit(&near, opts, progress)?;
            let frame = first.map(frame_of);
            let data = &frame.map_or(near, |f| f.register(data));
            plausibility::check_model(
                &model,
                &nominal,
                &[None; params::N_PARAMS],
                data,
                &plausibility::FitEvidence::default(),
            )?;
            let mut s = summary(opts.method, opts.criterion, &model, data, subset.as_deref());
            s.instrument_frame = frame.map(|f| f.summary());
            if opts.method == Method::Ls && subset.is_none() && n >= 3 {
                // Leave-one-out of the all-points least-squares fit: the normal equations' sums
                // less each point's terms (exact, O(N); `least_squares::DyadSums`), the frame
                // held.
                s.leave_one_out = Some(leave_one_out(
                    LooMethod::ExactSums,
                    &ls_leave_one_out_um(data, &nominal),
                ));
            }
            Ok(FitOutcome {
                model,
                frame,
                summary: s,
                std_dev: BTreeMap::new(),
                full: None,
                search,
            })
        }
        Method::Full => {
            if opts.points != Points::All {
                return Err(invalid!(
                    "choosing points applies to poly and ls; full fits every point"
                ));
            }
            let reject = RejectOptions {
                reject_sigma: opts.reject_sigma,
                instrument_sigma_um: opts.spec.instrument_sigma_um,
            };
            let RobustFit {
                fit: mut f,
                kept,
                report,
            } = fit_full_robust(&near, &nominal, &opts.fixed, &reject)?;
            // Into the machine frame: an exact change of frame, the residuals unchanged.
            let frame = first.map(|t| {
                let (model, std_dev, frame) = registration::registered_full(&f, &nominal, &t);
                f.model = model;
                f.std_dev = std_dev;
                frame
            });
            let registered = frame.map_or_else(|| near.clone(), |fr| fr.register(data));
            // The rows fitted: every row unless the blunder test rejected some.
            let kept_data: Vec<Measurement>;
            let data = if kept.len() == n {
                &registered[..]
            } else {
                kept_data = kept.iter().map(|&i| registered[i].clone()).collect();
                &kept_data[..]
            };
            let evidence = plausibility::FitEvidence {
                condition_number: Some(f.identifiability.condition_number),
                residual_sigma_um: Some(f.sigma_mm * 1e3),
                instrument_sigma_um: Some(opts.spec.instrument_sigma_um),
            };
            plausibility::check_model(&f.model, &nominal, &f.std_dev, data, &evidence)?;
            let mut s = summary(opts.method, opts.criterion, &f.model, data, None);
            s.instrument_frame = frame.map(|f| f.summary());
            s.std_dev = Some(
                params::std_dev_map(&f.std_dev)
                    .into_iter()
                    .map(|(k, v)| (k, round6(v)))
                    .collect(),
            );
            let held = |k: usize, why: String| Held {
                param: params::NAMES[k],
                held_at: "nominal",
                confounded: why,
            };
            s.fixed = Some(
                f.identifiability
                    .fixed
                    .iter()
                    .map(|(k, why)| held(*k, why.clone()))
                    .chain(opts.fixed.iter().map(|&k| held(k, "fixed by --fix".into())))
                    .collect(),
            );
            s.identifiability = Some(IdentifiabilitySummary {
                rank_all_params: f.identifiability.rank_all,
                condition_number_free: f.identifiability.condition_number,
                singular_values_rel: f.identifiability.singular_values_rel.clone(),
                poorly_conditioned: f.identifiability.condition_number > WARN_CONDITION,
            });
            s.sigma_um = Some(round6(f.sigma_mm * 1e3));
            s.iterations = Some(f.iterations);
            s.blunders = report;
            if opts.leave_one_out {
                // On the readings the fit was made on (the first frame): the predictions'
                // distances are the same in every frame.
                let near_kept: Vec<Measurement> = kept.iter().map(|&i| near[i].clone()).collect();
                let mut report = throttled(progress, Stage::LeaveOneOut);
                let (method, loo) =
                    leave_one_out_um(&near_kept, &f, &nominal, &opts.fixed, &mut report);
                s.leave_one_out = Some(leave_one_out(method, &loo));
            }
            Ok(FitOutcome {
                model: f.model,
                frame,
                summary: s,
                std_dev: params::std_dev_map(&f.std_dev),
                full: Some(f),
                search: None,
            })
        }
    }
}
