//! `full`'s blunder test: fit, find the rows the rest of the data cannot explain, drop them and
//! fit again; name every dropped row; refuse when too many would go.
//!
//! Why: laser-tracker files contain blunders (a mis-sighted point, a row with x and y swapped).
//! One such row among 60 moves a least-squares fit by many standard deviations; silently kept it
//! spoils the model, silently dropped it hides a problem with the measurement.
//!
//! The test, per round (at most [`MAX_ROUNDS`] + 1 fits):
//! * each row's test residual (µm): for a row the fit used, its *studentized deleted residual*
//!   `|(I − Hᵢᵢ)^(−1/2)·rᵢ|` ([`super::full::studentized_deleted_residuals_um`]): the
//!   hat-matrix leave-one-out prediction error `(I − Hᵢᵢ)⁻¹·rᵢ` (a row is judged by a fit it did
//!   not pull towards itself) scaled by `(I − Hᵢᵢ)^(1/2)` to the spread it has under pure noise,
//!   `N(0, σ²I)` at every row. Unscaled, a high-leverage row (the D-optimal poses sit at the
//!   workspace's edges) had a deleted residual up to `1/√(1 − h)` times larger by nature, and on
//!   the `paper` plant read by an instrument better than 0.5 µm the five-bar's own error at those
//!   poses passed for 5 blunders in 40 rows and the fit was refused; for a row rejected earlier,
//!   its residual under this fit (which did not use it);
//! * the scale σ (µm per coordinate): the largest of the machine file's instrument σ, the
//!   robust estimate `median(|e|) / √(2 ln 2)` over the fitted rows (the median of a 2-D
//!   Gaussian error's length is `σ·√(2 ln 2)`; a few blunders do not move a median) and the
//!   upper-quantile estimate `quantile(|e|, 0.8) / √(2 ln 5)` (the same σ for Gaussian
//!   residuals; larger when the good rows' residuals have heavier tails, as the five-bar's own
//!   error on the six-bar has; up to 20 % blunders leave the 0.8 quantile on a good row, so a
//!   flood of them is still refused). The largest, because the model's own systematic error on
//!   a real machine exceeds the instrument's noise and is no blunder;
//! * the threshold `t = max(k, √(2 ln(100·N)))` σ with `k` the `--reject-sigma` value and N the
//!   rows of the file: the second term is the Bonferroni bound at which N clean Gaussian rows lose
//!   one with probability 1 % (`P(|e| > tσ) = exp(−t²/2)` per row), so large clean data sets do
//!   not shed rows by chance (N = 60: 4.2σ; 1,000: 4.8σ; 20,000: 5.4σ);
//! * the rows beyond `t·σ` are the rejected set, decided afresh each round: a good row dragged
//!   beyond the threshold by a blunder's pull on the first fit comes back once the blunder is out;
//!   the rest are fitted again from the start model.
//!
//! The first fit leaves out the rows beyond `t·σ₀` of the start (nominal) model, σ₀ from the
//! median of its errors: a gross blunder (x and y swapped: 200 mm) would pull an all-rows fit
//! until a pose became unreachable. A good row left out there comes back in the next round.
//!
//! It stops when the rejected set no longer changes (1 fit on clean data). When more than [`MAX_REJECT_FRACTION`] of the rows
//! would be rejected the fit is refused: then the data or the model are wrong, not a few rows.
//! The rows report their residual against the final fit (which did not use them) in µm and in
//! units of the final σ. Cost: one fit per round plus O(N·k²) for the deleted residuals.

use super::full::{fit_full, studentized_deleted_residuals_um, FullFit};
use super::params;
use crate::calib::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::numeric::stats::median;
use crate::numeric::{round3, round6};
use kinematics_core::FiveBar;
use serde::Serialize;

/// The default `k` of the threshold (`--reject-sigma`).
pub const DEFAULT_REJECT_SIGMA: f64 = 4.0;
/// More rejected rows than this fraction of the data refuse the fit.
pub const MAX_REJECT_FRACTION: f64 = 0.10;
/// At most this many rounds of rejection (then the last fit stands).
pub const MAX_ROUNDS: usize = 4;
/// The Bonferroni bound's false-alarm probability over the whole data set.
const FALSE_ALARM: f64 = 0.01;
/// `median(|e|) / σ` for a 2-D Gaussian error of σ per coordinate: `√(2 ln 2)`.
const RAYLEIGH_MEDIAN: f64 = 1.177_410_022_515_474_6;
/// The upper quantile of `|e|` that also sets the scale: at most this fraction of blunders
/// leaves it on a good row (twice the fraction a fit may reject, so that a flood of blunders
/// is still seen and refused).
const UPPER_QUANTILE: f64 = 0.8;
/// `quantile(|e|, 0.8) / σ` for a 2-D Gaussian error: `√(2 ln 5)`.
const RAYLEIGH_UPPER: f64 = 1.794_122_577_994_101_5;

/// How to test for blunders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RejectOptions {
    /// `k` of the threshold (σ units); 0 turns the test off.
    pub reject_sigma: f64,
    /// The instrument's σ per coordinate (µm), the floor of the scale.
    pub instrument_sigma_um: f64,
}

/// Where the test's scale came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SigmaSource {
    /// The machine file's instrument σ (larger than the residuals' robust estimate).
    Instrument,
    /// `median(|deleted residual|) / √(2 ln 2)`.
    ResidualMedian,
    /// `quantile(|deleted residual|, 0.8) / √(2 ln 5)`: larger than the median's when the good
    /// rows' residuals have heavier tails than a Gaussian's (the five-bar's own error on the
    /// six-bar, read by an instrument better than that error).
    ResidualUpperQuantile,
}

/// A rejected row.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RejectedRow {
    /// 1-based data row (the n-th measurement of the file).
    pub row: usize,
    /// Line in the file (1-based, the header counted).
    pub line: usize,
    /// `|FK(angles) − measured|` under the final fit, which did not use the row (µm).
    pub residual_um: f64,
    /// `residual_um` over the final σ.
    pub sigma_units: f64,
}

/// What the blunder test did (the `blunders` record of the fit summary).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlunderReport {
    pub what: &'static str,
    /// `k` as given.
    pub reject_sigma: f64,
    /// The threshold applied to the final fit's rows (σ units).
    pub threshold_sigma: f64,
    /// The final σ per coordinate (µm) and its source.
    pub sigma_um: f64,
    pub sigma_source: SigmaSource,
    /// Fits run (1 when nothing was rejected).
    pub fits: usize,
    /// Whether the rejected set stopped changing; `false`: [`MAX_ROUNDS`] ran out and the last
    /// fit stands (rows near the threshold flip in and out).
    pub settled: bool,
    pub rejected: Vec<RejectedRow>,
}

/// The final fit on the kept rows and what the test did.
#[derive(Clone, Debug)]
pub struct RobustFit {
    pub fit: FullFit,
    /// The rows fitted (0-based, in file order).
    pub kept: Vec<usize>,
    /// `None` when the test is off.
    pub report: Option<BlunderReport>,
}

/// The threshold (σ units) for `n` rows: `max(k, √(2 ln(100·n)))`.
pub fn threshold_sigma(reject_sigma: f64, n: usize) -> f64 {
    reject_sigma.max((2.0 * (n.max(1) as f64 / FALSE_ALARM).ln()).sqrt())
}

/// The scale (µm) of the deleted residuals `e` (µm; `None` = not predictable, ignored).
fn scale_um(e: &[Option<f64>], instrument_sigma_um: f64) -> (f64, SigmaSource) {
    let mut ok: Vec<f64> = e.iter().flatten().copied().collect();
    let robust = median(&mut ok).map_or(0.0, |m| m / RAYLEIGH_MEDIAN);
    let upper = quantile(&mut ok, UPPER_QUANTILE).map_or(0.0, |q| q / RAYLEIGH_UPPER);
    if upper > robust.max(instrument_sigma_um) {
        (upper, SigmaSource::ResidualUpperQuantile)
    } else if robust > instrument_sigma_um {
        (robust, SigmaSource::ResidualMedian)
    } else {
        (instrument_sigma_um, SigmaSource::Instrument)
    }
}

/// The `q`-quantile of `values` (nearest rank), `None` when empty.
fn quantile(values: &mut [f64], q: f64) -> Option<f64> {
    let k = ((q * values.len() as f64).ceil() as usize).clamp(1, values.len().max(1)) - 1;
    (!values.is_empty()).then(|| *values.select_nth_unstable_by(k, f64::total_cmp).1)
}

/// Refuses a threshold that is not a number of σ (negative, NaN, infinite).
pub fn check_options(o: &RejectOptions) -> Result<(), CalibError> {
    if !o.reject_sigma.is_finite() || o.reject_sigma < 0.0 {
        return Err(invalid!("reject-sigma {} is not a threshold: give a number of σ ≥ 0 (0 turns the blunder test off)", o.reject_sigma));
    }
    if o.reject_sigma > 0.0 && o.reject_sigma < 2.0 {
        return Err(invalid!("reject-sigma {} would reject good rows: give at least 2 (or 0 to turn the blunder test off)", o.reject_sigma));
    }
    Ok(())
}

fn subset(data: &[Measurement], rows: &[usize]) -> Vec<Measurement> {
    rows.iter().map(|&i| data[i].clone()).collect()
}

/// Each row's test residual (µm) under `fit`, the fit of the rows `kept` (0-based, ascending):
/// the studentized deleted residual for a kept row, the plain residual for a rejected one (the
/// fit did not use it); `None` for a row that cannot be predicted (leverage one, or
/// unreachable).
fn test_residuals_um(data: &[Measurement], kept: &[usize], fit: &FullFit) -> Vec<Option<f64>> {
    let mut e: Vec<Option<f64>> = data
        .iter()
        .map(|m| params::residuals_mm(&fit.model, std::slice::from_ref(m)).map(|r| r.norm() * 1e3))
        .collect();
    for (&i, d) in kept.iter().zip(studentized_deleted_residuals_um(fit)) {
        e[i] = d;
    }
    e
}

/// The rows the first fit uses: those within `t` σ of the start model, σ from the median of
/// the start model's errors (a swapped x/y row, 200 mm off, would otherwise pull the first fit
/// until a pose is unreachable). Every row whose error cannot be computed is kept (the fit
/// names it), and so is every row when more than half would go (the start is too poor to judge).
fn prescreen(
    data: &[Measurement],
    start: &FiveBar<f64>,
    t: f64,
    instrument_sigma_um: f64,
) -> Vec<usize> {
    let e: Vec<Option<f64>> = data
        .iter()
        .map(|m| params::residuals_mm(start, std::slice::from_ref(m)).map(|r| r.norm() * 1e3))
        .collect();
    let (sigma_um, _) = scale_um(&e, instrument_sigma_um);
    let kept: Vec<usize> = (0..data.len())
        .filter(|&i| e[i].is_none_or(|v| v <= t * sigma_um))
        .collect();
    if 2 * kept.len() < data.len() {
        (0..data.len()).collect()
    } else {
        kept
    }
}

/// [`fit_full`] with the blunder test of the module doc.
pub fn fit_full_robust(
    data: &[Measurement],
    start: &FiveBar<f64>,
    fixed_by_user: &[usize],
    o: &RejectOptions,
) -> Result<RobustFit, CalibError> {
    check_options(o)?;
    let n = data.len();
    let all: Vec<usize> = (0..n).collect();
    if o.reject_sigma == 0.0 {
        return Ok(RobustFit {
            fit: fit_full(data, start, fixed_by_user)?,
            kept: all,
            report: None,
        });
    }
    let allowed = (MAX_REJECT_FRACTION * n as f64).floor() as usize;
    let t = threshold_sigma(o.reject_sigma, n);
    let mut kept = prescreen(data, start, t, o.instrument_sigma_um);
    let mut fits = 0;
    loop {
        let fit = fit_full(&subset(data, &kept), start, fixed_by_user)?;
        fits += 1;
        let e = test_residuals_um(data, &kept, &fit);
        let kept_e: Vec<Option<f64>> = kept.iter().map(|&i| e[i]).collect();
        let (sigma_um, source) = scale_um(&kept_e, o.instrument_sigma_um);
        // A rejected row comes back when the fit without it explains it (it was dragged out by
        // the blunders of an earlier round); the set is re-decided every round.
        let beyond: Vec<usize> = (0..n)
            .filter(|&i| e[i].is_some_and(|v| v > t * sigma_um))
            .collect();
        let settled =
            beyond.len() + kept.len() == n && beyond.iter().all(|i| kept.binary_search(i).is_err());
        if settled || fits > MAX_ROUNDS {
            if beyond.len() > allowed {
                let rows: Vec<String> = beyond
                    .iter()
                    .take(20)
                    .map(|i| (i + 1).to_string())
                    .collect();
                return Err(invalid!(
                    "blunder test: {} of {n} rows lie beyond {t:.1} σ (σ = {sigma_um:.2} µm), more than the {:.0} % ({allowed} rows) a fit may reject: \
                     the data or the model are wrong, not a few rows (rows {}{}); check the file, or give --reject-sigma 0 to fit every row",
                    beyond.len(),
                    MAX_REJECT_FRACTION * 100.0,
                    rows.join(", "),
                    if beyond.len() > 20 { ", ..." } else { "" }
                ));
            }
            let rejected: Vec<usize> = (0..n).filter(|i| kept.binary_search(i).is_err()).collect();
            let report = BlunderReport {
                what: "rows whose studentized leave-one-out residual exceeds threshold_sigma x sigma_um, rejected and the rest refitted",
                reject_sigma: o.reject_sigma,
                threshold_sigma: round3(t),
                sigma_um: round6(sigma_um),
                sigma_source: source,
                fits,
                settled,
                rejected: rejected
                    .iter()
                    .map(|&i| {
                        let r = e[i].unwrap_or(f64::INFINITY);
                        RejectedRow { row: i + 1, line: data[i].line, residual_um: round3(r), sigma_units: round3(r / sigma_um) }
                    })
                    .collect(),
            };
            return Ok(RobustFit {
                fit,
                kept,
                report: Some(report),
            });
        }
        let mut out = vec![false; n];
        beyond.iter().for_each(|&i| out[i] = true);
        kept = (0..n).filter(|&i| !out[i]).collect();
    }
}
