//! Homing in the servo loop: from `Unhomed` ([`ServoLoop::start_homing`]) through the index
//! search and the reference ([`ServoLoop::step_homing`], [`ServoLoop::referenced`]) to the
//! servo engaged at home, in joint space (the procedure itself is [`crate::homing`]).
use kinematics_core::ServoFault;

use super::{Mode, Sample, ServoLoop};
use crate::encoder_check::EncoderCheck;
use crate::fault::Fault;
use crate::homing::{Homing, HomingEvent, HomingFault, HomingPhase};
use crate::stop::MotionState;

/// The board's index capture, as homing needs it: the readings at index pulses since the last
/// call, and the reference that ties each axis's count at its index to a joint angle.
pub trait IndexCapture {
    /// The encoder reading (rad) at an index pulse captured since the last call, per axis.
    fn index_rad(&mut self) -> [Option<f32>; 2];
    /// Ties each axis's count at its captured index to `index_rad` (both or neither);
    /// `false` if an axis has no capture or its scale refused.
    fn reference_at_index(&mut self, index_rad: [f32; 2]) -> bool;
}

impl<'a> ServoLoop<'a> {
    /// Where homing is (`None`: not started, or the encoders are absolute).
    pub fn homing_phase(&self) -> Option<HomingPhase> {
        self.homing.map(|h| h.phase())
    }

    /// Starts homing from `Unhomed` (the host's Home command, or the boot with
    /// `HomingSettings::at_boot`), at the machine's reading `encoder_rad`. The caller enables the
    /// drives when this returns `Ok`. Refused in any other mode (a latched fault needs a reset;
    /// a homed machine is not re-homed), and when the homing settings are refused: then
    /// `Fault::Homing(Plan)` is latched and the machine stays off. Cheap enough for the servo
    /// task: the plan's kinematic check ran at boot.
    pub fn start_homing(&mut self, encoder_rad: [f32; 2]) -> Result<(), Mode> {
        if self.mode != Mode::Unhomed {
            return Err(self.mode);
        }
        match Homing::start(&self.settings.homing, encoder_rad) {
            Ok(h) => {
                self.homing = Some(h);
                self.encoders = EncoderCheck::new(encoder_rad, self.encoders.count_rad());
                self.last_torque_nm = [0.0; 2];
                self.reference_rad = encoder_rad;
                self.blend = None;
                self.mode = Mode::Homing;
                Ok(())
            }
            Err(f) => {
                self.mode = Mode::SafeState(Fault::Homing(f));
                Err(self.mode)
            }
        }
    }

    /// A homing sample with the board's index capture: [`ServoLoop::step_homing`], and the
    /// reference once both indexes are found ([`ServoLoop::referenced`]).
    pub fn homing_sample(
        &mut self,
        encoder_rad: [f32; 2],
        index: &mut impl IndexCapture,
    ) -> Sample {
        let mut sample = self.step_homing(encoder_rad, index.index_rad());
        if sample.set_reference {
            let ok = index.reference_at_index(self.settings.homing.index_rad);
            self.referenced(ok, &mut sample);
        }
        sample
    }

    /// One homing sample (mode `Homing`): the encoder check, then the homing procedure's
    /// joint-space step with `index_rad` the readings at index pulses latched since the last
    /// sample. At home the task-space servo engages and the mode becomes `Running`; a homing
    /// fault stops: category 0 at once, category 1 (the search came to rest) torque off.
    pub fn step_homing(&mut self, encoder_rad: [f32; 2], index_rad: [Option<f32>; 2]) -> Sample {
        let mut sample = self.begin_sample(encoder_rad);
        let (Mode::Homing, Some(mut homing)) = (self.mode, self.homing) else {
            return sample;
        };
        let dt_s = self.settings.servo.sample_period_s;
        if let Err(f) = self.encoders.check(
            encoder_rad,
            self.last_torque_nm,
            &self.settings.encoder_limits,
            dt_s,
        ) {
            self.latch(Fault::Encoder(f), &mut sample);
            return sample;
        }
        let out = homing.step(encoder_rad, index_rad, &self.settings.servo.axes, dt_s);
        self.homing = Some(homing);
        sample.torque_nm = out.torque_nm;
        sample.reference_rad = out.reference_rad;
        sample.following_error_rad = out.following_error_rad;
        self.reference_rad = out.reference_rad;
        match out.event {
            None => {}
            Some(HomingEvent::Reference { offset_rad }) => {
                self.pending_offset_rad = offset_rad;
                sample.set_reference = true;
            }
            Some(HomingEvent::Done) => self.engage_at_home(encoder_rad, &mut sample),
            Some(HomingEvent::Failed(f)) => self.homing_failed(f, &mut sample),
        }
        self.last_torque_nm = sample.torque_nm;
        sample
    }

    /// The outcome of the reference [`Sample::set_reference`] asked for (`ok`: the board's scale
    /// took it). Readings are absolute from the next sample on; the move to home starts.
    pub fn referenced(&mut self, ok: bool, sample: &mut Sample) {
        let (Mode::Homing, Some(mut homing)) = (self.mode, self.homing) else {
            return;
        };
        let offset = self.pending_offset_rad;
        let home = if ok {
            self.active
                .calibration()
                .command_rad(
                    self.settings.home_mm(),
                    self.settings.servo.min_transmission,
                )
                .map_err(|_| HomingFault::Reference)
        } else {
            Err(HomingFault::Reference)
        };
        let result = homing.referenced(offset, home);
        self.homing = Some(homing);
        match result {
            Ok(()) => {
                self.encoders.shift(offset);
                self.reference_rad = [
                    self.reference_rad[0] + offset[0],
                    self.reference_rad[1] + offset[1],
                ];
            }
            Err(f) => self.homing_failed(f, sample),
        }
    }

    fn engage_at_home(&mut self, encoder_rad: [f32; 2], sample: &mut Sample) {
        let Some(servo) = self.servo.as_mut() else {
            return self.latch(Fault::Servo(ServoFault::NotEngaged), sample);
        };
        match self.active.engage(servo, encoder_rad) {
            Ok(tool_mm) => {
                self.mode = Mode::Running;
                self.setpoint_mm = tool_mm;
                self.motion = MotionState::at_rest(tool_mm);
                self.reference_rad = encoder_rad;
                sample.setpoint_mm = tool_mm;
            }
            Err(e) => self.latch(Fault::Engage(e), sample),
        }
    }

    /// A homing fault: category 0 removes torque at once; category 1 (the search has come to
    /// rest at the end of its profile) removes it now too, the machine standing.
    fn homing_failed(&mut self, f: HomingFault, sample: &mut Sample) {
        sample.fault = Some(Fault::Homing(f));
        self.enter_safe_state(Fault::Homing(f), sample);
    }

    /// Homing's phase reached home.
    pub(super) fn homed(&self) -> bool {
        self.settings.homing.absolute_encoders || self.homing_phase() == Some(HomingPhase::Done)
    }
}
