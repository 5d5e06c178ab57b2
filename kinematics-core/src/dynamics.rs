//! The hidden robot's inverse dynamics: the motor torques a joint motion needs, in closed form
//! and linear in nine identifiable parameters.
//!
//! # The model
//! The machine moves in a horizontal plane (no gravity in the plane). Its rigid bodies reduce,
//! exactly, to five inertial elements of the five-bar (`p = A - A0`, `q = C - A`, arm 2 alike):
//!
//! * `I1`, `I2`: inertia about each motor axis: rotor through the gear, lever, the
//!   parallelogram's follower bar (it turns with the lever), the elbow piece (it translates with
//!   the elbow: a point mass at `|p|`) and the elbow-end share of the distal bars;
//! * `m_C`: a point mass at the tool point: platform, tool (the platform translates with `C`)
//!   and the tool-end share of the distal bars;
//! * `J3`, `J4`: what is left of each distal body's rotational inertia once its mass is split
//!   between its two ends (`J = I_A - m·x_c·|q|`: negative for a uniform bar, `-m·L²/6`); the
//!   distal bar and its parallel follower turn together, so they share one `J`.
//!
//! This holds for bodies symmetric about their axis (no first moment across it); the six-bar's
//! plant in `host-sim` builds the same numbers from its bars and checks the equivalence.
//! Friction at each motor: viscous `fv·θ̇` and Coulomb `fc·s(θ̇)`, `s(ω) = ω/(|ω| + ω_c)` (the
//! smoothed sign of the PID's Coulomb feed-forward).
//!
//! # The torques
//! By virtual power, each element contributes its inertial force mapped through the Jacobian of
//! its own motion (`J = ∂C/∂θ`, `J_φ = ∂φ3/∂θ = (Jᵀ·q⊥ - (q·p)·e1)/|q|²`):
//!
//! ```text
//! τ = I·θ̈  +  m_C·Jᵀ·C̈  +  J3·φ̈3·J_φ3ᵀ + J4·φ̈4·J_φ4ᵀ  +  fv·θ̇ + fc·s(θ̇)
//! φ̈3 = q1 × (C̈ - Ä) / |q1|²,   Ä = θ̈1·p1⊥ - θ̇1²·p1
//! ```
//! The velocity-product (centripetal and Coriolis) terms are inside `C̈` given the joint motion,
//! and inside `Ä` and `φ̈`. With `Jᵀx = (k1·(x × q2), k2·(q1 × x)) / (q1 × q2)`, `k = p × q`, no
//! matrix is formed. Every term is a regressor column times a parameter
//! ([`regressor`]); [`FiveBarDynamics::torque_nm`] is that product (without its structural
//! zeros), so identification (`host_sim::calib::dynamics`) and feed-forward use one
//! computation. `tests` checks it against a Lagrangian computed by finite differences of the
//! FK.
//!
//! Cost: five divisions and about 80 flops from a [`JointMotion`]; `BENCH inverse_dynamics_f32`
//! in `cargo qemu-bench`.

use crate::joint_motion::JointMotion;
use crate::pose::cross;
use crate::real::Real;
use crate::{KinematicsError, Singularity};

/// Number of identified parameters.
pub const PARAMETERS: usize = 9;

/// Names of the parameters in [`FiveBarDynamics::to_array`] order (with units).
pub const PARAMETER_NAMES: [&str; PARAMETERS] = [
    "motor_1_inertia_kg_m2",
    "motor_2_inertia_kg_m2",
    "tool_mass_kg",
    "distal_1_inertia_kg_m2",
    "distal_2_inertia_kg_m2",
    "viscous_1_nm_s_per_rad",
    "viscous_2_nm_s_per_rad",
    "coulomb_1_nm",
    "coulomb_2_nm",
];

/// The identified dynamic parameters of the hidden robot (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FiveBarDynamics<T> {
    /// `I1`, `I2`: inertia about each motor axis, joint side (kg·m², > 0).
    pub motor_inertia_kg_m2: [T; 2],
    /// `m_C`: point mass at the tool (kg, ≥ 0).
    pub tool_mass_kg: T,
    /// `J3`, `J4`: rotational remainder of each distal body (kg·m², any sign).
    pub distal_inertia_kg_m2: [T; 2],
    /// Viscous friction per motor (N·m·s/rad, ≥ 0).
    pub viscous_nm_s_per_rad: [T; 2],
    /// Coulomb friction per motor (N·m, ≥ 0).
    pub coulomb_nm: [T; 2],
    /// Speed at which the Coulomb term reaches half its value (rad/s, > 0; not identified).
    pub coulomb_speed_rad_s: T,
}

/// Why a set of dynamic parameters is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DynamicsError {
    /// A parameter is NaN or infinite.
    NonFinite,
    /// A motor inertia or the Coulomb speed is not positive, or a mass or friction negative.
    OutOfRange,
}

impl core::fmt::Display for DynamicsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DynamicsError::NonFinite => f.write_str("a dynamic parameter is not finite"),
            DynamicsError::OutOfRange => f.write_str(
                "a dynamic parameter is out of range (motor inertia or Coulomb speed not positive, mass or friction negative)",
            ),
        }
    }
}

impl core::error::Error for DynamicsError {}

impl<T: Real> FiveBarDynamics<T> {
    /// The identified parameters in [`PARAMETER_NAMES`] order.
    pub fn to_array(&self) -> [T; PARAMETERS] {
        [
            self.motor_inertia_kg_m2[0],
            self.motor_inertia_kg_m2[1],
            self.tool_mass_kg,
            self.distal_inertia_kg_m2[0],
            self.distal_inertia_kg_m2[1],
            self.viscous_nm_s_per_rad[0],
            self.viscous_nm_s_per_rad[1],
            self.coulomb_nm[0],
            self.coulomb_nm[1],
        ]
    }

    /// Parameters from [`PARAMETER_NAMES`] order and the Coulomb speed.
    pub fn from_array(p: [T; PARAMETERS], coulomb_speed_rad_s: T) -> Self {
        FiveBarDynamics {
            motor_inertia_kg_m2: [p[0], p[1]],
            tool_mass_kg: p[2],
            distal_inertia_kg_m2: [p[3], p[4]],
            viscous_nm_s_per_rad: [p[5], p[6]],
            coulomb_nm: [p[7], p[8]],
            coulomb_speed_rad_s,
        }
    }

    /// Checks ranges (see [`DynamicsError`]).
    pub fn validate(&self) -> Result<(), DynamicsError> {
        let p = self.to_array();
        if !(p.iter().all(|v| v.is_finite()) && self.coulomb_speed_rad_s.is_finite()) {
            return Err(DynamicsError::NonFinite);
        }
        let positive = p[0] > T::ZERO && p[1] > T::ZERO && self.coulomb_speed_rad_s > T::ZERO;
        let non_negative = p[2] >= T::ZERO && p[5..].iter().all(|v| *v >= T::ZERO);
        if !(positive && non_negative) {
            return Err(DynamicsError::OutOfRange);
        }
        Ok(())
    }

    /// Every mass and inertia scaled: `factors` multiply `I1, I2, m_C, J3, J4` (friction
    /// unchanged). What a model error of ±20 % looks like, for robustness studies.
    pub fn scaled_masses(&self, factors: [T; 5]) -> Self {
        FiveBarDynamics {
            motor_inertia_kg_m2: [
                self.motor_inertia_kg_m2[0] * factors[0],
                self.motor_inertia_kg_m2[1] * factors[1],
            ],
            tool_mass_kg: self.tool_mass_kg * factors[2],
            distal_inertia_kg_m2: [
                self.distal_inertia_kg_m2[0] * factors[3],
                self.distal_inertia_kg_m2[1] * factors[4],
            ],
            ..*self
        }
    }

    /// The same parameters in another scalar type.
    pub fn cast<U: Real>(&self) -> FiveBarDynamics<U> {
        let p = self.to_array().map(|v| U::from_f64(v.to_f64()));
        FiveBarDynamics::from_array(p, U::from_f64(self.coulomb_speed_rad_s.to_f64()))
    }

    /// This model without friction: the rigid bodies alone.
    #[inline(always)]
    fn rigid(&self) -> Self {
        FiveBarDynamics {
            viscous_nm_s_per_rad: [T::ZERO; 2],
            coulomb_nm: [T::ZERO; 2],
            ..*self
        }
    }

    /// The inertia matrix's columns at a pose: the torques that accelerate motor 1, then motor
    /// 2, at 1 rad/s² from rest with the other held (two evaluations of the inverse dynamics).
    #[inline(always)]
    fn inertia_columns(
        &self,
        pose: &crate::pose::Pose<T>,
    ) -> Result<([T; 2], [T; 2]), KinematicsError> {
        use crate::joint_motion::motion_from_pose;
        let rigid = self.rigid();
        let m0 = rigid.torque_nm(&motion_from_pose(pose, [T::ZERO; 2], [T::ONE, T::ZERO])?)?;
        let m1 = rigid.torque_nm(&motion_from_pose(pose, [T::ZERO; 2], [T::ZERO, T::ONE])?)?;
        Ok((m0, m1))
    }

    /// The inertia matrix `M` (kg·m², symmetric) and the velocity-product torques `h(θ, θ̇)`
    /// (N·m) at a pose, friction left out: `τ = M·θ̈ + h` (three evaluations of the inverse
    /// dynamics; for simulated plants).
    pub fn mass_matrix_and_bias(
        &self,
        pose: &crate::pose::Pose<T>,
        velocity_rad_s: [T; 2],
    ) -> Result<(crate::jacobian::Mat2<T>, [T; 2]), KinematicsError> {
        use crate::joint_motion::motion_from_pose;
        let h = self
            .rigid()
            .torque_nm(&motion_from_pose(pose, velocity_rad_s, [T::ZERO; 2])?)?;
        let (m0, m1) = self.inertia_columns(pose)?;
        Ok(([[m0[0], m1[0]], [m0[1], m1[1]]], h))
    }

    /// The diagonal of the inertia matrix at a pose (kg·m²): each motor's inertia with the
    /// other held (two evaluations of the inverse dynamics, friction left out). What the
    /// servo's gains are designed for (`crate::gain_design`).
    pub fn inertia_diagonal(&self, pose: &crate::pose::Pose<T>) -> Result<[T; 2], KinematicsError> {
        let (m0, m1) = self.inertia_columns(pose)?;
        Ok([m0[0], m1[1]])
    }

    /// The joint accelerations (rad/s²) that `torque_nm` produces at the pose with joint
    /// velocities `velocity_rad_s`, friction of this model left out (a plant adds its own):
    /// `θ̈ = M⁻¹·(τ - h(θ, θ̇))`.
    pub fn forward_acceleration(
        &self,
        pose: &crate::pose::Pose<T>,
        velocity_rad_s: [T; 2],
        torque_nm: [T; 2],
    ) -> Result<[T; 2], KinematicsError> {
        let (m, h) = self.mass_matrix_and_bias(pose, velocity_rad_s)?;
        solve_spd(&m, [torque_nm[0] - h[0], torque_nm[1] - h[1]])
    }

    /// Motor torques (N·m) for `motion`: the regressor times the parameters (summed without
    /// the regressor's structural zeros).
    #[inline]
    pub fn torque_nm(&self, motion: &JointMotion<T>) -> Result<[T; 2], KinematicsError> {
        let y = Terms::of(motion, self.coulomb_speed_rad_s)?;
        let mut tau = [T::ZERO; 2];
        for (i, t) in tau.iter_mut().enumerate() {
            *t = self.motor_inertia_kg_m2[i] * y.acceleration[i]
                + self.tool_mass_kg * y.tool[i]
                + self.distal_inertia_kg_m2[0] * y.distal_1[i]
                + self.distal_inertia_kg_m2[1] * y.distal_2[i]
                + self.viscous_nm_s_per_rad[i] * y.velocity[i]
                + self.coulomb_nm[i] * y.coulomb[i];
        }
        Ok(tau)
    }
}

/// The regressor's non-zero entries: the column of each parameter, per motor (the motor
/// inertia, friction columns only act on their own motor).
struct Terms<T> {
    acceleration: [T; 2],
    tool: [T; 2],
    distal_1: [T; 2],
    distal_2: [T; 2],
    velocity: [T; 2],
    coulomb: [T; 2],
}

/// `M⁻¹·r` for a 2×2 inertia matrix; refuses one that is not positive definite.
pub fn solve_spd<T: Real>(
    m: &crate::jacobian::Mat2<T>,
    r: [T; 2],
) -> Result<[T; 2], KinematicsError> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    if !(det > T::ZERO && m[0][0] > T::ZERO) {
        return Err(KinematicsError::NonFinite);
    }
    Ok([
        (r[0] * m[1][1] - m[0][1] * r[1]) / det,
        (m[0][0] * r[1] - r[0] * m[1][0]) / det,
    ])
}

#[inline(always)]
fn dot<T: Real>(u: [T; 2], v: [T; 2]) -> T {
    u[0] * v[0] + u[1] * v[1]
}

/// The regressor `Y` (2 × [`PARAMETERS`]) of `τ = Y·π` for `motion`, in SI units (the
/// motion's millimetres are converted). Fails at an exact parallel singularity.
pub fn regressor<T: Real>(
    motion: &JointMotion<T>,
    coulomb_speed_rad_s: T,
) -> Result<[[T; PARAMETERS]; 2], KinematicsError> {
    let y = Terms::of(motion, coulomb_speed_rad_s)?;
    let z = T::ZERO;
    Ok([
        [
            y.acceleration[0],
            z,
            y.tool[0],
            y.distal_1[0],
            y.distal_2[0],
            y.velocity[0],
            z,
            y.coulomb[0],
            z,
        ],
        [
            z,
            y.acceleration[1],
            y.tool[1],
            y.distal_1[1],
            y.distal_2[1],
            z,
            y.velocity[1],
            z,
            y.coulomb[1],
        ],
    ])
}

impl<T: Real> Terms<T> {
    #[inline(always)]
    fn of(motion: &JointMotion<T>, coulomb_speed_rad_s: T) -> Result<Self, KinematicsError> {
        let [p1, p2] = motion.proximal_mm;
        let [q1, q2] = motion.distal_mm;
        let [w1, w2] = motion.velocity_rad_s;
        let [al1, al2] = motion.acceleration_rad_s2;
        let acc = motion.tool_acceleration_mm_s2;
        let det = cross(q1, q2);
        if det == T::ZERO {
            return Err(KinematicsError::NearSingularity(Singularity::Parallel));
        }
        // One division for the three reciprocals (VDIV is 14 cycles on the Cortex-M4): the
        // product of link lengths squared and a determinant stays far inside the float range.
        let (b2, c2) = (dot(q1, q1), dot(q2, q2));
        let inv_all = T::ONE / (det * b2 * c2);
        let inv_det = b2 * c2 * inv_all;
        let (inv_b2, inv_c2) = (det * c2 * inv_all, det * b2 * inv_all);
        let (k1, k2) = (cross(p1, q1), cross(p2, q2));
        let q12 = dot(q1, q2);
        // Elbow accelerations Ä = θ̈·p⊥ - θ̇²·p; C̈ - Ä is the distal link's relative one.
        let rel = |p: [T; 2], w: T, al: T| {
            [
                acc[0] + al * p[1] + w * w * p[0],
                acc[1] - al * p[0] + w * w * p[1],
            ]
        };
        let phi3 = cross(q1, rel(p1, w1, al1)) * inv_b2;
        let phi4 = cross(q2, rel(p2, w2, al2)) * inv_c2;
        // m_C: Jᵀ·C̈ (mm → m twice).
        let si = T::from_f64(1e-6) * inv_det;
        let y = Terms {
            acceleration: [al1, al2],
            tool: [k1 * cross(acc, q2) * si, k2 * cross(q1, acc) * si],
            // J3: φ̈3·(Jᵀq1⊥ - (q1·p1)e1)/|q1|², with Jᵀq1⊥ = (-k1·(q1·q2), k2·|q1|²)/det.
            distal_1: [
                phi3 * (-(k1 * q12 * inv_det) - dot(q1, p1)) * inv_b2,
                phi3 * k2 * inv_det,
            ],
            // J4: φ̈4·(Jᵀq2⊥ - (q2·p2)e2)/|q2|², with Jᵀq2⊥ = (-k1·|q2|², k2·(q1·q2))/det.
            distal_2: [
                -phi4 * k1 * inv_det,
                phi4 * (k2 * q12 * inv_det - dot(q2, p2)) * inv_c2,
            ],
            velocity: [w1, w2],
            coulomb: [
                w1 / (w1.abs() + coulomb_speed_rad_s),
                w2 / (w2.abs() + coulomb_speed_rad_s),
            ],
        };
        // All finite exactly when their sum is (a sum beyond 1e38 is no machine's either).
        let all = [
            y.tool,
            y.distal_1,
            y.distal_2,
            y.coulomb,
            y.acceleration,
            y.velocity,
        ];
        let sum = all.iter().flatten().fold(T::ZERO, |s, v| s + *v);
        #[allow(clippy::eq_op)] // `sum - sum` is the test
        if !(sum - sum == T::ZERO) {
            return Err(KinematicsError::NonFinite);
        }
        Ok(y)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    extern crate std;
    use super::*;
    use crate::model::{FiveBar, WorkingMode};
    use crate::path::Figure8;
    use crate::trajectory::{PathMotion, TaskLimits};

    /// A machine with every length, base and encoder offset off the paper's: the dynamics'
    /// tests and the joint motion's move on it, so no symmetry of the nominal hides an error.
    pub(crate) fn machine() -> FiveBar<f64> {
        FiveBar {
            a_mm: 149.2,
            b_mm: 151.1,
            c_mm: 148.7,
            d_mm: 150.6,
            base_a0_mm: [0.4, -0.3],
            base_b0_mm: [0.8, -1.1],
            encoder_offset_rad: [0.01, -0.02],
            mode: WorkingMode::PAPER,
        }
    }

    fn params() -> FiveBarDynamics<f64> {
        FiveBarDynamics {
            motor_inertia_kg_m2: [3.1e-3, 2.7e-3],
            tool_mass_kg: 0.12,
            distal_inertia_kg_m2: [-2.0e-4, 3.0e-4],
            viscous_nm_s_per_rad: [0.0, 0.0],
            coulomb_nm: [0.0, 0.0],
            coulomb_speed_rad_s: 0.01,
        }
    }

    /// Kinetic energy `T(θ, θ̇)` of the five elements, from the FK alone (velocities by central
    /// differences along θ̇): an independent route to the same physics.
    fn kinetic_energy(
        m: &FiveBar<f64>,
        d: &FiveBarDynamics<f64>,
        th: [f64; 2],
        w: [f64; 2],
    ) -> f64 {
        let e = 1e-5;
        let pose = |s: f64| {
            m.forward_pose([th[0] + s * w[0], th[1] + s * w[1]], 0.0)
                .unwrap()
        };
        let (a, b) = (pose(-e), pose(e));
        let v = |pa: [f64; 2], pb: [f64; 2]| {
            [
                (pb[0] - pa[0]) / (2.0 * e) * 1e-3,
                (pb[1] - pa[1]) / (2.0 * e) * 1e-3,
            ]
        };
        let angle = |p: &crate::pose::Pose<f64>, elbow: [f64; 2]| {
            (p.tool_mm[1] - elbow[1]).atan2(p.tool_mm[0] - elbow[0])
        };
        let vc = v(a.tool_mm, b.tool_mm);
        let w3 = (angle(&b, b.elbow_a_mm) - angle(&a, a.elbow_a_mm)) / (2.0 * e);
        let w4 = (angle(&b, b.elbow_b_mm) - angle(&a, a.elbow_b_mm)) / (2.0 * e);
        0.5 * (d.motor_inertia_kg_m2[0] * w[0] * w[0]
            + d.motor_inertia_kg_m2[1] * w[1] * w[1]
            + d.tool_mass_kg * (vc[0] * vc[0] + vc[1] * vc[1])
            + d.distal_inertia_kg_m2[0] * w3 * w3
            + d.distal_inertia_kg_m2[1] * w4 * w4)
    }

    /// `τ = d/dt ∂T/∂θ̇ - ∂T/∂θ` by finite differences against the closed form, along a
    /// figure-eight at 5 g (the configuration, and so the inertia matrix, changes fast).
    #[test]
    fn torques_match_the_lagrangian() {
        let (m, d) = (machine(), params());
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * 9_806.65,
            jerk_mm_s3: 5e6,
        };
        let f8 = Figure8 {
            centre_mm: [212.0, 0.0],
            half_x_mm: 40.0,
            half_y_mm: 50.0,
            loops: 1.0,
        };
        let traj = PathMotion::plan(f8, &limits, 2000).unwrap();
        let joint = |t: f64| {
            let s = traj.at(t);
            m.inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.0)
                .unwrap()
        };
        // ∂T/∂θ̇ (T is quadratic in θ̇: central differences are exact up to rounding).
        let dt_dw = |th: [f64; 2], w: [f64; 2]| {
            let h = 1e-3;
            let mut g = [0.0; 2];
            for i in 0..2 {
                let (mut lo, mut hi) = (w, w);
                lo[i] -= h;
                hi[i] += h;
                g[i] =
                    (kinetic_energy(&m, &d, th, hi) - kinetic_energy(&m, &d, th, lo)) / (2.0 * h);
            }
            g
        };
        let mut worst = 0.0f64;
        let mut scale = 0.0f64;
        for k in 1..40 {
            let t = traj.duration_s() * k as f64 / 40.0;
            let j = joint(t);
            let tau = d.torque_nm(&j).unwrap();
            let h = 1e-4;
            let (ja, jb) = (joint(t - h), joint(t + h));
            let (pa, pb) = (
                dt_dw(ja.angle_rad, ja.velocity_rad_s),
                dt_dw(jb.angle_rad, jb.velocity_rad_s),
            );
            let e = 1e-5;
            let mut lag = [0.0; 2];
            for i in 0..2 {
                let (mut lo, mut hi) = (j.angle_rad, j.angle_rad);
                lo[i] -= e;
                hi[i] += e;
                let dt_dth = (kinetic_energy(&m, &d, hi, j.velocity_rad_s)
                    - kinetic_energy(&m, &d, lo, j.velocity_rad_s))
                    / (2.0 * e);
                lag[i] = (pb[i] - pa[i]) / (2.0 * h) - dt_dth;
            }
            for i in 0..2 {
                worst = worst.max((lag[i] - tau[i]).abs());
                scale = scale.max(tau[i].abs());
            }
        }
        assert!(
            scale > 0.3,
            "the motion must load the model: peak {scale} N·m"
        );
        std::eprintln!("Lagrangian vs closed form: worst {worst:.3e} N·m of {scale:.3} N·m peak");
        assert!(worst < 1e-4 * scale, "worst {worst} N·m of {scale}");
    }

    #[test]
    fn torque_is_the_regressor_times_the_parameters_and_friction_opposes_motion() {
        let m = machine();
        let j = m
            .inverse_motion([215.0, 20.0], [300.0, -400.0], [20_000.0, 5_000.0], 0.05)
            .unwrap();
        let d = FiveBarDynamics {
            viscous_nm_s_per_rad: [0.02, 0.03],
            coulomb_nm: [0.05, 0.04],
            ..params()
        };
        let tau = d.torque_nm(&j).unwrap();
        let y = regressor(&j, 0.01).unwrap();
        for i in 0..2 {
            let sum: f64 = (0..PARAMETERS).map(|k| y[i][k] * d.to_array()[k]).sum();
            assert!(
                (sum - tau[i]).abs() < 1e-12 * (1.0 + tau[i].abs()),
                "{sum} vs {}",
                tau[i]
            );
        }
        let mut bad = j;
        bad.velocity_rad_s[1] = f64::NAN;
        assert_eq!(d.torque_nm(&bad), Err(KinematicsError::NonFinite));
        assert_eq!(regressor(&bad, 0.01), Err(KinematicsError::NonFinite));
        // At rest (no acceleration) only friction would act, and there is none at zero speed.
        let still = m
            .inverse_motion([215.0, 20.0], [0.0; 2], [0.0; 2], 0.05)
            .unwrap();
        assert_eq!(d.torque_nm(&still).unwrap(), [0.0; 2]);
        // Friction alone: the sign of the joint velocity.
        let f =
            FiveBarDynamics::from_array([1e-3, 1e-3, 0.0, 0.0, 0.0, 0.02, 0.03, 0.05, 0.04], 0.01);
        let slow = m
            .inverse_motion([215.0, 20.0], [300.0, -400.0], [0.0; 2], 0.05)
            .unwrap();
        let t = f.torque_nm(&slow).unwrap();
        let mut with_inertia = [0.0; 2];
        for i in 0..2 {
            with_inertia[i] = 1e-3 * slow.acceleration_rad_s2[i];
            assert_eq!(
                (t[i] - with_inertia[i]).signum(),
                slow.velocity_rad_s[i].signum()
            );
        }
    }

    /// Forward dynamics inverts the inverse dynamics, and the inertia matrix is symmetric.
    #[test]
    fn forward_acceleration_inverts_the_torque() {
        let m = machine();
        let d = params();
        let j = m
            .inverse_motion([215.0, 20.0], [300.0, -400.0], [20_000.0, 5_000.0], 0.05)
            .unwrap();
        let tau = d.torque_nm(&j).unwrap();
        let pose = m.forward_pose(j.angle_rad, 0.05).unwrap();
        let acc = d
            .forward_acceleration(&pose, j.velocity_rad_s, tau)
            .unwrap();
        for i in 0..2 {
            assert!(
                (acc[i] - j.acceleration_rad_s2[i]).abs() < 1e-9 * (1.0 + acc[i].abs()),
                "{acc:?} vs {:?}",
                j.acceleration_rad_s2
            );
        }
        use crate::joint_motion::motion_from_pose;
        let col = |k: usize| {
            let mut e = [0.0; 2];
            e[k] = 1.0;
            d.torque_nm(&motion_from_pose(&pose, [0.0; 2], e).unwrap())
                .unwrap()
        };
        let (c0, c1) = (col(0), col(1));
        assert!(
            (c0[1] - c1[0]).abs() < 1e-12 * c0[0].abs(),
            "M symmetric: {c0:?} {c1:?}"
        );
        assert!(c0[1].abs() > 1e-5, "the motors are coupled: {c0:?}");
    }

    #[test]
    fn parameters_round_trip_and_are_validated() {
        let d = params();
        assert_eq!(FiveBarDynamics::from_array(d.to_array(), 0.01), d);
        assert_eq!(d.validate(), Ok(()));
        assert_eq!(d.cast::<f32>().cast::<f64>().tool_mass_kg, 0.12f32 as f64);
        let bad = |f: fn(&mut FiveBarDynamics<f64>)| {
            let mut p = params();
            f(&mut p);
            p.validate()
        };
        assert_eq!(
            bad(|p| p.tool_mass_kg = f64::NAN),
            Err(DynamicsError::NonFinite)
        );
        assert_eq!(
            bad(|p| p.motor_inertia_kg_m2[1] = 0.0),
            Err(DynamicsError::OutOfRange)
        );
        assert_eq!(
            bad(|p| p.coulomb_nm[0] = -0.1),
            Err(DynamicsError::OutOfRange)
        );
        assert_eq!(
            bad(|p| p.coulomb_speed_rad_s = 0.0),
            Err(DynamicsError::OutOfRange)
        );
        assert_eq!(
            bad(|p| p.distal_inertia_kg_m2[0] = -1.0),
            Ok(()),
            "J may be negative"
        );
    }
}
