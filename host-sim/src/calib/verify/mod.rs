//! The accuracy report a machine builder hands to a customer (`host-sim verify`): from the
//! verification measurements (the plan's `verify` list) and the repeat runs (the plan's
//! `repeat` list), measured before calibration (nominal model) and after it (model + grid),
//! the figures by the standards and the 2-D position error, each stage beside the other.
//!
//! # What goes in ([`VerifyOptions`])
//! Per stage ([`StageData`]): the verification rows (measurement CSV with `x_target_mm,
//! y_target_mm` on every row) and the repeat rows (targets and `run` on every row, rows in
//! motion order: what `measure --targets repeat.csv` writes). `after` is required, `before`
//! optional (a report of the delivered machine alone).
//!
//! # What comes out ([`VerifyReport`])
//! * the 2-D position error of the verification targets ([`PositionError`]): `|measured −
//!   target|` per row, its max and RMS, the mean error vector (a systematic offset), the per-axis
//!   max |Δx|, |Δy| and RMS: what the instrument read, the only truth a real machine has;
//! * per axis line of the repeat runs: the ISO 230-2 and VDI/DGQ 3441 figures of
//!   [`super::accuracy`] (ONE implementation of the standards; its module doc states every
//!   definition and the approach-direction rule): per target the mean deviations x̄i↑, x̄i↓ and
//!   the estimators si↑, si↓ of the standard deviation; reversal value B, mean reversal B̄,
//!   repeatability R↑, R↓, R, systematic positioning error E, mean bidirectional positional
//!   deviation M, accuracy A (x̄ ± 2s); VDI 3441 position scatter Ps, reversal span U,
//!   positional deviation Pa and positioning uncertainty P;
//! * before/after ratios ([`Improvement`]) when both stages are given;
//! * notes: what the report's reader must know (fewer than the 5 runs ISO 230-2 asks for,
//!   targets outside the machine's workspace).
//!
//! # What is refused (a clear error, never a half report)
//! An empty file, a row without its target (or, in the repeat runs, its run), a non-finite
//! number, an axis line whose targets lack 2 approaches from each direction (no estimator s;
//! "missing directions"), repeat runs without a line along each axis.
//!
//! The report itself (HTML with the plots embedded) is [`html`]; the plots are
//! `crate::io::verify_plot`. Cost: linear in the rows; the plots dominate (~0.1 s each).

pub mod html;

use super::accuracy::{analyse, LineStats};
use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::MachineSpec;
use crate::numeric::max_rms;
use serde::Serialize;

/// Approaches per target and direction ISO 230-2 asks for (5 runs); fewer gives a note.
pub const ISO_RUNS: usize = 5;

/// The measurements of one calibration state.
#[derive(Clone, Debug)]
pub struct StageData {
    /// Verification targets measured once each (or more): rows with targets.
    pub verify: Vec<Measurement>,
    /// Bidirectional repeat runs along axis lines: rows with targets and `run`, in motion order.
    pub repeat: Vec<Measurement>,
}

/// What to report on.
#[derive(Clone, Debug)]
pub struct VerifyOptions {
    /// The machine (its name heads the report; targets outside its workspace get a note).
    pub spec: MachineSpec,
    /// Before calibration (nominal model), if measured.
    pub before: Option<StageData>,
    /// After calibration (the delivered state).
    pub after: StageData,
}

/// The 2-D position error of the verification targets (µm, measured − target).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct PositionError {
    pub n_points: usize,
    /// Largest and RMS length of the error vector.
    pub max_um: f64,
    pub rms_um: f64,
    /// The mean error vector (a systematic offset of the whole workspace).
    pub mean_um: [f64; 2],
    /// Per axis: largest |Δx|, |Δy| and their RMS.
    pub max_abs_um: [f64; 2],
    pub rms_axis_um: [f64; 2],
}

/// One error vector of the map: the target and measured − target (µm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorVector {
    pub target_mm: [f64; 2],
    pub error_um: [f64; 2],
}

/// The figures of one calibration state.
#[derive(Clone, Debug, Serialize)]
pub struct StageReport {
    /// `before` or `after`.
    pub stage: &'static str,
    pub position: PositionError,
    /// Every axis line of the repeat runs (x lines first), with the standards' figures.
    pub lines: Vec<LineStats>,
    /// The verification rows' error vectors (for the map; not in the JSON).
    #[serde(skip)]
    pub vectors: Vec<ErrorVector>,
}

/// Before / after of one figure (> 1: calibration made it smaller).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Ratio {
    pub figure: String,
    pub before_um: f64,
    pub after_um: f64,
    /// before / after (infinite when after is 0).
    pub factor: f64,
}

/// What calibration changed: the position error and each line's A, R, E (ISO 230-2) and P
/// (VDI 3441), for lines present in both stages.
#[derive(Clone, Debug, Serialize)]
pub struct Improvement {
    pub ratios: Vec<Ratio>,
}

/// The report (`host-sim verify`'s JSON; [`html`] renders it with the plots).
#[derive(Clone, Debug, Serialize)]
pub struct VerifyReport {
    pub machine: String,
    pub standards: &'static str,
    /// `before` (if given), then `after`.
    pub stages: Vec<StageReport>,
    pub improvement: Option<Improvement>,
    pub notes: Vec<String>,
}

impl VerifyReport {
    /// The stage named `before` or `after`.
    pub fn stage(&self, name: &str) -> Option<&StageReport> {
        self.stages.iter().find(|s| s.stage == name)
    }
}

/// Every row has what `need` says and only finite numbers (the library's own check: the CSV
/// reader refuses non-finite numbers too, data built in code is checked here).
fn check_rows(rows: &[Measurement], need_run: bool) -> Result<(), CalibError> {
    if rows.is_empty() {
        return Err(invalid!("no measurements"));
    }
    for m in rows {
        let Some(t) = m.target_mm else {
            return Err(invalid!(
                "line {}: every row needs its target (x_target_mm,y_target_mm)",
                m.line
            ));
        };
        if need_run && m.run.is_none() {
            return Err(invalid!(
                "line {}: every row of the repeat runs needs its run",
                m.line
            ));
        }
        if !m.measured_mm.iter().chain(t.iter()).all(|v| v.is_finite()) {
            return Err(invalid!(
                "line {}: a position is not a finite number",
                m.line
            ));
        }
    }
    Ok(())
}

/// The 2-D position error of verification rows (checked).
pub fn position_error(
    rows: &[Measurement],
) -> Result<(PositionError, Vec<ErrorVector>), CalibError> {
    check_rows(rows, false)?;
    let vectors: Vec<ErrorVector> = rows
        .iter()
        .map(|m| {
            let t = m.target_mm.unwrap_or(m.measured_mm);
            ErrorVector {
                target_mm: t,
                error_um: [
                    (m.measured_mm[0] - t[0]) * 1e3,
                    (m.measured_mm[1] - t[1]) * 1e3,
                ],
            }
        })
        .collect();
    let n = vectors.len();
    let length: Vec<f64> = vectors
        .iter()
        .map(|v| v.error_um[0].hypot(v.error_um[1]))
        .collect();
    let radial = max_rms(&length);
    let axis = |k: usize| max_rms(&vectors.iter().map(|v| v.error_um[k]).collect::<Vec<f64>>());
    let (ax, ay) = (axis(0), axis(1));
    let mean = |k: usize| vectors.iter().map(|v| v.error_um[k]).sum::<f64>() / n as f64;
    Ok((
        PositionError {
            n_points: n,
            max_um: radial.max,
            rms_um: radial.rms,
            mean_um: [mean(0), mean(1)],
            max_abs_um: [ax.max, ay.max],
            rms_axis_um: [ax.rms, ay.rms],
        },
        vectors,
    ))
}

/// The axis lines of repeat runs (checked; module doc: what is refused).
pub fn axis_lines(rows: &[Measurement]) -> Result<Vec<LineStats>, CalibError> {
    check_rows(rows, true)?;
    let (lines, skipped) = analyse(rows)?;
    if let Some(s) = skipped.first() {
        return Err(invalid!("{s}"));
    }
    for axis in ["x", "y"] {
        if !lines.iter().any(|l| l.axis == axis) {
            return Err(invalid!(
                "no {axis}-axis line: the repeat runs need targets along a line of each axis, each approached from both directions"
            ));
        }
    }
    Ok(lines)
}

/// One stage's figures; errors name the stage and the list.
fn stage(
    name: &'static str,
    data: &StageData,
    spec: &MachineSpec,
    notes: &mut Vec<String>,
) -> Result<StageReport, CalibError> {
    let (position, vectors) = position_error(&data.verify)
        .map_err(|e| e.context(format!("{name}, verification measurements")))?;
    let lines = axis_lines(&data.repeat).map_err(|e| e.context(format!("{name}, repeat runs")))?;
    let fewest = lines
        .iter()
        .flat_map(|l| l.targets.iter())
        .map(|t| t.n_up.min(t.n_down))
        .min()
        .unwrap_or(0);
    if fewest < ISO_RUNS {
        notes.push(format!(
            "{name}: some targets have only {fewest} approaches from a direction; ISO 230-2 asks for {ISO_RUNS} (the figures are computed, with a wider uncertainty)"
        ));
    }
    let outside = data
        .verify
        .iter()
        .chain(&data.repeat)
        .filter(|m| {
            m.target_mm
                .is_some_and(|t| !spec.workspace.contains(t, 1e-3))
        })
        .count();
    if outside > 0 {
        notes.push(format!(
            "{name}: {outside} targets lie outside machine '{}''s workspace",
            spec.name
        ));
    }
    Ok(StageReport {
        stage: name,
        position,
        lines,
        vectors,
    })
}

/// The same line in another stage (axis and shared coordinate to 1 µm).
pub fn matching_line<'a>(lines: &'a [LineStats], l: &LineStats) -> Option<&'a LineStats> {
    lines
        .iter()
        .find(|o| o.axis == l.axis && (o.at_mm - l.at_mm).abs() < 1e-3)
}

fn improvement(before: &StageReport, after: &StageReport) -> Improvement {
    let ratio = |figure: String, b: f64, a: f64| Ratio {
        figure,
        before_um: b,
        after_um: a,
        factor: if a > 0.0 { b / a } else { f64::INFINITY },
    };
    let mut ratios = vec![
        ratio(
            "position error max".into(),
            before.position.max_um,
            after.position.max_um,
        ),
        ratio(
            "position error RMS".into(),
            before.position.rms_um,
            after.position.rms_um,
        ),
    ];
    for l in &after.lines {
        if let Some(b) = matching_line(&before.lines, l) {
            let at = format!(
                "{} line at {} = {} mm",
                l.axis,
                if l.axis == "x" { "y" } else { "x" },
                l.at_mm
            );
            ratios.push(ratio(
                format!("{at}: ISO 230-2 A"),
                b.iso_230_2.a_um,
                l.iso_230_2.a_um,
            ));
            ratios.push(ratio(
                format!("{at}: ISO 230-2 R"),
                b.iso_230_2.r_um,
                l.iso_230_2.r_um,
            ));
            ratios.push(ratio(
                format!("{at}: ISO 230-2 E"),
                b.iso_230_2.e_um,
                l.iso_230_2.e_um,
            ));
            ratios.push(ratio(
                format!("{at}: VDI 3441 P"),
                b.vdi_3441.p_um,
                l.vdi_3441.p_um,
            ));
        }
    }
    Improvement { ratios }
}

/// The figures of the report (module doc).
pub fn verify(opts: &VerifyOptions) -> Result<VerifyReport, CalibError> {
    let mut notes = Vec::new();
    let mut stages = Vec::new();
    if let Some(b) = &opts.before {
        stages.push(stage("before", b, &opts.spec, &mut notes)?);
    }
    stages.push(stage("after", &opts.after, &opts.spec, &mut notes)?);
    let improvement = match stages.as_slice() {
        [b, a] => Some(improvement(b, a)),
        _ => None,
    };
    Ok(VerifyReport {
        machine: opts.spec.name.clone(),
        standards: "ISO 230-2:2014 (A, R↑, R↓, R, B, B̄, E, M; bidirectional) and VDI/DGQ 3441 (P, Ps, U, Pa); positions measured − target",
        stages,
        improvement,
        notes,
    })
}

#[cfg(test)]
mod tests;
