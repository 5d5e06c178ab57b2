//! The structure of a residual: what it correlates with, so what no effect explains can be
//! described instead of named.
//!
//! Tests, each on the residual of the final model:
//! * periodic in a motor angle: the tool residual is mapped into joint space with the model's
//!   inverse Jacobian (a gear-tooth error of motor j is then a clean function of θ_j), and a
//!   least-squares periodogram `c + a·cos(Nθ_j) + b·sin(Nθ_j)` is scanned over N = 2..=360 cycles
//!   per revolution. For Gaussian noise the RSS drop over σ̂² is χ²₂, whose tail is exactly
//!   exp(−z/2); times the number of frequencies tried (Bonferroni) it must stay below 1e-3.
//! * approach direction: regression of each joint residual on dir_j, |z| > 5;
//! * time (`t_s`) and repeat index (`run`): linear drift of x and y, |z| > [`DRIFT_Z`] (a weaker
//!   trend is tried as a nuisance by the model comparison in `diagnose`, see `mod.rs`);
//! * smooth over the workspace: a quadratic in (x, y) per axis, RSS drop over σ̂² > 30 (χ²₅ tail
//!   far below 1e-4).
//!
//! Cost: the periodogram is 2 × 359 small (3×3) least-squares solves over n points: O(700 n).

use super::forward_model::Problem;
use crate::io::measurement_csv::Measurement;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// One thing the residual correlates with.
#[derive(Clone, Debug, Serialize)]
pub struct Finding {
    /// `periodic_theta1`, `periodic_theta2`, `direction_motor1`, `direction_motor2`, `drift_time`,
    /// `drift_run`, `smooth_workspace`.
    pub kind: String,
    pub significant: bool,
    /// Share of the residual's sum of squares this structure explains (0..1).
    pub share: f64,
    /// For `periodic_*`: the strongest period, cycles per motor revolution.
    pub cycles_per_rev: Option<f64>,
    pub description: String,
}

/// Least squares of y on the columns of a; returns (RSS, coefficients, their standard errors).
fn ls(a: &DMatrix<f64>, y: &DVector<f64>) -> Option<(f64, DVector<f64>, DVector<f64>)> {
    let ata = a.transpose() * a;
    let inv = ata.try_inverse()?;
    let coef = &inv * (a.transpose() * y);
    let r = y - a * &coef;
    let rss = r.norm_squared();
    let dof = (a.nrows() as f64 - a.ncols() as f64).max(1.0);
    let se = DVector::from_fn(a.ncols(), |i, _| (inv[(i, i)] * rss / dof).sqrt());
    Some((rss, coef, se))
}

fn demeaned_rss(y: &DVector<f64>) -> f64 {
    let m = y.mean();
    y.iter().map(|v| (v - m) * (v - m)).sum()
}

/// The tool residual mapped into joint space (µrad per motor) with the base model's inverse
/// Jacobian: a motor's own angle error shows up there as a clean function of its angle.
pub fn joint_residual_urad(problem: &Problem, residual_um: &[f64]) -> Vec<[f64; 2]> {
    problem
        .points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let ji = problem
                .base
                .forward_pose(p.theta_rad, 0.0)
                .ok()
                .and_then(|pose| pose.inverse_jacobian().ok());
            let r = [residual_um[2 * i], residual_um[2 * i + 1]];
            match ji {
                Some(m) => [
                    (m[0][0] * r[0] + m[0][1] * r[1]) * 1e3,
                    (m[1][0] * r[0] + m[1][1] * r[1]) * 1e3,
                ],
                None => [0.0, 0.0],
            }
        })
        .collect()
}

/// |z| of a linear trend in time (or run) above which the drift test calls it significant.
pub const DRIFT_Z: f64 = 5.0;

/// The linear trend of each axis of the residual (µm, x,y interleaved) against `t`, with an
/// intercept: per axis (rate per unit of t, its z, the RSS drop over the demeaned residual).
fn linear_trends(t: &[f64], residual_um: &[f64]) -> Vec<(f64, f64, f64)> {
    let n = t.len();
    let mut out = Vec::new();
    for axis in 0..2 {
        let y = DVector::from_fn(n, |r, _| residual_um[2 * r + axis]);
        let a = DMatrix::from_fn(n, 2, |r, c| if c == 0 { 1.0 } else { t[r] });
        if let Some((rss, coef, se)) = ls(&a, &y) {
            out.push((coef[1], coef[1] / se[1].max(1e-300), demeaned_rss(&y) - rss));
        }
    }
    out
}

/// The largest |z| of the residual's linear trend in time over the two axes (the drift test of
/// [`analyse`] without its threshold); `None` when the points have no times or all the same.
pub fn drift_time_z(problem: &Problem, data: &[Measurement], residual_um: &[f64]) -> Option<f64> {
    let t: Vec<f64> = problem
        .points
        .iter()
        .map(|p| data.get(p.index).and_then(|m| m.t_s))
        .collect::<Option<Vec<f64>>>()?;
    if t.len() < MIN_POINTS || t.iter().all(|v| *v == t[0]) {
        return None;
    }
    linear_trends(&t, residual_um)
        .into_iter()
        .map(|(_, z, _)| z.abs())
        .reduce(f64::max)
}

/// Minimum number of points for the periodogram and the workspace fit.
pub const MIN_POINTS: usize = 30;

/// Analyses a residual (µm, x,y interleaved, one pair per point of `problem`). `data` are the
/// measurements the problem was built from (for time and run; matched by `Point::index`).
pub fn analyse(problem: &Problem, data: &[Measurement], residual_um: &[f64]) -> Vec<Finding> {
    let n = problem.points.len();
    let mut out = Vec::new();
    if n < MIN_POINTS {
        out.push(Finding {
            kind: "too_few_points".into(),
            significant: false,
            share: 0.0,
            cycles_per_rev: None,
            description: format!("{n} points: too few to test the residual for periodicity, direction, drift or smooth structure (need {MIN_POINTS})"),
        });
        return out;
    }
    let total_ss: f64 = residual_um.iter().map(|v| v * v).sum::<f64>().max(1e-300);
    let joint = joint_residual_urad(problem, residual_um);
    let dth = [
        joint.iter().map(|d| d[0]).collect::<Vec<f64>>(),
        joint.iter().map(|d| d[1]).collect::<Vec<f64>>(),
    ];
    let th = [0, 1].map(|j| {
        problem
            .points
            .iter()
            .map(|p| p.theta_rad[j])
            .collect::<Vec<f64>>()
    });
    // Periodogram per motor.
    let n_max = 360usize;
    let tried = (n_max - 1) as f64;
    for j in 0..2 {
        let y = DVector::from_vec(dth[j].clone());
        let rss0 = demeaned_rss(&y);
        let mut best: Option<(usize, f64, f64)> = None; // (N, rss, amplitude)
        for cycles in 2..=n_max {
            let a = DMatrix::from_fn(n, 3, |r, c| match c {
                0 => 1.0,
                1 => (cycles as f64 * th[j][r]).cos(),
                _ => (cycles as f64 * th[j][r]).sin(),
            });
            if let Some((rss, coef, _)) = ls(&a, &y) {
                if best.is_none_or(|b| rss < b.1) {
                    best = Some((cycles, rss, coef[1].hypot(coef[2])));
                }
            }
        }
        if let Some((cycles, rss, amp)) = best {
            let s2 = rss / (n as f64 - 3.0).max(1.0);
            let z = (rss0 - rss) / s2.max(1e-300);
            let fap = tried * (-z / 2.0).exp();
            let significant = fap < 1e-3;
            let share = ((rss0 - rss) / rss0.max(1e-300)).clamp(0.0, 1.0);
            out.push(Finding {
                kind: format!("periodic_theta{}", j + 1),
                significant,
                share,
                cycles_per_rev: Some(cycles as f64),
                description: format!(
                    "motor {} joint-space residual vs θ{}: strongest period {} cycles/rev ({:.2}° per cycle), amplitude {:.1} µrad \
                     (≈ {:.1} µm at 150 mm), explains {:.0}% of that residual; false-alarm probability {:.1e}{}",
                    j + 1,
                    j + 1,
                    cycles,
                    360.0 / cycles as f64,
                    amp,
                    amp * 0.15,
                    100.0 * share,
                    fap.min(1.0),
                    if significant { "" } else { " (not significant)" }
                ),
            });
        }
    }
    // Approach direction.
    if problem.has_dir {
        // j is the motor: it indexes the joint residuals and each point's directions.
        #[allow(clippy::needless_range_loop)]
        for j in 0..2 {
            let y = DVector::from_vec(dth[j].clone());
            let a = DMatrix::from_fn(n, 2, |r, c| {
                if c == 0 {
                    1.0
                } else {
                    problem.points[r].dir[j]
                }
            });
            if let Some((rss, coef, se)) = ls(&a, &y) {
                let z = coef[1] / se[1].max(1e-300);
                let rss0 = demeaned_rss(&y);
                out.push(Finding {
                    kind: format!("direction_motor{}", j + 1),
                    significant: z.abs() > 5.0,
                    share: ((rss0 - rss) / rss0.max(1e-300)).clamp(0.0, 1.0),
                    cycles_per_rev: None,
                    description: format!(
                        "motor {} joint residual differs by {:.1} µrad between approach directions (z = {:.1})",
                        j + 1,
                        2.0 * coef[1],
                        z
                    ),
                });
            }
        }
    }
    // Time and run.
    let kept: Vec<&Measurement> = problem
        .points
        .iter()
        .filter_map(|p| data.get(p.index))
        .collect();
    if kept.len() == n {
        let series: [(&str, Option<Vec<f64>>, &str); 2] = [
            (
                "drift_time",
                kept.iter().map(|m| m.t_s).collect::<Option<Vec<f64>>>(),
                "s",
            ),
            (
                "drift_run",
                kept.iter()
                    .map(|m| m.run.map(|r| r as f64))
                    .collect::<Option<Vec<f64>>>(),
                "run",
            ),
        ];
        for (kind, t, unit) in series {
            let Some(t) = t else { continue };
            if t.iter().all(|v| *v == t[0]) {
                continue;
            }
            let mut parts = Vec::new();
            let mut significant = false;
            let mut drop = 0.0;
            for (axis, (rate, z, d)) in linear_trends(&t, residual_um).into_iter().enumerate() {
                significant |= z.abs() > DRIFT_Z;
                drop += d;
                parts.push(format!(
                    "{} {rate:.3} µm/{unit} (z = {z:.1})",
                    ["x", "y"][axis]
                ));
            }
            out.push(Finding {
                kind: kind.into(),
                significant,
                share: (drop / total_ss).clamp(0.0, 1.0),
                cycles_per_rev: None,
                description: format!("linear drift: {}", parts.join(", ")),
            });
        }
    }
    // Smooth over the workspace.
    {
        let mut drop = 0.0;
        let mut z_max = 0.0f64;
        let pos: Vec<[f64; 2]> = problem.points.iter().map(|p| p.measured_mm).collect();
        let (cx, cy) = (
            pos.iter().map(|p| p[0]).sum::<f64>() / n as f64,
            pos.iter().map(|p| p[1]).sum::<f64>() / n as f64,
        );
        for axis in 0..2 {
            let y = DVector::from_fn(n, |r, _| residual_um[2 * r + axis]);
            let a = DMatrix::from_fn(n, 6, |r, c| {
                let (x, yy) = ((pos[r][0] - cx) / 50.0, (pos[r][1] - cy) / 50.0);
                [1.0, x, yy, x * x, x * yy, yy * yy][c]
            });
            if let Some((rss, _, _)) = ls(&a, &y) {
                let rss0 = demeaned_rss(&y);
                drop += rss0 - rss;
                z_max = z_max.max((rss0 - rss) / (rss / (n as f64 - 6.0)).max(1e-300));
            }
        }
        let share = (drop / total_ss).clamp(0.0, 1.0);
        out.push(Finding {
            kind: "smooth_workspace".into(),
            significant: z_max > 30.0,
            share,
            cycles_per_rev: None,
            description: format!(
                "a quadratic in (x, y) explains {:.0}% of the residual (χ² drop / σ̂² up to {:.0}; > 30 is significant)",
                100.0 * share,
                z_max
            ),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::FiveBar;

    /// The 5 mm grid's poses with approach directions that are not tied to the configuration
    /// (a fixed pseudo-random pattern), and the problem over them.
    fn grid_with_directions() -> (FiveBar<f64>, Vec<Measurement>, Problem) {
        let spec = crate::machine_spec::MachineSpec::paper();
        let (nominal, g) = (spec.nominal, spec.grid);
        let mut data = Vec::new();
        for i in 0..g.nx {
            for j in 0..g.ny {
                let th = nominal
                    .inverse(g.node_mm(i, j), spec.min_transmission)
                    .unwrap();
                let c = nominal.forward(th, 0.0).unwrap();
                let k = data.len();
                let dir = [
                    if (k * 7) % 11 < 5 { 1 } else { -1 },
                    if (k * 13) % 17 < 9 { 1 } else { -1 },
                ];
                data.push(Measurement {
                    theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                    measured_mm: c,
                    target_mm: None,
                    dir: Some(dir),
                    run: None,
                    t_s: None,
                    line: 0,
                });
            }
        }
        let p = Problem::new(nominal, &crate::loop_closure::SixBarDesign::paper(), &data);
        (nominal, data, p)
    }

    /// Tool residual (µm) of joint errors `dth_urad(point index, point)` on both motors, plus a
    /// little deterministic "noise".
    fn residual(
        nominal: &FiveBar<f64>,
        p: &Problem,
        dth_urad: impl Fn(usize, &crate::diagnose::forward_model::Point) -> [f64; 2],
    ) -> Vec<f64> {
        let mut r = Vec::new();
        for (k, q) in p.points.iter().enumerate() {
            let j = nominal
                .forward_pose(q.theta_rad, 0.0)
                .unwrap()
                .jacobian()
                .unwrap();
            let d = dth_urad(k, q).map(|v| v * 1e-6);
            let wobble = 1e-3 * ((k * 7919) % 13) as f64 / 13.0;
            r.push((j[0][0] * d[0] + j[0][1] * d[1]) * 1e3 + wobble);
            r.push((j[1][0] * d[0] + j[1][1] * d[1]) * 1e3 - wobble);
        }
        r
    }

    #[test]
    fn periodogram_finds_a_joint_ripple_and_ignores_none() {
        let (nominal, data, p) = grid_with_directions();
        assert!(p.has_dir);
        // 30 µrad · sin(40 θ2) on motor 2.
        let r = residual(&nominal, &p, |_, q| {
            [0.0, 30.0 * (40.0 * q.theta_rad[1]).sin()]
        });
        let f = analyse(&p, &data, &r);
        let per2 = f.iter().find(|f| f.kind == "periodic_theta2").unwrap();
        assert!(
            per2.significant && per2.cycles_per_rev == Some(40.0),
            "{per2:?}"
        );
        // The direction test ran on both motors and found nothing: the ripple does not depend
        // on the approach direction.
        let dirs: Vec<&Finding> = f
            .iter()
            .filter(|f| f.kind.starts_with("direction"))
            .collect();
        assert_eq!(dirs.len(), 2, "{f:?}");
        assert!(dirs.iter().all(|d| !d.significant), "{dirs:?}");
    }

    #[test]
    fn direction_test_finds_a_lost_motion_on_its_motor_only() {
        // Motor 1 lags by 15 µrad against its approach direction (a 30 µrad backlash): the
        // test must find it on motor 1, with its size, and not on motor 2.
        let (nominal, data, p) = grid_with_directions();
        let r = residual(&nominal, &p, |_, q| [-15.0 * q.dir[0], 0.0]);
        let f = analyse(&p, &data, &r);
        let d1 = f
            .iter()
            .find(|f| f.kind == "direction_motor1")
            .expect("tested");
        let d2 = f
            .iter()
            .find(|f| f.kind == "direction_motor2")
            .expect("tested");
        assert!(d1.significant && d1.share > 0.9, "{d1:?}");
        assert!(d1.description.contains("-30.0 µrad"), "{d1:?}");
        assert!(!d2.significant, "{d2:?}");
    }
}
