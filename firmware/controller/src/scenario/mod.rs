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
//! reset; the boot after it is [`Scenario::WatchdogRestart`]: the drives must stay off
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
//! # Bounds (`track-5g`, issue 14)
//! The same tour with the time-optimal jerk-limited profile at 5 g (exact derivatives through
//! the setpoint queue, the image's identified dynamics fed forward; the QEMU plant's masses
//! and inertias are 20 % off them, its linkage couples the motors), the same checks, and:
//! * at least [`MIN_SAMPLES_AT_5G`] samples whose setpoint acceleration (backward second
//!   difference of the accepted setpoints, as the servo's jump check sees it) is 4.75 g or more;
//! * the following error at the tool, `|J·(reference - encoder)|` with the image model's
//!   Jacobian at the setpoint, at most [`MAX_FOLLOWING_ERROR_5G_UM`] in every sample.
use kinematics_core::{wrap_angle_rad, Calibration, CorrectionGrid, GridError, SetpointRefusal};

use crate::calibration::{CalibrationState, ImageError};
use crate::calibration_slots::SlotError;
use crate::encoder_check::{EncoderFault, EncoderFaultKind};
use crate::fault::{Fault, StopCategory};
use crate::homing::HomingFault;
use crate::servo_loop::Mode;
use crate::settings::Settings;
use crate::status::Status;
use crate::stop::{MotionState, StopProfile};
use crate::trajectory::{Profile, Trajectory};
use crate::watchdog::{ResetCause, WatchdogFault, TIMEOUT_US};

pub mod stop_check;

use stop_check::{CoastModel, PlantState, StopCheck, StopReport};

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
/// Largest following error at the tool during `track-5g` (µm): the issue's bound with ±20 %
/// error in every mass and inertia.
pub const MAX_FOLLOWING_ERROR_5G_UM: f32 = 10.0;
/// `track-5g` must run at least this many samples at 4.75 g or more (50 ms).
pub const MIN_SAMPLES_AT_5G: u32 = 100;
/// No test scenario may run longer than this (6 s): then it fails. [`Scenario::Run`] has no
/// limit and [`Scenario::LongRun`] ends itself at [`LONG_RUN_TICKS`].
pub const MAX_TICKS: u32 = 12_000;
/// [`Scenario::LongRun`] observes the production path for 8 s, past [`MAX_TICKS`].
pub const LONG_RUN_TICKS: u32 = 16_000;
/// The tour of [`Scenario::OutOfReach`]: towards (320, 0) mm, beyond the 300 mm reach.
pub const OUT_OF_REACH_TOUR_MM: [[f32; 2]; 1] = [[320.0, 0.0]];
/// The encoder frozen at rest freezes this many samples before the move that reaches the top
/// speed starts (in the 200-sample dwell before it).
pub const FROZEN_AT_REST_LEAD: u32 = 100;
/// ... and must be found within this many samples of that move's start (20 ms).
pub const FROZEN_AT_REST_WITHIN: u32 = 40;
/// ... and the tool, coasting from the low speed it had then (about 0.6 rad/s at joint 1),
/// gets no further than this from where it was at the fault (mm; measured: 0.50 mm with the
/// drives' dynamic braking, 1.63 mm free-wheeling; the issue measured 43 mm before the stuck
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
    /// The same tour, jerk-limited at 5 g, with the following error bounded at the tool.
    Track5g,
    /// A NaN setpoint at top speed: `Setpoint(NonFinite)`, category 1.
    NanSetpoint,
    /// A move towards (320, 0) mm, beyond the grid and the 300 mm reach:
    /// `StopOutsideWorkspace` while still inside, category 2, the stop ends inside.
    OutOfReach,
    /// A 1 mm setpoint step at top speed: `Setpoint(Jump)`, category 2.
    Jump,
    /// The setpoint stream runs dry at top speed: `Underrun`, category 2.
    Underrun,
    /// Three 700 µs steps in a row at top speed: `DeadlineMissed` in the third, category 0.
    Overrun,
    /// The encoder of joint 1 frozen at rest, before a move: `Encoder(Stuck)` once the move
    /// starts, category 0.
    EncoderFrozenAtRest,
    /// The encoder of joint 1 frozen at top speed: `Encoder(..)`, category 0.
    EncoderFrozenMoving,
    /// Joint 1's reading off by [`SMALL_GLITCH_RAD`] for one sample at top speed:
    /// `Encoder(Acceleration)`, category 0.
    GlitchSmall,
    /// Joint 1's reading off by [`LARGE_GLITCH_RAD`] for one sample at top speed:
    /// `Encoder(Speed)`, category 0.
    GlitchLarge,
    /// The servo task stalls (interrupts disabled, spinning) at top speed: the watchdog must
    /// remove torque within its timeout (category 0), then reset.
    StalledTask,
    /// The boot after [`Scenario::StalledTask`]'s watchdog reset (not named on the command
    /// line: [`Scenario::after_reset`]): the drives must never be enabled.
    WatchdogRestart,
    /// Incremental encoders with index marks, the machine powered up at an unknown pose
    /// ([`HOMING_POWER_ON_MM`]): homing at boot (speed and torque limited, never a fault), the
    /// encoder zero it sets must make the readings equal the plant's true angles, then the
    /// built-in tour with `track`'s checks (the grid applied).
    Homing,
    /// The same, but joint 1's index mark is missing: `Homing(IndexNotFound(0))`, the machine at
    /// rest with the drives off, never running.
    HomingNoIndex,
    /// `track`, and at [`UPLOAD_AT_TICKS`] the firmware uploads its bundled second image (the
    /// first one's correction field negated) into the inactive slot, commits it and switches
    /// at the next rest: the calibration id shows commit 1, and from the switch on the grid
    /// check finds the new image's corrections applied.
    CalibrationUpload,
    /// The same upload with one byte corrupted on the way: refused (`BadCrc`), the old image
    /// stays in force (commit 0) and applied to the end.
    CalibrationUploadCorrupt,
    /// A bad image flashed by the test, refused with this error: drives never enabled.
    BadImage(GridError),
    /// The host link drives the machine (`firmware/qemu/link.sh`, `host-sim link`): the setpoints
    /// come from the link's motion stream, the built-in tour is not run, nothing is injected,
    /// and the run never concludes (the host ends QEMU). The harness still checks every sample
    /// (deadline and watchdog) and fails the run on a missed deadline. The encoders are
    /// incremental (the machine powers up unhomed at [`HOMING_POWER_ON_MM`]): the host homes it.
    Link,
    /// Self-test of the panic path: the harness panics at boot (`qemu/test.sh` expects the
    /// panic handler's line and exit 1).
    Panic,
    /// Self-test of the HardFault path: the harness executes `udf` at boot.
    HardFault,
}

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
const DUTY_STEP_NM: f32 = 2.0 * 10.0 / 4250.0;

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

impl Scenario {
    /// Parses the semihosting command line (`"<program> <scenario>"`).
    pub fn from_command_line(line: &str) -> Scenario {
        let name = line.split_whitespace().nth(1).unwrap_or("");
        match name {
            "long-run" => Scenario::LongRun,
            "track" => Scenario::Track,
            "track-5g" => Scenario::Track5g,
            "nan-setpoint" => Scenario::NanSetpoint,
            "out-of-reach" => Scenario::OutOfReach,
            "jump" => Scenario::Jump,
            "underrun" => Scenario::Underrun,
            "overrun" => Scenario::Overrun,
            "encoder-frozen-at-rest" => Scenario::EncoderFrozenAtRest,
            "encoder-frozen-moving" => Scenario::EncoderFrozenMoving,
            "glitch-small" => Scenario::GlitchSmall,
            "glitch-large" => Scenario::GlitchLarge,
            "stalled-task" => Scenario::StalledTask,
            "calibration-upload" => Scenario::CalibrationUpload,
            "calibration-upload-corrupt" => Scenario::CalibrationUploadCorrupt,
            "homing" => Scenario::Homing,
            "homing-no-index" => Scenario::HomingNoIndex,
            "bad-image-crc" => Scenario::BadImage(GridError::BadCrc),
            "bad-image-magic" => Scenario::BadImage(GridError::BadMagic),
            "link" => Scenario::Link,
            "panic" => Scenario::Panic,
            "hard-fault" => Scenario::HardFault,
            _ => Scenario::Run,
        }
    }

    /// The scenario of a boot that followed a reset with `cause`: the boot after the stalled
    /// task's watchdog reset is [`Scenario::WatchdogRestart`].
    pub fn after_reset(self, cause: ResetCause) -> Scenario {
        match (self, cause) {
            (Scenario::StalledTask, ResetCause::Watchdog) => Scenario::WatchdogRestart,
            _ => self,
        }
    }

    /// What a watchdog interrupt means in this scenario (the QEMU board's NMI handler, after it
    /// removed torque, asks). See the module doc.
    pub fn watchdog_fired(self, o: &WatchdogObservation) -> WatchdogVerdict {
        match self {
            Scenario::Run => WatchdogVerdict::Production,
            Scenario::StalledTask => match check_watchdog(o) {
                Ok(()) => WatchdogVerdict::AsExpected,
                Err(why) => WatchdogVerdict::Fail(why),
            },
            _ => WatchdogVerdict::Fail("watchdog fired: the servo task did not complete on time"),
        }
    }

    /// Whether the host link's motion replaces the built-in tour ([`Scenario::Link`]).
    pub fn link_motion(self) -> bool {
        self == Scenario::Link
    }

    /// The built-in tour this scenario runs instead of the board's (`production`).
    pub fn tour_mm(self, production: &'static [[f32; 2]]) -> &'static [[f32; 2]] {
        match self {
            Scenario::OutOfReach => &OUT_OF_REACH_TOUR_MM,
            _ => production,
        }
    }

    /// The built-in trajectory's profile and peak acceleration (mm/s²) in this scenario;
    /// `production`'s otherwise.
    pub fn trajectory(self, production: (Profile, f32)) -> (Profile, f32) {
        match self {
            Scenario::Track5g => (
                Profile::JerkLimited,
                5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2,
            ),
            _ => production,
        }
    }

    /// The sample the fault goes in (`None`: nothing injected, or not at a known sample).
    pub fn inject_at(self, i: &Injection) -> Option<u32> {
        match self {
            Scenario::NanSetpoint
            | Scenario::Jump
            | Scenario::Underrun
            | Scenario::Overrun
            | Scenario::EncoderFrozenMoving
            | Scenario::GlitchSmall
            | Scenario::GlitchLarge
            | Scenario::StalledTask => Some(i.top_speed_sample),
            Scenario::EncoderFrozenAtRest => {
                Some(i.move_start_sample.saturating_sub(FROZEN_AT_REST_LEAD))
            }
            _ => None,
        }
    }

    /// The setpoint the intake actually queues as the `n`-th (0-based); `None`: the stream has
    /// run dry.
    pub fn tamper(self, i: &Injection, n: u32, setpoint_mm: [f32; 2]) -> Option<[f32; 2]> {
        let at = self.inject_at(i).unwrap_or(u32::MAX);
        match self {
            Scenario::NanSetpoint if n == at => Some([setpoint_mm[0], f32::NAN]),
            Scenario::Jump if n >= at => Some([setpoint_mm[0] + 1.0, setpoint_mm[1]]),
            Scenario::Underrun if n >= at => None,
            _ => Some(setpoint_mm),
        }
    }

    /// Whether sample `index` must overrun its deadline (deadline fault injection).
    pub fn overrun_at(self, i: &Injection, index: u32) -> bool {
        match (self, self.inject_at(i)) {
            (Scenario::Overrun, Some(at)) => (at..at.saturating_add(3)).contains(&index),
            _ => false,
        }
    }

    /// What happens to joint 1's encoder reading in sample `index`.
    pub fn encoder_at(self, i: &Injection, index: u32) -> EncoderInjection {
        let Some(at) = self.inject_at(i) else {
            return EncoderInjection::None;
        };
        match self {
            Scenario::EncoderFrozenAtRest | Scenario::EncoderFrozenMoving if index >= at => {
                EncoderInjection::Freeze
            }
            Scenario::GlitchSmall if index == at => EncoderInjection::Offset(SMALL_GLITCH_RAD),
            Scenario::GlitchLarge if index == at => EncoderInjection::Offset(LARGE_GLITCH_RAD),
            _ => EncoderInjection::None,
        }
    }

    /// Whether the servo task must stall at the start of sample `index` (`stalled-task`).
    pub fn stall_at(self, i: &Injection, index: u32) -> bool {
        self == Scenario::StalledTask && self.inject_at(i) == Some(index)
    }

    /// When the firmware uploads its bundled second image, and whether corrupted on the way
    /// (`None`: no upload in this scenario).
    pub fn upload(self) -> Option<(u32, bool)> {
        match self {
            Scenario::CalibrationUpload => Some((UPLOAD_AT_TICKS, false)),
            Scenario::CalibrationUploadCorrupt => Some((UPLOAD_AT_TICKS, true)),
            _ => None,
        }
    }

    /// The homing scenarios' (and `link`'s) simulated machine: incremental encoders, where it
    /// powers up, which axes have an index mark (`None`: absolute encoders, no homing).
    pub fn homing_sim(self) -> Option<HomingSim> {
        match self {
            Scenario::Homing => Some(HomingSim {
                power_on_mm: HOMING_POWER_ON_MM,
                index: [true, true],
            }),
            Scenario::HomingNoIndex => Some(HomingSim {
                power_on_mm: HOMING_POWER_ON_MM,
                index: [false, true],
            }),
            // The host link's test homes through the link (`host-sim link home`).
            Scenario::Link => Some(HomingSim {
                power_on_mm: HOMING_POWER_ON_MM,
                index: [true, true],
            }),
            _ => None,
        }
    }

    /// Samples after which the scenario fails if it has not concluded.
    pub fn time_limit_ticks(self) -> Option<u32> {
        match self {
            Scenario::Run | Scenario::LongRun | Scenario::Link => None,
            Scenario::Homing => Some(HOMING_MAX_TICKS),
            Scenario::CalibrationUpload | Scenario::CalibrationUploadCorrupt => {
                Some(MAX_TICKS + 1_000)
            }
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
    /// The simulated plant's true joint state (not the encoders).
    pub plant: PlantState,
}

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
fn check_watchdog(o: &WatchdogObservation) -> Result<(), &'static str> {
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

/// What a fault scenario expects.
#[derive(Clone, Copy)]
struct Expected {
    /// The fault's first sample must be in this window (inclusive), if known.
    window: Option<(u32, u32)>,
    fault: fn(Fault) -> bool,
    /// Largest travel of the tool from the fault (mm), beyond the category's own bound.
    max_travel_mm: Option<f32>,
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

    /// [`Scenario::WatchdogRestart`]: the controller reset while the machine was moving; `plant`
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
        let at = self.scenario.inject_at(&self.injection);
        let at_top_speed = |within: u32| at.map(|a| (a, a + within));
        let verdict = match self.scenario {
            Scenario::Run => None,
            // The host checks the motion; the harness ends the run if a deadline is missed.
            Scenario::Link => {
                (s.overruns > 0).then_some(Err("servo deadline missed while the host link ran"))
            }
            Scenario::Panic | Scenario::HardFault => {
                Some(Err("the self-test did not stop the firmware"))
            }
            Scenario::LongRun => self.long_run(o),
            Scenario::Track => self.track(o),
            Scenario::Track5g => match self.track_motion(o) {
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
            Scenario::NanSetpoint => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(0),
                    fault: |f| f == Fault::Setpoint(SetpointRefusal::NonFinite),
                    max_travel_mm: None,
                },
            ),
            Scenario::Jump => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(0),
                    fault: |f| f == Fault::Setpoint(SetpointRefusal::Jump),
                    max_travel_mm: None,
                },
            ),
            Scenario::Underrun => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(0),
                    fault: |f| f == Fault::Underrun,
                    max_travel_mm: None,
                },
            ),
            Scenario::OutOfReach => {
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
                self.fault_scenario(
                    o,
                    Expected {
                        window: None,
                        fault: |f| f == Fault::StopOutsideWorkspace,
                        max_travel_mm: None,
                    },
                )
            }
            Scenario::Overrun => {
                let streak = self.settings.overrun_streak_limit.max(1) - 1;
                let window = at.map(|a| (a + streak, a + streak));
                let verdict = self.fault_scenario(
                    o,
                    Expected {
                        window,
                        fault: |f| f == Fault::DeadlineMissed,
                        max_travel_mm: None,
                    },
                );
                verdict.map(|v| v.and_then(|()| require(s.overruns >= 3, "overruns not counted")))
            }
            Scenario::EncoderFrozenAtRest => {
                let start = self.injection.move_start_sample;
                self.fault_scenario(
                    o,
                    Expected {
                        window: Some((start, start + FROZEN_AT_REST_WITHIN)),
                        fault: |f| {
                            matches!(
                                f,
                                Fault::Encoder(EncoderFault {
                                    axis: 0,
                                    kind: EncoderFaultKind::Stuck
                                })
                            )
                        },
                        max_travel_mm: Some(FROZEN_AT_REST_MAX_TRAVEL_MM),
                    },
                )
            }
            Scenario::EncoderFrozenMoving => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(FROZEN_MOVING_WITHIN),
                    fault: |f| matches!(f, Fault::Encoder(EncoderFault { axis: 0, .. })),
                    max_travel_mm: None,
                },
            ),
            Scenario::GlitchSmall => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(0),
                    fault: |f| {
                        f == Fault::Encoder(EncoderFault {
                            axis: 0,
                            kind: EncoderFaultKind::Acceleration,
                        })
                    },
                    max_travel_mm: None,
                },
            ),
            Scenario::GlitchLarge => self.fault_scenario(
                o,
                Expected {
                    window: at_top_speed(0),
                    fault: |f| {
                        f == Fault::Encoder(EncoderFault {
                            axis: 0,
                            kind: EncoderFaultKind::Speed,
                        })
                    },
                    max_travel_mm: None,
                },
            ),
            Scenario::Homing => self.homing_then_track(o),
            Scenario::CalibrationUpload | Scenario::CalibrationUploadCorrupt => self
                .track(o)
                .map(|v| v.and_then(|()| self.upload_outcome(s))),
            Scenario::HomingNoIndex => self.homing_no_index(o),
            Scenario::BadImage(expected) => self.bad_image(o, expected),
            Scenario::StalledTask => self.before_stall(o),
            Scenario::WatchdogRestart => self.watchdog_restart(o),
        };
        self.last_joint_rad = o.plant.joint_rad;
        verdict
    }

    /// A fault is expected (in `e.window` if given): before it the drives must be on and the
    /// machine running; from its own sample on, the reaction of its stop category
    /// ([`stop_check`]).
    fn fault_scenario(&mut self, o: &Observation<'_>, e: Expected) -> Verdict {
        let s = o.status;
        let sample = s.ticks.wrapping_sub(1);
        let Ok(cal) = self.image else {
            return Some(Err("calibration image not valid"));
        };
        let (tool, inside) = tool_mm(&cal, o.plant.joint_rad);
        let Some(fault) = s.fault else {
            if matches!(e.window, Some((_, last)) if sample >= last) {
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
            if matches!(e.window, Some((first, last)) if !(first..=last).contains(&sample)) {
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
    fn upload_outcome(&self, s: &Status) -> Result<(), &'static str> {
        let sequence = s.calibration_id.map(|i| i.sequence);
        if self.scenario == Scenario::CalibrationUploadCorrupt {
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
    /// index, and its whole travel can reach the parallel singularity, firmware/README.md,
    /// "Homing", known limitation.)
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

/// The hardware shows the safe state: drive enable off, zero torque.
fn safe_state(o: &Observation<'_>) -> Result<(), &'static str> {
    require(!o.drive_enable, "drive enable still on after the fault")?;
    require(
        o.drive_torque_nm == [0.0; 2],
        "torque commanded after the fault",
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{
        append_dynamics, append_workspace, encode, GridGeometry, WorkspaceLimits, DYNAMICS_LEN,
        WORKSPACE_LEN,
    };
    use kinematics_core::{ConvexWorkspace, FiveBar, FiveBarDynamics, KinematicsError};

    /// The QEMU image's geometry with a constant correction, without extension blocks.
    fn plain_image(correction_rad: [f32; 2]) -> Vec<u8> {
        let g = GridGeometry {
            nx: 21,
            ny: 31,
            x0_mm: 162.132,
            y0_mm: -75.0,
            step_x_mm: 5.0,
            step_y_mm: 5.0,
        };
        let mut img = vec![0u8; g.image_len()];
        encode(
            &mut img,
            &g,
            &FiveBar::paper_nominal(),
            &vec![correction_rad; g.len()],
        )
        .unwrap();
        img
    }

    /// [`plain_image`] with the workspace and dynamics blocks, as the bundled image has them.
    fn image(correction_rad: [f32; 2]) -> Vec<u8> {
        let mut img = plain_image(correction_rad);
        let n = img.len();
        img.resize(n + WORKSPACE_LEN + DYNAMICS_LEN, 0);
        let region = ConvexWorkspace::rectangle([162.132, 262.132], [-75.0, 75.0]).unwrap();
        let end = append_workspace(
            &mut img,
            n,
            n,
            &WorkspaceLimits {
                region,
                stop_margin_mm: 0.1,
            },
        )
        .unwrap();
        let d = FiveBarDynamics {
            motor_inertia_kg_m2: [3e-3; 2],
            tool_mass_kg: 0.1,
            distal_inertia_kg_m2: [0.0; 2],
            viscous_nm_s_per_rad: [0.01; 2],
            coulomb_nm: [0.0; 2],
            coulomb_speed_rad_s: 0.01,
        };
        append_dynamics(&mut img, n, end, &d).unwrap();
        img
    }

    const D_RAD: [f32; 2] = [3e-4, -2.5e-4];
    const P_MM: [f32; 2] = [212.132, 0.0];
    const DT_S: f32 = crate::SAMPLE_PERIOD_S;
    /// Independent joints with the QEMU plant's rotors: dynamic braking 0.225 N·m·s/rad, coast
    /// time constants 9.4 / 7.7 ms (the plant itself is coupled, `coupled_inertia_kg_m2`).
    const COAST: CoastModel = CoastModel {
        inertia_kg_m2: [2.2e-3, 1.8e-3],
        viscous_nm_s_per_rad: 0.01,
        dynamic_brake_nm_s_per_rad: 0.225,
        coupled_inertia_kg_m2: 0.0,
    };
    /// Faults at sample 1000; the move reaching it starts at 900.
    const INJECTION: Injection = Injection {
        top_speed_sample: 1000,
        top_speed_mm_s: 1000.0,
        move_start_sample: 900,
    };

    fn cal(img: &[u8]) -> Calibration<'_> {
        Calibration::from_grid(CorrectionGrid::parse(img).unwrap())
    }

    /// A running status at `ticks` with the reference IK + `d` at `P_MM`.
    fn running(ticks: u32, d: [f32; 2]) -> Status {
        let ik = FiveBar::<f32>::paper_nominal().inverse(P_MM, 0.05).unwrap();
        let reference = [ik[0] + d[0], ik[1] + d[1]];
        Status {
            ticks,
            overruns: 0,
            worst_step_us: 12.0,
            calibration: CalibrationState::Valid,
            mode: Mode::Running,
            fault: None,
            fault_tick: 0,
            drives_enabled: true,
            stop_distance_mm: 0.0,
            setpoint_mm: P_MM,
            setpoint_moved: false,
            reference_rad: reference,
            encoder_rad: reference,
            torque_nm: [0.1, -0.1],
            max_following_error_rad: 1e-4,
            setpoint_underruns: 0,
            calibration_id: None,
            last_upload: None,
            homing: None,
        }
    }

    /// The plant at the status' reference (a machine that follows exactly).
    fn plant_of(status: &Status) -> PlantState {
        PlantState {
            joint_rad: status.reference_rad,
            joint_rad_s: [0.0; 2],
        }
    }

    fn on(status: &Status) -> Observation<'_> {
        Observation {
            status,
            drive_enable: true,
            drive_enable_ever: true,
            drive_torque_nm: status.torque_nm,
            plant: plant_of(status),
        }
    }

    fn off(status: &Status) -> Observation<'_> {
        Observation {
            status,
            drive_enable: false,
            drive_enable_ever: true,
            drive_torque_nm: [0.0; 2],
            plant: plant_of(status),
        }
    }

    fn checker(scenario: Scenario, img: &[u8]) -> Checker<'_> {
        Checker::new(
            scenario,
            CorrectionGrid::parse(img),
            &Settings::default(),
            3_000,
            INJECTION,
            COAST,
        )
    }

    /// `homing`: torque above the homing limit while homing fails; after homing, readings that
    /// are not the plant's true angles (a wrong zero) fail; the right zero goes on to `track`.
    #[test]
    fn homing_fails_on_torque_above_its_limit_or_a_wrong_zero() {
        let img = image(D_RAD);
        let homing = |ticks, torque_nm| Status {
            mode: Mode::Homing,
            torque_nm,
            ..running(ticks, D_RAD)
        };
        let mut c = checker(Scenario::Homing, &img);
        assert_eq!(c.observe(&on(&homing(1, [1.9, -1.9]))), None);
        assert_eq!(
            c.observe(&on(&homing(2, [2.5, 0.0]))),
            Some(Err("torque above the homing limit"))
        );
        assert_eq!(
            c.observe(&off(&homing(3, [0.0, 0.0]))),
            Some(Err("drives not enabled while homing"))
        );
        let s = running(100, D_RAD);
        let mut wrong = on(&s);
        wrong.plant.joint_rad[0] += 1e-3;
        let mut c = checker(Scenario::Homing, &img);
        assert_eq!(
            c.observe(&wrong),
            Some(Err(
                "after homing the readings are not the joints' true angles"
            ))
        );
        let mut c = checker(Scenario::Homing, &img);
        assert_eq!(c.observe(&on(&s)), None);
        assert_eq!(c.homed_at(), Some(100));
    }

    /// The upload scenarios' verdict at the end of the tour: committed and switched (with grid
    /// checks against the new image), or refused for its CRC with the old image kept.
    #[test]
    fn the_upload_outcome_is_checked() {
        use crate::calibration_slots::CalibrationId;
        let img = image(D_RAD);
        let id = |sequence| CalibrationId {
            slot: sequence as u8,
            sequence,
            crc32: 7,
            len: 100,
        };
        let c = checker(Scenario::CalibrationUpload, &img);
        let not_switched = Status {
            calibration_id: Some(id(0)),
            last_upload: Some(Ok(id(1))),
            ..running(1, D_RAD)
        };
        assert_eq!(
            c.upload_outcome(&not_switched),
            Err("the servo did not switch to the new image")
        );
        let switched = Status {
            calibration_id: Some(id(1)),
            ..not_switched
        };
        assert_eq!(
            c.upload_outcome(&switched),
            Err("too few grid checks against the new image")
        );
        let c = checker(Scenario::CalibrationUploadCorrupt, &img);
        let refused = Status {
            calibration_id: Some(id(0)),
            last_upload: Some(Err(SlotError::Image(ImageError::Grid(GridError::BadCrc)))),
            ..running(1, D_RAD)
        };
        assert_eq!(c.upload_outcome(&refused), Ok(()));
        assert!(c.upload_outcome(&switched).is_err());
    }

    #[test]
    fn command_line_names() {
        for (line, want) in [
            ("firmware", Scenario::Run),
            ("", Scenario::Run),
            ("firmware link", Scenario::Link),
            ("firmware bogus", Scenario::Run),
            ("firmware long-run", Scenario::LongRun),
            ("firmware track", Scenario::Track),
            ("firmware track-5g", Scenario::Track5g),
            ("firmware nan-setpoint", Scenario::NanSetpoint),
            ("firmware out-of-reach", Scenario::OutOfReach),
            ("firmware jump", Scenario::Jump),
            ("firmware underrun", Scenario::Underrun),
            ("firmware overrun", Scenario::Overrun),
            (
                "firmware encoder-frozen-at-rest",
                Scenario::EncoderFrozenAtRest,
            ),
            (
                "firmware encoder-frozen-moving",
                Scenario::EncoderFrozenMoving,
            ),
            ("firmware glitch-small", Scenario::GlitchSmall),
            ("firmware glitch-large", Scenario::GlitchLarge),
            ("firmware stalled-task", Scenario::StalledTask),
            (
                "firmware bad-image-crc",
                Scenario::BadImage(GridError::BadCrc),
            ),
            (
                "firmware bad-image-magic",
                Scenario::BadImage(GridError::BadMagic),
            ),
            ("firmware panic", Scenario::Panic),
            ("firmware hard-fault", Scenario::HardFault),
        ] {
            assert_eq!(Scenario::from_command_line(line), want, "{line:?}");
        }
    }

    #[test]
    fn injection_happens_only_where_the_scenario_says() {
        let (i, at) = (&INJECTION, INJECTION.top_speed_sample);
        let p = [200.0, 10.0];
        assert!(Scenario::NanSetpoint.tamper(i, at, p).unwrap()[1].is_nan());
        assert_eq!(Scenario::NanSetpoint.tamper(i, at + 1, p), Some(p));
        assert_eq!(Scenario::Jump.tamper(i, at - 1, p), Some(p));
        assert_eq!(Scenario::Jump.tamper(i, at + 5, p), Some([201.0, 10.0]));
        assert_eq!(Scenario::Underrun.tamper(i, at - 1, p), Some(p));
        assert_eq!(Scenario::Underrun.tamper(i, at + 7, p), None);
        for s in [Scenario::Run, Scenario::LongRun, Scenario::Track] {
            assert_eq!(s.tamper(i, at, p), Some(p));
            assert!(!s.overrun_at(i, at));
            assert_eq!(s.encoder_at(i, at), EncoderInjection::None);
            assert_eq!(s.tour_mm(&[[1.0, 2.0]]), &[[1.0, 2.0]]);
        }
        let overruns: Vec<u32> = (0..5_000)
            .filter(|&k| Scenario::Overrun.overrun_at(i, k))
            .collect();
        assert_eq!(overruns, [at, at + 1, at + 2]);
        assert_eq!(Scenario::OutOfReach.tour_mm(&[]), &OUT_OF_REACH_TOUR_MM);
        assert_eq!(
            Scenario::GlitchSmall.encoder_at(i, at),
            EncoderInjection::Offset(SMALL_GLITCH_RAD)
        );
        assert_eq!(
            Scenario::GlitchSmall.encoder_at(i, at + 1),
            EncoderInjection::None
        );
        assert_eq!(
            Scenario::GlitchLarge.encoder_at(i, at),
            EncoderInjection::Offset(LARGE_GLITCH_RAD)
        );
        assert_eq!(
            Scenario::EncoderFrozenMoving.encoder_at(i, at - 1),
            EncoderInjection::None
        );
        assert_eq!(
            Scenario::EncoderFrozenMoving.encoder_at(i, at + 300),
            EncoderInjection::Freeze
        );
        let rest = INJECTION.move_start_sample - FROZEN_AT_REST_LEAD;
        assert_eq!(
            Scenario::EncoderFrozenAtRest.encoder_at(i, rest - 1),
            EncoderInjection::None
        );
        assert_eq!(
            Scenario::EncoderFrozenAtRest.encoder_at(i, rest),
            EncoderInjection::Freeze
        );
    }

    /// On the built-in tour the top speed is 1.38 m/s, mid-way along the long diagonal, and
    /// the move reaching it starts after a rest.
    #[test]
    fn injection_finds_the_tours_top_speed_and_the_rest_before_it() {
        let settings = Settings {
            builtin_tour_mm: &crate::trajectory::WORKSPACE_TOUR_MM,
            ..Settings::default()
        };
        let t = Trajectory::builtin(P_MM, &settings);
        let i = Injection::find(&t, DT_S);
        // 15/8·D/T with D = 160.4 mm and T = 0.218 s (436 samples: the 2 g limit binds).
        assert!((i.top_speed_mm_s - 1379.4).abs() < 0.5, "{i:?}");
        let mut t2 = t.clone();
        let points: Vec<[f32; 2]> = (0..t.total_samples()).map(|_| t2.next_mm()).collect();
        let at = i.top_speed_sample as usize;
        // Mid-way between (255, -68) and (170, 68).
        assert!(
            (points[at][0] - 212.5).abs() < 1.0 && points[at][1].abs() < 1.5,
            "{:?}",
            points[at]
        );
        let start = i.move_start_sample as usize;
        assert_eq!(
            points[start - 1],
            [255.0, -68.0],
            "rests at the move's start point"
        );
        assert_ne!(points[start], points[start - 1]);
        assert!(points[start - 1 - FROZEN_AT_REST_LEAD as usize..start]
            .iter()
            .all(|p| *p == [255.0, -68.0]));
    }

    /// The bug of issue 18: the production path must never be stopped by a time limit.
    #[test]
    fn the_production_path_has_no_time_limit() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::Run, &img);
        for ticks in [
            1,
            MAX_TICKS - 1,
            MAX_TICKS,
            LONG_RUN_TICKS,
            10 * LONG_RUN_TICKS,
            u32::MAX,
        ] {
            let s = running(ticks, D_RAD);
            assert_eq!(c.observe(&on(&s)), None, "ticks {ticks}");
        }
        // A test scenario is limited.
        let mut c = checker(Scenario::NanSetpoint, &img);
        assert_eq!(
            c.observe(&on(&running(MAX_TICKS, D_RAD))),
            Some(Err("scenario did not finish in time"))
        );
    }

    #[test]
    fn long_run_passes_at_8_s_only_if_still_running_without_fault() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::LongRun, &img);
        for ticks in [1, 5_000, MAX_TICKS, LONG_RUN_TICKS - 1] {
            assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
        }
        assert_eq!(
            c.observe(&on(&running(LONG_RUN_TICKS, D_RAD))),
            Some(Ok(()))
        );
        let s = running(9_000, D_RAD);
        assert!(
            matches!(
                checker(Scenario::LongRun, &img).observe(&off(&s)),
                Some(Err(_))
            ),
            "enable line low"
        );
        let s = Status {
            fault: Some(Fault::DeadlineMissed),
            ..running(9_000, D_RAD)
        };
        assert!(matches!(
            checker(Scenario::LongRun, &img).observe(&on(&s)),
            Some(Err(_))
        ));
    }

    // -----------------------------------------------------------------------------------------
    // Fault scenarios against a synthetic machine: at rest at 190 mm, then along +x at 1 m/s
    // for 20 samples; at the fault (sample `fault_at`) it follows the stop the checker
    // plans (or coasts, category 0), with `tweak` changing what the hardware or plant shows.

    /// One sample of the synthetic machine.
    struct Frame {
        status: Status,
        enable: bool,
        torque_nm: [f32; 2],
        plant: PlantState,
    }

    /// What to break.
    #[derive(Clone, Copy, PartialEq)]
    enum Tweak {
        None,
        /// The stop goes this much further (mm).
        Overshoot(f32),
        /// Enable low during a category-2 stop.
        EnableLow,
        /// Category 0: enable left on / torque left on.
        EnableLeftOn,
        TorqueLeftOn,
        /// Category 0: the joints keep going at their speed (pushed, or a drive that does not
        /// brake).
        Pushed,
        /// Category 0: the joints never come to rest.
        NeverAtRest,
        /// Category 1: torque never removed.
        NeverOff,
        /// Category 2: the tool drifts 5 µm per sample while holding.
        Drift,
        /// Category 2: the status never says Holding.
        NotHolding,
    }

    /// The synthetic machine's setpoint before the fault at `fault_at`: at rest at 190 mm,
    /// moving at 1 m/s along +x for the last 20 samples.
    fn x_before(k: u32, fault_at: u32) -> f32 {
        190.0 + 1000.0 * DT_S * k.saturating_sub(fault_at - 20) as f32
    }

    fn synthetic<'i>(
        img: &'i [u8],
        fault: Fault,
        fault_at: u32,
        tweak: Tweak,
    ) -> impl Fn(u32) -> Frame + 'i {
        let c = cal(img);
        let dt = DT_S;
        let settings = Settings::default();
        let v = [1000.0f32, 0.0];
        let state =
            MotionState::from_differences([x_before(fault_at - 1, fault_at), 0.0], v, [0.0; 2], dt);
        let profile = StopProfile::plan(&state, &settings.stop.limits);
        let category = fault.stop_category();
        let theta = move |x: f32| c.command_rad([x, 0.0], 0.05).unwrap();
        // The setpoint of sample k; the plant lags one sample behind (it is where the previous
        // sample's setpoint asked it to be, as the QEMU plant is).
        let x_at = move |k: u32| {
            if k < fault_at {
                x_before(k, fault_at)
            } else {
                let t = (k - fault_at + 1) as f32 * dt;
                let extra = match tweak {
                    Tweak::Overshoot(mm) => mm * (t / profile.duration_s()).min(1.0),
                    // From the start of the hold check on.
                    Tweak::Drift => {
                        5e-3 * ((t - profile.duration_s() - stop_check::HOLD_AFTER_S) / dt).max(0.0)
                    }
                    _ => 0.0,
                };
                profile.origin_mm()[0] + profile.distance_at(t) + extra
            }
        };
        move |k: u32| {
            let mut status = running(k + 1, D_RAD);
            let (x, mode, enable) = if k < fault_at {
                (x_before(k, fault_at), Mode::Running, true)
            } else {
                let t = (k - fault_at + 1) as f32 * dt;
                let x = x_at(k);
                let finished = profile.finished(t);
                let mode = match category {
                    StopCategory::Zero => Mode::SafeState(fault),
                    StopCategory::One if finished && tweak != Tweak::NeverOff => {
                        Mode::SafeState(fault)
                    }
                    StopCategory::Two if finished && tweak != Tweak::NotHolding => {
                        Mode::Holding(fault)
                    }
                    _ => Mode::Stopping(fault),
                };
                let enable = match category {
                    StopCategory::Zero => tweak == Tweak::EnableLeftOn,
                    StopCategory::One => !matches!(mode, Mode::SafeState(_)),
                    StopCategory::Two => tweak != Tweak::EnableLow,
                };
                (x, mode, enable)
            };
            status.setpoint_mm = [x, 0.0];
            status.mode = mode;
            if k >= fault_at {
                status.fault = Some(fault);
                status.fault_tick = fault_at;
                status.overruns = 3;
            }
            let mut plant = PlantState {
                joint_rad: theta(x_at(k.saturating_sub(1))),
                joint_rad_s: [0.0; 2],
            };
            if category == StopCategory::Zero && k >= fault_at {
                // Coasts: the joints' speed at the fault, decelerating to rest in 10 ms (travel
                // w·5 ms, inside the dynamic-braking bound J·w/(c + b) = w·7.7 ms for joint 2).
                let (a, b) = (
                    theta(x_before(fault_at - 2, fault_at)),
                    theta(x_before(fault_at - 1, fault_at)),
                );
                let w = [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt];
                let t = (k - fault_at) as f32 * dt;
                let (travel, speed) = match tweak {
                    Tweak::Pushed => (t, 1.0),
                    Tweak::NeverAtRest => (t.min(0.005), if t < 0.005 { 1.0 } else { 0.01 }),
                    _ => {
                        let t = t.min(0.01);
                        (t - t * t / 0.02, 1.0 - t / 0.01)
                    }
                };
                plant = PlantState {
                    joint_rad: [0, 1].map(|i| b[i] + w[i] * travel),
                    joint_rad_s: [0, 1].map(|i| w[i] * speed),
                };
            }
            let torque_nm = if enable || tweak == Tweak::TorqueLeftOn {
                [0.3, -0.2]
            } else {
                [0.0; 2]
            };
            status.torque_nm = torque_nm;
            Frame {
                status,
                enable,
                torque_nm,
                plant,
            }
        }
    }

    /// Runs `scenario`'s checker over the synthetic machine; returns the verdict and the report.
    fn run_fault(
        scenario: Scenario,
        fault: Fault,
        fault_at: u32,
        tweak: Tweak,
    ) -> (Verdict, Option<StopReport>) {
        run_fault_coasting(COAST, scenario, fault, fault_at, tweak)
    }

    /// [`run_fault`] with the checker bounding a coast by `coast`.
    fn run_fault_coasting(
        coast: CoastModel,
        scenario: Scenario,
        fault: Fault,
        fault_at: u32,
        tweak: Tweak,
    ) -> (Verdict, Option<StopReport>) {
        let img = image(D_RAD);
        let frames = synthetic(&img, fault, fault_at, tweak);
        let mut c = Checker::new(
            scenario,
            CorrectionGrid::parse(&img),
            &Settings::default(),
            3_000,
            INJECTION,
            coast,
        );
        for k in 0..MAX_TICKS {
            let f = frames(k);
            let o = Observation {
                status: &f.status,
                drive_enable: f.enable,
                drive_enable_ever: true,
                drive_torque_nm: f.torque_nm,
                plant: f.plant,
            };
            if let Some(v) = c.observe(&o) {
                return (Some(v), c.stop_report());
            }
        }
        (None, c.stop_report())
    }

    #[test]
    fn category_two_passes_only_braking_within_the_plan_and_holding() {
        let jump = Fault::Setpoint(SetpointRefusal::Jump);
        let (v, report) = run_fault(Scenario::Jump, jump, 1000, Tweak::None);
        assert_eq!(v, Some(Ok(())));
        let r = report.unwrap();
        // 1 m/s: 10.2 + 2.5 mm.
        assert!(
            (r.planned_mm - 12.70).abs() < 0.05 && (r.travelled_mm - r.planned_mm).abs() < 0.05,
            "{r:?}"
        );
        assert!((r.speed_mm_s - 1000.0).abs() < 5.0, "{r:?}");
        for (tweak, why) in [
            (Tweak::Overshoot(0.2), "the stop went further than planned"),
            (
                Tweak::EnableLow,
                "drive enable low during a category-2 stop",
            ),
            (Tweak::Drift, "the tool does not hold the stop's end point"),
            (Tweak::NotHolding, "the loop is not holding after the stop"),
        ] {
            assert_eq!(
                run_fault(Scenario::Jump, jump, 1000, tweak).0,
                Some(Err(why))
            );
        }
        assert_eq!(
            run_fault(Scenario::Jump, jump, 1001, Tweak::None).0,
            Some(Err("no fault in the sample the fault was injected in"))
        );
        assert_eq!(
            run_fault(Scenario::Jump, jump, 999, Tweak::None).0,
            Some(Err("fault not in the sample the fault was injected in"))
        );
        assert_eq!(
            run_fault(Scenario::Jump, Fault::Underrun, 1000, Tweak::None).0,
            Some(Err("wrong fault"))
        );
        assert_eq!(
            run_fault(Scenario::Underrun, Fault::Underrun, 1000, Tweak::None).0,
            Some(Ok(()))
        );
    }

    #[test]
    fn category_one_passes_only_with_torque_removed_after_the_stop() {
        let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
        let (v, report) = run_fault(Scenario::NanSetpoint, nan, 1000, Tweak::None);
        assert_eq!(v, Some(Ok(())));
        assert!(report.unwrap().torque_off_after > 20);
        assert_eq!(
            run_fault(Scenario::NanSetpoint, nan, 1000, Tweak::NeverOff).0,
            Some(Err("torque not removed after the stop"))
        );
        assert_eq!(
            run_fault(Scenario::NanSetpoint, nan, 1000, Tweak::Overshoot(0.2)).0,
            Some(Err("the stop went further than planned"))
        );
    }

    #[test]
    fn category_zero_passes_only_with_the_hardware_off_a_braked_coast_and_the_tool_inside() {
        let at = INJECTION.top_speed_sample + 2;
        let (v, report) = run_fault(Scenario::Overrun, Fault::DeadlineMissed, at, Tweak::None);
        assert_eq!(v, Some(Ok(())));
        let r = report.unwrap();
        assert!(
            r.joint_travel_rad
                .iter()
                .zip(r.coast_bound_rad)
                .all(|(t, b)| *t <= b && b > 0.0),
            "{r:?}"
        );
        for (tweak, why) in [
            (Tweak::EnableLeftOn, "drive enable still on after the fault"),
            (Tweak::TorqueLeftOn, "torque commanded after the fault"),
            (
                Tweak::Pushed,
                "a joint coasted further than the dynamic-braking bound",
            ),
            (
                Tweak::NeverAtRest,
                "the joints are not at rest at the end of the coast",
            ),
        ] {
            assert_eq!(
                run_fault(Scenario::Overrun, Fault::DeadlineMissed, at, tweak).0,
                Some(Err(why)),
                "{why}"
            );
        }
        // Checked against a free-wheeling drive's bound (no dynamic braking), a coast that goes
        // on at speed leaves the calibrated rectangle first: the workspace bound holds on its own.
        let free = CoastModel {
            dynamic_brake_nm_s_per_rad: 0.0,
            ..COAST
        };
        let (v, report) = run_fault_coasting(
            free,
            Scenario::Overrun,
            Fault::DeadlineMissed,
            at,
            Tweak::Pushed,
        );
        assert_eq!(v, Some(Err("the tool left the calibrated rectangle")));
        assert!(report.unwrap().left_workspace);
        // An encoder fault at rest must also keep the tool inside and barely moving.
        let stuck = Fault::Encoder(EncoderFault {
            axis: 0,
            kind: EncoderFaultKind::Stuck,
        });
        assert_eq!(
            run_fault(Scenario::EncoderFrozenAtRest, stuck, 910, Tweak::None).0,
            Some(Err("the tool travelled further than the scenario allows"))
        );
        let glitch = Fault::Encoder(EncoderFault {
            axis: 0,
            kind: EncoderFaultKind::Acceleration,
        });
        assert_eq!(
            run_fault(Scenario::GlitchSmall, glitch, 1000, Tweak::None).0,
            Some(Ok(()))
        );
        assert_eq!(
            run_fault(Scenario::GlitchLarge, glitch, 1000, Tweak::None).0,
            Some(Err("wrong fault"))
        );
        assert_eq!(
            run_fault(Scenario::EncoderFrozenMoving, glitch, 1005, Tweak::None).0,
            Some(Ok(()))
        );
    }

    #[test]
    fn drives_off_before_the_fault_fail() {
        let img = image(D_RAD);
        let s = running(5, D_RAD);
        assert_eq!(
            checker(Scenario::NanSetpoint, &img).observe(&off(&s)),
            Some(Err("drives not enabled before the fault"))
        );
    }

    #[test]
    fn out_of_reach_fails_if_an_out_of_grid_setpoint_was_accepted() {
        let img = image(D_RAD);
        let mut c = checker(Scenario::OutOfReach, &img);
        assert_eq!(
            c.observe(&on(&Status {
                setpoint_mm: [263.0, 0.0],
                ..running(2_999, D_RAD)
            })),
            None
        );
        let s = Status {
            fault: Some(Fault::StopOutsideWorkspace),
            ..running(3_000, D_RAD)
        };
        assert_eq!(
            c.observe(&on(&s)),
            Some(Err("an out-of-grid setpoint was accepted"))
        );
        let mut c = checker(Scenario::OutOfReach, &img);
        assert_eq!(c.observe(&on(&running(2_999, D_RAD))), None);
        let s = Status {
            fault: Some(Fault::Setpoint(SetpointRefusal::Kinematics(
                KinematicsError::Unreachable,
            ))),
            ..running(3_000, D_RAD)
        };
        assert_eq!(c.observe(&on(&s)), Some(Err("wrong fault")));
    }

    #[test]
    fn a_bad_image_passes_only_if_the_drives_were_never_enabled() {
        let refused = |ticks| Status {
            calibration: CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
            fault: Some(Fault::Calibration(ImageError::Grid(GridError::BadCrc))),
            torque_nm: [0.0; 2],
            ..running(ticks, D_RAD)
        };
        fn never(s: &Status) -> Observation<'_> {
            Observation {
                drive_enable_ever: false,
                ..off(s)
            }
        }
        let settings = Settings::default();
        let mut c = Checker::new(
            Scenario::BadImage(GridError::BadCrc),
            Err(GridError::BadCrc),
            &settings,
            0,
            INJECTION,
            COAST,
        );
        for ticks in 1..BAD_IMAGE_TICKS {
            assert_eq!(c.observe(&never(&refused(ticks))), None);
        }
        assert_eq!(c.observe(&never(&refused(BAD_IMAGE_TICKS))), Some(Ok(())));
        // Enabled once, even if off now.
        assert_eq!(
            c.observe(&off(&refused(5))),
            Some(Err("drives enabled at a boot that must keep them off"))
        );
        let wrong = Status {
            calibration: CalibrationState::Refused(ImageError::Grid(GridError::BadMagic)),
            ..refused(BAD_IMAGE_TICKS)
        };
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
    fn track_fails_on_an_image_without_its_extension_blocks() {
        let img = plain_image(D_RAD);
        let mut c = checker(Scenario::Track, &img);
        let verdict = (1..MAX_TICKS).find_map(|ticks| c.observe(&on(&running(ticks, D_RAD))));
        assert_eq!(
            verdict,
            Some(Err("the image lacks its workspace or dynamics block"))
        );
    }

    #[test]
    fn track_passes_only_if_the_grid_is_applied_and_large_enough_to_tell() {
        assert_eq!(run_track(D_RAD, D_RAD), Some(Ok(())));
        // Grid validated but not applied: the reference is the bare IK.
        assert_eq!(
            run_track([0.0; 2], D_RAD),
            Some(Err(
                "commanded angle minus model IK is not the grid correction: grid not applied"
            ))
        );
        // An image whose corrections are too small to tell.
        assert_eq!(
            run_track([1e-5, 0.0], [1e-5, 0.0]),
            Some(Err(
                "grid corrections too small to tell an applied grid from a missing one"
            ))
        );
        let img = image(D_RAD);
        let mut c = checker(Scenario::Track, &img);
        for ticks in 1..5_000 {
            c.observe(&on(&running(ticks, D_RAD)));
        }
        let g = c.grid_check();
        assert!(
            g.checks >= 10 && g.worst_residual_rad <= MAX_GRID_RESIDUAL_RAD,
            "{g:?}"
        );
        assert_eq!(g.largest_correction_rad, 3e-4);
    }

    #[test]
    fn track_fails_on_a_fault_a_low_enable_line_or_a_bound() {
        let img = image(D_RAD);
        let s = running(10, D_RAD);
        assert_eq!(
            checker(Scenario::Track, &img).observe(&off(&s)),
            Some(Err("drives not enabled"))
        );
        let s = Status {
            fault: Some(Fault::Drive),
            ..running(10, D_RAD)
        };
        assert_eq!(
            checker(Scenario::Track, &img).observe(&on(&s)),
            Some(Err("unexpected fault"))
        );
        let end = MIN_TRACK_TICKS.max(3_000 + SETTLE_TICKS);
        for (bad, why) in [
            (
                Status {
                    overruns: 1,
                    ..running(end, D_RAD)
                },
                "deadline overrun",
            ),
            (
                Status {
                    worst_step_us: 501.0,
                    ..running(end, D_RAD)
                },
                "step longer than the deadline",
            ),
            (
                Status {
                    setpoint_underruns: 1,
                    ..running(end, D_RAD)
                },
                "setpoint queue ran empty",
            ),
            (
                Status {
                    max_following_error_rad: 3e-4,
                    ..running(end, D_RAD)
                },
                "following error above bound",
            ),
            (
                Status {
                    encoder_rad: [0.81, -0.75],
                    ..running(end, D_RAD)
                },
                "settled tool error above bound",
            ),
        ] {
            let mut c = checker(Scenario::Track, &img);
            for ticks in 1..end {
                assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
            }
            assert_eq!(c.observe(&on(&bad)), Some(Err(why)));
        }
    }

    #[test]
    fn stalled_task_stalls_at_top_speed_and_the_machine_must_run_until_then() {
        let (i, at) = (&INJECTION, INJECTION.top_speed_sample);
        let stalls: Vec<u32> = (0..5_000)
            .filter(|&k| Scenario::StalledTask.stall_at(i, k))
            .collect();
        assert_eq!(stalls, [at]);
        for s in [Scenario::Run, Scenario::Overrun, Scenario::WatchdogRestart] {
            assert!(!s.stall_at(i, at));
        }
        let img = image(D_RAD);
        let mut c = checker(Scenario::StalledTask, &img);
        // Status ticks count the samples done: sample `at` (the stall) would be tick at + 1.
        for ticks in 1..=at {
            assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None, "tick {ticks}");
        }
        assert_eq!(
            c.observe(&on(&running(at + 1, D_RAD))),
            Some(Err("the servo task completed a sample after the stall"))
        );
        // Before the stall the machine must run.
        let s = running(5, D_RAD);
        assert_eq!(
            checker(Scenario::StalledTask, &img).observe(&off(&s)),
            Some(Err("drives not enabled before the stall"))
        );
        let s = Status {
            fault: Some(Fault::Drive),
            ..running(5, D_RAD)
        };
        assert_eq!(
            checker(Scenario::StalledTask, &img).observe(&on(&s)),
            Some(Err("fault before the stall"))
        );
        let s = running(5, D_RAD);
        let mut outside = on(&s);
        outside.plant.joint_rad = FiveBar::<f32>::paper_nominal()
            .inverse([200.0, 100.0], 0.05)
            .unwrap();
        assert_eq!(
            checker(Scenario::StalledTask, &img).observe(&outside),
            Some(Err(
                "the tool left the calibrated rectangle before the stall"
            ))
        );
    }

    fn fired(o: WatchdogObservation) -> WatchdogVerdict {
        Scenario::StalledTask.watchdog_fired(&o)
    }

    #[test]
    fn a_watchdog_interrupt_passes_only_if_it_removed_torque_within_the_timeout_of_the_stall() {
        // Fed at t = 1000 µs, stalled 40 µs later, fired exactly the timeout after the feed.
        let good = WatchdogObservation {
            stalled_at_us: Some(1_040.0),
            last_feed_at_us: Some(1_000.0),
            fired_at_us: 1_000.0 + TIMEOUT_US,
            drive_enable_at_fire: true,
            drive_enable: false,
            drive_torque_nm: [0.0; 2],
        };
        assert_eq!(fired(good), WatchdogVerdict::AsExpected);
        for (bad, why) in [
            (
                WatchdogObservation {
                    stalled_at_us: None,
                    ..good
                },
                "watchdog fired before the servo task was stalled",
            ),
            (
                WatchdogObservation {
                    last_feed_at_us: None,
                    ..good
                },
                "the watchdog was never fed",
            ),
            (
                WatchdogObservation {
                    drive_enable_at_fire: false,
                    ..good
                },
                "drives already off when the watchdog fired: the test proves nothing",
            ),
            (
                WatchdogObservation {
                    drive_enable: true,
                    ..good
                },
                "drive enable still on after the watchdog fired",
            ),
            (
                WatchdogObservation {
                    drive_torque_nm: [0.0, 0.1],
                    ..good
                },
                "torque commanded after the watchdog fired",
            ),
            // Fed long before the stall: the watchdog's timeout is right but torque came off late.
            (
                WatchdogObservation {
                    stalled_at_us: Some(900.0),
                    last_feed_at_us: Some(0.0),
                    fired_at_us: 4_000.0,
                    ..good
                },
                "torque not removed within the watchdog timeout of the stall",
            ),
            (
                WatchdogObservation {
                    fired_at_us: 1_000.0 + TIMEOUT_US + 200.0,
                    stalled_at_us: Some(1_300.0),
                    ..good
                },
                "the watchdog did not fire its stated timeout after the last feed",
            ),
            (
                WatchdogObservation {
                    fired_at_us: 1_000.0 + 0.5 * TIMEOUT_US,
                    ..good
                },
                "the watchdog did not fire its stated timeout after the last feed",
            ),
            (
                WatchdogObservation {
                    fired_at_us: f32::NAN,
                    ..good
                },
                "torque not removed within the watchdog timeout of the stall",
            ),
        ] {
            assert_eq!(fired(bad), WatchdogVerdict::Fail(why), "{bad:?}");
        }
        // The production path: torque off, wait for the reset. Any other test: a failure.
        assert_eq!(
            Scenario::Run.watchdog_fired(&good),
            WatchdogVerdict::Production
        );
        for s in [
            Scenario::Track,
            Scenario::LongRun,
            Scenario::Overrun,
            Scenario::WatchdogRestart,
        ] {
            assert_eq!(
                s.watchdog_fired(&good),
                WatchdogVerdict::Fail("watchdog fired: the servo task did not complete on time")
            );
        }
    }

    #[test]
    fn the_boot_after_the_stall_must_keep_the_drives_off_and_the_machine_coast_as_category_zero() {
        assert_eq!(
            Scenario::StalledTask.after_reset(ResetCause::Watchdog),
            Scenario::WatchdogRestart
        );
        assert_eq!(
            Scenario::StalledTask.after_reset(ResetCause::PowerOnOrBrownOut),
            Scenario::StalledTask
        );
        assert_eq!(
            Scenario::Track.after_reset(ResetCause::Watchdog),
            Scenario::Track
        );
        let restarted = |ticks, fault| Status {
            fault: Some(fault),
            torque_nm: [0.0; 2],
            drives_enabled: false,
            ..running(ticks, D_RAD)
        };
        fn never(s: &Status) -> Observation<'_> {
            Observation {
                drive_enable_ever: false,
                ..off(s)
            }
        }
        let img = image(D_RAD);
        let reset = Fault::Watchdog(WatchdogFault::Reset);
        // The machine at the watchdog's interrupt: where `running` has it, at rest.
        let kept = plant_of(&running(1, D_RAD));
        let restart = || {
            let mut c = checker(Scenario::WatchdogRestart, &img);
            c.coast_after_reset(kept);
            c
        };
        let mut c = restart();
        for ticks in 1..=BAD_IMAGE_TICKS {
            assert_eq!(
                c.observe(&never(&restarted(ticks, reset))),
                None,
                "tick {ticks}"
            );
        }
        // Passes once both the boot's 0.5 s and the coast's 1000 samples are over.
        assert_eq!(
            c.observe(&never(&restarted(BAD_IMAGE_TICKS + 1, reset))),
            Some(Ok(()))
        );
        assert_eq!(c.fault_sample(), Some(0));
        assert_eq!(
            restart().observe(&never(&restarted(
                BAD_IMAGE_TICKS + 1,
                Fault::DeadlineMissed
            ))),
            Some(Err("watchdog reset not reported as the fault"))
        );
        assert_eq!(
            restart().observe(&off(&restarted(3, reset))),
            Some(Err("drives enabled at a boot that must keep them off"))
        );
        // The machine's state did not survive the reset: nothing to check the coast against.
        assert_eq!(
            checker(Scenario::WatchdogRestart, &img).observe(&never(&restarted(3, reset))),
            Some(Err("the machine's state at the watchdog's interrupt did not reach the boot after the reset"))
        );
        // A coast from rest that moves 0.01 rad: beyond the bound (0 rad plus round-off).
        let s = restarted(3, reset);
        let mut moved = never(&s);
        moved.plant.joint_rad[0] += 0.01;
        assert_eq!(
            restart().observe(&moved),
            Some(Err(
                "a joint coasted further than the dynamic-braking bound"
            ))
        );
        // Kept at speed, the bound is the dynamic-braking one from that speed: 1 rad/s on joint 1
        // is 9.4 mrad; 5 mrad passes, 12 mrad fails.
        let fast = PlantState {
            joint_rad_s: [1.0, 0.0],
            ..kept
        };
        for (travel, verdict) in [
            (5e-3, None),
            (
                12e-3,
                Some(Err(
                    "a joint coasted further than the dynamic-braking bound",
                )),
            ),
        ] {
            let mut c = checker(Scenario::WatchdogRestart, &img);
            c.coast_after_reset(fast);
            let mut o = never(&s);
            o.plant.joint_rad[0] += travel;
            assert_eq!(c.observe(&o), verdict, "{travel}");
            let r = c.stop_report().unwrap();
            assert!(
                (r.coast_bound_rad[0] - 2.2e-3 / 0.235).abs() < 1e-6,
                "{r:?}"
            );
        }
    }

    /// A running status for `track-5g`: the setpoint oscillates ±5 mm in x at 101 rad/s (5.2 g
    /// at the turning points) until sample 3000, then rests at `P_MM`; while it moves the
    /// encoders lag the reference by `lag_rad` on axis 1.
    fn oscillating(ticks: u32, lag_rad: f32) -> Status {
        let t = ticks.saturating_sub(1) as f32 * crate::SAMPLE_PERIOD_S;
        let x = if ticks < 3_000 {
            P_MM[0] + 5.0 * libm::sinf(101.0 * t)
        } else {
            P_MM[0]
        };
        let p = [x, P_MM[1]];
        let ik = FiveBar::<f32>::paper_nominal().inverse(p, 0.05).unwrap();
        let reference = [ik[0] + D_RAD[0], ik[1] + D_RAD[1]];
        Status {
            setpoint_mm: p,
            reference_rad: reference,
            encoder_rad: [
                reference[0] - if ticks < 3_000 { lag_rad } else { 0.0 },
                reference[1],
            ],
            ..running(ticks, D_RAD)
        }
    }

    fn run_track_5g(lag_rad: f32, oscillate: bool) -> (Verdict, MotionCheck) {
        let img = image(D_RAD);
        let mut c = checker(Scenario::Track5g, &img);
        for ticks in 1..MAX_TICKS {
            let s = if oscillate {
                oscillating(ticks, lag_rad)
            } else {
                running(ticks, D_RAD)
            };
            if let Some(v) = c.observe(&on(&s)) {
                return (Some(v), c.motion_check());
            }
        }
        (None, c.motion_check())
    }

    #[test]
    fn track_5g_needs_5g_moves_and_a_small_following_error_at_the_tool() {
        let (v, m) = run_track_5g(0.0, true);
        assert_eq!(v, Some(Ok(())), "{m:?}");
        assert!(
            m.samples_at_5g >= MIN_SAMPLES_AT_5G && m.max_following_error_um < 1e-3,
            "{m:?}"
        );
        // 1e-4 rad on motor 1 is about 15 µm at the tool: above the bound.
        let (v, m) = run_track_5g(1.0e-4, true);
        assert_eq!(
            v,
            Some(Err("following error at the tool above the 5 g bound")),
            "{m:?}"
        );
        assert!(m.max_following_error_um > MAX_FOLLOWING_ERROR_5G_UM);
        // 2e-5 rad: a few µm, within.
        let (v, m) = run_track_5g(2.0e-5, true);
        assert_eq!(v, Some(Ok(())), "{m:?}");
        assert!(m.max_following_error_um > 1.0, "{m:?}");
        // Standing still: no 5 g at all.
        let (v, _) = run_track_5g(0.0, false);
        assert_eq!(v, Some(Err("too few samples at 5 g")));
        let g5 = 5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
        assert_eq!(
            Scenario::Track5g.trajectory((Profile::Quintic, 1.0)),
            (Profile::JerkLimited, g5)
        );
        assert_eq!(
            Scenario::Track.trajectory((Profile::Quintic, 1.0)),
            (Profile::Quintic, 1.0)
        );
    }

    #[test]
    fn self_tests_that_return_fail() {
        let img = image(D_RAD);
        for s in [Scenario::Panic, Scenario::HardFault] {
            assert!(matches!(
                checker(s, &img).observe(&on(&running(1, D_RAD))),
                Some(Err(_))
            ));
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
