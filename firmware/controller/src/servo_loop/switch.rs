//! Switching to a newly committed calibration (`calibration_slots`), without a jump.
//!
//! The app hands the servo loop a committed calibration ([`ServoLoop::offer_calibration`]); it
//! stays pending until [`ServoLoop::switch_pending`] finds the machine where a switch cannot
//! move it by surprise:
//! * running at rest (between moves, nothing queued moving, no blend under way): the new
//!   calibration is engaged at the current reading (the reference is the reading: no torque
//!   step), and where it puts the tool is compared with the stream's position, where the old
//!   one held it. That difference, the two calibrations' disagreement at this pose, is the
//!   only motion a switch makes: a jerk-limited straight move back to the stream's position at
//!   [`SwitchSettings`](crate::settings::SwitchSettings)' speed and acceleration (the blend,
//!   stepped before the queue is read again). A difference beyond
//!   `SwitchSettings::max_move_mm` refuses the switch ([`SwitchRefused::TooFar`]): the old
//!   calibration stays in force;
//! * unhomed or in the safe state (drives off): the calibration is replaced; the next engage
//!   (homing, a reset) uses it;
//! * moving, homing, stopping or holding after a fault: it stays pending (a running machine
//!   comes to rest between moves; a held one after its reset).
//!
//! A new calibration that would not engage at the machine's pose is refused
//! ([`SwitchRefused::Engage`]) before anything changes: [`ActiveCalibration::tool_mm`] tells
//! where it would engage without touching the servo, so there is nothing to roll back.
use kinematics_core::path::Line;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, EngageError, PathMotion, TaskLimits};

use super::{ActiveCalibration, Mode, ServoLoop};
use crate::calibration_slots::CalibrationId;

/// A jerk-limited straight move the loop steps by itself (after a calibration switch).
#[derive(Clone, Copy, Debug)]
pub struct Blend {
    motion: PathMotion<f32, Line<f32>>,
    t_s: f32,
}

impl Blend {
    /// A blend along `motion` from its start (tests put the loop in any state).
    #[cfg(test)]
    pub(super) fn for_test(motion: PathMotion<f32, Line<f32>>) -> Self {
        Blend { motion, t_s: 0.0 }
    }
}

/// Why a committed calibration was not switched to (now).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchRefused {
    /// The machine moves, homes, stops or holds after a fault: it stays pending, tried again
    /// at the next sample.
    NotAtRest,
    /// The new calibration cannot engage at the machine's pose (its kinematics refuse it): the
    /// old one stays.
    Engage(EngageError),
    /// The new calibration puts the tool this far (mm) from where the old one holds it, more
    /// than `SwitchSettings::max_move_mm`: the old one stays.
    TooFar {
        /// The distance (mm).
        distance_mm: f32,
        /// The bound (mm).
        max_mm: f32,
    },
    /// The blend back to the stream's position could not be planned: the old one stays.
    Blend,
}

/// What became of a committed calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchOutcome {
    /// In force from this sample on.
    Switched(CalibrationId),
    /// Refused: the old calibration stays in force.
    Refused(CalibrationId, SwitchRefused),
}

/// Below this (mm) a switch's difference needs no blend: the servo's history starts there and
/// the next setpoint is within a sample's jump limit of it.
const NO_BLEND_BELOW_MM: f32 = 1.0e-4;

impl<'a> ServoLoop<'a> {
    /// A newly committed calibration for the servo to switch to at the next rest (a newer one
    /// replaces one still pending).
    pub fn offer_calibration(&mut self, calibration: Calibration<'a>, id: CalibrationId) {
        self.pending = Some((calibration, id));
    }

    /// The committed calibration waiting for the next rest, if any.
    pub fn pending_calibration(&self) -> Option<CalibrationId> {
        self.pending.map(|(_, id)| id)
    }

    /// Whether a blend after a switch is under way.
    pub fn blending(&self) -> bool {
        self.blend.is_some()
    }

    /// Tries the pending calibration at the machine's reading `encoder_rad` (module doc):
    /// `None` while nothing is pending or the machine is not at rest.
    pub fn switch_pending(&mut self, encoder_rad: [f32; 2]) -> Option<SwitchOutcome> {
        let (calibration, id) = self.pending?;
        match self.switch_calibration(calibration, encoder_rad) {
            Err(SwitchRefused::NotAtRest) => None,
            Ok(()) => {
                self.pending = None;
                Some(SwitchOutcome::Switched(id))
            }
            Err(e) => {
                self.pending = None;
                Some(SwitchOutcome::Refused(id, e))
            }
        }
    }

    /// Switches to `calibration` now if the machine allows it (module doc); `NotAtRest`: keep
    /// it and try again.
    pub fn switch_calibration(
        &mut self,
        calibration: Calibration<'a>,
        encoder_rad: [f32; 2],
    ) -> Result<(), SwitchRefused> {
        let at_rest = self.mode == Mode::Running && self.motion.is_at_rest() && !self.blending();
        if !(at_rest || matches!(self.mode, Mode::Unhomed | Mode::SafeState(_))) {
            return Err(SwitchRefused::NotAtRest);
        }
        let next = ActiveCalibration::new(calibration, self.settings);
        if at_rest {
            self.switch_at_rest(&next, encoder_rad)?;
        }
        self.active = next;
        Ok(())
    }

    /// Engages `next` at the reading and plans the blend back to the stream's position; the
    /// servo is touched only once every check has passed.
    fn switch_at_rest(
        &mut self,
        next: &ActiveCalibration<'a>,
        encoder_rad: [f32; 2],
    ) -> Result<(), SwitchRefused> {
        let tool_mm = next.tool_mm(encoder_rad).map_err(SwitchRefused::Engage)?;
        let held_mm = self.motion.position_mm;
        let distance_mm = libm::hypotf(held_mm[0] - tool_mm[0], held_mm[1] - tool_mm[1]);
        let max_mm = self.settings.switch.max_move_mm;
        if !(distance_mm <= max_mm) {
            return Err(SwitchRefused::TooFar {
                distance_mm,
                max_mm,
            });
        }
        let s = &self.settings.switch;
        let limits = TaskLimits {
            speed_mm_s: s.speed_mm_s,
            accel_mm_s2: s.accel_mm_s2,
            jerk_mm_s3: self.settings.stop.limits.jerk_mm_s3,
        };
        let blend = match PathMotion::line(tool_mm, held_mm, &limits) {
            Ok(motion) => Some(Blend { motion, t_s: 0.0 }),
            Err(_) if distance_mm < NO_BLEND_BELOW_MM => None,
            Err(_) => return Err(SwitchRefused::Blend),
        };
        let Some(servo) = self.servo.as_mut() else {
            return Err(SwitchRefused::NotAtRest);
        };
        let engaged = next
            .engage(servo, encoder_rad)
            .map_err(SwitchRefused::Engage)?;
        self.blend = blend;
        self.setpoint_mm = engaged;
        self.reference_rad = encoder_rad;
        Ok(())
    }

    /// The blend's next setpoint, while one is under way.
    pub(super) fn next_blend_setpoint(&mut self) -> Option<MotionSetpoint<f32>> {
        let blend = self.blend.as_mut()?;
        blend.t_s += self.settings.servo.sample_period_s;
        let setpoint = blend.motion.at(blend.t_s);
        if blend.t_s >= blend.motion.duration_s() {
            self.blend = None;
        }
        Some(setpoint)
    }
}
