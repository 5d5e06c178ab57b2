//! Grid nodes the machine cannot be driven to: outside its workspace (a polygon inside the
//! grid's rectangle, like the second machine's octagon), where the controller's soft limit
//! refuses every move. The grid still needs them: the bilinear cells that straddle the
//! workspace's edge interpolate between nodes inside and outside.
//!
//! Method: the model's residual `r(p) = measured − FK(θ)` is a smooth field of the tool's
//! position (what the grid corrects). At each missing node it is extrapolated from the readings
//! nearby by a least-squares quadratic in the position (the nearest [`NEIGHBOURS`] readings,
//! weighted by distance), and the node gets one pseudo-reading there: commanded at the model's
//! inverse, read at `p + r(p)`. The grid is then built from all nodes as usual (its smoother
//! treats the pseudo-readings as readings). A quadratic follows the field's curvature across the
//! one or two grid steps between the workspace's edge and the nodes outside it.
//!
//! # The smoothing
//! Each quadratic is fitted to noisy readings on one side of its node and extrapolated: the
//! estimated nodes carry an amplified noise of their own that varies from node to node, and
//! the grid's choice of smoothing (restricted likelihood, cross-validation) reads it as detail
//! to follow: on the second machine's octagon (123 of 704 nodes estimated, 1 µm instrument)
//! it picked λ ≈ 1 (127 effective nodes) where the measured nodes alone ask for far more,
//! and the noise it kept set the accuracy at fresh targets (0.3 µm RMS). So the estimated
//! nodes are then refined by the grid's own estimate (expectation-maximisation for missing
//! values): each rebuild gives them the values the grid fitted there, until no value moves by
//! more than [`REFINED_MM`] or after [`MAX_REFINEMENTS`] rebuilds. The measured nodes then
//! decide the smoothing alone; the quadratic is the starting point (and what stays where the
//! grid applies no correction). A rebuild costs a few tens of milliseconds on that lattice.
//!
//! Only nodes outside the workspace may be missing; a node inside without a reading is the
//! same error as ever. The noise report counts each pseudo-reading as a reading, so its
//! degrees of freedom are a little optimistic on such a machine.

use super::{build_with, BuiltGrid, GridOptions};
use crate::calib::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use kinematics_core::FiveBar;

/// Readings a missing node's quadratic is fitted to.
pub const NEIGHBOURS: usize = 40;
/// Most rebuilds that refine the estimated nodes from the grid's own estimate.
pub const MAX_REFINEMENTS: usize = 60;
/// The estimated nodes are refined when no value changes by more than this (mm) in a rebuild.
pub const REFINED_MM: f64 = 1e-6;

/// A grid built with some nodes estimated rather than measured.
#[derive(Clone, Debug)]
pub struct Filled {
    pub built: BuiltGrid,
    /// The nodes estimated (mm).
    pub estimated: Vec<[f64; 2]>,
}

/// The model's residual field at the readings: (position, residual), both mm.
fn residuals(model: &FiveBar<f64>, data: &[Measurement]) -> Vec<([f64; 2], [f64; 2])> {
    data.iter()
        .filter_map(|m| {
            let at = model.forward(m.theta_rad(), 0.0).ok()?;
            Some((at, [m.measured_mm[0] - at[0], m.measured_mm[1] - at[1]]))
        })
        .collect()
}

/// The residual at `p` by a weighted least-squares quadratic through the nearest readings.
fn extrapolate(field: &[([f64; 2], [f64; 2])], p: [f64; 2], step_mm: f64) -> Option<[f64; 2]> {
    let mut near: Vec<(f64, usize)> = field
        .iter()
        .enumerate()
        .map(|(k, (q, _))| ((q[0] - p[0]).hypot(q[1] - p[1]), k))
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.truncate(NEIGHBOURS);
    if near.len() < 6 {
        return None;
    }
    // Normal equations of the 6 monomials in (x − p) / step, each reading weighted by
    // 1 / (1 + (d / step)²).
    let mut ata = nalgebra::SMatrix::<f64, 6, 6>::zeros();
    let mut atb = nalgebra::SMatrix::<f64, 6, 2>::zeros();
    for &(d, k) in &near {
        let (q, r) = field[k];
        let (u, v) = ((q[0] - p[0]) / step_mm, (q[1] - p[1]) / step_mm);
        let a = nalgebra::SVector::<f64, 6>::from([1.0, u, v, u * u, u * v, v * v]);
        let w = 1.0 / (1.0 + (d / step_mm).powi(2));
        ata += w * a * a.transpose();
        for c in 0..2 {
            for i in 0..6 {
                atb[(i, c)] += w * a[i] * r[c];
            }
        }
    }
    let x = ata.cholesky()?.solve(&atb);
    Some([x[(0, 0)], x[(0, 1)]])
}

/// The grid of `data` over the lattice `nodes` (every node of the machine's lattice), the
/// nodes without a reading estimated (module doc); `reachable(p)` says whether the machine can
/// be driven to `p` (such a node must have a reading).
pub fn build_filling(
    model: &FiveBar<f64>,
    data: &[Measurement],
    nodes: &[[f64; 2]],
    opts: &GridOptions,
    reachable: impl Fn([f64; 2]) -> bool,
) -> Result<Filled, CalibError> {
    let tol = 1e-6 * opts.step_mm;
    let read = |p: &[f64; 2]| {
        data.iter().any(|m| {
            m.target_mm
                .is_some_and(|t| (t[0] - p[0]).abs() < tol && (t[1] - p[1]).abs() < tol)
        })
    };
    let missing: Vec<[f64; 2]> = nodes.iter().filter(|p| !read(p)).copied().collect();
    if let Some(p) = missing.iter().find(|p| reachable(**p)) {
        return Err(invalid!(
            "node ({}, {}) is inside the machine's workspace and has no reading: measure it",
            p[0],
            p[1]
        ));
    }
    let field = residuals(model, data);
    let mut pseudo = Vec::with_capacity(missing.len());
    for &p in &missing {
        let theta = model.inverse(p, 0.0).map_err(|e| {
            invalid!(
                "node ({}, {}) outside the workspace: the model cannot reach it ({e})",
                p[0],
                p[1]
            )
        })?;
        let r = extrapolate(&field, p, opts.step_mm).ok_or_else(|| {
            invalid!(
                "node ({}, {}) outside the workspace: too few readings to estimate it from",
                p[0],
                p[1]
            )
        })?;
        pseudo.push((p, theta, r));
    }
    let with_pseudo = |pseudo: &[([f64; 2], [f64; 2], [f64; 2])]| {
        let mut all = data.to_vec();
        all.extend(pseudo.iter().map(|&(p, theta, r)| Measurement {
            theta_deg: theta.map(f64::to_degrees),
            measured_mm: [p[0] + r[0], p[1] + r[1]],
            target_mm: Some(p),
            dir: Some([1, 1]),
            run: None,
            t_s: None,
            line: 0,
        }));
        all
    };
    let mut built = build_with(model, &with_pseudo(&pseudo), opts)?;
    // The estimated nodes' values taken from the grid's own estimate until they agree with it
    // (module doc, "The smoothing"): at most MAX_REFINEMENTS rebuilds, each a few tens of ms.
    for _ in 0..MAX_REFINEMENTS {
        if pseudo.is_empty() || !built.noise.applied {
            break;
        }
        let mut change_mm = 0.0f64;
        for (p, _, r) in &mut pseudo {
            let at = |n: &&super::Node| {
                (n.target_mm[0] - p[0]).abs() < tol && (n.target_mm[1] - p[1]).abs() < tol
            };
            if let Some(n) = built.nodes.iter().find(at) {
                let d = [n.corrected_mm[0] - r[0], n.corrected_mm[1] - r[1]];
                change_mm = change_mm.max(d[0].hypot(d[1]));
                *r = n.corrected_mm;
            }
        }
        let next = build_with(model, &with_pseudo(&pseudo), opts)?;
        if !next.noise.applied {
            break;
        }
        built = next;
        if change_mm < REFINED_MM {
            break;
        }
    }
    Ok(Filled {
        built,
        estimated: missing,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::machine::PlantMachine;
    use crate::calib::measure::{measure_list, rows};
    use crate::calib::protocol::Visit;
    use crate::machine_spec::MachineSpec;
    use crate::plant::PlantConfig;
    use kinematics_core::{Calibration, CorrectionGrid};

    /// The second machine (an octagon inside its grid's rectangle), measured through its
    /// nominal model (a residual field of millimetres, the hardest case) with a noiseless
    /// instrument, so that what differs is the estimate alone: the grid from the nodes inside
    /// the workspace, the others estimated, corrects the workspace as the grid from every node
    /// does, to a fraction of a micrometre.
    #[test]
    fn nodes_outside_the_workspace_are_estimated_from_the_others() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let spec =
            crate::io::machine_file::read_machine(&root.join("machines/second.toml")).unwrap();
        let plant =
            PlantConfig::by_name(root.join("plants/second.toml").to_str().unwrap()).unwrap();
        let mut m = PlantMachine::from_config(plant, "second", Some(0.0), 3).unwrap();
        let nodes = spec.grid_nodes_mm();
        let visits: Vec<Visit> = nodes
            .iter()
            .map(|&t| Visit {
                target_mm: t,
                from_mm: t,
                run: 0,
                dir: Some([1, 1]),
            })
            .collect();
        let cal = Calibration {
            model: spec.nominal.cast(),
            grid: None,
        };
        let all = rows(&measure_list(&mut m, &cal, &visits, spec.approach, 3, &spec).unwrap());
        let opts = GridOptions::for_machine(&spec);
        let full = build_with(&spec.nominal, &all, &opts).unwrap();
        let inside: Vec<Measurement> = all
            .iter()
            .filter(|r| spec.workspace.contains(r.target_mm.unwrap(), 1e-9))
            .cloned()
            .collect();
        assert!(
            inside.len() < all.len() - 100,
            "{} of {}",
            inside.len(),
            all.len()
        );
        let f = build_filling(&spec.nominal, &inside, &nodes, &opts, |p| {
            spec.workspace.contains(p, 1e-9)
        })
        .unwrap();
        assert_eq!(f.estimated.len(), all.len() - inside.len());
        let (a, b) = (
            CorrectionGrid::parse(&full.image).unwrap(),
            CorrectionGrid::parse(&f.built.image).unwrap(),
        );
        let mut worst = 0.0f64;
        for k in 0..2000 {
            let p = [
                168.0 + (k as f64 * 0.618_034).fract() * 84.0,
                -72.0 + (k as f64 * 0.414_214).fract() * 124.0,
            ];
            if !spec.workspace.contains(p, 0.0) {
                continue;
            }
            let p32 = [p[0] as f32, p[1] as f32];
            let (ca, cb) = (
                a.correction_rad(p32).unwrap(),
                b.correction_rad(p32).unwrap(),
            );
            // µrad to µm at the tool: about 150 mm per rad.
            worst = worst.max(150.0 * f64::from((ca[0] - cb[0]).hypot(ca[1] - cb[1])) * 1e3);
        }
        eprintln!(
            "{} nodes estimated; largest difference {worst:.3} µm",
            f.estimated.len()
        );
        assert!(worst < 0.5, "{worst} µm");
        // A node inside the workspace without a reading is an error.
        let mut gap = inside.clone();
        let at = gap
            .iter()
            .position(|r| spec.workspace.contains(r.target_mm.unwrap(), 5.0))
            .unwrap();
        gap.remove(at);
        let e = build_filling(&spec.nominal, &gap, &nodes, &opts, |p| {
            spec.workspace.contains(p, 1e-9)
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("inside the machine's workspace"), "{e}");
        let _ = MachineSpec::paper();
    }
}
