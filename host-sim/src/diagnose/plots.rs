//! The diagnosis' plots (`host-sim diagnose --plots DIR`): the residual field before and after
//! each step (one scale per step), and the final residual against configuration, direction and
//! time. Staged with the command's other outputs (`crate::io::atomic::Outputs`). Cost: a few
//! tenths of a second per plot.

use super::forward_model::Problem;
use super::report::Report;
use super::structure;
use crate::io::atomic::Outputs;
use crate::io::measurement_csv::Measurement;
use crate::io::plot::{vector_plot_png, xy_plot_png, Mark, Series, VectorField};
use crate::io::IoError;
use std::path::Path;

/// What the plots draw: the residual field of the start and after each step of the gap-shrink
/// table, at the measured points.
pub struct ResidualPlotData {
    /// Where each point was measured (mm).
    pub base_mm: Vec<[f64; 2]>,
    /// (label, residual µm per point): "start", then one per step.
    pub fields: Vec<(String, Vec<[f64; 2]>)>,
    /// The diagnosed problem (its points' angles, directions and times).
    pub problem: Problem,
}

/// A plot's file name, axis label and x value of point i.
type Abscissa<'a> = (&'a str, &'a str, Box<dyn Fn(usize) -> f64 + 'a>);

/// A vector plot staged in the command's outputs.
fn vector_plot(
    out: &mut Outputs,
    path: &Path,
    title: &str,
    fields: &[VectorField<'_>],
) -> Result<(), IoError> {
    out.bytes(path, &vector_plot_png(title, fields, &[])?)
}

/// An x-y plot staged in the command's outputs.
fn xy_plot(
    out: &mut Outputs,
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> Result<(), IoError> {
    out.bytes(path, &xy_plot_png(title, x_label, y_label, series)?)
}

/// Stages every plot into `dir` in `out` (written with the command's other outputs, or none).
pub fn write_plots(
    out: &mut Outputs,
    dir: &Path,
    data: &[Measurement],
    report: &Report,
    h: &ResidualPlotData,
) -> Result<(), IoError> {
    vector_plot(
        out,
        &dir.join("residual_start.png"),
        "residual of the starting model",
        &[VectorField::new("start", &h.base_mm, &h.fields[0].1)],
    )?;
    for k in 1..h.fields.len() {
        let name = &report.steps[k - 1].effect;
        vector_plot(
            out,
            &dir.join(format!("residual_step{k}_{name}.png")),
            &format!("step {k}: {name}"),
            &[
                VectorField::new("before", &h.base_mm, &h.fields[k - 1].1),
                VectorField::new("after", &h.base_mm, &h.fields[k].1),
            ],
        )?;
    }
    let Some((_, last)) = h.fields.last() else {
        return Ok(());
    };
    let first = &h.fields[0].1;
    let pts = &h.problem.points;
    let radial = |r: &[[f64; 2]], f: &dyn Fn(usize) -> f64| -> Vec<[f64; 2]> {
        r.iter()
            .enumerate()
            .map(|(i, e)| [f(i), e[0].hypot(e[1])])
            .collect()
    };
    let configs: [Abscissa<'_>; 3] = [
        (
            "theta1",
            "θ1 (deg)",
            Box::new(|i| pts[i].theta_rad[0].to_degrees()),
        ),
        (
            "theta2",
            "θ2 (deg)",
            Box::new(|i| pts[i].theta_rad[1].to_degrees()),
        ),
        (
            "theta_diff",
            "θ1 − θ2 (deg)",
            Box::new(|i| (pts[i].theta_rad[0] - pts[i].theta_rad[1]).to_degrees()),
        ),
    ];
    for (file, label, f) in configs.iter() {
        let a = radial(first, f.as_ref());
        let b = radial(last, f.as_ref());
        xy_plot(
            out,
            &dir.join(format!("residual_vs_{file}.png")),
            &format!("radial residual vs {label}"),
            label,
            "radial residual (µm)",
            &[
                Series {
                    label: "start",
                    points: &a,
                    mark: Mark::Dots,
                },
                Series {
                    label: "final",
                    points: &b,
                    mark: Mark::Dots,
                },
            ],
        )?;
    }
    // Joint-space residual against each motor's own angle: where a gear or encoder error shows.
    let flat: Vec<f64> = last.iter().flat_map(|e| [e[0], e[1]]).collect();
    let joint = structure::joint_residual_urad(&h.problem, &flat);
    for j in 0..2 {
        let pts_j: Vec<[f64; 2]> = joint
            .iter()
            .enumerate()
            .map(|(i, d)| [pts[i].theta_rad[j].to_degrees(), d[j]])
            .collect();
        xy_plot(
            out,
            &dir.join(format!("final_joint_residual_motor{}.png", j + 1)),
            &format!(
                "final residual in joint space, motor {} vs its angle",
                j + 1
            ),
            &format!("θ{} (deg)", j + 1),
            &format!("δθ{} (µrad)", j + 1),
            &[Series {
                label: "final",
                points: &pts_j,
                mark: Mark::Dots,
            }],
        )?;
    }
    if h.problem.has_dir {
        // Final residual along θ1 split by approach direction of motor 1.
        let plus: Vec<[f64; 2]> = last
            .iter()
            .enumerate()
            .filter(|(i, _)| pts[*i].dir[0] > 0.0)
            .map(|(i, e)| [pts[i].theta_rad[0].to_degrees(), e[0].hypot(e[1])])
            .collect();
        let minus: Vec<[f64; 2]> = last
            .iter()
            .enumerate()
            .filter(|(i, _)| pts[*i].dir[0] < 0.0)
            .map(|(i, e)| [pts[i].theta_rad[0].to_degrees(), e[0].hypot(e[1])])
            .collect();
        xy_plot(
            out,
            &dir.join("final_residual_by_direction.png"),
            "final radial residual by approach direction of motor 1",
            "θ1 (deg)",
            "radial residual (µm)",
            &[
                Series {
                    label: "dir1 = +1",
                    points: &plus,
                    mark: Mark::Dots,
                },
                Series {
                    label: "dir1 = −1",
                    points: &minus,
                    mark: Mark::Dots,
                },
            ],
        )?;
    }
    let times: Option<Vec<f64>> = h
        .problem
        .points
        .iter()
        .map(|p| data.get(p.index).and_then(|m| m.t_s))
        .collect();
    if let Some(t) = times {
        if t.len() == last.len() {
            let a: Vec<[f64; 2]> = last
                .iter()
                .zip(&t)
                .map(|(e, t)| [*t, e[0].hypot(e[1])])
                .collect();
            xy_plot(
                out,
                &dir.join("final_residual_vs_time.png"),
                "final radial residual vs time",
                "t (s)",
                "radial residual (µm)",
                &[Series {
                    label: "final",
                    points: &a,
                    mark: Mark::Dots,
                }],
            )?;
        }
    }
    Ok(())
}
