//! The correction-grid flash image from measurements at the grid nodes (`host-sim grid`, the
//! demo's steps 3 and 4).
//!
//! Why: the fitted five-bar cannot explain every error of the real six-bar (link flexibility,
//! joint clearance; Table I's 1.5 mm → 0.7 mm after the fit). The paper's second step measures
//! the machine on a 5 mm grid and corrects the joint commands by the measured error mapped
//! through `J⁻¹`. Per node, with the model's IK `θ_ik = IK(target)`, the commanded angles `θ_cmd`
//! (the CSV's angles) and the measured error `e = measured − target`, the machine is at
//! `target + e` for `θ_cmd`, so to first order it reaches the target at `θ_cmd − J⁻¹·e`; the node
//! stores what the firmware must add to `IK(target)`:
//!
//! ```text
//! δθ = (θ_cmd − θ_ik) − J⁻¹(θ_ik)·(measured − target)          (f64, fitted model)
//! ```
//!
//! The paper's Eq. 8 (with its denominators fixed to a and d) is exactly `δθ = J⁻¹·δ`, the
//! leading minus absorbing `sin(θ1 − θ3) = −sin(θ3 − θ1)`; with its δ = desired − measured = −e
//! and its final `θ − δθ` that composes to `θ + J⁻¹·e`: one sign is flipped as printed. Ours
//! is fixed by the grid sign test on a synthetic machine. With `θ_cmd = θ_ik` (measured with the
//! model alone) the first term vanishes; with `θ_cmd` from a
//! previous grid it makes a second measurement round refine the grid instead of replacing it.
//!
//! Error: first order in e, so the residual at the nodes is ~ e × (relative Jacobian error
//! between model and machine), e.g. 1 mm × 1e-3 = 1 µm, and a second round removes it (the
//! grid test: 1.7 µm → 0.03 µm at the nodes for a 0.7 mm error field). Between nodes add the
//! bilinear interpolation error of the correction field, h²/8 × its curvature: it grows towards
//! the workspace corners where J⁻¹ changes fast and scales with the error, ~0.8 µm for that
//! 0.7 mm field with 5 mm cells; fit the model first so the grid only corrects what is left.
//! Cost: one IK and one 2x2 inverse per node.
//!
//! The node lattice is read from the targets: origin = smallest x and y, spacing = the given step
//! (must match the targets' spacing); every node must be measured exactly once. The readable node
//! table ([`format_csv`], `grid.csv`) is this module's file format.

use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::GridLattice;
use crate::numeric::{max_rms, MaxRms};
use kinematics_core::grid::{encode, GridGeometry, MAX_NODES_PER_AXIS};
use kinematics_core::jacobian::mat2_mul_vec;
use kinematics_core::{wrap_angle_rad, FiveBar};
use serde::Serialize;

/// Largest distance (in steps) a target may be from its node.
const LATTICE_TOL_STEPS: f64 = 1e-4;

/// Spacings between neighbouring distinct values (equal within the tolerance).
fn gaps(mut v: Vec<f64>, tol: f64) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.windows(2).map(|w| w[1] - w[0]).filter(|&g| g > tol).collect()
}

/// Finds the lattice and the row of every node (`rows[j·nx + i]`, x fastest).
pub fn detect_lattice(data: &[Measurement], step_mm: f64) -> Result<(GridLattice, Vec<usize>), CalibError> {
    if !(step_mm > 0.0 && step_mm.is_finite()) {
        return Err(invalid!("the grid step must be positive, got {step_mm}"));
    }
    let mut targets = Vec::with_capacity(data.len());
    for m in data {
        targets.push(
            m.target_mm.ok_or_else(|| invalid!("line {}: no x_target_mm,y_target_mm: the grid nodes are the targets", m.line))?,
        );
    }
    let tol = LATTICE_TOL_STEPS * step_mm;
    // The spacing most neighbouring target columns (rows) have must be the step; single
    // targets off the lattice are reported by line below.
    for (axis, name) in [(0, "x"), (1, "y")] {
        let gaps = gaps(targets.iter().map(|t| t[axis]).collect(), tol);
        let matching = gaps.iter().filter(|g| (*g - step_mm).abs() <= tol).count();
        if !gaps.is_empty() && 2 * matching <= gaps.len() {
            let mut sorted = gaps.clone();
            sorted.sort_by(f64::total_cmp);
            let typical = sorted[sorted.len() / 2];
            return Err(invalid!("step mismatch: the targets are {typical} mm apart along {name}, the step is {step_mm}"));
        }
    }
    let x0 = targets.iter().map(|t| t[0]).fold(f64::INFINITY, f64::min);
    let y0 = targets.iter().map(|t| t[1]).fold(f64::INFINITY, f64::min);
    let mut ij = Vec::with_capacity(data.len());
    for (m, t) in data.iter().zip(&targets) {
        let (fi, fj) = ((t[0] - x0) / step_mm, (t[1] - y0) / step_mm);
        let (i, j) = (fi.round(), fj.round());
        if (fi - i).abs() > LATTICE_TOL_STEPS || (fj - j).abs() > LATTICE_TOL_STEPS {
            return Err(invalid!("line {}: target ({}, {}) is not on the {step_mm} mm lattice from ({x0}, {y0})", m.line, t[0], t[1]));
        }
        ij.push((i as usize, j as usize));
    }
    let nx = ij.iter().map(|p| p.0).max().unwrap_or(0) + 1;
    let ny = ij.iter().map(|p| p.1).max().unwrap_or(0) + 1;
    let max = MAX_NODES_PER_AXIS as usize;
    if nx < 2 || ny < 2 || nx > max || ny > max {
        return Err(invalid!("the targets span {nx} x {ny} nodes; a grid needs 2..={max} nodes along each axis"));
    }
    let lattice = GridLattice { x0_mm: x0, y0_mm: y0, step_mm, nx, ny };
    let mut rows: Vec<Option<usize>> = vec![None; nx * ny];
    for (r, &(i, j)) in ij.iter().enumerate() {
        if let Some(prev) = rows[j * nx + i].replace(r) {
            let p = lattice.node_mm(i, j);
            return Err(invalid!(
                "line {}: node ({i}, {j}) at ({}, {}) is measured twice (also line {})",
                data[r].line,
                p[0],
                p[1],
                data[prev].line
            ));
        }
    }
    let rows = rows
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let (i, j) = (k % nx, k / nx);
            let p = lattice.node_mm(i, j);
            r.ok_or_else(|| invalid!("node ({i}, {j}) at ({}, {}) is missing from the data ({nx} x {ny} lattice)", p[0], p[1]))
        })
        .collect::<Result<Vec<_>, CalibError>>()?;
    Ok((lattice, rows))
}

/// One node's correction.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub i: usize,
    pub j: usize,
    pub target_mm: [f64; 2],
    /// measured − target (mm).
    pub error_mm: [f64; 2],
    /// To add to the model's IK angles (rad).
    pub dtheta_rad: [f64; 2],
}

/// The corrections of every node (see the module doc), in image order.
pub fn build_nodes(model: &FiveBar<f64>, data: &[Measurement], lattice: &GridLattice, rows: &[usize]) -> Result<Vec<Node>, CalibError> {
    rows.iter()
        .enumerate()
        .map(|(k, &r)| {
            let m = &data[r];
            let (i, j) = (k % lattice.nx, k / lattice.nx);
            let target = m.target_mm.ok_or_else(|| invalid!("line {}: node ({i}, {j}) has no target", m.line))?;
            let pose = model
                .inverse_pose(target, 0.0)
                .map_err(|e| invalid!("line {}: node ({i}, {j}) at ({}, {}): model IK: {e}", m.line, target[0], target[1]))?;
            let jinv = pose
                .inverse_jacobian()
                .map_err(|e| invalid!("line {}: node ({i}, {j}): {e}", m.line))?;
            let e = [m.measured_mm[0] - target[0], m.measured_mm[1] - target[1]];
            let th_cmd = m.theta_rad();
            let lin = mat2_mul_vec(&jinv, e);
            let d = [
                wrap_angle_rad(th_cmd[0] - pose.theta_rad[0]) - lin[0],
                wrap_angle_rad(th_cmd[1] - pose.theta_rad[1]) - lin[1],
            ];
            Ok(Node { i, j, target_mm: target, error_mm: e, dtheta_rad: d })
        })
        .collect()
}

/// The flash image of the nodes for `model`.
pub fn encode_image(model: &FiveBar<f64>, lattice: &GridLattice, nodes: &[Node]) -> Result<Vec<u8>, CalibError> {
    let geometry = GridGeometry {
        nx: lattice.nx as u16,
        ny: lattice.ny as u16,
        x0_mm: lattice.x0_mm as f32,
        y0_mm: lattice.y0_mm as f32,
        step_x_mm: lattice.step_mm as f32,
        step_y_mm: lattice.step_mm as f32,
    };
    let values: Vec<[f32; 2]> = nodes.iter().map(|n| [n.dtheta_rad[0] as f32, n.dtheta_rad[1] as f32]).collect();
    let mut image = vec![0u8; geometry.image_len()];
    encode(&mut image, &geometry, &model.cast::<f32>(), &values).map_err(|e| invalid!("encoding the grid image: {e}"))?;
    Ok(image)
}

/// A built grid: the lattice, the nodes and the image.
#[derive(Clone, Debug)]
pub struct BuiltGrid {
    pub lattice: GridLattice,
    pub nodes: Vec<Node>,
    /// The flash image (`kinematics_core::grid` format) for the model.
    pub image: Vec<u8>,
}

/// Figures of a built grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GridStats {
    /// |measured − target| at the nodes (µm).
    pub node_err: MaxRms,
    /// The largest correction (µrad).
    pub max_abs_dtheta_urad: f64,
}

impl BuiltGrid {
    /// The node errors and the largest correction.
    pub fn stats(&self) -> GridStats {
        let err_um: Vec<f64> = self.nodes.iter().map(|n| n.error_mm[0].hypot(n.error_mm[1]) * 1e3).collect();
        let max_dtheta = self.nodes.iter().flat_map(|n| n.dtheta_rad).map(f64::abs).fold(0.0, f64::max);
        GridStats { node_err: max_rms(&err_um), max_abs_dtheta_urad: max_dtheta * 1e6 }
    }
}

/// Lattice detection, node corrections and image in one call.
pub fn build(model: &FiveBar<f64>, data: &[Measurement], step_mm: f64) -> Result<BuiltGrid, CalibError> {
    let (lattice, rows) = detect_lattice(data, step_mm)?;
    let nodes = build_nodes(model, data, &lattice, &rows)?;
    let image = encode_image(model, &lattice, &nodes)?;
    Ok(BuiltGrid { lattice, nodes, image })
}

/// The readable node table.
pub fn format_csv(nodes: &[Node]) -> String {
    let mut s = String::from("i,j,x_mm,y_mm,dx_um,dy_um,dtheta1_urad,dtheta2_urad\n");
    for n in nodes {
        s.push_str(&format!(
            "{},{},{:.6},{:.6},{:.3},{:.3},{:.3},{:.3}\n",
            n.i,
            n.j,
            n.target_mm[0],
            n.target_mm[1],
            n.error_mm[0] * 1e3,
            n.error_mm[1] * 1e3,
            n.dtheta_rad[0] * 1e6,
            n.dtheta_rad[1] * 1e6
        ));
    }
    s
}
