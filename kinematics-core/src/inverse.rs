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
//! so one arm costs one `atan2` and one `√(h²)` (VSQRT on the MCU). `atan2` needs only the
//! direction, so the elbow vectors stay scaled by `2ρ²` and nothing is divided: the checks
//! use the same scaled vectors and compare their margins multiplied out.
//!
//! * Reach: the arm reaches C exactly when both Heron factors are non-negative.
//! * Assembly side: C must lie on the side of A→B that the assembly mode prescribes (else FK
//!   of the angles would give the mirror point: the target is beyond a parallel
//!   singularity). The sign of `(C - A) × (C - B)`, from the scaled distal vectors.
//! * Serial margin: `|p1 × q1| = h/2` for the unscaled links (the Heron quantity itself),
//!   compared with `m·a·b`.
//! * Parallel margin: `|q1 × q2|`, the same cross product as the side test, against
//!   `m·b·c·4ρ1²ρ2²` (the scale of the two distal vectors).
//! * Finite: the angles, the elbow vectors and the cross product.
//!
//! Cost: two `atan2_f32`, two square roots (VSQRT on the MCU) and no other division; on every
//! call a dozen instructions check the model's links and raise the margin to its floor, which
//! [`crate::ValidFiveBar::inverse`] (the servo's IK) does once instead. `BENCH ik_f32` and
//! `BENCH ik_f32_valid` in `cargo qemu-bench` count both on the MCU
//! (docs/validation/benchmarks.md). Error: f32 round trips FK(IK(p)) stay within 0.1 µm and
//! f64 within 1 nm over the paper's workspace, the f32 IK alone within 0.1 µm of f64 at the
//! tool: `cargo test -p kinematics-core --release --test round_trip -- --nocapture` asserts
//! the bounds and prints the worst cases.
//!
//! ```
//! use kinematics_core::FiveBar;
//!
//! let m = FiveBar::<f64>::paper_nominal();
//! // The workspace's centre, where the nominal five-bar is a square: ±45°.
//! let theta = m.inverse([150.0 * 2f64.sqrt(), 0.0], 0.05).unwrap();
//! assert!((theta[0] - 45f64.to_radians()).abs() < 1e-12);
//! assert!((theta[1] + 45f64.to_radians()).abs() < 1e-12);
//! // Out of reach (the arms are 300 mm long together): a typed refusal, never NaN angles.
//! assert!(m.inverse([400.0, 0.0], 0.05).is_err());
//! ```

use crate::model::{Branch, FiveBar};
use crate::pose::{cross, Pose};
use crate::real::{effective_margin, wrap_near_rad, Real};
use crate::{KinematicsError, Singularity};

/// One arm solved: its angle and what the checks and `inverse_pose` need, the vectors scaled
/// by `2ρ²` (the division is left to who needs lengths).
pub(crate) struct Arm<T> {
    pub(crate) theta_rad: T,
    /// `2ρ²·(A - A0)`: the proximal link's direction, all `atan2` needs.
    pub(crate) proximal: [T; 2],
    /// `2ρ²·(C - A)`: the distal link's direction.
    pub(crate) distal: [T; 2],
    /// `ρ²`.
    pub(crate) rho2: T,
    /// The serial transmission is at least the margin: `|p × q| / (|p|·|q|) = h / (2·|p|·|q|)`,
    /// with `|p × q| = h/2` for the unscaled links (the Heron quantity, no cross product).
    serial_ok: bool,
}

/// Solves one arm for the target `r` (relative to its base): `None` if out of reach.
/// `offset_rad` is the encoder offset, `min_h` the margin times `2·|p|·|q|`.
#[inline(always)]
fn solve_arm<T: Real>(
    r: [T; 2],
    proximal_mm: T,
    distal_mm: T,
    elbow: Branch,
    offset_rad: T,
    min_h: T,
) -> Option<Arm<T>> {
    let rho2 = r[0] * r[0] + r[1] * r[1];
    let diff = proximal_mm - distal_mm;
    let sum = proximal_mm + distal_mm;
    let h2 = (rho2 - diff * diff) * (sum * sum - rho2);
    // `!(h2 >= 0)` also catches NaN; `rho2 > 0` excludes the degenerate target at the base.
    if !(h2 >= T::ZERO) || !(rho2 > T::ZERO) {
        return None;
    }
    // m = 2aρ cos α: the projection of link a on r, scaled by 2ρ.
    let m = rho2 + diff * sum;
    let h_abs = h2.sqrt();
    let h = elbow.sign::<T>() * h_abs;
    let proximal = [m * r[0] - h * r[1], m * r[1] + h * r[0]];
    // 2ρ²·(C - A) = 2ρ²·r - 2ρ²·(A - A0).
    let two_rho2 = rho2 + rho2;
    Some(Arm {
        // An absurd encoder offset (beyond ±3π) gives NaN here: refused as non-finite.
        theta_rad: wrap_near_rad(proximal[1].atan2(proximal[0]) - offset_rad),
        proximal,
        distal: [two_rho2 * r[0] - proximal[0], two_rho2 * r[1] - proximal[1]],
        rho2,
        // `x >= m` is false for a NaN `h_abs`.
        serial_ok: h_abs >= min_h,
    })
}

/// `true` when every value is finite (`x - x` is 0 for finite `x` and NaN otherwise).
#[inline(always)]
#[allow(clippy::eq_op)] // `v - v` is the test
fn all_finite<T: Real, const N: usize>(values: [T; N]) -> bool {
    values.map(|v| v - v).into_iter().reduce(|a, b| a + b) == Some(T::ZERO)
}

/// `true` when every value is finite and their sum does not overflow (cheaper than
/// [`all_finite`]: the sum is NaN or infinite as soon as one term is). For results whose
/// overflow is itself a failure (beyond 1e38 a pose is not a machine's).
#[inline(always)]
#[allow(clippy::eq_op)] // `sum - sum` is the test
fn finite_without_overflow<T: Real, const N: usize>(values: [T; N]) -> bool {
    values
        .into_iter()
        .reduce(|a, b| a + b)
        .is_some_and(|sum| sum - sum == T::ZERO)
}

/// The IK solved up to the angles, with what `inverse_pose` needs to place the elbows.
pub(crate) struct Solved<T> {
    pub(crate) arm_1: Arm<T>,
    pub(crate) arm_2: Arm<T>,
    base_b0_mm: [T; 2],
}

impl<T: Real> FiveBar<T> {
    /// The closed form and every check, without a division: the margins are compared
    /// multiplied out (`|p × q| >= m·a·b` instead of `|p × q| / (a·b) >= m`, the same test for
    /// positive lengths) and the elbows are only scaled where a caller wants positions. Each
    /// arm is finished (angle included) before the next one starts, which keeps few values
    /// alive at a time; the errors come in the same order whatever is computed first.
    #[inline(always)]
    pub(crate) fn solve_inverse(
        &self,
        tool_mm: [T; 2],
        min_transmission: T,
    ) -> Result<Solved<T>, KinematicsError> {
        if !all_finite(tool_mm) {
            return Err(KinematicsError::NonFinite);
        }
        // A link that is not positive solves to angles whose FK is another point (the law of
        // cosines squares the lengths). A non-finite parameter needs no test here: it makes
        // the angles or the cross product non-finite, refused below.
        if !self.links_positive() {
            return Err(self.invalid_model());
        }
        self.solve_checked(
            tool_mm,
            effective_margin(min_transmission, T::IK_MIN_TRANSMISSION),
        )
    }

    /// [`Self::solve_inverse`] for a model whose links are known positive
    /// ([`crate::ValidFiveBar`]) and a margin already raised to its floor
    /// ([`crate::IkMargin`]): the target's checks only.
    #[inline(always)]
    pub(crate) fn solve_inverse_valid(
        &self,
        tool_mm: [T; 2],
        min_transmission: T,
    ) -> Result<Solved<T>, KinematicsError> {
        if !all_finite(tool_mm) {
            return Err(KinematicsError::NonFinite);
        }
        self.solve_checked(tool_mm, min_transmission)
    }

    /// The closed form and the target's checks, for positive links and a margin at least the
    /// floor (or NaN). The target is tested finite by the callers, or proven finite (the
    /// servo's); a non-finite one is still refused here, by the reach test (`ρ²` infinite or
    /// NaN), as `Unreachable`.
    #[inline(always)]
    pub(crate) fn solve_checked(
        &self,
        tool_mm: [T; 2],
        min_transmission: T,
    ) -> Result<Solved<T>, KinematicsError> {
        let a0 = self.base_a0_mm;
        let b0 = [a0[0] + self.base_b0_mm[0], a0[1] + self.base_b0_mm[1]];
        let r1 = [tool_mm[0] - a0[0], tool_mm[1] - a0[1]];
        let r2 = [tool_mm[0] - b0[0], tool_mm[1] - b0[1]];
        let min_h = |p: T, d: T| min_transmission * (T::TWO * p * d).abs();
        let (off, mode) = (self.encoder_offset_rad, self.mode);
        let arm_1 = solve_arm(
            r1,
            self.a_mm,
            self.b_mm,
            mode.elbow_1,
            off[0],
            min_h(self.a_mm, self.b_mm),
        )
        .ok_or(KinematicsError::Unreachable)?;
        let arm_2 = solve_arm(
            r2,
            self.d_mm,
            self.c_mm,
            mode.elbow_2,
            off[1],
            min_h(self.d_mm, self.c_mm),
        )
        .ok_or(KinematicsError::Unreachable)?;
        // (C - A) × (C - B) = (B - A) × (C - A), scaled by 4ρ1²ρ2² > 0: its sign says on which
        // side of A→B the target lies. On the wrong side this target belongs to the other
        // assembly mode (across a parallel singularity) and FK of these angles would give
        // another point. Its magnitude is the parallel transmission's numerator.
        let distal_cross = cross(arm_1.distal, arm_2.distal);
        if distal_cross * mode.assembly.sign::<T>() < T::ZERO {
            return Err(KinematicsError::Unreachable);
        }
        let values = [
            arm_1.theta_rad,
            arm_2.theta_rad,
            arm_1.proximal[0],
            arm_1.proximal[1],
            arm_2.proximal[0],
            arm_2.proximal[1],
            distal_cross,
        ];
        if !finite_without_overflow(values) {
            return Err(KinematicsError::NonFinite);
        }
        if !(arm_1.serial_ok && arm_2.serial_ok) {
            return Err(KinematicsError::NearSingularity(Singularity::Serial));
        }
        // Parallel: |q1 × q2| / (b·c) with q1 × q2 = distal_cross / (4ρ1²ρ2²); `!(x >= m)`
        // also refuses NaN.
        let scale = T::TWO * arm_1.rho2 * (T::TWO * arm_2.rho2);
        if !(distal_cross.abs() >= min_transmission * (self.b_mm * self.c_mm).abs() * scale) {
            return Err(KinematicsError::NearSingularity(Singularity::Parallel));
        }
        Ok(Solved {
            arm_1,
            arm_2,
            base_b0_mm: b0,
        })
    }

    /// Encoder angles that put the tool point at `tool_mm`, with the full pose.
    ///
    /// `min_transmission` is the smallest acceptable `|sin|` of the transmission angles (see
    /// [`Pose`]). It is raised to [`Real::IK_MIN_TRANSMISSION`] (∛ε: 6e-6 in f64, 4.9e-3 in
    /// f32, 0.28°): 0 or a negative margin accepts everything except a singularity and the
    /// poses so close to one that FK of the angles could round across it; a pose IK accepts
    /// with margin 0 is one FK returns with margin 0 (FK's floor is lower, √ε). A NaN margin
    /// refuses every pose. A model whose links are not all positive
    /// is [`KinematicsError::InvalidModel`]. A caller solving many targets with one model (the
    /// servo) checks it once instead: [`crate::ValidFiveBar::inverse`]. Angles are wrapped into
    /// `(-π, π]`; the servo unwraps them next to the motor's current position.
    pub fn inverse_pose(
        &self,
        tool_mm: [T; 2],
        min_transmission: T,
    ) -> Result<Pose<T>, KinematicsError> {
        let s = self.solve_inverse(tool_mm, min_transmission)?;
        let a0 = self.base_a0_mm;
        let place = |base: [T; 2], arm: &Arm<T>| {
            let scale = T::ONE / (T::TWO * arm.rho2);
            [
                base[0] + arm.proximal[0] * scale,
                base[1] + arm.proximal[1] * scale,
            ]
        };
        let pose = Pose {
            theta_rad: [s.arm_1.theta_rad, s.arm_2.theta_rad],
            elbow_a_mm: place(a0, &s.arm_1),
            elbow_b_mm: place(s.base_b0_mm, &s.arm_2),
            tool_mm,
            base_a0_mm: a0,
            base_b0_mm: s.base_b0_mm,
        };
        // The angles and margins are checked; the elbows can still overflow on absurd input.
        if !all_finite([
            pose.elbow_a_mm[0],
            pose.elbow_a_mm[1],
            pose.elbow_b_mm[0],
            pose.elbow_b_mm[1],
        ]) {
            return Err(KinematicsError::NonFinite);
        }
        Ok(pose)
    }

    /// Encoder angles that put the tool point at `tool_mm` (see [`FiveBar::inverse_pose`]).
    ///
    /// The servo's path: the same closed form and checks as `inverse_pose` without placing
    /// the elbows (no division at all).
    pub fn inverse(&self, tool_mm: [T; 2], min_transmission: T) -> Result<[T; 2], KinematicsError> {
        self.solve_inverse(tool_mm, min_transmission)
            .map(|s| [s.arm_1.theta_rad, s.arm_2.theta_rad])
    }
}
