//! The six-bar's loop closure, linearised about the nominal machine: how a small error of any
//! bar or pin moves the tool point, turns the platform and stretches the distal bars, at one
//! configuration (θ1, θ2). The diagnosis' six-bar effects (`parallelogram_mismatch`,
//! `link_stretch`) are reduced from these responses ([`crate::diagnose::sixbar_modes`]); the
//! correction grid's six-bar prior (`calib::grid`) is built from them too. Here, below both, so
//! that each can use it without importing the other.
//!
//! # The structure (any five-bar geometry)
//! The hidden five-bar (a, b, c, d, A0, B0, from the nominal model) is made a drafting-machine
//! six-bar by a [`SixBarDesign`]: the platform T carries the tool point C and the distal bars'
//! pins D = C + pD and E = C + pE; the motors sit at A0 + pD and B0 + pE (so that, with perfect
//! parts, C moves exactly like the five-bar's end point); each arm has two parallelograms in
//! series: lever / follower F (offset g) keeps the elbow piece K at a constant orientation,
//! distal bar Q / follower G (offset h) keeps the platform at K's orientation. Unknowns: the
//! small planar displacements (x, y, φ) of K1, K2 and T (9); elements: the six bars F1, Q1, G1,
//! F2, Q2, G2 (axial springs) and the two elbow bearings A, B (radial springs, 2 rows each): 10
//! compatibility rows for 9 unknowns, statically indeterminate by one, as the paper's machine.
//!
//! With the compatibility matrix B (elongation = B·dx − e, e the misfit the errors cause) and the
//! element stiffnesses K: `dx = (BᵀKB)⁻¹BᵀK·e`, elongations `ε = B·dx − e`, forces `K·ε` (a
//! multiple of the one self-stress state). Only stiffness *ratios* matter for dx and ε.
//!
//! # Raw errors ([`N_RAW`], µm): three per bar, three per bearing
//! * bar k: its length error δL and the difference Δp = δp(end Q) − δp(end P) of its two pins'
//!   position errors (x, y); misfit `e_k = δL − u_k·Δp` (u_k: the bar's direction);
//! * bearing A (B): the lever tip's displacement, motor-axis error (x, y) plus lever length error
//!   along the lever: misfit `e = δA0 + δa·u(θ1)`.
//!
//! Every plant error (`plant::config::SixBarErrors`) is one of these or a sum of them; a test
//! checks the tool displacement predicted here against the plant's nonlinear equilibrium.
//!
//! # Why two scalar functions say it all
//! The levers are held at θ1, θ2; C is where the two distal bars' ends meet. So the tool moves,
//! to first order, only through the change of the *effective distal lengths* ℓ1 (|A → D| along
//! the distal bar) and ℓ2: `dC = ∂C/∂b·ℓ1 + ∂C/∂c·ℓ2`. Each response is reported split by
//! cause: the platform rotation φT (moving D and E about C: `ℓ1 = −u3·J·pD·φT`, the
//! parallelogram mismatch), the elastic elongation of the distal bars (ε_Q: link stretch), and
//! the rest (bearings, lengths and pins: what a five-bar's constant parameters do, plus the
//! bearings' elastic deflection).
//!
//! Cost: one 9×9 solve and a 10×24 product per configuration (a few µs).

use crate::plant::config::SixBarConfig;
use kinematics_core::FiveBar;
use nalgebra::{SMatrix, SVector};

/// Number of raw errors (see the module doc).
pub const N_RAW: usize = 24;

/// Names of the raw errors (µm), in order: per bar F1, Q1, G1, F2, Q2, G2 (length, pin
/// difference x, y), then bearings A, B (motor axis x, y, lever length).
#[rustfmt::skip]
pub const RAW_NAMES: [&str; N_RAW] = [
    "f1_len", "f1_dpx", "f1_dpy", "q1_len", "q1_dpx", "q1_dpy", "g1_len", "g1_dpx", "g1_dpy",
    "f2_len", "f2_dpx", "f2_dpy", "q2_len", "q2_dpx", "q2_dpy", "g2_len", "g2_dpx", "g2_dpy",
    "a_x", "a_y", "a_len", "b_x", "b_y", "b_len",
];

type Mat9 = SMatrix<f64, 9, 9>;
type Row9 = SVector<f64, 9>;

/// The parts of the six-bar that the five-bar model does not have: where the platform pins and
/// the parallelograms' offsets are, and the elements' stiffnesses (only their ratios matter).
#[derive(Clone, Debug, PartialEq)]
pub struct SixBarDesign {
    /// Platform pins D (arm 1's distal bar) and E (arm 2's), relative to the tool point C (mm).
    pub platform_pin_mm: [[f64; 2]; 2],
    /// Offsets of each arm's [first, second] parallelogram (mm): the follower F runs from
    /// motor axis + g to elbow + g, the follower G from elbow + h to platform pin + h.
    pub offset_mm: [[[f64; 2]; 2]; 2],
    /// Axial stiffness of each arm's [F, Q, G] bars (N/mm).
    pub bar_k_n_per_mm: [[f64; 3]; 2],
    /// Radial stiffness of the elbow bearings A and B (N/mm).
    pub bearing_k_n_per_mm: f64,
}

impl SixBarDesign {
    /// The paper machine's design: [`SixBarDesign::for_model`] of its nominal five-bar at its
    /// workspace centre (equal to the `paper` plant's drawing).
    pub fn paper() -> Self {
        let spec = crate::machine_spec::MachineSpec::paper();
        Self::for_model(&spec.nominal, spec.workspace.centre_mm())
            .expect("the paper machine reaches its workspace centre")
    }

    /// The nominal design of a plant's six-bar (its drawing: the errors are ignored). The plant
    /// places D at C + (0, w/2) and its arm 2 mirrored in x.
    pub fn of_plant(cfg: &SixBarConfig) -> Self {
        let mirror = |v: [f64; 2]| [v[0], -v[1]];
        let (g, h) = (cfg.parallelogram_1_offset_mm, cfg.parallelogram_2_offset_mm);
        let w2 = cfg.platform_half_width_mm;
        let k = |section: f64| cfg.youngs_modulus_n_per_mm2 * section / cfg.link_mm;
        let arm = [
            k(cfg.follower_bar_section_mm2),
            k(cfg.main_bar_section_mm2),
            k(cfg.follower_bar_section_mm2),
        ];
        SixBarDesign {
            platform_pin_mm: [[0.0, w2], [0.0, -w2]],
            offset_mm: [[g, h], [mirror(g), mirror(h)]],
            bar_k_n_per_mm: [arm, arm],
            bearing_k_n_per_mm: cfg.pin_stiffness_n_per_mm,
        }
    }

    /// A design derived from a nominal five-bar and the centre of its workspace, for a machine
    /// whose drawing is not given: the paper machine's proportions (they reproduce
    /// [`SixBarDesign::of_plant`] of the paper plant exactly; a test checks it). Let L be the
    /// mean link length and n the unit normal (+90°) of the direction from A0 to the workspace
    /// centre: platform pins at ±(2/15)·L·n; each parallelogram offset 0.2·L long,
    /// perpendicular to its bar at the workspace centre (arm 1 turned +90°, arm 2 −90°), so no
    /// parallelogram comes near its flat shape; distal bars three times as stiff as the
    /// followers (120 vs 40 mm² of aluminium), bearings 20 kN/mm.
    pub fn for_model(model: &FiveBar<f64>, centre_mm: [f64; 2]) -> Result<Self, String> {
        let l = 0.25 * (model.a_mm + model.b_mm + model.c_mm + model.d_mm);
        let pose = model.inverse_pose(centre_mm, 0.0).map_err(|e| {
            format!(
                "the workspace centre ({:.3}, {:.3}) mm: {e}",
                centre_mm[0], centre_mm[1]
            )
        })?;
        let unit = |v: [f64; 2]| {
            let n = v[0].hypot(v[1]);
            [v[0] / n, v[1] / n]
        };
        let d = unit(sub(centre_mm, model.base_a0_mm));
        let n = [-d[1], d[0]];
        let w2 = 2.0 / 15.0 * l;
        let turn = |v: [f64; 2], s: f64| [-s * v[1] * 0.2 * l, s * v[0] * 0.2 * l];
        let (a, b) = (pose.elbow_a_mm, pose.elbow_b_mm);
        let (a0, b0, c) = (pose.base_a0_mm, pose.base_b0_mm, pose.tool_mm);
        let offset_mm = [
            [turn(unit(sub(a, a0)), 1.0), turn(unit(sub(c, a)), 1.0)],
            [turn(unit(sub(b, b0)), -1.0), turn(unit(sub(c, b)), -1.0)],
        ];
        // EA/L of aluminium (70 GPa) at the paper machine's sections.
        let k = |section_mm2: f64| 70_000.0 * section_mm2 / l;
        let arm = [k(40.0), k(120.0), k(40.0)];
        Ok(SixBarDesign {
            platform_pin_mm: [[w2 * n[0], w2 * n[1]], [-w2 * n[0], -w2 * n[1]]],
            offset_mm,
            bar_k_n_per_mm: [arm, arm],
            bearing_k_n_per_mm: 20_000.0,
        })
    }
}

/// The linear responses at one configuration, per µm of each raw error.
#[derive(Clone, Debug)]
pub struct Response {
    /// Tool displacement (µm per µm).
    pub tool: [[f64; 2]; N_RAW],
    /// Platform rotation (µrad per µm).
    pub platform_rot_urad: [f64; N_RAW],
    /// Elastic elongation of the distal bars Q1, Q2 (µm per µm).
    pub distal_elongation: [[f64; N_RAW]; 2],
    /// ∂C/∂b and ∂C/∂c of the five-bar here (µm per µm): the directions the effective distal
    /// lengths move the tool in.
    pub dc_db: [[f64; 2]; 2],
    /// Effective distal length change of each arm per µrad of platform rotation, `−u·J·p`
    /// (µm/µrad; u: the distal bar's direction, p: its platform pin).
    pub distal_per_rot: [f64; 2],
}

fn sub(u: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    [u[0] - v[0], u[1] - v[1]]
}
fn add(u: [f64; 2], v: [f64; 2]) -> [f64; 2] {
    [u[0] + v[0], u[1] + v[1]]
}

/// Where a bar end sits: on the ground, or on body 0 (K1), 1 (K2), 2 (T) at `r` from the body's
/// reference point (K: its bearing pin; T: the tool point).
#[derive(Clone, Copy)]
enum End {
    Ground([f64; 2]),
    Body(usize, [f64; 2], [f64; 2]),
}

impl End {
    fn at(self) -> [f64; 2] {
        match self {
            End::Ground(p) | End::Body(_, p, _) => p,
        }
    }
}

/// Why no response exists at a configuration.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LoopError {
    #[error("the five-bar has no pose at these angles: {0}")]
    NoPose(String),
    #[error("the six-bar's stiffness is singular here (a parallelogram or the five-bar is flat)")]
    Singular,
}

/// The linear responses of the six-bar built on `model` by `design`, at encoder angles
/// `theta_rad` (the model's own offsets applied, as in its forward kinematics).
pub fn response(
    model: &FiveBar<f64>,
    design: &SixBarDesign,
    theta_rad: [f64; 2],
) -> Result<Response, LoopError> {
    let pose = model
        .forward_pose(theta_rad, 0.0)
        .map_err(|e| LoopError::NoPose(e.to_string()))?;
    let [p_d, p_e] = design.platform_pin_mm;
    let c = pose.tool_mm;
    let elbow = [add(pose.elbow_a_mm, p_d), add(pose.elbow_b_mm, p_e)];
    let motor = [add(pose.base_a0_mm, p_d), add(pose.base_b0_mm, p_e)];
    let pin = [p_d, p_e];
    // Bars per arm: F (ground → K), Q (K → T), G (K → T).
    let mut bars: Vec<(End, End, f64)> = Vec::with_capacity(6);
    for arm in 0..2 {
        let [g, h] = design.offset_mm[arm];
        let [kf, kq, kg] = design.bar_k_n_per_mm[arm];
        bars.push((
            End::Ground(add(motor[arm], g)),
            End::Body(arm, add(elbow[arm], g), g),
            kf,
        ));
        bars.push((
            End::Body(arm, elbow[arm], [0.0; 2]),
            End::Body(2, add(c, pin[arm]), pin[arm]),
            kq,
        ));
        bars.push((
            End::Body(arm, add(elbow[arm], h), h),
            End::Body(2, add(add(c, pin[arm]), h), add(pin[arm], h)),
            kg,
        ));
    }
    // Compatibility rows (10 × 9), stiffnesses, and each bar's direction.
    let mut rows: Vec<(Row9, f64)> = Vec::with_capacity(10);
    let mut dirs = [[0.0; 2]; 6];
    for (k, &(p, q, stiffness)) in bars.iter().enumerate() {
        let d = sub(q.at(), p.at());
        let len = d[0].hypot(d[1]);
        if !(len > 0.0) {
            return Err(LoopError::Singular);
        }
        let u = [d[0] / len, d[1] / len];
        dirs[k] = u;
        let mut row = Row9::zeros();
        for (end, sign) in [(q, 1.0), (p, -1.0)] {
            if let End::Body(b, _, r) = end {
                row[3 * b] += sign * u[0];
                row[3 * b + 1] += sign * u[1];
                // d(end)/dφ = J·r = (−r_y, r_x).
                row[3 * b + 2] += sign * (u[0] * -r[1] + u[1] * r[0]);
            }
        }
        rows.push((row, stiffness));
    }
    for body in 0..2 {
        for axis in 0..2 {
            let mut row = Row9::zeros();
            row[3 * body + axis] = 1.0;
            rows.push((row, design.bearing_k_n_per_mm));
        }
    }
    let mut kmat = Mat9::zeros();
    for (row, k) in &rows {
        kmat += row * row.transpose() * *k;
    }
    let chol = kmat.cholesky().ok_or(LoopError::Singular)?;
    // Condition guard: a flat parallelogram makes the stiffness nearly singular.
    let diag_max = (0..9).map(|i| kmat[(i, i)]).fold(0.0, f64::max);
    let diag_min = (0..9).map(|i| kmat[(i, i)]).fold(f64::INFINITY, f64::min);
    if !(diag_min > 1e-9 * diag_max) {
        return Err(LoopError::Singular);
    }
    let lever = [
        {
            let v = sub(pose.elbow_a_mm, pose.base_a0_mm);
            let n = v[0].hypot(v[1]);
            [v[0] / n, v[1] / n]
        },
        {
            let v = sub(pose.elbow_b_mm, pose.base_b0_mm);
            let n = v[0].hypot(v[1]);
            [v[0] / n, v[1] / n]
        },
    ];
    let mut out = Response {
        tool: [[0.0; 2]; N_RAW],
        platform_rot_urad: [0.0; N_RAW],
        distal_elongation: [[0.0; N_RAW]; 2],
        dc_db: five_bar_distal_sensitivity(model, theta_rad)?,
        distal_per_rot: [0.0; 2],
    };
    for arm in 0..2 {
        let u = dirs[3 * arm + 1];
        let p = pin[arm];
        // ℓ = u·(shift of the arm's base) with the base shifted by −J·p·φ (1 µrad → 1e-6·|p| mm).
        out.distal_per_rot[arm] = -(u[0] * -p[1] + u[1] * p[0]) * 1e-3;
    }
    for raw in 0..N_RAW {
        let mut e = [0.0; 10];
        if raw < 18 {
            let (bar, kind) = (raw / 3, raw % 3);
            e[bar] = match kind {
                0 => 1.0,
                1 => -dirs[bar][0],
                _ => -dirs[bar][1],
            };
        } else {
            let (body, kind) = ((raw - 18) / 3, (raw - 18) % 3);
            let v = match kind {
                0 => [1.0, 0.0],
                1 => [0.0, 1.0],
                _ => lever[body],
            };
            e[6 + 2 * body] = v[0];
            e[7 + 2 * body] = v[1];
        }
        let mut rhs = Row9::zeros();
        for (i, (row, k)) in rows.iter().enumerate() {
            rhs += row * (*k * e[i]);
        }
        let dx = chol.solve(&rhs);
        out.tool[raw] = [dx[6], dx[7]];
        // Pin offsets r are in mm and displacements in µm, so φ comes out in µm/mm = mrad.
        out.platform_rot_urad[raw] = dx[8] * 1e3;
        for arm in 0..2 {
            let k = 3 * arm + 1;
            out.distal_elongation[arm][raw] = rows[k].0.dot(&dx) - e[k];
        }
    }
    Ok(out)
}

/// ∂C/∂b and ∂C/∂c of the five-bar at these angles (µm per µm), by central differences.
fn five_bar_distal_sensitivity(
    model: &FiveBar<f64>,
    theta_rad: [f64; 2],
) -> Result<[[f64; 2]; 2], LoopError> {
    let h = 1e-4;
    let mut out = [[0.0; 2]; 2];
    for (k, slot) in out.iter_mut().enumerate() {
        let eval = |s: f64| {
            let mut m = *model;
            if k == 0 {
                m.b_mm += s;
            } else {
                m.c_mm += s;
            }
            m.forward(theta_rad, 0.0)
                .map_err(|e| LoopError::NoPose(e.to_string()))
        };
        let (hi, lo) = (eval(h)?, eval(-h)?);
        *slot = [(hi[0] - lo[0]) / (2.0 * h), (hi[1] - lo[1]) / (2.0 * h)];
    }
    Ok(out)
}

/// The raw errors (µm) of a plant's six-bar errors (mm): what [`response`] multiplies.
pub fn raw_of_plant(e: &crate::plant::config::SixBarErrors) -> [f64; N_RAW] {
    let d = |q: [f64; 2], p: [f64; 2]| [1e3 * (q[0] - p[0]), 1e3 * (q[1] - p[1])];
    let f = [
        d(e.elbow_1_pin_f_mm, e.ground_follower_1_mm),
        d(e.elbow_2_pin_f_mm, e.ground_follower_2_mm),
    ];
    let q = [
        d(e.platform_pin_d_mm, e.elbow_1_pin_q_mm),
        d(e.platform_pin_e_mm, e.elbow_2_pin_q_mm),
    ];
    let g = [
        d(e.platform_pin_dd_mm, e.elbow_1_pin_g_mm),
        d(e.platform_pin_ee_mm, e.elbow_2_pin_g_mm),
    ];
    let motor = [e.ground_motor_1_mm, e.ground_motor_2_mm];
    let mut raw = [0.0; N_RAW];
    for arm in 0..2 {
        let o = 9 * arm;
        raw[o..o + 3].copy_from_slice(&[1e3 * e.bar_f_length_mm[arm], f[arm][0], f[arm][1]]);
        raw[o + 3..o + 6].copy_from_slice(&[1e3 * e.bar_q_length_mm[arm], q[arm][0], q[arm][1]]);
        raw[o + 6..o + 9].copy_from_slice(&[1e3 * e.bar_g_length_mm[arm], g[arm][0], g[arm][1]]);
        raw[18 + 3 * arm..21 + 3 * arm].copy_from_slice(&[
            1e3 * motor[arm][0],
            1e3 * motor[arm][1],
            1e3 * e.lever_length_mm[arm],
        ]);
    }
    raw
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine_spec::MachineSpec;
    use crate::plant::config::PlantConfig;
    use crate::plant::SixBar;

    fn poses() -> Vec<[f64; 2]> {
        let spec = MachineSpec::paper();
        spec.grid_nodes_mm()
            .into_iter()
            .step_by(7)
            .map(|t| spec.nominal.inverse(t, 0.0).unwrap())
            .collect()
    }

    #[test]
    fn paper_rule_reproduces_the_paper_plants_design() {
        let spec = MachineSpec::paper();
        let rule = SixBarDesign::for_model(&spec.nominal, spec.workspace.centre_mm()).unwrap();
        let plant = SixBarDesign::of_plant(&PlantConfig::ideal().sixbar);
        for (a, b) in rule
            .platform_pin_mm
            .iter()
            .flatten()
            .zip(plant.platform_pin_mm.iter().flatten())
        {
            assert!((a - b).abs() < 1e-9, "{rule:?} vs {plant:?}");
        }
        for (a, b) in rule
            .offset_mm
            .iter()
            .flatten()
            .flatten()
            .zip(plant.offset_mm.iter().flatten().flatten())
        {
            assert!((a - b).abs() < 1e-3, "{rule:?} vs {plant:?}");
        }
        for (a, b) in rule
            .bar_k_n_per_mm
            .iter()
            .flatten()
            .zip(plant.bar_k_n_per_mm.iter().flatten())
        {
            assert!((a / b - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn linear_response_matches_the_plants_equilibrium() {
        // Small random errors (10 µm), no clearances: the plant's nonlinear six-bar against the
        // linear prediction, at 93 poses over the workspace.
        let spec = MachineSpec::paper();
        for seed in 0..3 {
            let cfg = PlantConfig::ideal().with_random_errors(seed, 0.01, 0.0);
            let raw = raw_of_plant(&cfg.sixbar.errors);
            let design = SixBarDesign::of_plant(&cfg.sixbar);
            let mut sb = SixBar::new(&cfg.sixbar);
            let (mut worst, mut size, mut rot_worst, mut rot_size) =
                (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for th in poses() {
                let sol = sb.solve(th).unwrap();
                let nominal = spec.nominal.forward(th, 0.0).unwrap();
                let truth = [
                    (sol.tool_mm[0] - nominal[0]) * 1e3,
                    (sol.tool_mm[1] - nominal[1]) * 1e3,
                ];
                let r = response(&spec.nominal, &design, th).unwrap();
                let mut pred = [0.0; 2];
                let mut rot = 0.0;
                for (k, e) in raw.iter().enumerate() {
                    pred[0] += r.tool[k][0] * e;
                    pred[1] += r.tool[k][1] * e;
                    rot += r.platform_rot_urad[k] * e;
                }
                worst = worst.max((pred[0] - truth[0]).hypot(pred[1] - truth[1]));
                size = size.max(truth[0].hypot(truth[1]));
                rot_worst = rot_worst.max((rot - sol.platform_rot_rad * 1e6).abs());
                rot_size = rot_size.max(rot.abs());
            }
            // Second-order terms of 10 µm errors on 150 mm links: well below 0.1 µm.
            assert!(
                worst < 0.01 * size && worst < 0.2,
                "seed {seed}: worst {worst} µm of {size} µm"
            );
            assert!(
                rot_worst < 0.01 * rot_size,
                "seed {seed}: platform rotation off by {rot_worst} µrad of {rot_size}"
            );
        }
    }
}
