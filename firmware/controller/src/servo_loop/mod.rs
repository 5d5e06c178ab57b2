//! One servo sample, without hardware: the mode machine, setpoint intake with underrun
//! handling, the encoder check, the workspace check, the controlled stop, and what torque and
//! drive enable result.
//!
//! ```text
//!  boot ── settings valid, image valid (or uncorrected allowed), engage accepted ──► Running
//!    │      (absolute encoders only: with incremental ones the zero is unknown)
//!    ├──── incremental encoders, image valid ──► Unhomed ── start_homing ──► Homing
//!    │                                       Homing ── at home, engage accepted ──► Running
//!    │                                       Homing ── homing fault ──► SafeState
//!    └──── otherwise ───────────────────────────────────────────────────────────────► SafeState
//!  Running ──── category 1 or 2 fault ──► Stopping ── profile done ── cat. 2 ──► Holding
//!     │                                     │                    └── cat. 1, standstill ──► SafeState
//!     └──── category 0 fault ─────────────────────────────────────────────────────────► SafeState
//!  Stopping, Holding ── category 0 fault ──────────────────────────────────────────► SafeState
//!  boot after a watchdog reset, watchdog not started ([`ServoLoop::latch_at_boot`]) ──► SafeState
//!  Holding, SafeState ── reset ──► Running (re-engaged where the machine is)
//!  SafeState ── reset, never homed (incremental encoders) ──► Unhomed (drives stay off; Home again)
//! ```
//! Every mode but `SafeState` and `Unhomed` has the drives on. `Unhomed` refuses every setpoint
//! (the queue is left alone, zero torque, drives off): **the drives never engage on an unhomed
//! machine for normal motion**. `Homing` runs [`crate::homing`] through
//! [`ServoLoop::step_homing`], in joint space, instead of the setpoint stream. `Holding` keeps
//! the servo on the stop's end point (the fault stays latched); `SafeState` is zero torque,
//! drive enable off, the queue left alone. Only a reset leaves `Holding` or `SafeState`. Stop
//! categories and the table of faults: [`crate::fault`].
//!
//! The loop's parts, one job each:
//! * this module: the state, the boot, one sample while running (the setpoint stream);
//! * [`active`]: the calibration in force ([`ActiveCalibration`]: the image's model checked
//!   once, its dynamics, its workspace and its backlash, built by one constructor and engaged
//!   as one);
//! * [`switch`]: switching to a newly committed calibration at rest, and the blend after it;
//! * [`homing_step`]: homing, until the servo engages at home;
//! * [`stops`]: faults, the controlled stop and the safe state;
//! * [`requests`]: the host's requests (stop, disable, reset, home); what a reset clears in each
//!   mode is the table of [`requests`].
//!
//! A sample while the drives are on:
//! 1. the encoder check ([`crate::encoder_check`]) with the torque that acted since the last
//!    reading: a finding is category 0;
//! 2. `Running`: the blend after a calibration switch if one is under way, else the next
//!    setpoint from the queue, with its exact derivatives and the one after it as the
//!    feed-forward's look-ahead (an empty queue holds the last setpoint if the machine is at
//!    rest, or is [`Fault::Underrun`] if it moves), [`Servo::accept_motion`] (the identified
//!    dynamics the image carries fed forward, the model checked once); a refusal is
//!    [`Fault::Setpoint`]; an accepted setpoint whose stop would end outside the workspace
//!    ([`Workspace`], the image's workspace polygon or the grid's rectangle, less a margin) is
//!    dropped and is [`Fault::StopOutsideWorkspace`]; otherwise it is tracked;
//!    `Stopping` / `Holding`: the stop profile's next setpoint is stepped;
//! 3. a category-1 or -2 fault found in step 2 starts the stop **in the same sample**, from the
//!    last accepted setpoint (whose stop the workspace check accepted), so the torque of this
//!    sample already brakes; a servo fault (following error, non-finite encoder) or a refused
//!    stop setpoint is category 0.
//!
//! The board-facing part of a sample is in the app (`firmware/src/main.rs`, `servo_tick`):
//! read encoders, [`ServoLoop::tick`] (the posted request, a committed calibration, the step or
//! the homing step), write the torques (a failed write is [`ServoLoop::latch`]ed as
//! [`Fault::Drive`]), [`ServoLoop::record_deadline`], disable the drives if the sample says so
//! ([`Sample::torque_off`]), publish the [`Status`](crate::status::Status), and last feed the
//! watchdog if [`Sample::feed_watchdog`] (the step was on time; see [`crate::watchdog`]).
//!
//! A motor never jumps: the servo refuses a setpoint it cannot follow, it never clamps one into
//! reach; a stop never steps the velocity; torque is removed only in category 0 (at once) or
//! after a category-1 stop has reached standstill.
use heapless::spsc::Consumer;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, Servo, ServoOutput};

use crate::calibration::CalibrationState;
use crate::calibration_slots::CalibrationId;
use crate::deadline::Deadline;
use crate::encoder::EncoderScale;
use crate::encoder_check::EncoderCheck;
use crate::fault::Fault;
use crate::homing::{self, Homing};
use crate::setpoints::REFILL_BELOW;
use crate::settings::{Settings, SettingsError};
use crate::stop::MotionState;
use crate::watchdog;

pub mod active;
pub mod homing_step;
pub mod requests;
pub mod stops;
pub mod switch;

pub use active::ActiveCalibration;
pub use homing_step::IndexCapture;
pub use requests::{ResetRefusal, ServoRequest};
pub use switch::{Blend, SwitchOutcome, SwitchRefused};

use stops::Stop;

/// Where the servo is.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Drives enabled, following the setpoint stream.
    Running,
    /// Drives enabled, braking along the path after a category-1 or -2 fault.
    Stopping(Fault),
    /// Drives enabled, holding the stop's end point after a category-2 fault (latched).
    Holding(Fault),
    /// Drives disabled, zero torque: a category-0 fault, a category-1 stop done, or a fault at
    /// boot.
    SafeState(Fault),
    /// Incremental encoders not referenced yet: drives disabled, every setpoint refused, until
    /// [`ServoLoop::start_homing`].
    Unhomed,
    /// Drives enabled, homing ([`ServoLoop::step_homing`]).
    Homing,
}

impl Mode {
    /// Whether the drives are on in this mode: all but the safe state and `Unhomed`.
    pub fn drives_on(&self) -> bool {
        !matches!(self, Mode::SafeState(_) | Mode::Unhomed)
    }

    /// The latched fault, if any.
    pub fn fault(&self) -> Option<Fault> {
        match *self {
            Mode::Running | Mode::Unhomed | Mode::Homing => None,
            Mode::Stopping(f) | Mode::Holding(f) | Mode::SafeState(f) => Some(f),
        }
    }
}

/// What one sample decided, and what it saw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Index of the sample since the timer started (0 is the first).
    pub index: u32,
    /// The encoder angles it was given (rad).
    pub encoder_rad: [f32; 2],
    /// The last setpoint the servo accepted (mm): this sample's, an earlier one after an
    /// underrun at rest or in the safe state, or the stop's.
    pub setpoint_mm: [f32; 2],
    /// The encoder angles commanded for [`Sample::setpoint_mm`] (rad).
    pub reference_rad: [f32; 2],
    /// Torques to write (N·m): zero in the safe state and in the sample that entered it.
    pub torque_nm: [f32; 2],
    /// Largest |following error| of the two axes this sample (rad; 0 when not stepping).
    pub following_error_rad: f32,
    /// The queue was empty.
    pub underrun: bool,
    /// Fewer than [`REFILL_BELOW`] setpoints are left: the intake should refill the queue.
    pub refill: bool,
    /// The fault this sample latched: the first one, or a category-0 fault ending a stop.
    pub fault: Option<Fault>,
    /// This sample entered the safe state: disable the drives now.
    pub torque_off: bool,
    /// Homing found both indexes (the machine at rest): the app ties each axis's reading at its
    /// index to `HomingSettings::index_rad` (the board's `EncoderScale::set_reference`) and
    /// reports the outcome with [`ServoLoop::referenced`] in the same sample.
    pub set_reference: bool,
    /// The step completed on time: the servo task feeds the independent watchdog at its end.
    /// Set only by [`ServoLoop::record_deadline`] (a sample whose deadline was not recorded
    /// does not feed); in the safe state too (drives off is not a stall).
    pub feed_watchdog: bool,
}

/// What [`ServoLoop::tick`] decided besides the sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tick {
    /// The sample.
    pub sample: Sample,
    /// The drives were off and must be enabled now (a reset re-engaged, homing started).
    pub enable_drives: bool,
    /// A committed calibration was switched to, or refused, in this sample.
    pub switch: Option<SwitchOutcome>,
}

/// The servo loop's state from one sample to the next.
#[derive(Clone, Debug)]
pub struct ServoLoop<'a> {
    settings: &'a Settings,
    /// The calibration in force, with everything derived from it.
    active: ActiveCalibration<'a>,
    /// A committed calibration waiting for the next rest ([`ServoLoop::offer_calibration`]).
    pending: Option<(Calibration<'a>, CalibrationId)>,
    /// `None` only when the settings were refused at boot (then the mode is `SafeState`).
    servo: Option<Servo>,
    mode: Mode,
    deadline: Deadline,
    encoders: EncoderCheck,
    /// The last accepted setpoint's motion: where a stop starts.
    motion: MotionState,
    stop: Option<Stop>,
    setpoint_mm: [f32; 2],
    reference_rad: [f32; 2],
    /// The torque written in the last sample: it acts until the next reading.
    last_torque_nm: [f32; 2],
    samples: u32,
    /// One count of each axis's encoder (rad): the encoder check's quantisation.
    count_rad: [f32; 2],
    /// The homing procedure, from `start_homing` until the servo engages at home.
    homing: Option<Homing>,
    /// The offset of the reference homing asked for, until `referenced`.
    pending_offset_rad: [f32; 2],
    /// After a calibration switch at rest: the short move from where the new calibration puts
    /// the tool back to the stream's position, stepped before the queue is read again.
    blend: Option<Blend>,
}

impl<'a> ServoLoop<'a> {
    /// Boots the loop: validates the settings and engages the servo at the machine's actual
    /// position (`encoder_rad`) unless the settings or the calibration forbid it.
    /// [`ServoLoop::mode`] tells the outcome: `Running` (enable the drives) or `SafeState` with
    /// the reason.
    pub fn boot(
        settings: &'a Settings,
        calibration: Calibration<'a>,
        state: CalibrationState,
        encoder_rad: [f32; 2],
    ) -> Self {
        let active = ActiveCalibration::new(calibration, settings);
        let servo = settings
            .validate()
            .and_then(|()| Servo::new(settings.servo).map_err(SettingsError::Servo));
        let (servo, engaged) = match servo {
            Err(e) => (None, Err(Fault::Settings(e))),
            Ok(mut servo) => {
                let engaged = match state {
                    CalibrationState::Refused(e) => Err(Fault::Calibration(e)),
                    // Incremental encoders: the zero is not known, nothing to engage at.
                    CalibrationState::Valid | CalibrationState::Uncorrected(_)
                        if !settings.homing.absolute_encoders =>
                    {
                        Ok(None)
                    }
                    CalibrationState::Valid | CalibrationState::Uncorrected(_) => active
                        .engage(&mut servo, encoder_rad)
                        .map(Some)
                        .map_err(Fault::Engage),
                };
                (Some(servo), engaged)
            }
        };
        let engaged = match (engaged, active.homing_rectangle_mm()) {
            // Homing's sweeps checked against the singularities once, here (hundreds of
            // thousands of instructions: not in a servo sample), from every start in the
            // calibrated rectangle (the machine may be anywhere the grid covers at power-on).
            (Ok(None), Some(rect)) => homing::check_plan(
                &settings.homing,
                &calibration.model,
                rect,
                settings.home_mm(),
            )
            .map(|_| None)
            .map_err(Fault::Homing),
            (other, _) => other,
        };
        let (mode, setpoint_mm) = match engaged {
            Ok(Some(tool_mm)) => (Mode::Running, tool_mm),
            Ok(None) => (Mode::Unhomed, [0.0; 2]),
            Err(fault) => (Mode::SafeState(fault), [0.0; 2]),
        };
        // One count of each axis's encoder: the quantisation the encoder check allows (a refused
        // configuration was refused by `validate` above: the loop is in the safe state).
        let count_rad = settings
            .encoders
            .map(|c| EncoderScale::new(&c).map_or(0.0, |s| s.rad_per_count()));
        ServoLoop {
            settings,
            active,
            pending: None,
            servo,
            mode,
            deadline: Deadline::default(),
            encoders: EncoderCheck::new(encoder_rad, count_rad),
            motion: MotionState::at_rest(setpoint_mm),
            stop: None,
            setpoint_mm,
            reference_rad: encoder_rad,
            last_torque_nm: [0.0; 2],
            samples: 0,
            count_rad,
            homing: None,
            pending_offset_rad: [0.0; 2],
            blend: None,
        }
    }

    /// One servo sample as the servo task runs it: the host's `request` (applied first), a
    /// newly committed calibration `offered` (switched to at rest, else kept pending), then the
    /// homing step (with the board's index captures and reference, `index`) or the step on the
    /// setpoint `queue`.
    pub fn tick(
        &mut self,
        request: Option<ServoRequest>,
        offered: Option<(Calibration<'a>, CalibrationId)>,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
        index: &mut impl IndexCapture,
    ) -> Tick {
        // A refused reset leaves the mode as it was, which the host reads in the status.
        let enable_drives = request.is_some_and(|r| {
            self.request(r, queue, encoder_rad)
                .is_ok_and(|enable| enable)
        });
        if let Some((calibration, id)) = offered {
            self.offer_calibration(calibration, id);
        }
        let switch = self.switch_pending(encoder_rad);
        let sample = if self.mode == Mode::Homing {
            self.homing_sample(encoder_rad, index)
        } else {
            self.step(queue, encoder_rad)
        };
        Tick {
            sample,
            enable_drives,
            switch,
        }
    }

    /// The mode after the last sample.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the drives should be enabled: in every mode but the safe state and `Unhomed`.
    pub fn drives_enabled(&self) -> bool {
        self.mode.drives_on()
    }

    /// The last setpoint accepted (mm); after boot, where the servo engaged: the first
    /// setpoint must be there.
    pub fn setpoint_mm(&self) -> [f32; 2] {
        self.setpoint_mm
    }

    /// The encoder angles commanded for [`ServoLoop::setpoint_mm`] (after boot, the encoder
    /// reading it engaged at).
    pub fn reference_rad(&self) -> [f32; 2] {
        self.reference_rad
    }

    /// Deadline bookkeeping so far.
    pub fn deadline(&self) -> &Deadline {
        &self.deadline
    }

    /// The settings the loop runs with.
    pub fn settings(&self) -> &'a Settings {
        self.settings
    }

    /// The calibration in force.
    pub fn calibration(&self) -> &ActiveCalibration<'a> {
        &self.active
    }

    /// A new sample at `encoder_rad`: nothing decided yet, zero torque.
    #[inline]
    fn begin_sample(&mut self, encoder_rad: [f32; 2]) -> Sample {
        let sample = self.undecided_sample(encoder_rad);
        self.samples = self.samples.wrapping_add(1);
        sample
    }

    /// The sample `begin_sample` would start, without counting it (a request's scratch).
    #[inline]
    fn undecided_sample(&self, encoder_rad: [f32; 2]) -> Sample {
        Sample {
            index: self.samples,
            encoder_rad,
            setpoint_mm: self.setpoint_mm,
            reference_rad: self.reference_rad,
            torque_nm: [0.0; 2],
            following_error_rad: 0.0,
            underrun: false,
            refill: false,
            fault: None,
            torque_off: false,
            set_reference: false,
            feed_watchdog: false,
        }
    }

    /// One sample (see the module doc): the encoder check, then the next setpoint from `queue`
    /// or from the stop, through the servo. In the safe state the queue is left alone and the
    /// torques are zero.
    pub fn step(
        &mut self,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Sample {
        let mut sample = self.begin_sample(encoder_rad);
        if matches!(self.mode, Mode::SafeState(_) | Mode::Unhomed | Mode::Homing) {
            // Homing runs through `step_homing`; nothing is taken from the queue.
            return sample;
        }
        let dt_s = self.settings.servo.sample_period_s;
        let checked = self.encoders.check(
            encoder_rad,
            self.last_torque_nm,
            &self.settings.encoder_limits,
            dt_s,
        );
        match checked {
            Err(f) => self.latch(Fault::Encoder(f), &mut sample),
            Ok(()) if self.mode == Mode::Running => self.run(queue, encoder_rad, &mut sample),
            Ok(()) => self.follow_stop(encoder_rad, &mut sample),
        }
        self.last_torque_nm = sample.torque_nm;
        sample
    }

    /// `Running`: the blend's next setpoint, else the stream's, or the start of a stop.
    fn run(
        &mut self,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
        sample: &mut Sample,
    ) {
        if let Some(setpoint) = self.next_blend_setpoint() {
            // After a calibration switch: the blend's setpoints, the queue left alone.
            return self.track_setpoint(setpoint, None, encoder_rad, sample);
        }
        let next = queue.dequeue();
        sample.refill = queue.len() < REFILL_BELOW;
        let setpoint = match next {
            Some(p) => p,
            None => {
                sample.underrun = true;
                if !self.motion.is_at_rest() {
                    return self.begin_stop(Fault::Underrun, encoder_rad, sample);
                }
                MotionSetpoint::at_rest(self.motion.position_mm)
            }
        };
        // The one after it, if queued: the feed-forward's look-ahead (else it is predicted).
        let ahead = queue.peek().copied();
        self.track_setpoint(setpoint, ahead, encoder_rad, sample)
    }

    /// Accepts and tracks one setpoint (`ahead` the next, if known), or starts the stop.
    fn track_setpoint(
        &mut self,
        setpoint: MotionSetpoint<f32>,
        ahead: Option<MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
        sample: &mut Sample,
    ) {
        let setpoint_mm = setpoint.position_mm;
        let Some(servo) = self.servo.as_mut() else {
            return self.latch(
                Fault::Servo(kinematics_core::ServoFault::NotEngaged),
                sample,
            );
        };
        let accepted = match self.active.accept_motion(servo, &setpoint, ahead.as_ref()) {
            Ok(a) => a,
            Err(refusal) => return self.begin_stop(Fault::Setpoint(refusal), encoder_rad, sample),
        };
        let dt_s = self.settings.servo.sample_period_s;
        let state = MotionState::from_differences(
            setpoint_mm,
            accepted.velocity_mm_s(),
            accepted.accel_mm_s2(),
            dt_s,
        );
        if !self
            .active
            .stop_ends_inside(&state, &self.settings.stop.limits)
        {
            // `accepted` is not tracked: the servo stays as it was.
            return self.begin_stop(Fault::StopOutsideWorkspace, encoder_rad, sample);
        }
        match accepted.track(encoder_rad) {
            Ok(out) => {
                self.motion = state;
                self.record(&out, setpoint_mm, sample);
            }
            Err(f) => self.latch(Fault::Servo(f), sample),
        }
    }

    fn record(&mut self, out: &ServoOutput, setpoint_mm: [f32; 2], sample: &mut Sample) {
        self.setpoint_mm = setpoint_mm;
        self.reference_rad = out.reference_rad;
        sample.setpoint_mm = setpoint_mm;
        sample.reference_rad = out.reference_rad;
        sample.torque_nm = out.torque_nm;
        sample.following_error_rad = out.following_error_rad[0]
            .abs()
            .max(out.following_error_rad[1].abs());
    }

    /// Records how long the sample took (`step_us` from its tick) and whether the next tick
    /// already came; a streak of `overrun_streak_limit` misses latches
    /// [`Fault::DeadlineMissed`] (category 0). The torques already written stand until the
    /// drives are disabled (they were the best available). Sets [`Sample::feed_watchdog`] when
    /// the step was on time ([`watchdog::step_on_time`]).
    pub fn record_deadline(&mut self, step_us: f32, overrun: bool, sample: &mut Sample) {
        if self
            .deadline
            .record(step_us, overrun, self.settings.overrun_streak_limit)
        {
            self.latch(Fault::DeadlineMissed, sample);
        }
        sample.feed_watchdog = watchdog::step_on_time(step_us, overrun);
    }

    /// Keeps the drives off from boot, before the first sample, with `fault` (e.g. the last
    /// reset was the watchdog's, or the watchdog could not be started). A fault already
    /// latched at boot (a refused image) stays the one reported.
    pub fn latch_at_boot(&mut self, fault: Fault) {
        if matches!(self.mode, Mode::Running | Mode::Unhomed) {
            self.mode = Mode::SafeState(fault);
        }
    }
}

#[cfg(test)]
mod tests;
