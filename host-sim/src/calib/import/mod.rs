//! A real instrument's export turned into the measurement CSV: a laser tracker's (or
//! interferometer's) points (`io::tracker_export`, read through a column map) joined by point
//! id with the commanded list of the session (`io::commanded_csv`: what `command` wrote and the
//! controller was told, in session order), optionally with the plan's list the angles were
//! commanded for (its `run` and `dir` columns). `host-sim import` is the command line's edge;
//! `fit`, `grid`, `accuracy` and `verify` read what it writes.
//!
//! # Point ids
//! An id is a prefix and a number: the number is the id's trailing decimal digits (`P017` →
//! 17, `Pt-3` → 3, `42` → 42), the prefix everything before them. Point number `first_id`
//! (default 1) is the commanded list's first row, `first_id + 1` its second, and so on: a
//! tracker numbering its points `P001, P002, ...` as the session visits the list's rows maps
//! one to one. All points of the export must share one prefix, unless `id_prefix` says which
//! prefix the session's points carry: then the other points (reference nests, `BASE1`, ...)
//! are skipped with a note.
//!
//! # What is checked, what is noted
//! * A point whose number is not a row of the list: an error (a wrong list or numbering), or
//!   with [`Unlisted::Skip`] a note naming them.
//! * A row of the list with no reading (the tracker lost the beam): a note naming them, or with
//!   [`Missing::Refuse`] an error.
//! * Repeated readings of a point are kept, each its own row, `run` = the reading's index (0,
//!   1, ... in export order) added to the list's run; `fit` takes them as separate poses and
//!   `grid` averages them. In a list of several runs (a plan's `repeat.csv`, whose runs
//!   `accuracy` analyses) a second reading of a row has no run of its own: refused.
//! * Z (optional): the machine is planar, so Z is not written; its spread about the best-fit
//!   plane is reported and, with `z_tolerance_mm`, refused above it (a blunder, a target
//!   holder not seated); a plane tilted to the export's XY plane is warned about when it
//!   shortens lengths in the plane by more than [`TILT_WARN_UM`] over the measured extent
//!   (the tracker's frame is not aligned with the machine plane).
//! * The frame (when the list has targets and they span ≥ 1 mm): the export's points against
//!   the targets by a similarity fit. A scale outside [0.5, 2] is refused as a unit mistake
//!   (metres read as mm); a mirrored frame (the plane seen from the other side: no rotation
//!   of the model can absorb it) is refused; a rigid-fit residual above [`FRAME_WARN_MM`]
//!   (a numbering off by some rows, a wrong list) is warned about.
//!
//! The rows come out in the list's order (the session's order, which `accuracy` relies on),
//! each with the commanded angles, the measured X, Y, the target and directions when known,
//! and the run.

use crate::io::commanded_csv::CommandedRow;
use crate::io::measurement_csv::Measurement;
use crate::io::targets_csv::ListedTarget;
use crate::io::tracker_export::{Export, ExportPoint};
use crate::numeric::stats::{round3, round6};
use crate::numeric::two_regressors::TwoRegressors;
use serde::Serialize;
use std::collections::BTreeMap;

/// Above this in-plane length error (µm) a tilted plane is warned about.
pub const TILT_WARN_UM: f64 = 1.0;
/// Above this rigid-fit residual (mm) between the export and the targets, a warning.
pub const FRAME_WARN_MM: f64 = 2.0;

/// What to do with export points whose number is no row of the list.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Unlisted {
    #[default]
    Refuse,
    Skip,
}

/// What to do with list rows the export has no reading of.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Missing {
    #[default]
    Note,
    Refuse,
}

/// How to join an export with the commanded list (module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// The prefix of the session's point ids; `None`: every point's, which must be one.
    pub id_prefix: Option<String>,
    /// The point number of the list's first row.
    pub first_id: u64,
    pub unlisted: Unlisted,
    pub missing: Missing,
    /// Largest |Z − best-fit plane| accepted (mm); `None`: reported only.
    pub z_tolerance_mm: Option<f64>,
}

impl Default for ImportOptions {
    fn default() -> Self {
        ImportOptions {
            id_prefix: None,
            first_id: 1,
            unlisted: Unlisted::Refuse,
            missing: Missing::Note,
            z_tolerance_mm: None,
        }
    }
}

/// Why an export cannot be imported.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ImportError {
    #[error("line {line}: point id '{id}' {reason}")]
    PointId {
        line: usize,
        id: String,
        reason: String,
    },
    #[error("point ids with different prefixes: '{first}' (line {first_line}) and '{other}' (line {other_line}); give the session's prefix (--id-prefix) to skip the other points")]
    MixedPrefixes {
        first: String,
        first_line: usize,
        other: String,
        other_line: usize,
    },
    #[error("line {line}: point '{id}' is number {number}, but the list's rows are numbers {first_id}..={last_id} ({rows} rows; --first-id sets the first); skip such points with --skip-unlisted")]
    Unlisted {
        line: usize,
        id: String,
        number: u64,
        first_id: u64,
        last_id: u64,
        rows: usize,
    },
    #[error("{} of the list's {rows} rows have no reading: points {}", numbers.len(), short_list(numbers))]
    Missing { numbers: Vec<u64>, rows: usize },
    #[error("line {line}: point '{id}' is read again, but the list is a repeat list (its rows carry runs 0..={max_run}) and a second reading has no run of its own; delete the extra reading")]
    RepeatedInRunList {
        line: usize,
        id: String,
        max_run: u32,
    },
    #[error("the plan list and the commanded list differ: {0}")]
    PlanMismatch(String),
    #[error("line {line}: point '{id}' is {residual_mm:.4} mm off the best-fit plane of the points' Z, above the tolerance {tolerance_mm} mm")]
    ZTolerance {
        line: usize,
        id: String,
        residual_mm: f64,
        tolerance_mm: f64,
    },
    #[error("the export's points span {scale:.4}× the targets' distances: {hint}")]
    Scale { scale: f64, hint: String },
    #[error("the export's frame is mirrored relative to the machine's (rigid residual {proper_rms_mm:.3} mm RMS, {mirrored_rms_mm:.3} mm with one axis flipped): the tracker sees the plane from the other side; flip an axis of its frame and export again")]
    Mirrored {
        proper_rms_mm: f64,
        mirrored_rms_mm: f64,
    },
    #[error("no point of the export is a row of the list")]
    Nothing,
    #[error("--first-id {first_id}: the list's {rows} rows would be numbered past {}, the largest point number; give the number of the list's first point", u64::MAX)]
    FirstIdTooLarge { first_id: u64, rows: usize },
}

/// Numbers as a short list for messages (the first 20, then how many more).
fn short_list(numbers: &[u64]) -> String {
    let mut s: Vec<String> = numbers.iter().take(20).map(u64::to_string).collect();
    if numbers.len() > 20 {
        s.push(format!("... ({} more)", numbers.len() - 20));
    }
    s.join(", ")
}

/// Z against the points' best-fit plane.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ZReport {
    pub points: usize,
    /// max − min of Z (mm).
    pub range_mm: f64,
    /// |Z − plane|, max and RMS (µm). The report's figures are rounded (µm to 1 nm, mm and
    /// mrad to 6 decimals).
    pub plane_residual_max_um: f64,
    pub plane_residual_rms_um: f64,
    /// The plane's angle to the export's XY plane (mrad).
    pub tilt_mrad: f64,
    /// How much shorter the tilt makes lengths in the plane over the measured extent (µm).
    pub tilt_length_error_um: f64,
    pub tolerance_mm: Option<f64>,
}

/// The export's points against the list's targets (module doc, *The frame*).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameReport {
    /// Distances between the export's points over the targets' (1 when the units agree).
    pub scale: f64,
    /// Residual of the best rigid motion (rotation + shift) from targets to points (mm).
    pub rigid_residual_max_mm: f64,
    pub rigid_residual_rms_mm: f64,
}

/// What the import did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImportReport {
    pub export_points: usize,
    pub list_rows: usize,
    /// Measurement rows written.
    pub imported: usize,
    /// List rows with at least one reading.
    pub rows_measured: usize,
    pub first_id: u64,
    pub id_prefix: String,
    /// Point numbers of list rows with no reading.
    pub missing: Vec<u64>,
    /// Point numbers read more than once.
    pub repeated: Vec<u64>,
    /// Export ids skipped: not the session's prefix, or numbers no row of the list has.
    pub skipped: Vec<String>,
    pub z: Option<ZReport>,
    pub frame: Option<FrameReport>,
    /// Everything a user should read (the reader's notes too).
    pub notes: Vec<String>,
    /// The notes that point at a likely mistake.
    pub warnings: Vec<String>,
}

/// The measurement rows and the report.
#[derive(Clone, Debug, PartialEq)]
pub struct Imported {
    pub rows: Vec<Measurement>,
    pub report: ImportReport,
}

/// One list row: what was commanded, with the plan's columns merged in.
struct Row {
    theta_deg: [f64; 2],
    target_mm: Option<[f64; 2]>,
    dir: Option<[i8; 2]>,
    run: Option<u32>,
}

/// The list rows, the plan's run and dir merged in where the commanded list has none.
fn merge(
    commanded: &[CommandedRow],
    plan: Option<&[ListedTarget]>,
) -> Result<Vec<Row>, ImportError> {
    if let Some(p) = plan {
        if p.len() != commanded.len() {
            return Err(ImportError::PlanMismatch(format!(
                "{} plan rows, {} commanded",
                p.len(),
                commanded.len()
            )));
        }
    }
    commanded
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let p = plan.map(|p| p[k]);
            if let (Some(p), Some(t)) = (p, c.target_mm) {
                if (p.target_mm[0] - t[0]).abs() > 1e-6 || (p.target_mm[1] - t[1]).abs() > 1e-6 {
                    return Err(ImportError::PlanMismatch(format!(
                        "row {} (plan line {}, commanded line {}): target ({}, {}) against ({}, {})",
                        k + 1,
                        p.line,
                        c.line,
                        p.target_mm[0],
                        p.target_mm[1],
                        t[0],
                        t[1]
                    )));
                }
            }
            Ok(Row {
                theta_deg: c.theta_deg,
                target_mm: c.target_mm.or(p.map(|p| p.target_mm)),
                dir: c.dir.or(p.and_then(|p| p.dir)),
                run: c.run.or(p.and_then(|p| p.run)),
            })
        })
        .collect()
}

/// An id's prefix and number (module doc, *Point ids*).
fn split_id(p: &ExportPoint) -> Result<(&str, u64), ImportError> {
    let digits = p.id.bytes().rev().take_while(u8::is_ascii_digit).count();
    let (prefix, number) = p.id.split_at(p.id.len() - digits);
    if number.is_empty() {
        return Err(ImportError::PointId {
            line: p.line,
            id: p.id.clone(),
            reason: "ends in no number (ids are a prefix and the point number, e.g. P017)".into(),
        });
    }
    let n = number.parse().map_err(|_| ImportError::PointId {
        line: p.line,
        id: p.id.clone(),
        reason: "has a number too large".into(),
    })?;
    Ok((prefix, n))
}

/// Joins `export` with the commanded list (and the plan's list it was commanded for).
pub fn import(
    export: &Export,
    commanded: &[CommandedRow],
    plan: Option<&[ListedTarget]>,
    opts: &ImportOptions,
) -> Result<Imported, ImportError> {
    let rows = merge(commanded, plan)?;
    let n = rows.len();
    // Numbers past u64::MAX would wrap to the list's start.
    let last_id = opts
        .first_id
        .checked_add(n.saturating_sub(1) as u64)
        .ok_or(ImportError::FirstIdTooLarge {
            first_id: opts.first_id,
            rows: n,
        })?;
    let mut notes = export.notes.clone();
    let mut warnings = Vec::new();
    let mut skipped = Vec::new();
    let mut prefix_seen: Option<(String, usize)> = None;
    // Readings per list row, in export order.
    let mut readings: BTreeMap<usize, Vec<&ExportPoint>> = BTreeMap::new();
    for p in &export.points {
        let number = match &opts.id_prefix {
            Some(want) => match p.id.strip_prefix(want.as_str()) {
                Some(rest) if !rest.is_empty() && rest.bytes().all(|b| b.is_ascii_digit()) => {
                    split_id(p)?.1
                }
                _ => {
                    skipped.push(p.id.clone());
                    continue;
                }
            },
            None => {
                let (prefix, number) = split_id(p)?;
                match &prefix_seen {
                    None => prefix_seen = Some((prefix.to_string(), p.line)),
                    Some((first, first_line)) if first != prefix => {
                        return Err(ImportError::MixedPrefixes {
                            first: first.clone(),
                            first_line: *first_line,
                            other: prefix.to_string(),
                            other_line: p.line,
                        });
                    }
                    Some(_) => {}
                }
                number
            }
        };
        if number < opts.first_id || number > last_id {
            match opts.unlisted {
                Unlisted::Refuse => {
                    return Err(ImportError::Unlisted {
                        line: p.line,
                        id: p.id.clone(),
                        number,
                        first_id: opts.first_id,
                        last_id,
                        rows: n,
                    })
                }
                Unlisted::Skip => {
                    skipped.push(p.id.clone());
                    continue;
                }
            }
        }
        readings
            .entry((number - opts.first_id) as usize)
            .or_default()
            .push(p);
    }
    if !skipped.is_empty() {
        notes.push(format!(
            "{} point(s) skipped (not the session's): {}",
            skipped.len(),
            skipped.join(", ")
        ));
    }
    if readings.is_empty() {
        return Err(ImportError::Nothing);
    }
    let number = |k: usize| opts.first_id + k as u64;
    let missing: Vec<u64> = (0..n)
        .filter(|k| !readings.contains_key(k))
        .map(number)
        .collect();
    if !missing.is_empty() {
        match opts.missing {
            Missing::Refuse => {
                return Err(ImportError::Missing {
                    numbers: missing,
                    rows: n,
                })
            }
            Missing::Note => notes.push(format!(
                "{} of the list's {n} rows have no reading (not written): points {}",
                missing.len(),
                short_list(&missing)
            )),
        }
    }
    let runs: Vec<u32> = rows.iter().filter_map(|r| r.run).collect();
    let max_run = runs.iter().copied().max().unwrap_or(0);
    let repeat_list = runs.iter().any(|&r| r != runs[0]);
    let mut repeated = Vec::new();
    let mut out = Vec::new();
    let mut used: Vec<&ExportPoint> = Vec::new();
    for (&k, points) in &readings {
        if points.len() > 1 {
            if repeat_list {
                return Err(ImportError::RepeatedInRunList {
                    line: points[1].line,
                    id: points[1].id.clone(),
                    max_run,
                });
            }
            repeated.push(number(k));
        }
        let r = &rows[k];
        for (i, p) in points.iter().enumerate() {
            out.push(Measurement {
                theta_deg: r.theta_deg,
                measured_mm: p.xy_mm,
                target_mm: r.target_mm,
                dir: r.dir,
                run: Some(r.run.unwrap_or(0) + i as u32),
                t_s: None,
                line: 0,
            });
            used.push(p);
        }
    }
    if !repeated.is_empty() {
        notes.push(format!(
            "{} point(s) read more than once, each reading kept with its run index: points {}",
            repeated.len(),
            short_list(&repeated)
        ));
    }
    let z = z_check(&used, opts.z_tolerance_mm)?;
    if let Some(z) = &z {
        if z.tilt_length_error_um > TILT_WARN_UM {
            warnings.push(format!(
                "the points lie on a plane tilted {:.2} mrad to the export's XY plane: lengths in the plane read up to {:.1} µm short over the measured extent; align the tracker's frame with the machine plane and export again",
                z.tilt_mrad, z.tilt_length_error_um
            ));
        }
    }
    let frame = frame_check(&out)?;
    if let Some(f) = &frame {
        if f.rigid_residual_max_mm > FRAME_WARN_MM {
            warnings.push(format!(
                "the points are up to {:.2} mm from the targets after the best rotation and shift: check the numbering (--first-id) and that the list is the session's",
                f.rigid_residual_max_mm
            ));
        }
    }
    let report = ImportReport {
        export_points: export.points.len(),
        list_rows: n,
        imported: out.len(),
        rows_measured: readings.len(),
        first_id: opts.first_id,
        id_prefix: opts
            .id_prefix
            .clone()
            .or(prefix_seen.map(|p| p.0))
            .unwrap_or_default(),
        missing,
        repeated,
        skipped,
        z,
        frame,
        notes,
        warnings,
    };
    Ok(Imported { rows: out, report })
}

/// Z of the imported points against their best-fit plane (module doc).
fn z_check(
    points: &[&ExportPoint],
    tolerance_mm: Option<f64>,
) -> Result<Option<ZReport>, ImportError> {
    let with_z: Vec<(&ExportPoint, f64)> = points
        .iter()
        .filter_map(|p| p.z_mm.map(|z| (*p, z)))
        .collect();
    if with_z.is_empty() {
        return Ok(None);
    }
    let count = with_z.len() as f64;
    let mean = |f: &dyn Fn(&(&ExportPoint, f64)) -> f64| with_z.iter().map(f).sum::<f64>() / count;
    let (mx, my, mz) = (
        mean(&|p| p.0.xy_mm[0]),
        mean(&|p| p.0.xy_mm[1]),
        mean(&|p| p.1),
    );
    // z − z̄ = b (x − x̄) + c (y − ȳ), least squares; a plane needs points not on one line.
    let mut plane = TwoRegressors::default();
    for (p, z) in &with_z {
        plane.add(p.xy_mm[0] - mx, p.xy_mm[1] - my, z - mz);
    }
    let (b, c) = if with_z.len() >= 3 && plane.det() > 1e-9 * (plane.uu + plane.vv).powi(2) {
        plane.solve()
    } else {
        (0.0, 0.0)
    };
    let residual =
        |(p, z): &(&ExportPoint, f64)| z - mz - b * (p.xy_mm[0] - mx) - c * (p.xy_mm[1] - my);
    let worst = with_z
        .iter()
        .max_by(|a, b2| residual(a).abs().total_cmp(&residual(b2).abs()))
        .expect("not empty");
    let max_mm = residual(worst).abs();
    let rms_mm = (with_z.iter().map(|p| residual(p).powi(2)).sum::<f64>() / count).sqrt();
    if let Some(t) = tolerance_mm {
        if max_mm > t {
            return Err(ImportError::ZTolerance {
                line: worst.0.line,
                id: worst.0.id.clone(),
                residual_mm: max_mm,
                tolerance_mm: t,
            });
        }
    }
    let tilt_rad = b.hypot(c).atan();
    let span = |a: usize| {
        let v = with_z.iter().map(|p| p.0.xy_mm[a]);
        v.clone().fold(f64::NEG_INFINITY, f64::max) - v.fold(f64::INFINITY, f64::min)
    };
    let extent_mm = span(0).hypot(span(1));
    let zs = with_z.iter().map(|p| p.1);
    Ok(Some(ZReport {
        points: with_z.len(),
        range_mm: round6(
            zs.clone().fold(f64::NEG_INFINITY, f64::max) - zs.fold(f64::INFINITY, f64::min),
        ),
        plane_residual_max_um: round3(max_mm * 1e3),
        plane_residual_rms_um: round3(rms_mm * 1e3),
        tilt_mrad: round6(tilt_rad * 1e3),
        tilt_length_error_um: round3(extent_mm * (1.0 - tilt_rad.cos()) * 1e3),
        tolerance_mm,
    }))
}

/// The best rigid motion (rotation + shift) from `from` to `to`: its RMS and max residual.
fn rigid_residual(from: &[[f64; 2]], to: &[[f64; 2]]) -> (f64, f64) {
    let n = from.len() as f64;
    let centre = |v: &[[f64; 2]]| {
        [
            v.iter().map(|p| p[0]).sum::<f64>() / n,
            v.iter().map(|p| p[1]).sum::<f64>() / n,
        ]
    };
    let (cf, ct) = (centre(from), centre(to));
    let (mut dot, mut cross) = (0.0, 0.0);
    for (f, t) in from.iter().zip(to) {
        let (a, b) = ([f[0] - cf[0], f[1] - cf[1]], [t[0] - ct[0], t[1] - ct[1]]);
        dot += a[0] * b[0] + a[1] * b[1];
        cross += a[0] * b[1] - a[1] * b[0];
    }
    let (s, c) = cross.atan2(dot).sin_cos();
    let r: Vec<f64> = from
        .iter()
        .zip(to)
        .map(|(f, t)| {
            let a = [f[0] - cf[0], f[1] - cf[1]];
            (c * a[0] - s * a[1] + ct[0] - t[0]).hypot(s * a[0] + c * a[1] + ct[1] - t[1])
        })
        .collect();
    (
        (r.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        r.iter().copied().fold(0.0, f64::max),
    )
}

/// The export's points against the targets (module doc, *The frame*); `None` without targets
/// spanning ≥ 1 mm RMS.
fn frame_check(rows: &[Measurement]) -> Result<Option<FrameReport>, ImportError> {
    let pairs: Vec<([f64; 2], [f64; 2])> = rows
        .iter()
        .filter_map(|m| m.target_mm.map(|t| (t, m.measured_mm)))
        .collect();
    if pairs.len() < 3 {
        return Ok(None);
    }
    let (targets, measured): (Vec<[f64; 2]>, Vec<[f64; 2]>) = pairs.into_iter().unzip();
    let spread = |v: &[[f64; 2]]| {
        let n = v.len() as f64;
        let c = [
            v.iter().map(|p| p[0]).sum::<f64>() / n,
            v.iter().map(|p| p[1]).sum::<f64>() / n,
        ];
        (v.iter()
            .map(|p| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    };
    let st = spread(&targets);
    if st < 1.0 {
        return Ok(None);
    }
    let scale = spread(&measured) / st;
    if !(0.5..=2.0).contains(&scale) {
        let hint = if (0.5e-3..=2e-3).contains(&scale) {
            "the export looks like metres read as mm: give --units m".to_string()
        } else if (0.5e3..=2e3).contains(&scale) {
            "the export looks like mm read as metres: give --units mm".to_string()
        } else {
            "a unit mistake, or the wrong list".to_string()
        };
        return Err(ImportError::Scale { scale, hint });
    }
    let (rms, max) = rigid_residual(&targets, &measured);
    let flipped: Vec<[f64; 2]> = measured.iter().map(|p| [p[0], -p[1]]).collect();
    let (mirrored_rms, _) = rigid_residual(&targets, &flipped);
    if rms > 1.0 && mirrored_rms < 0.1 * rms {
        return Err(ImportError::Mirrored {
            proper_rms_mm: rms,
            mirrored_rms_mm: mirrored_rms,
        });
    }
    Ok(Some(FrameReport {
        scale: round6(scale),
        rigid_residual_max_mm: round6(max),
        rigid_residual_rms_mm: round6(rms),
    }))
}

#[cfg(test)]
mod tests;
