//! Why the drives are off: the latched fault.
//!
//! Any fault puts the machine in the safe state in the sample that found it (drive enable off,
//! zero torque; see [`crate::servo_loop`]); only a reset clears it. Stop categories and a
//! controlled stop (bring a moving machine to rest before removing torque) will grow here.
use kinematics_core::{GridError, ServoFault};

use crate::watchdog::WatchdogFault;

/// Why the drives are off. Latched: only a reset clears it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fault {
    /// The servo step refused a sample (non-finite value, unreachable or singular setpoint,
    /// outside the grid, a jump beyond 5 g, following error).
    Servo(ServoFault),
    /// `overrun_streak_limit` consecutive samples missed their 500 µs deadline.
    DeadlineMissed,
    /// Writing a PWM duty failed, or the drive outputs are off while they should be on (on
    /// the STM32G474: TIM1's break input, the external safe-torque-off, cleared its main
    /// output enable).
    Drive,
    /// The calibration image was refused at boot (drives never enabled).
    Calibration(GridError),
    /// The independent watchdog reset the controller, or could not be started (at boot;
    /// drives never enabled). See [`crate::watchdog`].
    Watchdog(WatchdogFault),
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Fault::Servo(e) => write!(f, "servo: {e}"),
            Fault::DeadlineMissed => f.write_str("servo deadline missed repeatedly"),
            Fault::Drive => f.write_str("PWM write failed or drive outputs off (safe-torque-off)"),
            Fault::Calibration(e) => write!(f, "calibration image refused: {e}"),
            Fault::Watchdog(e) => write!(f, "watchdog: {e}"),
        }
    }
}

impl core::error::Error for Fault {}
