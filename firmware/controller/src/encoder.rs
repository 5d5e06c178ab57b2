//! Quadrature encoders: counts to joint angle, per axis.
//!
//! embedded-hal 1.0 has no encoder trait, hence [`QuadratureEncoder`]. Each axis has its own
//! [`EncoderConfig`] in the settings (counts per motor revolution, counting direction, gear
//! ratio from motor to joint); [`EncoderScale`] is the validated conversion both boards read
//! their counters through.
//!
//! **The zero is not a setting.** At power-on the counters read 0 wherever the machine stands;
//! homing (a later issue: an index pulse, a hard stop or an absolute sensor at a known joint
//! angle) calls [`EncoderScale::set_reference`] to tie a counter reading to a joint angle.
//! Until then the joint angle is relative to the power-on position.
//!
//! **A wrong sign is positive feedback**: the servo pushes the joint the way that increases its
//! error until the following-error limit trips. The first-power-up direction test of the
//! bring-up guide (docs/guides/g474-bring-up.md) catches it at a low torque limit before anything
//! else runs; [`EncoderSign`] is what it corrects.
//!
//! Encoder plausibility (a reading that jumps further than the machine can move in one
//! sample, a counter that stopped) is [`crate::encoder_check`]; it reads the angles converted
//! here and takes the resolution from [`EncoderScale::rad_per_count`] (a coarse encoder's
//! quantisation must not read as a glitch or a stuck axis).

/// A quadrature encoder read through a hardware counter.
pub trait QuadratureEncoder {
    /// Position in counts, extended to 32 bits (no wrap within the machine's travel).
    fn position_counts(&mut self) -> i32;
}

/// Which way the counter counts when the joint turns positive (counter-clockwise seen from
/// above, the kinematics' convention).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncoderSign {
    /// The counter counts up when the joint angle increases.
    Normal,
    /// The counter counts down when the joint angle increases (encoder mounted the other way,
    /// channels A and B swapped, or a reversing gear stage).
    Reversed,
}

/// One axis's encoder, as fitted: the settings' part of the counts-to-angle conversion.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderConfig {
    /// Counts per motor revolution after quadrature decoding (4 × lines for a plain
    /// incremental encoder, the interpolated count for a sin/cos one).
    pub counts_per_rev: u32,
    /// Counting direction for a positive joint angle.
    pub sign: EncoderSign,
    /// Motor revolutions per joint revolution (a 50:1 reducer is 50.0; direct drive 1.0).
    /// The encoder sits on the motor.
    pub gear_ratio: f32,
}

impl EncoderConfig {
    /// A 2^22 counts/rev encoder on a direct-drive joint, counting up for positive angles (the
    /// QEMU board's simulated machine, and the default until the real encoders are known).
    pub const DIRECT_DRIVE_2_22: EncoderConfig = EncoderConfig {
        counts_per_rev: 1 << 22,
        sign: EncoderSign::Normal,
        gear_ratio: 1.0,
    };
}

/// Why an [`EncoderConfig`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncoderConfigError {
    /// `counts_per_rev` is 0.
    ZeroCountsPerRev,
    /// `gear_ratio` is not a finite number above zero (a negative ratio is not a way to
    /// reverse the sign: use [`EncoderSign::Reversed`]).
    GearRatio,
    /// One count would be so small an angle that f32 cannot represent the conversion (below
    /// 1e-12 rad), or so large that the machine could not be controlled (above 0.01 rad).
    Resolution,
}

impl core::fmt::Display for EncoderConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            EncoderConfigError::ZeroCountsPerRev => "encoder counts per revolution is 0",
            EncoderConfigError::GearRatio => "gear ratio is not a finite number above 0",
            EncoderConfigError::Resolution => {
                "one encoder count is not between 1e-12 and 0.01 rad of joint angle"
            }
        })
    }
}

impl core::error::Error for EncoderConfigError {}

/// Coarsest joint resolution accepted (rad per count): 0.01 rad is 1.5 mm at the tool.
const MAX_RAD_PER_COUNT: f32 = 0.01;
/// Finest joint resolution accepted (rad per count).
const MIN_RAD_PER_COUNT: f32 = 1.0e-12;

/// Counter reading to joint angle for one axis: the validated [`EncoderConfig`] and the zero
/// that homing sets.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderScale {
    /// Joint radians per count, signed by [`EncoderSign`].
    rad_per_count: f32,
    /// Counter reading at joint angle 0.
    zero_counts: i32,
}

impl EncoderScale {
    /// What an axis with a refused configuration reads: NaN, which the servo refuses at engage
    /// (`EngageError::NonFiniteFeedback`), so the drives stay disabled.
    pub const REFUSED: EncoderScale = EncoderScale {
        rad_per_count: f32::NAN,
        zero_counts: 0,
    };

    /// The scale for `config`, zero at counter reading 0 (the power-on position) until
    /// [`EncoderScale::set_reference`].
    pub fn new(config: &EncoderConfig) -> Result<Self, EncoderConfigError> {
        if config.counts_per_rev == 0 {
            return Err(EncoderConfigError::ZeroCountsPerRev);
        }
        // `!(x > 0)` also refuses NaN.
        if !(config.gear_ratio > 0.0) || !config.gear_ratio.is_finite() {
            return Err(EncoderConfigError::GearRatio);
        }
        let magnitude = core::f32::consts::TAU / (config.counts_per_rev as f32 * config.gear_ratio);
        if !(MIN_RAD_PER_COUNT..=MAX_RAD_PER_COUNT).contains(&magnitude) {
            return Err(EncoderConfigError::Resolution);
        }
        let rad_per_count = match config.sign {
            EncoderSign::Normal => magnitude,
            EncoderSign::Reversed => -magnitude,
        };
        Ok(EncoderScale {
            rad_per_count,
            zero_counts: 0,
        })
    }

    /// The scales of both axes; an axis whose configuration is refused reads
    /// [`EncoderScale::REFUSED`] (NaN) and its error is returned next to it.
    pub fn both(
        configs: &[EncoderConfig; 2],
    ) -> ([EncoderScale; 2], [Option<EncoderConfigError>; 2]) {
        let mut scales = [EncoderScale::REFUSED; 2];
        let mut errors = [None; 2];
        for k in 0..2 {
            match EncoderScale::new(&configs[k]) {
                Ok(s) => scales[k] = s,
                Err(e) => errors[k] = Some(e),
            }
        }
        (scales, errors)
    }

    /// Joint angle (rad) of a counter reading. The difference to the zero is taken in wrapping
    /// 32-bit arithmetic, so a counter that wrapped past `i32::MAX` still reads right.
    #[inline]
    pub fn joint_rad(&self, counts: i32) -> f32 {
        counts.wrapping_sub(self.zero_counts) as f32 * self.rad_per_count
    }

    /// Joint radians per count (negative for [`EncoderSign::Reversed`]).
    pub fn rad_per_count(&self) -> f32 {
        self.rad_per_count
    }

    /// **The homing hook.** The joint is at `joint_rad` while the counter reads `counts` (an
    /// index pulse, a hard stop or an absolute sensor at a known angle): from now on
    /// [`EncoderScale::joint_rad`] is relative to that reference. The zero is rounded to the
    /// nearest count; a non-finite angle, or one further than 2^30 counts, is refused and the
    /// zero left as it was.
    pub fn set_reference(&mut self, counts: i32, joint_rad: f32) -> Result<(), EncoderConfigError> {
        let offset = libm::roundf(joint_rad / self.rad_per_count);
        if !(offset.abs() <= (1u32 << 30) as f32) {
            return Err(EncoderConfigError::Resolution);
        }
        self.zero_counts = counts.wrapping_sub(offset as i32);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::{FRAC_PI_2, PI, TAU};

    fn scale(counts_per_rev: u32, sign: EncoderSign, gear_ratio: f32) -> EncoderScale {
        EncoderScale::new(&EncoderConfig {
            counts_per_rev,
            sign,
            gear_ratio,
        })
        .unwrap()
    }

    #[test]
    fn a_motor_revolution_is_two_pi_over_the_gear_ratio_and_the_sign_is_kept() {
        let cpr = 1u32 << 22;
        let direct = scale(cpr, EncoderSign::Normal, 1.0);
        assert!((direct.joint_rad(cpr as i32) - TAU).abs() < 1e-6);
        assert_eq!(direct.joint_rad(-(cpr as i32) / 4), -FRAC_PI_2);
        assert_eq!(direct.joint_rad(0), 0.0);
        // One count is 1.5 µrad at 2^22 counts per revolution.
        assert!((direct.joint_rad(1) - 1.498e-6).abs() < 1e-9);
        // A 50:1 reducer: 50 motor revolutions are one joint revolution.
        let geared = scale(10_000, EncoderSign::Normal, 50.0);
        assert!((geared.joint_rad(500_000) - TAU).abs() < 1e-5);
        assert!((geared.joint_rad(125_000) - FRAC_PI_2).abs() < 1e-6);
        // 4096 counts per revolution at 1:1: a quarter turn.
        assert_eq!(
            scale(4096, EncoderSign::Normal, 1.0).joint_rad(1024),
            FRAC_PI_2
        );
    }

    /// What the direction test of the bring-up guide looks for: the joint turns positive (the
    /// counter of an encoder mounted the other way counts down) and a `Normal` configuration
    /// reads the motion backwards. `Reversed` reads it right.
    #[test]
    fn a_reversed_encoder_reads_backwards_until_its_sign_is_set() {
        let (cpr, ratio) = (8_000u32, 10.0);
        let counter_after_positive_quarter_turn = -(cpr as f32 * ratio / 4.0) as i32;
        let wrong = scale(cpr, EncoderSign::Normal, ratio);
        let right = scale(cpr, EncoderSign::Reversed, ratio);
        assert!(
            wrong.joint_rad(counter_after_positive_quarter_turn) < 0.0,
            "the motion reads negative"
        );
        assert!((right.joint_rad(counter_after_positive_quarter_turn) - FRAC_PI_2).abs() < 1e-6);
        assert_eq!(right.rad_per_count(), -wrong.rad_per_count());
    }

    #[test]
    fn homing_ties_a_counter_reading_to_a_joint_angle() {
        let mut s = scale(1 << 22, EncoderSign::Normal, 1.0);
        // Power-on: relative to where the machine stood.
        assert_eq!(s.joint_rad(1000), 1000.0 * s.rad_per_count());
        // The index pulse at counter 123_456 marks joint angle 0.8 rad.
        s.set_reference(123_456, 0.8).unwrap();
        assert!(
            (s.joint_rad(123_456) - 0.8).abs() < 2e-6,
            "{}",
            s.joint_rad(123_456)
        );
        assert!((s.joint_rad(123_456 + (1 << 20)) - (0.8 + FRAC_PI_2)).abs() < 2e-6);
        // Reversed and geared: the reference holds the same way.
        let mut r = scale(4096, EncoderSign::Reversed, 20.0);
        r.set_reference(-5000, -1.2).unwrap();
        assert!((r.joint_rad(-5000) + 1.2).abs() < 1e-4);
        // A non-finite or absurd reference is refused and the zero kept.
        let before = r;
        assert_eq!(
            r.set_reference(0, f32::NAN),
            Err(EncoderConfigError::Resolution)
        );
        assert_eq!(
            r.set_reference(0, 1e30),
            Err(EncoderConfigError::Resolution)
        );
        assert_eq!(r, before);
    }

    #[test]
    fn a_counter_that_wrapped_past_i32_max_still_reads_right() {
        let mut s = scale(1 << 22, EncoderSign::Normal, 1.0);
        s.set_reference(i32::MAX - 10, 0.0).unwrap();
        // 20 counts further the 32-bit counter wrapped to i32::MIN + 9.
        let wrapped = (i32::MAX - 10).wrapping_add(20);
        assert!((s.joint_rad(wrapped) - 20.0 * s.rad_per_count()).abs() < 1e-9);
    }

    #[test]
    fn bad_configurations_are_refused_and_read_nan() {
        let ok = EncoderConfig::DIRECT_DRIVE_2_22;
        for (bad, why) in [
            (
                EncoderConfig {
                    counts_per_rev: 0,
                    ..ok
                },
                EncoderConfigError::ZeroCountsPerRev,
            ),
            (
                EncoderConfig {
                    gear_ratio: 0.0,
                    ..ok
                },
                EncoderConfigError::GearRatio,
            ),
            (
                EncoderConfig {
                    gear_ratio: -50.0,
                    ..ok
                },
                EncoderConfigError::GearRatio,
            ),
            (
                EncoderConfig {
                    gear_ratio: f32::NAN,
                    ..ok
                },
                EncoderConfigError::GearRatio,
            ),
            (
                EncoderConfig {
                    gear_ratio: f32::INFINITY,
                    ..ok
                },
                EncoderConfigError::GearRatio,
            ),
            (
                EncoderConfig {
                    gear_ratio: 1e-30,
                    ..ok
                },
                EncoderConfigError::Resolution,
            ),
            (
                EncoderConfig {
                    counts_per_rev: 100,
                    gear_ratio: 1.0,
                    ..ok
                },
                EncoderConfigError::Resolution,
            ),
            (
                EncoderConfig {
                    counts_per_rev: u32::MAX,
                    gear_ratio: 1e6,
                    ..ok
                },
                EncoderConfigError::Resolution,
            ),
        ] {
            assert_eq!(EncoderScale::new(&bad), Err(why), "{bad:?}");
        }
        let (scales, errors) = EncoderScale::both(&[
            ok,
            EncoderConfig {
                counts_per_rev: 0,
                ..ok
            },
        ]);
        assert_eq!(errors, [None, Some(EncoderConfigError::ZeroCountsPerRev)]);
        assert_eq!(scales[0].joint_rad(1 << 21), PI);
        assert!(
            scales[1].joint_rad(1234).is_nan(),
            "a refused axis reads NaN, which the servo refuses"
        );
    }
}
