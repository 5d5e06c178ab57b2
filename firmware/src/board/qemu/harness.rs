//! The QEMU test harness: the scenarios of `cargo qemu-test`, hooked into the app only through
//! the QEMU board (the production app knows nothing of them).
//!
//! * Boot ([`Harness::boot`], from `Board::init`): reads the scenario from the semihosting
//!   command line and runs the self-tests of the failure paths (`panic`, `hard-fault`), which
//!   end the run through the panic / HardFault handlers.
//! * Setpoint fault injection ([`Injected`], the board's setpoint source): the built-in
//!   trajectory with the scenario's NaN or jump (`Scenario::tamper`).
//! * Deadline fault injection ([`Harness::begin_sample`]): burns time in the scenario's samples.
//! * The checks ([`Harness::end_sample`], after every sample's status is published):
//!   `controller::scenario::Checker` on the status and on what the simulated hardware shows
//!   (drive-enable line, torque in the PWM registers); a verdict prints `PASS` or `FAIL <why>`
//!   on the console and ends QEMU with exit code 0 or 1. `Scenario::Run` never concludes.
//!
//! The checker validates the calibration region on its own, so the firmware's reading of it is
//! under test too.
use controller::deadline::DEADLINE_US;
use controller::scenario::{Checker, Observation, Scenario};
use controller::settings::Settings;
use controller::setpoints::SetpointSource;
use controller::status::Status;
use controller::trajectory::Trajectory;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::CorrectionGrid;

use super::{hardware, semihosting, CmsdkTimer};

/// The harness's state, owned by the QEMU board.
pub struct Harness {
    scenario: Scenario,
    settings: &'static Settings,
    /// Set up with the trajectory (the checks need its length).
    checker: Option<Checker<'static>>,
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
        Harness { scenario, settings, checker: None, sample: 0 }
    }

    /// The board's setpoint source: `trajectory` with the scenario's setpoint faults.
    pub fn setpoints(&mut self, trajectory: Trajectory) -> Injected {
        let image = CorrectionGrid::parse(crate::calibration::region());
        self.checker = Some(Checker::new(self.scenario, image, self.settings, trajectory.total_samples()));
        Injected { scenario: self.scenario, trajectory, queued: 0 }
    }

    /// Start of a sample: the deadline fault injection.
    #[inline]
    pub fn begin_sample(&mut self, timer: &CmsdkTimer) {
        if self.scenario.overrun_at(self.sample) {
            timer.burn_until_us(1.4 * DEADLINE_US);
        }
        self.sample = self.sample.wrapping_add(1);
    }

    /// End of a sample: the checks; a verdict ends the run.
    pub fn end_sample(&mut self, status: &Status) {
        let observation = Observation {
            status,
            drive_enable: hardware::drive_enable(),
            drive_enable_ever: hardware::drive_enable_ever(),
            drive_torque_nm: hardware::commanded_torque_nm(self.settings.drive_full_scale_nm),
        };
        let Some(checker) = &mut self.checker else {
            semihosting::console("FAIL harness: no setpoint source set up before the first sample");
            semihosting::exit(false)
        };
        match checker.observe(&observation) {
            None => {}
            Some(Ok(())) => {
                defmt::info!("PASS {}: {}", self.scenario, status);
                if matches!(self.scenario, Scenario::Track | Scenario::Track5g) {
                    defmt::info!(
                        "track: grid {}, settled tool error {} mm",
                        checker.grid_check(),
                        checker.settled_tool_error_mm()
                    );
                }
                if self.scenario == Scenario::Track5g {
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
                semihosting::console("FAIL");
                semihosting::console(why);
                semihosting::exit(false)
            }
        }
    }
}

/// The built-in trajectory with the scenario's setpoint faults (the `n`-th setpoint queued has
/// the position `Scenario::tamper(n, ..)` of the trajectory's, its derivatives untouched).
pub struct Injected {
    scenario: Scenario,
    trajectory: Trajectory,
    queued: u32,
}

impl SetpointSource for Injected {
    fn next_setpoint(&mut self) -> MotionSetpoint<f32> {
        let mut s = self.trajectory.next_setpoint();
        s.position_mm = self.scenario.tamper(self.queued, s.position_mm);
        self.queued = self.queued.wrapping_add(1);
        s
    }
}
