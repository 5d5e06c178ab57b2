//! Why the machine stops, and how: the latched fault and its stop category.
//!
//! Stop categories as IEC 60204-1 (9.2.2) defines them and IEC 61800-5-2 names the drive
//! functions:
//!
//! | fault | category | what the machine does |
//! |---|---|---|
//! | non-finite setpoint | 1 (SS1) | brakes along its path at 5 g (jerk-limited), then torque off once at standstill |
//! | unreachable / near-singular / outside-grid setpoint, setpoint jump | 2 (SS2) | brakes along its path, then holds the stop point (drives on) |
//! | a setpoint whose stop would leave the workspace | 2 | the same, from the previous setpoint |
//! | setpoint queue empty while moving | 2 | the same |
//! | encoder: non-finite, speed or acceleration beyond the mechanism's, stuck | 0 (STO) | torque off in the sample that found it |
//! | following error beyond the limit, non-finite encoder in the servo | 0 | torque off at once |
//! | deadline overrun streak, PWM write error, drive outputs off (safe-torque-off input) | 0 | torque off at once |
//! | servo task stalled: the independent watchdog expires ([`crate::watchdog`]) | 0 | torque off by the watchdog (QEMU: its NMI; STM32G474: the reset, the enable line pulled low), then a reset |
//! | the controlled stop's own setpoint refused | 0 | torque off at once (a fallback the workspace check makes unreachable) |
//! | host link: `Stop` command | 2 | brakes along its path, then holds (not a failure; latched so that only a reset or an enable moves it again) |
//! | host link: `Disable` command | 1 | brakes along its path, then torque off |
//! | bad calibration image, settings refused, engage refused, the last reset was the watchdog's, watchdog not started | (boot) | drives never enabled |
//!
//! Why these categories: a fault of the setpoint stream leaves the feedback, the servo and the
//! drives trustworthy, so they brake the machine along its path, which removing torque would
//! leave to the drives' dynamic braking, off the path (at the built-in tour's 1.38 m/s the QEMU
//! plant then coasts 40 mm; with free-wheeling drives it leaves the workspace). A **finite** refused setpoint (a place the machine should not go, a
//! sequence it cannot follow, a stream that ran dry) is something a host can re-plan from:
//! the machine holds where it stopped (category 2), so resuming needs no re-homing. A
//! **non-finite** setpoint means its producer is broken (corrupt data, a computation gone
//! wrong), not merely out of bounds: the machine is stopped, then de-energised (category 1),
//! and only a deliberate re-engage (a reset) brings it back. A fault of the feedback or of the
//! controller itself means the servo can no longer brake the machine (it would brake towards
//! a position it does not know, or too late): torque off at once (category 0). What stops the
//! machine then is the drives' dynamic braking, a hardware requirement (firmware/README.md,
//! "Category 0 needs dynamic braking in the drives"): the firmware cannot brake, hold or steer
//! a machine after a category-0 fault.
//!
//! Only a reset clears a latched fault: a reboot, or the host link's `ResetFault` / `Enable`
//! ([`ServoLoop::request`](crate::servo_loop::ServoLoop::request): re-engages where the machine is; what a reset clears in each mode is the table of [`crate::servo_loop::requests`]). The mode machine is in [`crate::servo_loop`], the stop
//! profile in [`crate::stop`], the encoder checks in [`crate::encoder_check`].
use kinematics_core::{EngageError, ServoFault, SetpointRefusal};

use crate::calibration::ImageError;
use crate::encoder_check::EncoderFault;
use crate::homing::HomingFault;
use crate::settings::SettingsError;
use crate::watchdog::{ResetCause, WatchdogFault};

/// How the machine is brought to rest (IEC 60204-1 stop categories).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StopCategory {
    /// Category 0: torque removed at once (safe torque off); the machine coasts, braked by the
    /// drives' dynamic braking (a hardware requirement).
    Zero,
    /// Category 1: a controlled stop, then torque removed at standstill (SS1).
    One,
    /// Category 2: a controlled stop, then the position held with the drives on (SS2).
    Two,
}

/// Why the machine stopped. Latched: only a reset clears it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fault {
    /// The servo refused a setpoint of the stream: non-finite (category 1), unreachable, near a
    /// singularity, outside the grid, a jump beyond 5 g (category 2).
    Setpoint(SetpointRefusal),
    /// The stop from this setpoint would end outside the calibrated rectangle (category 2): the
    /// stream heads for the edge faster than the machine could stop before it.
    StopOutsideWorkspace,
    /// The setpoint queue ran empty while the machine was moving (category 2).
    Underrun,
    /// A fault of the servo's feedback: non-finite encoder reading, following error beyond the
    /// limit (category 0).
    Servo(ServoFault),
    /// An encoder reading the mechanism cannot produce, or an encoder that does not move under
    /// torque (category 0).
    Encoder(EncoderFault),
    /// The controlled stop's own setpoint was refused (category 0).
    StopRefused(SetpointRefusal),
    /// `overrun_streak_limit` consecutive samples missed their 500 µs deadline (category 0).
    DeadlineMissed,
    /// Writing a PWM duty failed, or the drive outputs are off while they should be on (on
    /// the STM32G474: TIM1's break input, the external safe-torque-off, cleared its main
    /// output enable). Category 0.
    Drive,
    /// The host link commanded a stop (category 2: controlled stop, then hold). Not a failure;
    /// latched like one so that the machine moves again only after a reset or an enable.
    StopCommanded,
    /// The host link commanded the drives off (category 1: controlled stop, then torque off).
    DisableCommanded,
    /// Homing failed ([`HomingFault`]): the index not found within the travel or a reference
    /// refused (category 1: the search has ended at rest, torque off), a following error while
    /// homing or the homing plan refused (category 0).
    Homing(HomingFault),
    /// The calibration image was refused at boot (drives never enabled).
    Calibration(ImageError),
    /// The settings were refused at boot (drives never enabled).
    Settings(SettingsError),
    /// The servo could not engage at the encoder reading at boot (drives never enabled).
    Engage(EngageError),
    /// The independent watchdog reset the controller (the servo task stalled: the watchdog
    /// removed torque at once, category 0), or could not be started; at boot, so the drives
    /// are never enabled. See [`crate::watchdog`].
    Watchdog(WatchdogFault),
}

impl Fault {
    /// How the machine reacts (see the module's table). Boot faults are category 0: the drives
    /// were never enabled.
    pub fn stop_category(&self) -> StopCategory {
        match self {
            Fault::Setpoint(SetpointRefusal::NonFinite) => StopCategory::One,
            Fault::Setpoint(_)
            | Fault::StopOutsideWorkspace
            | Fault::Underrun
            | Fault::StopCommanded => StopCategory::Two,
            Fault::DisableCommanded => StopCategory::One,
            Fault::Homing(HomingFault::IndexNotFound(_) | HomingFault::Reference) => {
                StopCategory::One
            }
            Fault::Homing(HomingFault::FollowingError(_) | HomingFault::Plan) => StopCategory::Zero,
            Fault::Servo(_)
            | Fault::Encoder(_)
            | Fault::StopRefused(_)
            | Fault::DeadlineMissed
            | Fault::Drive
            | Fault::Calibration(_)
            | Fault::Settings(_)
            | Fault::Engage(_)
            | Fault::Watchdog(_) => StopCategory::Zero,
        }
    }

    /// The fault a boot after `cause` starts with, if any: a watchdog reset keeps the drives
    /// off ([`crate::watchdog`]).
    pub fn after_reset(cause: ResetCause) -> Option<Fault> {
        match cause {
            ResetCause::Watchdog => Some(Fault::Watchdog(WatchdogFault::Reset)),
            ResetCause::PowerOnOrBrownOut
            | ResetCause::Pin
            | ResetCause::Software
            | ResetCause::LowPower
            | ResetCause::OptionByteLoad
            | ResetCause::Unknown => None,
        }
    }

    /// Faults only a reboot clears: settings or calibration refused at boot, and a watchdog
    /// that did not start (without it a stalled controller would keep the drives on). The
    /// servo loop refuses to reset them and the host link answers them as faulted.
    pub fn needs_reboot(&self) -> bool {
        matches!(
            self,
            Fault::Settings(_) | Fault::Calibration(_) | Fault::Watchdog(WatchdogFault::NotStarted)
        )
    }
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Fault::Setpoint(e) => write!(f, "setpoint: {e}"),
            Fault::StopOutsideWorkspace => {
                f.write_str("setpoint refused: its stop would leave the workspace")
            }
            Fault::Underrun => f.write_str("setpoint queue ran empty while moving"),
            Fault::Servo(e) => write!(f, "servo: {e}"),
            Fault::Encoder(e) => write!(f, "encoder: {e}"),
            Fault::StopRefused(e) => write!(f, "controlled stop refused ({e})"),
            Fault::DeadlineMissed => f.write_str("servo deadline missed repeatedly"),
            Fault::Drive => f.write_str("PWM write failed or drive outputs off (safe-torque-off)"),
            Fault::Homing(e) => write!(f, "homing: {e}"),
            Fault::Calibration(e) => write!(f, "calibration image refused: {e}"),
            Fault::Settings(e) => write!(f, "settings refused: {e}"),
            Fault::Engage(e) => write!(f, "{e}"),
            Fault::Watchdog(e) => write!(f, "watchdog: {e}"),
            Fault::StopCommanded => f.write_str("stop commanded by the host"),
            Fault::DisableCommanded => f.write_str("drives off commanded by the host"),
        }
    }
}

impl core::error::Error for Fault {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoder_check::EncoderFaultKind;
    use kinematics_core::{GridError, KinematicsError};

    #[test]
    fn categories_follow_the_table() {
        use StopCategory::*;
        for (fault, want) in [
            (Fault::Setpoint(SetpointRefusal::NonFinite), One),
            (Fault::Setpoint(SetpointRefusal::Jump), Two),
            (
                Fault::Setpoint(SetpointRefusal::Grid(GridError::OutsideGrid)),
                Two,
            ),
            (
                Fault::Setpoint(SetpointRefusal::Kinematics(KinematicsError::Unreachable)),
                Two,
            ),
            (Fault::StopOutsideWorkspace, Two),
            (Fault::Underrun, Two),
            (Fault::Servo(ServoFault::FollowingError), Zero),
            (
                Fault::Encoder(EncoderFault {
                    axis: 1,
                    kind: EncoderFaultKind::Stuck,
                }),
                Zero,
            ),
            (Fault::StopRefused(SetpointRefusal::Jump), Zero),
            (Fault::DeadlineMissed, Zero),
            (Fault::Drive, Zero),
            (Fault::StopCommanded, Two),
            (Fault::DisableCommanded, One),
            (Fault::Watchdog(WatchdogFault::Reset), Zero),
            (Fault::Watchdog(WatchdogFault::NotStarted), Zero),
        ] {
            assert_eq!(fault.stop_category(), want, "{fault}");
        }
    }

    #[test]
    fn only_a_watchdog_reset_keeps_the_drives_off_at_the_next_boot() {
        assert_eq!(
            Fault::after_reset(ResetCause::Watchdog),
            Some(Fault::Watchdog(WatchdogFault::Reset))
        );
        for cause in [
            ResetCause::PowerOnOrBrownOut,
            ResetCause::Pin,
            ResetCause::Software,
            ResetCause::LowPower,
            ResetCause::OptionByteLoad,
            ResetCause::Unknown,
        ] {
            assert_eq!(Fault::after_reset(cause), None, "{cause:?}");
        }
    }
}
