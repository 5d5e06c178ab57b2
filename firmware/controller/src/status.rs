//! What the servo task publishes every sample: counters, deadline figures, the latched fault,
//! the last setpoint, reference, encoder reading and torque. Telemetry reads it; so does the
//! QEMU test harness, next to the simulated drive registers.
use crate::calibration::CalibrationState;
use crate::calibration_slots::{CalibrationId, SlotError};
use crate::deadline::Deadline;
use crate::fault::Fault;
use crate::homing::HomingPhase;
use crate::servo_loop::{Mode, Sample, ServoLoop, SwitchOutcome};

/// Snapshot the servo task publishes every sample.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Servo samples run since the timer started.
    pub ticks: u32,
    /// Samples whose step did not finish before the next tick.
    pub overruns: u32,
    /// Longest step (timer interrupt to torque written, µs).
    pub worst_step_us: f32,
    /// What the boot check found in the calibration region.
    pub calibration: CalibrationState,
    /// Running, stopping, holding or safe state (with the fault that led there).
    pub mode: Mode,
    /// The first fault latched (at boot or while running).
    pub fault: Option<Fault>,
    /// Sample at which the fault latched (0 for a fault at boot).
    pub fault_tick: u32,
    /// Whether the servo loop wants the drives enabled (the board's line is the truth).
    pub drives_enabled: bool,
    /// The distance of the controlled stop under way or done (mm; 0 without one).
    pub stop_distance_mm: f32,
    /// Last setpoint the servo accepted (mm).
    pub setpoint_mm: [f32; 2],
    /// The last sample's setpoint differs from the one before it: the setpoint still changes.
    /// What says "moving" when the motion source is not the host link (the built-in tour),
    /// whose hold point the link cannot see.
    pub setpoint_moved: bool,
    /// Encoder angles the servo commanded for that setpoint (model IK plus grid correction,
    /// unwrapped next to the previous reference; rad).
    pub reference_rad: [f32; 2],
    /// Last encoder reading (rad).
    pub encoder_rad: [f32; 2],
    /// Last torque command (N·m); zero in the safe state.
    pub torque_nm: [f32; 2],
    /// Largest |following error| of either axis while running (rad).
    pub max_following_error_rad: f32,
    /// Samples that found the setpoint queue empty (the last setpoint was held).
    pub setpoint_underruns: u32,
    /// The calibration image in force: its slot, commit sequence and CRC-32 (`None`: no valid
    /// image). Set at boot and when the servo switches to a newly committed one.
    pub calibration_id: Option<CalibrationId>,
    /// The outcome of the last calibration upload (`None`: none since boot).
    pub last_upload: Option<Result<CalibrationId, SlotError>>,
    /// A committed calibration the servo has not switched to yet (it does at the next rest).
    pub calibration_pending: Option<CalibrationId>,
    /// The move after a calibration switch is under way: the setpoint is on its way back to
    /// where the motion source holds it (a source resumed now would hold the wrong point).
    pub blending: bool,
    /// What became of the last committed calibration the servo was offered (`None`: none since
    /// boot).
    pub last_switch: Option<SwitchOutcome>,
    /// Where homing is ([`ServoLoop::homing_phase`]; `None`: not started, or absolute encoders).
    pub homing: Option<HomingPhase>,
}

impl Status {
    /// The status after boot, before the first sample, with the encoders read at boot.
    pub fn at_boot(
        calibration: CalibrationState,
        servo_loop: &ServoLoop<'_>,
        encoder_rad: [f32; 2],
    ) -> Self {
        let mode = servo_loop.mode();
        Status {
            mode,
            ticks: 0,
            overruns: 0,
            worst_step_us: 0.0,
            calibration,
            fault: mode.fault(),
            fault_tick: 0,
            drives_enabled: servo_loop.drives_enabled(),
            stop_distance_mm: 0.0,
            setpoint_mm: servo_loop.setpoint_mm(),
            setpoint_moved: false,
            reference_rad: servo_loop.reference_rad(),
            encoder_rad,
            torque_nm: [0.0; 2],
            max_following_error_rad: 0.0,
            setpoint_underruns: 0,
            calibration_id: None,
            last_upload: None,
            calibration_pending: None,
            blending: false,
            last_switch: None,
            homing: servo_loop.homing_phase(),
        }
    }

    /// Records the sample the servo loop just ran (`mode` is the loop's mode after it,
    /// `stop_distance_mm` that of its stop, if any).
    pub fn record(
        &mut self,
        sample: &Sample,
        mode: Mode,
        deadline: &Deadline,
        stop_distance_mm: f32,
    ) {
        self.ticks = sample.index.wrapping_add(1);
        self.overruns = deadline.overruns;
        self.worst_step_us = deadline.worst_step_us;
        self.encoder_rad = sample.encoder_rad;
        self.torque_nm = sample.torque_nm;
        self.setpoint_moved = sample.setpoint_mm != self.setpoint_mm;
        self.setpoint_mm = sample.setpoint_mm;
        self.reference_rad = sample.reference_rad;
        if sample.underrun {
            self.setpoint_underruns += 1;
        }
        self.mode = mode;
        self.stop_distance_mm = stop_distance_mm;
        self.drives_enabled = mode.drives_on();
        if mode == Mode::Running {
            self.max_following_error_rad =
                self.max_following_error_rad.max(sample.following_error_rad);
        }
        if let Some(fault) = sample.fault.or(mode.fault()) {
            if self.fault.is_none() {
                self.fault = Some(fault);
                self.fault_tick = sample.index;
            }
        }
    }

    /// Publishes the sample the servo task just ran: [`Status::record`] with the loop's mode,
    /// deadline and stop, its homing phase and pending calibration, and the calibration switch
    /// of this sample (`switch`), if any.
    pub fn publish(
        &mut self,
        sample: &Sample,
        servo_loop: &ServoLoop<'_>,
        switch: Option<SwitchOutcome>,
    ) {
        let stop_mm = servo_loop.stop_profile().map_or(0.0, |p| p.distance_mm());
        self.record(sample, servo_loop.mode(), servo_loop.deadline(), stop_mm);
        self.homing = servo_loop.homing_phase();
        self.calibration_pending = servo_loop.pending_calibration();
        self.blending = servo_loop.blending();
        if let Some(outcome) = switch {
            if let SwitchOutcome::Switched(id) = outcome {
                self.calibration_id = Some(id);
            }
            self.last_switch = Some(outcome);
        }
    }
}
