//! Closed-form forward kinematics of the five-bar: encoder angles in, tool point out.
//!
//! The elbows are `A = A0 + a·(cos θ1g, sin θ1g)` and `B = B0 + d·(cos θ2g, sin θ2g)` with the
//! geometric angles `θg = θ + encoder offset`. C is where the circles of radius `b` about A and
//! `c` about B meet. With `s = B - A` and `m = b² + s·s - c²`,
//!
//! ```text
//! h² = 4b²(s·s) - m² = (s·s - (b - c)²) · ((b + c)² - s·s)
//! C  = A + (m·s + σ·h·s⊥) / (2 s·s),   s⊥ = (-s_y, s_x),   σ = ±1 (assembly mode)
//! ```
//!
//! (check: `|C - A|² = (m² + h²)/(4 s·s) = b²`). `σ = +1` puts C to the left of A→B. The paper's
//! Eq. 9 is the same construction in angles (`θ3 = φ + π + acos(...)`); this form needs no
//! inverse trigonometry and gives the parallel-singularity margin `h / 2bc` for free.
//!
//! Cost: two `sin_cos` (one per motor), one square root and one division, the assembly and
//! margin checks; `BENCH fk_f32` in `cargo qemu-bench` counts it on the MCU
//! (docs/validation/benchmarks.md). Error: see [`crate::inverse`] (`tests/round_trip.rs`).
//!
//! ```
//! use kinematics_core::FiveBar;
//!
//! let m = FiveBar::<f64>::paper_nominal();
//! // Both arms at ±45°: the square pose, the tool on the x axis at 150·√2 mm.
//! let c = m.forward([45f64.to_radians(), -45f64.to_radians()], 0.05).unwrap();
//! assert!((c[0] - 150.0 * 2f64.sqrt()).abs() < 1e-9 && c[1].abs() < 1e-9);
//! // FK undoes IK.
//! let theta = m.inverse([200.0, 30.0], 0.05).unwrap();
//! let back = m.forward(theta, 0.05).unwrap();
//! assert!((back[0] - 200.0).abs() < 1e-9 && (back[1] - 30.0).abs() < 1e-9);
//! // Distal links that cannot meet: refused.
//! assert!(m.forward([0.0, 3.0], 0.05).is_err());
//! ```

use crate::model::FiveBar;
use crate::pose::Pose;
use crate::real::Real;
use crate::KinematicsError;

impl<T: Real> FiveBar<T> {
    /// The pose reached with encoder angles `theta_rad` (see [`FiveBar::inverse_pose`] for
    /// `min_transmission`).
    pub fn forward_pose(
        &self,
        theta_rad: [T; 2],
        min_transmission: T,
    ) -> Result<Pose<T>, KinematicsError> {
        self.solve_forward(theta_rad, min_transmission)
    }

    /// The tool point reached with encoder angles `theta_rad`.
    pub fn forward(
        &self,
        theta_rad: [T; 2],
        min_transmission: T,
    ) -> Result<[T; 2], KinematicsError> {
        self.solve_forward(theta_rad, min_transmission)
            .map(|p| p.tool_mm)
    }

    /// The closed form and its checks, inlined into both entry points so that `forward`
    /// neither builds nor returns the whole pose.
    #[inline(always)]
    fn solve_forward(
        &self,
        theta_rad: [T; 2],
        min_transmission: T,
    ) -> Result<Pose<T>, KinematicsError> {
        if !(theta_rad[0].is_finite() && theta_rad[1].is_finite()) {
            return Err(KinematicsError::NonFinite);
        }
        if !self.links_positive() {
            return Err(self.invalid_model());
        }
        let (s1, c1) = (theta_rad[0] + self.encoder_offset_rad[0]).sin_cos();
        let (s2, c2) = (theta_rad[1] + self.encoder_offset_rad[1]).sin_cos();
        let a0 = self.base_a0_mm;
        let b0 = [a0[0] + self.base_b0_mm[0], a0[1] + self.base_b0_mm[1]];
        let a = [a0[0] + self.a_mm * c1, a0[1] + self.a_mm * s1];
        let b = [b0[0] + self.d_mm * c2, b0[1] + self.d_mm * s2];
        let s = [b[0] - a[0], b[1] - a[1]];
        let ss = s[0] * s[0] + s[1] * s[1];
        let diff = self.b_mm - self.c_mm;
        let sum = self.b_mm + self.c_mm;
        let h2 = (ss - diff * diff) * (sum * sum - ss);
        if !(h2 >= T::ZERO) || !(ss > T::ZERO) {
            return Err(if h2.is_finite() && ss.is_finite() {
                KinematicsError::Unreachable
            } else {
                KinematicsError::NonFinite
            });
        }
        let m = self.b_mm * self.b_mm + ss - self.c_mm * self.c_mm;
        let h = self.mode.assembly.sign::<T>() * h2.sqrt();
        let scale = T::ONE / (T::TWO * ss);
        let tool = [
            a[0] + (m * s[0] - h * s[1]) * scale,
            a[1] + (m * s[1] + h * s[0]) * scale,
        ];
        Pose {
            theta_rad,
            elbow_a_mm: a,
            elbow_b_mm: b,
            tool_mm: tool,
            base_a0_mm: a0,
            base_b0_mm: b0,
        }
        .check(self, min_transmission)
    }
}
