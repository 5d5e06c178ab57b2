//! The five-bar's joint motion from the tool's: angles, velocities and accelerations of the
//! motors for a tool position, velocity and acceleration, in closed form.
//!
//! With `p = A - A0` (proximal link), `q = C - A` (distal link) and `k = p × q` for arm 1
//! (arm 2 alike with `B0`, `B`), differentiating the loop constraint `|C - A|² = b²` once and
//! twice, with `Ȧ = θ̇·p⊥` and `Ä = θ̈·p⊥ - θ̇²·p`:
//!
//! ```text
//! q·(Ċ - Ȧ) = 0                          ⇒  θ̇ = q·Ċ / k                  (a row of J⁻¹)
//! |Ċ - Ȧ|² + q·(C̈ - Ä) = 0                ⇒  θ̈ = (q·C̈ + θ̇²·(q·p) + |Ċ - θ̇·p⊥|²) / k
//! ```
//! The second line is `J⁻¹·(C̈ - J̇·θ̇)` without forming `J̇`. The result carries the link
//! vectors, which the inverse dynamics ([`crate::dynamics`]) reuses.
//!
//! The other way round ([`FiveBar::forward_motion`], for simulated plants): the same two
//! relations of both arms, `q1·Ċ = θ̇1·k1`, `q2·Ċ = θ̇2·k2` and
//! `qi·C̈ = qi·Äi - |Ċ - Ȧi|²`, are two 2×2 systems with the determinant `q1 × q2`.
//!
//! Cost: the IK (`BENCH ik_f32`) plus four divisions and about 40 flops; `BENCH
//! inverse_motion_f32` in `cargo qemu-bench`. Error: exact up to rounding (the tests compare
//! with finite differences of the IK along a trajectory).

use crate::inverse::Solved;
use crate::model::FiveBar;
use crate::pose::{cross, Pose};
use crate::real::Real;
use crate::{KinematicsError, Singularity};

/// The motors' motion and the five-bar's link vectors for one tool motion.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointMotion<T> {
    /// Encoder angles (rad), as [`FiveBar::inverse`] gives them.
    pub angle_rad: [T; 2],
    /// Their rates (rad/s).
    pub velocity_rad_s: [T; 2],
    /// Their second derivatives (rad/s²).
    pub acceleration_rad_s2: [T; 2],
    /// Proximal links `A - A0`, `B - B0` (mm).
    pub proximal_mm: [[T; 2]; 2],
    /// Distal links `C - A`, `C - B` (mm).
    pub distal_mm: [[T; 2]; 2],
    /// The tool velocity it was computed for (mm/s).
    pub tool_velocity_mm_s: [T; 2],
    /// The tool acceleration it was computed for (mm/s²).
    pub tool_acceleration_mm_s2: [T; 2],
}

#[inline(always)]
fn dot<T: Real>(u: [T; 2], v: [T; 2]) -> T {
    u[0] * v[0] + u[1] * v[1]
}

impl<T: Real> FiveBar<T> {
    /// Joint angles, velocities and accelerations that move the tool through `tool_mm` with
    /// `velocity_mm_s` and `acceleration_mm_s2`; the same checks as [`FiveBar::inverse`].
    #[inline]
    pub fn inverse_motion(
        &self,
        tool_mm: [T; 2],
        velocity_mm_s: [T; 2],
        acceleration_mm_s2: [T; 2],
        min_transmission: T,
    ) -> Result<JointMotion<T>, KinematicsError> {
        self.solve_motion(
            tool_mm,
            velocity_mm_s,
            Some(acceleration_mm_s2),
            min_transmission,
        )
    }

    /// [`FiveBar::inverse_motion`] without the accelerations (left zero): angles, rates and the
    /// link vectors, for the servo's joint samples.
    #[inline]
    pub fn inverse_rates(
        &self,
        tool_mm: [T; 2],
        velocity_mm_s: [T; 2],
        min_transmission: T,
    ) -> Result<JointMotion<T>, KinematicsError> {
        self.solve_motion(tool_mm, velocity_mm_s, None, min_transmission)
    }

    #[inline(always)]
    fn solve_motion(
        &self,
        tool_mm: [T; 2],
        velocity_mm_s: [T; 2],
        acceleration_mm_s2: Option<[T; 2]>,
        min_transmission: T,
    ) -> Result<JointMotion<T>, KinematicsError> {
        let s = self.solve_inverse(tool_mm, min_transmission)?;
        motion_of_solved(&s, velocity_mm_s, acceleration_mm_s2)
    }

    /// The tool's motion for joint angles, velocities and accelerations (the FK's checks).
    pub fn forward_motion(
        &self,
        angle_rad: [T; 2],
        velocity_rad_s: [T; 2],
        acceleration_rad_s2: [T; 2],
        min_transmission: T,
    ) -> Result<JointMotion<T>, KinematicsError> {
        let pose = self.forward_pose(angle_rad, min_transmission)?;
        motion_from_pose(&pose, velocity_rad_s, acceleration_rad_s2)
    }
}

/// The joint motion of a solved IK: the rates (and accelerations, if asked) from the IK's
/// link vectors. Shared by [`FiveBar::inverse_motion`] and [`crate::ValidFiveBar::inverse_rates`].
#[inline(always)]
pub(crate) fn motion_of_solved<T: Real>(
    s: &Solved<T>,
    velocity_mm_s: [T; 2],
    acceleration_mm_s2: Option<[T; 2]>,
) -> Result<JointMotion<T>, KinematicsError> {
    let mut m = JointMotion {
        angle_rad: [s.arm_1.theta_rad, s.arm_2.theta_rad],
        velocity_rad_s: [T::ZERO; 2],
        acceleration_rad_s2: [T::ZERO; 2],
        proximal_mm: [[T::ZERO; 2]; 2],
        distal_mm: [[T::ZERO; 2]; 2],
        tool_velocity_mm_s: velocity_mm_s,
        tool_acceleration_mm_s2: acceleration_mm_s2.unwrap_or([T::ZERO; 2]),
    };
    for (i, arm) in [&s.arm_1, &s.arm_2].into_iter().enumerate() {
        // The IK's vectors are scaled by 2ρ².
        let unscale = T::ONE / (arm.rho2 + arm.rho2);
        let p = [arm.proximal[0] * unscale, arm.proximal[1] * unscale];
        let q = [arm.distal[0] * unscale, arm.distal[1] * unscale];
        let k = cross(p, q);
        if k == T::ZERO {
            return Err(KinematicsError::NearSingularity(Singularity::Serial));
        }
        let inv_k = T::ONE / k;
        let w = dot(q, velocity_mm_s) * inv_k;
        if let Some(acc) = acceleration_mm_s2 {
            // Ċ - Ȧ with Ȧ = θ̇·p⊥, p⊥ = (-p_y, p_x).
            let rel = [velocity_mm_s[0] + w * p[1], velocity_mm_s[1] - w * p[0]];
            m.acceleration_rad_s2[i] = (dot(q, acc) + w * w * dot(q, p) + dot(rel, rel)) * inv_k;
        }
        m.velocity_rad_s[i] = w;
        m.proximal_mm[i] = p;
        m.distal_mm[i] = q;
    }
    // All finite exactly when their sum is (beyond 1e38 no machine moves either).
    let sum = m.velocity_rad_s[0]
        + m.velocity_rad_s[1]
        + m.acceleration_rad_s2[0]
        + m.acceleration_rad_s2[1];
    #[allow(clippy::eq_op)] // `sum - sum` is the test
    if !(sum - sum == T::ZERO) {
        return Err(KinematicsError::NonFinite);
    }
    Ok(m)
}

/// The tool's motion at a solved pose for joint velocities and accelerations.
pub fn motion_from_pose<T: Real>(
    pose: &Pose<T>,
    velocity_rad_s: [T; 2],
    acceleration_rad_s2: [T; 2],
) -> Result<JointMotion<T>, KinematicsError> {
    let (p1, q1, p2, q2) = pose.link_vectors();
    let det = cross(q1, q2);
    if det == T::ZERO {
        return Err(KinematicsError::NearSingularity(Singularity::Parallel));
    }
    let inv_det = T::ONE / det;
    // Solves q1·x = r1, q2·x = r2.
    let solve = |r1: T, r2: T| {
        [
            (r1 * q2[1] - r2 * q1[1]) * inv_det,
            (r2 * q1[0] - r1 * q2[0]) * inv_det,
        ]
    };
    let [w1, w2] = velocity_rad_s;
    let [al1, al2] = acceleration_rad_s2;
    let v = solve(w1 * cross(p1, q1), w2 * cross(p2, q2));
    // qi·C̈ = qi·Äi - |Ċ - Ȧi|², Ä = θ̈·p⊥ - θ̇²·p, Ȧ = θ̇·p⊥.
    let rhs = |p: [T; 2], q: [T; 2], w: T, al: T| {
        let acc_elbow = [-al * p[1] - w * w * p[0], al * p[0] - w * w * p[1]];
        let rel = [v[0] + w * p[1], v[1] - w * p[0]];
        dot(q, acc_elbow) - dot(rel, rel)
    };
    let a = solve(rhs(p1, q1, w1, al1), rhs(p2, q2, w2, al2));
    let m = JointMotion {
        angle_rad: pose.theta_rad,
        velocity_rad_s,
        acceleration_rad_s2,
        proximal_mm: [p1, p2],
        distal_mm: [q1, q2],
        tool_velocity_mm_s: v,
        tool_acceleration_mm_s2: a,
    };
    if !(v.iter().chain(a.iter()).all(|x| x.is_finite())) {
        return Err(KinematicsError::NonFinite);
    }
    Ok(m)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::dynamics::tests::machine;
    use crate::path::Circle;
    use crate::trajectory::{PathMotion, TaskLimits};

    /// Along a circle at 5 g, the joint velocities and accelerations are the derivatives of the
    /// IK's angles (central differences).
    #[test]
    fn velocities_and_accelerations_are_the_derivatives_of_the_ik() {
        let m = machine();
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * 9_806.65,
            jerk_mm_s3: 5e6,
        };
        let circle = Circle {
            centre_mm: [212.0, 0.0],
            radius_mm: 40.0,
            start_rad: 0.5,
            turns: 1.0,
        };
        let traj = PathMotion::plan(circle, &limits, 2000).unwrap();
        let h = 1e-5;
        let angle = |t: f64| m.inverse(traj.at(t).position_mm, 0.0).unwrap();
        for k in 1..100 {
            let t = traj.duration_s() * k as f64 / 100.0;
            let s = traj.at(t);
            let j = m
                .inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.05)
                .unwrap();
            let (a, b, c) = (angle(t - h), angle(t), angle(t + h));
            assert_eq!(j.angle_rad, b);
            for i in 0..2 {
                let fv = (c[i] - a[i]) / (2.0 * h);
                let fa = (c[i] - 2.0 * b[i] + a[i]) / (h * h);
                assert!(
                    (fv - j.velocity_rad_s[i]).abs() < 1e-6 * (1.0 + fv.abs()),
                    "v{i} at {t}: {fv} vs {}",
                    j.velocity_rad_s[i]
                );
                assert!(
                    (fa - j.acceleration_rad_s2[i]).abs() < 2e-3 * (1.0 + fa.abs()),
                    "a{i} at {t}: {fa} vs {}",
                    j.acceleration_rad_s2[i]
                );
            }
            // The velocities are J⁻¹·v from the pose's inverse Jacobian.
            let ji = m
                .inverse_pose(s.position_mm, 0.0)
                .unwrap()
                .inverse_jacobian()
                .unwrap();
            for (row, wj) in ji.iter().zip(j.velocity_rad_s) {
                let w = row[0] * s.velocity_mm_s[0] + row[1] * s.velocity_mm_s[1];
                assert!((w - wj).abs() < 1e-9 * (1.0 + w.abs()));
            }
        }
    }

    /// Forward and inverse motion are each other's inverse.
    #[test]
    fn forward_motion_inverts_inverse_motion() {
        let m = machine();
        for (p, v, a) in [
            ([215.0, 20.0], [300.0, -400.0], [20_000.0, 5_000.0]),
            ([180.0, -60.0], [-1200.0, 100.0], [-30_000.0, 40_000.0]),
            ([250.0, 65.0], [0.0, 0.0], [1_000.0, -2_000.0]),
        ] {
            let j = m.inverse_motion(p, v, a, 0.05).unwrap();
            let f = m
                .forward_motion(j.angle_rad, j.velocity_rad_s, j.acceleration_rad_s2, 0.05)
                .unwrap();
            for i in 0..2 {
                assert!((f.tool_velocity_mm_s[i] - v[i]).abs() < 1e-9 * (1.0 + v[i].abs()));
                assert!((f.tool_acceleration_mm_s2[i] - a[i]).abs() < 1e-8 * (1.0 + a[i].abs()));
                for k in 0..2 {
                    assert!((f.proximal_mm[i][k] - j.proximal_mm[i][k]).abs() < 1e-9);
                    assert!((f.distal_mm[i][k] - j.distal_mm[i][k]).abs() < 1e-9);
                }
            }
        }
    }

    #[test]
    fn refuses_what_the_ik_refuses_and_non_finite_rates() {
        let m = machine();
        assert_eq!(
            m.inverse_motion([400.0, 0.0], [0.0; 2], [0.0; 2], 0.05),
            Err(KinematicsError::Unreachable)
        );
        assert_eq!(
            m.inverse_motion([212.0, 0.0], [f64::NAN, 0.0], [0.0; 2], 0.05),
            Err(KinematicsError::NonFinite)
        );
        assert_eq!(
            m.inverse_motion([212.0, 0.0], [0.0; 2], [f64::INFINITY, 0.0], 0.05),
            Err(KinematicsError::NonFinite)
        );
    }
}
