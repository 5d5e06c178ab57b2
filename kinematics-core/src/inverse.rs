//! Closed-form inverse kinematics of the five-bar: tool point in, encoder angles out.
//!
//! Each arm is a dyad solved on its own. For arm 1 (base A0, proximal `a`, distal `b`) and a
//! target C with `r = C - A0`, `ρ² = r·r`, the angle α between `r` and link a obeys the law
//! of cosines `2aρ cos α = a² + ρ² - b² =: m`. Instead of `φ ± acos(m / 2aρ)` (two
//! transcendental calls, and `acos` loses half the digits near the workspace boundary), we
//! rotate `r` by `±α` algebraically: with `h := 2aρ sin α`,
//!
//! ```text
//! h² = 4a²ρ² - m² = (ρ² - (a - b)²) · ((a + b)² - ρ²)      (Heron, cancellation-free)
//! A - A0 = (m·r + σ·h·r⊥) / (2ρ²),   r⊥ = (-r_y, r_x),   σ = ±1 (the elbow branch)
//! θ1 = atan2(σ·h·r_x + m·r_y, m·r_x - σ·h·r_y) - encoder offset
//! ```
//!
//! so one arm costs one `atan2`, no square root but `√(h²)`, and the elbow position falls out
//! for the singularity checks and the Jacobian. The target is reachable by the arm exactly when
//! both Heron factors are non-negative, and by the machine when, in addition, C lies on the
//! side of A→B that the assembly mode prescribes (else FK of the angles would give the mirror
//! point: the target is beyond a parallel singularity).
//!
//! Cost and error: see `cargo qemu-bench` (`BENCH ik_f32`) and the round-trip tests: f32
//! round trips stay within 0.1 µm and f64 within 1 nm over the paper's workspace.

use crate::model::{Branch, FiveBar};
use crate::pose::{cross, sub, Pose};
use crate::real::{wrap_angle_rad, Real};
use crate::KinematicsError;

/// Solves one dyad: returns the elbow position relative to the base, or `None` if out of reach.
#[inline]
fn solve_dyad<T: Real>(r: [T; 2], proximal: T, distal: T, elbow: Branch) -> Option<[T; 2]> {
    let rho2 = r[0] * r[0] + r[1] * r[1];
    let diff = proximal - distal;
    let sum = proximal + distal;
    let h2 = (rho2 - diff * diff) * (sum * sum - rho2);
    // `!(h2 >= 0)` also catches NaN; `rho2 > 0` excludes the degenerate target at the base.
    if !(h2 >= T::ZERO) || !(rho2 > T::ZERO) {
        return None;
    }
    let m = proximal * proximal + rho2 - distal * distal;
    let h = elbow.sign::<T>() * h2.sqrt();
    let scale = T::ONE / (T::TWO * rho2);
    Some([(m * r[0] - h * r[1]) * scale, (h * r[0] + m * r[1]) * scale])
}

impl<T: Real> FiveBar<T> {
    /// Encoder angles that put the tool point at `tool_mm`, with the full pose.
    ///
    /// `min_transmission` is the smallest acceptable `|sin|` of the transmission angles (see
    /// [`Pose`]); 0 accepts everything short of an exact singularity. Angles are wrapped into
    /// `(-π, π]`; the servo unwraps them next to the motor's current position.
    pub fn inverse_pose(
        &self,
        tool_mm: [T; 2],
        min_transmission: T,
    ) -> Result<Pose<T>, KinematicsError> {
        if !(tool_mm[0].is_finite() && tool_mm[1].is_finite()) {
            return Err(KinematicsError::NonFinite);
        }
        let a0 = self.base_a0_mm;
        let b0 = [a0[0] + self.base_b0_mm[0], a0[1] + self.base_b0_mm[1]];
        let r1 = sub(tool_mm, a0);
        let r2 = sub(tool_mm, b0);
        let pa = solve_dyad(r1, self.a_mm, self.b_mm, self.mode.elbow_1)
            .ok_or(KinematicsError::Unreachable)?;
        let pb = solve_dyad(r2, self.d_mm, self.c_mm, self.mode.elbow_2)
            .ok_or(KinematicsError::Unreachable)?;
        let elbow_a = [pa[0] + a0[0], pa[1] + a0[1]];
        let elbow_b = [pb[0] + b0[0], pb[1] + b0[1]];
        // The elbows fix A and B; C must also lie on the configured side of A→B, otherwise this
        // target belongs to the other assembly mode (across a parallel singularity) and FK of
        // these angles would give a different point.
        let side = cross(sub(elbow_b, elbow_a), sub(tool_mm, elbow_a));
        if side * self.mode.assembly.sign::<T>() < T::ZERO {
            return Err(KinematicsError::Unreachable);
        }
        let theta1 = wrap_angle_rad(pa[1].atan2(pa[0]) - self.encoder_offset_rad[0]);
        let theta2 = wrap_angle_rad(pb[1].atan2(pb[0]) - self.encoder_offset_rad[1]);
        Pose {
            theta_rad: [theta1, theta2],
            elbow_a_mm: elbow_a,
            elbow_b_mm: elbow_b,
            tool_mm,
            base_a0_mm: a0,
            base_b0_mm: b0,
        }
        .check(self, min_transmission)
    }

    /// Encoder angles that put the tool point at `tool_mm` (see [`FiveBar::inverse_pose`]).
    pub fn inverse(&self, tool_mm: [T; 2], min_transmission: T) -> Result<[T; 2], KinematicsError> {
        self.inverse_pose(tool_mm, min_transmission).map(|p| p.theta_rad)
    }
}
