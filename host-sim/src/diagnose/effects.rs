//! The effect library: small parametric extensions of the five-bar forward model, each with a
//! physical meaning, and the one forward function that applies any subset of them.
//!
//! Why one flat parameter vector: every effect owns a fixed slice of [`N_PARAMS`] numbers;
//! inactive effects keep theirs at zero, so "the model with effects E" is just "the forward
//! function with only E's entries free". Internal units are chosen so every parameter is O(1..100)
//! (µm, µrad, ppm): the LM and its finite differences then need no scaling.
//!
//! Prediction of the instrument reading for a measured pose (encoder angles θ, approach
//! directions dir):
//!
//! ```text
//! θg_j = θ_j + offset_j(base model) + δθ_j − dir_j·β_j/2 + g_j·(θ_j − mean θ_j)
//! a' = a + δa,  d' = d + δd
//! b' = b + δb + Σ k_b·u_b,  c' = c + δc + Σ k_c·u_c   (link_stretch, two basis functions each, below)
//! B0' = B0 + (bx, by)
//! reading = (1 + s)·R(φ)·FK(...) + (tx, ty)
//! ```
//!
//! link_stretch basis. The internal stress of the overconstrained loops depends on the shape of
//! the mechanism only (the machine is planar; no gravity in its plane). With A0 = B0 and equal
//! links the shape is one-dimensional: every internal angle is a function of |A0C| alone, and a
//! rotation of C about A0 turns the mechanism rigidly. A distal link length error δb(shape) moves
//! C by `∂C/∂b · δb`, while a constant δb, δa and motor offset δθ1 move it by `∂C/∂b · f` with
//! `f ∈ span{1, cos e1, sin e1}` (e1: the elbow angle between links a and b). So the part of any
//! stretch that lies in that span is *exactly* what different constant link lengths and encoder
//! offsets do, and no tool-point measurement can tell them apart. Worse, on the nominal machine
//! A0ACB is a rhombus: the elbow angle is π − ψ (ψ: angle between the distal links at C), so
//! `{1, cos e1, sin e1} = {1, cos ψ, sin ψ}` and over the workspace's ψ range (about 1 rad) these
//! three reproduce any smooth function of ψ up to its third-order terms. The basis therefore keeps
//! only what they cannot do: `u_b = g − (weighted least-squares projection of g on
//! {1, cos e1, sin e1} over the data)` for `g = cos 2ψ` and `g = sin 2ψ` (the lowest harmonic of
//! ψ not reproduced exactly; cos for the even, sin for the odd part about ψ = 90°; weights
//! |∂C/∂b|²), likewise `u_c` with e2, each scaled to unit RMS over the data, so the four k's are
//! RMS stretches in µm. Like the "zero mean" rule, the rest stays `link_lengths` /
//! `encoder_offset`. If nothing is left (rounding only), the effect is switched off with a note.
//!
//! Sign of backlash: a motor that last moved in +θ (dir = +1) drags the link behind it through
//! the lost motion, so the link sits β/2 short of the encoder angle; β > 0 is lost motion.
//!
//! Cost: one closed-form FK per point per evaluation (a few hundred ns); no allocation per point.

use crate::effect::PhysicalEffect;
use crate::io::measurement_csv::Measurement;
use kinematics_core::{wrap_angle_rad, FiveBar};

/// Smallest transmission |sin| of a usable point (about 0.06° from a singular configuration).
pub const MIN_TRANSMISSION: f64 = 1e-3;

/// Number of entries of the full parameter vector.
pub const N_PARAMS: usize = 20;

/// One candidate effect: a [`PhysicalEffect`] with its parameters in the extended forward model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Effect {
    /// Which effect (its name is the report's: the tests and other tools rely on it).
    pub kind: PhysicalEffect,
    /// Indices into the full parameter vector.
    pub params: &'static [usize],
    /// Physical meaning, for the report.
    pub meaning: &'static str,
    /// The effect needs the dir1/dir2 columns.
    pub needs_dir: bool,
}

/// Parameter names with units (index = position in the full vector).
#[rustfmt::skip]
pub const PARAM_NAMES: [&str; N_PARAMS] = [
    "da_um", "db_um", "dc_um", "dd_um", // 0..4 link_lengths
    "dtheta1_urad", "dtheta2_urad",     // 4..6 encoder_offset
    "b0x_um", "b0y_um",                 // 6..8 base_offset
    "beta1_urad", "beta2_urad",         // 8..10 backlash
    "kb_cos2_um", "kc_cos2_um",         // 10..12 link_stretch (RMS stretch over the data, µm), cos 2ψ part
    "tx_um", "ty_um", "rot_urad",       // 12..15 frame
    "scale_ppm",                        // 15 scale
    "gear1_ppm", "gear2_ppm",           // 16..18 gear_ratio
    "kb_sin2_um", "kc_sin2_um",         // 18..20 link_stretch, sin 2ψ part
];

/// The library, in a fixed order (ties in the selection go to the earlier one).
pub const LIBRARY: [Effect; 8] = [
    Effect {
        kind: PhysicalEffect::LinkLengths,
        params: &[0, 1, 2, 3],
        meaning: "a, b, c, d differ from the model (manufacturing, assembly)",
        needs_dir: false,
    },
    Effect {
        kind: PhysicalEffect::EncoderOffset,
        params: &[4, 5],
        meaning: "motor zero offsets (encoder index not at the model's zero)",
        needs_dir: false,
    },
    Effect { kind: PhysicalEffect::BaseOffset, params: &[6, 7], meaning: "B0 is not where the model has it", needs_dir: false },
    Effect {
        kind: PhysicalEffect::Backlash,
        params: &[8, 9],
        meaning: "lost motion per motor: the link lags the encoder by beta/2 against the approach direction",
        needs_dir: true,
    },
    Effect {
        kind: PhysicalEffect::LinkStretch,
        params: &[10, 11, 18, 19],
        meaning: "configuration-dependent distal link lengths from the internal stress of the overconstrained loops: \
                  b and c vary with cos 2ψ and sin 2ψ (ψ: angle between the distal links), minus the part constant link \
                  lengths and encoder offsets reproduce exactly (see effects.rs)",
        needs_dir: false,
    },
    Effect {
        kind: PhysicalEffect::Frame,
        params: &[12, 13, 14],
        meaning: "instrument frame offset (x, y) and rotation about A0",
        needs_dir: false,
    },
    Effect { kind: PhysicalEffect::Scale, params: &[15], meaning: "instrument scale error (about A0)", needs_dir: false },
    Effect {
        kind: PhysicalEffect::GearRatio,
        params: &[16, 17],
        meaning: "transmission ratio error per motor: link angle = encoder angle scaled by (1+g) about the data's mean angle \
                  (the constant part stays encoder_offset)",
        needs_dir: false,
    },
];

impl Effect {
    /// The effect's name ([`PhysicalEffect::name`]).
    pub const fn name(&self) -> &'static str {
        self.kind.name()
    }
}

/// Looks an effect up by its exact name.
pub fn effect(name: &str) -> Option<&'static Effect> {
    LIBRARY.iter().find(|e| e.name() == name)
}

/// A point's shape for the link_stretch basis: (cos 2ψ, sin 2ψ), (cos e1, sin e1),
/// (cos e2, sin e2), (|∂C/∂b|², |∂C/∂c|²).
type Shape = ([f64; 2], [f64; 2], [f64; 2], [f64; 2]);

/// Everything per point the forward model needs besides the parameters.
#[derive(Clone, Debug)]
pub struct Point {
    /// Index of the measurement this point came from (in the slice given to [`Problem::new`]).
    pub index: usize,
    pub theta_rad: [f64; 2],
    pub dir: [f64; 2],
    pub measured_mm: [f64; 2],
    /// The link_stretch basis [b·cos2ψ, c·cos2ψ, b·sin2ψ, c·sin2ψ] (unit RMS over the data).
    pub stretch_u: [f64; 4],
    /// θ_j minus its circular mean over the data, wrapped to (−π, π] (the gear_ratio basis), rad.
    pub theta_centred_rad: [f64; 2],
}

/// The data prepared once for all fits: points plus the base model.
#[derive(Clone, Debug)]
pub struct Problem {
    pub base: FiveBar<f64>,
    pub points: Vec<Point>,
    /// Every point has dir1/dir2.
    pub has_dir: bool,
    /// Points where the base model has no forward solution or is within [`MIN_TRANSMISSION`] of
    /// a singularity (dropped, by file line).
    pub dropped_lines: Vec<usize>,
    /// The link_stretch basis is indistinguishable from link lengths and offsets on these poses.
    pub stretch_degenerate: bool,
}

impl Problem {
    /// Prepares the points. Points the base model cannot reach are dropped (listed by line).
    pub fn new(base: FiveBar<f64>, data: &[Measurement]) -> Problem {
        let has_dir = !data.is_empty() && data.iter().all(|m| m.dir.is_some());
        let mut points = Vec::with_capacity(data.len());
        // Per point: (cos 2ψ, sin 2ψ), (cos e1, sin e1), (cos e2, sin e2), (|∂C/∂b|², |∂C/∂c|²).
        let mut geo: Vec<Shape> = Vec::with_capacity(data.len());
        let mut dropped_lines = Vec::new();
        let unit = |v: [f64; 2]| {
            let n = v[0].hypot(v[1]);
            [v[0] / n, v[1] / n]
        };
        for (index, m) in data.iter().enumerate() {
            let th = m.theta_rad();
            // A point at (or within ~0.06° of) a singularity has unbounded sensitivities: dropped.
            let Ok(pose) = base.forward_pose(th, MIN_TRANSMISSION) else {
                dropped_lines.push(m.line);
                continue;
            };
            let p1 = unit(pose.elbow_a_mm);
            let p2 = unit([pose.elbow_b_mm[0] - pose.base_b0_mm[0], pose.elbow_b_mm[1] - pose.base_b0_mm[1]]);
            let q1 = unit([pose.tool_mm[0] - pose.elbow_a_mm[0], pose.tool_mm[1] - pose.elbow_a_mm[1]]);
            let q2 = unit([pose.tool_mm[0] - pose.elbow_b_mm[0], pose.tool_mm[1] - pose.elbow_b_mm[1]]);
            // g = cos 2ψ, sin 2ψ (see the module doc for why not cos ψ).
            let (cp, sp) = (q1[0] * q2[0] + q1[1] * q2[1], q1[0] * q2[1] - q1[1] * q2[0]);
            let g = [cp * cp - sp * sp, 2.0 * sp * cp];
            let e1 = [p1[0] * q1[0] + p1[1] * q1[1], p1[0] * q1[1] - p1[1] * q1[0]];
            let e2 = [p2[0] * q2[0] + p2[1] * q2[1], p2[0] * q2[1] - p2[1] * q2[0]];
            let sens = |f: &dyn Fn(&mut FiveBar<f64>)| -> f64 {
                let mut mm = base;
                f(&mut mm);
                match mm.forward(th, 0.0) {
                    Ok(c) => ((c[0] - pose.tool_mm[0]).powi(2) + (c[1] - pose.tool_mm[1]).powi(2)) / 1e-6,
                    Err(_) => 1.0,
                }
            };
            let w = [sens(&|m| m.b_mm += 1e-3), sens(&|m| m.c_mm += 1e-3)];
            geo.push((g, e1, e2, w));
            let d = m.dir.map(|d| [d[0] as f64, d[1] as f64]).unwrap_or([0.0; 2]);
            points.push(Point {
                index,
                theta_rad: th,
                dir: d,
                measured_mm: m.measured_mm,
                stretch_u: [0.0; 4],
                theta_centred_rad: [0.0; 2],
            });
        }
        let n = points.len().max(1) as f64;
        // Circular mean: the gear_ratio basis is θ about it, modulo 360° (Table I prints some
        // angles as θ + 360°; a plain mean would turn that bookkeeping into a huge "ratio error").
        let mean_t = [0, 1].map(|j| {
            let (s, c) = points.iter().fold((0.0, 0.0), |(s, c), p| (s + p.theta_rad[j].sin(), c + p.theta_rad[j].cos()));
            s.atan2(c)
        });
        // link_stretch basis: g minus its weighted least-squares projection on
        // {1, cos e_j, sin e_j} (what constant link lengths and encoder offsets of that arm do).
        // Order: [b·cos2ψ, c·cos2ψ, b·sin2ψ, c·sin2ψ] (as the parameters 10, 11, 18, 19).
        let mut u =
            [vec![0.0; points.len()], vec![0.0; points.len()], vec![0.0; points.len()], vec![0.0; points.len()]];
        let mut stretch_degenerate = points.len() < 6;
        // The slot indexes both the basis `u` and (through arm and harmonic) the shapes.
        #[allow(clippy::needless_range_loop)]
        for slot in 0..4 {
            let (arm, harmonic) = (slot % 2, slot / 2);
            let cols = |i: usize| -> [f64; 3] {
                let e = if arm == 0 { geo[i].1 } else { geo[i].2 };
                [1.0, e[0], e[1]]
            };
            let mut ata = nalgebra::Matrix3::<f64>::zeros();
            let mut atb = nalgebra::Vector3::<f64>::zeros();
            for i in 0..points.len() {
                let c = nalgebra::Vector3::from(cols(i));
                let wi = geo[i].3[arm];
                ata += c * c.transpose() * wi;
                atb += c * geo[i].0[harmonic] * wi;
            }
            let coef = ata.try_inverse().map(|inv| inv * atb).unwrap_or_else(nalgebra::Vector3::zeros);
            for i in 0..points.len() {
                let c = cols(i);
                u[slot][i] = geo[i].0[harmonic] - (coef[0] * c[0] + coef[1] * c[1] + coef[2] * c[2]);
            }
            // Normalise to unit RMS so the k's are RMS stretches (µm) over the data. A basis
            // that is all rounding (nothing left after the projection) switches the effect off.
            let rms = (u[slot].iter().map(|v| v * v).sum::<f64>() / n).sqrt();
            if rms <= 1e-7 {
                stretch_degenerate = true;
            } else {
                for v in u[slot].iter_mut() {
                    *v /= rms;
                }
            }
        }
        if stretch_degenerate {
            for slot in u.iter_mut() {
                slot.iter_mut().for_each(|v| *v = 0.0);
            }
        }
        for (i, p) in points.iter_mut().enumerate() {
            p.stretch_u = [u[0][i], u[1][i], u[2][i], u[3][i]];
            p.theta_centred_rad = [0, 1].map(|j| wrap_angle_rad(p.theta_rad[j] - mean_t[j]));
        }
        Problem { base, points, has_dir, dropped_lines, stretch_degenerate }
    }

    /// Predicted instrument reading of point `p` with full parameter vector `x`.
    pub fn predict(&self, p: &Point, x: &[f64; N_PARAMS]) -> Option<[f64; 2]> {
        let um = 1e-3;
        let urad = 1e-6;
        let mut m = self.base;
        m.a_mm += x[0] * um;
        m.b_mm += (x[1] + x[10] * p.stretch_u[0] + x[18] * p.stretch_u[2]) * um;
        m.c_mm += (x[2] + x[11] * p.stretch_u[1] + x[19] * p.stretch_u[3]) * um;
        m.d_mm += x[3] * um;
        m.base_b0_mm[0] += x[6] * um;
        m.base_b0_mm[1] += x[7] * um;
        let th = [0, 1].map(|j| {
            p.theta_rad[j] + x[4 + j] * urad - p.dir[j] * x[8 + j] * urad * 0.5
                + x[16 + j] * 1e-6 * p.theta_centred_rad[j]
        });
        let c = m.forward(th, 0.0).ok()?;
        let (s, co) = (x[14] * urad).sin_cos();
        let k = 1.0 + x[15] * 1e-6;
        Some([k * (co * c[0] - s * c[1]) + x[12] * um, k * (s * c[0] + co * c[1]) + x[13] * um])
    }

    /// Residuals (measured − predicted, µm), x then y per point; `None` if a point has no FK.
    pub fn residuals_um(&self, x: &[f64; N_PARAMS]) -> Option<Vec<f64>> {
        let mut r = Vec::with_capacity(2 * self.points.len());
        for p in &self.points {
            let c = self.predict(p, x)?;
            r.push((p.measured_mm[0] - c[0]) * 1e3);
            r.push((p.measured_mm[1] - c[1]) * 1e3);
        }
        Some(r)
    }

    /// Whether an effect can be fitted on these data (and why not).
    pub fn available(&self, e: &Effect) -> Result<(), String> {
        if e.needs_dir && !self.has_dir {
            return Err(format!("{} skipped: the data have no dir1/dir2 columns", e.name()));
        }
        if e.kind == PhysicalEffect::LinkStretch && self.stretch_degenerate {
            return Err(
                "link_stretch skipped: on these poses its basis is exactly what link_lengths and encoder_offset do"
                    .into(),
            );
        }
        Ok(())
    }
}

/// Indices of the free parameters of a set of effects, in effect order.
pub fn free_params(effects: &[&Effect]) -> Vec<usize> {
    effects.iter().flat_map(|e| e.params.iter().copied()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::fit::jacobian;

    fn meas(theta_deg: [f64; 2], dir: [i8; 2], m: &FiveBar<f64>) -> Measurement {
        let c = m.forward([theta_deg[0].to_radians(), theta_deg[1].to_radians()], 0.0).unwrap();
        Measurement { theta_deg, measured_mm: c, target_mm: None, dir: Some(dir), run: None, t_s: None, line: 0 }
    }

    fn grid(m: &FiveBar<f64>) -> Vec<Measurement> {
        let spec = crate::machine_spec::MachineSpec::paper();
        let (nominal, ws) = (spec.nominal, spec.workspace);
        let mut out = Vec::new();
        for i in 0..=10 {
            for j in 0..=10 {
                let t = [ws.x_mm[0] + 10.0 * i as f64, ws.y_mm[0] + 15.0 * j as f64];
                let th = nominal.inverse(t, spec.min_transmission).unwrap();
                out.push(meas(
                    [th[0].to_degrees(), th[1].to_degrees()],
                    [if i % 2 == 0 { 1 } else { -1 }, if j % 2 == 0 { 1 } else { -1 }],
                    m,
                ));
            }
        }
        out
    }

    #[test]
    fn zero_parameters_reproduce_the_base_model() {
        let p = Problem::new(FiveBar::paper_nominal(), &grid(&FiveBar::paper_nominal()));
        let r = p.residuals_um(&[0.0; N_PARAMS]).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-9), "{:?}", &r[..4]);
    }

    #[test]
    fn library_offsets_and_lengths_match_the_five_bar_model() {
        let mut truth = FiveBar::<f64>::paper_nominal();
        truth.a_mm += 0.05;
        truth.encoder_offset_rad = [2e-4, -1e-4];
        truth.base_b0_mm = [0.03, -0.02];
        let p = Problem::new(FiveBar::paper_nominal(), &grid(&truth));
        let mut x = [0.0; N_PARAMS];
        x[0] = 50.0;
        x[4] = 200.0;
        x[5] = -100.0;
        x[6] = 30.0;
        x[7] = -20.0;
        let r = p.residuals_um(&x).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-6), "{:?}", &r[..4]);
    }

    #[test]
    fn backlash_sign_lags_the_approach_direction() {
        // dir = +1: the link sits β/2 short of the encoder angle.
        let base = FiveBar::<f64>::paper_nominal();
        let mut shifted = base;
        shifted.encoder_offset_rad = [-50e-6, 0.0];
        let mut data = vec![meas([45.0, -45.0], [1, 1], &shifted)];
        data[0].dir = Some([1, 1]);
        let p = Problem::new(base, &data);
        let mut x = [0.0; N_PARAMS];
        x[8] = 100.0; // β1 = 100 µrad
        let r = p.residuals_um(&x).unwrap();
        assert!(r.iter().all(|v| v.abs() < 1e-6), "{r:?}");
    }

    #[test]
    fn stretch_basis_is_outside_what_lengths_and_offsets_do() {
        let p = Problem::new(FiveBar::paper_nominal(), &grid(&FiveBar::paper_nominal()));
        assert!(!p.stretch_degenerate);
        let x = [0.0; N_PARAMS];
        let rigid = jacobian(&p, &x, &[0, 1, 2, 3, 4, 5]).unwrap();
        let stretch = jacobian(&p, &x, &[10, 11, 18, 19]).unwrap();
        let cos = crate::diagnose::confounding::max_cos(&rigid, &stretch);
        assert!(cos < 0.99, "stretch basis overlaps lengths+offsets: cos {cos}");
        // Unit RMS basis.
        let n = p.points.len() as f64;
        let rms = (p.points.iter().map(|q| q.stretch_u[0].powi(2)).sum::<f64>() / n).sqrt();
        assert!((rms - 1.0).abs() < 1e-9);
    }
}
