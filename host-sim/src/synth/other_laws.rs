//! Effects that follow other laws than the diagnosis library's: what a real machine does where
//! the library's shape of an effect is only an approximation. The diagnosis must name the effect
//! (its library shape takes what it can) and report what is left as a shape misfit of that
//! effect, not as other effects.
//!
//! Each law is a formula of the pose (link angles, elbows, tool point of the true rigid five-bar),
//! written from the physics of a cause, never from the library's bases (`diagnose::library`,
//! `crate::loop_closure`):
//! * [`StretchLaw::Opening`]: the distal bars' tension follows the angle between the two levers
//!   (a preloaded spring between the elbows): `t ∝ cos(2·(θ1 − θ2) + φ)`;
//! * [`StretchLaw::ExternalForce`]: a constant force on the platform (a hose's or cable's drag
//!   in a fixed direction ψ): the two distal bars carry it, their tensions from the statics of the
//!   pose, `t_b·u_b + t_c·u_c = F` (u: the bars' unit vectors toward the tool point);
//! * [`StretchLaw::Thermal`]: both bars lengthen with a temperature that varies linearly across
//!   the workspace along ψ (a heat source at one side): `δ ∝ (C − C̄)·(cos ψ, sin ψ)`;
//! * [`StretchLaw::StiffeningSelfStress`]: the loops' self-stress (the plant's nonlinear six-bar
//!   with random part errors, as `Stretch`), through a nonlinear compliance, `δ ∝ t + t²/t_rms`;
//! * [`StretchLaw::SaturatingSelfStress`]: the same self-stress through a compliance that
//!   saturates, `t_max·tanh(t/t_max)` (a joint that slips beyond a friction force);
//! * [`StretchLaw::VaryingCompliance`]: the same self-stress through a compliance that changes
//!   across the workspace with the lever's angle (a preload that varies with it);
//! * [`StretchLaw::LargeErrors`], [`StretchLaw::SoftBearings`]: the self-stress of part errors
//!   of tenths of a millimetre (far beyond the linear range), or of a six-bar with 10× softer
//!   elbow bearings and 4× stiffer followers than drawn;
//! * [`StretchLaw::OtherDesign`]: the loops' self-stress of a six-bar built otherwise than the
//!   drawing the diagnosis assumes (a wider platform, other parallelogram offsets, stiffer
//!   followers, softer elbow bearings), with random part errors: the plant's nonlinear
//!   equilibrium, compliance linear.
//!
//! [`StretchLaw::kind`] says which of them the diagnosis' generalised stretch covers (a
//! self-stress of the six-bar as drawn, by any law of the configuration) and which are beyond it
//! (loads from outside the loops, a temperature field, another design).
//!
//! Magnitudes: the RMS elongation of the two bars over the poses is `rms_um`; c's is scaled by
//! `c_ratio` (bars alike: near 1).
//!
//! Cost: one forward pose per measurement (plus, for the self-stress, the plant's equilibrium).

use crate::io::measurement_csv::Measurement;
use crate::plant::{PlantConfig, SixBar};
use kinematics_core::FiveBar;

/// How the distal bars' elongation depends on the configuration (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StretchLaw {
    /// Tension follows the angle between the levers: `cos(2·(θ1 − θ2) + phase_rad)`.
    Opening { phase_rad: f64 },
    /// A constant force on the platform in direction `angle_rad` (machine frame), carried by the
    /// two distal bars as the pose's statics say.
    ExternalForce { angle_rad: f64 },
    /// A temperature linear across the workspace along `angle_rad`: both bars lengthen alike.
    Thermal { angle_rad: f64 },
    /// The loops' self-stress of a six-bar with random part errors (seed, σ mm), through a
    /// stiffening compliance `t + t²/t_rms`.
    StiffeningSelfStress { seed: u64, part_error_mm: f64 },
    /// The loops' self-stress of a six-bar of other proportions and stiffnesses (module doc)
    /// with random part errors (seed, σ mm).
    OtherDesign { seed: u64, part_error_mm: f64 },
    /// The loops' self-stress of the six-bar as drawn but with other stiffnesses (elbow
    /// bearings 10× softer, followers 4× stiffer), random part errors (seed, σ mm).
    SoftBearings { seed: u64, part_error_mm: f64 },
    /// The loops' self-stress of part errors far beyond the linear range (seed, σ mm: tenths of
    /// a millimetre), the plant's nonlinear equilibrium.
    LargeErrors { seed: u64, part_error_mm: f64 },
    /// The loops' self-stress (random part errors, seed, σ mm) through a compliance that
    /// saturates, `t_max·tanh(t/t_max)` with `t_max` 0.7 of the tension's RMS (a joint that slips
    /// beyond a friction force).
    SaturatingSelfStress { seed: u64, part_error_mm: f64 },
    /// The loops' self-stress (random part errors, seed, σ mm) through a compliance that changes
    /// across the workspace, `(1 + gradient·(θ1 − θ̄1)/spread)·t` (a preload that varies with the
    /// lever's angle).
    VaryingCompliance {
        seed: u64,
        part_error_mm: f64,
        gradient: f64,
    },
}

/// Which laws the diagnosis' generalised stretch covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum LawKind {
    /// The loops' self-stress of the six-bar as drawn, by another law of the configuration
    /// than the linearised loop closure's (what `diagnose::shape` generalises).
    SelfStress,
    /// A load from outside the loops, a temperature field, or a six-bar built otherwise than
    /// its drawing: beyond the generalised shape (a known limit of the diagnosis).
    Beyond,
}

impl StretchLaw {
    /// Every law, with the parameters the sweep draws from `k` (0, 1, 2, ...).
    pub fn all(k: u64) -> [StretchLaw; 9] {
        let f = k as f64;
        [
            StretchLaw::Opening {
                phase_rad: 0.7 + 1.3 * f,
            },
            StretchLaw::ExternalForce {
                angle_rad: -1.2 + 0.9 * f,
            },
            StretchLaw::Thermal {
                angle_rad: 0.4 + 1.7 * f,
            },
            StretchLaw::StiffeningSelfStress {
                seed: 31 + k,
                part_error_mm: 0.05,
            },
            StretchLaw::OtherDesign {
                seed: 57 + k,
                part_error_mm: 0.05,
            },
            StretchLaw::SoftBearings {
                seed: 83 + k,
                part_error_mm: 0.05,
            },
            StretchLaw::LargeErrors {
                seed: 101 + k,
                part_error_mm: 0.4,
            },
            StretchLaw::SaturatingSelfStress {
                seed: 131 + k,
                part_error_mm: 0.05,
            },
            StretchLaw::VaryingCompliance {
                seed: 151 + k,
                part_error_mm: 0.05,
                gradient: if k % 2 == 0 { 0.4 } else { -0.6 },
            },
        ]
    }

    /// A short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            StretchLaw::Opening { .. } => "opening",
            StretchLaw::ExternalForce { .. } => "external_force",
            StretchLaw::Thermal { .. } => "thermal",
            StretchLaw::StiffeningSelfStress { .. } => "stiffening",
            StretchLaw::OtherDesign { .. } => "other_design",
            StretchLaw::SoftBearings { .. } => "soft_bearings",
            StretchLaw::LargeErrors { .. } => "large_errors",
            StretchLaw::SaturatingSelfStress { .. } => "saturating",
            StretchLaw::VaryingCompliance { .. } => "varying_compliance",
        }
    }

    /// Whether the diagnosis' generalised stretch covers this law.
    pub fn kind(&self) -> LawKind {
        match self {
            StretchLaw::Opening { .. }
            | StretchLaw::ExternalForce { .. }
            | StretchLaw::Thermal { .. }
            | StretchLaw::OtherDesign { .. } => LawKind::Beyond,
            _ => LawKind::SelfStress,
        }
    }
}

/// A distal stretch of another law: RMS elongation `rms_um` over the poses and both bars, c's
/// scaled by `c_ratio`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OtherStretch {
    pub law: StretchLaw,
    pub rms_um: f64,
    pub c_ratio: f64,
}

/// The elongation (µm) of b and c at each row, `link_rad(row)` giving the true link angles and
/// `rigid` the true rigid five-bar.
pub fn elongation_um(
    s: &OtherStretch,
    rigid: &FiveBar<f64>,
    rows: &[Measurement],
    link_rad: &dyn Fn(&Measurement) -> [f64; 2],
) -> Result<Vec<[f64; 2]>, String> {
    let mut raw = Vec::with_capacity(rows.len());
    let mut tools = Vec::with_capacity(rows.len());
    let mut six = match s.law {
        StretchLaw::OtherDesign {
            seed,
            part_error_mm,
        } => {
            let mut p = PlantConfig::ideal();
            let c = &mut p.sixbar;
            c.platform_half_width_mm *= 1.8;
            let turn = |v: [f64; 2], a: f64| {
                let (sn, cs) = a.sin_cos();
                [1.5 * (cs * v[0] - sn * v[1]), 1.5 * (sn * v[0] + cs * v[1])]
            };
            c.parallelogram_1_offset_mm = turn(c.parallelogram_1_offset_mm, 1.0);
            c.parallelogram_2_offset_mm = turn(c.parallelogram_2_offset_mm, -0.7);
            c.follower_bar_section_mm2 *= 4.0;
            c.pin_stiffness_n_per_mm *= 0.2;
            Some(SixBar::new(
                &p.with_random_errors(seed, part_error_mm, 0.0).sixbar,
            ))
        }
        StretchLaw::SoftBearings {
            seed,
            part_error_mm,
        } => {
            let mut p = PlantConfig::ideal();
            p.sixbar.follower_bar_section_mm2 *= 4.0;
            p.sixbar.pin_stiffness_n_per_mm *= 0.1;
            Some(SixBar::new(
                &p.with_random_errors(seed, part_error_mm, 0.0).sixbar,
            ))
        }
        StretchLaw::StiffeningSelfStress {
            seed,
            part_error_mm,
        }
        | StretchLaw::LargeErrors {
            seed,
            part_error_mm,
        }
        | StretchLaw::SaturatingSelfStress {
            seed,
            part_error_mm,
        }
        | StretchLaw::VaryingCompliance {
            seed,
            part_error_mm,
            ..
        } => Some(SixBar::new(
            &PlantConfig::ideal()
                .with_random_errors(seed, part_error_mm, 0.0)
                .sixbar,
        )),
        _ => None,
    };
    for r in rows {
        let th = link_rad(r);
        let pose = rigid.forward_pose(th, 0.0).map_err(|e| e.to_string())?;
        let c = pose.tool_mm;
        let unit = |from: [f64; 2]| {
            let v = [c[0] - from[0], c[1] - from[1]];
            let n = v[0].hypot(v[1]);
            [v[0] / n, v[1] / n]
        };
        let (ub, uc) = (unit(pose.elbow_a_mm), unit(pose.elbow_b_mm));
        tools.push(c);
        raw.push(match s.law {
            StretchLaw::Opening { phase_rad } => {
                let t = (2.0 * (th[0] - th[1]) + phase_rad).cos();
                [t, t]
            }
            StretchLaw::ExternalForce { angle_rad } => {
                // t_b·u_b + t_c·u_c = F (Cramer's rule; the workspace keeps the bars apart).
                let f = [angle_rad.cos(), angle_rad.sin()];
                let det = ub[0] * uc[1] - ub[1] * uc[0];
                [
                    (f[0] * uc[1] - f[1] * uc[0]) / det,
                    (ub[0] * f[1] - ub[1] * f[0]) / det,
                ]
            }
            StretchLaw::Thermal { .. } => [0.0; 2],
            StretchLaw::StiffeningSelfStress { .. }
            | StretchLaw::OtherDesign { .. }
            | StretchLaw::SoftBearings { .. }
            | StretchLaw::LargeErrors { .. }
            | StretchLaw::SaturatingSelfStress { .. }
            | StretchLaw::VaryingCompliance { .. } => {
                let sol = six
                    .as_mut()
                    .expect("built above")
                    .solve(th)
                    .map_err(|e| e.to_string())?;
                [sol.bar_tension_n[1], sol.bar_tension_n[4]]
            }
        });
    }
    match s.law {
        StretchLaw::Thermal { angle_rad } => {
            let n = tools.len().max(1) as f64;
            let mean = tools
                .iter()
                .fold([0.0; 2], |m, c| [m[0] + c[0] / n, m[1] + c[1] / n]);
            let dir = [angle_rad.cos(), angle_rad.sin()];
            for (r, c) in raw.iter_mut().zip(&tools) {
                let t = (c[0] - mean[0]) * dir[0] + (c[1] - mean[1]) * dir[1];
                *r = [t, t];
            }
        }
        StretchLaw::StiffeningSelfStress { .. } => {
            let rms = rms(&raw);
            if rms > 0.0 {
                for r in raw.iter_mut() {
                    *r = r.map(|t| t + t * t / rms);
                }
            }
        }
        StretchLaw::SaturatingSelfStress { .. } => {
            let t_max = 0.7 * rms(&raw);
            if t_max > 0.0 {
                for r in raw.iter_mut() {
                    *r = r.map(|t| t_max * (t / t_max).tanh());
                }
            }
        }
        StretchLaw::VaryingCompliance { gradient, .. } => {
            // The lever's angle about its mean over the rows, in units of its spread.
            let th: Vec<f64> = rows.iter().map(|r| link_rad(r)[0]).collect();
            let n = th.len().max(1) as f64;
            let mean = th.iter().sum::<f64>() / n;
            let spread = (th.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / n)
                .sqrt()
                .max(1e-9);
            for (r, t) in raw.iter_mut().zip(&th) {
                let k = 1.0 + gradient * (t - mean) / spread;
                *r = r.map(|v| k * v);
            }
        }
        _ => {}
    }
    let rms = rms(&raw);
    if rms == 0.0 {
        return Ok(vec![[0.0; 2]; rows.len()]);
    }
    let k = s.rms_um / rms;
    Ok(raw
        .iter()
        .map(|r| [k * r[0], k * s.c_ratio * r[1]])
        .collect())
}

/// RMS over the rows and both bars.
fn rms(v: &[[f64; 2]]) -> f64 {
    (v.iter().map(|r| r[0] * r[0] + r[1] * r[1]).sum::<f64>() / (2 * v.len().max(1)) as f64).sqrt()
}
