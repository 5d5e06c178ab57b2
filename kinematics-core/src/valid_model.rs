//! A five-bar checked once, and an IK margin raised to its floor once: what the servo's IK
//! needs per sample without repeating the checks.
//!
//! [`FiveBar::inverse`] refuses, on every call, a model whose links are not all positive
//! ([`KinematicsError::InvalidModel`]) and raises the caller's margin to
//! [`Real::IK_MIN_TRANSMISSION`]: a dozen instructions of the IK on the Cortex-M4F, for facts
//! that do not change between the 2 kHz samples. Here both move to construction time:
//!
//! * [`ValidFiveBar::new`] runs [`FiveBar::validate`] (every parameter finite, every link
//!   positive, a superset of the per-call test): a `ValidFiveBar` cannot hold an invalid
//!   model, its field is private and it has no other constructor (a parsed grid image holds
//!   one: [`crate::CorrectionGrid::valid_model`]);
//! * [`IkMargin::new`] applies the floor once.
//!
//! [`ValidFiveBar::inverse`] is then the same closed form and the same checks on the target
//! (finite, reach, assembly side, finite results, serial and parallel margins) in the same
//! order of floating-point operations: its angles are bit-identical to `FiveBar::inverse`'s
//! (`tests/valid_model.rs`). Cost: `BENCH ik_f32_valid` against `BENCH ik_f32`
//! (`cargo qemu-bench`).

use crate::joint_motion::JointMotion;
use crate::model::{FiveBar, ModelError};
use crate::real::{effective_margin, Real};
use crate::KinematicsError;

/// A [`FiveBar`] that passed [`FiveBar::validate`]: every parameter finite, every link
/// positive. Built only by [`ValidFiveBar::new`] (or by parsing a grid image, which validates
/// its model the same way).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValidFiveBar<T>(FiveBar<T>);

/// The smallest `|sin|` of the transmission angles the IK accepts, already raised to
/// [`Real::IK_MIN_TRANSMISSION`] (see [`FiveBar::inverse_pose`] for its meaning). A NaN margin
/// stays NaN and refuses every pose, as it does in `FiveBar::inverse`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct IkMargin<T>(T);

impl<T: Real> IkMargin<T> {
    /// `min_transmission` raised to the IK's floor (0 or a negative margin gives the floor).
    pub fn new(min_transmission: T) -> Self {
        IkMargin(effective_margin(min_transmission, T::IK_MIN_TRANSMISSION))
    }

    /// The margin applied (at least the floor, or NaN).
    pub fn get(self) -> T {
        self.0
    }
}

impl<T: Real> ValidFiveBar<T> {
    /// `model` if [`FiveBar::validate`] accepts it, else its reason.
    pub fn new(model: FiveBar<T>) -> Result<Self, ModelError> {
        model.validate()?;
        Ok(ValidFiveBar(model))
    }

    /// For a model already validated by the caller in this crate (the grid image's parser).
    pub(crate) fn from_validated(model: FiveBar<T>) -> Self {
        ValidFiveBar(model)
    }

    /// The model.
    pub fn model(&self) -> &FiveBar<T> {
        &self.0
    }

    /// [`FiveBar::inverse`] without the per-call model check and margin floor (done when
    /// `self` and `margin` were built): the same angles, bit for bit, and the same errors
    /// for every target ([`KinematicsError::InvalidModel`] cannot occur).
    #[inline]
    pub fn inverse(&self, tool_mm: [T; 2], margin: IkMargin<T>) -> Result<[T; 2], KinematicsError> {
        self.0
            .solve_inverse_valid(tool_mm, margin.0)
            .map(|s| [s.arm_1.theta_rad, s.arm_2.theta_rad])
    }

    /// [`ValidFiveBar::inverse`] for a target the caller has proven finite (the servo's jump
    /// check does: a setpoint whose speed from the last, finite, setpoint is below a finite
    /// limit is finite). Without the target's finiteness test, not without its effect: a
    /// non-finite target still never passes, it makes `ρ²` infinite or NaN and is refused by
    /// the reach test, as [`KinematicsError::Unreachable`] instead of `NonFinite`.
    #[inline(always)]
    pub(crate) fn inverse_of_finite(
        &self,
        tool_mm: [T; 2],
        margin: IkMargin<T>,
    ) -> Result<[T; 2], KinematicsError> {
        self.0
            .solve_checked(tool_mm, margin.0)
            .map(|s| [s.arm_1.theta_rad, s.arm_2.theta_rad])
    }

    /// [`FiveBar::inverse_rates`] without the per-call model check and margin floor.
    #[inline]
    pub fn inverse_rates(
        &self,
        tool_mm: [T; 2],
        velocity_mm_s: [T; 2],
        margin: IkMargin<T>,
    ) -> Result<JointMotion<T>, KinematicsError> {
        let s = self.0.solve_inverse_valid(tool_mm, margin.0)?;
        crate::joint_motion::motion_of_solved(&s, velocity_mm_s, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The servo's IK without the target's finiteness test still refuses every non-finite or
    /// overflowing target (as `Unreachable`: `ρ²` is infinite or NaN), and answers a finite
    /// one exactly as `inverse` does.
    #[test]
    fn a_non_finite_target_never_passes_without_the_finiteness_test() {
        let mut offset = FiveBar::<f32>::paper_nominal();
        offset.base_a0_mm = [-0.61, 0.27];
        offset.encoder_offset_rad = [0.004, -0.007];
        for model in [FiveBar::<f32>::paper_nominal(), offset] {
            let Ok(v) = ValidFiveBar::new(model) else {
                panic!("a valid model")
            };
            for margin in [
                IkMargin::new(0.0),
                IkMargin::new(0.05),
                IkMargin::new(f32::NAN),
            ] {
                for p in [
                    [f32::NAN, 0.0],
                    [0.0, f32::NAN],
                    [f32::INFINITY, 0.0],
                    [f32::NEG_INFINITY, 1.0],
                    [0.0, f32::INFINITY],
                    [f32::INFINITY, f32::NEG_INFINITY],
                    [f32::NAN, f32::INFINITY],
                    [1e30, 0.0],
                    [f32::MAX, f32::MAX],
                ] {
                    assert_eq!(
                        v.inverse_of_finite(p, margin),
                        Err(KinematicsError::Unreachable),
                        "{p:?}"
                    );
                    assert!(v.inverse(p, margin).is_err());
                }
                for p in [[212.132, 0.0], [250.0, 40.0], [180.0, -60.0]] {
                    assert_eq!(
                        v.inverse_of_finite(p, margin),
                        v.inverse(p, margin),
                        "{p:?}"
                    );
                }
            }
        }
    }
}
