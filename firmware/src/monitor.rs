//! What the servo task publishes: counters, deadline figures, the latched fault.
use kinematics_core::{GridError, ServoFault};

use crate::calibration::CalibrationState;

/// Why the drives are off. Latched: only a reset clears it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Fault {
    /// The servo step refused a sample (non-finite value, unreachable or singular setpoint,
    /// outside the grid, a jump beyond 5 g, following error).
    Servo(ServoFault),
    /// `overrun_streak_limit` consecutive samples missed their 500 µs deadline.
    DeadlineMissed,
    /// Writing a PWM duty failed.
    Drive,
    /// The calibration image was refused at boot (drives never enabled).
    Calibration(GridError),
}

/// Snapshot the servo task publishes every sample (read by telemetry and the test checks).
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct Status {
    /// Servo samples run since the timer started.
    pub ticks: u32,
    /// Samples whose step did not finish before the next tick.
    pub overruns: u32,
    /// Longest step (timer interrupt to torque written, µs).
    pub worst_step_us: f32,
    pub calibration: CalibrationState,
    pub fault: Option<Fault>,
    /// Sample at which the fault latched.
    pub fault_tick: u32,
    pub drives_enabled: bool,
    /// Whether the drives were ever enabled since boot.
    pub drives_ever_enabled: bool,
    /// Last setpoint the servo accepted (mm).
    pub setpoint_mm: [f32; 2],
    /// Last encoder reading (rad).
    pub encoder_rad: [f32; 2],
    /// Last torque command (N·m); zero in the safe state.
    pub torque_nm: [f32; 2],
    /// Largest |following error| of either axis while running (rad).
    pub max_following_error_rad: f32,
    /// Largest |torque command| written after the fault latched (N·m): must stay 0.
    pub max_torque_after_fault_nm: f32,
    /// Samples that found the setpoint queue empty (the last setpoint was held).
    pub setpoint_underruns: u32,
}

impl Status {
    pub const fn new(calibration: CalibrationState) -> Self {
        Status {
            ticks: 0,
            overruns: 0,
            worst_step_us: 0.0,
            calibration,
            fault: None,
            fault_tick: 0,
            drives_enabled: false,
            drives_ever_enabled: false,
            setpoint_mm: [0.0; 2],
            encoder_rad: [0.0; 2],
            torque_nm: [0.0; 2],
            max_following_error_rad: 0.0,
            max_torque_after_fault_nm: 0.0,
            setpoint_underruns: 0,
        }
    }
}

/// Deadline bookkeeping of the servo task.
#[derive(Clone, Copy, Debug, Default)]
pub struct Deadline {
    pub overruns: u32,
    pub streak: u32,
    pub worst_step_us: f32,
}

impl Deadline {
    /// Records one sample; returns `true` when the overrun streak reaches `streak_limit`.
    pub fn record(&mut self, step_us: f32, overrun: bool, streak_limit: u32) -> bool {
        if step_us > self.worst_step_us {
            self.worst_step_us = step_us;
        }
        if overrun {
            self.overruns += 1;
            self.streak += 1;
        } else {
            self.streak = 0;
        }
        self.streak >= streak_limit
    }
}
