//! The QEMU test scenarios: what `cargo qemu-test` runs, the faults it injects and the checks
//! that end each run. Compiled into the QEMU board's test harness (feature `qemu-harness`) and
//! into the host unit tests; a production build contains none of it.
//!
//! The scenario is chosen by the semihosting command line (`qemu/test.sh` passes its name). An
//! empty or unknown name is [`Scenario::Run`], the production path: nothing injected, nothing
//! checked, no time limit (the real board has no harness at all). A corrupt or missing image is
//! injected from outside, by overwriting the calibration region with QEMU's `-device loader`
//! exactly as a bad flash would leave it; the firmware is the same binary in every scenario.
//!
//! # What the checks read
//! [`Checker::observe`] runs at the end of every servo sample with an [`Observation`]: what the
//! hardware shows (the drive-enable line, the torque the PWM duty registers command, as the QEMU
//! board's simulated hardware holds them) next to the published [`Status`]. The safe state is
//! checked on the hardware, not on status fields the firmware's fault branch writes itself, in
//! the very sample the fault latched and in every sample after it. The calibration is checked
//! against the harness's own reading of the flash region, not the firmware's.
//!
//! # Bounds (`track`)
//! * at least [`MIN_TRACK_TICKS`] samples (2 s of simulated time at 2 kHz) and the whole tour;
//! * no fault, drive enable on in every sample, no overrun, no setpoint underrun, worst step
//!   under the 500 µs deadline;
//! * the grid is applied: every [`GRID_CHECK_PERIOD`] samples, the commanded encoder angles
//!   minus the model's IK of the accepted setpoint equal the grid's correction there, within
//!   [`MAX_GRID_RESIDUAL_RAD`], and the largest correction seen is at least
//!   [`MIN_GRID_CORRECTION_RAD`] (so a grid left out would show);
//! * following error of either joint during the 2 g moves at most
//!   [`MAX_FOLLOWING_ERROR_RAD`];
//! * after the last move has settled ([`SETTLE_TICKS`]), tool error at most
//!   [`MAX_SETTLED_TOOL_ERROR_MM`], measured as `|FK(θ - δ) - setpoint|`.
use kinematics_core::{wrap_angle_rad, Calibration, CorrectionGrid, GridError, KinematicsError, ServoFault};

use crate::calibration::CalibrationState;
use crate::fault::Fault;
use crate::settings::Settings;
use crate::status::Status;

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
/// `track` checks that the grid is applied every this many samples (20 Hz).
pub const GRID_CHECK_PERIOD: u32 = 100;
/// Largest |commanded - IK - correction| accepted (rad): f32 rounding of angles near 1 rad.
pub const MAX_GRID_RESIDUAL_RAD: f32 = 1.0e-6;
/// The largest correction `track` meets must be at least this (rad), 200x the residual bound:
/// otherwise the test could not tell an applied grid from a missing one.
pub const MIN_GRID_CORRECTION_RAD: f32 = 2.0e-4;
/// A fault scenario passes this long after its fault latched: 0.1 s.
pub const AFTER_FAULT_TICKS: u32 = 200;
/// A bad-image scenario passes after this many samples with the drives never enabled: 0.5 s.
pub const BAD_IMAGE_TICKS: u32 = 1_000;
/// No test scenario may run longer than this (6 s): then it fails. [`Scenario::Run`] has no
/// limit and [`Scenario::LongRun`] ends itself at [`LONG_RUN_TICKS`].
pub const MAX_TICKS: u32 = 12_000;
/// [`Scenario::LongRun`] observes the production path for 8 s, past [`MAX_TICKS`].
pub const LONG_RUN_TICKS: u32 = 16_000;
/// The tour of [`Scenario::OutOfReach`]: towards (320, 0) mm, beyond the 300 mm reach.
pub const OUT_OF_REACH_TOUR_MM: [[f32; 2]; 1] = [[320.0, 0.0]];

/// A test scenario (or the production path).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Scenario {
    /// The production path: follow the trajectory forever, inject and check nothing.
    Run,
    /// The production path, observed: after 8 s (past the old 6 s scenario limit) the servo
    /// still runs, the drive enable is on, no fault.
    LongRun,
    /// Follow the workspace tour and check the tracking bounds and the grid.
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
    /// Self-test of the panic path: the harness panics at boot (`qemu/test.sh` expects the
    /// panic handler's line and exit 1).
    Panic,
    /// Self-test of the HardFault path: the harness executes `udf` at boot.
    HardFault,
}

impl Scenario {
    /// Parses the semihosting command line (`"<program> <scenario>"`).
    pub fn from_command_line(line: &str) -> Scenario {
        let name = line.split_whitespace().nth(1).unwrap_or("");
        match name {
            "long-run" => Scenario::LongRun,
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

    /// The built-in tour this scenario runs instead of the board's (`production`).
    pub fn tour_mm(self, production: &'static [[f32; 2]]) -> &'static [[f32; 2]] {
        match self {
            Scenario::OutOfReach => &OUT_OF_REACH_TOUR_MM,
            _ => production,
        }
    }

    /// The setpoint the intake actually queues as the `n`-th (0-based).
    pub fn tamper(self, n: u32, setpoint_mm: [f32; 2]) -> [f32; 2] {
        match self {
            Scenario::NanSetpoint if n == INJECT_AT_SAMPLE => [f32::NAN, setpoint_mm[1]],
            Scenario::Jump if n >= INJECT_AT_SAMPLE => [setpoint_mm[0] + 1.0, setpoint_mm[1]],
            _ => setpoint_mm,
        }
    }

    /// Whether sample `index` must overrun its deadline (deadline fault injection).
    pub fn overrun_at(self, index: u32) -> bool {
        self == Scenario::Overrun && (INJECT_AT_SAMPLE..INJECT_AT_SAMPLE + 3).contains(&index)
    }

    /// Samples after which the scenario fails if it has not concluded.
    pub fn time_limit_ticks(self) -> Option<u32> {
        match self {
            Scenario::Run | Scenario::LongRun => None,
            _ => Some(MAX_TICKS),
        }
    }
}

/// What the harness sees at the end of a sample.
#[derive(Clone, Copy, Debug)]
pub struct Observation<'s> {
    /// The status the servo task published in this sample.
    pub status: &'s Status,
    /// The drive-enable line, as the (simulated) hardware holds it.
    pub drive_enable: bool,
    /// Whether the drive-enable line was ever high since power-on (a sticky probe on the line).
    pub drive_enable_ever: bool,
    /// The torque the PWM duty registers command (N·m), decoded from the duty.
    pub drive_torque_nm: [f32; 2],
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

/// What `track`'s grid check found so far (logged with the verdict).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridCheck {
    /// Samples checked.
    pub checks: u32,
    /// Largest |correction| of either axis at the checked setpoints (rad).
    pub largest_correction_rad: f32,
    /// Largest |commanded - IK - correction| (rad).
    pub worst_residual_rad: f32,
}

/// Checks one scenario, sample by sample.
#[derive(Clone, Debug)]
pub struct Checker<'a> {
    scenario: Scenario,
    /// The harness's own validation of the calibration region (independent of the firmware's).
    image: Result<Calibration<'a>, GridError>,
    min_transmission: f32,
    overrun_streak_limit: u32,
    track_end_tick: u32,
    fault_at: Option<u32>,
    grid: GridCheck,
    settled_tool_error_mm: Option<f32>,
}

impl<'a> Checker<'a> {
    /// A checker for `scenario`. `image` is the harness's own parse of the calibration region;
    /// `track_end_tick` the sample at which the built-in trajectory is done.
    pub fn new(
        scenario: Scenario,
        image: Result<CorrectionGrid<'a>, GridError>,
        settings: &Settings,
        track_end_tick: u32,
    ) -> Self {
        Checker {
            scenario,
            image: image.map(Calibration::from_grid),
            min_transmission: settings.servo.min_transmission,
            overrun_streak_limit: settings.overrun_streak_limit,
            track_end_tick,
            fault_at: None,
            grid: GridCheck::default(),
            settled_tool_error_mm: None,
        }
    }

    /// The scenario checked.
    pub fn scenario(&self) -> Scenario {
        self.scenario
    }

    /// `track`'s grid check so far.
    pub fn grid_check(&self) -> GridCheck {
        self.grid
    }

    /// `track`'s settled tool error, once measured (mm).
    pub fn settled_tool_error_mm(&self) -> Option<f32> {
        self.settled_tool_error_mm
    }

    /// Checks the end of one sample; `Some` ends the run with the verdict.
    pub fn observe(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if let Some(limit) = self.scenario.time_limit_ticks() {
            if s.ticks >= limit {
                return Some(Err("scenario did not finish in time"));
            }
        }
        let refused_out_of_reach = |f: Fault| {
            matches!(
                f,
                Fault::Servo(ServoFault::Grid(GridError::OutsideGrid))
                    | Fault::Servo(ServoFault::Kinematics(
                        KinematicsError::Unreachable | KinematicsError::NearSingularity(_)
                    ))
            )
        };
        match self.scenario {
            Scenario::Run => None,
            Scenario::Panic | Scenario::HardFault => Some(Err("the self-test did not stop the firmware")),
            Scenario::LongRun => self.long_run(o),
            Scenario::Track => self.track(o),
            Scenario::NanSetpoint => self.fault_scenario(o, Some(INJECT_AT_SAMPLE), |f| {
                f == Fault::Servo(ServoFault::NonFiniteSetpoint)
            }),
            Scenario::Jump => {
                self.fault_scenario(o, Some(INJECT_AT_SAMPLE), |f| f == Fault::Servo(ServoFault::SetpointJump))
            }
            Scenario::Overrun => {
                let at = INJECT_AT_SAMPLE + self.overrun_streak_limit.max(1) - 1;
                let verdict = self.fault_scenario(o, Some(at), |f| f == Fault::DeadlineMissed)?;
                Some(verdict.and_then(|()| require(s.overruns >= 3, "overruns not counted")))
            }
            Scenario::OutOfReach => {
                if s.fault.is_some() && self.fault_at.is_none() {
                    // The last accepted setpoint must still be inside the calibrated rectangle.
                    let inside = match &self.image {
                        Ok(Calibration { grid: Some(g), .. }) => g.correction_rad(s.setpoint_mm).is_ok(),
                        _ => false,
                    };
                    if !inside {
                        return Some(Err("an out-of-grid setpoint was accepted"));
                    }
                }
                self.fault_scenario(o, None, refused_out_of_reach)
            }
            Scenario::BadImage(expected) => self.bad_image(o, expected),
        }
    }

    /// A fault is expected (at sample `expected_at` if given): before it the drives must be
    /// on, from its own sample on the hardware must show the safe state.
    fn fault_scenario(&mut self, o: &Observation<'_>, expected_at: Option<u32>, expected: fn(Fault) -> bool) -> Verdict {
        let s = o.status;
        let sample = s.ticks.wrapping_sub(1);
        let Some(fault) = s.fault else {
            if matches!(expected_at, Some(at) if sample >= at) {
                return Some(Err("no fault in the sample the fault was injected in"));
            }
            // Before the fault the machine runs; otherwise the safe-state check proves nothing.
            return (!o.drive_enable).then_some(Err("drives not enabled before the fault"));
        };
        let first = *self.fault_at.get_or_insert(sample);
        if first == sample {
            if !expected(fault) {
                return Some(Err("wrong fault"));
            }
            if matches!(expected_at, Some(at) if at != sample) {
                return Some(Err("fault not in the sample the fault was injected in"));
            }
        }
        if let Err(why) = safe_state(o) {
            return Some(Err(why));
        }
        (sample >= first + AFTER_FAULT_TICKS).then_some(Ok(()))
    }

    fn bad_image(&mut self, o: &Observation<'_>, expected: GridError) -> Verdict {
        let s = o.status;
        let now = (|| {
            require(!o.drive_enable_ever, "drives enabled without a valid image")?;
            require(o.drive_torque_nm == [0.0; 2], "torque commanded without a valid image")
        })();
        if now.is_err() {
            return Some(now);
        }
        (s.ticks >= BAD_IMAGE_TICKS).then(|| {
            require(
                s.calibration == CalibrationState::Refused(expected),
                "bad image not refused, or refused for another reason",
            )?;
            require(s.fault == Some(Fault::Calibration(expected)), "calibration fault not reported")
        })
    }

    fn long_run(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if s.fault.is_some() {
            return Some(Err("fault during the run"));
        }
        if !o.drive_enable {
            return Some(Err("drives disabled during the run"));
        }
        (s.ticks >= LONG_RUN_TICKS).then(|| require(s.setpoint_underruns == 0, "setpoint queue ran empty"))
    }

    fn track(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if s.fault.is_some() {
            return Some(Err("unexpected fault"));
        }
        if !o.drive_enable {
            return Some(Err("drives not enabled"));
        }
        if s.ticks.wrapping_sub(1) % GRID_CHECK_PERIOD == 0 {
            if let Err(why) = self.check_grid_applied(s) {
                return Some(Err(why));
            }
        }
        if s.ticks < self.track_end_tick + SETTLE_TICKS || s.ticks < MIN_TRACK_TICKS {
            return None;
        }
        let cal = match &self.image {
            Ok(cal) => *cal,
            Err(_) => return Some(Err("calibration image not valid")),
        };
        self.settled_tool_error_mm = tool_error_mm(&cal, s.encoder_rad, s.setpoint_mm);
        let tool_error = self.settled_tool_error_mm;
        Some((|| {
            require(s.calibration == CalibrationState::Valid, "calibration image not valid")?;
            require(s.overruns == 0, "deadline overrun")?;
            require(s.worst_step_us < crate::deadline::DEADLINE_US, "step longer than the deadline")?;
            require(s.setpoint_underruns == 0, "setpoint queue ran empty")?;
            require(s.max_following_error_rad <= MAX_FOLLOWING_ERROR_RAD, "following error above bound")?;
            require(self.grid.checks >= 10, "too few grid checks")?;
            require(
                self.grid.largest_correction_rad >= MIN_GRID_CORRECTION_RAD,
                "grid corrections too small to tell an applied grid from a missing one",
            )?;
            require(
                matches!(tool_error, Some(e) if e <= MAX_SETTLED_TOOL_ERROR_MM),
                "settled tool error above bound",
            )
        })())
    }

    /// Commanded encoder angles minus the model's IK of the accepted setpoint must be the
    /// grid's correction at that setpoint.
    fn check_grid_applied(&mut self, s: &Status) -> Result<(), &'static str> {
        let Ok(Calibration { model, grid: Some(grid) }) = &self.image else {
            return Err("calibration image not valid");
        };
        let ik = model.inverse(s.setpoint_mm, self.min_transmission).map_err(|_| "IK refuses an accepted setpoint")?;
        let d = grid.correction_rad(s.setpoint_mm).map_err(|_| "an accepted setpoint is outside the grid")?;
        self.grid.checks += 1;
        for k in 0..2 {
            let residual = wrap_angle_rad(s.reference_rad[k] - ik[k] - d[k]).abs();
            // `!(a <= b)` so that NaN fails too.
            if !(residual <= self.grid.worst_residual_rad) {
                self.grid.worst_residual_rad = residual;
            }
            self.grid.largest_correction_rad = self.grid.largest_correction_rad.max(d[k].abs());
        }
        require(
            self.grid.worst_residual_rad <= MAX_GRID_RESIDUAL_RAD,
            "commanded angle minus model IK is not the grid correction: grid not applied",
        )
    }
}

/// The hardware shows the safe state: drive enable off, zero torque.
fn safe_state(o: &Observation<'_>) -> Result<(), &'static str> {
    require(!o.drive_enable, "drive enable still on after the fault")?;
    require(o.drive_torque_nm == [0.0; 2], "torque commanded after the fault")
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{encode, GridGeometry};
    use kinematics_core::FiveBar;

    /// The QEMU image's geometry with a constant correction.
    fn image(correction_rad: [f32; 2]) -> Vec<u8> {
        let g = GridGeometry { nx: 21, ny: 31, x0_mm: 162.132, y0_mm: -75.0, step_x_mm: 5.0, step_y_mm: 5.0 };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &vec![correction_rad; g.len()]).unwrap();
        img
    }

    const D_RAD: [f32; 2] = [3e-4, -2.5e-4];
    const P_MM: [f32; 2] = [212.132, 0.0];

    /// A running status at `ticks` with the reference IK + `d` at `P_MM`.
    fn running(ticks: u32, d: [f32; 2]) -> Status {
        let ik = FiveBar::<f32>::paper_nominal().inverse(P_MM, 0.05).unwrap();
        let reference = [ik[0] + d[0], ik[1] + d[1]];
        Status {
            ticks,
            overruns: 0,
            worst_step_us: 12.0,
            calibration: CalibrationState::Valid,
            fault: None,
            fault_tick: 0,
            drives_enabled: true,
            setpoint_mm: P_MM,
            reference_rad: reference,
            encoder_rad: reference,
            torque_nm: [0.1, -0.1],
            max_following_error_rad: 1e-4,
            setpoint_underruns: 0,
        }
    }

    fn on(status: &Status) -> Observation<'_> {
        Observation { status, drive_enable: true, drive_enable_ever: true, drive_torque_nm: status.torque_nm }
    }

    fn off(status: &Status) -> Observation<'_> {
        Observation { status, drive_enable: false, drive_enable_ever: true, drive_torque_nm: [0.0; 2] }
    }

    fn checker(scenario: Scenario, img: &[u8]) -> Checker<'_> {
        Checker::new(scenario, CorrectionGrid::parse(img), &Settings::default(), 3_000)
    }

    #[test]
    fn command_line_names() {
        for (line, want) in [
            ("firmware", Scenario::Run),
            ("", Scenario::Run),
            ("firmware bogus", Scenario::Run),
            ("firmware long-run", Scenario::LongRun),
            ("firmware track", Scenario::Track),
            ("firmware nan-setpoint", Scenario::NanSetpoint),
            ("firmware out-of-reach", Scenario::OutOfReach),
            ("firmware jump", Scenario::Jump),
            ("firmware overrun", Scenario::Overrun),
            ("firmware bad-image-crc", Scenario::BadImage(GridError::BadCrc)),
            ("firmware bad-image-magic", Scenario::BadImage(GridError::BadMagic)),
            ("firmware panic", Scenario::Panic),
            ("firmware hard-fault", Scenario::HardFault),
        ] {
            assert_eq!(Scenario::from_command_line(line), want, "{line:?}");
        }
    }

    #[test]
    fn injection_happens_only_where_the_scenario_says() {
        let p = [200.0, 10.0];
        assert!(Scenario::NanSetpoint.tamper(INJECT_AT_SAMPLE, p)[0].is_nan());
        assert_eq!(Scenario::NanSetpoint.tamper(INJECT_AT_SAMPLE + 1, p), p);
        assert_eq!(Scenario::Jump.tamper(INJECT_AT_SAMPLE - 1, p), p);
        assert_eq!(Scenario::Jump.tamper(INJECT_AT_SAMPLE + 5, p), [201.0, 10.0]);
        for s in [Scenario::Run, Scenario::LongRun, Scenario::Track] {
            assert_eq!(s.tamper(INJECT_AT_SAMPLE, p), p);
            assert!(!s.overrun_at(INJECT_AT_SAMPLE));
            assert_eq!(s.tour_mm(&[[1.0, 2.0]]), &[[1.0, 2.0]]);
        }
        let overruns: Vec<u32> = (0..5_000).filter(|&k| Scenario::Overrun.overrun_at(k)).collect();
        assert_eq!(overruns, [INJECT_AT_SAMPLE, INJECT_AT_SAMPLE + 1, INJECT_AT_SAMPLE + 2]);
        assert_eq!(Scenario::OutOfReach.tour_mm(&[]), &OUT_OF_REACH_TOUR_MM);
    }

    /// The bug of issue 18: the production path must never be stopped by a time limit.
    #[test]
    fn the_production_path_has_no_time_limit() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::Run, &img);
        for ticks in [1, MAX_TICKS - 1, MAX_TICKS, LONG_RUN_TICKS, 10 * LONG_RUN_TICKS, u32::MAX] {
            let s = running(ticks, D_RAD);
            assert_eq!(c.observe(&on(&s)), None, "ticks {ticks}");
        }
        // A test scenario is limited.
        let mut c = checker(Scenario::NanSetpoint, &img);
        assert_eq!(c.observe(&on(&running(MAX_TICKS, D_RAD))), Some(Err("scenario did not finish in time")));
    }

    #[test]
    fn long_run_passes_at_8_s_only_if_still_running_without_fault() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::LongRun, &img);
        for ticks in [1, 5_000, MAX_TICKS, LONG_RUN_TICKS - 1] {
            assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
        }
        assert_eq!(c.observe(&on(&running(LONG_RUN_TICKS, D_RAD))), Some(Ok(())));
        let s = running(9_000, D_RAD);
        assert!(matches!(checker(Scenario::LongRun, &img).observe(&off(&s)), Some(Err(_))), "enable line low");
        let s = Status { fault: Some(Fault::DeadlineMissed), ..running(9_000, D_RAD) };
        assert!(matches!(checker(Scenario::LongRun, &img).observe(&on(&s)), Some(Err(_))));
    }

    /// Runs a fault scenario: running until `fault_tick`, then the status shows `fault` and
    /// the hardware shows what `hardware` says. Returns the first verdict.
    fn run_fault(scenario: Scenario, fault_tick: u32, fault: Fault, hardware: fn(&Status) -> Observation<'_>) -> Verdict {
        let img = image(D_RAD);
        let mut c = checker(scenario, &img);
        for sample in 0..MAX_TICKS {
            let mut s = running(sample + 1, D_RAD);
            let o = if sample >= fault_tick {
                s.fault = Some(fault);
                s.fault_tick = fault_tick;
                s.torque_nm = [0.0; 2];
                s.overruns = 3;
                hardware(&s)
            } else {
                on(&s)
            };
            if let Some(v) = c.observe(&o) {
                return Some(v);
            }
        }
        None
    }

    #[test]
    fn a_fault_passes_only_with_the_hardware_in_the_safe_state_from_its_own_sample() {
        let nan = Fault::Servo(ServoFault::NonFiniteSetpoint);
        assert_eq!(run_fault(Scenario::NanSetpoint, INJECT_AT_SAMPLE, nan, off), Some(Ok(())));
        // The firmware's status says "fault" but the drive-enable line stayed high.
        fn enable_left_on(s: &Status) -> Observation<'_> {
            Observation { drive_enable: true, ..off(s) }
        }
        assert_eq!(
            run_fault(Scenario::NanSetpoint, INJECT_AT_SAMPLE, nan, enable_left_on),
            Some(Err("drive enable still on after the fault"))
        );
        fn torque_left_on(s: &Status) -> Observation<'_> {
            Observation { drive_torque_nm: [0.0, 0.2], ..off(s) }
        }
        assert_eq!(
            run_fault(Scenario::NanSetpoint, INJECT_AT_SAMPLE, nan, torque_left_on),
            Some(Err("torque commanded after the fault"))
        );
        assert_eq!(
            run_fault(Scenario::NanSetpoint, INJECT_AT_SAMPLE + 1, nan, off),
            Some(Err("no fault in the sample the fault was injected in"))
        );
        assert_eq!(run_fault(Scenario::NanSetpoint, 10, nan, off), Some(Err("fault not in the sample the fault was injected in")));
        assert_eq!(
            run_fault(Scenario::Jump, INJECT_AT_SAMPLE, nan, off),
            Some(Err("wrong fault"))
        );
        assert_eq!(run_fault(Scenario::Overrun, INJECT_AT_SAMPLE + 2, Fault::DeadlineMissed, off), Some(Ok(())));
        let refused = Fault::Servo(ServoFault::Grid(GridError::OutsideGrid));
        assert_eq!(run_fault(Scenario::OutOfReach, 1234, refused, off), Some(Ok(())));
        // Drives off before any fault: the safe-state check would prove nothing.
        let img = image(D_RAD);
        let s = running(5, D_RAD);
        assert_eq!(checker(Scenario::NanSetpoint, &img).observe(&off(&s)), Some(Err("drives not enabled before the fault")));
    }

    #[test]
    fn out_of_reach_fails_if_an_out_of_grid_setpoint_was_accepted() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::OutOfReach, &img);
        let s = Status {
            fault: Some(Fault::Servo(ServoFault::Kinematics(KinematicsError::Unreachable))),
            setpoint_mm: [290.0, 0.0],
            ..running(3_000, D_RAD)
        };
        assert_eq!(c.observe(&off(&s)), Some(Err("an out-of-grid setpoint was accepted")));
    }

    #[test]
    fn a_bad_image_passes_only_if_the_drives_were_never_enabled() {
        let refused = |ticks| Status {
            calibration: CalibrationState::Refused(GridError::BadCrc),
            fault: Some(Fault::Calibration(GridError::BadCrc)),
            torque_nm: [0.0; 2],
            ..running(ticks, D_RAD)
        };
        fn never(s: &Status) -> Observation<'_> {
            Observation { drive_enable_ever: false, ..off(s) }
        }
        let mut c = Checker::new(Scenario::BadImage(GridError::BadCrc), Err(GridError::BadCrc), &Settings::default(), 0);
        for ticks in 1..BAD_IMAGE_TICKS {
            assert_eq!(c.observe(&never(&refused(ticks))), None);
        }
        assert_eq!(c.observe(&never(&refused(BAD_IMAGE_TICKS))), Some(Ok(())));
        // Enabled once, even if off now.
        assert_eq!(c.observe(&off(&refused(5))), Some(Err("drives enabled without a valid image")));
        let wrong = Status { calibration: CalibrationState::Refused(GridError::BadMagic), ..refused(BAD_IMAGE_TICKS) };
        assert!(matches!(c.observe(&never(&wrong)), Some(Err(_))));
    }

    /// Runs `track` to its end with the reference carrying correction `applied` while the
    /// image holds `D_RAD`.
    fn run_track(applied: [f32; 2], img_d: [f32; 2]) -> Verdict {
        let img = image(img_d);
        let mut c = checker(Scenario::Track, &img);
        for ticks in 1..MAX_TICKS {
            if let Some(v) = c.observe(&on(&running(ticks, applied))) {
                return Some(v);
            }
        }
        None
    }

    #[test]
    fn track_passes_only_if_the_grid_is_applied_and_large_enough_to_tell() {
        assert_eq!(run_track(D_RAD, D_RAD), Some(Ok(())));
        // Grid validated but not applied: the reference is the bare IK.
        assert_eq!(
            run_track([0.0; 2], D_RAD),
            Some(Err("commanded angle minus model IK is not the grid correction: grid not applied"))
        );
        // An image whose corrections are too small to tell.
        assert_eq!(
            run_track([1e-5, 0.0], [1e-5, 0.0]),
            Some(Err("grid corrections too small to tell an applied grid from a missing one"))
        );
        let img = image(D_RAD);
        let mut c = checker(Scenario::Track, &img);
        for ticks in 1..5_000 {
            c.observe(&on(&running(ticks, D_RAD)));
        }
        let g = c.grid_check();
        assert!(g.checks >= 10 && g.worst_residual_rad <= MAX_GRID_RESIDUAL_RAD, "{g:?}");
        assert_eq!(g.largest_correction_rad, 3e-4);
    }

    #[test]
    fn track_fails_on_a_fault_a_low_enable_line_or_a_bound() {
        let img = image(D_RAD);
        let s = running(10, D_RAD);
        assert_eq!(checker(Scenario::Track, &img).observe(&off(&s)), Some(Err("drives not enabled")));
        let s = Status { fault: Some(Fault::Drive), ..running(10, D_RAD) };
        assert_eq!(checker(Scenario::Track, &img).observe(&on(&s)), Some(Err("unexpected fault")));
        let end = MIN_TRACK_TICKS.max(3_000 + SETTLE_TICKS);
        for (bad, why) in [
            (Status { overruns: 1, ..running(end, D_RAD) }, "deadline overrun"),
            (Status { worst_step_us: 501.0, ..running(end, D_RAD) }, "step longer than the deadline"),
            (Status { setpoint_underruns: 1, ..running(end, D_RAD) }, "setpoint queue ran empty"),
            (Status { max_following_error_rad: 3e-4, ..running(end, D_RAD) }, "following error above bound"),
            (Status { encoder_rad: [0.81, -0.75], ..running(end, D_RAD) }, "settled tool error above bound"),
        ] {
            let mut c = checker(Scenario::Track, &img);
            for ticks in 1..end {
                assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
            }
            assert_eq!(c.observe(&on(&bad)), Some(Err(why)));
        }
    }

    #[test]
    fn self_tests_that_return_fail() {
        let img = image(D_RAD);
        for s in [Scenario::Panic, Scenario::HardFault] {
            assert!(matches!(checker(s, &img).observe(&on(&running(1, D_RAD))), Some(Err(_))));
        }
    }

    #[test]
    fn tool_error_undoes_the_correction() {
        let img = image(D_RAD);
        let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
        let theta = cal.command_rad(P_MM, 0.05).unwrap();
        assert!(tool_error_mm(&cal, theta, P_MM).unwrap() < 1e-4);
        let bare = FiveBar::<f32>::paper_nominal().inverse(P_MM, 0.05).unwrap();
        // Without the correction the tool is ~50 µm off (3e-4 rad at 150 mm).
        assert!(tool_error_mm(&cal, bare, P_MM).unwrap() > 0.02);
    }
}
