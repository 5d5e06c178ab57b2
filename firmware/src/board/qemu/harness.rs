//! The QEMU test harness: the scenarios of `cargo qemu-test`, hooked into the app only through
//! the QEMU board (the production app knows nothing of them).
//!
//! * Boot ([`Harness::boot`], from `Board::init`): reads the scenario from the semihosting
//!   command line and runs the self-tests of the failure paths (`panic`, `hard-fault`), which
//!   end the run through the panic / HardFault handlers.
//! * Where the faults go ([`Harness::setpoints`]): `controller::scenario::Injection::find` scans
//!   the trajectory for its top speed (and the rest before that move).
//! * Setpoint fault injection ([`Injected`], the board's setpoint source): the built-in
//!   trajectory with the scenario's NaN, jump or dry stream (`Scenario::tamper`).
//! * Deadline and encoder fault injection ([`Harness::begin_sample`], before the plant updates
//!   the encoder counters): burns time in the scenario's samples; freezes joint 1's counter or
//!   offsets it for one sample (`hardware::inject_encoder`).
//! * The stalled servo task (`stalled-task`, [`Harness::begin_sample`]): at the top-speed
//!   sample the servo task disables interrupts and spins, and the harness keeps the plant
//!   moving in real time meanwhile (a machine does not stop with its controller), keeping its
//!   state across the coming reset ([`super::across_reset`]); [`watchdog_fired`], called by the
//!   watchdog's NMI after it removed torque, judges the reaction and waits for the watchdog's
//!   reset. The boot after it is `watchdog-restart` (`Scenario::after_reset`), which
//!   checks the machine's coast from where the interrupt left it ([`Harness::resumed`]).
//! * The checks ([`Harness::end_sample`], after every sample's status is published):
//!   `controller::scenario::Checker` on the status, on what the simulated hardware shows
//!   (drive-enable line, torque in the PWM registers) and on the plant's true joint state; a
//!   verdict prints `PASS` or `FAIL <why>` on the console and ends QEMU with exit code 0 or 1.
//!   `run` never concludes.
//! * The run-time upload of the upload scenarios ([`Harness::upload_due`], the board's
//!   `Board::bundled_upload_due`): the bundled second image, once, at the scenario's sample.
//!
//! The checker validates the calibration region on its own, so the firmware's reading of it is
//! under test too.
use core::cell::Cell;
use core::fmt::Write;
use core::sync::atomic::{AtomicU32, Ordering};

use controller::calibration::ImageCheck;
use controller::calibration_slots::{CalibrationId, ReadOnly, SlotStore};
use controller::deadline::DEADLINE_US;
use controller::scenario::stop_check::{CoastModel, PlantState};
use controller::scenario::{
    registry, Check, Checker, EncoderInjection, Injection, Observation, Scenario, SelfTest,
    WatchdogObservation, WatchdogVerdict, LIST_COMMAND,
};
use controller::setpoints::SetpointSource;
use controller::settings::Settings;
use controller::status::Status;
use controller::watchdog::TIMEOUT_US;
use controller::waypoint_moves::Trajectory;
use critical_section::Mutex;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{CorrectionGrid, GridError};

use super::plant::Plant;
use super::{
    across_reset, clock, hardware, semihosting, CmsdkTimer, COUNTS_PER_REV, TIMER_CLOCK_HZ,
};

/// What the watchdog's NMI needs (it cannot reach the `Harness`, which the servo task owns).
/// The scenario of this boot, set once at boot before the watchdog starts.
static SCENARIO: Mutex<Cell<Option<Scenario>>> = Mutex::new(Cell::new(None));
/// Clock ticks at the last watchdog feed, at the stall; [`NEVER`] until then.
static LAST_FEED_AT: AtomicU32 = AtomicU32::new(NEVER);
static STALLED_AT: AtomicU32 = AtomicU32::new(NEVER);
/// Tool speed at the stall (f32 bits, mm/s).
static STALL_SPEED: AtomicU32 = AtomicU32::new(0);
const NEVER: u32 = u32::MAX;

/// The image in force by the harness's own reading of the slots (not the firmware's).
fn image_in_force(
    settings: &Settings,
) -> (
    Option<CalibrationId>,
    Result<CorrectionGrid<'static>, GridError>,
) {
    // Which image is in force, not whether it is plausible (the firmware's judgement, tested
    // on the host): this runs inside a servo sample.
    let check = ImageCheck {
        max_slope_change_rad_per_mm: None,
        ..settings.image_check()
    };
    let store = SlotStore::open(ReadOnly(crate::calibration::region()), check);
    match store.active_id() {
        Some(id) => (
            Some(id),
            CorrectionGrid::parse(crate::calibration::slot_bytes(id)),
        ),
        None => (None, CorrectionGrid::parse(crate::calibration::region())),
    }
}

/// Records a watchdog feed (the QEMU board's `feed_watchdog` calls it right after the feed).
#[inline]
pub fn note_feed() {
    LAST_FEED_AT.store(clock::now_ticks(), Ordering::SeqCst);
}

fn at_us(ticks: u32) -> Option<f32> {
    (ticks != NEVER).then(|| clock::ticks_to_us(ticks))
}

/// The harness's state, owned by the QEMU board.
pub struct Harness {
    scenario: Scenario,
    settings: &'static Settings,
    /// The upload scenarios' upload has been started.
    upload_started: bool,
    /// Set up with the trajectory (the checks need its length).
    checker: Option<Checker<'static>>,
    /// Where the faults go, found in the trajectory.
    injection: Injection,
    /// Index of the sample about to run.
    sample: u32,
    /// The machine's state when the controller last reset, if it was kept ([`Harness::resumed`]).
    resumed: Option<PlantState>,
    /// The image in force the checker checks against (its id).
    checked_id: Option<CalibrationId>,
}

impl Harness {
    /// The scenario named on the semihosting command line, as it continues after the last
    /// reset (the boot after `stalled-task`'s watchdog reset is `watchdog-restart`). The
    /// command line `list` prints the registry's runs (`qemu/test.sh` reads them) and ends the
    /// run; an empty or unknown name ends it with `FAIL`.
    pub fn scenario() -> Scenario {
        let mut line = [0u8; 64];
        let line = semihosting::command_line(&mut line);
        if line.split_whitespace().nth(1) == Some(LIST_COMMAND) {
            list()
        }
        match Scenario::from_command_line(line) {
            Ok(s) => s.after_reset(hardware::peek_reset_cause()),
            Err(_) => {
                semihosting::console(
                    "FAIL harness: no scenario of that name (the command line `list` lists them)",
                );
                semihosting::exit(false)
            }
        }
    }

    /// Reads the scenario, starts the harness's clock and runs the self-tests of the failure
    /// paths.
    pub fn boot(settings: &'static Settings) -> Self {
        let scenario = Self::scenario();
        defmt::info!("harness: scenario {}", scenario);
        critical_section::with(|cs| SCENARIO.borrow(cs).set(Some(scenario)));
        clock::start();
        match scenario.spec().check {
            Check::SelfTest(SelfTest::Panic) => {
                let v: Option<u32> = core::hint::black_box(None);
                let _ = v.expect("self-test: panic path");
            }
            Check::SelfTest(SelfTest::HardFault) => cortex_m::asm::udf(),
            _ => {}
        }
        Harness {
            scenario,
            settings,
            upload_started: false,
            checker: None,
            injection: Injection::default(),
            sample: 0,
            resumed: None,
            checked_id: None,
        }
    }

    /// The machine was in `state` when the controller reset (the plant resumed there): the
    /// boot after `stalled-task`'s watchdog reset checks its coast from there.
    pub fn resumed(&mut self, state: PlantState) {
        defmt::info!(
            "harness: the machine moves on from before the reset: {}",
            state
        );
        self.resumed = Some(state);
    }

    /// The board's setpoint source: `trajectory` with the scenario's setpoint faults. `coast`
    /// is the plant's (the checks' bound for a coast with the drives off).
    pub fn setpoints(&mut self, trajectory: Trajectory, coast: CoastModel) -> Injected {
        let (id, image) = image_in_force(self.settings);
        self.checked_id = id;
        self.injection = Injection::find(&trajectory, self.settings.servo.sample_period_s);
        if self.scenario.inject_at(&self.injection).is_some() {
            defmt::info!(
                "harness: {} injected at sample {}",
                self.scenario,
                self.injection
            );
        }
        let total = trajectory.total_samples();
        let mut checker = Checker::new(
            self.scenario,
            image,
            self.settings,
            total,
            self.injection,
            coast,
        );
        if let (Check::WatchdogRestart, Some(state)) = (self.scenario.spec().check, self.resumed) {
            checker.coast_after_reset(state);
        }
        self.checker = Some(checker);
        Injected {
            scenario: self.scenario,
            injection: self.injection,
            trajectory,
            queued: 0,
        }
    }

    /// The upload scenarios (`Scenario::upload`): `Some(corrupt)` once, at the first sample at
    /// or after the upload's.
    pub fn upload_due(&mut self, ticks: u32) -> Option<bool> {
        let (at, corrupt) = self.scenario.upload()?;
        let due = ticks >= at && !self.upload_started;
        self.upload_started |= due;
        due.then_some(corrupt)
    }

    /// Start of a sample, before the plant moves and updates the encoder counters: the deadline
    /// and encoder fault injection, and the stalled task (which keeps `plant` moving).
    #[inline]
    pub fn begin_sample(&mut self, timer: &CmsdkTimer, plant: &mut Plant) {
        if self.scenario.overrun_at(&self.injection, self.sample) {
            timer.burn_until_us(1.4 * DEADLINE_US);
        }
        if self.scenario.stall_at(&self.injection, self.sample) {
            stall(self.injection.top_speed_mm_s, plant);
        }
        let counts_per_rad = COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI);
        match self.scenario.encoder_at(&self.injection, self.sample) {
            EncoderInjection::None => hardware::inject_encoder(0, false, 0),
            EncoderInjection::Freeze => hardware::inject_encoder(0, true, 0),
            EncoderInjection::Offset(rad) => {
                hardware::inject_encoder(0, false, libm::roundf(rad * counts_per_rad) as i32)
            }
        }
        self.sample = self.sample.wrapping_add(1);
    }

    /// End of a sample: the checks on `status`, the hardware and the plant's true state
    /// `plant`; a verdict ends the run.
    pub fn end_sample(&mut self, status: &Status, plant: PlantState) {
        let observation = Observation {
            status,
            drive_enable: hardware::drive_enable(),
            drive_enable_ever: hardware::drive_enable_ever(),
            drive_torque_nm: hardware::commanded_torque_nm(self.settings.drive_full_scale_nm),
            plant,
        };
        let Some(checker) = &mut self.checker else {
            semihosting::console("FAIL harness: no setpoint source set up before the first sample");
            semihosting::exit(false)
        };
        // The firmware switched images: the checker reads the slots itself and checks against
        // the image in force from now on.
        if status.calibration_id != self.checked_id && self.scenario.upload().is_some() {
            let (id, image) = image_in_force(self.settings);
            if id != status.calibration_id {
                semihosting::console(
                    "FAIL harness: the firmware's image in force is not the slots' committed one",
                );
                semihosting::exit(false)
            }
            self.checked_id = id;
            checker.switch_image(image);
        }
        match checker.observe(&observation) {
            None => {}
            Some(Ok(())) => {
                defmt::info!("PASS {}: {}", self.scenario, status);
                if let (Some(at), Some(report)) = (checker.fault_sample(), checker.stop_report()) {
                    defmt::info!(
                        "stop: fault at sample {} ({}): {}",
                        at,
                        status.fault,
                        report
                    );
                }
                if let Some(at) = checker.homed_at() {
                    defmt::info!("homing: homed and engaged at sample {}", at);
                }
                if let Some(upload) = status.last_upload {
                    defmt::info!(
                        "upload: {}, image in force {}",
                        upload,
                        status.calibration_id
                    );
                }
                if self.scenario.tracks() {
                    defmt::info!(
                        "track: grid {}, settled tool error {} mm",
                        checker.grid_check(),
                        checker.settled_tool_error_mm()
                    );
                }
                if self.scenario.at_5g() {
                    let m = checker.motion_check();
                    defmt::info!(
                        "track-5g: {} samples at 5 g, max following error {} um at the tool (bound {})",
                        m.samples_at_5g,
                        m.max_following_error_um,
                        controller::scenario::MAX_FOLLOWING_ERROR_5G_UM
                    );
                }
                semihosting::console("PASS");
                semihosting::exit(true)
            }
            Some(Err(why)) => {
                defmt::error!("FAIL {}: {} ({})", self.scenario, why, status);
                if let Some(report) = checker.stop_report() {
                    defmt::error!("stop: {}", report);
                }
                semihosting::console("FAIL");
                semihosting::console(why);
                semihosting::exit(false)
            }
        }
    }
}

/// The built-in trajectory with the scenario's setpoint faults (the `n`-th setpoint queued is
/// `Scenario::tamper(.., n, ..)` of the trajectory's; `None` once the stream has run dry).
pub struct Injected {
    scenario: Scenario,
    injection: Injection,
    trajectory: Trajectory,
    queued: u32,
}

/// The tampering acts on the setpoint's position; its derivatives are the trajectory's.
impl SetpointSource for Injected {
    fn next_setpoint(&mut self) -> Option<MotionSetpoint<f32>> {
        let mut s = self.trajectory.next_setpoint();
        s.position_mm = self
            .scenario
            .tamper(&self.injection, self.queued, s.position_mm)?;
        self.queued = self.queued.wrapping_add(1);
        Some(s)
    }
}

/// How often the stalled task's loop moves the plant on (s): a tenth of a servo period.
const STALLED_PLANT_STEP_S: f32 = 50.0e-6;

/// Stops the servo task from ever completing, the way a logger blocking inside a critical
/// section would: interrupts disabled, spinning. Only the NMI gets through. Meanwhile the
/// machine moves on under whatever the hardware commands (the last duty while the enable line
/// is on; the drives' dynamic braking once the NMI has removed torque): the loop advances
/// `plant` in steps of [`STALLED_PLANT_STEP_S`] on the harness's clock and keeps its state for
/// the boot after the watchdog's reset.
fn stall(speed_mm_s: f32, plant: &mut Plant) -> ! {
    defmt::info!(
        "harness: stalling the servo task (interrupts disabled) at {} mm/s",
        speed_mm_s
    );
    STALL_SPEED.store(speed_mm_s.to_bits(), Ordering::SeqCst);
    cortex_m::interrupt::disable();
    let stalled_at = clock::now_ticks();
    STALLED_AT.store(stalled_at, Ordering::SeqCst);
    across_reset::keep(plant.state());
    let step_ticks = (STALLED_PLANT_STEP_S * TIMER_CLOCK_HZ as f32) as u32;
    let mut simulated_ticks = 0u32;
    loop {
        if clock::now_ticks().wrapping_sub(stalled_at) >= simulated_ticks.wrapping_add(step_ticks) {
            plant.advance(STALLED_PLANT_STEP_S);
            simulated_ticks = simulated_ticks.wrapping_add(step_ticks);
            across_reset::keep(plant.state());
        }
    }
}

/// Called by the watchdog's NMI after it removed torque (`drive_enable_at_fire`: the enable
/// line as the NMI found it): the scenario's verdict (`Scenario::watchdog_fired`). A failure
/// ends the run; otherwise it reports and waits for the watchdog's reset (its second expiry).
/// No defmt here: the NMI may have interrupted a defmt frame.
pub fn watchdog_fired(drive_enable_at_fire: bool) -> ! {
    let fired_at = clock::now_ticks();
    let o = WatchdogObservation {
        stalled_at_us: at_us(STALLED_AT.load(Ordering::SeqCst)),
        last_feed_at_us: at_us(LAST_FEED_AT.load(Ordering::SeqCst)),
        fired_at_us: clock::ticks_to_us(fired_at),
        drive_enable_at_fire,
        drive_enable: hardware::drive_enable(),
        // Zero torque is a zero at any full scale; 1 N·m keeps any other duty non-zero.
        drive_torque_nm: hardware::commanded_torque_nm(1.0),
    };
    let Some(scenario) = critical_section::with(|cs| SCENARIO.borrow(cs).get()) else {
        semihosting::console("FAIL watchdog fired before the harness started");
        semihosting::exit(false)
    };
    let mut line: heapless::String<200> = heapless::String::new();
    match scenario.watchdog_fired(&o) {
        WatchdogVerdict::Fail(why) => {
            semihosting::console("FAIL");
            semihosting::console(why);
            semihosting::exit(false)
        }
        WatchdogVerdict::AsExpected => {
            let since = |t: Option<f32>| t.map_or(f32::NAN, |t| o.fired_at_us - t);
            let _ = write!(
                line,
                "watchdog: torque off {:.0} us after the stall at {:.0} mm/s, {:.0} us after the last on-time step (timeout {:.0} us)",
                since(o.stalled_at_us),
                f32::from_bits(STALL_SPEED.load(Ordering::SeqCst)),
                since(o.last_feed_at_us),
                TIMEOUT_US
            );
        }
        WatchdogVerdict::Production => {
            semihosting::console(
                "watchdog: the servo task stalled: drives off, waiting for the watchdog's reset",
            );
            loop {
                cortex_m::asm::nop();
            }
        }
    }
    semihosting::console(&line);
    // The reset comes at the next expiry, one timeout later; if it does not, the test fails.
    let wait_ticks = (3.0 * TIMEOUT_US * (TIMER_CLOCK_HZ as f32 / 1.0e6)) as u32;
    while clock::now_ticks().wrapping_sub(fired_at) < wait_ticks {}
    semihosting::console("FAIL no reset after the watchdog interrupt");
    semihosting::exit(false)
}

/// The command line `list`: one line per run of every scenario of the registry
/// (`controller::scenario::Run::list_line`), then the end of the run.
fn list() -> ! {
    for spec in &registry::SCENARIOS {
        for run in spec.runs {
            let mut line: heapless::String<120> = heapless::String::new();
            if run.list_line(spec.name, &mut line).is_err() {
                semihosting::console("FAIL harness: a list line does not fit");
                semihosting::exit(false)
            }
            semihosting::console(&line);
        }
    }
    semihosting::exit(true)
}
