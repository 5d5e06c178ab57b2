//! A fully solved pose of the five-bar: motor angles and every joint position.
//!
//! Inverse and forward kinematics both end here, so the singularity margins and the Jacobian
//! are computed from the same vectors whichever way a pose was found, with no extra
//! trigonometry: with `p1 = A - A0`, `q1 = C - A`, `p2 = B - B0`, `q2 = C - B`,
//!
//! * serial transmission of arm 1 = `|sin(θ3 - θ1)| = |p1 × q1| / (a b)` (0 = arm stretched or
//!   folded), likewise arm 2 with `p2 × q2 / (d c)`;
//! * parallel transmission = `|sin(θ4 - θ3)| = |q1 × q2| / (b c)` (0 = distal links aligned);
//!
//! where θ3, θ4 are the directions of the distal links b and c (the paper's Eq. 9).

use crate::model::FiveBar;
use crate::real::Real;

/// 2-D cross product `u × v` (z component).
#[inline]
pub(crate) fn cross<T: Real>(u: [T; 2], v: [T; 2]) -> T {
    u[0] * v[1] - u[1] * v[0]
}

#[inline]
pub(crate) fn sub<T: Real>(u: [T; 2], v: [T; 2]) -> [T; 2] {
    [u[0] - v[0], u[1] - v[1]]
}

/// Motor angles, elbows and tool point of one configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Pose<T> {
    /// Encoder angles of motors 1 and 2.
    pub theta_rad: [T; 2],
    /// Elbow A (end of link a).
    pub elbow_a_mm: [T; 2],
    /// Elbow B (end of link d).
    pub elbow_b_mm: [T; 2],
    /// Tool point C.
    pub tool_mm: [T; 2],
    /// Base joint A0.
    pub base_a0_mm: [T; 2],
    /// Base joint B0.
    pub base_b0_mm: [T; 2],
}

impl<T: Real> Pose<T> {
    /// `|sin|` of the angle between each proximal link and its distal link, in `[0, 1]`.
    pub fn serial_transmission(&self, model: &FiveBar<T>) -> [T; 2] {
        let (p1, q1, p2, q2) = self.link_vectors();
        [
            (cross(p1, q1) / (model.a_mm * model.b_mm)).abs(),
            (cross(p2, q2) / (model.d_mm * model.c_mm)).abs(),
        ]
    }

    /// `|sin|` of the angle between the two distal links, in `[0, 1]`.
    pub fn parallel_transmission(&self, model: &FiveBar<T>) -> T {
        let (_, q1, _, q2) = self.link_vectors();
        (cross(q1, q2) / (model.b_mm * model.c_mm)).abs()
    }

    /// `(A - A0, C - A, B - B0, C - B)`.
    pub(crate) fn link_vectors(&self) -> ([T; 2], [T; 2], [T; 2], [T; 2]) {
        (
            sub(self.elbow_a_mm, self.base_a0_mm),
            sub(self.tool_mm, self.elbow_a_mm),
            sub(self.elbow_b_mm, self.base_b0_mm),
            sub(self.tool_mm, self.elbow_b_mm),
        )
    }

    /// Refuses the pose if a transmission is below `min_transmission` or anything is not finite.
    #[inline(always)]
    pub(crate) fn check(
        self,
        model: &FiveBar<T>,
        min_transmission: T,
    ) -> Result<Self, crate::KinematicsError> {
        use crate::{KinematicsError, Singularity};
        let finite = self
            .theta_rad
            .iter()
            .chain(self.tool_mm.iter())
            .chain(self.elbow_a_mm.iter())
            .chain(self.elbow_b_mm.iter())
            .all(|v| v.is_finite());
        if !finite {
            return Err(KinematicsError::NonFinite);
        }
        // The transmissions compared multiplied out, `|p × q| >= m·|a·b|` for
        // `|p × q| / (a·b) >= m` (no division; the same test for positive lengths).
        // `!(x >= m)` also refuses a NaN margin. The serial transmissions are the caller's
        // business only (FK is well defined with an arm stretched or folded: the tool still
        // moves with the motors, which a simulated plant sweeping through such a pose needs);
        // the parallel one is raised to √ε (below the IK's floor, `FiveBar::inverse_pose`), so
        // FK never returns a point across a parallel singularity it cannot resolve.
        let (p1, q1, p2, q2) = self.link_vectors();
        let serial_1 = cross(p1, q1).abs() >= min_transmission * (model.a_mm * model.b_mm).abs();
        let serial_2 = cross(p2, q2).abs() >= min_transmission * (model.d_mm * model.c_mm).abs();
        if !(serial_1 && serial_2) {
            return Err(KinematicsError::NearSingularity(Singularity::Serial));
        }
        let min_transmission =
            crate::real::effective_margin(min_transmission, T::FK_MIN_TRANSMISSION);
        if !(cross(q1, q2).abs() >= min_transmission * (model.b_mm * model.c_mm).abs()) {
            return Err(KinematicsError::NearSingularity(Singularity::Parallel));
        }
        Ok(self)
    }
}
