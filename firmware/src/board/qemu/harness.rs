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
//! * The checks ([`Harness::end_sample`], after every sample's status is published):
//!   `controller::scenario::Checker` on the status, on what the simulated hardware shows
//!   (drive-enable line, torque in the PWM registers) and on the plant's true joint state; a
//!   verdict prints `PASS` or `FAIL <why>` on the console and ends QEMU with exit code 0 or 1.
//!   `Scenario::Run` never concludes.
//!
//! The checker validates the calibration region on its own, so the firmware's reading of it is
//! under test too.
use controller::deadline::DEADLINE_US;
use controller::scenario::stop_check::{CoastModel, PlantState};
use controller::scenario::{Checker, EncoderInjection, Injection, Observation, Scenario};
use controller::settings::Settings;
use controller::setpoints::SetpointSource;
use controller::status::Status;
use controller::trajectory::Trajectory;
use kinematics_core::CorrectionGrid;

use super::{hardware, semihosting, CmsdkTimer, COUNTS_PER_REV};

/// The harness's state, owned by the QEMU board.
pub struct Harness {
    scenario: Scenario,
    settings: &'static Settings,
    /// Set up with the trajectory (the checks need its length).
    checker: Option<Checker<'static>>,
    /// Where the faults go, found in the trajectory.
    injection: Injection,
    /// Index of the sample about to run.
    sample: u32,
}

impl Harness {
    /// The scenario named on the semihosting command line.
    pub fn scenario() -> Scenario {
        let mut line = [0u8; 64];
        Scenario::from_command_line(semihosting::command_line(&mut line))
    }

    /// Reads the scenario and runs the self-tests of the failure paths.
    pub fn boot(settings: &'static Settings) -> Self {
        let scenario = Self::scenario();
        defmt::info!("harness: scenario {}", scenario);
        match scenario {
            Scenario::Panic => {
                let v: Option<u32> = core::hint::black_box(None);
                let _ = v.expect("self-test: panic path");
            }
            Scenario::HardFault => cortex_m::asm::udf(),
            _ => {}
        }
        Harness { scenario, settings, checker: None, injection: Injection::default(), sample: 0 }
    }

    /// The board's setpoint source: `trajectory` with the scenario's setpoint faults. `coast`
    /// is the plant's (the checks' bound for a coast with the drives off).
    pub fn setpoints(&mut self, trajectory: Trajectory, coast: CoastModel) -> Injected {
        let image = CorrectionGrid::parse(crate::calibration::region());
        self.injection = Injection::find(&trajectory, self.settings.servo.sample_period_s);
        if self.scenario.inject_at(&self.injection).is_some() {
            defmt::info!("harness: {} injected at sample {}", self.scenario, self.injection);
        }
        let total = trajectory.total_samples();
        self.checker = Some(Checker::new(self.scenario, image, self.settings, total, self.injection, coast));
        Injected { scenario: self.scenario, injection: self.injection, trajectory, queued: 0 }
    }

    /// Start of a sample, before the plant moves and updates the encoder counters: the deadline
    /// and encoder fault injection.
    #[inline]
    pub fn begin_sample(&mut self, timer: &CmsdkTimer) {
        if self.scenario.overrun_at(&self.injection, self.sample) {
            timer.burn_until_us(1.4 * DEADLINE_US);
        }
        let counts_per_rad = COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI);
        match self.scenario.encoder_at(&self.injection, self.sample) {
            EncoderInjection::None => hardware::inject_encoder(0, false, 0),
            EncoderInjection::Freeze => hardware::inject_encoder(0, true, 0),
            EncoderInjection::Offset(rad) => hardware::inject_encoder(0, false, libm::roundf(rad * counts_per_rad) as i32),
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
        match checker.observe(&observation) {
            None => {}
            Some(Ok(())) => {
                defmt::info!("PASS {}: {}", self.scenario, status);
                if let (Some(at), Some(report)) = (checker.fault_sample(), checker.stop_report()) {
                    defmt::info!("stop: fault at sample {} ({}): {}", at, status.fault, report);
                }
                if self.scenario == Scenario::Track {
                    defmt::info!(
                        "track: grid {}, settled tool error {} mm",
                        checker.grid_check(),
                        checker.settled_tool_error_mm()
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

impl SetpointSource for Injected {
    fn next_mm(&mut self) -> Option<[f32; 2]> {
        let p = self.scenario.tamper(&self.injection, self.queued, self.trajectory.next_mm())?;
        self.queued = self.queued.wrapping_add(1);
        Some(p)
    }
}
