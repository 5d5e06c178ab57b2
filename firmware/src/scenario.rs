//! Test scenarios: what `cargo qemu-test` runs, the faults it injects and the bounds it checks.
//!
//! The scenario is chosen by the semihosting command line (`qemu/test.sh` passes its name);
//! the real board always runs [`Scenario::Run`], which injects nothing and checks nothing.
//! A corrupt or missing image is injected from outside, by overwriting the calibration region
//! with QEMU's `-device loader` exactly as a bad flash would leave it; the firmware is the same
//! binary in every scenario.
//!
//! # Bounds (`track`)
//! * at least [`MIN_TRACK_TICKS`] samples (2 s of simulated time at 2 kHz) and the whole tour;
//! * no fault, no overrun, no setpoint underrun, worst step under the 500 µs deadline;
//! * following error of either joint during the 2 g moves at most
//!   [`MAX_FOLLOWING_ERROR_RAD`];
//! * after the last move has settled ([`SETTLE_TICKS`]), tool error at most
//!   [`MAX_SETTLED_TOOL_ERROR_MM`], measured as `|FK(θ - δ) - setpoint|`.
use kinematics_core::{Calibration, GridError, KinematicsError, ServoFault};

use crate::calibration::CalibrationState;
use crate::monitor::{Fault, Status};

/// Sample at which the injected faults are applied (1 s into the run).
pub const INJECT_AT_SAMPLE: u32 = 2_000;
/// Minimum run of the tracking test: 2 s at 2 kHz.
pub const MIN_TRACK_TICKS: u32 = 4_000;
/// Largest following error accepted during the moves (rad); 2e-4 rad is 30 µm at 150 mm.
pub const MAX_FOLLOWING_ERROR_RAD: f32 = 2.0e-4;
/// Largest settled tool error (mm): 1 µm.
pub const MAX_SETTLED_TOOL_ERROR_MM: f32 = 1.0e-3;
/// Settling time after the last move before the tool error is checked: 0.25 s.
pub const SETTLE_TICKS: u32 = 500;
/// A fault scenario is checked this long after its fault latched: 0.1 s.
pub const AFTER_FAULT_TICKS: u32 = 200;
/// No scenario may run longer than this (6 s): then it fails.
pub const MAX_TICKS: u32 = 12_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Scenario {
    /// Normal operation: follow the trajectory forever, check nothing (the real board).
    Run,
    /// Follow the workspace tour and check the tracking bounds.
    Track,
    /// A NaN setpoint at 1 s: `Servo(NonFiniteSetpoint)`, drives off, torque zero.
    NanSetpoint,
    /// A move towards (320, 0) mm, beyond the 300 mm reach: refused at the grid edge or by the
    /// IK before any out-of-reach setpoint is accepted.
    OutOfReach,
    /// A 1 mm setpoint step at 1 s: `Servo(SetpointJump)`.
    Jump,
    /// Three 700 µs steps in a row at 1 s: `DeadlineMissed`.
    Overrun,
    /// A bad image flashed by the test, refused with this error: drives never enabled.
    BadImage(GridError),
    /// Self-tests of the failure paths: must make QEMU exit non-zero.
    Panic,
    HardFault,
}

impl Scenario {
    /// Parses the semihosting command line ("<program> <scenario>").
    pub fn from_command_line(line: &str) -> Scenario {
        let name = line.split_whitespace().nth(1).unwrap_or("");
        match name {
            "track" => Scenario::Track,
            "nan-setpoint" => Scenario::NanSetpoint,
            "out-of-reach" => Scenario::OutOfReach,
            "jump" => Scenario::Jump,
            "overrun" => Scenario::Overrun,
            "bad-image-crc" => Scenario::BadImage(GridError::BadCrc),
            "bad-image-magic" => Scenario::BadImage(GridError::BadMagic),
            "panic" => Scenario::Panic,
            "hard-fault" => Scenario::HardFault,
            _ => Scenario::Run,
        }
    }

    /// The setpoint the intake actually queues as sample `n`.
    pub fn tamper(self, n: u32, setpoint_mm: [f32; 2]) -> [f32; 2] {
        match self {
            Scenario::NanSetpoint if n == INJECT_AT_SAMPLE => [f32::NAN, setpoint_mm[1]],
            Scenario::Jump if n >= INJECT_AT_SAMPLE => [setpoint_mm[0] + 1.0, setpoint_mm[1]],
            _ => setpoint_mm,
        }
    }

    /// Whether the servo task must burn time in sample `tick` (deadline fault injection).
    pub fn overrun_at(self, tick: u32) -> bool {
        self == Scenario::Overrun && (INJECT_AT_SAMPLE..INJECT_AT_SAMPLE + 3).contains(&tick)
    }
}

/// Outcome of a check: `None` while the scenario is still running.
pub type Verdict = Option<Result<(), &'static str>>;

fn require(ok: bool, why: &'static str) -> Result<(), &'static str> {
    if ok {
        Ok(())
    } else {
        Err(why)
    }
}

/// Tool error `|FK(θ - δ(p)) - p|` (mm) of encoder angles `theta_rad` against setpoint `p_mm`.
pub fn tool_error_mm(cal: &Calibration<'_>, theta_rad: [f32; 2], p_mm: [f32; 2]) -> Option<f32> {
    let d = match &cal.grid {
        Some(g) => g.correction_rad(p_mm).ok()?,
        None => [0.0; 2],
    };
    let tool = cal.model.forward([theta_rad[0] - d[0], theta_rad[1] - d[1]], 0.0).ok()?;
    Some(libm::hypotf(tool[0] - p_mm[0], tool[1] - p_mm[1]))
}

/// Checks the scenario's bounds against the published status. `track_end_tick` is the sample
/// at which the trajectory is done; `deadline_us` the step deadline.
pub fn check(
    scenario: Scenario,
    s: &Status,
    cal: &Calibration<'_>,
    track_end_tick: u32,
    deadline_us: f32,
) -> Verdict {
    if s.ticks >= MAX_TICKS {
        return Some(Err("scenario did not finish in time"));
    }
    let faulted_long_enough = s.fault.is_some() && s.ticks >= s.fault_tick + AFTER_FAULT_TICKS;
    let safe = |s: &Status| {
        require(!s.drives_enabled, "drives still enabled after the fault")?;
        require(s.max_torque_after_fault_nm == 0.0, "torque commanded after the fault")
    };
    match scenario {
        Scenario::Run | Scenario::Panic | Scenario::HardFault => None,
        Scenario::Track => {
            if let Some(f) = s.fault {
                defmt::error!("track: unexpected fault {}", f);
                return Some(Err("unexpected fault"));
            }
            if s.ticks < track_end_tick + SETTLE_TICKS || s.ticks < MIN_TRACK_TICKS {
                return None;
            }
            let tool_error = tool_error_mm(cal, s.encoder_rad, s.setpoint_mm);
            defmt::info!(
                "track: ticks {} overruns {} worst step {} us, max following error {} rad, settled tool error {} mm",
                s.ticks, s.overruns, s.worst_step_us, s.max_following_error_rad, tool_error
            );
            Some((|| {
                require(s.calibration == CalibrationState::Valid, "calibration image not valid")?;
                require(s.drives_enabled, "drives not enabled")?;
                require(s.overruns == 0, "deadline overrun")?;
                require(s.worst_step_us < deadline_us, "step longer than the deadline")?;
                require(s.setpoint_underruns == 0, "setpoint queue ran empty")?;
                require(
                    s.max_following_error_rad <= MAX_FOLLOWING_ERROR_RAD,
                    "following error above bound",
                )?;
                require(
                    matches!(tool_error, Some(e) if e <= MAX_SETTLED_TOOL_ERROR_MM),
                    "settled tool error above bound",
                )
            })())
        }
        Scenario::NanSetpoint => faulted_long_enough.then(|| {
            require(s.fault == Some(Fault::Servo(ServoFault::NonFiniteSetpoint)), "wrong fault")?;
            require(s.fault_tick == INJECT_AT_SAMPLE, "fault not at the NaN sample")?;
            safe(s)
        }),
        Scenario::Jump => faulted_long_enough.then(|| {
            require(s.fault == Some(Fault::Servo(ServoFault::SetpointJump)), "wrong fault")?;
            require(s.fault_tick == INJECT_AT_SAMPLE, "fault not at the jump sample")?;
            safe(s)
        }),
        Scenario::OutOfReach => faulted_long_enough.then(|| {
            let refused = matches!(
                s.fault,
                Some(Fault::Servo(ServoFault::Grid(GridError::OutsideGrid)))
                    | Some(Fault::Servo(ServoFault::Kinematics(
                        KinematicsError::Unreachable | KinematicsError::NearSingularity(_)
                    )))
            );
            require(refused, "wrong fault")?;
            // The last accepted setpoint must still be inside the calibrated rectangle.
            let inside = match &cal.grid {
                Some(g) => g.correction_rad(s.setpoint_mm).is_ok(),
                None => false,
            };
            require(inside, "an out-of-grid setpoint was accepted")?;
            safe(s)
        }),
        Scenario::Overrun => faulted_long_enough.then(|| {
            require(s.fault == Some(Fault::DeadlineMissed), "wrong fault")?;
            require(s.overruns >= 3, "overruns not counted")?;
            safe(s)
        }),
        Scenario::BadImage(expected) => (s.ticks >= MIN_TRACK_TICKS / 4).then(|| {
            require(
                s.calibration == CalibrationState::Refused(expected),
                "bad image not refused, or refused for another reason",
            )?;
            require(!s.drives_ever_enabled, "drives enabled without a valid image")?;
            require(s.torque_nm == [0.0; 2], "torque commanded without a valid image")?;
            require(s.fault == Some(Fault::Calibration(expected)), "calibration fault not reported")
        }),
    }
}
