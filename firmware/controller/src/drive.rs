//! Torque-mode amplifiers commanded by PWM duty: 50 % is zero torque, 0 % and 100 % are minus
//! and plus the full scale (locked anti-phase, or an amplifier's PWM torque input).
//!
//! The PWM output itself is embedded-hal 1.0's `SetDutyCycle`, implemented by each board.
use embedded_hal::pwm::SetDutyCycle;

/// A PWM write failed: the drive's torque is unknown (latched as
/// [`Fault::Drive`](crate::fault::Fault::Drive)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriveError;

/// Duty for a torque (clamped to full scale), rounded to the nearest step. A non-finite torque
/// (the servo never emits one) commands zero torque, never a full-scale one.
#[inline]
pub fn torque_to_duty(torque_nm: f32, full_scale_nm: f32, max_duty: u16) -> u16 {
    let fraction = 0.5 + 0.5 * torque_nm / full_scale_nm;
    if !fraction.is_finite() {
        return max_duty / 2;
    }
    // `fraction` is finite; clamped into [0, 1] the product is within [0, max_duty + 0.5].
    (fraction.clamp(0.0, 1.0) * max_duty as f32 + 0.5) as u16
}

/// Torque that a duty commands (the inverse of [`torque_to_duty`]).
#[inline]
pub fn duty_to_torque_nm(duty: u16, full_scale_nm: f32, max_duty: u16) -> f32 {
    (2.0 * duty as f32 / max_duty as f32 - 1.0) * full_scale_nm
}

/// One amplifier and its PWM input.
pub struct TorqueDrive<P> {
    /// The PWM output driving the amplifier.
    pub pwm: P,
    /// Torque at 0 % / 100 % duty (N·m).
    pub full_scale_nm: f32,
}

impl<P: SetDutyCycle> TorqueDrive<P> {
    /// Commands `torque_nm`; returns the torque actually commanded after duty rounding.
    pub fn set_torque_nm(&mut self, torque_nm: f32) -> Result<f32, DriveError> {
        let max = self.pwm.max_duty_cycle();
        let duty = torque_to_duty(torque_nm, self.full_scale_nm, max);
        self.pwm.set_duty_cycle(duty).map_err(|_| DriveError)?;
        Ok(duty_to_torque_nm(duty, self.full_scale_nm, max))
    }
}

/// Commands both axes; returns the torques commanded after duty rounding, or the first error
/// (axis 1 is not written after axis 0 failed).
pub fn set_torques_nm<P: SetDutyCycle>(
    drives: &mut [TorqueDrive<P>; 2],
    torque_nm: [f32; 2],
) -> Result<[f32; 2], DriveError> {
    let a = drives[0].set_torque_nm(torque_nm[0])?;
    let b = drives[1].set_torque_nm(torque_nm[1])?;
    Ok([a, b])
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAX: u16 = 4250;
    const FULL_NM: f32 = 10.0;

    #[test]
    fn zero_torque_is_half_duty_and_full_scale_the_ends() {
        assert_eq!(torque_to_duty(0.0, FULL_NM, MAX), 2125);
        assert_eq!(torque_to_duty(-0.0, FULL_NM, MAX), 2125);
        assert_eq!(torque_to_duty(FULL_NM, FULL_NM, MAX), MAX);
        assert_eq!(torque_to_duty(-FULL_NM, FULL_NM, MAX), 0);
        assert_eq!(duty_to_torque_nm(2125, FULL_NM, MAX), 0.0);
        assert_eq!(duty_to_torque_nm(MAX, FULL_NM, MAX), FULL_NM);
        assert_eq!(duty_to_torque_nm(0, FULL_NM, MAX), -FULL_NM);
    }

    #[test]
    fn beyond_full_scale_saturates_and_non_finite_commands_zero_torque() {
        assert_eq!(torque_to_duty(1e6, FULL_NM, MAX), MAX);
        assert_eq!(torque_to_duty(-1e6, FULL_NM, MAX), 0);
        for t in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(torque_to_duty(t, FULL_NM, MAX), 2125, "{t}");
        }
        // A zero full scale would divide 0 by 0: zero torque, not a rail.
        assert_eq!(torque_to_duty(0.0, 0.0, MAX), 2125);
    }

    #[test]
    fn duty_rounds_to_the_nearest_step_and_round_trips_within_half_a_step() {
        let step_nm = 2.0 * FULL_NM / MAX as f32;
        // One step above zero torque, and a hair below half a step (rounds down).
        assert_eq!(torque_to_duty(step_nm, FULL_NM, MAX), 2126);
        assert_eq!(torque_to_duty(0.49 * step_nm, FULL_NM, MAX), 2125);
        assert_eq!(torque_to_duty(0.51 * step_nm, FULL_NM, MAX), 2126);
        for k in -1000..=1000 {
            let t = k as f32 * 0.00917;
            let back = duty_to_torque_nm(torque_to_duty(t, FULL_NM, MAX), FULL_NM, MAX);
            assert!((back - t).abs() <= 0.5 * step_nm * 1.0001, "{t} -> {back}");
        }
        // Monotonic over the whole range.
        let mut last = 0;
        for k in -1100..=1100 {
            let d = torque_to_duty(k as f32 * 0.01, FULL_NM, MAX);
            assert!(d >= last);
            last = d;
        }
    }

    /// A PWM that records its duty, or fails.
    struct Recorder {
        duty: u16,
        fail: bool,
    }
    impl embedded_hal::pwm::ErrorType for Recorder {
        type Error = embedded_hal::pwm::ErrorKind;
    }
    impl SetDutyCycle for Recorder {
        fn max_duty_cycle(&self) -> u16 {
            MAX
        }
        fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
            if self.fail {
                return Err(embedded_hal::pwm::ErrorKind::Other);
            }
            self.duty = duty;
            Ok(())
        }
    }

    #[test]
    fn a_drive_writes_the_duty_and_reports_the_torque_it_commands() {
        let mut d = TorqueDrive {
            pwm: Recorder {
                duty: 0,
                fail: false,
            },
            full_scale_nm: FULL_NM,
        };
        let got = d.set_torque_nm(2.5).unwrap();
        assert_eq!(d.pwm.duty, torque_to_duty(2.5, FULL_NM, MAX));
        assert!((got - 2.5).abs() <= FULL_NM / MAX as f32);
        d.pwm.fail = true;
        assert_eq!(d.set_torque_nm(1.0), Err(DriveError));
        let mut both = [
            TorqueDrive {
                pwm: Recorder {
                    duty: 0,
                    fail: false,
                },
                full_scale_nm: FULL_NM,
            },
            TorqueDrive {
                pwm: Recorder {
                    duty: 0,
                    fail: false,
                },
                full_scale_nm: FULL_NM,
            },
        ];
        let got = set_torques_nm(&mut both, [-FULL_NM, 0.0]).unwrap();
        assert_eq!(got, [-FULL_NM, 0.0]);
        assert_eq!((both[0].pwm.duty, both[1].pwm.duty), (0, 2125));
        both[1].pwm.fail = true;
        assert_eq!(set_torques_nm(&mut both, [0.0; 2]), Err(DriveError));
    }
}
