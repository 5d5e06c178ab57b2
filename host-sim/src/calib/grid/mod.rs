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
//! Cost: one IK and two 2x2 matrices per reading, plus the smoother (under a millisecond for
//! the paper's 21 × 31 nodes).
//!
//! # Noise: averaged repeats, smoothed node errors
//! A real instrument's noise (a laser tracker: σ ≈ 10 µm per axis) is as large as the errors
//! the grid is for; copied node by node into the image it would be added to the machine (the
//! paper plant with a 10 µm instrument: fit alone 22/5.2 µm, fit + a raw grid 27/9.6 µm at fresh
//! targets). [`build`] therefore
//! 1. averages the readings of each node (a node may be measured any number of times; every
//!    reading is first referred to the node's own command, so readings taken through different
//!    grids average correctly), and pools their scatter into the instrument's σ (`repeats`);
//! 2. estimates the error field from the nodes' mean errors (x and y, one smoothing): the
//!    model's parameter shapes, the six-bar's part-error responses from its linearised loop
//!    closure under a prior, and the 2-D Whittaker smoother of
//!    [`crate::numeric::lattice_smoother`] on the rest, both λs by restricted maximum
//!    likelihood ([`field`], "The six-bar prior": on simulated six-bar machines with a 10 µm
//!    instrument it leaves a fifth less than the generic bases: mean of the maxima at fresh
//!    targets 4.3 against 5.4 µm); without the prior
//!    ([`GridOptions::six_bar_prior`] off, or when the loop closure has no response at a node)
//!    the generic bases and the smoother, λ chosen by **generalised cross-validation**. Why
//!    a criterion from the data (REML, GCV) and not the σ of the repeats: it needs no σ, so it
//!    works with one reading per node (the normal session); a σ from repeats is only as good as the repeats
//!    are independent (readings taken back to back share drift and the same approach, so their
//!    scatter underestimates the noise), while the criterion sees the noise as it shows across the
//!    lattice. The repeats' σ is reported next to the one the estimate implies, and is what the expected
//!    residual uses when there are enough repeats (≥ [`MIN_REPEAT_DOF`] degrees of freedom);
//! 3. estimates what the correction leaves at the nodes (Stein's unbiased risk with that σ:
//!    `RSS/n − 2σ² + 4σ²·tr H/n` per node, never below the noise it keeps, `2σ²·tr H²/n`) and
//!    what the nodes' error is without it (`‖ē‖²/n − 2σ²`), and **applies no new correction
//!    when the first is not smaller**: a grid never adds more error than it removes
//!    ([`NoiseReport::applied`]). Without noise the smoother keeps the errors to rounding, so
//!    noiseless data give the grid of the unsmoothed formula.
//!
//! The nodes are weighted equally (their means, not their readings): exact when every node has
//! the same number of readings (what the protocols measure), and otherwise nodes with more
//! readings count no more than the others. [`Smoothing::None`] is the unsmoothed grid of
//! earlier versions (each node's own mean); [`Smoothing::Fixed`] a given λ; [`Smoothing::Exactly`]
//! another grid's basis and λ (to split its error into bias and noise).
//!
//! The node lattice is read from the targets: origin = smallest x and y, spacing = the given step
//! (must match the targets' spacing); every node must be measured at least once
//! ([`detect_lattice`], for callers that need exactly once, refuses repeats). The readable node
//! table ([`format_csv`], `grid.csv`) is this module's file format.

pub mod field;
pub mod unmeasured;

use super::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::{GridLattice, MachineSpec};
use crate::numeric::lattice_smoother::LatticeSmoother;
use crate::numeric::{max_rms, round3, MaxRms};
pub use field::{Basis, Smoothing};
use kinematics_core::grid::{encode, GridGeometry, MAX_NODES_PER_AXIS};
use kinematics_core::jacobian::mat2_mul_vec;
use kinematics_core::{wrap_angle_rad, FiveBar};
use nalgebra::DMatrix;
use serde::Serialize;

/// Largest distance (in steps) a target may be from its node.
const LATTICE_TOL_STEPS: f64 = 1e-4;
/// Degrees of freedom of the repeats' scatter from which their σ is trusted for the expected
/// residual (fewer: the smoother's σ is used).
pub const MIN_REPEAT_DOF: usize = 10;

/// Spacings between neighbouring distinct values (equal within the tolerance).
fn gaps(mut v: Vec<f64>, tol: f64) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&g| g > tol)
        .collect()
}

/// The lattice of the targets and each row's node `(i, j)`.
fn lattice_of(
    data: &[Measurement],
    step_mm: f64,
) -> Result<(GridLattice, Vec<(usize, usize)>), CalibError> {
    if !(step_mm > 0.0 && step_mm.is_finite()) {
        return Err(invalid!("the grid step must be positive, got {step_mm}"));
    }
    let mut targets = Vec::with_capacity(data.len());
    for m in data {
        targets.push(m.target_mm.ok_or_else(|| {
            invalid!(
                "line {}: no x_target_mm,y_target_mm: the grid nodes are the targets",
                m.line
            )
        })?);
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
    let max = MAX_NODES_PER_AXIS as usize;
    for (m, t) in data.iter().zip(&targets) {
        let (fi, fj) = ((t[0] - x0) / step_mm, (t[1] - y0) / step_mm);
        let (i, j) = (fi.round(), fj.round());
        if (fi - i).abs() > LATTICE_TOL_STEPS || (fj - j).abs() > LATTICE_TOL_STEPS {
            return Err(invalid!(
                "line {}: target ({}, {}) is not on the {step_mm} mm lattice from ({x0}, {y0})",
                m.line,
                t[0],
                t[1]
            ));
        }
        if i >= max as f64 || j >= max as f64 {
            return Err(invalid!(
                "the targets span more than {max} nodes along an axis (line {}: ({}, {}))",
                m.line,
                t[0],
                t[1]
            ));
        }
        ij.push((i as usize, j as usize));
    }
    let nx = ij.iter().map(|p| p.0).max().unwrap_or(0) + 1;
    let ny = ij.iter().map(|p| p.1).max().unwrap_or(0) + 1;
    if nx < 2 || ny < 2 {
        return Err(invalid!(
            "the targets span {nx} x {ny} nodes; a grid needs 2..={max} nodes along each axis"
        ));
    }
    Ok((
        GridLattice {
            x0_mm: x0,
            y0_mm: y0,
            step_mm,
            nx,
            ny,
        },
        ij,
    ))
}

/// The error for the first node without a reading.
fn missing(lattice: &GridLattice, k: usize) -> CalibError {
    let (i, j) = (k % lattice.nx, k / lattice.nx);
    let p = lattice.node_mm(i, j);
    invalid!(
        "node ({i}, {j}) at ({}, {}) is missing from the data ({} x {} lattice)",
        p[0],
        p[1],
        lattice.nx,
        lattice.ny
    )
}

/// Finds the lattice and the row of every node (`rows[j·nx + i]`, x fastest), refusing a node
/// measured more than once (see [`group_readings`] for repeats).
pub fn detect_lattice(
    data: &[Measurement],
    step_mm: f64,
) -> Result<(GridLattice, Vec<usize>), CalibError> {
    let (lattice, ij) = lattice_of(data, step_mm)?;
    let nx = lattice.nx;
    let mut rows: Vec<Option<usize>> = vec![None; nx * lattice.ny];
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
        .map(|(k, r)| r.ok_or_else(|| missing(&lattice, k)))
        .collect::<Result<Vec<_>, CalibError>>()?;
    Ok((lattice, rows))
}

/// Finds the lattice and the rows of every node's readings (`rows[j·nx + i]`, file order),
/// each node read at least once.
pub fn group_readings(
    data: &[Measurement],
    step_mm: f64,
) -> Result<(GridLattice, Vec<Vec<usize>>), CalibError> {
    let (lattice, ij) = lattice_of(data, step_mm)?;
    let mut rows: Vec<Vec<usize>> = vec![Vec::new(); lattice.nx * lattice.ny];
    for (r, &(i, j)) in ij.iter().enumerate() {
        rows[j * lattice.nx + i].push(r);
    }
    if let Some(k) = rows.iter().position(Vec::is_empty) {
        return Err(missing(&lattice, k));
    }
    Ok((lattice, rows))
}

/// One node's correction.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub i: usize,
    pub j: usize,
    pub target_mm: [f64; 2],
    /// measured − target (mm), the mean of the node's readings.
    pub error_mm: [f64; 2],
    /// The error corrected for (mm): the estimate of the machine's error at the model's IK
    /// command (see the module doc); with one reading and no smoothing `error_mm − J·(θ_cmd −
    /// θ_ik)`, zero when the grid applies no correction.
    pub corrected_mm: [f64; 2],
    /// Readings of the node.
    pub readings: usize,
    /// To add to the model's IK angles (rad): `−J⁻¹·corrected`.
    pub dtheta_rad: [f64; 2],
}

/// One node's readings referred to the node: the model's pose there and the means.
struct NodeMeans {
    target: [f64; 2],
    /// The model's IK (encoder angles, rad).
    theta_ik: [f64; 2],
    jinv: [[f64; 2]; 2],
    /// Mean measured − target (mm).
    error: [f64; 2],
    /// Mean of each reading's error referred to the IK command, `e − J·(θ_cmd − θ_ik)` (mm).
    error_ik: [f64; 2],
    /// Σ over readings of |v − v̄|² (mm²), v = the reading's error referred to the IK command.
    scatter: f64,
    readings: usize,
}

fn node_means(
    model: &FiveBar<f64>,
    data: &[Measurement],
    rows: &[usize],
    i: usize,
    j: usize,
) -> Result<NodeMeans, CalibError> {
    let first = &data[rows[0]];
    let target = first
        .target_mm
        .ok_or_else(|| invalid!("line {}: node ({i}, {j}) has no target", first.line))?;
    let pose = model.inverse_pose(target, 0.0).map_err(|e| {
        invalid!(
            "line {}: node ({i}, {j}) at ({}, {}): model IK: {e}",
            first.line,
            target[0],
            target[1]
        )
    })?;
    let jinv = pose
        .inverse_jacobian()
        .map_err(|e| invalid!("line {}: node ({i}, {j}): {e}", first.line))?;
    let jac = pose
        .jacobian()
        .map_err(|e| invalid!("line {}: node ({i}, {j}): {e}", first.line))?;
    let n = rows.len() as f64;
    let (mut error, mut error_ik) = ([0.0; 2], [0.0; 2]);
    let mut v = Vec::with_capacity(rows.len());
    for &r in rows {
        let m = &data[r];
        let th = m.theta_rad();
        let d = [
            wrap_angle_rad(th[0] - pose.theta_rad[0]),
            wrap_angle_rad(th[1] - pose.theta_rad[1]),
        ];
        let e = [m.measured_mm[0] - target[0], m.measured_mm[1] - target[1]];
        // The reading's error had it been commanded at θ_ik: e − J·Δθ (first order in Δθ).
        let jd = mat2_mul_vec(&jac, d);
        let vr = [e[0] - jd[0], e[1] - jd[1]];
        for k in 0..2 {
            error[k] += e[k] / n;
            error_ik[k] += vr[k] / n;
        }
        v.push(vr);
    }
    let scatter = v
        .iter()
        .map(|p| (p[0] - error_ik[0]).powi(2) + (p[1] - error_ik[1]).powi(2))
        .sum();
    Ok(NodeMeans {
        target,
        theta_ik: pose.theta_rad,
        jinv,
        error,
        error_ik,
        scatter,
        readings: rows.len(),
    })
}

/// The node's correction for the error `corrected` (mm) at the IK command: `−J⁻¹·corrected`.
fn node(means: &NodeMeans, i: usize, j: usize, corrected: [f64; 2]) -> Node {
    let lin = mat2_mul_vec(&means.jinv, corrected);
    Node {
        i,
        j,
        target_mm: means.target,
        error_mm: means.error,
        corrected_mm: corrected,
        readings: means.readings,
        dtheta_rad: [-lin[0], -lin[1]],
    }
}

/// The corrections of every node from one reading each (`rows` from [`detect_lattice`]), in
/// image order, unsmoothed (the formula of the module doc).
pub fn build_nodes(
    model: &FiveBar<f64>,
    data: &[Measurement],
    lattice: &GridLattice,
    rows: &[usize],
) -> Result<Vec<Node>, CalibError> {
    rows.iter()
        .enumerate()
        .map(|(k, &r)| {
            let (i, j) = (k % lattice.nx, k / lattice.nx);
            let m = node_means(model, data, &[r], i, j)?;
            Ok(node(&m, i, j, m.error_ik))
        })
        .collect()
}

/// The flash image of the nodes for `model`.
pub fn encode_image(
    model: &FiveBar<f64>,
    lattice: &GridLattice,
    nodes: &[Node],
) -> Result<Vec<u8>, CalibError> {
    let geometry = GridGeometry {
        nx: lattice.nx as u16,
        ny: lattice.ny as u16,
        x0_mm: lattice.x0_mm as f32,
        y0_mm: lattice.y0_mm as f32,
        step_x_mm: lattice.step_mm as f32,
        step_y_mm: lattice.step_mm as f32,
    };
    let values: Vec<[f32; 2]> = nodes
        .iter()
        .map(|n| [n.dtheta_rad[0] as f32, n.dtheta_rad[1] as f32])
        .collect();
    let mut image = vec![0u8; geometry.image_len()];
    encode(&mut image, &geometry, &model.cast::<f32>(), &values)
        .map_err(|e| invalid!("encoding the grid image: {e}"))?;
    Ok(image)
}

/// How to build a grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridOptions {
    /// Node spacing (mm).
    pub step_mm: f64,
    pub smoothing: Smoothing,
    /// The instrument's σ per axis the machine file states (µm): reported beside the σ the
    /// data show, and the σ used when the data give none. The smoothing never depends on it
    /// (GCV needs no σ; module doc).
    pub instrument_sigma_um: Option<f64>,
    /// Describe the field by the six-bar's loop closure under a prior (`field.rs`, the
    /// default): the machine is the paper's kind of overconstrained six-bar. Off: the generic
    /// bases only (a machine that is not such a six-bar, or to compare).
    pub six_bar_prior: bool,
}

impl GridOptions {
    /// The grid of `spec`'s machine: its lattice step and instrument, the smoothing chosen from
    /// the data, the six-bar prior on.
    pub fn for_machine(spec: &MachineSpec) -> Self {
        GridOptions {
            step_mm: spec.grid.step_mm,
            smoothing: Smoothing::Gcv,
            instrument_sigma_um: Some(spec.instrument_sigma_um),
            six_bar_prior: true,
        }
    }
}

/// A σ the data show this many times the machine file's is named (`NoiseReport::describe`).
pub const SIGMA_ABOVE_INSTRUMENT: f64 = 2.0;

/// What the grid knows about the noise of its nodes and what it did about it (µm; σ per axis).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NoiseReport {
    pub readings: usize,
    pub readings_per_node_min: usize,
    pub readings_per_node_max: usize,
    /// σ of one reading from the scatter of repeated readings about their node's mean.
    pub repeats_sigma_um: Option<f64>,
    /// Degrees of freedom of that scatter (Σ (readings − 1) × 2 axes).
    pub repeats_dof: usize,
    /// σ of one reading implied by the estimate's residual (`RSS / (2n − tr A)`).
    pub smoother_sigma_um: Option<f64>,
    /// The instrument's σ the machine file states ([`GridOptions::instrument_sigma_um`]).
    pub instrument_sigma_um: Option<f64>,
    /// The σ the expected residual uses, and where it comes from (`repeats`, `smoother`,
    /// `machine file` when the data give none, or `unknown`).
    pub noise_sigma_um: Option<f64>,
    pub noise_source: &'static str,
    /// `gcv`, `fixed`, `exactly` or `none`.
    pub smoothing: &'static str,
    /// The parametric part chosen (see `field.rs`) and its independent columns.
    pub basis: Basis,
    pub basis_columns: usize,
    pub lambda: f64,
    /// The six-bar prior's λ (`basis` `six_bar`; 0 otherwise): σ² over the variance of a part
    /// error, µm² per µm² (`field.rs`, module doc).
    pub six_bar_lambda: f64,
    /// `tr A / 2`: nodes' worth of freedom the estimated field has (of `nodes`).
    pub effective_nodes: f64,
    pub nodes: usize,
    /// `sqrt(tr AᵀA / 2n)`: the fraction of a node mean's noise that stays in the correction.
    pub noise_kept: f64,
    /// RMS of the nodes' mean errors (at the IK command) and of the field corrected for.
    pub node_mean_error_rms_um: f64,
    pub correction_rms_um: f64,
    /// The nodes' true error without the grid, estimated (`‖ȳ‖²/n − 2σ²`).
    pub error_before_rms_um: Option<f64>,
    /// What the correction leaves at the nodes, estimated (module doc, step 3).
    pub expected_residual_rms_um: Option<f64>,
    /// False when the correction would not have removed more error than it adds: the grid
    /// then applies none (zero at every node).
    pub applied: bool,
}

impl NoiseReport {
    /// One line for people (stderr).
    pub fn describe(&self) -> String {
        let um = |v: Option<f64>| v.map_or("unknown".to_string(), |v| format!("{v:.2} µm"));
        let mut s = format!(
            "{} readings on {} nodes ({}..{} per node); noise σ {} per axis (from {}; repeats {}, smoother {}); ",
            self.readings,
            self.nodes,
            self.readings_per_node_min,
            self.readings_per_node_max,
            um(self.noise_sigma_um),
            self.noise_source,
            um(self.repeats_sigma_um),
            um(self.smoother_sigma_um),
        );
        s.push_str(&match self.smoothing {
            "none" => "no smoothing".to_string(),
            how => format!(
                "smoothing ({how}): basis {:?} ({} columns{}), λ = {:.3e}, {:.1} effective nodes of {}",
                self.basis,
                self.basis_columns,
                if self.basis == Basis::SixBar { format!(", six-bar prior λ = {:.3e}", self.six_bar_lambda) } else { String::new() },
                self.lambda,
                self.effective_nodes,
                self.nodes
            ),
        });
        s.push_str(&format!(
            "; node error {:.2} µm RMS measured, {} true before, {} expected after",
            self.node_mean_error_rms_um,
            um(self.error_before_rms_um),
            um(self.expected_residual_rms_um)
        ));
        if let (Some(data), Some(stated)) = (self.noise_sigma_um, self.instrument_sigma_um) {
            if self.noise_source != "machine file" && data > SIGMA_ABOVE_INSTRUMENT * stated {
                s.push_str(&format!(
                    "; the data's σ is {:.1}x the machine file's instrument σ ({stated} µm): a worse instrument than stated, or errors rougher than the lattice",
                    data / stated
                ));
            }
        }
        if !self.applied {
            s.push_str("; NOT applied: the nodes' errors are not above the noise, the grid corrects nothing");
        }
        s
    }
}

/// A built grid: the lattice, the nodes and the image.
#[derive(Clone, Debug)]
pub struct BuiltGrid {
    pub lattice: GridLattice,
    pub nodes: Vec<Node>,
    /// The flash image (`kinematics_core::grid` format) for the model.
    pub image: Vec<u8>,
    pub noise: NoiseReport,
}

/// Figures of a built grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GridStats {
    /// |measured − target| at the nodes (µm), the nodes' mean readings.
    pub node_err: MaxRms,
    /// The largest correction (µrad).
    pub max_abs_dtheta_urad: f64,
}

impl BuiltGrid {
    /// The node errors and the largest correction.
    pub fn stats(&self) -> GridStats {
        let err_um: Vec<f64> = self
            .nodes
            .iter()
            .map(|n| n.error_mm[0].hypot(n.error_mm[1]) * 1e3)
            .collect();
        let max_dtheta = self
            .nodes
            .iter()
            .flat_map(|n| n.dtheta_rad)
            .map(f64::abs)
            .fold(0.0, f64::max);
        GridStats {
            node_err: max_rms(&err_um),
            max_abs_dtheta_urad: max_dtheta * 1e6,
        }
    }
}

/// Lattice detection, node means, smoothing (chosen from the data, the six-bar prior on) and
/// image in one call.
pub fn build(
    model: &FiveBar<f64>,
    data: &[Measurement],
    step_mm: f64,
) -> Result<BuiltGrid, CalibError> {
    build_with(
        model,
        data,
        &GridOptions {
            step_mm,
            smoothing: Smoothing::Gcv,
            instrument_sigma_um: None,
            six_bar_prior: true,
        },
    )
}

/// The model's parameter shapes `∂FK/∂p` at the nodes' IK (2n × 10, rows x, y per node; µm per
/// parameter unit); `None` where a node's neighbourhood leaves the model's domain.
fn parameter_shapes(model: &FiveBar<f64>, means: &[NodeMeans]) -> Option<DMatrix<f64>> {
    let poses: Vec<Measurement> = means
        .iter()
        .map(|m| Measurement {
            theta_deg: [m.theta_ik[0].to_degrees(), m.theta_ik[1].to_degrees()],
            measured_mm: m.target,
            target_mm: Some(m.target),
            dir: None,
            run: None,
            t_s: None,
            line: 0,
        })
        .collect();
    super::fit::params::jacobian(model, &poses)
        .ok()
        .map(|j| j * 1e3)
}

/// The six-bar's tool displacement per µm of each part error at the nodes' IK (2n × 24, rows x,
/// y per node; `loop_closure`, the design from the model's proportions about the
/// lattice's centre); `None` where the loop closure has no response (a flat parallelogram, a
/// node the model cannot reach), and the grid then falls back to the generic bases.
fn six_bar_responses(
    model: &FiveBar<f64>,
    means: &[NodeMeans],
    lattice: &GridLattice,
) -> Option<DMatrix<f64>> {
    use crate::loop_closure::{response, SixBarDesign, N_RAW};
    let centre = [
        lattice.x0_mm + 0.5 * (lattice.nx - 1) as f64 * lattice.step_mm,
        lattice.y0_mm + 0.5 * (lattice.ny - 1) as f64 * lattice.step_mm,
    ];
    let design = SixBarDesign::for_model(model, centre).ok()?;
    let mut r = DMatrix::zeros(2 * means.len(), N_RAW);
    for (k, m) in means.iter().enumerate() {
        let at = response(model, &design, m.theta_ik).ok()?;
        for (c, tool) in at.tool.iter().enumerate() {
            r[(2 * k, c)] = tool[0];
            r[(2 * k + 1, c)] = tool[1];
        }
    }
    r.iter().all(|v| v.is_finite()).then_some(r)
}

/// The nodes' coordinates scaled to [−1, 1] over the lattice.
fn scaled_coords(lattice: &GridLattice) -> Vec<[f64; 2]> {
    let s = |i: usize, n: usize| {
        if n > 1 {
            2.0 * i as f64 / (n - 1) as f64 - 1.0
        } else {
            0.0
        }
    };
    (0..lattice.nx * lattice.ny)
        .map(|k| [s(k % lattice.nx, lattice.nx), s(k / lattice.nx, lattice.ny)])
        .collect()
}

/// [`build`] with the smoothing chosen.
pub fn build_with(
    model: &FiveBar<f64>,
    data: &[Measurement],
    opts: &GridOptions,
) -> Result<BuiltGrid, CalibError> {
    if let Some(s) = opts.instrument_sigma_um {
        if !(s >= 0.0 && s.is_finite()) {
            return Err(invalid!(
                "the instrument's σ must be a non-negative number, got {s}"
            ));
        }
    }
    if let Smoothing::Fixed(l) | Smoothing::Exactly(_, l, _) = opts.smoothing {
        if !(l >= 0.0 && l.is_finite()) {
            return Err(invalid!(
                "the smoothing λ must be a non-negative number, got {l}"
            ));
        }
    }
    if let Smoothing::Exactly(Basis::SixBar, _, l) = opts.smoothing {
        if !(l > 0.0 && l.is_finite()) {
            return Err(invalid!(
                "the six-bar prior's λ must be a positive number, got {l}"
            ));
        }
    }
    let (lattice, rows) = group_readings(data, opts.step_mm)?;
    let means = rows
        .iter()
        .enumerate()
        .map(|(k, r)| node_means(model, data, r, k % lattice.nx, k / lattice.nx))
        .collect::<Result<Vec<_>, CalibError>>()?;
    let n = means.len();
    let nf = n as f64;
    let counts: Vec<usize> = means.iter().map(|m| m.readings).collect();
    // Mean of 1/readings: a node mean's noise variance is σ² times this, on average.
    let inv_count = counts.iter().map(|&c| 1.0 / c as f64).sum::<f64>() / nf;
    let repeats_dof = 2 * counts.iter().map(|c| c - 1).sum::<usize>();
    let repeats_sigma_um = (repeats_dof > 0)
        .then(|| (means.iter().map(|m| m.scatter).sum::<f64>() / repeats_dof as f64).sqrt() * 1e3);

    let y: Vec<[f64; 2]> = means
        .iter()
        .map(|m| [m.error_ik[0] * 1e3, m.error_ik[1] * 1e3])
        .collect();
    let shapes = match opts.smoothing {
        Smoothing::None => None,
        _ => parameter_shapes(model, &means),
    };
    let smoother = LatticeSmoother::new(lattice.nx, lattice.ny);
    let responses = match opts.smoothing {
        Smoothing::None => None,
        Smoothing::Exactly(Basis::SixBar, ..) => Some(six_bar_responses(model, &means, &lattice).ok_or_else(|| {
            invalid!("the six-bar prior's choice cannot be re-applied: the loop closure has no response at every node")
        })?),
        _ if !opts.six_bar_prior => None,
        _ => six_bar_responses(model, &means, &lattice),
    };
    let est = field::estimate(
        &smoother,
        &y,
        shapes.as_ref(),
        responses.as_ref(),
        &scaled_coords(&lattice),
        opts.smoothing,
    );
    // σ of one reading: the estimate's is a node mean's, scaled by the readings.
    let smoother_sigma_um = est.noise_sigma_um().map(|s| s / inv_count.sqrt());
    let (noise_sigma_um, noise_source) = match (repeats_sigma_um, smoother_sigma_um) {
        (Some(s), _) if repeats_dof >= MIN_REPEAT_DOF => (Some(s), "repeats"),
        (_, Some(s)) => (Some(s), "smoother"),
        (Some(s), None) => (Some(s), "repeats"),
        (None, None) => match opts.instrument_sigma_um {
            Some(s) => (Some(s), "machine file"),
            None => (None, "unknown"),
        },
    };
    let mean_sq = y.iter().map(|v| v[0] * v[0] + v[1] * v[1]).sum::<f64>() / nf;
    let corr_sq = est
        .fitted_um
        .iter()
        .map(|v| v[0] * v[0] + v[1] * v[1])
        .sum::<f64>()
        / nf;
    let (error_before, expected) = match noise_sigma_um {
        None => (None, None),
        Some(s) => {
            // σ² of a node mean per axis; the risk is per node (both axes).
            let var = s * s * inv_count;
            let kept = var * est.noise_dof / nf;
            let risk = est.rss / nf - 2.0 * var + 2.0 * var * est.dof / nf;
            (
                Some((mean_sq - 2.0 * var).max(0.0).sqrt()),
                Some(risk.max(kept).sqrt()),
            )
        }
    };
    let applied = match (opts.smoothing, error_before, expected) {
        // Another grid's choice re-applied: the estimate as it is (a decomposition, not a
        // correction to judge).
        (Smoothing::None | Smoothing::Exactly(..), ..) => true,
        (_, Some(before), Some(after)) => after < before,
        _ => true,
    };
    let nodes: Vec<Node> = means
        .iter()
        .zip(&est.fitted_um)
        .enumerate()
        .map(|(k, (m, f))| {
            node(
                m,
                k % lattice.nx,
                k / lattice.nx,
                if applied {
                    [f[0] * 1e-3, f[1] * 1e-3]
                } else {
                    [0.0; 2]
                },
            )
        })
        .collect();
    let image = encode_image(model, &lattice, &nodes)?;
    let r3 = |v: Option<f64>| v.map(round3);
    let noise = NoiseReport {
        readings: data.len(),
        readings_per_node_min: counts.iter().copied().min().unwrap_or(0),
        readings_per_node_max: counts.iter().copied().max().unwrap_or(0),
        repeats_sigma_um: r3(repeats_sigma_um),
        repeats_dof,
        smoother_sigma_um: r3(smoother_sigma_um),
        instrument_sigma_um: opts.instrument_sigma_um,
        noise_sigma_um: r3(noise_sigma_um),
        noise_source,
        smoothing: match opts.smoothing {
            Smoothing::Gcv => "gcv",
            Smoothing::Fixed(_) => "fixed",
            Smoothing::Exactly(..) => "exactly",
            Smoothing::None => "none",
        },
        basis: est.basis,
        basis_columns: est.columns,
        lambda: est.lambda,
        six_bar_lambda: est.prior_lambda,
        effective_nodes: round3(est.dof / 2.0),
        nodes: n,
        noise_kept: round3((est.noise_dof / (2.0 * nf)).sqrt()),
        node_mean_error_rms_um: round3(mean_sq.sqrt()),
        correction_rms_um: round3(if applied { corr_sq.sqrt() } else { 0.0 }),
        error_before_rms_um: r3(error_before),
        expected_residual_rms_um: r3(if applied { expected } else { error_before }),
        applied,
    };
    Ok(BuiltGrid {
        lattice,
        nodes,
        image,
        noise,
    })
}

/// The readable node table (`dx_um,dy_um`: the nodes' mean errors; `dtheta*_urad`: the
/// corrections, after smoothing). The columns are a contract: scripts read them.
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
