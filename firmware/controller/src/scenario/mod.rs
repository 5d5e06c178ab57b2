//! The QEMU test scenarios: what `cargo qemu-test` runs, the faults it injects and the checks
//! that end each run. Compiled into the QEMU board's test harness (feature `qemu-harness`) and
//! into the host unit tests; a production build contains none of it.
//!
//! # One registry
//! Every scenario is one entry of [`registry::SCENARIOS`]: its name on the semihosting command
//! line, the runs `qemu/test.sh` makes of it (test name, calibration image loaded, expected exit
//! code and console), what it injects and where, the machine and motion it runs with, its time
//! limit and its check. The parser ([`Scenario::from_command_line`]: an empty or unknown name is
//! an error, never the production path), the board's hooks ([`Scenario::tamper`],
//! [`Scenario::encoder_at`], ...), the checks ([`Checker::observe`]), `qemu/test.sh` (it asks the
//! firmware for the list: the command line `list`, [`LIST_COMMAND`]) and the scenario table of
//! docs/dev/testing.md (a host test compares its rows with the registry's runs) all read it.
//! Adding a scenario is one entry (and its check, if none of the existing kinds fits).
//!
//! `run` is the production path on the QEMU board: nothing injected, nothing checked, no time
//! limit (the real board has no harness at all). A corrupt or missing image is injected from
//! outside, by overwriting the calibration region with QEMU's `-device loader` exactly as a bad
//! flash would leave it; the firmware is the same binary in every scenario.
//!
//! # Where faults are injected: at full speed
//! Every fault of a moving machine is injected at the sample where the built-in tour's
//! setpoint speed is highest ([`Injection::find`] scans the trajectory at boot: 1.38 m/s, the
//! middle of the long diagonal, the tour's 2 g moves never reach the 1.5 m/s cap). Setpoint
//! faults replace the setpoint of that sample (the queue hands sample `n` the `n`-th
//! setpoint); encoder faults act on that sample's reading (the QEMU board's simulated counter:
//! frozen, or offset for one sample); the overrun streak starts there. The encoder frozen **at
//! rest** freezes 100 samples before the move that reaches the top speed, in the dwell before
//! it: it must be found once that move starts.
//!
//! # The stalled servo task (`stalled-task`, the watchdog)
//! At the top-speed sample the harness stops the servo task from completing: at the start of
//! that sample it disables interrupts and spins, as a logger blocking inside a critical section
//! would. Nothing but the watchdog can act: the QEMU board's CMSDK watchdog raises its NMI,
//! whose handler removes torque. [`Scenario::watchdog_fired`] then checks the hardware as the
//! NMI found it and after (drive enable on until then, off and zero torque after), that torque
//! was removed within the stated timeout of the stall ([`crate::watchdog::TIMEOUT_US`]) and that
//! the watchdog fired that long after its last feed. The run then waits for the watchdog's
//! reset; the boot after it is `watchdog-restart` ([`Scenario::after_reset`]): the drives must stay off
//! (`Fault::Watchdog(Reset)`), and the machine, which does not stop with its controller, must
//! coast as category 0 requires ([`stop_check`]): the QEMU board keeps its plant moving under
//! the last torque while the task is stalled, and hands the plant's state at the watchdog's
//! interrupt to the boot after the reset ([`Checker::coast_after_reset`]), where the coast is
//! checked from that state sample by sample, as in the other category-0 scenarios. In any
//! other test scenario a watchdog interrupt fails the run; in the production path it removes
//! torque and waits for the reset.
//!
//! # What the checks read
//! [`Checker::observe`] runs at the end of every servo sample with an [`Observation`]: what the
//! hardware shows (the drive-enable line, the torque the PWM duty registers command, as the QEMU
//! board's simulated hardware holds them) and the plant's true joint state, next to the
//! published [`Status`]. The reaction is checked on the hardware and the plant, not on status
//! fields the firmware writes itself, in the very sample the fault latched and in every sample
//! after it ([`stop_check`]: stopping distance within the planned stop, or for category 0
//! each joint's coast within the drives' dynamic-braking bound; the tool inside the
//! calibrated rectangle in every category; torque off for categories 0 and 1, holding for
//! category 2). The
//! calibration is checked against the harness's own reading of the flash region, not the
//! firmware's.
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
//!   [`MAX_SETTLED_TOOL_ERROR_MM`], measured as `|FK(θ - δ) - setpoint|`;
//! * the image carries both extension blocks of its chain (`kinematics_core::grid`): the
//!   workspace (`HRWS`) and the dynamics (`HRDY`), so an image that lost one shows.
//!
//! # Bounds (`track-5g`)
//! The same tour with the time-optimal jerk-limited profile at 5 g (exact derivatives through
//! the setpoint queue, the image's identified dynamics fed forward; the QEMU plant's masses
//! and inertias are 20 % off them, its linkage couples the motors), the same checks, and:
//! * at least [`MIN_SAMPLES_AT_5G`] samples whose setpoint acceleration (backward second
//!   difference of the accepted setpoints, as the servo's jump check sees it) is 4.75 g or more;
//! * the following error at the tool, `|J·(reference - encoder)|` with the image model's
//!   Jacobian at the setpoint, at most [`MAX_FOLLOWING_ERROR_5G_UM`] in every sample.
use crate::fault::Fault;
use crate::watchdog::ResetCause;
use crate::waypoint_moves::{Profile, Trajectory};
use kinematics_core::GridError;

pub mod checker;
pub mod observation;
pub mod registry;
pub mod stop_check;

pub use checker::{
    tool_error_mm, tool_mm, Checker, GridCheck, MotionCheck, Verdict, WatchdogObservation,
    WatchdogVerdict,
};
pub use observation::Observation;

/// The semihosting command line `list` asks the harness for the registry instead of a run: one
/// line per run of every scenario (`qemu/test.sh` reads them, [`Run::list_line`]).
pub const LIST_COMMAND: &str = "list";

/// A scenario: a handle on its entry in [`registry::SCENARIOS`] (compared by name).
#[derive(Clone, Copy)]
pub struct Scenario(&'static Spec);

impl PartialEq for Scenario {
    fn eq(&self, other: &Self) -> bool {
        self.0.name == other.0.name
    }
}
impl Eq for Scenario {}

impl core::fmt::Debug for Scenario {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.0.name)
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Scenario {
    fn format(&self, f: defmt::Formatter) {
        defmt::write!(f, "{=str}", self.0.name)
    }
}

/// Everything about one scenario (module doc, "One registry").
#[derive(Clone, Copy, Debug)]
pub struct Spec {
    /// Its name on the semihosting command line.
    pub name: &'static str,
    /// What `qemu/test.sh` runs of it (none: not run directly, e.g. `run`, `link`, the boot
    /// after a watchdog reset).
    pub runs: &'static [Run],
    /// The fault injected, and where (`None`: nothing).
    pub fault: Option<FaultInjection>,
    /// The built-in tour (`None`: the board's production tour).
    pub tour_mm: Option<&'static [[f32; 2]]>,
    /// The built-in trajectory's profile and peak acceleration (mm/s²) (`None`: production's).
    pub trajectory: Option<(Profile, f32)>,
    /// The host link's motion replaces the built-in tour.
    pub link_motion: bool,
    /// Incremental encoders: where the machine powers up, which axes have an index mark
    /// (`None`: absolute encoders, no homing).
    pub homing: Option<HomingSim>,
    /// Homing starts at boot (otherwise the host's Home command starts it).
    pub home_at_boot: bool,
    /// The run-time upload of the bundled second image (`None`: none).
    pub upload: Option<Upload>,
    /// Samples after which the scenario fails (`None`: no limit).
    pub time_limit_ticks: Option<u32>,
    /// What the harness checks every sample ([`Checker::observe`]).
    pub check: Check,
    /// What a watchdog interrupt means ([`Scenario::watchdog_fired`]).
    pub watchdog: OnWatchdog,
    /// The scenario of the boot after a watchdog reset in this one (`None`: the same).
    pub after_watchdog_reset: Option<&'static str>,
}

/// One run of a scenario by `qemu/test.sh`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Run {
    /// The test's name in the output (and in docs/dev/testing.md's table).
    pub test: &'static str,
    /// What the calibration region holds.
    pub image: Image,
    /// The console output and exit code required.
    pub expect: Console,
}

impl Run {
    /// The line `list` prints: `SCENARIO <test> <scenario> <exit> <console> <image>`.
    pub fn list_line<W: core::fmt::Write>(&self, scenario: &str, w: &mut W) -> core::fmt::Result {
        write!(
            w,
            "SCENARIO {} {} {} {} {}",
            self.test,
            scenario,
            self.expect.exit_code(),
            self.expect.name(),
            self.image.name()
        )
    }
}

/// What `qemu/test.sh` puts in the calibration region for a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Image {
    /// The valid image cut out of the ELF, loaded with QEMU's `-device loader`.
    Valid,
    /// The same with one node value replaced (its CRC no longer matches).
    Corrupt,
    /// 64 KiB of 0xFF (erased flash).
    Erased,
    /// Nothing loaded (the program runs without its image).
    None,
    /// The ELF as built, its bundled image in place (no loader).
    Bundled,
}

impl Image {
    /// Its name in the `list` output.
    pub fn name(self) -> &'static str {
        match self {
            Image::Valid => "valid",
            Image::Corrupt => "corrupt",
            Image::Erased => "erased",
            Image::None => "none",
            Image::Bundled => "bundled",
        }
    }
}

/// The console output (lines joined by spaces) and exit code a run must end with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Console {
    /// Exactly `PASS`, exit 0.
    Pass,
    /// The panic handler's line for the self-test panic, exit 1.
    Panic,
    /// `FAIL HardFault`, exit 1.
    HardFault,
    /// The watchdog's report (torque off within the timeout), then `PASS` from the boot after
    /// the reset, exit 0.
    Watchdog,
}

impl Console {
    /// Its name in the `list` output (`qemu/test.sh` maps it to the pattern).
    pub fn name(self) -> &'static str {
        match self {
            Console::Pass => "pass",
            Console::Panic => "panic",
            Console::HardFault => "hard-fault",
            Console::Watchdog => "watchdog",
        }
    }

    /// The exit code QEMU must end with.
    pub fn exit_code(self) -> u8 {
        match self {
            Console::Pass | Console::Watchdog => 0,
            Console::Panic | Console::HardFault => 1,
        }
    }
}

/// Where an injected fault goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InjectAt {
    /// The sample of the tour's fastest setpoint.
    TopSpeed,
    /// This many samples before the move that reaches the top speed starts (in the dwell).
    BeforeTopSpeedMove(u32),
}

/// The fault a scenario injects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum InjectedFault {
    /// The setpoint of that sample is NaN (its y).
    NanSetpoint,
    /// Every setpoint from that sample on is offset along x (mm).
    SetpointStep(f32),
    /// The stream runs dry from that sample on.
    DryStream,
    /// That sample and the next ones overrun their deadline (count).
    Overruns(u32),
    /// Joint 1's counter freezes from that sample on.
    EncoderFreeze,
    /// Joint 1's reading is off by this much (rad) in that sample only.
    EncoderOffset(f32),
    /// The servo task stalls at the start of that sample (interrupts disabled).
    Stall,
}

/// What a scenario injects, and where.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaultInjection {
    /// Where.
    pub at: InjectAt,
    /// What.
    pub fault: InjectedFault,
}

/// The upload scenarios' run-time upload of the bundled second image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Upload {
    /// The sample it starts at.
    pub at_ticks: u32,
    /// One bit flipped on the way.
    pub corrupt: bool,
}

/// What a watchdog interrupt means in a scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnWatchdog {
    /// A failure: the servo task did not complete on time.
    Fail,
    /// The scenario stalls the task on purpose: check the reaction ([`checker::check_watchdog`]).
    Expected,
    /// The production path: torque is off; wait for the reset.
    Production,
}

/// What the harness checks in a scenario, sample by sample ([`Checker::observe`]).
#[derive(Clone, Copy, Debug)]
pub enum Check {
    /// Nothing (the production path).
    Nothing,
    /// The host link drives: only the deadline.
    Link,
    /// A self-test of a failure path, which must have stopped the firmware at boot.
    SelfTest(SelfTest),
    /// The production path observed for [`LONG_RUN_TICKS`].
    LongRun,
    /// The tour's tracking bounds and the grid.
    Track,
    /// `Track` at 5 g, with the following error bounded at the tool.
    Track5g,
    /// A fault of a moving machine and its stop category's reaction.
    Fault(Expected),
    /// `Fault`, and the last setpoint accepted before it inside the calibrated rectangle.
    FaultInsideGrid(Expected),
    /// `Fault`, and the overruns counted.
    FaultWithOverruns(Expected),
    /// Homing at boot, then `Track`.
    HomingThenTrack,
    /// Homing fails for joint 1's missing index.
    HomingNoIndex,
    /// `Track`, and the run-time upload's outcome.
    Upload,
    /// A refused image: the drives never enabled, refused for this error.
    BadImage(GridError),
    /// The machine runs until the stall ([`Scenario::watchdog_fired`] gives the verdict).
    UntilStall,
    /// The boot after the stall's watchdog reset: drives off, the machine coasting.
    WatchdogRestart,
}

/// The failure path a self-test takes at boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SelfTest {
    /// A panic.
    Panic,
    /// A HardFault (`udf`).
    HardFault,
}

/// What a fault scenario expects.
#[derive(Clone, Copy, Debug)]
pub struct Expected {
    /// The fault's first sample must lie in this window (`None`: anywhere).
    pub window: Option<Window>,
    /// The fault expected.
    pub fault: fn(Fault) -> bool,
    /// Largest travel of the tool from the fault (mm), beyond the category's own bound.
    pub max_travel_mm: Option<f32>,
}

/// Where a fault's first sample must be, relative to the injection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Window {
    /// From the injection's sample to this many samples after it.
    AfterInjection(u32),
    /// Exactly `overrun_streak_limit - 1` samples after the injection (the streak's last).
    EndOfOverrunStreak,
    /// From the start of the move that reaches the top speed to this many samples after it.
    AfterMoveStart(u32),
}

/// Why a command line names no scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownScenario;

impl Scenario {
    /// The scenario named `name`.
    pub fn named(name: &str) -> Result<Scenario, UnknownScenario> {
        registry::SCENARIOS
            .iter()
            .find(|s| s.name == name)
            .map(Scenario)
            .ok_or(UnknownScenario)
    }

    /// Parses the semihosting command line (`"<program> <scenario>"`). An empty or unknown
    /// name is an error (the harness ends the run with `FAIL`), never the production path.
    pub fn from_command_line(line: &str) -> Result<Scenario, UnknownScenario> {
        Scenario::named(line.split_whitespace().nth(1).unwrap_or(""))
    }

    /// Its registry entry.
    pub fn spec(self) -> &'static Spec {
        self.0
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        self.0.name
    }

    /// The scenario of a boot that followed a reset with `cause`: the boot after the stalled
    /// task's watchdog reset is `watchdog-restart`.
    pub fn after_reset(self, cause: ResetCause) -> Scenario {
        match (self.0.after_watchdog_reset, cause) {
            (Some(next), ResetCause::Watchdog) => Scenario::named(next).unwrap_or(self),
            _ => self,
        }
    }

    /// What a watchdog interrupt means in this scenario (the QEMU board's NMI handler, after it
    /// removed torque, asks). See the module doc.
    pub fn watchdog_fired(self, o: &WatchdogObservation) -> WatchdogVerdict {
        match self.0.watchdog {
            OnWatchdog::Production => WatchdogVerdict::Production,
            OnWatchdog::Expected => match checker::check_watchdog(o) {
                Ok(()) => WatchdogVerdict::AsExpected,
                Err(why) => WatchdogVerdict::Fail(why),
            },
            OnWatchdog::Fail => {
                WatchdogVerdict::Fail("watchdog fired: the servo task did not complete on time")
            }
        }
    }

    /// Whether the host link's motion replaces the built-in tour.
    pub fn link_motion(self) -> bool {
        self.0.link_motion
    }

    /// The built-in tour this scenario runs instead of the board's (`production`).
    pub fn tour_mm(self, production: &'static [[f32; 2]]) -> &'static [[f32; 2]] {
        self.0.tour_mm.unwrap_or(production)
    }

    /// The built-in trajectory's profile and peak acceleration (mm/s²) in this scenario;
    /// `production`'s otherwise.
    pub fn trajectory(self, production: (Profile, f32)) -> (Profile, f32) {
        self.0.trajectory.unwrap_or(production)
    }

    /// The sample the fault goes in (`None`: nothing injected, or not at a known sample).
    pub fn inject_at(self, i: &Injection) -> Option<u32> {
        Some(match self.0.fault?.at {
            InjectAt::TopSpeed => i.top_speed_sample,
            InjectAt::BeforeTopSpeedMove(lead) => i.move_start_sample.saturating_sub(lead),
        })
    }

    /// The setpoint the intake actually queues as the `n`-th (0-based); `None`: the stream has
    /// run dry.
    pub fn tamper(self, i: &Injection, n: u32, setpoint_mm: [f32; 2]) -> Option<[f32; 2]> {
        let (Some(f), Some(at)) = (self.0.fault, self.inject_at(i)) else {
            return Some(setpoint_mm);
        };
        match f.fault {
            InjectedFault::NanSetpoint if n == at => Some([setpoint_mm[0], f32::NAN]),
            InjectedFault::SetpointStep(mm) if n >= at => {
                Some([setpoint_mm[0] + mm, setpoint_mm[1]])
            }
            InjectedFault::DryStream if n >= at => None,
            _ => Some(setpoint_mm),
        }
    }

    /// Whether sample `index` must overrun its deadline (deadline fault injection).
    pub fn overrun_at(self, i: &Injection, index: u32) -> bool {
        match (self.0.fault.map(|f| f.fault), self.inject_at(i)) {
            (Some(InjectedFault::Overruns(n)), Some(at)) => {
                (at..at.saturating_add(n)).contains(&index)
            }
            _ => false,
        }
    }

    /// What happens to joint 1's encoder reading in sample `index`.
    pub fn encoder_at(self, i: &Injection, index: u32) -> EncoderInjection {
        let (Some(f), Some(at)) = (self.0.fault, self.inject_at(i)) else {
            return EncoderInjection::None;
        };
        match f.fault {
            InjectedFault::EncoderFreeze if index >= at => EncoderInjection::Freeze,
            InjectedFault::EncoderOffset(rad) if index == at => EncoderInjection::Offset(rad),
            _ => EncoderInjection::None,
        }
    }

    /// Whether the servo task must stall at the start of sample `index`.
    pub fn stall_at(self, i: &Injection, index: u32) -> bool {
        matches!(
            self.0.fault,
            Some(FaultInjection {
                fault: InjectedFault::Stall,
                ..
            })
        ) && self.inject_at(i) == Some(index)
    }

    /// When the firmware uploads its bundled second image, and whether corrupted on the way
    /// (`None`: no upload in this scenario).
    pub fn upload(self) -> Option<(u32, bool)> {
        self.0.upload.map(|u| (u.at_ticks, u.corrupt))
    }

    /// The scenario's simulated machine with incremental encoders: where it powers up, which
    /// axes have an index mark (`None`: absolute encoders, no homing).
    pub fn homing_sim(self) -> Option<HomingSim> {
        self.0.homing
    }

    /// Whether homing starts at boot.
    pub fn home_at_boot(self) -> bool {
        self.0.home_at_boot
    }

    /// Samples after which the scenario fails if it has not concluded.
    pub fn time_limit_ticks(self) -> Option<u32> {
        self.0.time_limit_ticks
    }

    /// Whether the harness prints `track`'s figures with the verdict.
    pub fn tracks(self) -> bool {
        matches!(
            self.0.check,
            Check::Track | Check::Track5g | Check::HomingThenTrack | Check::Upload
        )
    }

    /// Whether this is the 5 g tracking scenario (its motion figures are printed).
    pub fn at_5g(self) -> bool {
        matches!(self.0.check, Check::Track5g)
    }
}

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
/// A bad-image scenario passes after this many samples with the drives never enabled: 0.5 s.
pub const BAD_IMAGE_TICKS: u32 = 1_000;
/// Largest following error at the tool during `track-5g` (µm): the 5 g bound with ±20 %
/// error in every mass and inertia.
pub const MAX_FOLLOWING_ERROR_5G_UM: f32 = 10.0;
/// `track-5g` must run at least this many samples at 4.75 g or more (50 ms).
pub const MIN_SAMPLES_AT_5G: u32 = 100;
/// No test scenario may run longer than this (6 s): then it fails. `run` has no
/// limit and `long-run` ends itself at [`LONG_RUN_TICKS`].
pub const MAX_TICKS: u32 = 12_000;
/// `long-run` observes the production path for 8 s, past [`MAX_TICKS`].
pub const LONG_RUN_TICKS: u32 = 16_000;
/// The tour of `out-of-reach`: towards (320, 0) mm, beyond the 300 mm reach.
pub const OUT_OF_REACH_TOUR_MM: [[f32; 2]; 1] = [[320.0, 0.0]];
/// The encoder frozen at rest freezes this many samples before the move that reaches the top
/// speed starts (in the 200-sample dwell before it).
pub const FROZEN_AT_REST_LEAD: u32 = 100;
/// ... and must be found within this many samples of that move's start (20 ms).
pub const FROZEN_AT_REST_WITHIN: u32 = 40;
/// ... and the tool, coasting from the low speed it had then (about 0.6 rad/s at joint 1),
/// gets no further than this from where it was at the fault (mm; measured: 0.50 mm with the
/// drives' dynamic braking, 1.63 mm free-wheeling; without the check, 43 mm were measured before the stuck
/// check existed).
pub const FROZEN_AT_REST_MAX_TRAVEL_MM: f32 = 2.0;
/// A frozen reading at speed must be found within this many samples (the acceleration check
/// finds it at once if the joint turns faster than `max_accel·dt` = 3 rad/s, the stuck check
/// within a few samples otherwise).
pub const FROZEN_MOVING_WITHIN: u32 = 10;
/// The small glitch: 5 mrad (3,338 counts), 0.75 mm at a 150 mm link.
pub const SMALL_GLITCH_RAD: f32 = 5.0e-3;
/// The large glitch: 0.1 rad.
pub const LARGE_GLITCH_RAD: f32 = 0.1;
/// How far the watchdog's interrupt may be from its stated timeout after the last feed (µs):
/// a tenth of a servo period (QEMU's timing is exact; this is the NMI's entry and the reading of
/// the clock).
pub const WATCHDOG_TIMING_TOLERANCE_US: f32 = 50.0;

/// The homing scenarios' machine (see [`Scenario::homing_sim`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingSim {
    /// Where the tool stands at power-on (mm); the counters read 0 there.
    pub power_on_mm: [f32; 2],
    /// Which axes have an index mark.
    pub index: [bool; 2],
}

/// When the upload scenarios upload (sample): 0.5 s into the tour.
pub const UPLOAD_AT_TICKS: u32 = 1_000;

/// Where the homing scenarios' machine powers up (mm): off home, inside the rectangle.
pub const HOMING_POWER_ON_MM: [f32; 2] = [235.0, -40.0];
/// `homing` may run this long (10 s: homing about 3.5 s, then the tour).
pub const HOMING_MAX_TICKS: u32 = 20_000;
/// After homing, the firmware's readings must equal the plant's true angles within this (rad):
/// a few counts (2^22 counts/rev: 1.5 µrad each).
pub const MAX_HOMED_ENCODER_ERROR_RAD: f32 = 1.0e-5;
/// The drives' torque resolution (N·m): one PWM duty step at 10 N·m full scale over 4250.
pub(crate) const DUTY_STEP_NM: f32 = 2.0 * 10.0 / 4250.0;

/// What the harness does to joint 1's encoder reading in a sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EncoderInjection {
    /// Nothing: the plant's count.
    None,
    /// The counter stops: the reading stays what it was in the previous sample.
    Freeze,
    /// The reading is off by this much (rad) in this sample only.
    Offset(f32),
}

/// Where in the run the faults go: found once at boot from the trajectory.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Injection {
    /// The sample whose setpoint is the trajectory's fastest.
    pub top_speed_sample: u32,
    /// That speed (mm/s).
    pub top_speed_mm_s: f32,
    /// The first sample of the move that reaches it (the machine rests just before).
    pub move_start_sample: u32,
}

impl Injection {
    /// Scans a copy of `trajectory` sample by sample (a few thousand samples, at boot).
    pub fn find(trajectory: &Trajectory, sample_period_s: f32) -> Self {
        let mut t = trajectory.clone();
        let n = t.total_samples();
        let mut last = t.next_mm();
        let (mut best, mut rest) = (Injection::default(), 0u32);
        for k in 1..n {
            let p = t.next_mm();
            let step = libm::hypotf(p[0] - last[0], p[1] - last[1]);
            if step == 0.0 {
                rest = k;
            }
            if step / sample_period_s > best.top_speed_mm_s {
                best = Injection {
                    top_speed_sample: k,
                    top_speed_mm_s: step / sample_period_s,
                    move_start_sample: rest + 1,
                };
            }
            last = p;
        }
        best
    }
}

#[cfg(test)]
mod tests;
