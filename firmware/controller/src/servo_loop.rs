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
//!  SafeState ── reset, never homed (incremental encoders) ──► Unhomed (drives stay off; Home again)
//! ```
//! Every mode but `SafeState` and `Unhomed` has the drives on. `Unhomed` refuses every setpoint
//! (the queue is left alone, zero torque, drives off): **the drives never engage on an unhomed
//! machine for normal motion**. `Homing` runs [`crate::homing`] through
//! [`ServoLoop::step_homing`], in joint space, instead of the setpoint stream. `Holding` keeps the servo on the stop's end
//! point (the fault stays latched); `SafeState` is zero torque, drive enable off, the queue
//! left alone. Only a reset leaves `Holding` or `SafeState`. Stop categories and the table of
//! faults: [`crate::fault`].
//!
//! A sample while the drives are on:
//! 1. the encoder check ([`crate::encoder_check`]) with the torque that acted since the last
//!    reading: a finding is category 0;
//! 2. `Running`: the next setpoint from the queue, with its exact derivatives and the one after
//!    it as the feed-forward's look-ahead (an empty queue holds the last setpoint if the
//!    machine is at rest, or is [`Fault::Underrun`] if it moves), [`Servo::accept_motion`]
//!    (the identified dynamics the image carries fed forward, issue 14; through
//!    [`Servo::accept_motion_valid`], the model checked once at boot or at a calibration
//!    switch, issue 16); a refusal
//!    is [`Fault::Setpoint`]; an accepted setpoint whose stop would end outside the workspace
//!    ([`Workspace`], the image's workspace polygon or the grid's rectangle, less a margin) is dropped and is
//!    [`Fault::StopOutsideWorkspace`]; otherwise it is tracked;
//!    `Stopping` / `Holding`: the stop profile's next setpoint is stepped;
//! 3. a category-1 or -2 fault found in step 2 starts the stop **in the same sample**, from the
//!    last accepted setpoint (whose stop the workspace check accepted), so the torque of this
//!    sample already brakes; a servo fault (following error, non-finite encoder) or a refused
//!    stop setpoint is category 0.
//!
//! The board-facing part of a sample is in the app (`firmware/src/main.rs`, `servo_tick`):
//! read encoders, [`ServoLoop::step`], write the torques (a failed write is
//! [`ServoLoop::latch`]ed as [`Fault::Drive`]), [`ServoLoop::record_deadline`], disable the
//! drives if the sample says so ([`Sample::torque_off`]), publish the
//! [`Status`](crate::status::Status), and last feed the watchdog if [`Sample::feed_watchdog`]
//! (the step was on time; see [`crate::watchdog`]).
//!
//! A motor never jumps: the servo refuses a setpoint it cannot follow, it never clamps one into
//! reach; a stop never steps the velocity; torque is removed only in category 0 (at once) or
//! after a category-1 stop has reached standstill.
use heapless::spsc::Consumer;
use kinematics_core::path::Line;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{
    Calibration, EngageError, PathMotion, Servo, ServoOutput, StepError, TaskLimits,
    ValidCalibration,
};

use crate::calibration::CalibrationState;
use crate::deadline::Deadline;
use crate::encoder::EncoderScale;
use crate::encoder_check::EncoderCheck;
use crate::fault::{Fault, StopCategory};
use crate::homing::{self, Homing, HomingEvent, HomingFault, HomingPhase};
use crate::setpoints::REFILL_BELOW;
use crate::settings::{Settings, SettingsError};
use crate::stop::{MotionState, StopProfile, Workspace};
use crate::watchdog;

/// Where the servo is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// What the host link asks of the servo loop ([`ServoLoop::request`]). The servo task applies
/// it at the start of a sample, before the step (the link's task only posts it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoRequest {
    /// Controlled stop, then hold ([`Fault::StopCommanded`], category 2).
    Stop,
    /// Controlled stop, then torque off ([`Fault::DisableCommanded`], category 1).
    Disable,
    /// Clear the latched fault and re-engage where the machine is ([`ServoLoop::request`]).
    Reset,
    /// Start homing ([`ServoLoop::start_homing`]): only from `Unhomed`.
    Home,
}

/// Why [`ServoRequest::Reset`] was refused; the mode is unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetRefusal {
    /// A controlled stop is under way: reset once it has ended.
    Stopping,
    /// The fault cannot be cleared without a reboot (settings or calibration refused at boot,
    /// or the watchdog could not be started: no motion without it).
    Permanent(Fault),
    /// The servo would not engage at the machine's position.
    Engage(kinematics_core::EngageError),
    /// Incremental encoders and homing never reached home, and the drives are on (a machine
    /// in the safe state instead goes back to `Unhomed`, see [`ServoLoop::request`]): the
    /// encoder zero is unknown, nothing engages.
    NotHomed,
}

/// A stop under way: its profile and the samples stepped along it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stop {
    profile: StopProfile,
    samples: u32,
}

/// The servo loop's state from one sample to the next.
#[derive(Clone, Debug)]
pub struct ServoLoop<'a> {
    settings: &'a Settings,
    calibration: Calibration<'a>,
    /// `calibration` with its model checked once, what the servo's samples use (its IK then
    /// repeats no model check: issue 16). `None` when the model is invalid: the samples then
    /// go through `calibration`, whose IK refuses it on every call, so it is never used.
    valid: Option<ValidCalibration<'a>>,
    /// Where a stop may end: the image's workspace polygon (or, without one, the grid's
    /// rectangle) less the margin (`None`: no grid, running uncorrected; then only the servo's
    /// reach and singularity checks bound a stop).
    workspace: Option<Workspace>,
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

/// A jerk-limited straight move the loop steps by itself (after a calibration switch).
#[derive(Clone, Copy, Debug)]
struct Blend {
    motion: PathMotion<f32, Line<f32>>,
    t_s: f32,
}

/// Why [`ServoLoop::switch_calibration`] did not switch (now).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchRefused {
    /// The machine moves, homes, stops or holds after a fault: try again at the next sample
    /// (a running machine comes to rest between moves).
    NotAtRest,
    /// The new calibration cannot engage at the machine's pose (its kinematics refuse it): the
    /// old one stays.
    Engage(EngageError),
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
        let servo = settings
            .validate()
            .and_then(|()| Servo::new(settings.servo).map_err(SettingsError::Servo));
        let (servo, engaged) = match servo {
            Err(e) => (None, Err(Fault::Settings(e))),
            Ok(mut servo) => {
                // Validated when the image was parsed; `set_dynamics` checks again and keeps
                // none if not (the gains' constant feed-forward then).
                let _ = servo.set_dynamics(
                    calibration
                        .grid
                        .as_ref()
                        .and_then(|g| g.dynamics().copied()),
                );
                let engaged = match state {
                    CalibrationState::Refused(e) => Err(Fault::Calibration(e)),
                    // Incremental encoders: the zero is not known, nothing to engage at.
                    CalibrationState::Valid | CalibrationState::Uncorrected(_)
                        if !settings.homing.absolute_encoders =>
                    {
                        Ok(None)
                    }
                    CalibrationState::Valid | CalibrationState::Uncorrected(_) => servo
                        .engage(&calibration, encoder_rad)
                        .map(Some)
                        .map_err(Fault::Engage),
                };
                (Some(servo), engaged)
            }
        };
        let margin_mm = settings.stop.workspace_margin_mm;
        let workspace = calibration
            .grid
            .as_ref()
            .and_then(|g| Workspace::of_image(g, margin_mm));
        // Homing's sweeps checked against the singularities once, here (hundreds of thousands
        // of instructions: not in a servo sample), from every start in the calibrated rectangle
        // (the grid's, less the margin: the machine may be anywhere the grid covers at power-on,
        // also outside a polygon workspace).
        let calibrated = calibration
            .grid
            .as_ref()
            .and_then(|g| Workspace::of_grid(g.geometry(), margin_mm));
        let engaged = match (engaged, calibrated) {
            (Ok(None), Some(w)) => {
                let ([x0, x1], [y0, y1]) = w.region().bounds_mm();
                let rect = [
                    x0 + margin_mm,
                    x1 - margin_mm,
                    y0 + margin_mm,
                    y1 - margin_mm,
                ];
                homing::check_plan(&settings.homing, &calibration.model, rect, settings.home_mm)
                    .map(|_| None)
                    .map_err(Fault::Homing)
            }
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
            valid: ValidCalibration::new(calibration).ok(),
            calibration,
            workspace,
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

    /// Switches to a newly committed calibration (`calibration_slots`), without a jump:
    /// * running at rest (between moves, nothing queued moving): the servo re-engages at the
    ///   current reading with the new calibration (the reference is the reading: no torque
    ///   step), then a jerk-limited move within the stop's limits brings the tool from where
    ///   the new calibration says it is to the stream's position (micrometres: the two
    ///   calibrations' difference) before the queue is read again;
    /// * unhomed or in the safe state (drives off): the calibration is replaced;
    /// * otherwise ([`SwitchRefused::NotAtRest`]): the caller keeps it pending and tries again.
    pub fn switch_calibration(
        &mut self,
        calibration: Calibration<'a>,
        encoder_rad: [f32; 2],
    ) -> Result<(), SwitchRefused> {
        let margin_mm = self.settings.stop.workspace_margin_mm;
        let workspace = calibration
            .grid
            .as_ref()
            .and_then(|g| Workspace::of_image(g, margin_mm));
        let dynamics = calibration
            .grid
            .as_ref()
            .and_then(|g| g.dynamics().copied());
        match self.mode {
            Mode::Unhomed | Mode::SafeState(_) => {}
            Mode::Running if self.motion.is_at_rest() && self.blend.is_none() => {
                let Some(servo) = self.servo.as_mut() else {
                    return Err(SwitchRefused::NotAtRest);
                };
                let tool_mm = match servo.engage(&calibration, encoder_rad) {
                    Ok(p) => p,
                    Err(e) => {
                        // Back to the old calibration, at the same reading (as at boot).
                        let _ = servo.engage(&self.calibration, encoder_rad);
                        let _ = servo.set_dynamics(
                            self.calibration
                                .grid
                                .as_ref()
                                .and_then(|g| g.dynamics().copied()),
                        );
                        return Err(SwitchRefused::Engage(e));
                    }
                };
                let _ = servo.set_dynamics(dynamics);
                let l = &self.settings.stop.limits;
                let limits = TaskLimits {
                    speed_mm_s: self.settings.trajectory_speed_mm_s,
                    accel_mm_s2: l.decel_mm_s2,
                    jerk_mm_s3: l.jerk_mm_s3,
                };
                self.blend = PathMotion::line(tool_mm, self.motion.position_mm, &limits)
                    .ok()
                    .map(|motion| Blend { motion, t_s: 0.0 });
                self.setpoint_mm = tool_mm;
                self.reference_rad = encoder_rad;
            }
            _ => return Err(SwitchRefused::NotAtRest),
        }
        self.calibration = calibration;
        self.valid = ValidCalibration::new(calibration).ok();
        self.workspace = workspace;
        Ok(())
    }

    /// The mode after the last sample.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether the drives should be enabled: in every mode but the safe state and `Unhomed`.
    pub fn drives_enabled(&self) -> bool {
        self.mode.drives_on()
    }

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
                self.mode = Mode::Homing;
                Ok(())
            }
            Err(f) => {
                self.mode = Mode::SafeState(Fault::Homing(f));
                Err(self.mode)
            }
        }
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
            self.calibration
                .command_rad(self.settings.home_mm, self.settings.servo.min_transmission)
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
            return self.latch(
                Fault::Servo(kinematics_core::ServoFault::NotEngaged),
                sample,
            );
        };
        match servo.engage(&self.calibration, encoder_rad) {
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

    /// The stop under way or done (`Stopping`, `Holding`, or a safe state a stop led to).
    pub fn stop_profile(&self) -> Option<StopProfile> {
        self.stop.map(|s| s.profile)
    }

    /// Deadline bookkeeping so far.
    pub fn deadline(&self) -> &Deadline {
        &self.deadline
    }

    /// The settings the loop runs with.
    pub fn settings(&self) -> &'a Settings {
        self.settings
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

    /// `Running`: the next setpoint of the stream, or the start of a stop.
    fn run(
        &mut self,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
        sample: &mut Sample,
    ) {
        if let Some(blend) = self.blend.as_mut() {
            // After a calibration switch: the blend's setpoints, the queue left alone.
            blend.t_s += self.settings.servo.sample_period_s;
            let setpoint = blend.motion.at(blend.t_s);
            if blend.t_s >= blend.motion.duration_s() {
                self.blend = None;
            }
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
        let accepted = match &self.valid {
            Some(valid) => servo.accept_motion(valid, &setpoint, ahead.as_ref()),
            None => servo.accept_motion(&self.calibration, &setpoint, ahead.as_ref()),
        };
        let accepted = match accepted {
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
        if let Some(workspace) = &self.workspace {
            if !workspace.contains(StopProfile::plan(&state, &self.settings.stop.limits).end_mm()) {
                // `accepted` is not tracked: the servo stays as it was.
                return self.begin_stop(Fault::StopOutsideWorkspace, encoder_rad, sample);
            }
        }
        match accepted.track(encoder_rad) {
            Ok(out) => {
                self.motion = state;
                self.record(&out, setpoint_mm, sample);
            }
            Err(f) => self.latch(Fault::Servo(f), sample),
        }
    }

    /// Latches `fault` found in this sample; a category-1 or -2 fault starts the stop and steps
    /// its first setpoint now.
    fn begin_stop(&mut self, fault: Fault, encoder_rad: [f32; 2], sample: &mut Sample) {
        if fault.stop_category() == StopCategory::Zero {
            return self.latch(fault, sample);
        }
        sample.fault = Some(fault);
        self.mode = Mode::Stopping(fault);
        self.stop = Some(Stop {
            profile: StopProfile::plan(&self.motion, &self.settings.stop.limits),
            samples: 0,
        });
        self.follow_stop(encoder_rad, sample);
    }

    /// `Stopping` and `Holding`: the stop's next setpoint; at its end, hold (category 2) or
    /// remove torque at standstill (category 1).
    fn follow_stop(&mut self, encoder_rad: [f32; 2], sample: &mut Sample) {
        let (Some(mut stop), Some(servo)) = (self.stop, self.servo.as_mut()) else {
            return self.latch(
                Fault::Servo(kinematics_core::ServoFault::NotEngaged),
                sample,
            );
        };
        stop.samples = stop.samples.saturating_add(1);
        self.stop = Some(stop);
        let dt_s = self.settings.servo.sample_period_s;
        let t_s = stop.samples as f32 * dt_s;
        let setpoint_mm = stop.profile.at(t_s);
        let stepped = match &self.valid {
            Some(valid) => servo.step(valid, setpoint_mm, encoder_rad),
            None => servo.step(&self.calibration, setpoint_mm, encoder_rad),
        };
        match stepped {
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

    fn enter_safe_state(&mut self, fault: Fault, sample: &mut Sample) {
        self.mode = Mode::SafeState(fault);
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
                self.mode = Mode::Stopping(fault);
                self.stop = Some(Stop {
                    profile: StopProfile::plan(&self.motion, &self.settings.stop.limits),
                    samples: 0,
                });
            }
            Mode::Stopping(_) | Mode::Holding(_) => {}
        }
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

    /// Applies a host link request (see [`ServoRequest`]) before this sample's step.
    /// `Stop` and `Disable` start the controlled stop while running (from the last accepted
    /// setpoint, as a fault would) and do nothing otherwise. `Reset` from `Holding` or
    /// `SafeState` clears the fault, drops what is queued (`queue`: setpoints planned before the
    /// stop) and re-engages at `encoder_rad`, at rest there; it does nothing while running and
    /// is refused during a stop and after a permanent boot fault. With incremental encoders
    /// before homing reached home it never engages: from `SafeState` (drives off) it clears the
    /// fault back to `Unhomed`, drives still off, so that `Home` can run again without a reboot
    /// (a homing that failed, a fault latched before homing); otherwise it is refused
    /// ([`ResetRefusal::NotHomed`]). `Home` starts homing from `Unhomed`
    /// ([`ServoLoop::start_homing`]: the drives go on) and does nothing in any other mode (a
    /// refused plan latches its fault there). Returns whether the drives must be enabled now
    /// (they were off).
    pub fn request(
        &mut self,
        request: ServoRequest,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<bool, ResetRefusal> {
        let mut scratch = self.undecided_sample(encoder_rad);
        let fault = match (request, self.mode) {
            (ServoRequest::Stop, Mode::Running) => Fault::StopCommanded,
            (ServoRequest::Disable, Mode::Running | Mode::Holding(_)) => Fault::DisableCommanded,
            (ServoRequest::Stop | ServoRequest::Disable, _)
            | (ServoRequest::Reset, Mode::Running) => return Ok(false),
            // The drives go on with the homing search (its torque is limited).
            (ServoRequest::Home, _) => return Ok(self.start_homing(encoder_rad).is_ok()),
            (ServoRequest::Reset, Mode::Stopping(_)) => return Err(ResetRefusal::Stopping),
            // Homing decides when the servo engages.
            (ServoRequest::Reset, Mode::Unhomed | Mode::Homing) => return Ok(false),
            (ServoRequest::Reset, Mode::Holding(f) | Mode::SafeState(f)) => {
                return self.reset(f, queue, encoder_rad)
            }
        };
        if let Mode::Holding(_) = self.mode {
            // Disable while holding: torque off at once, the machine is at rest.
            self.enter_safe_state(fault, &mut scratch);
            return Ok(false);
        }
        self.latch(fault, &mut scratch);
        Ok(false)
    }

    fn reset(
        &mut self,
        fault: Fault,
        queue: &mut Consumer<'_, MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<bool, ResetRefusal> {
        if fault.needs_reboot() {
            return Err(ResetRefusal::Permanent(fault));
        }
        if !self.settings.homing.absolute_encoders && self.homing_phase() != Some(HomingPhase::Done)
        {
            if let Mode::SafeState(_) = self.mode {
                // The zero is unknown: nothing engages. Back to where the boot left an
                // incremental machine (drives off, every setpoint refused), so Home may run.
                while queue.dequeue().is_some() {}
                self.mode = Mode::Unhomed;
                self.homing = None;
                self.stop = None;
                self.last_torque_nm = [0.0; 2];
                return Ok(false);
            }
            return Err(ResetRefusal::NotHomed);
        }
        let servo = self.servo.as_mut().ok_or(ResetRefusal::Permanent(fault))?;
        let tool_mm = servo
            .engage(&self.calibration, encoder_rad)
            .map_err(ResetRefusal::Engage)?;
        while queue.dequeue().is_some() {}
        let was_off = !self.drives_enabled();
        self.mode = Mode::Running;
        self.stop = None;
        self.motion = MotionState::at_rest(tool_mm);
        self.setpoint_mm = tool_mm;
        self.reference_rad = encoder_rad;
        self.encoders = EncoderCheck::new(encoder_rad, self.count_rad);
        self.last_torque_nm = [0.0; 2];
        Ok(was_off)
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
mod tests {
    use super::*;
    use crate::watchdog::WatchdogFault;
    use heapless::spsc::Queue;
    use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
    use kinematics_core::{EngageError, FiveBar, GridError, SetpointRefusal};

    use crate::calibration::ImageError;
    use crate::encoder_check::{EncoderFault, EncoderFaultKind};
    use crate::setpoints::QUEUE_SLOTS;
    use crate::stop::stopping_distance_bound_mm;
    use crate::trajectory::{Trajectory, WORKSPACE_TOUR_MM};

    const HOME_MM: [f32; 2] = [212.132, 0.0];

    /// The default settings with absolute encoders: the servo engages at boot (the QEMU
    /// plant's encoders in every scenario but homing's).
    fn absolute() -> Settings {
        let mut s = Settings::default();
        s.homing.absolute_encoders = true;
        s
    }

    fn image() -> Vec<u8> {
        let g = GridGeometry {
            nx: 3,
            ny: 3,
            x0_mm: 160.0,
            y0_mm: -80.0,
            step_x_mm: 50.0,
            step_y_mm: 80.0,
        };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &[[3e-4, -2e-4]; 9]).unwrap();
        img
    }

    /// Boots on a valid image with the machine at the home pose.
    fn running<'a>(settings: &'a Settings, img: &'a [u8]) -> (ServoLoop<'a>, [f32; 2]) {
        let cal = Calibration::from_grid(CorrectionGrid::parse(img).unwrap());
        let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
        let l = ServoLoop::boot(settings, cal, CalibrationState::Valid, encoder);
        assert_eq!(l.mode(), Mode::Running);
        (l, encoder)
    }

    #[test]
    fn boot_engages_where_the_machine_is() {
        let (settings, img) = (absolute(), image());
        let (l, encoder) = running(&settings, &img);
        assert!(l.drives_enabled());
        let p = l.setpoint_mm();
        assert!(
            (p[0] - HOME_MM[0]).abs() < 1e-3 && (p[1] - HOME_MM[1]).abs() < 1e-3,
            "{p:?}"
        );
        assert_eq!(l.reference_rad(), encoder);
    }

    #[test]
    fn a_refused_image_keeps_the_loop_safe_and_leaves_the_queue_alone() {
        let settings = absolute();
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
        let mut l = ServoLoop::boot(
            &settings,
            cal,
            CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
            encoder,
        );
        assert_eq!(
            l.mode(),
            Mode::SafeState(Fault::Calibration(ImageError::Grid(GridError::BadCrc)))
        );
        assert!(!l.drives_enabled());
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        for _ in 0..3 {
            let s = l.step(&mut rx, encoder);
            assert_eq!(s.torque_nm, [0.0; 2]);
            assert_eq!((s.fault, s.underrun, s.refill), (None, false, false));
        }
        assert_eq!(
            rx.len(),
            1,
            "nothing taken from the queue in the safe state"
        );
        // Uncorrected running allowed: engages with the nominal model.
        let l = ServoLoop::boot(
            &settings,
            cal,
            CalibrationState::Uncorrected(ImageError::Grid(GridError::BadCrc)),
            encoder,
        );
        assert_eq!(l.mode(), Mode::Running);
    }

    #[test]
    fn boot_refuses_an_encoder_reading_the_kinematics_refuse() {
        // Encoder zero: both arms stretched along x, the distal links cannot meet.
        let (settings, img) = (absolute(), image());
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        assert!(
            matches!(
                l.mode(),
                Mode::SafeState(Fault::Engage(EngageError::Kinematics(_)))
            ),
            "{:?}",
            l.mode()
        );
    }

    #[test]
    fn boot_refuses_an_encoder_configuration_the_scale_refuses() {
        use crate::encoder::EncoderConfigError;
        let img = image();
        let mut settings = absolute();
        settings.encoders[1].counts_per_rev = 0;
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
        let l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, encoder);
        let want = Fault::Settings(SettingsError::Encoder {
            axis: 1,
            error: EncoderConfigError::ZeroCountsPerRev,
        });
        assert_eq!(l.mode(), Mode::SafeState(want));
    }

    /// Issue 11: a refused setpoint used to remove torque at once whatever the speed. At rest,
    /// a NaN (category 1) stops at once (an empty stop) and removes torque at standstill, in the
    /// same sample; the stop from rest holds the last accepted setpoint.
    #[test]
    fn a_nan_setpoint_at_rest_removes_torque_at_standstill() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        tx.enqueue(MotionSetpoint::at_rest([f32::NAN, 0.0]))
            .unwrap();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        let s = l.step(&mut rx, encoder);
        assert!(s.fault.is_none() && !s.torque_off);
        let s = l.step(&mut rx, encoder);
        let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
        assert_eq!(
            (s.fault, s.torque_off, s.torque_nm),
            (Some(nan), true, [0.0; 2])
        );
        assert_eq!(
            s.setpoint_mm, HOME_MM,
            "the last accepted setpoint, not the NaN"
        );
        assert_eq!(l.mode(), Mode::SafeState(nan));
        assert_eq!(l.stop_profile().map(|p| p.distance_mm()), Some(0.0));
        let s = l.step(&mut rx, encoder);
        assert_eq!(
            (s.fault, s.torque_nm, s.torque_off),
            (None, [0.0; 2], false),
            "latched once, zero ever after"
        );
        assert_eq!(rx.len(), 1);
    }

    #[test]
    fn an_empty_queue_holds_the_last_setpoint_and_asks_for_a_refill() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let s = l.step(&mut rx, encoder);
        assert!(s.underrun && s.refill && s.fault.is_none());
        assert_eq!(s.setpoint_mm, l.setpoint_mm());
        while tx.ready() {
            tx.enqueue(MotionSetpoint::at_rest(l.setpoint_mm()))
                .unwrap();
        }
        let s = l.step(&mut rx, encoder);
        assert!(!s.underrun && !s.refill, "{} left", rx.len());
        while rx.len() >= REFILL_BELOW {
            rx.dequeue();
        }
        assert!(l.step(&mut rx, encoder).refill);
    }

    #[test]
    fn a_streak_of_overruns_latches_deadline_missed_once() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        for k in 0..settings.overrun_streak_limit {
            let mut s = l.step(&mut rx, encoder);
            l.record_deadline(700.0, true, &mut s);
            let last = k + 1 == settings.overrun_streak_limit;
            assert_eq!(
                s.fault,
                last.then_some(Fault::DeadlineMissed),
                "overrun {k}"
            );
        }
        assert_eq!(l.mode(), Mode::SafeState(Fault::DeadlineMissed));
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(700.0, true, &mut s);
        assert_eq!(s.fault, None, "already safe: nothing new latched");
        assert_eq!(l.deadline().overruns, settings.overrun_streak_limit + 1);
    }

    #[test]
    fn only_an_on_time_step_feeds_the_watchdog_and_the_safe_state_still_does() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        let s = l.step(&mut rx, encoder);
        assert!(!s.feed_watchdog, "no deadline recorded, no feed");
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(15.0, false, &mut s);
        assert!(s.feed_watchdog);
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(700.0, true, &mut s);
        assert!(!s.feed_watchdog, "late");
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(f32::NAN, false, &mut s);
        assert!(!s.feed_watchdog, "step time unreadable");
        // In the safe state the drives are off and the task still runs on time: it feeds.
        l.latch(Fault::Drive, &mut s);
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(10.0, false, &mut s);
        assert!(s.feed_watchdog && !l.drives_enabled());
    }

    #[test]
    fn a_fault_at_boot_keeps_the_drives_off_and_the_first_reason_is_kept() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        l.latch_at_boot(Fault::Watchdog(WatchdogFault::Reset));
        assert_eq!(
            l.mode(),
            Mode::SafeState(Fault::Watchdog(WatchdogFault::Reset))
        );
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        let s = l.step(&mut rx, [encoder[0] + 1e-3, encoder[1]]);
        assert_eq!((s.torque_nm, s.fault), ([0.0; 2], None));
        // A refused image at boot stays the reason reported.
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let mut l = ServoLoop::boot(
            &settings,
            cal,
            CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
            encoder,
        );
        l.latch_at_boot(Fault::Watchdog(WatchdogFault::NotStarted));
        assert_eq!(
            l.mode(),
            Mode::SafeState(Fault::Calibration(ImageError::Grid(GridError::BadCrc)))
        );
    }

    #[test]
    fn a_failed_pwm_write_latches_a_drive_fault() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        let mut s = l.step(&mut rx, [encoder[0] + 1e-5, encoder[1]]);
        assert!(s.torque_nm[0] != 0.0);
        l.latch(Fault::Drive, &mut s);
        assert_eq!(
            (s.fault, s.torque_nm, s.torque_off),
            (Some(Fault::Drive), [0.0; 2], true)
        );
        assert!(!l.drives_enabled());
    }

    #[test]
    fn the_reference_is_model_ik_plus_the_grid_correction() {
        let (settings, img) = (absolute(), image());
        let (mut l, encoder) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        let s = l.step(&mut rx, encoder);
        assert!(s.fault.is_none());
        let ik = FiveBar::<f32>::paper_nominal()
            .inverse(HOME_MM, 0.05)
            .unwrap();
        assert!(
            (s.reference_rad[0] - ik[0] - 3e-4).abs() < 1e-6,
            "{:?} vs {ik:?}",
            s.reference_rad
        );
        assert!((s.reference_rad[1] - ik[1] + 2e-4).abs() < 1e-6);
    }

    // -----------------------------------------------------------------------------------------
    // Closed loop: the servo loop against two joint inertias with friction (the QEMU plant's
    // parameters: its rotors plus the diagonal of its linkage's inertia matrix, 5.4e-3 kg·m²,
    // without the coupling), the encoders quantised to 2^22 counts/rev.

    const DT_S: f32 = crate::SAMPLE_PERIOD_S;

    use crate::host_link::doubles::JointPlant as Plant;

    /// What a closed run saw.
    struct Run {
        samples: Vec<Sample>,
        modes: Vec<Mode>,
        /// The plant's joint angles after each sample's torque acted (rad).
        angles: Vec<[f32; 2]>,
        enabled: Vec<bool>,
    }

    /// Runs `n` samples from HOME: `setpoint(k)` is queued before sample k (`None`: nothing),
    /// `reading(k, encoder)` is what the loop reads.
    fn closed(
        settings: &Settings,
        cal: Calibration<'_>,
        n: usize,
        setpoint: impl FnMut(usize) -> Option<[f32; 2]>,
        reading: impl FnMut(usize, [f32; 2]) -> [f32; 2],
    ) -> Run {
        closed_with_requests(settings, cal, n, setpoint, reading, |_| None)
    }

    /// [`closed`], with `request(k)` applied before sample k (as the servo task does).
    fn closed_with_requests(
        settings: &Settings,
        cal: Calibration<'_>,
        n: usize,
        mut setpoint: impl FnMut(usize) -> Option<[f32; 2]>,
        mut reading: impl FnMut(usize, [f32; 2]) -> [f32; 2],
        mut request: impl FnMut(usize) -> Option<ServoRequest>,
    ) -> Run {
        let start = cal.command_rad(HOME_MM, 0.05).unwrap();
        let mut plant = Plant {
            angle_rad: start,
            velocity_rad_s: [0.0; 2],
            torque_nm: [0.0; 2],
            enabled: true,
        };
        let mut l = ServoLoop::boot(settings, cal, CalibrationState::Valid, plant.encoder_rad());
        assert_eq!(l.mode(), Mode::Running);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut run = Run {
            samples: vec![],
            modes: vec![],
            angles: vec![],
            enabled: vec![],
        };
        for k in 0..n {
            if let Some(p) = setpoint(k) {
                // Full once the loop stops taking setpoints (stopping, holding, safe state).
                // Positions only (a source without derivatives): no inertia fed forward.
                let _ = tx.enqueue(MotionSetpoint::at_rest(p));
            }
            if let Some(r) = request(k) {
                if let Ok(true) = l.request(r, &mut rx, reading(k, plant.encoder_rad())) {
                    plant.enabled = true;
                }
            }
            let s = l.step(&mut rx, reading(k, plant.encoder_rad()));
            if s.torque_off {
                plant.enabled = false;
            }
            plant.torque_nm = s.torque_nm;
            plant.advance();
            run.samples.push(s);
            run.modes.push(l.mode());
            run.angles.push(plant.angle_rad);
            run.enabled.push(plant.enabled);
        }
        run
    }

    fn tour() -> Trajectory {
        let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
        Trajectory::new(HOME_MM, &WORKSPACE_TOUR_MM, 2.0 * g, 1500.0, 0.1, DT_S)
    }

    /// The sample of the tour's top speed, and that speed (mm/s).
    fn top_speed() -> (usize, f32) {
        let mut t = tour();
        let mut last = t.next_mm();
        let mut best = (0, 0.0f32);
        for k in 1..t.total_samples() as usize {
            let p = t.next_mm();
            let v = libm::hypotf(p[0] - last[0], p[1] - last[1]) / DT_S;
            if v > best.1 {
                best = (k, v);
            }
            last = p;
        }
        best
    }

    fn tool_mm(cal: &Calibration<'_>, theta: [f32; 2]) -> [f32; 2] {
        let p = cal.model.forward(theta, 0.0).unwrap();
        let d = cal
            .grid
            .as_ref()
            .map_or([0.0; 2], |g| g.correction_rad(p).unwrap_or([0.0; 2]));
        cal.model
            .forward([theta[0] - d[0], theta[1] - d[1]], 0.0)
            .unwrap()
    }

    fn grid_cal(img: &[u8]) -> Calibration<'_> {
        Calibration::from_grid(CorrectionGrid::parse(img).unwrap())
    }

    /// The whole built-in tour at 2 g / 1.5 m/s, closed around the plant: the encoder check,
    /// the workspace check and the underrun logic never trip.
    #[test]
    fn the_tour_runs_without_a_false_trip() {
        let (settings, img) = (absolute(), image());
        let mut t = tour();
        let n = t.total_samples() as usize + 200;
        let run = closed(
            &settings,
            grid_cal(&img),
            n,
            |_| Some(t.next_mm()),
            |_, e| e,
        );
        let faults: Vec<_> = run.samples.iter().filter_map(|s| s.fault).collect();
        assert!(faults.is_empty(), "{faults:?}");
        assert!(run.modes.iter().all(|m| *m == Mode::Running));
        let worst = run
            .samples
            .iter()
            .map(|s| s.following_error_rad)
            .fold(0.0, f32::max);
        assert!(worst < 2e-4, "following error {worst}");
    }

    /// Injects a fault through `inject` at the tour's top speed and returns the run, the
    /// sample, and the stated stopping distance from the last accepted setpoint (its speed and
    /// acceleration along the path from the setpoints).
    fn stop_at_top_speed(
        settings: &Settings,
        img: &[u8],
        n: usize,
        inject: impl Fn(usize, [f32; 2]) -> Option<[f32; 2]>,
    ) -> (Run, usize, f32) {
        let (at, _) = top_speed();
        let mut t = tour();
        let run = closed(
            settings,
            grid_cal(img),
            at + n,
            |k| inject(k.wrapping_sub(at), t.next_mm()),
            |_, e| e,
        );
        let [p1, p2, p3] = [1, 2, 3].map(|j| run.samples[at - j].setpoint_mm);
        let v = [0, 1].map(|k| (p1[k] - p2[k]) / DT_S);
        let a = [0, 1].map(|k| (p1[k] - 2.0 * p2[k] + p3[k]) / (DT_S * DT_S));
        let m = MotionState::from_differences(p1, v, a, DT_S);
        let along = (m.accel_mm_s2[0] * m.velocity_mm_s[0] + m.accel_mm_s2[1] * m.velocity_mm_s[1])
            / m.speed_mm_s();
        (
            run,
            at,
            stopping_distance_bound_mm(m.speed_mm_s(), along, &settings.stop.limits),
        )
    }

    /// Checks a controlled stop from sample `at`: the stop's setpoints end at the stated
    /// distance `bound_mm` from its origin (the last accepted setpoint) within 0.1 %; the tool
    /// gets no further from the origin than that plus 0.1 mm (tracking) and stays inside the
    /// calibrated rectangle. Returns (planned, travelled) in mm.
    fn check_controlled_stop(
        cal: &Calibration<'_>,
        run: &Run,
        at: usize,
        bound_mm: f32,
    ) -> (f32, f32) {
        let from = run.samples[at - 1].setpoint_mm;
        let end = run.samples[run.samples.len() - 1].setpoint_mm;
        let planned = libm::hypotf(end[0] - from[0], end[1] - from[1]);
        assert!(
            (planned - bound_mm).abs() <= 1e-3 * bound_mm,
            "planned {planned} mm, stated {bound_mm}"
        );
        let mut furthest = 0.0f32;
        for k in at..run.angles.len() {
            let p = tool_mm(cal, run.angles[k]);
            furthest = furthest.max(libm::hypotf(p[0] - from[0], p[1] - from[1]));
            assert!(
                (160.0..=260.0).contains(&p[0]) && (-80.0..=80.0).contains(&p[1]),
                "left the rectangle: {p:?}"
            );
        }
        assert!(
            furthest <= planned + 0.1 && furthest >= planned - 0.1,
            "stopped in {furthest} mm, planned {planned}"
        );
        (planned, furthest)
    }

    /// Issue 11: a NaN at 1.4 m/s used to remove torque at once; the machine coasted 20-130 mm.
    /// Now: category 1, braked along the path within the stated distance, torque off at
    /// standstill, never before.
    #[test]
    fn a_nan_at_top_speed_brakes_along_the_path_then_removes_torque() {
        let (settings, img) = (absolute(), image());
        let (run, at, bound) = stop_at_top_speed(&settings, &img, 300, |k, p| {
            Some(if k == 0 { [p[0], f32::NAN] } else { p })
        });
        let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
        assert_eq!(run.samples[at].fault, Some(nan));
        assert!(
            run.samples[at].torque_nm != [0.0; 2],
            "the fault's sample already brakes"
        );
        let off = run
            .samples
            .iter()
            .position(|s| s.torque_off)
            .expect("torque never removed");
        let stop = (settings.stop.limits.decel_mm_s2, bound);
        let duration = ((off - at) as f32) * DT_S;
        assert!(
            duration < 0.05 + 0.005,
            "torque removed {duration} s after the fault ({stop:?})"
        );
        assert!(run.enabled[..off].iter().all(|&e| e) && run.enabled[off..].iter().all(|&e| !e));
        assert!(run.samples[off..].iter().all(|s| s.torque_nm == [0.0; 2]));
        assert_eq!(run.modes[off], Mode::SafeState(nan));
        let (planned, travelled) = check_controlled_stop(&grid_cal(&img), &run, at, bound);
        println!("NaN at {at}: planned {planned:.3} mm (stated {bound:.3} mm), tool {travelled:.3} mm, torque off after {duration} s");
    }

    /// A setpoint jump at top speed: category 2, braked, then held with the drives on.
    #[test]
    fn a_jump_at_top_speed_brakes_then_holds() {
        let (settings, img) = (absolute(), image());
        let (run, at, bound) = stop_at_top_speed(&settings, &img, 300, |k, p| {
            Some(if k < 1000 { [p[0] + 1.0, p[1]] } else { p })
        });
        let jump = Fault::Setpoint(SetpointRefusal::Jump);
        assert_eq!(run.samples[at].fault, Some(jump));
        assert_eq!(run.modes[run.modes.len() - 1], Mode::Holding(jump));
        assert!(run.enabled.iter().all(|&e| e) && !run.samples.iter().any(|s| s.torque_off));
        check_controlled_stop(&grid_cal(&img), &run, at, bound);
        // Holding: from 50 ms after the stop within 20 µm of its end point (the integrator
        // gives back what it took on during the 5 g stop: ~10 µm for ~100 ms), the last 50
        // samples within a micrometre.
        let cal = grid_cal(&img);
        let end = run.samples[run.samples.len() - 1].setpoint_mm;
        let stop_end = at
            + run.modes[at..]
                .iter()
                .position(|m| matches!(m, Mode::Holding(_)))
                .unwrap();
        let error = |a: &[f32; 2]| {
            let p = tool_mm(&cal, *a);
            libm::hypotf(p[0] - end[0], p[1] - end[1])
        };
        let worst = run.angles[stop_end + 100..]
            .iter()
            .map(error)
            .fold(0.0, f32::max);
        assert!(worst < 0.02, "holding {worst} mm off the stop's end");
        let last = tool_mm(&cal, run.angles[run.angles.len() - 1]);
        for a in &run.angles[run.angles.len() - 50..] {
            let p = tool_mm(&cal, *a);
            assert!(
                libm::hypotf(p[0] - last[0], p[1] - last[1]) < 1e-3,
                "still moving: {p:?} vs {last:?}"
            );
        }
    }

    /// Issue 11: an empty queue for one sample at speed read as an infinite deceleration. Now:
    /// category 2 from the last setpoint; at rest it just holds.
    #[test]
    fn an_underrun_while_moving_brakes_then_holds() {
        let (settings, img) = (absolute(), image());
        let (run, at, bound) =
            stop_at_top_speed(&settings, &img, 300, |k, p| (k >= 1 << 30).then_some(p));
        assert_eq!(run.samples[at].fault, Some(Fault::Underrun));
        assert!(run.samples[at].underrun);
        assert_eq!(
            run.modes[run.modes.len() - 1],
            Mode::Holding(Fault::Underrun)
        );
        check_controlled_stop(&grid_cal(&img), &run, at, bound);
    }

    /// The host's Stop at top speed is the same controlled stop (category 2, then hold); a
    /// reset re-engages where it held, dropping what was queued; Disable brakes and
    /// removes torque, and a reset turns the drives back on.
    #[test]
    fn a_commanded_stop_brakes_then_holds_and_a_reset_resumes() {
        let (settings, img) = (absolute(), image());
        let (at, _) = top_speed();
        let mut t = tour();
        let n = at + 401;
        let run = closed_with_requests(
            &settings,
            grid_cal(&img),
            n,
            |_| Some(t.next_mm()),
            |_, e| e,
            |k| match k {
                _ if k == at => Some(ServoRequest::Stop),
                _ if k == at + 1 => Some(ServoRequest::Reset), // refused: stopping
                _ if k == at + 400 => Some(ServoRequest::Reset),
                _ => None,
            },
        );
        assert_eq!(
            run.samples[at].fault, None,
            "a request takes effect from the next sample's stop"
        );
        assert_eq!(run.modes[at], Mode::Stopping(Fault::StopCommanded));
        assert_eq!(
            run.modes[at + 1],
            Mode::Stopping(Fault::StopCommanded),
            "reset refused during the stop"
        );
        assert_eq!(run.modes[at + 399], Mode::Holding(Fault::StopCommanded));
        assert_eq!(
            run.modes[at + 400],
            Mode::Running,
            "the reset dropped the tour's queued setpoints"
        );
        // The stop braked along the path, within its bound from the last accepted setpoint.
        let from = run.samples[at - 1].setpoint_mm;
        let end = run.samples[at + 399].setpoint_mm;
        let v = libm::hypotf(
            from[0] - run.samples[at - 2].setpoint_mm[0],
            from[1] - run.samples[at - 2].setpoint_mm[1],
        ) / DT_S;
        let travelled = libm::hypotf(end[0] - from[0], end[1] - from[1]);
        let bound = stopping_distance_bound_mm(v, 2.0 * 9806.65, &settings.stop.limits);
        assert!(
            travelled > 0.0 && travelled <= bound,
            "{travelled} mm, bound {bound} mm"
        );

        // Direct: disable at rest, reset turns the drives back on, a boot fault is permanent.
        let (mut l, enc) = running(&settings, &img);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, enc),
            Ok(false),
            "running: nothing to reset"
        );
        assert_eq!(l.request(ServoRequest::Disable, &mut rx, enc), Ok(false));
        let mut torque_off = false;
        for _ in 0..200 {
            torque_off |= l.step(&mut rx, enc).torque_off;
        }
        assert!(torque_off);
        assert_eq!(l.mode(), Mode::SafeState(Fault::DisableCommanded));
        let _ = tx.enqueue(MotionSetpoint::at_rest([200.0, 10.0]));
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, enc),
            Ok(true),
            "drives back on"
        );
        assert_eq!(l.mode(), Mode::Running);
        assert_eq!(rx.len(), 0, "the stale setpoint was dropped");
        let boot_fault = Fault::Calibration(ImageError::Grid(GridError::BadCrc));
        let nominal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let mut l = ServoLoop::boot(
            &settings,
            nominal,
            CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
            enc,
        );
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, enc),
            Err(ResetRefusal::Permanent(boot_fault))
        );
    }

    /// A stream that heads for the edge of the calibrated rectangle too fast to stop before it
    /// is refused early enough: the stop ends inside (the setpoint that would not is never
    /// tracked), whereas the servo alone would accept setpoints up to the grid's edge.
    #[test]
    fn a_stream_too_fast_for_the_edge_is_stopped_inside() {
        let (settings, img) = (absolute(), image());
        let cal = grid_cal(&img);
        let (run, at) = towards_x_320(&settings, cal);
        assert_eq!(run.samples[at].fault, Some(Fault::StopOutsideWorkspace));
        assert!(run
            .samples
            .iter()
            .all(|s| s.setpoint_mm[0] <= 260.0 - settings.stop.workspace_margin_mm));
        assert!(matches!(
            run.modes[run.modes.len() - 1],
            Mode::Holding(Fault::StopOutsideWorkspace)
        ));
        let end = tool_mm(&cal, run.angles[run.angles.len() - 1]);
        assert!(
            end[0] <= 260.0 - 0.09 && end[0] > 230.0,
            "stopped at {end:?}"
        );
        // The speed when refused: well above what could stop in the last millimetre.
        let v = (run.samples[at - 1].setpoint_mm[0] - run.samples[at - 2].setpoint_mm[0]) / DT_S;
        assert!(v > 1000.0, "{v} mm/s");
    }

    /// From home towards x = 320 mm (beyond the grid's 260 mm edge) at 2 g / 1.5 m/s: the run and
    /// the sample of its first fault.
    fn towards_x_320<'a>(settings: &Settings, cal: Calibration<'a>) -> (Run, usize) {
        let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
        let mut t = Trajectory::new(HOME_MM, &[[320.0, 0.0]], 2.0 * g, 1500.0, 0.1, DT_S);
        let run = closed(settings, cal, 800, |_| Some(t.next_mm()), |_, e| e);
        let at = run.samples.iter().position(|s| s.fault.is_some()).unwrap();
        (run, at)
    }

    /// With the machine's workspace in the image (issue 12), the edge is the polygon's, not the
    /// grid's: the same stream towards x = 320 mm is stopped inside the polygon's right edge
    /// at x = 240 mm (20 mm before the grid's), by the image's stop margin of 0.5 mm.
    #[test]
    fn the_edge_is_the_images_workspace_when_it_has_one() {
        use kinematics_core::grid::{append_workspace, WorkspaceLimits, WORKSPACE_LEN};
        use kinematics_core::ConvexWorkspace;
        let settings = absolute();
        let mut img = image();
        let n = img.len();
        img.resize(n + WORKSPACE_LEN, 0);
        let region =
            ConvexWorkspace::new(&[[170.0, -70.0], [240.0, -70.0], [240.0, 70.0], [170.0, 70.0]])
                .unwrap();
        append_workspace(
            &mut img,
            n,
            n,
            &WorkspaceLimits {
                region,
                stop_margin_mm: 0.5,
            },
        )
        .unwrap();
        let cal = grid_cal(&img);
        let (run, at) = towards_x_320(&settings, cal);
        assert_eq!(run.samples[at].fault, Some(Fault::StopOutsideWorkspace));
        assert!(
            run.samples.iter().all(|s| s.setpoint_mm[0] <= 240.0 - 0.5),
            "a setpoint beyond the polygon's edge"
        );
        let end = tool_mm(&cal, run.angles[run.angles.len() - 1]);
        assert!(
            end[0] <= 240.0 - 0.45 && end[0] > 215.0,
            "stopped at {end:?}"
        );
    }

    /// An encoder frozen during a stop, and a glitch while moving: category 0 at once, even
    /// mid-stop (the stop never hides a feedback fault).
    #[test]
    fn encoder_faults_remove_torque_at_once_even_during_a_stop() {
        let (settings, img) = (absolute(), image());
        let (at, _) = top_speed();
        // A jump at top speed starts a category-2 stop; 10 samples into it the encoder of axis
        // 1 freezes (mid-stop, decelerating at 5 g).
        let mut t = tour();
        let mut frozen = None;
        let run = closed(
            &settings,
            grid_cal(&img),
            at + 100,
            |k| {
                Some(if k >= at {
                    [t.next_mm()[0] + 1.0, 0.0]
                } else {
                    t.next_mm()
                })
            },
            |k, e| {
                if k >= at + 10 {
                    [e[0], *frozen.get_or_insert(e[1])]
                } else {
                    e
                }
            },
        );
        let bad = run
            .samples
            .iter()
            .position(|s| {
                s.fault
                    .is_some_and(|f| f.stop_category() == StopCategory::Zero)
            })
            .unwrap();
        // Joint 2 turns slower than 3 rad/s there: the stuck check, not the acceleration check,
        // finds it, within a few samples.
        assert!(
            (at + 10..=at + 20).contains(&bad),
            "found at {bad}, frozen at {}",
            at + 10
        );
        assert!(matches!(
            run.samples[bad].fault,
            Some(Fault::Encoder(EncoderFault { axis: 1, .. }))
        ));
        assert!(run.samples[bad].torque_off && run.samples[bad].torque_nm == [0.0; 2]);
        assert!(matches!(
            run.modes[run.modes.len() - 1],
            Mode::SafeState(Fault::Encoder(_))
        ));
        // A 5 mrad glitch at top speed: caught in its sample.
        let mut t = tour();
        let run = closed(
            &settings,
            grid_cal(&img),
            at + 10,
            |_| Some(t.next_mm()),
            |k, e| if k == at { [e[0] + 5e-3, e[1]] } else { e },
        );
        assert_eq!(
            run.samples[at].fault,
            Some(Fault::Encoder(EncoderFault {
                axis: 0,
                kind: EncoderFaultKind::Acceleration
            }))
        );
        assert!(run.samples[at].torque_off);
    }

    /// Issue 11: an encoder frozen at rest went unnoticed until the machine moved, then 8 N·m
    /// drove the tool 43 mm off. Now the move's torque finds joint 1's reading stuck a few
    /// samples after the move starts, the tool a fraction of a millimetre off; then it coasts
    /// (category 0) from the low speed it had.
    #[test]
    fn an_encoder_frozen_at_rest_is_stuck_as_soon_as_the_machine_is_asked_to_move() {
        let (settings, img) = (absolute(), image());
        let cal = grid_cal(&img);
        let mut t = tour();
        // Rest 50 samples at home (the tour starts with a move), joint 1 frozen from sample 20.
        let mut frozen = None;
        let run = closed(
            &settings,
            cal,
            1000,
            |k| Some(if k < 50 { HOME_MM } else { t.next_mm() }),
            |k, e| {
                if k >= 20 {
                    [*frozen.get_or_insert(e[0]), e[1]]
                } else {
                    e
                }
            },
        );
        let bad = run
            .samples
            .iter()
            .position(|s| s.fault.is_some())
            .expect("not detected");
        assert_eq!(
            run.samples[bad].fault,
            Some(Fault::Encoder(EncoderFault {
                axis: 0,
                kind: EncoderFaultKind::Stuck
            }))
        );
        assert!(run.samples[bad].torque_off);
        let p0 = tool_mm(&cal, run.angles[19]);
        let off = |k: usize| {
            let p = tool_mm(&cal, run.angles[k]);
            libm::hypotf(p[0] - p0[0], p[1] - p0[1])
        };
        let at_detection = off(bad);
        let coasted = (bad..run.angles.len()).map(off).fold(0.0, f32::max);
        println!(
            "frozen at rest: stuck {} samples after the move started, tool {at_detection:.3} mm off, {coasted:.3} mm after the coast",
            bad - 50
        );
        assert!(bad > 50 && bad <= 50 + 30, "detected at sample {bad}");
        assert!(
            at_detection < 0.5,
            "tool {at_detection} mm off at detection"
        );
        assert!(coasted < 3.0, "coasted to {coasted} mm");
    }

    /// Without a grid (running uncorrected) there is no rectangle to check a stop against: a
    /// stop the kinematics refuse on the way ends in category 0.
    #[test]
    fn a_stop_the_servo_refuses_is_category_zero() {
        let settings = absolute();
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
        // A stream along +x: 2 g up to 0.5 m/s, then cruising towards the 300 mm reach (a host
        // stream could do that, meaning to brake late); a NaN once past 297 mm, where the
        // 3.8 mm stop would end beyond the reach.
        let (mut x, mut v, mut nan_sent) = (HOME_MM[0], 0.0f32, false);
        let run = closed(
            &settings,
            cal,
            600,
            |_| {
                if x >= 297.0 && !nan_sent {
                    nan_sent = true;
                    return Some([f32::NAN, 0.0]);
                }
                v = (v + 2.0 * g * DT_S).min(500.0);
                x += v * DT_S;
                Some([x, 0.0])
            },
            |_, e| e,
        );
        let faults: Vec<Fault> = run.samples.iter().filter_map(|s| s.fault).collect();
        assert_eq!(
            faults.first(),
            Some(&Fault::Setpoint(SetpointRefusal::NonFinite)),
            "{faults:?}"
        );
        assert!(
            matches!(
                faults.get(1),
                Some(Fault::StopRefused(SetpointRefusal::Kinematics(_)))
            ),
            "{faults:?}"
        );
        assert!(matches!(
            run.modes[run.modes.len() - 1],
            Mode::SafeState(Fault::StopRefused(_))
        ));
    }

    /// The homing plan is checked at boot: settings whose search runs into a singularity keep
    /// the drives off.
    #[test]
    fn a_homing_plan_near_a_singularity_is_refused_at_boot() {
        use crate::homing::{Direction, HomingFault};
        let img = image();
        let mut settings = Settings::default();
        settings.homing.search_direction = [Direction::Negative, Direction::Positive];
        settings.homing.index_rad = [0.10, -0.10];
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        assert_eq!(l.mode(), Mode::SafeState(Fault::Homing(HomingFault::Plan)));
        assert!(l.start_homing([0.0; 2]).is_err() && !l.drives_enabled());
    }

    /// The host link's Home request: starts homing from `Unhomed` (drives on), nothing twice, and
    /// nothing on a machine that is already running (a homed machine is not re-homed).
    #[test]
    fn a_home_request_starts_homing_only_from_unhomed() {
        let (settings, img) = (Settings::default(), image());
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (_, mut rx) = q.split();
        assert_eq!(l.mode(), Mode::Unhomed);
        assert_eq!(l.homing_phase(), None);
        assert_eq!(
            l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
            Ok(true),
            "drives on"
        );
        assert_eq!(
            (l.mode(), l.homing_phase()),
            (Mode::Homing, Some(HomingPhase::Search(0)))
        );
        assert_eq!(
            l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
            Ok(false),
            "not twice"
        );
        assert_eq!(l.mode(), Mode::Homing);
        // A fault while homing: the safe state; no reset engages the unhomed machine, it goes
        // back to Unhomed with the drives off, and Home runs again (no reboot).
        let mut sample = l.step_homing([0.0; 2], [None; 2]);
        l.latch(Fault::DeadlineMissed, &mut sample);
        assert_eq!(l.mode(), Mode::SafeState(Fault::DeadlineMissed));
        assert_eq!(
            l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
            Ok(false),
            "not before the fault is reset"
        );
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, [0.0; 2]),
            Ok(false),
            "nothing to enable"
        );
        assert_eq!(
            (l.mode(), l.homing_phase(), l.drives_enabled()),
            (Mode::Unhomed, None, false)
        );
        let s = l.step(&mut rx, [0.0; 2]);
        assert_eq!(
            (s.torque_nm, s.fault),
            ([0.0; 2], None),
            "Unhomed: zero torque"
        );
        assert_eq!(
            l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
            Ok(true),
            "homing again, drives on"
        );
        assert_eq!(
            (l.mode(), l.homing_phase()),
            (Mode::Homing, Some(HomingPhase::Search(0)))
        );
        // The same after a fault latched at boot (a watchdog reset) before homing.
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        l.latch_at_boot(Fault::DeadlineMissed);
        assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(false));
        assert!(!l.drives_enabled());
        assert_eq!(l.request(ServoRequest::Reset, &mut rx, [0.0; 2]), Ok(false));
        assert_eq!((l.mode(), l.drives_enabled()), (Mode::Unhomed, false));
        assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(true));
        // A watchdog that did not start is permanent: no reset, no homing, drives off.
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        let nowd = Fault::Watchdog(WatchdogFault::NotStarted);
        l.latch_at_boot(nowd);
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, [0.0; 2]),
            Err(ResetRefusal::Permanent(nowd))
        );
        assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(false));
        assert_eq!(
            (l.mode(), l.drives_enabled()),
            (Mode::SafeState(nowd), false)
        );
        let absolute = Settings {
            homing: crate::homing::HomingSettings {
                absolute_encoders: true,
                ..settings.homing
            },
            ..settings
        };
        let at = cal.command_rad(HOME_MM, 0.05).unwrap();
        let mut l = ServoLoop::boot(&absolute, cal, CalibrationState::Valid, at);
        assert_eq!(l.mode(), Mode::Running);
        assert_eq!(l.request(ServoRequest::Home, &mut rx, at), Ok(false));
        assert_eq!((l.mode(), l.homing_phase()), (Mode::Running, None));
        // Absolute encoders and a watchdog that did not start: no reset engages the drives
        // (before, a reset cleared it like any fault and the machine ran without a watchdog).
        let mut l = ServoLoop::boot(&absolute, cal, CalibrationState::Valid, at);
        l.latch_at_boot(nowd);
        assert_eq!(
            l.request(ServoRequest::Reset, &mut rx, at),
            Err(ResetRefusal::Permanent(nowd))
        );
        assert!(!l.drives_enabled());
    }

    /// Incremental encoders (the default): the loop boots `Unhomed`, drives off, refusing the
    /// queue; homing against the joint plant (indexes at the settings' angles, counters reading
    /// 0 at power-on) references the encoders and engages at home; the tour's first setpoint is
    /// then accepted. An index that never comes ends in the safe state at rest.
    #[test]
    fn an_unhomed_machine_refuses_setpoints_until_homing_engages_it_at_home() {
        use crate::homing::HomingFault;
        let (settings, img) = (Settings::default(), image());
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let power_on = cal.command_rad([230.0, -30.0], 0.05).unwrap();
        for index_on_axis_2 in [true, false] {
            let mut plant = Plant {
                angle_rad: power_on,
                velocity_rad_s: [0.0; 2],
                torque_nm: [0.0; 2],
                enabled: false,
            };
            let relative = |p: &Plant, offset: [f32; 2]| {
                [0, 1].map(|k| p.encoder_rad()[k] - power_on[k] + offset[k])
            };
            let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
            assert_eq!(l.mode(), Mode::Unhomed);
            assert!(!l.drives_enabled());
            let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
            let (mut tx, mut rx) = q.split();
            tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
            let s = l.step(&mut rx, [0.0; 2]);
            assert_eq!((s.torque_nm, s.fault), ([0.0; 2], None));
            assert_eq!(rx.len(), 1, "an unhomed machine takes no setpoint");
            l.start_homing([0.0; 2]).unwrap();
            assert_eq!(l.start_homing([0.0; 2]), Err(Mode::Homing), "not twice");
            plant.enabled = true;
            let index_rad = settings.homing.index_rad;
            let (mut offset, mut latched) = ([0.0; 2], [false; 2]);
            let (mut end, mut before) = (None, plant.angle_rad);
            for k in 0..20_000 {
                let reading = relative(&plant, offset);
                let index = [0, 1].map(|a| {
                    let crossed =
                        (before[a] - index_rad[a]) * (plant.angle_rad[a] - index_rad[a]) <= 0.0;
                    (crossed && !latched[a] && (a == 0 || index_on_axis_2)).then(|| {
                        latched[a] = true;
                        index_rad[a] - power_on[a]
                    })
                });
                before = plant.angle_rad;
                let mut s = l.step_homing(reading, index);
                if s.set_reference {
                    l.referenced(true, &mut s);
                    offset = power_on;
                }
                assert!(s
                    .torque_nm
                    .iter()
                    .all(|t| t.abs() <= settings.homing.torque_limit_nm));
                if s.torque_off {
                    plant.enabled = false;
                }
                plant.torque_nm = s.torque_nm;
                plant.advance();
                if l.mode() != Mode::Homing {
                    end = Some((k, s));
                    break;
                }
            }
            let (k, s) = end.expect("homing did not end");
            if index_on_axis_2 {
                assert_eq!(l.mode(), Mode::Running, "after {k} samples");
                let p = l.setpoint_mm();
                assert!(
                    (p[0] - HOME_MM[0]).abs() < 0.01 && (p[1] - HOME_MM[1]).abs() < 0.01,
                    "engaged at {p:?}"
                );
                // The readings are absolute: the task-space servo takes the queued setpoint.
                let s = l.step(&mut rx, relative(&plant, offset));
                assert!(
                    s.fault.is_none() && s.torque_nm != [0.0; 2] && rx.is_empty(),
                    "{s:?}"
                );
                assert!(plant.enabled);
            } else {
                assert_eq!(
                    l.mode(),
                    Mode::SafeState(Fault::Homing(HomingFault::IndexNotFound(1)))
                );
                assert!(s.torque_off && !plant.enabled);
                assert!(
                    plant.velocity_rad_s.iter().all(|w| w.abs() < 0.05),
                    "{:?}",
                    plant.velocity_rad_s
                );
                assert_eq!(rx.len(), 1);
            }
        }
    }

    /// A calibration committed while the tour runs: the loop switches in the next dwell (not
    /// while moving), without a torque step; after the blend the reference carries the new
    /// grid's correction and the tour goes on without a fault.
    #[test]
    fn a_new_calibration_is_switched_to_at_rest_without_a_jump() {
        let settings = absolute();
        let img = image();
        let g = GridGeometry {
            nx: 3,
            ny: 3,
            x0_mm: 160.0,
            y0_mm: -80.0,
            step_x_mm: 50.0,
            step_y_mm: 80.0,
        };
        let mut new_img = vec![0u8; g.image_len()];
        encode(
            &mut new_img,
            &g,
            &FiveBar::paper_nominal(),
            &[[-3e-4, 2e-4]; 9],
        )
        .unwrap();
        let (old, new) = (grid_cal(&img), grid_cal(&new_img));
        let start = old.command_rad(HOME_MM, 0.05).unwrap();
        let mut plant = Plant {
            angle_rad: start,
            velocity_rad_s: [0.0; 2],
            torque_nm: [0.0; 2],
            enabled: true,
        };
        let mut l = ServoLoop::boot(&settings, old, CalibrationState::Valid, plant.encoder_rad());
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut t = tour();
        let (mut pending, mut switched_at, mut last_torque, mut worst_step) =
            (false, None, [0.0f32; 2], 0.0f32);
        for k in 0..6000 {
            while tx.ready() && !t.finished() {
                tx.enqueue(t.next_setpoint()).unwrap();
            }
            if k == 700 {
                pending = true;
            }
            if pending {
                match l.switch_calibration(new, plant.encoder_rad()) {
                    Ok(()) => {
                        pending = false;
                        switched_at = Some(k);
                    }
                    Err(e) => assert_eq!(e, SwitchRefused::NotAtRest),
                }
            }
            let s = l.step(&mut rx, plant.encoder_rad());
            assert!(s.fault.is_none(), "sample {k}: {:?}", s.fault);
            if switched_at.is_some_and(|at| k >= at && k < at + 50) {
                worst_step = worst_step
                    .max((s.torque_nm[0] - last_torque[0]).abs())
                    .max((s.torque_nm[1] - last_torque[1]).abs());
            }
            last_torque = s.torque_nm;
            plant.torque_nm = s.torque_nm;
            plant.advance();
        }
        let at = switched_at.expect("never switched");
        assert!(at > 700, "switched at {at}");
        // The reference now carries the new correction: commanded minus IK is the new grid's.
        let p = l.setpoint_mm();
        let ik = FiveBar::<f32>::paper_nominal().inverse(p, 0.05).unwrap();
        let d = [l.reference_rad()[0] - ik[0], l.reference_rad()[1] - ik[1]];
        assert!(
            (d[0] + 3e-4).abs() < 2e-6 && (d[1] - 2e-4).abs() < 2e-6,
            "{d:?}"
        );
        println!("switched at sample {at}, largest torque change per sample in the next 50: {worst_step:.3} N·m");
        assert!(worst_step < 1.0, "{worst_step}");
    }
}
