//! Positioning accuracy and repeatability (`host-sim accuracy`) per axis line from repeated
//! bidirectional runs, by VDI/DGQ 3441 and ISO 230-2 (the paper reports ±37 µm/m precision and
//! ±26 µm/m repeatability "compatible with VDI/DGQ 3441").
//!
//! # Axis lines
//! Targets sharing y (to 1 nm) form an x-axis line, targets sharing x a y-axis line; a line needs
//! at least two distinct targets. A row counts on an axis-a line only if it lies on a pass along
//! a: its previous or next row in the run with another target differs from it along a only
//! ([`on_pass`]). So where an x line and a y line cross (the repeat protocol's lines share the
//! workspace's centre) each line keeps its own approaches: the y passes' visits of the centre
//! are not x-line approaches (their x direction is not one the x test cycle made). Along an x line the deviation is `x_measured − x_target` (the
//! positioning deviation along the axis; the other coordinate is straightness, not reported).
//!
//! # Approach direction (derived, documented rule)
//! Backlash depends on the last motion *along the axis* before the measurement, so for row r of
//! run k and axis a (rows of a run in file order):
//! 1. the previous row of the run has the *same target* (both coordinates): the machine reversed
//!    there (the overrun at the end of a pass, as in ISO 230-2's linear cycle) → the opposite of
//!    the previous row's direction;
//! 2. else the previous row's target differs along a only → `sign(target_a(r) − target_a(prev))`;
//!    if it differs along both axes (a move from one line to another: a new pass starts, and a
//!    pass starts from its own overrun, as `measure --protocol repeat` makes it) → the
//!    direction of the next move along a within the run (the sign above if there is none);
//! 3. else (the last move was along the other axis only) → the previous row's direction;
//! 4. the first row of a run: the direction of the run's first move along a (approach from an
//!    overrun, as a pass starts); a run that never moves along a has no direction: its rows are
//!    left out of that axis.
//!
//! The `dir1,dir2` columns are motor directions, not axis directions; they are not used here.
//!
//! # Figures (x_ij = deviation of approach j at target i; ↑ positive, ↓ negative direction)
//! `x̄i↑`, `x̄i↓` means, `si↑`, `si↓` sample standard deviations (n − 1), `x̄i = (x̄i↑ + x̄i↓)/2`.
//! * ISO 230-2:2014, clause 2: reversal value `Bi = x̄i↑ − x̄i↓`, `B = max|Bi|`, mean reversal
//!   value `B̄ = Σ Bi / m`; repeatability `Ri = max(2si↑ + 2si↓ + |Bi|, 4si↑, 4si↓)`, `R = max Ri`,
//!   unidirectional `R↑ = max 4si↑`, `R↓ = max 4si↓`;
//!   systematic deviation `E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓)`; mean bidirectional positional
//!   deviation `M = max x̄i − min x̄i`; accuracy
//!   `A = max(x̄i↑ + 2si↑, x̄i↓ + 2si↓) − min(x̄i↑ − 2si↑, x̄i↓ − 2si↓)`.
//! * VDI/DGQ 3441 (1977): reversal span `Ui = |x̄i↑ − x̄i↓|`, `U = max Ui`; position scatter
//!   `Psi = 6·s̄i` with `s̄i = (si↑ + si↓)/2`, `Ps = max Psi`; position deviation
//!   `Pa = max x̄i − min x̄i`; position uncertainty
//!   `P = max(x̄i + (Ui + Psi)/2) − min(x̄i − (Ui + Psi)/2)`.
//!
//! All in µm, and normalised per metre of line length (`figure / length`); the paper's "±"
//! figures are half of the span figures (`P/2`, `Ps/2` per metre).
//! Cost: linear in the rows. Each (target, direction) needs at least 2 approaches (a standard
//! deviation); lines that lack them are listed as skipped with the reason.

use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use serde::Serialize;
use std::collections::BTreeMap;

/// Statistics at one target of a line.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct TargetStats {
    pub position_mm: f64,
    pub n_up: usize,
    pub n_down: usize,
    pub mean_up_um: f64,
    pub mean_down_um: f64,
    pub s_up_um: f64,
    pub s_down_um: f64,
}

/// ISO 230-2 figures (µm).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Iso230 {
    pub a_um: f64,
    pub r_um: f64,
    /// Unidirectional repeatability `R↑ = max 4si↑`, `R↓ = max 4si↓`.
    pub r_up_um: f64,
    pub r_down_um: f64,
    pub b_um: f64,
    pub b_mean_um: f64,
    pub m_um: f64,
    pub e_um: f64,
}

/// VDI/DGQ 3441 figures (µm).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Vdi3441 {
    pub p_um: f64,
    pub ps_um: f64,
    pub u_um: f64,
    pub pa_um: f64,
}

/// One axis line.
#[derive(Clone, Debug, Serialize)]
pub struct LineStats {
    /// "x" or "y".
    pub axis: &'static str,
    /// The shared coordinate (y of an x line, x of a y line).
    pub at_mm: f64,
    pub length_mm: f64,
    pub iso_230_2: Iso230,
    pub vdi_3441: Vdi3441,
    /// Figures per metre of line length (µm/m); `p_pm`/`ps_pm` are the paper's "±" forms.
    pub per_m: BTreeMap<&'static str, f64>,
    pub targets: Vec<TargetStats>,
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// The figures of one line from per-target deviations `(position, up devs, down devs)` (µm).
pub fn line_figures(
    targets: &[TargetDevs],
) -> Result<(Iso230, Vdi3441, Vec<TargetStats>), CalibError> {
    let mut stats = Vec::new();
    for (p, up, down) in targets {
        if up.len() < 2 || down.len() < 2 {
            return Err(invalid!(
                "target {p} mm has {} approaches in + and {} in − direction; each needs at least 2",
                up.len(),
                down.len()
            ));
        }
        let (mu, su) = mean_sd(up);
        let (md, sd) = mean_sd(down);
        stats.push(TargetStats {
            position_mm: *p,
            n_up: up.len(),
            n_down: down.len(),
            mean_up_um: mu,
            mean_down_um: md,
            s_up_um: su,
            s_down_um: sd,
        });
    }
    if stats.len() < 2 {
        return Err(invalid!("a line needs at least 2 targets"));
    }
    let max =
        |f: &dyn Fn(&TargetStats) -> f64| stats.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
    let min = |f: &dyn Fn(&TargetStats) -> f64| stats.iter().map(f).fold(f64::INFINITY, f64::min);
    let b = |t: &TargetStats| t.mean_up_um - t.mean_down_um;
    let mid = |t: &TargetStats| 0.5 * (t.mean_up_um + t.mean_down_um);
    let iso = Iso230 {
        a_um: max(&|t| (t.mean_up_um + 2.0 * t.s_up_um).max(t.mean_down_um + 2.0 * t.s_down_um))
            - min(&|t| (t.mean_up_um - 2.0 * t.s_up_um).min(t.mean_down_um - 2.0 * t.s_down_um)),
        r_um: max(&|t| {
            (2.0 * t.s_up_um + 2.0 * t.s_down_um + b(t).abs())
                .max(4.0 * t.s_up_um)
                .max(4.0 * t.s_down_um)
        }),
        r_up_um: max(&|t| 4.0 * t.s_up_um),
        r_down_um: max(&|t| 4.0 * t.s_down_um),
        b_um: max(&|t| b(t).abs()),
        b_mean_um: stats.iter().map(b).sum::<f64>() / stats.len() as f64,
        m_um: max(&mid) - min(&mid),
        e_um: max(&|t| t.mean_up_um.max(t.mean_down_um))
            - min(&|t| t.mean_up_um.min(t.mean_down_um)),
    };
    let ps = |t: &TargetStats| 6.0 * 0.5 * (t.s_up_um + t.s_down_um);
    let half = |t: &TargetStats| 0.5 * (b(t).abs() + ps(t));
    let vdi = Vdi3441 {
        p_um: max(&|t| mid(t) + half(t)) - min(&|t| mid(t) - half(t)),
        ps_um: max(&ps),
        u_um: max(&|t| b(t).abs()),
        pa_um: max(&mid) - min(&mid),
    };
    Ok((iso, vdi, stats))
}

/// Approach direction (+1/−1, 0 = none) of every row along axis `a` (see the module doc).
pub fn directions(data: &[Measurement], a: usize) -> Vec<i8> {
    let mut dir = vec![0i8; data.len()];
    let mut by_run: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (r, m) in data.iter().enumerate() {
        by_run.entry(m.run.unwrap_or(0)).or_default().push(r);
    }
    // Rows without a target (refused by `analyse`) count as at the origin.
    let t = |r: usize| data[r].target_mm.unwrap_or_default();
    let sign = |d: f64| {
        if d > 0.0 {
            1
        } else if d < 0.0 {
            -1
        } else {
            0
        }
    };
    for rows in by_run.values() {
        for (k, &r) in rows.iter().enumerate() {
            dir[r] = if k == 0 {
                rows.windows(2)
                    .map(|w| sign(t(w[1])[a] - t(w[0])[a]))
                    .find(|&s| s != 0)
                    .unwrap_or(0)
            } else {
                let p = rows[k - 1];
                if t(p) == t(r) {
                    -dir[p]
                } else if t(p)[a] != t(r)[a] && t(p)[1 - a] != t(r)[1 - a] {
                    let next = rows[k..]
                        .windows(2)
                        .map(|w| sign(t(w[1])[a] - t(w[0])[a]))
                        .find(|&s| s != 0);
                    next.unwrap_or_else(|| sign(t(r)[a] - t(p)[a]))
                } else if t(p)[a] != t(r)[a] {
                    sign(t(r)[a] - t(p)[a])
                } else {
                    dir[p]
                }
            };
        }
    }
    dir
}

/// Whether each row lies on a pass along axis `a` (module doc, *Axis lines*): the previous or
/// next row of its run with another target differs from it along `a` only.
pub fn on_pass(data: &[Measurement], a: usize) -> Vec<bool> {
    let mut on = vec![false; data.len()];
    let mut by_run: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (r, m) in data.iter().enumerate() {
        by_run.entry(m.run.unwrap_or(0)).or_default().push(r);
    }
    let t = |r: usize| data[r].target_mm.unwrap_or_default();
    for rows in by_run.values() {
        for (k, &r) in rows.iter().enumerate() {
            let along = |o: &&usize| t(**o)[a] != t(r)[a] && t(**o)[1 - a] == t(r)[1 - a];
            let prev = rows[..k].iter().rev().find(|&&o| t(o) != t(r));
            let next = rows[k + 1..].iter().find(|&&o| t(o) != t(r));
            on[r] = prev.as_ref().is_some_and(along) || next.as_ref().is_some_and(along);
        }
    }
    on
}

/// Deviations (µm) at one target: `(position_mm, + direction, − direction)`.
type TargetDevs = (f64, Vec<f64>, Vec<f64>);
/// Lines of one axis: shared coordinate key → (shared coordinate, position key → deviations).
type AxisGroups = BTreeMap<i64, (f64, BTreeMap<i64, TargetDevs>)>;
/// Sum of error vectors per target: key → (target, Σ error µm, count).
type TargetSums = BTreeMap<(i64, i64), ([f64; 2], [f64; 2], usize)>;

/// Every axis line of the data; lines without enough repeats come back in the second list with
/// the reason.
pub fn analyse(data: &[Measurement]) -> Result<(Vec<LineStats>, Vec<String>), CalibError> {
    for m in data {
        if m.target_mm.is_none() || m.run.is_none() {
            return Err(invalid!(
                "line {}: accuracy needs x_target_mm,y_target_mm and run on every row",
                m.line
            ));
        }
    }
    let key = |v: f64| (v * 1e6).round() as i64;
    let mut lines = Vec::new();
    let mut skipped = Vec::new();
    for (a, axis) in [(0usize, "x"), (1usize, "y")] {
        let other = 1 - a;
        let dir = directions(data, a);
        let on = on_pass(data, a);
        // shared coordinate -> position -> (up, down) deviations
        let mut groups: AxisGroups = BTreeMap::new();
        for (r, m) in data.iter().enumerate().filter(|(r, _)| on[*r]) {
            let t = m.target_mm.unwrap_or_default();
            let g = groups
                .entry(key(t[other]))
                .or_insert((t[other], BTreeMap::new()));
            let e =
                g.1.entry(key(t[a]))
                    .or_insert((t[a], Vec::new(), Vec::new()));
            let dev_um = (m.measured_mm[a] - t[a]) * 1e3;
            match dir[r] {
                1 => e.1.push(dev_um),
                -1 => e.2.push(dev_um),
                _ => {}
            }
        }
        for (_, (at, targets)) in groups {
            if targets.len() < 2 {
                continue;
            }
            let t: Vec<TargetDevs> = targets.into_values().collect();
            match line_figures(&t) {
                Err(e) => skipped.push(format!(
                    "{axis} line at {} = {at} mm: {e}",
                    ["x", "y"][other]
                )),
                Ok((iso, vdi, stats)) => {
                    let length_mm = t.last().expect("≥2").0 - t[0].0;
                    let per = |v: f64| v / (length_mm / 1000.0);
                    let per_m = BTreeMap::from([
                        ("a", per(iso.a_um)),
                        ("r", per(iso.r_um)),
                        ("b", per(iso.b_um)),
                        ("m", per(iso.m_um)),
                        ("p", per(vdi.p_um)),
                        ("ps", per(vdi.ps_um)),
                        ("u", per(vdi.u_um)),
                        ("pa", per(vdi.pa_um)),
                        ("p_pm", per(vdi.p_um) / 2.0),
                        ("ps_pm", per(vdi.ps_um) / 2.0),
                    ]);
                    lines.push(LineStats {
                        axis,
                        at_mm: at,
                        length_mm,
                        iso_230_2: iso,
                        vdi_3441: vdi,
                        per_m,
                        targets: stats,
                    });
                }
            }
        }
    }
    if lines.is_empty() {
        return Err(invalid!(
            "no axis line has at least 2 targets with 2 approaches from each direction{}",
            skipped
                .first()
                .map_or(String::new(), |s| format!(" (e.g. {s})"))
        ));
    }
    Ok((lines, skipped))
}

/// The worst line of one axis.
#[derive(Clone, Debug, Serialize)]
pub struct AxisWorst {
    pub lines: usize,
    pub worst_p_um: f64,
    pub worst_ps_um: f64,
    pub worst_a_um: f64,
    pub worst_r_um: f64,
    pub worst_p_pm_um_per_m: f64,
    pub worst_ps_pm_um_per_m: f64,
}

/// The worst line per axis (`None` for an axis without lines).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub x: Option<AxisWorst>,
    pub y: Option<AxisWorst>,
}

/// Which standards and rule the figures follow.
#[derive(Clone, Debug, Serialize)]
pub struct Standards {
    pub iso_230_2: &'static str,
    pub vdi_3441: &'static str,
}

/// What `host-sim accuracy` prints.
#[derive(Clone, Debug, Serialize)]
pub struct AccuracyReport {
    pub standards: Standards,
    pub direction_rule: &'static str,
    pub summary: Summary,
    pub lines: Vec<LineStats>,
    /// Lines without enough repeats, with the reason.
    pub skipped: Vec<String>,
}

/// Every axis line's figures and the worst per axis.
pub fn report(data: &[Measurement]) -> Result<AccuracyReport, CalibError> {
    let (lines, skipped) = analyse(data)?;
    let worst = |axis: &str| {
        let l: Vec<&LineStats> = lines.iter().filter(|l| l.axis == axis).collect();
        if l.is_empty() {
            return None;
        }
        let m = |f: &dyn Fn(&LineStats) -> f64| {
            l.iter().map(|x| f(x)).fold(f64::NEG_INFINITY, f64::max)
        };
        Some(AxisWorst {
            lines: l.len(),
            worst_p_um: m(&|x| x.vdi_3441.p_um),
            worst_ps_um: m(&|x| x.vdi_3441.ps_um),
            worst_a_um: m(&|x| x.iso_230_2.a_um),
            worst_r_um: m(&|x| x.iso_230_2.r_um),
            worst_p_pm_um_per_m: m(&|x| x.per_m["p_pm"]),
            worst_ps_pm_um_per_m: m(&|x| x.per_m["ps_pm"]),
        })
    };
    Ok(AccuracyReport {
        standards: Standards {
            iso_230_2: "A, R, B, B_mean, M, E (ISO 230-2:2014 cl. 2)",
            vdi_3441: "P, Ps, U, Pa (VDI/DGQ 3441)",
        },
        direction_rule: "approach direction along the axis from the last move along it within the run; a repeated target means a reversal (see accuracy.rs)",
        summary: Summary { x: worst("x"), y: worst("y") },
        lines,
        skipped,
    })
}

/// The mean error vector (µm) at every target (rows with a target), for a plot: `(target, mean
/// measured − target)`, ordered by target.
pub fn mean_error_per_target(data: &[Measurement]) -> Vec<([f64; 2], [f64; 2])> {
    let mut by_target: TargetSums = BTreeMap::new();
    for m in data {
        let Some(t) = m.target_mm else { continue };
        let e = by_target
            .entry(((t[0] * 1e6).round() as i64, (t[1] * 1e6).round() as i64))
            .or_insert((t, [0.0; 2], 0));
        e.1[0] += (m.measured_mm[0] - t[0]) * 1e3;
        e.1[1] += (m.measured_mm[1] - t[1]) * 1e3;
        e.2 += 1;
    }
    by_target
        .values()
        .map(|v| (v.0, [v.1[0] / v.2 as f64, v.1[1] / v.2 as f64]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(run: u32, x: f64, y: f64, dev_x_um: f64) -> Measurement {
        Measurement {
            theta_deg: [0.0, 0.0],
            measured_mm: [x + dev_x_um * 1e-3, y],
            target_mm: Some([x, y]),
            dir: None,
            run: Some(run),
            t_s: None,
            line: 0,
        }
    }

    /// A hand-computed x line: targets 0, 10, 20 mm; two runs of up 0→20 then down 20→0.
    fn known() -> Vec<Measurement> {
        // deviations (µm): up [t0, t10, t20], down [t20, t10, t0]
        let runs = [
            ([1.0, 2.0, 0.0], [1.0, 0.0, -1.0]),
            ([3.0, 2.0, 4.0], [1.0, 2.0, -1.0]),
        ];
        let mut v = Vec::new();
        for (k, (up, down)) in runs.iter().enumerate() {
            for (i, d) in up.iter().enumerate() {
                v.push(row(k as u32, 10.0 * i as f64, 0.0, *d));
            }
            for (i, d) in down.iter().enumerate() {
                v.push(row(k as u32, 20.0 - 10.0 * i as f64, 0.0, *d));
            }
        }
        v
    }

    #[test]
    fn directions_follow_the_documented_rule() {
        let d = known();
        assert_eq!(
            directions(&d, 0),
            vec![1, 1, 1, -1, -1, -1, 1, 1, 1, -1, -1, -1]
        );
        // A raster: x moves, then a y step (x direction kept), then x back.
        let r = vec![
            row(0, 0.0, 0.0, 0.0),
            row(0, 5.0, 0.0, 0.0),
            row(0, 5.0, 5.0, 0.0),
            row(0, 0.0, 5.0, 0.0),
        ];
        assert_eq!(directions(&r, 0), vec![1, 1, 1, -1]);
        assert_eq!(directions(&r, 1), vec![1, 1, 1, 1]);
    }

    /// `measure --protocol repeat` runs the x line and then the y line in the same
    /// run, each pass from its own overrun; the first y target follows the x line's last one
    /// (a move along both axes) and is approached upwards, not downwards.
    #[test]
    fn a_move_between_lines_starts_a_pass() {
        let r = vec![
            row(0, 0.0, 5.0, 0.0),
            row(0, 10.0, 5.0, 0.0),
            row(0, 10.0, 5.0, 0.0),
            row(0, 0.0, 5.0, 0.0),
            row(0, 5.0, 0.0, 0.0),
            row(0, 5.0, 10.0, 0.0),
            row(0, 5.0, 10.0, 0.0),
            row(0, 5.0, 0.0, 0.0),
        ];
        assert_eq!(directions(&r, 1)[4..], [1, 1, -1, -1]);
        assert_eq!(directions(&r, 0)[..4], [1, 1, -1, -1]);
    }

    /// An x line and a y line crossing at (10, 0): each keeps its own approaches there (2 runs
    /// × 1 per direction), not the other line's passes through it.
    #[test]
    fn crossing_lines_keep_their_own_approaches() {
        let mut d = Vec::new();
        for run in 0..2 {
            for (x, y) in [
                (0.0, 0.0),
                (10.0, 0.0),
                (20.0, 0.0),
                (20.0, 0.0),
                (10.0, 0.0),
                (0.0, 0.0),
            ] {
                d.push(row(run, x, y, 1.0));
            }
            for (x, y) in [
                (10.0, -10.0),
                (10.0, 0.0),
                (10.0, 10.0),
                (10.0, 10.0),
                (10.0, 0.0),
                (10.0, -10.0),
            ] {
                d.push(row(run, x, y, 5.0));
            }
        }
        assert_eq!(
            on_pass(&d, 0)[..12],
            [true, true, true, true, true, true, false, false, false, false, false, false]
        );
        assert_eq!(
            on_pass(&d, 1)[..12],
            [false, false, false, false, false, false, true, true, true, true, true, true]
        );
        let (lines, skipped) = analyse(&d).unwrap();
        assert!(skipped.is_empty(), "{skipped:?}");
        let x = lines.iter().find(|l| l.axis == "x").unwrap();
        let centre = &x.targets[1];
        assert_eq!(
            (centre.position_mm, centre.n_up, centre.n_down),
            (10.0, 2, 2)
        );
        // Only the x passes' deviations (1 µm), not the y passes' x deviation (5 µm).
        assert!(
            (centre.mean_up_um - 1.0).abs() < 1e-9 && (centre.mean_down_um - 1.0).abs() < 1e-9,
            "{centre:?}"
        );
    }

    #[test]
    fn figures_match_hand_computation() {
        let (lines, skipped) = analyse(&known()).unwrap();
        assert!(skipped.is_empty(), "{skipped:?}");
        assert_eq!(lines.len(), 1);
        let l = &lines[0];
        assert_eq!((l.axis, l.at_mm, l.length_mm), ("x", 0.0, 20.0));
        let r2 = 2f64.sqrt();
        let close =
            |a: f64, b: f64, what: &str| assert!((a - b).abs() < 1e-9, "{what}: {a} vs {b}");
        let iso = &l.iso_230_2;
        close(iso.b_um, 3.0, "B");
        close(iso.b_mean_um, 5.0 / 3.0, "B mean");
        close(iso.m_um, 1.0, "M");
        close(iso.e_um, 3.0, "E");
        close(iso.r_um, 8.0 * r2, "R");
        close(iso.r_up_um, 8.0 * r2, "R up");
        close(iso.r_down_um, 4.0 * r2, "R down");
        close(iso.a_um, 8.0 * r2, "A");
        let vdi = &l.vdi_3441;
        close(vdi.u_um, 3.0, "U");
        close(vdi.ps_um, 6.0 * r2, "Ps");
        close(vdi.pa_um, 1.0, "Pa");
        close(vdi.p_um, 1.0 + 6.0 * r2, "P");
        close(l.per_m["p"], (1.0 + 6.0 * r2) * 50.0, "P per m");
        close(l.per_m["p_pm"], (1.0 + 6.0 * r2) * 25.0, "±P per m");
    }

    #[test]
    fn too_few_repeats_is_reported() {
        let d: Vec<Measurement> = known().into_iter().filter(|m| m.run == Some(0)).collect();
        let e = analyse(&d).unwrap_err().to_string();
        assert!(
            e.contains("target 0 mm has 1 approaches in + and 1 in − direction"),
            "{e}"
        );
    }
}
