//! The six-bar's rigid-body dynamics: every bar, the elbow pieces and the platform with the
//! tool, body by body, as the motors feel them.
//!
//! # Bodies (per arm; arm 2 mirrors arm 1, see `sixbar` for the names)
//! | body | motion | mass from | inertia |
//! |---|---|---|---|
//! | lever P (A0→A) | turns with the link angle about A0 | density × main section × length | uniform rod, `m·L²/3` about A0 |
//! | follower F (A0*→A*) | turns with the link angle about A0* (parallelogram) | density × follower section × length | `m·L²/3` about A0* |
//! | elbow piece K | translates with the elbow A (parallelogram keeps its orientation) | `elbow_piece_mass_kg` | none (no rotation) |
//! | distal bar Q (A→D) | ends move like A and the tool point C; turns with the distal angle φ | density × main section × length | `m·L²/12` about its middle |
//! | follower G (A**→D**) | parallel to Q, ends move like A and C | density × follower section × length | `m·L²/12` |
//! | platform T + tool | translates with C | `platform_mass_kg + tool_mass_kg` | none |
//!
//! The kinematics are the equivalent five-bar's (the arms' effective geometry, `SixBar`): the
//! manufacturing errors move pins by tens of micrometres, which changes the inertias by parts
//! in 10⁵; the elastic deformations are far smaller still. Gravity acts out of the plane.
//!
//! # Torques (projected Newton–Euler)
//! For joint angles, velocities and accelerations, each body's centre-of-mass acceleration and
//! angular acceleration follow from the elbow's (`Ä = θ̈·p⊥ - θ̇²·p`) and the tool point's
//! (`kinematics_core::joint_motion::motion_from_pose`); its inertial force and moment are mapped
//! to the motors through the body's own Jacobian (`J_A`, `J_C`, `J_φ`):
//! `τ = Σ J_comᵀ·m·a_com + J_φᵀ·I·α`. The inertia matrix and the velocity-product torques
//! (centripetal, Coriolis) are three such evaluations: `M` column k at `θ̈ = e_k`, `θ̇ = 0`, and
//! `h` at `θ̈ = 0`. The tests check the torques against a Lagrangian of the same bodies computed
//! from positions alone (finite differences), the energy balance of a free swing, and that the
//! hidden robot's five lumped parameters ([`Linkage::lumped`], `kinematics_core::dynamics`)
//! reproduce them.
//!
//! Cost: about 150 flops per torque evaluation; [`Linkage::inertia_and_coriolis`] is five at
//! one pose (one FK), which the plant evaluates once per 2 kHz sample (`motion`).

use kinematics_core::dynamics::FiveBarDynamics;
use kinematics_core::jacobian::Mat2;
use kinematics_core::joint_motion::motion_from_pose;
use kinematics_core::{FiveBar, KinematicsError, Pose};

pub use super::config::LinkageConfig;

/// A uniform bar: mass (kg) and length (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bar {
    pub mass_kg: f64,
    pub length_m: f64,
}

impl Bar {
    fn new(density_kg_per_m3: f64, section_mm2: f64, length_mm: f64) -> Self {
        let length_m = length_mm * 1e-3;
        Bar {
            mass_kg: density_kg_per_m3 * section_mm2 * 1e-6 * length_m,
            length_m,
        }
    }

    /// About an end.
    fn end_inertia_kg_m2(&self) -> f64 {
        self.mass_kg * self.length_m * self.length_m / 3.0
    }

    /// About its middle.
    fn centre_inertia_kg_m2(&self) -> f64 {
        self.mass_kg * self.length_m * self.length_m / 12.0
    }
}

/// The bodies of one arm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arm {
    pub lever: Bar,
    pub follower_f: Bar,
    pub distal_q: Bar,
    pub follower_g: Bar,
    pub elbow_piece_kg: f64,
}

/// The inertia matrix and velocity-product coefficients at one configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InertiaAt {
    /// `M` (kg·m²), symmetric.
    pub mass_kg_m2: Mat2<f64>,
    /// Per motor `i`: `[c_i11, c_i22, c_i12]` with `h_i = c_i11·θ̇1² + c_i22·θ̇2² + 2·c_i12·θ̇1·θ̇2`.
    pub quadratic: [[f64; 3]; 2],
}

impl InertiaAt {
    /// The velocity-product torques `h(θ̇)` (N·m).
    pub fn bias_nm(&self, w: [f64; 2]) -> [f64; 2] {
        let q = &self.quadratic;
        [0, 1].map(|i| q[i][0] * w[0] * w[0] + q[i][1] * w[1] * w[1] + 2.0 * q[i][2] * w[0] * w[1])
    }
}

/// The six-bar's bodies on the equivalent five-bar's kinematics.
#[derive(Clone, Debug)]
pub struct Linkage {
    /// The equivalent five-bar (link angles in, machine frame shifted by its base).
    five: FiveBar<f64>,
    pub arms: [Arm; 2],
    /// Platform and tool (kg).
    pub platform_kg: f64,
}

fn dot(u: [f64; 2], v: [f64; 2]) -> f64 {
    u[0] * v[0] + u[1] * v[1]
}
fn cross(u: [f64; 2], v: [f64; 2]) -> f64 {
    u[0] * v[1] - u[1] * v[0]
}
fn perp(u: [f64; 2]) -> [f64; 2] {
    [-u[1], u[0]]
}

impl Linkage {
    /// The bodies of a six-bar whose arms have the equivalent five-bar `five` (link angles as
    /// its encoder angles), nominal link length `link_mm` with the bar length errors of
    /// `errors`, the bar sections of `[sixbar]`.
    pub fn new(
        cfg: &LinkageConfig,
        five: FiveBar<f64>,
        sixbar: &super::config::SixBarConfig,
    ) -> Self {
        let (rho, e, l) = (cfg.bar_density_kg_per_m3, &sixbar.errors, sixbar.link_mm);
        let (main, follower) = (sixbar.main_bar_section_mm2, sixbar.follower_bar_section_mm2);
        let arm = |i: usize| Arm {
            lever: Bar::new(rho, main, l + e.lever_length_mm[i]),
            follower_f: Bar::new(rho, follower, l + e.bar_f_length_mm[i]),
            distal_q: Bar::new(rho, main, l + e.bar_q_length_mm[i]),
            follower_g: Bar::new(rho, follower, l + e.bar_g_length_mm[i]),
            elbow_piece_kg: cfg.elbow_piece_mass_kg,
        };
        Linkage {
            five,
            arms: [arm(0), arm(1)],
            platform_kg: cfg.platform_mass_kg + cfg.tool_mass_kg,
        }
    }

    /// Motor torques (N·m) the linkage needs for link angles `angle_rad`, velocities and
    /// accelerations: body by body (module doc).
    pub fn torque_nm(
        &self,
        angle_rad: [f64; 2],
        velocity_rad_s: [f64; 2],
        acceleration_rad_s2: [f64; 2],
    ) -> Result<[f64; 2], KinematicsError> {
        let pose = self.five.forward_pose(angle_rad, 0.0)?;
        let jc = pose.jacobian()?;
        self.torque_at(&pose, &jc, velocity_rad_s, acceleration_rad_s2)
    }

    /// [`Linkage::torque_nm`] at a solved pose with its Jacobian `jc` (mm/rad).
    fn torque_at(
        &self,
        pose: &Pose<f64>,
        jc: &Mat2<f64>,
        velocity_rad_s: [f64; 2],
        acceleration_rad_s2: [f64; 2],
    ) -> Result<[f64; 2], KinematicsError> {
        let m = motion_from_pose(pose, velocity_rad_s, acceleration_rad_s2)?;
        let mm = 1e-3;
        // Tool point (m/s²) and its Jacobian (m/rad), columns per motor.
        let a_c = [
            m.tool_acceleration_mm_s2[0] * mm,
            m.tool_acceleration_mm_s2[1] * mm,
        ];
        let jc_col = |k: usize| [jc[0][k] * mm, jc[1][k] * mm];
        let mut tau = [0.0; 2];
        // Platform and tool: a point mass at C.
        for (k, t) in tau.iter_mut().enumerate() {
            *t += self.platform_kg * dot(jc_col(k), a_c);
        }
        for i in 0..2 {
            let arm = &self.arms[i];
            let (w, al) = (velocity_rad_s[i], acceleration_rad_s2[i]);
            let p = [m.proximal_mm[i][0] * mm, m.proximal_mm[i][1] * mm];
            let q = [m.distal_mm[i][0] * mm, m.distal_mm[i][1] * mm];
            let pp = perp(p);
            let a_a = [al * pp[0] - w * w * p[0], al * pp[1] - w * w * p[1]];
            // The elbow's Jacobian: column i is p⊥, the other column zero.
            let ja_col = |k: usize| if k == i { pp } else { [0.0; 2] };
            // Lever and follower F: fixed-axis rotation with the link angle.
            tau[i] += (arm.lever.end_inertia_kg_m2() + arm.follower_f.end_inertia_kg_m2()) * al;
            // Elbow piece: a point mass moving with A.
            tau[i] += arm.elbow_piece_kg * dot(pp, a_a);
            // Distal bar and its follower: centre at the middle of A–C, turning with φ.
            let q2 = dot(q, q);
            let phi_dd = cross(q, [a_c[0] - a_a[0], a_c[1] - a_a[1]]) / q2;
            let a_mid = [(a_a[0] + a_c[0]) / 2.0, (a_a[1] + a_c[1]) / 2.0];
            for bar in [arm.distal_q, arm.follower_g] {
                for (k, t) in tau.iter_mut().enumerate() {
                    let (ja, jck) = (ja_col(k), jc_col(k));
                    let j_mid = [(ja[0] + jck[0]) / 2.0, (ja[1] + jck[1]) / 2.0];
                    let j_phi = cross(q, [jck[0] - ja[0], jck[1] - ja[1]]) / q2;
                    *t += bar.mass_kg * dot(j_mid, a_mid)
                        + bar.centre_inertia_kg_m2() * j_phi * phi_dd;
                }
            }
        }
        Ok(tau)
    }

    /// The inertia matrix (kg·m²) and velocity-product torques (N·m) at link angles and
    /// velocities: `τ = M·θ̈ + h`.
    pub fn mass_matrix_and_bias(
        &self,
        angle_rad: [f64; 2],
        velocity_rad_s: [f64; 2],
    ) -> Result<(Mat2<f64>, [f64; 2]), KinematicsError> {
        let d = self.inertia_and_coriolis(angle_rad)?;
        Ok((d.mass_kg_m2, d.bias_nm(velocity_rad_s)))
    }

    /// The inertia matrix and the velocity-product coefficients at link angles: five torque
    /// evaluations at one pose (the velocity products are a quadratic form in `θ̇`).
    pub fn inertia_and_coriolis(&self, angle_rad: [f64; 2]) -> Result<InertiaAt, KinematicsError> {
        let pose = self.five.forward_pose(angle_rad, 0.0)?;
        let jc = pose.jacobian()?;
        let t = |w: [f64; 2], al: [f64; 2]| self.torque_at(&pose, &jc, w, al);
        let (c0, c1) = (t([0.0; 2], [1.0, 0.0])?, t([0.0; 2], [0.0, 1.0])?);
        let (h1, h2, h12) = (
            t([1.0, 0.0], [0.0; 2])?,
            t([0.0, 1.0], [0.0; 2])?,
            t([1.0, 1.0], [0.0; 2])?,
        );
        let mut quadratic = [[0.0; 3]; 2];
        for i in 0..2 {
            quadratic[i] = [h1[i], h2[i], 0.5 * (h12[i] - h1[i] - h2[i])];
        }
        Ok(InertiaAt {
            mass_kg_m2: [[c0[0], c1[0]], [c0[1], c1[1]]],
            quadratic,
        })
    }

    /// Kinetic energy (J) at link angles and velocities: `½·θ̇ᵀ·M·θ̇`.
    pub fn kinetic_energy_j(
        &self,
        angle_rad: [f64; 2],
        velocity_rad_s: [f64; 2],
    ) -> Result<f64, KinematicsError> {
        let (m, _) = self.mass_matrix_and_bias(angle_rad, [0.0; 2])?;
        let w = velocity_rad_s;
        Ok(0.5
            * (w[0] * (m[0][0] * w[0] + m[0][1] * w[1]) + w[1] * (m[1][0] * w[0] + m[1][1] * w[1])))
    }

    /// The hidden robot's dynamic parameters that reproduce these bodies exactly
    /// (`kinematics_core::dynamics`), at the equivalent five-bar's link lengths, without the
    /// rotors and friction: every bar's mass split between its ends, the distal bars'
    /// remainder `I_centre - m·|q|²/4`.
    pub fn lumped(&self) -> FiveBarDynamics<f64> {
        let a = [self.five.a_mm * 1e-3, self.five.d_mm * 1e-3];
        let b = [self.five.b_mm * 1e-3, self.five.c_mm * 1e-3];
        let mut motor = [0.0; 2];
        let mut distal = [0.0; 2];
        let mut tool = self.platform_kg;
        for i in 0..2 {
            let arm = &self.arms[i];
            let rods = arm.distal_q.mass_kg + arm.follower_g.mass_kg;
            motor[i] = arm.lever.end_inertia_kg_m2()
                + arm.follower_f.end_inertia_kg_m2()
                + (arm.elbow_piece_kg + rods / 2.0) * a[i] * a[i];
            tool += rods / 2.0;
            distal[i] = arm.distal_q.centre_inertia_kg_m2() + arm.follower_g.centre_inertia_kg_m2()
                - rods * b[i] * b[i] / 4.0;
        }
        FiveBarDynamics {
            motor_inertia_kg_m2: motor,
            tool_mass_kg: tool,
            distal_inertia_kg_m2: distal,
            viscous_nm_s_per_rad: [0.0; 2],
            coulomb_nm: [0.0; 2],
            coulomb_speed_rad_s: 0.01,
        }
    }

    /// The equivalent five-bar the bodies move on.
    pub fn five_bar(&self) -> &FiveBar<f64> {
        &self.five
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::{Plant, PlantConfig};

    fn paper_linkage() -> Linkage {
        Plant::new(&PlantConfig::paper(), 1).linkage
    }

    /// Kinetic energy of every body from positions alone: the five-bar's FK at `θ ± ε·θ̇`,
    /// each body's centre and angle, central differences. Independent of `torque_nm`'s
    /// velocity and acceleration propagation.
    fn kinetic_energy_from_positions(l: &Linkage, th: [f64; 2], w: [f64; 2]) -> f64 {
        let e = 1e-6;
        let pose = |s: f64| {
            l.five
                .forward_pose([th[0] + s * w[0], th[1] + s * w[1]], 0.0)
                .unwrap()
        };
        let (a, b) = (pose(-e), pose(e));
        let speed2 = |pa: [f64; 2], pb: [f64; 2]| {
            let v = [
                (pb[0] - pa[0]) / (2.0 * e) * 1e-3,
                (pb[1] - pa[1]) / (2.0 * e) * 1e-3,
            ];
            v[0] * v[0] + v[1] * v[1]
        };
        let rate = |x: f64, y: f64| {
            let mut d = y - x;
            if d > std::f64::consts::PI {
                d -= std::f64::consts::TAU;
            } else if d < -std::f64::consts::PI {
                d += std::f64::consts::TAU;
            }
            d / (2.0 * e)
        };
        let mid = |p: [f64; 2], q: [f64; 2]| [(p[0] + q[0]) / 2.0, (p[1] + q[1]) / 2.0];
        let angle = |from: [f64; 2], to: [f64; 2]| (to[1] - from[1]).atan2(to[0] - from[0]);
        let mut t = 0.5 * l.platform_kg * speed2(a.tool_mm, b.tool_mm);
        for i in 0..2 {
            let arm = &l.arms[i];
            let (ea, eb) = if i == 0 {
                (a.elbow_a_mm, b.elbow_a_mm)
            } else {
                (a.elbow_b_mm, b.elbow_b_mm)
            };
            let (ba, bb) = if i == 0 {
                (a.base_a0_mm, b.base_a0_mm)
            } else {
                (a.base_b0_mm, b.base_b0_mm)
            };
            // Lever and follower: centre halfway out along the link angle, turning with it.
            for bar in [arm.lever, arm.follower_f] {
                let half = bar.length_m * 1e3 / 2.0;
                let c = |base: [f64; 2], elbow: [f64; 2]| {
                    let d = [elbow[0] - base[0], elbow[1] - base[1]];
                    let n = (d[0] * d[0] + d[1] * d[1]).sqrt();
                    [base[0] + half * d[0] / n, base[1] + half * d[1] / n]
                };
                let wr = rate(angle(ba, ea), angle(bb, eb));
                t += 0.5 * bar.mass_kg * speed2(c(ba, ea), c(bb, eb))
                    + 0.5 * bar.centre_inertia_kg_m2() * wr * wr;
            }
            t += 0.5 * arm.elbow_piece_kg * speed2(ea, eb);
            for bar in [arm.distal_q, arm.follower_g] {
                let wr = rate(angle(ea, a.tool_mm), angle(eb, b.tool_mm));
                t += 0.5 * bar.mass_kg * speed2(mid(ea, a.tool_mm), mid(eb, b.tool_mm))
                    + 0.5 * bar.centre_inertia_kg_m2() * wr * wr;
            }
        }
        t
    }

    /// A motion through the workspace at several g: angles, velocities, accelerations.
    fn motion(t: f64) -> ([f64; 2], [f64; 2], [f64; 2]) {
        let th = [
            0.79 + 0.25 * (9.0 * t).sin(),
            -0.78 + 0.2 * (13.0 * t).cos(),
        ];
        let w = [0.25 * 9.0 * (9.0 * t).cos(), -0.2 * 13.0 * (13.0 * t).sin()];
        let al = [
            -0.25 * 81.0 * (9.0 * t).sin(),
            -0.2 * 169.0 * (13.0 * t).cos(),
        ];
        (th, w, al)
    }

    #[test]
    fn torques_match_a_lagrangian_of_the_bodies() {
        let l = paper_linkage();
        let dtdw = |th: [f64; 2], w: [f64; 2]| {
            let h = 1e-3;
            let mut g = [0.0; 2];
            for i in 0..2 {
                let (mut lo, mut hi) = (w, w);
                lo[i] -= h;
                hi[i] += h;
                g[i] = (kinetic_energy_from_positions(&l, th, hi)
                    - kinetic_energy_from_positions(&l, th, lo))
                    / (2.0 * h);
            }
            g
        };
        let (mut worst, mut scale) = (0.0f64, 0.0f64);
        for k in 0..25 {
            let t = 0.03 * k as f64;
            let (th, w, al) = motion(t);
            let tau = l.torque_nm(th, w, al).unwrap();
            let h = 1e-4;
            let (ma, mb) = (motion(t - h), motion(t + h));
            let (pa, pb) = (dtdw(ma.0, ma.1), dtdw(mb.0, mb.1));
            for i in 0..2 {
                let e = 1e-5;
                let (mut lo, mut hi) = (th, th);
                lo[i] -= e;
                hi[i] += e;
                let dtdth = (kinetic_energy_from_positions(&l, hi, w)
                    - kinetic_energy_from_positions(&l, lo, w))
                    / (2.0 * e);
                let lagrange = (pb[i] - pa[i]) / (2.0 * h) - dtdth;
                worst = worst.max((lagrange - tau[i]).abs());
                scale = scale.max(tau[i].abs());
            }
        }
        eprintln!(
            "six-bar bodies: Lagrangian vs Newton-Euler, worst {worst:.2e} N·m of {scale:.3} N·m"
        );
        assert!(scale > 0.05, "the motion must load the linkage: {scale}");
        assert!(worst < 1e-4 * scale, "{worst} of {scale}");
    }

    /// The hidden robot's five lumped parameters reproduce the bodies (the model the servo
    /// identifies and feeds forward is exact for this machine, up to its geometry).
    #[test]
    fn the_lumped_five_bar_parameters_reproduce_the_bodies() {
        let l = paper_linkage();
        let d = l.lumped();
        for k in 0..40 {
            let (th, w, al) = motion(0.017 * k as f64);
            let tau = l.torque_nm(th, w, al).unwrap();
            let pose = l.five.forward_pose(th, 0.0).unwrap();
            let lumped = d
                .torque_nm(&motion_from_pose(&pose, w, al).unwrap())
                .unwrap();
            for i in 0..2 {
                assert!(
                    (tau[i] - lumped[i]).abs() < 1e-9 * (1.0 + tau[i].abs()),
                    "{tau:?} vs {lumped:?}"
                );
            }
        }
        // The nominal machine's numbers (documented in paper.toml and
        // firmware/src/board/qemu/machine.rs; the paper plant's bar errors move them by ~2 %).
        let d = Plant::new(&PlantConfig::ideal(), 1).linkage.lumped();
        assert!(
            (d.motor_inertia_kg_m2[0] - 1.89e-3).abs() < 0.01e-3,
            "{d:?}"
        );
        assert!((d.tool_mass_kg - 0.165).abs() < 0.002, "{d:?}");
        assert!(
            (d.distal_inertia_kg_m2[0] + 2.43e-4).abs() < 0.05e-4,
            "{d:?}"
        );
    }

    #[test]
    fn a_massless_linkage_needs_no_torque_and_the_inertia_matrix_is_symmetric() {
        let mut cfg = PlantConfig::paper();
        cfg.linkage = LinkageConfig::massless();
        let l = Plant::new(&cfg, 1).linkage;
        let (th, w, al) = motion(0.1);
        assert_eq!(l.torque_nm(th, w, al).unwrap(), [0.0; 2]);
        let l = paper_linkage();
        let (m, _) = l.mass_matrix_and_bias(th, w).unwrap();
        assert!(
            (m[0][1] - m[1][0]).abs() < 1e-15 && m[0][1].abs() > 1e-5,
            "{m:?}"
        );
        assert!(m[0][0] > 0.0 && m[0][0] * m[1][1] > m[0][1] * m[1][0]);
    }
}
