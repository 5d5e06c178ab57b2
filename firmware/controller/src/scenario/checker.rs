//! The checks that end each scenario's run ([`Checker::observe`], every sample, dispatched on
//! the registry's [`Check`]), and of the watchdog's interrupt ([`check_watchdog`]). What each
//! checks: the module doc of [`super`].
use kinematics_core::{wrap_angle_rad, Calibration, CorrectionGrid, GridError};

pub use super::observation::Observation;
use super::observation::{require, safe_state, PlantState};
use super::stop_check::{CoastModel, StopCheck, StopReport};
use super::{
    Check, Expected, Injection, Scenario, Window, BAD_IMAGE_TICKS, DUTY_STEP_NM, GRID_CHECK_PERIOD,
    LONG_RUN_TICKS, MAX_FOLLOWING_ERROR_5G_UM, MAX_FOLLOWING_ERROR_RAD, MAX_GRID_RESIDUAL_RAD,
    MAX_HOMED_ENCODER_ERROR_RAD, MAX_SETTLED_TOOL_ERROR_MM, MIN_GRID_CORRECTION_RAD,
    MIN_SAMPLES_AT_5G, MIN_TRACK_TICKS, SETTLE_TICKS, WATCHDOG_TIMING_TOLERANCE_US,
};
use crate::calibration::{CalibrationState, ImageError};
use crate::calibration_slots::SlotError;
use crate::fault::{Fault, StopCategory};
use crate::homing::HomingFault;
use crate::servo_loop::Mode;
use crate::settings::Settings;
use crate::status::Status;
use crate::stop::{MotionState, StopProfile};
use crate::watchdog::{WatchdogFault, TIMEOUT_US};

/// What the QEMU board's watchdog interrupt found (times in µs on the harness's own clock).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WatchdogObservation {
    /// When the harness stalled the servo task (`None`: it had not).
    pub stalled_at_us: Option<f32>,
    /// When the servo task last fed the watchdog (`None`: never).
    pub last_feed_at_us: Option<f32>,
    /// When the watchdog's interrupt came.
    pub fired_at_us: f32,
    /// The drive-enable line as the interrupt found it, before its handler removed torque.
    pub drive_enable_at_fire: bool,
    /// The drive-enable line after the handler.
    pub drive_enable: bool,
    /// The torque the PWM registers command after the handler (N·m).
    pub drive_torque_nm: [f32; 2],
}

/// What a watchdog interrupt means ([`Scenario::watchdog_fired`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WatchdogVerdict {
    /// `stalled-task`: the checks passed; wait for the watchdog's reset.
    AsExpected,
    /// The production path: torque is off; wait for the reset.
    Production,
    /// The run fails with this reason.
    Fail(&'static str),
}

/// The checks of a watchdog interrupt in `stalled-task` (see the module doc).
pub fn check_watchdog(o: &WatchdogObservation) -> Result<(), &'static str> {
    let Some(stalled_at_us) = o.stalled_at_us else {
        return Err("watchdog fired before the servo task was stalled");
    };
    let Some(last_feed_at_us) = o.last_feed_at_us else {
        return Err("the watchdog was never fed");
    };
    require(
        o.drive_enable_at_fire,
        "drives already off when the watchdog fired: the test proves nothing",
    )?;
    require(
        !o.drive_enable,
        "drive enable still on after the watchdog fired",
    )?;
    require(
        o.drive_torque_nm == [0.0; 2],
        "torque commanded after the watchdog fired",
    )?;
    // `!(a <= b)` refuses NaN as well.
    require(
        o.fired_at_us - stalled_at_us <= TIMEOUT_US,
        "torque not removed within the watchdog timeout of the stall",
    )?;
    require(
        (o.fired_at_us - last_feed_at_us - TIMEOUT_US).abs() <= WATCHDOG_TIMING_TOLERANCE_US,
        "the watchdog did not fire its stated timeout after the last feed",
    )
}

/// Outcome of a check: `None` while the scenario is still running.
pub type Verdict = Option<Result<(), &'static str>>;

/// Tool error `|FK(θ - δ(p)) - p|` (mm) of encoder angles `theta_rad` against setpoint `p_mm`.
pub fn tool_error_mm(cal: &Calibration<'_>, theta_rad: [f32; 2], p_mm: [f32; 2]) -> Option<f32> {
    let d = match &cal.grid {
        Some(g) => g.correction_rad(p_mm).ok()?,
        None => [0.0; 2],
    };
    let tool = cal
        .model
        .forward([theta_rad[0] - d[0], theta_rad[1] - d[1]], 0.0)
        .ok()?;
    Some(libm::hypotf(tool[0] - p_mm[0], tool[1] - p_mm[1]))
}

/// The tool position of joint angles `theta_rad` (mm): `FK(θ - δ(FK(θ)))`, the correction
/// taken as zero outside the grid; `None` where the forward kinematics refuse. Returns it with
/// whether it lies in the calibrated rectangle.
pub fn tool_mm(cal: &Calibration<'_>, theta_rad: [f32; 2]) -> (Option<[f32; 2]>, bool) {
    let Ok(p) = cal.model.forward(theta_rad, 0.0) else {
        return (None, false);
    };
    let Some(grid) = &cal.grid else {
        return (Some(p), false);
    };
    let d = grid.correction_rad(p).unwrap_or([0.0; 2]);
    match cal
        .model
        .forward([theta_rad[0] - d[0], theta_rad[1] - d[1]], 0.0)
    {
        Ok(tool) => (Some(tool), grid.correction_rad(tool).is_ok()),
        Err(_) => (None, false),
    }
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
    settings: Settings,
    track_end_tick: u32,
    injection: Injection,
    coast: CoastModel,
    /// The last three setpoints the status showed, newest first (a stop's plan starts there).
    setpoints_mm: [[f32; 2]; 3],
    /// The plant's joint angles in the previous sample (the tool's speed at the fault).
    last_joint_rad: [f32; 2],
    fault_at: Option<u32>,
    stop: Option<StopCheck>,
    grid: GridCheck,
    settled_tool_error_mm: Option<f32>,
    motion: MotionCheck,
    /// The sample homing ended and the servo engaged (`homing`).
    homed_at: Option<u32>,
    /// Grid checks done when the checked image was replaced (the upload scenarios).
    grid_checks_at_switch: Option<u32>,
}

/// What `track-5g`'s motion check found so far (logged with the verdict).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionCheck {
    /// Samples whose setpoint acceleration was 4.75 g or more.
    pub samples_at_5g: u32,
    /// Largest following error at the tool (µm).
    pub max_following_error_um: f32,
    /// The last two accepted setpoints (mm), for the acceleration.
    last_setpoints_mm: [[f32; 2]; 2],
    /// Samples seen.
    seen: u32,
}

impl<'a> Checker<'a> {
    /// A checker for `scenario`. `image` is the harness's own parse of the calibration region;
    /// `track_end_tick` the sample at which the built-in trajectory is done; `injection` where
    /// the faults go; `coast` the plant's inertia, viscous friction and the drives' dynamic
    /// braking (the category-0 bound).
    pub fn new(
        scenario: Scenario,
        image: Result<CorrectionGrid<'a>, GridError>,
        settings: &Settings,
        track_end_tick: u32,
        injection: Injection,
        coast: CoastModel,
    ) -> Self {
        Checker {
            scenario,
            image: image.map(Calibration::from_grid),
            settings: *settings,
            track_end_tick,
            injection,
            coast,
            setpoints_mm: [[0.0; 2]; 3],
            last_joint_rad: [0.0; 2],
            fault_at: None,
            stop: None,
            grid: GridCheck::default(),
            settled_tool_error_mm: None,
            motion: MotionCheck::default(),
            homed_at: None,
            grid_checks_at_switch: None,
        }
    }

    /// The image in force changed (the harness's own reading of the slots): check the grid
    /// against `image` from now on.
    pub fn switch_image(&mut self, image: Result<CorrectionGrid<'a>, GridError>) {
        self.image = image.map(Calibration::from_grid);
        self.grid_checks_at_switch = Some(self.grid.checks);
        // The blend after the switch delays the tour by a few samples.
        self.track_end_tick += 100;
    }

    /// The sample homing ended at (`homing`), once it did.
    pub fn homed_at(&self) -> Option<u32> {
        self.homed_at
    }

    /// `track-5g`'s motion check so far.
    pub fn motion_check(&self) -> MotionCheck {
        self.motion
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

    /// What the stop of a fault scenario did, once the fault came.
    pub fn stop_report(&self) -> Option<StopReport> {
        self.stop.map(|s| s.report())
    }

    /// The sample the fault latched in, once it did.
    pub fn fault_sample(&self) -> Option<u32> {
        self.fault_at
    }

    /// `watchdog-restart`: the controller reset while the machine was moving; `plant`
    /// is the machine's state then (the watchdog's interrupt removed torque there). Its coast is
    /// checked as category 0 from there on, the boot's first sample counting as the fault's.
    pub fn coast_after_reset(&mut self, plant: PlantState) {
        let Ok(cal) = self.image else { return };
        let dt = self.settings.servo.sample_period_s;
        let tool = tool_mm(&cal, plant.joint_rad).0;
        // The tool's speed: where the joints' speed takes it in one sample.
        let ahead = [0, 1].map(|k| plant.joint_rad[k] + plant.joint_rad_s[k] * dt);
        let speed_mm_s = match (tool, tool_mm(&cal, ahead).0) {
            (Some(p), Some(q)) => libm::hypotf(p[0] - q[0], p[1] - q[1]) / dt,
            _ => f32::NAN,
        };
        self.fault_at = Some(0);
        let settle_s = self.settings.stop.settle_timeout_s;
        self.stop = Some(StopCheck::new(
            StopCategory::Zero,
            0,
            &plant,
            tool,
            speed_mm_s,
            None,
            &self.coast,
            dt,
            settle_s,
        ));
    }

    /// Checks the end of one sample; `Some` ends the run with the verdict.
    pub fn observe(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if let Some(limit) = self.scenario.time_limit_ticks() {
            if s.ticks >= limit {
                return Some(Err("scenario did not finish in time"));
            }
        }
        let verdict = match self.scenario.spec().check {
            Check::Nothing => None,
            // The host checks the motion; the harness ends the run if a deadline is missed.
            Check::Link => {
                (s.overruns > 0).then_some(Err("servo deadline missed while the host link ran"))
            }
            Check::SelfTest(_) => Some(Err("the self-test did not stop the firmware")),
            Check::LongRun => self.long_run(o),
            Check::Track => self.track(o),
            Check::Track5g => match self.track_motion(o) {
                Err(why) => Some(Err(why)),
                Ok(()) => self.track(o).map(|v| {
                    v.and_then(|()| {
                        require(
                            self.motion.samples_at_5g >= MIN_SAMPLES_AT_5G,
                            "too few samples at 5 g",
                        )
                    })
                }),
            },
            Check::Fault(e) => self.fault_scenario(o, e),
            Check::FaultInsideGrid(e) => {
                if s.fault.is_some() && self.fault_at.is_none() {
                    // The last accepted setpoint must still be inside the calibrated rectangle.
                    let inside = match &self.image {
                        Ok(Calibration { grid: Some(g), .. }) => {
                            g.correction_rad(self.setpoints_mm[0]).is_ok()
                        }
                        _ => false,
                    };
                    if !inside {
                        return Some(Err("an out-of-grid setpoint was accepted"));
                    }
                }
                self.fault_scenario(o, e)
            }
            Check::FaultWithOverruns(e) => self
                .fault_scenario(o, e)
                .map(|v| v.and_then(|()| require(s.overruns >= 3, "overruns not counted"))),
            Check::HomingThenTrack => self.homing_then_track(o),
            Check::Upload => self
                .track(o)
                .map(|v| v.and_then(|()| self.upload_outcome(s))),
            Check::HomingNoIndex => self.homing_no_index(o),
            Check::BadImage(expected) => self.bad_image(o, expected),
            Check::UntilStall => self.before_stall(o),
            Check::WatchdogRestart => self.watchdog_restart(o),
        };
        self.last_joint_rad = o.plant.joint_rad;
        verdict
    }

    /// The samples (first, last) a fault's first sample must lie in.
    fn window(&self, w: Window) -> Option<(u32, u32)> {
        let at = self.scenario.inject_at(&self.injection);
        match w {
            Window::AfterInjection(within) => at.map(|a| (a, a + within)),
            Window::EndOfOverrunStreak => {
                let streak = self.settings.overrun_streak_limit.max(1) - 1;
                at.map(|a| (a + streak, a + streak))
            }
            Window::AfterMoveStart(within) => {
                let start = self.injection.move_start_sample;
                Some((start, start + within))
            }
        }
    }

    /// A fault is expected (in `e.window` if given): before it the drives must be on and the
    /// machine running; from its own sample on, the reaction of its stop category
    /// ([`stop_check`]).
    fn fault_scenario(&mut self, o: &Observation<'_>, e: Expected) -> Verdict {
        let s = o.status;
        let window = e.window.and_then(|w| self.window(w));
        let sample = s.ticks.wrapping_sub(1);
        let Ok(cal) = self.image else {
            return Some(Err("calibration image not valid"));
        };
        let (tool, inside) = tool_mm(&cal, o.plant.joint_rad);
        let Some(fault) = s.fault else {
            if matches!(window, Some((_, last)) if sample >= last) {
                return Some(Err("no fault in the sample the fault was injected in"));
            }
            // Before the fault the machine runs; otherwise the checks after prove nothing.
            if !o.drive_enable {
                return Some(Err("drives not enabled before the fault"));
            }
            if !inside {
                return Some(Err(
                    "the tool left the calibrated rectangle before the fault",
                ));
            }
            self.setpoints_mm = [s.setpoint_mm, self.setpoints_mm[0], self.setpoints_mm[1]];
            return None;
        };
        if self.fault_at.is_none() {
            self.fault_at = Some(sample);
            if !(e.fault)(fault) {
                return Some(Err("wrong fault"));
            }
            if matches!(window, Some((first, last)) if !(first..=last).contains(&sample)) {
                return Some(Err("fault not in the sample the fault was injected in"));
            }
            let category = fault.stop_category();
            let dt = self.settings.servo.sample_period_s;
            let planned = (category != StopCategory::Zero).then(|| {
                let [p1, p2, p3] = self.setpoints_mm;
                let v = [(p1[0] - p2[0]) / dt, (p1[1] - p2[1]) / dt];
                let a = [
                    (p1[0] - 2.0 * p2[0] + p3[0]) / (dt * dt),
                    (p1[1] - 2.0 * p2[1] + p3[1]) / (dt * dt),
                ];
                StopProfile::plan(
                    &MotionState::from_differences(p1, v, a, dt),
                    &self.settings.stop.limits,
                )
            });
            let speed_mm_s = match (tool, tool_mm(&cal, self.last_joint_rad).0) {
                (Some(p), Some(q)) => libm::hypotf(p[0] - q[0], p[1] - q[1]) / dt,
                _ => f32::NAN,
            };
            self.stop = Some(StopCheck::new(
                category,
                sample,
                &o.plant,
                tool,
                speed_mm_s,
                planned,
                &self.coast,
                dt,
                self.settings.stop.settle_timeout_s,
            ));
        }
        let stop = self.stop.as_mut()?;
        let done = match stop.observe(o, sample, tool, inside) {
            Ok(done) => done,
            Err(why) => return Some(Err(why)),
        };
        if let Some(max) = e.max_travel_mm {
            if !(stop.report().travelled_mm <= max) {
                return Some(Err("the tool travelled further than the scenario allows"));
            }
        }
        done.then_some(Ok(()))
    }

    /// `stalled-task` until the stall: the machine runs (drives on, no fault, the tool inside).
    /// The harness stalls the servo task at the top-speed sample ([`Scenario::stall_at`]); the
    /// verdict comes from the watchdog's interrupt ([`Scenario::watchdog_fired`]), so a sample
    /// that ends after the stall sample is a failure.
    fn before_stall(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if s.fault.is_some() {
            return Some(Err("fault before the stall"));
        }
        if !o.drive_enable {
            return Some(Err("drives not enabled before the stall"));
        }
        let Ok(cal) = self.image else {
            return Some(Err("calibration image not valid"));
        };
        if !tool_mm(&cal, o.plant.joint_rad).1 {
            return Some(Err(
                "the tool left the calibrated rectangle before the stall",
            ));
        }
        if matches!(self.scenario.inject_at(&self.injection), Some(at) if s.ticks > at) {
            return Some(Err("the servo task completed a sample after the stall"));
        }
        None
    }

    /// The boot after `stalled-task`'s watchdog reset: the drives stay off with
    /// `Fault::Watchdog(Reset)`, and the machine's coast from the state it was in at the
    /// watchdog's interrupt stays within category 0's bounds.
    fn watchdog_restart(&mut self, o: &Observation<'_>) -> Verdict {
        let sample = o.status.ticks.wrapping_sub(1);
        let Ok(cal) = self.image else {
            return Some(Err("calibration image not valid"));
        };
        let (tool, inside) = tool_mm(&cal, o.plant.joint_rad);
        let Some(stop) = self.stop.as_mut() else {
            return Some(Err("the machine's state at the watchdog's interrupt did not reach the boot after the reset"));
        };
        let coast_done = match stop.observe(o, sample, tool, inside) {
            Ok(done) => done,
            Err(why) => return Some(Err(why)),
        };
        match self.never_enabled(o, |s| {
            require(
                s.fault == Some(Fault::Watchdog(WatchdogFault::Reset)),
                "watchdog reset not reported as the fault",
            )
        }) {
            Some(Ok(())) if !coast_done => None,
            verdict => verdict,
        }
    }

    fn bad_image(&mut self, o: &Observation<'_>, expected: GridError) -> Verdict {
        self.never_enabled(o, |s| {
            require(
                s.calibration == CalibrationState::Refused(ImageError::Grid(expected)),
                "bad image not refused, or refused for another reason",
            )?;
            require(
                s.fault == Some(Fault::Calibration(ImageError::Grid(expected))),
                "calibration fault not reported",
            )
        })
    }

    /// A boot that must never enable the drives: the enable line never high and no torque in
    /// any sample; after [`BAD_IMAGE_TICKS`], `reason` checks why.
    fn never_enabled(
        &mut self,
        o: &Observation<'_>,
        reason: impl FnOnce(&Status) -> Result<(), &'static str>,
    ) -> Verdict {
        let now = (|| {
            require(
                !o.drive_enable_ever,
                "drives enabled at a boot that must keep them off",
            )?;
            require(
                o.drive_torque_nm == [0.0; 2],
                "torque commanded at a boot that must keep the drives off",
            )
        })();
        if now.is_err() {
            return Some(now);
        }
        (o.status.ticks >= BAD_IMAGE_TICKS).then(|| reason(o.status))
    }

    /// While homing: the drives on, no fault, the torque within the homing limit. From the
    /// first `Running` sample: the readings equal the plant's true angles (the zero is right)
    /// and `track`'s checks, the tour starting there.
    fn homing_then_track(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if s.fault.is_some() {
            return Some(Err("unexpected fault"));
        }
        match (s.mode, self.homed_at) {
            (Mode::Homing, None) => {
                let limit = self.settings.homing.torque_limit_nm + DUTY_STEP_NM;
                let within = o.drive_torque_nm.iter().all(|t| t.abs() <= limit);
                return Some(Err("torque above the homing limit"))
                    .filter(|_| !within)
                    .or_else(|| {
                        (!o.drive_enable).then_some(Err("drives not enabled while homing"))
                    });
            }
            (Mode::Running, None) => {
                self.homed_at = Some(s.ticks);
                self.track_end_tick += s.ticks;
            }
            (Mode::Running, Some(_)) => {}
            _ => return Some(Err("neither homing nor running")),
        }
        let off = [0, 1].map(|k| (s.encoder_rad[k] - o.plant.joint_rad[k]).abs());
        if !(off[0] <= MAX_HOMED_ENCODER_ERROR_RAD && off[1] <= MAX_HOMED_ENCODER_ERROR_RAD) {
            return Some(Err(
                "after homing the readings are not the joints' true angles",
            ));
        }
        self.track(o)
    }

    /// The upload scenarios at the end of the tour: the upload's outcome and the image in force.
    pub(super) fn upload_outcome(&self, s: &Status) -> Result<(), &'static str> {
        let sequence = s.calibration_id.map(|i| i.sequence);
        if self.scenario.upload().is_some_and(|(_, corrupt)| corrupt) {
            require(
                s.last_upload == Some(Err(SlotError::Image(ImageError::Grid(GridError::BadCrc)))),
                "the corrupted upload was not refused for its CRC",
            )?;
            return require(
                sequence == Some(0) && self.grid_checks_at_switch.is_none(),
                "the old image did not stay in force",
            );
        }
        require(
            matches!(s.last_upload, Some(Ok(id)) if id.sequence == 1),
            "the upload was not committed",
        )?;
        require(
            sequence == Some(1),
            "the servo did not switch to the new image",
        )?;
        let after = self
            .grid_checks_at_switch
            .map_or(0, |at| self.grid.checks - at);
        require(after >= 10, "too few grid checks against the new image")
    }

    /// `homing-no-index`: homing until joint 1's search (the first) ends without an index, then
    /// `Homing(IndexNotFound(0))`, the safe state, the machine at rest; never running. (Joint
    /// 2's missing index is not the scenario: its search runs with joint 1 parked at its own
    /// index, and its whole travel can reach the parallel singularity,
    /// docs/design/firmware-architecture.md, "Homing", known limitation.)
    fn homing_no_index(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        match (s.mode, s.fault) {
            (Mode::Homing, None) => {
                (!o.drive_enable).then_some(Err("drives not enabled while homing"))
            }
            (
                Mode::SafeState(Fault::Homing(HomingFault::IndexNotFound(0))),
                Some(Fault::Homing(HomingFault::IndexNotFound(0))),
            ) => {
                if let Err(why) = safe_state(o) {
                    return Some(Err(why));
                }
                let at = *self.fault_at.get_or_insert(s.ticks);
                let still = o.plant.joint_rad_s.iter().all(|w| w.abs() < 0.01);
                (s.ticks >= at + 200)
                    .then(|| require(still, "the machine is not at rest after the failed search"))
            }
            _ => Some(Err("not homing, or another fault than the missing index")),
        }
    }

    fn long_run(&mut self, o: &Observation<'_>) -> Verdict {
        let s = o.status;
        if s.fault.is_some() {
            return Some(Err("fault during the run"));
        }
        if !o.drive_enable {
            return Some(Err("drives disabled during the run"));
        }
        (s.ticks >= LONG_RUN_TICKS)
            .then(|| require(s.setpoint_underruns == 0, "setpoint queue ran empty"))
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
        let blocks = cal
            .grid
            .is_some_and(|g| g.workspace().is_some() && g.dynamics().is_some());
        Some((|| {
            require(
                s.calibration == CalibrationState::Valid,
                "calibration image not valid",
            )?;
            require(blocks, "the image lacks its workspace or dynamics block")?;
            require(s.overruns == 0, "deadline overrun")?;
            require(
                s.worst_step_us < crate::deadline::DEADLINE_US,
                "step longer than the deadline",
            )?;
            require(s.setpoint_underruns == 0, "setpoint queue ran empty")?;
            require(
                s.max_following_error_rad <= MAX_FOLLOWING_ERROR_RAD,
                "following error above bound",
            )?;
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

    /// `track-5g`, every sample: the setpoint acceleration seen and the following error at the
    /// tool within [`MAX_FOLLOWING_ERROR_5G_UM`].
    fn track_motion(&mut self, o: &Observation<'_>) -> Result<(), &'static str> {
        let s = o.status;
        let m = &mut self.motion;
        let [p1, p2] = m.last_setpoints_mm;
        let p = s.setpoint_mm;
        if m.seen >= 2 {
            let dt = crate::SAMPLE_PERIOD_S;
            let a =
                libm::hypotf(p[0] - 2.0 * p1[0] + p2[0], p[1] - 2.0 * p1[1] + p2[1]) / (dt * dt);
            if a >= 0.95 * 5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2 {
                m.samples_at_5g += 1;
            }
        }
        m.last_setpoints_mm = [p, p1];
        m.seen = m.seen.saturating_add(1);
        let Ok(cal) = &self.image else {
            return Err("calibration image not valid");
        };
        let j = cal
            .model
            .inverse_pose(p, self.settings.servo.min_transmission)
            .and_then(|pose| pose.jacobian())
            .map_err(|_| "IK refuses an accepted setpoint")?;
        let e = [
            s.reference_rad[0] - s.encoder_rad[0],
            s.reference_rad[1] - s.encoder_rad[1],
        ];
        let um = 1e3
            * libm::hypotf(
                j[0][0] * e[0] + j[0][1] * e[1],
                j[1][0] * e[0] + j[1][1] * e[1],
            );
        // `!(a <= b)` so that NaN counts as the largest.
        if !(um <= m.max_following_error_um) {
            m.max_following_error_um = um;
        }
        require(
            m.max_following_error_um <= MAX_FOLLOWING_ERROR_5G_UM,
            "following error at the tool above the 5 g bound",
        )
    }

    /// Commanded encoder angles minus the model's IK of the accepted setpoint must be the
    /// grid's correction at that setpoint.
    fn check_grid_applied(&mut self, s: &Status) -> Result<(), &'static str> {
        let Ok(Calibration {
            model,
            grid: Some(grid),
        }) = &self.image
        else {
            return Err("calibration image not valid");
        };
        let ik = model
            .inverse(s.setpoint_mm, self.settings.servo.min_transmission)
            .map_err(|_| "IK refuses an accepted setpoint")?;
        let d = grid
            .correction_rad(s.setpoint_mm)
            .map_err(|_| "an accepted setpoint is outside the grid")?;
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
