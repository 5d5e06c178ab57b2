//! The five-bar's Jacobian `J = ∂C/∂θ` and its inverse, from a solved [`Pose`].
//!
//! Differentiating the loop constraint `|C - A|² = b²` with `dA = dθ1 · (A - A0)⊥` gives
//! `q1·dC = (p1 × q1) dθ1`, with `p1 = A - A0`, `q1 = C - A` (likewise arm 2). Hence
//!
//! ```text
//! J⁻¹ = [ q1ᵀ / (p1 × q1) ]        J = 1/(q1 × q2) · [  (p1×q1)·q2_y   -(p2×q2)·q1_y ]
//!       [ q2ᵀ / (p2 × q2) ]                          [ -(p1×q1)·q2_x    (p2×q2)·q1_x ]
//! ```
//!
//! In angles, row 1 of `J⁻¹` is `(cos θ3, sin θ3) / (a·sin(θ3 - θ1))`: the paper's Eq. 8 with
//! the *proximal* link `a` in the denominator (the paper prints `b`, and `e` for arm 2, where
//! `d` is right). The tests check both matrices against central finite differences on machines
//! with unequal links, a base offset and encoder offsets.
//!
//! Cost: from a solved pose, three cross products and four (J⁻¹) or five (J) divisions; no
//! trigonometry.
//!
//! ```
//! use kinematics_core::jacobian::mat2_mul_vec;
//! use kinematics_core::FiveBar;
//!
//! let m = FiveBar::<f64>::paper_nominal();
//! let pose = m.inverse_pose([200.0, 30.0], 0.05).unwrap();
//! let (j, j_inv) = (pose.jacobian().unwrap(), pose.inverse_jacobian().unwrap());
//! // A small joint step moves the tool by J·dθ, and J⁻¹ maps it back.
//! let dtheta = [1e-6, -2e-6];
//! let dc = mat2_mul_vec(&j, dtheta);
//! let theta = m.inverse([200.0 + dc[0], 30.0 + dc[1]], 0.05).unwrap();
//! assert!((theta[0] - pose.theta_rad[0] - dtheta[0]).abs() < 1e-10);
//! assert!((theta[1] - pose.theta_rad[1] - dtheta[1]).abs() < 1e-10);
//! let back = mat2_mul_vec(&j_inv, dc);
//! assert!((back[0] - dtheta[0]).abs() < 1e-15 && (back[1] - dtheta[1]).abs() < 1e-15);
//! ```

use crate::pose::{cross, Pose};
use crate::real::Real;
use crate::{KinematicsError, Singularity};

/// A 2x2 matrix, row-major: `m[row][col]`.
pub type Mat2<T> = [[T; 2]; 2];

/// Multiplies a 2x2 matrix by a vector.
pub fn mat2_mul_vec<T: Real>(m: &Mat2<T>, v: [T; 2]) -> [T; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

impl<T: Real> Pose<T> {
    /// `J⁻¹ = ∂θ/∂C` (rad/mm). Fails exactly at a serial singularity.
    pub fn inverse_jacobian(&self) -> Result<Mat2<T>, KinematicsError> {
        let (p1, q1, p2, q2) = self.link_vectors();
        let k1 = cross(p1, q1);
        let k2 = cross(p2, q2);
        if k1 == T::ZERO || k2 == T::ZERO {
            return Err(KinematicsError::NearSingularity(Singularity::Serial));
        }
        finite([[q1[0] / k1, q1[1] / k1], [q2[0] / k2, q2[1] / k2]])
    }

    /// `J = ∂C/∂θ` (mm/rad). Fails exactly at a parallel singularity.
    pub fn jacobian(&self) -> Result<Mat2<T>, KinematicsError> {
        let (p1, q1, p2, q2) = self.link_vectors();
        let k1 = cross(p1, q1);
        let k2 = cross(p2, q2);
        let det = cross(q1, q2);
        if det == T::ZERO {
            return Err(KinematicsError::NearSingularity(Singularity::Parallel));
        }
        finite([
            [k1 * q2[1] / det, -k2 * q1[1] / det],
            [-k1 * q2[0] / det, k2 * q1[0] / det],
        ])
    }
}

fn finite<T: Real>(m: Mat2<T>) -> Result<Mat2<T>, KinematicsError> {
    if m.iter().flatten().all(|v| v.is_finite()) {
        Ok(m)
    } else {
        Err(KinematicsError::NonFinite)
    }
}
