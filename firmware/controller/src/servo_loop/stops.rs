//! Faults in the servo loop: latching one ([`ServoLoop::latch`]), the controlled stop of
//! categories 1 and 2 along the path and what follows it (hold, or torque off at standstill),
//! and the safe state (category 0). A fault ends whatever motion was under way, the blend after
//! a calibration switch included: the stop starts from the last accepted setpoint.
use kinematics_core::{ServoFault, StepError};

use super::{Mode, Sample, ServoLoop};
use crate::fault::{Fault, StopCategory};
use crate::stop::StopProfile;

/// A stop under way: its profile and the samples stepped along it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Stop {
    pub(super) profile: StopProfile,
    pub(super) samples: u32,
}

impl<'a> ServoLoop<'a> {
    /// The stop under way or done (`Stopping`, `Holding`, or a safe state a stop led to).
    pub fn stop_profile(&self) -> Option<StopProfile> {
        self.stop.map(|s| s.profile)
    }

    /// Latches `fault` found in this sample; a category-1 or -2 fault starts the stop and steps
    /// its first setpoint now.
    pub(super) fn begin_stop(&mut self, fault: Fault, encoder_rad: [f32; 2], sample: &mut Sample) {
        if fault.stop_category() == StopCategory::Zero {
            return self.latch(fault, sample);
        }
        sample.fault = Some(fault);
        self.plan_stop(fault);
        self.follow_stop(encoder_rad, sample);
    }

    /// `Stopping` from the last accepted setpoint's motion; the blend, if any, is abandoned.
    fn plan_stop(&mut self, fault: Fault) {
        self.mode = Mode::Stopping(fault);
        self.blend = None;
        self.stop = Some(Stop {
            profile: StopProfile::plan(&self.motion, &self.settings.stop.limits),
            samples: 0,
        });
    }

    /// `Stopping` and `Holding`: the stop's next setpoint; at its end, hold (category 2) or
    /// remove torque at standstill (category 1).
    pub(super) fn follow_stop(&mut self, encoder_rad: [f32; 2], sample: &mut Sample) {
        let (Some(mut stop), Some(servo)) = (self.stop, self.servo.as_mut()) else {
            return self.latch(Fault::Servo(ServoFault::NotEngaged), sample);
        };
        stop.samples = stop.samples.saturating_add(1);
        self.stop = Some(stop);
        let dt_s = self.settings.servo.sample_period_s;
        let t_s = stop.samples as f32 * dt_s;
        let setpoint_mm = stop.profile.at(t_s);
        match self.active.step(servo, setpoint_mm, encoder_rad) {
            Ok(out) => self.record(&out, setpoint_mm, sample),
            Err(StepError::Refused(r)) => return self.latch(Fault::StopRefused(r), sample),
            Err(StepError::Fault(f)) => return self.latch(Fault::Servo(f), sample),
        }
        let Mode::Stopping(fault) = self.mode else {
            return;
        };
        if !stop.profile.finished(t_s) {
            return;
        }
        if fault.stop_category() == StopCategory::Two {
            self.mode = Mode::Holding(fault);
            return;
        }
        let s = &self.settings.stop;
        let speed = self.encoders.speed_rad_s(dt_s);
        let still = speed[0].abs() <= s.standstill_rad_s && speed[1].abs() <= s.standstill_rad_s;
        if still || t_s >= stop.profile.duration_s() + s.settle_timeout_s {
            self.enter_safe_state(fault, sample);
        }
    }

    pub(super) fn enter_safe_state(&mut self, fault: Fault, sample: &mut Sample) {
        self.mode = Mode::SafeState(fault);
        self.blend = None;
        sample.torque_nm = [0.0; 2];
        sample.torque_off = true;
    }

    /// Latches `fault` found outside the sample logic (a failed PWM write, a deadline streak;
    /// later: link loss). Category 0: zero torque and drives off in this sample (the caller
    /// disables them, [`Sample::torque_off`]). Category 1 or 2 while running: the stop starts
    /// with the next sample (this sample's torque is already written). A stop already under way
    /// keeps its first fault; in the safe state nothing new is latched.
    pub fn latch(&mut self, fault: Fault, sample: &mut Sample) {
        match self.mode {
            Mode::SafeState(_) | Mode::Unhomed => sample.torque_nm = [0.0; 2],
            // No task-space stop while homing: every fault removes torque (the homing moves
            // are slow, the drives' dynamic braking stops them within a fraction of a degree).
            Mode::Homing => {
                sample.fault = Some(fault);
                self.enter_safe_state(fault, sample);
            }
            _ if fault.stop_category() == StopCategory::Zero => {
                sample.fault = Some(fault);
                self.enter_safe_state(fault, sample);
            }
            Mode::Running => {
                sample.fault = Some(fault);
                self.plan_stop(fault);
            }
            Mode::Stopping(_) | Mode::Holding(_) => {}
        }
    }
}
