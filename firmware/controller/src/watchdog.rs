//! The independent watchdog: when it is fed, how long it waits, and what a watchdog reset means
//! at the next boot.
//!
//! Both boards run a hardware watchdog clocked independently of the core (STM32G474: the IWDG
//! on the LSI oscillator; QEMU: the MPS2's CMSDK APB watchdog). The servo task feeds it **only
//! when its step completed on time** ([`step_on_time`], decided in
//! [`ServoLoop::record_deadline`](crate::servo_loop::ServoLoop::record_deadline)), never from
//! idle or a timer of its own: a servo interrupt that stops (timer dead, interrupts masked by a
//! stuck critical section, a task spinning at a higher priority) or steps that keep missing
//! their deadline let it expire. It keeps being fed in the safe state: a latched fault with the
//! drives off is not a stall, and the reset would only lose the report.
//!
//! **Timeout: [`TIMEOUT_US`] = 3 ms** (six servo periods), on both boards. Why:
//! * long enough that the software acts first on what it can see: an overrun streak latches
//!   `Fault::DeadlineMissed` after `overrun_streak_limit` (3) late steps, and the first on-time
//!   step after it feeds again, [`MIN_TIMEOUT_US`] = (3 + 1) periods after the last feed; the
//!   G474's IWDG runs on an RC oscillator up to 6 % fast, so its shortest timeout is 2.82 ms;
//! * short enough that a stalled controller removes torque quickly: the last torque written
//!   stays on the motors for at most the timeout (G474 IWDG up to 3.25 ms with a slow LSI).
//!
//! What expiry does: the G474 resets (every pin goes to its reset state; the drive-enable line's
//! external pull-down disables the amplifiers; see the bring-up guide); the QEMU board's
//! watchdog raises an NMI whose handler removes torque, and resets the machine at its second
//! expiry. **After a watchdog reset the drives stay disabled** ([`Fault::after_reset`](crate::fault::Fault::after_reset)): a
//! controller that stalled once is not trusted to engage again by itself; a power cycle or the
//! reset button (a deliberate act) clears it.

use crate::deadline::DEADLINE_US;

/// The watchdog timeout both boards implement (µs): 3 ms.
pub const TIMEOUT_US: f32 = 3_000.0;

/// The timeout must exceed this (µs): the default overrun streak (3 late steps) plus the
/// on-time step after it, so that the software's own deadline fault acts before the watchdog.
pub const MIN_TIMEOUT_US: f32 = 4.0 * DEADLINE_US;

/// Whether the servo step that just ended feeds the watchdog: it finished before the next tick
/// came (`overrun` false) and within the deadline (`step_us` from its tick; NaN refuses).
#[inline]
pub fn step_on_time(step_us: f32, overrun: bool) -> bool {
    !overrun && step_us < DEADLINE_US
}

/// Why the controller last reset, as the board's reset flags tell it (read once at boot, then
/// cleared).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-on or brown-out (the supply dipped below the brown-out level).
    PowerOnOrBrownOut,
    /// The reset pin (the board's reset button, or a debug probe pulling NRST).
    Pin,
    /// A software reset (the firmware, or a debug probe after flashing).
    Software,
    /// The independent (or window) watchdog expired.
    Watchdog,
    /// An illegal entry into a low-power mode.
    LowPower,
    /// An option-byte reload.
    OptionByteLoad,
    /// No flag set (or the board cannot tell).
    Unknown,
}

/// Faults of the watchdog itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WatchdogFault {
    /// The last reset was the watchdog's: the drives stay disabled until a power cycle or a
    /// reset by the operator.
    Reset,
    /// The watchdog could not be started (its registers did not update in time): without it
    /// a stalled controller would keep the drives on, so they stay disabled.
    NotStarted,
}

impl core::fmt::Display for WatchdogFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            WatchdogFault::Reset => {
                "reset by the watchdog (the servo task stalled); power-cycle or press reset"
            }
            WatchdogFault::NotStarted => "the watchdog could not be started",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::Settings;

    #[test]
    fn only_a_step_that_finished_before_the_next_tick_feeds() {
        assert!(step_on_time(15.0, false));
        assert!(step_on_time(499.0, false));
        assert!(!step_on_time(15.0, true), "the next tick already came");
        assert!(!step_on_time(700.0, true));
        assert!(!step_on_time(500.0, false), "at the deadline is late");
        assert!(
            !step_on_time(f32::NAN, false),
            "a step time that cannot be read does not feed"
        );
        assert!(!step_on_time(f32::INFINITY, false));
    }

    /// The timeout is long enough for the default overrun streak to be handled by the software
    /// first, even on a G474 whose LSI runs 6 % fast (the IWDG's shortest timeout), and short
    /// enough that the last torque stays at most 3.5 ms with a slow LSI.
    #[test]
    fn the_timeout_leaves_the_overrun_streak_to_the_software() {
        let streak_us = (Settings::default().overrun_streak_limit + 1) as f32 * DEADLINE_US;
        assert_eq!(streak_us, MIN_TIMEOUT_US);
        let (lsi_fast, lsi_slow) = (34.0 / 32.0, 29.5 / 32.0);
        assert!(
            TIMEOUT_US / lsi_fast > MIN_TIMEOUT_US + 0.5 * DEADLINE_US,
            "{}",
            TIMEOUT_US / lsi_fast
        );
        assert!(TIMEOUT_US / lsi_slow < 3_500.0, "{}", TIMEOUT_US / lsi_slow);
    }
}
