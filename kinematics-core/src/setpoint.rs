//! One sample of a tool motion: position and its exact first three derivatives, what a path
//! ([`crate::path`]) evaluates to and what the servo's motion step takes
//! ([`crate::trajectory`] plans them). Cost: a copy of eight numbers.

use crate::real::Real;

/// Where the tool should be, and its exact derivatives, at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionSetpoint<T> {
    /// Position (mm).
    pub position_mm: [T; 2],
    /// Velocity (mm/s).
    pub velocity_mm_s: [T; 2],
    /// Acceleration (mm/s²).
    pub acceleration_mm_s2: [T; 2],
    /// Jerk (mm/s³).
    pub jerk_mm_s3: [T; 2],
}

impl<T: Real> MotionSetpoint<T> {
    /// At rest at `position_mm`.
    pub fn at_rest(position_mm: [T; 2]) -> Self {
        MotionSetpoint {
            position_mm,
            velocity_mm_s: [T::ZERO; 2],
            acceleration_mm_s2: [T::ZERO; 2],
            jerk_mm_s3: [T::ZERO; 2],
        }
    }

    /// Every number finite.
    pub fn is_finite(&self) -> bool {
        [
            self.position_mm,
            self.velocity_mm_s,
            self.acceleration_mm_s2,
            self.jerk_mm_s3,
        ]
        .iter()
        .flatten()
        .all(|v| v.is_finite())
    }
}
