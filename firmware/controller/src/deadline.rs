//! Deadline bookkeeping of the servo task.
//!
//! The step's deadline is the next tick ([`DEADLINE_US`]). The board measures how long after
//! its tick the step finished and whether the next tick already came; [`Deadline::record`]
//! counts the misses and reports a streak, which the servo loop latches as
//! [`Fault::DeadlineMissed`](crate::fault::Fault::DeadlineMissed).

/// The servo deadline (µs): the next tick.
pub const DEADLINE_US: f32 = 1.0e6 / crate::SAMPLE_RATE_HZ as f32;

/// Time since the tick that started a step (µs), from a timer that restarts every period:
/// `elapsed_us` since the current period began (read first), the period, and whether the next
/// tick is already pending (read after). A pending tick with less than half a period elapsed
/// means the counter restarted: the step ran past the next tick. A pending tick with more
/// elapsed came between the two reads. Steps longer than 1.5 periods read short (they are
/// overruns either way).
pub fn step_time_us(elapsed_us: f32, period_us: f32, next_tick_pending: bool) -> f32 {
    if next_tick_pending && elapsed_us < 0.5 * period_us {
        period_us + elapsed_us
    } else {
        elapsed_us
    }
}

/// Overrun counts and the worst step time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Deadline {
    /// Samples whose step did not finish before the next tick.
    pub overruns: u32,
    /// Consecutive overruns up to the last sample.
    pub streak: u32,
    /// Longest step (tick to torque written, µs).
    pub worst_step_us: f32,
}

impl Deadline {
    /// Records one sample that took `step_us` and did (`overrun`) or did not finish before the
    /// next tick; returns `true` when the overrun streak reaches `streak_limit`.
    pub fn record(&mut self, step_us: f32, overrun: bool, streak_limit: u32) -> bool {
        if step_us > self.worst_step_us {
            self.worst_step_us = step_us;
        }
        if overrun {
            self.overruns += 1;
            self.streak += 1;
        } else {
            self.streak = 0;
        }
        self.streak >= streak_limit
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_time_counts_past_the_next_tick() {
        assert_eq!(step_time_us(15.0, 500.0, false), 15.0);
        // The counter restarted 200 µs ago: 700 µs since the step's tick.
        assert_eq!(step_time_us(200.0, 500.0, true), 700.0);
        // The tick arrived between the two reads, at the period's end.
        assert_eq!(step_time_us(499.9, 500.0, true), 499.9);
    }

    #[test]
    fn deadline_is_the_next_tick() {
        assert_eq!(DEADLINE_US, 500.0);
    }

    #[test]
    fn a_streak_of_overruns_reaches_the_limit_and_a_good_sample_resets_it() {
        let mut d = Deadline::default();
        assert!(!d.record(10.0, true, 3));
        assert!(!d.record(12.0, true, 3));
        assert!(
            !d.record(8.0, false, 3),
            "an on-time sample ends the streak"
        );
        assert_eq!((d.overruns, d.streak), (2, 0));
        assert!(!d.record(600.0, true, 3));
        assert!(!d.record(700.0, true, 3));
        assert!(d.record(650.0, true, 3), "third in a row");
        assert!(
            d.record(650.0, true, 3),
            "and it stays reached while the streak lasts"
        );
        assert_eq!((d.overruns, d.streak), (6, 4));
        assert_eq!(d.worst_step_us, 700.0);
    }

    #[test]
    fn worst_step_keeps_the_maximum_and_ignores_nan() {
        let mut d = Deadline::default();
        for us in [3.0, 9.0, f32::NAN, 4.0] {
            d.record(us, false, 3);
        }
        assert_eq!(d.worst_step_us, 9.0);
        assert_eq!(d.overruns, 0);
    }
}
