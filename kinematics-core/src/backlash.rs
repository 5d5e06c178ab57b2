//! Backlash compensation in the servo: the continuous inverse of the play operator, applied to
//! the joint reference.
//!
//! # The model and its convention
//! Motor j reaches its link through a lost motion (gap) of β_j. The encoder sits on the motor;
//! the link follows it as a play operator of half-width β_j/2: a motor that last moved in +θ
//! (dir = +1) drags the link β_j/2 behind it, `link = encoder − dir·β_j/2` (the host's
//! convention, `host-sim/src/calib/backlash.rs`, and the plant's `drive.rs`). To put the link
//! at the reference `r`, the motor must be at `r + dir·β_j/2`.
//!
//! # The algorithm
//! The exact inverse of a play operator steps the motor by β_j whenever the reference reverses:
//! a jump no drive may be asked for. The servo uses its continuous form instead, the play
//! operator of the reference itself: the correction `c_j` moves with the reference's own
//! increments and saturates at ±β_j/2,
//!
//! ```text
//! c ← clamp(c + (r_k − r_{k−1}), −β/2, +β/2),      motor reference = r_k + c
//! ```
//!
//! Moving steadily in +θ, `c` sits at +β/2 (the motor leads the link by the half gap: the
//! link lands at `r`). When the reference reverses, `c` runs down with it: the motor moves at
//! twice the reference's rate and crosses the gap while the link stays; after the reference
//! has come back by β/2 the gap is crossed, `c = −β/2`, and the link follows again. So the
//! motor reference is continuous (never a step of β), its rate is at most twice the
//! reference's, and at rest after any move longer than β/2 the link is where the reference
//! is. During a reversal the link lags the reference by at most β/2, as it would without the
//! compensation, but only for the reference's first β/2 of travel instead of for ever.
//!
//! # The initial state
//! At boot, engage and homing the direction the motors came from is unknown: `c = 0`, the
//! mid-gap (what `Servo::engage` sets). The cost: the
//! first β/2 of reference travel of each joint crosses whatever part of the gap is really
//! there, so during it the link may lead or lag the reference by up to β/2 (no more than
//! without compensation), and a first move shorter than β/2 in a joint may end up to β/2 off
//! in that joint (10 µrad on the `paper` plant, ~1.5 µm at the tool). A first move of β/2 or
//! more takes the gap up whichever side it was on, so its target is already exact.
//!
//! # Cost and error
//! Per axis: one subtraction, one addition, two comparisons, one addition (`BENCH
//! servo_step_backlash` against `servo_step`). Numerically it is a clamp of sums: the state
//! stays within ±β/2 exactly; in f32 the correction carries the rounding of the reference's
//! increments (relative 6e-8 per sample on a few-radian reference, under 1 nrad over a move),
//! and it is the same routine on MCU and host, generic over [`Real`].

use crate::real::Real;

/// Largest lost motion accepted (rad): more is not a backlash but a broken drive.
pub const MAX_BACKLASH_RAD: f64 = 0.01;

/// Why a backlash was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InvalidBacklash {
    /// The motor (0 or 1) whose lost motion is not finite or outside `0..=MAX_BACKLASH_RAD`.
    pub axis: u8,
}

impl core::fmt::Display for InvalidBacklash {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "backlash of motor {} is not a lost motion in [0, {MAX_BACKLASH_RAD}] rad",
            self.axis + 1
        )
    }
}

impl core::error::Error for InvalidBacklash {}

/// The lost motion of both motors, validated: finite and in `0..=MAX_BACKLASH_RAD`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Backlash<T> {
    /// `β_j / 2` (rad): where the correction saturates.
    half_gap_rad: [T; 2],
}

impl<T: Real> Backlash<T> {
    /// The lost motion `beta_rad` (β_j, the whole gap, rad) if every value is finite and in
    /// `0..=MAX_BACKLASH_RAD`.
    pub fn new(beta_rad: [T; 2]) -> Result<Self, InvalidBacklash> {
        for (axis, b) in beta_rad.iter().enumerate() {
            if !(b.is_finite() && *b >= T::ZERO && *b <= T::from_f64(MAX_BACKLASH_RAD)) {
                return Err(InvalidBacklash { axis: axis as u8 });
            }
        }
        Ok(Backlash {
            half_gap_rad: [beta_rad[0] * T::HALF, beta_rad[1] * T::HALF],
        })
    }

    /// The whole gap β_j of each motor (rad).
    pub fn beta_rad(&self) -> [T; 2] {
        [self.half_gap_rad[0] * T::TWO, self.half_gap_rad[1] * T::TWO]
    }

    /// `β_j / 2` of each motor (rad).
    pub fn half_gap_rad(&self) -> [T; 2] {
        self.half_gap_rad
    }

    /// The next correction of both axes from the last one and the reference's increments: the
    /// play operator of the reference (module doc). `correction_rad` must be within ±β/2 (as
    /// every output is, and 0 is).
    #[inline(always)]
    pub fn next_correction_rad(&self, correction_rad: [T; 2], increment_rad: [T; 2]) -> [T; 2] {
        [0, 1].map(|k| {
            let h = self.half_gap_rad[k];
            let c = correction_rad[k] + increment_rad[k];
            // Comparisons, not `clamp` (which checks its bounds at run time); NaN passes
            // through, and the servo's following-error check refuses it.
            let c = if c > h { h } else { c };
            if c < -h {
                -h
            } else {
                c
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The compensation as a stand-alone filter for these tests: the reference in, the motor
    /// reference out, the last reference and the correction kept, as the servo keeps them in
    /// its history around [`Backlash::next_correction_rad`].
    #[derive(Clone, Copy, Debug, PartialEq)]
    struct BacklashCompensator<T> {
        backlash: Backlash<T>,
        /// The last reference, `None` before the first (or after [`Self::reset`]).
        last_reference_rad: Option<[T; 2]>,
        correction_rad: [T; 2],
    }

    impl<T: Real> BacklashCompensator<T> {
        /// A compensator at the mid-gap (direction unknown).
        fn new(backlash: Backlash<T>) -> Self {
            BacklashCompensator {
                backlash,
                last_reference_rad: None,
                correction_rad: [T::ZERO; 2],
            }
        }

        /// Back to the mid-gap, the next reference taken as the start (boot, engage, homing).
        fn reset(&mut self) {
            self.last_reference_rad = None;
            self.correction_rad = [T::ZERO; 2];
        }

        /// The current correction (rad, within ±β/2).
        fn correction_rad(&self) -> [T; 2] {
            self.correction_rad
        }

        /// The motor reference for the link reference `reference_rad`.
        fn motor_reference_rad(&mut self, reference_rad: [T; 2]) -> [T; 2] {
            let last = self.last_reference_rad.unwrap_or(reference_rad);
            let increment = [reference_rad[0] - last[0], reference_rad[1] - last[1]];
            self.correction_rad = self
                .backlash
                .next_correction_rad(self.correction_rad, increment);
            self.last_reference_rad = Some(reference_rad);
            [
                reference_rad[0] + self.correction_rad[0],
                reference_rad[1] + self.correction_rad[1],
            ]
        }
    }

    /// The plant's play operator (`host-sim` `drive.rs`): the link follows the motor once the
    /// gap is taken up.
    fn play(link: f64, motor: f64, half: f64) -> f64 {
        if motor - link > half {
            motor - half
        } else if motor - link < -half {
            motor + half
        } else {
            link
        }
    }

    #[test]
    fn validates_the_gap() {
        assert!(Backlash::new([0.0f32, 0.01]).is_ok());
        assert_eq!(
            Backlash::new([-1e-6f64, 0.0]),
            Err(InvalidBacklash { axis: 0 })
        );
        assert_eq!(
            Backlash::new([0.0f64, 0.0101]),
            Err(InvalidBacklash { axis: 1 })
        );
        assert_eq!(
            Backlash::new([f32::NAN, 0.0]),
            Err(InvalidBacklash { axis: 0 })
        );
        assert_eq!(
            Backlash::new([0.0, f64::INFINITY]),
            Err(InvalidBacklash { axis: 1 })
        );
        let b = Backlash::new([20e-6f64, 40e-6]).unwrap();
        assert_eq!(b.beta_rad(), [20e-6, 40e-6]);
        assert_eq!(b.half_gap_rad(), [10e-6, 20e-6]);
    }

    /// Through the plant's play, the link lands on every target reached from either side, and
    /// the motor reference never steps by more than twice the reference's step.
    #[test]
    fn link_lands_on_targets_from_both_sides_without_steps() {
        let beta = 20e-6;
        let mut comp = BacklashCompensator::new(Backlash::new([beta, beta]).unwrap());
        let (mut link, mut last_motor) = (0.0f64, 0.0f64);
        let targets = [1e-3, 0.4e-3, 0.9e-3, -0.2e-3, -0.1e-3, 0.3e-3];
        let step = 1e-6;
        let mut r = 0.0f64;
        for &t in &targets {
            while (t - r).abs() > step / 2.0 {
                r += step * (t - r).signum();
                let m = comp.motor_reference_rad([r, r])[0];
                assert!(
                    (m - last_motor).abs() <= 2.0 * step + 1e-15,
                    "motor step {}",
                    m - last_motor
                );
                last_motor = m;
                link = play(link, m, beta / 2.0);
            }
            assert!((link - t).abs() < 1e-12, "target {t}: link {link}");
        }
    }

    /// Without the compensation the same moves leave the link β/2 short, alternating.
    #[test]
    fn without_compensation_the_link_misses_by_half_the_gap() {
        let half = 10e-6;
        let mut link = 0.0f64;
        for (t, dir) in [(1e-3, 1.0), (0.5e-3, -1.0)] {
            link = play(link, t, half);
            assert!((link - (t - dir * half)).abs() < 1e-15);
        }
    }

    #[test]
    fn starts_at_mid_gap_and_resets() {
        let mut comp = BacklashCompensator::new(Backlash::new([20e-6f32, 0.0]).unwrap());
        assert_eq!(comp.motor_reference_rad([1.0, 2.0]), [1.0, 2.0]);
        comp.motor_reference_rad([1.001, 1.999]);
        assert_eq!(comp.correction_rad(), [10e-6, 0.0]);
        comp.reset();
        assert_eq!(comp.correction_rad(), [0.0, 0.0]);
        assert_eq!(comp.motor_reference_rad([0.5, 0.5]), [0.5, 0.5]);
    }

    #[test]
    fn zero_gap_is_the_identity_and_nan_passes_through() {
        let b = Backlash::new([0.0f32; 2]).unwrap();
        assert_eq!(b.next_correction_rad([0.0; 2], [1.0, -1.0]), [0.0, 0.0]);
        let b = Backlash::new([1e-3f32; 2]).unwrap();
        assert!(b.next_correction_rad([0.0; 2], [f32::NAN, 0.0])[0].is_nan());
    }
}
