//! Position controller of one axis: PID on the joint angle with velocity and acceleration
//! feed-forward, a torque limit and anti-windup.
//!
//! ```text
//! τ = kp·e + ki·∫e + kd·(ω_ref - ω) + inertia·α_ref + viscous·ω_ref + coulomb·s(ω_ref),
//! e = θ_ref - θ,   s(ω) = ω / (|ω| + ω_c)
//! ```
//! The feed-forward terms supply the torque a 5 g move needs, so the feedback only has to
//! correct what the model of the drive gets wrong, and the following error at high
//! acceleration stays small. The Coulomb term uses a smoothed sign of the *reference* velocity
//! (`ω_c` sets how fast it turns over), so it switches where the motion reverses instead of
//! waiting for the integrator to unwind, and never chatters on encoder noise. Anti-windup is
//! conditional integration: while the output is saturated the integrator only moves in the
//! direction that brings it out of saturation, and it is clamped to `integral_limit_nm` of
//! torque in any case. Derivative acts on the velocity
//! error (reference velocity minus measured), not on the error of a stepped reference, so a
//! new setpoint never kicks the output. Cost: about 25 floating-point operations.
//!
//! [`AxisController::feedback`] is the same controller with the feed-forward torque given from
//! outside (the servo's inverse dynamics): the gains' own feed-forward terms are then unused.
//!
//! No panic for any gains: [`AxisGains::validate`] says which gains a servo may run with (the
//! servo refuses others, see `ServoConfig::validate`), but [`AxisController::update`] itself
//! never panics and never returns a NaN, an infinity or more than the limit, whatever it is
//! given: the output and the integrator go through [`saturate`] (no `f32::clamp`, which panics
//! when its bounds are crossed or NaN).

/// Gains and limits of one axis (joint side: torques in N·m at the link, angles in rad).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisGains {
    /// Proportional gain (N·m/rad).
    pub kp_nm_per_rad: f32,
    /// Integral gain (N·m/(rad·s)).
    pub ki_nm_per_rad_s: f32,
    /// Velocity-error gain (N·m·s/rad).
    pub kd_nm_s_per_rad: f32,
    /// Acceleration feed-forward: the axis' effective inertia (kg·m²).
    pub inertia_ff_kg_m2: f32,
    /// Velocity feed-forward: the axis' viscous friction (N·m·s/rad).
    pub viscous_ff_nm_s_per_rad: f32,
    /// Coulomb friction feed-forward (N·m), applied with the sign of the reference velocity.
    pub coulomb_ff_nm: f32,
    /// Reference speed (rad/s) at which the Coulomb feed-forward reaches half its value.
    pub coulomb_ff_speed_rad_s: f32,
    /// Output limit (N·m), symmetric.
    pub torque_limit_nm: f32,
    /// Largest torque the integrator may hold (N·m).
    pub integral_limit_nm: f32,
    /// Bandwidth of the servo's disturbance observer (rad/s; 0: off): how fast the torque the
    /// feed-forward lacks is estimated and added (`crate::disturbance_observer`; the servo's
    /// motion step only, [`AxisController::update`] does not use it).
    pub observer_bandwidth_rad_s: f32,
    /// The observer's nominal inertia of the axis (kg·m²): the diagonal of the identified
    /// inertia matrix; stable for less than twice the axis' true inertia.
    pub observer_inertia_kg_m2: f32,
}

/// A gain or limit [`AxisGains::validate`] refuses: the name of the field.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InvalidGain(pub &'static str);

impl core::fmt::Display for InvalidGain {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} must be finite (and, for a feedback gain or a limit, not negative)",
            self.0
        )
    }
}

impl core::error::Error for InvalidGain {}

impl AxisGains {
    /// Checks that a servo can run with these gains: every field finite; the feedback gains
    /// (`kp`, `ki`, `kd`, the observer's bandwidth and nominal inertia) and both limits not
    /// negative (a negative feedback gain is positive
    /// feedback, a negative limit no limit at all); the Coulomb turn-over speed positive (it
    /// divides). The feed-forward terms may have either sign.
    pub fn validate(&self) -> Result<(), InvalidGain> {
        let non_negative = [
            (self.kp_nm_per_rad, "kp_nm_per_rad"),
            (self.ki_nm_per_rad_s, "ki_nm_per_rad_s"),
            (self.kd_nm_s_per_rad, "kd_nm_s_per_rad"),
            (self.torque_limit_nm, "torque_limit_nm"),
            (self.integral_limit_nm, "integral_limit_nm"),
            (self.observer_bandwidth_rad_s, "observer_bandwidth_rad_s"),
            (self.observer_inertia_kg_m2, "observer_inertia_kg_m2"),
        ];
        for (v, name) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(InvalidGain(name));
            }
        }
        let finite = [
            (self.inertia_ff_kg_m2, "inertia_ff_kg_m2"),
            (self.viscous_ff_nm_s_per_rad, "viscous_ff_nm_s_per_rad"),
            (self.coulomb_ff_nm, "coulomb_ff_nm"),
        ];
        for (v, name) in finite {
            if !v.is_finite() {
                return Err(InvalidGain(name));
            }
        }
        if !(self.coulomb_ff_speed_rad_s.is_finite() && self.coulomb_ff_speed_rad_s > 0.0) {
            return Err(InvalidGain("coulomb_ff_speed_rad_s"));
        }
        Ok(())
    }

    /// The gains' own feed-forward torque (N·m) for a reference moving at `velocity_rad_s`
    /// with `acceleration_rad_s2`: inertia, viscous and Coulomb terms. The Coulomb term's
    /// division (14 cycles) is skipped when it is off (`coulomb_ff_nm == 0`, the default).
    #[inline]
    pub fn feed_forward_nm(&self, velocity_rad_s: f32, acceleration_rad_s2: f32) -> f32 {
        let tau = self.inertia_ff_kg_m2 * acceleration_rad_s2
            + self.viscous_ff_nm_s_per_rad * velocity_rad_s;
        if self.coulomb_ff_nm == 0.0 {
            return tau;
        }
        tau + self.coulomb_ff_nm * velocity_rad_s
            / (velocity_rad_s.abs() + self.coulomb_ff_speed_rad_s)
    }
}

/// `value` limited to `[-limit, limit]`: zero when `value` is NaN, or when `limit` is not a
/// finite non-negative number (gains `validate` refuses; this must not panic on them either).
/// `f32::clamp` would panic on such a limit. The usual case (a valid limit, `value` within it)
/// costs two comparisons: `|value| <= limit` is false for a NaN value or a NaN or negative
/// limit, `limit <= f32::MAX` for an infinite one; a value beyond a valid limit two or three
/// more.
#[inline]
pub fn saturate(value: f32, limit: f32) -> f32 {
    if value.abs() <= limit && limit <= f32::MAX {
        return value;
    }
    // Beyond the limit, or NaN. Neither comparison holds for a NaN value nor for a NaN or
    // infinite limit (zero then); a negative limit is refused before them.
    if limit >= 0.0 {
        if value > limit {
            return limit;
        }
        if value < -limit {
            return -limit;
        }
    }
    0.0
}

/// The axis state carried from one sample to the next.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisController {
    /// Integrator contents, already multiplied by `ki` (N·m).
    integral_nm: f32,
}

/// What one axis is asked to do in one sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisReference {
    /// Angle the axis should be at (rad).
    pub angle_rad: f32,
    /// Its rate of change (rad/s): the velocity feed-forward and the kd term's reference.
    pub velocity_rad_s: f32,
    /// Its second derivative (rad/s²): the acceleration feed-forward.
    pub acceleration_rad_s2: f32,
}

impl AxisController {
    /// One control sample of length `dt_s`: returns the torque command (N·m), within the limit.
    /// Never panics; the result is always finite and within `±torque_limit_nm` (zero for a
    /// limit that is not a finite non-negative number, or when the terms add up to NaN).
    #[inline(always)]
    pub fn update(
        &mut self,
        gains: &AxisGains,
        reference: &AxisReference,
        angle_rad: f32,
        velocity_rad_s: f32,
        dt_s: f32,
    ) -> f32 {
        self.feedback(
            gains,
            reference.angle_rad - angle_rad,
            reference.velocity_rad_s - velocity_rad_s,
            gains.feed_forward_nm(reference.velocity_rad_s, reference.acceleration_rad_s2),
            dt_s,
        )
    }

    /// The PID on the remainder of a feed-forward computed elsewhere (the servo's model-based
    /// one): `τ = kp·e + ki·∫e + kd·ė + feedforward`, limited, with the same anti-windup as
    /// [`AxisController::update`] (which is this with the gains' own feed-forward). The gains'
    /// feed-forward terms are not used here. Never panics, and the same guarantees on the
    /// result as `update` (finite, within the limit, zero for a NaN sum).
    #[inline(always)]
    pub fn feedback(
        &mut self,
        gains: &AxisGains,
        error_rad: f32,
        velocity_error_rad_s: f32,
        feedforward_nm: f32,
        dt_s: f32,
    ) -> f32 {
        let unsaturated = gains.kp_nm_per_rad * error_rad
            + self.integral_nm
            + gains.kd_nm_s_per_rad * velocity_error_rad_s
            + feedforward_nm;
        let limit = gains.torque_limit_nm;
        let output = saturate(unsaturated, limit);
        let increment = gains.ki_nm_per_rad_s * error_rad * dt_s;
        let winds_up =
            (unsaturated > limit && increment > 0.0) || (unsaturated < -limit && increment < 0.0);
        if !winds_up {
            // A NaN sum (only with absurd gains or inputs) empties the integrator.
            self.integral_nm = saturate(self.integral_nm + increment, gains.integral_limit_nm);
        }
        output
    }

    /// Integrator contents (N·m).
    pub fn integral_nm(&self) -> f32 {
        self.integral_nm
    }

    /// Empties the integrator (after a fault, before the drives are enabled again).
    pub fn reset(&mut self) {
        self.integral_nm = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains() -> AxisGains {
        AxisGains {
            kp_nm_per_rad: 100.0,
            ki_nm_per_rad_s: 1000.0,
            kd_nm_s_per_rad: 1.0,
            inertia_ff_kg_m2: 0.01,
            viscous_ff_nm_s_per_rad: 0.1,
            coulomb_ff_nm: 0.0,
            coulomb_ff_speed_rad_s: 0.01,
            torque_limit_nm: 2.0,
            integral_limit_nm: 1.0,
            observer_bandwidth_rad_s: 0.0,
            observer_inertia_kg_m2: 0.0,
        }
    }

    fn still(angle_rad: f32) -> AxisReference {
        AxisReference {
            angle_rad,
            velocity_rad_s: 0.0,
            acceleration_rad_s2: 0.0,
        }
    }

    #[test]
    fn output_is_limited_and_integrator_does_not_wind_up() {
        let mut c = AxisController::default();
        for _ in 0..10_000 {
            let t = c.update(&gains(), &still(1.0), 0.0, 0.0, 5e-4);
            assert!((-2.0..=2.0).contains(&t));
        }
        // Saturated the whole time with a positive error: the integrator must not have grown.
        assert_eq!(c.integral_nm(), 0.0);
    }

    #[test]
    fn integrator_removes_a_constant_disturbance() {
        // A unit-inertia axis with a constant 0.5 N·m load: the integrator must take it over.
        let g = gains();
        let mut c = AxisController::default();
        let (mut angle, mut vel) = (0.0f32, 0.0f32);
        let dt = 5e-4;
        for _ in 0..40_000 {
            let tau = c.update(&g, &still(0.1), angle, vel, dt);
            let acc = (tau - 0.5) / 0.01;
            vel += acc * dt;
            angle += vel * dt;
        }
        assert!((angle - 0.1).abs() < 1e-5, "angle {angle}");
        assert!(
            (c.integral_nm() - 0.5).abs() < 1e-3,
            "integral {}",
            c.integral_nm()
        );
    }

    #[test]
    fn coulomb_feed_forward_follows_the_reference_direction() {
        let g = AxisGains {
            coulomb_ff_nm: 0.5,
            ..gains()
        };
        let at = |w: f32| {
            let r = AxisReference {
                angle_rad: 0.0,
                velocity_rad_s: w,
                acceleration_rad_s2: 0.0,
            };
            // Measured velocity = reference: no kd term; only viscous and Coulomb remain.
            AxisController::default().update(&g, &r, 0.0, w, 5e-4) - 0.1 * w
        };
        assert!((at(10.0) - 0.5).abs() < 1e-3 && (at(-10.0) + 0.5).abs() < 1e-3);
        assert!(
            (at(0.01) - 0.25).abs() < 1e-6,
            "half at the turn-over speed"
        );
        assert_eq!(at(0.0), 0.0);
    }

    #[test]
    fn feed_forward_supplies_the_acceleration_torque() {
        let mut c = AxisController::default();
        let r = AxisReference {
            angle_rad: 0.0,
            velocity_rad_s: 0.0,
            acceleration_rad_s2: 100.0,
        };
        let t = c.update(&gains(), &r, 0.0, 0.0, 5e-4);
        assert!((t - 1.0).abs() < 1e-6);
    }

    // One sample per term: each test turns on one gain, feeds a reference whose angle,
    // velocity and acceleration all differ from the measured ones, and requires exactly that
    // term's torque. A gain acting on the wrong signal (viscous feed-forward on the measured
    // velocity, the integrator on kp, ...) gives another number.

    /// Every term off, limits out of the way.
    fn only() -> AxisGains {
        AxisGains {
            kp_nm_per_rad: 0.0,
            ki_nm_per_rad_s: 0.0,
            kd_nm_s_per_rad: 0.0,
            inertia_ff_kg_m2: 0.0,
            viscous_ff_nm_s_per_rad: 0.0,
            coulomb_ff_nm: 0.0,
            coulomb_ff_speed_rad_s: 0.01,
            torque_limit_nm: 100.0,
            integral_limit_nm: 100.0,
            observer_bandwidth_rad_s: 0.0,
            observer_inertia_kg_m2: 0.0,
        }
    }

    /// Reference: 1.25 rad, 4 rad/s, 300 rad/s². Measured: 1.0 rad, -1 rad/s.
    const REF: AxisReference = AxisReference {
        angle_rad: 1.25,
        velocity_rad_s: 4.0,
        acceleration_rad_s2: 300.0,
    };
    const ANGLE_RAD: f32 = 1.0;
    const VELOCITY_RAD_S: f32 = -1.0;

    fn one_sample(g: &AxisGains, dt_s: f32) -> (f32, AxisController) {
        let mut c = AxisController::default();
        let t = c.update(g, &REF, ANGLE_RAD, VELOCITY_RAD_S, dt_s);
        (t, c)
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-6 * (1.0 + b.abs())
    }

    #[test]
    fn kp_acts_on_the_angle_error() {
        let (t, c) = one_sample(
            &AxisGains {
                kp_nm_per_rad: 200.0,
                ..only()
            },
            5e-4,
        );
        assert!(close(t, 200.0 * 0.25), "{t}");
        assert_eq!(c.integral_nm(), 0.0, "kp does not integrate");
    }

    #[test]
    fn ki_integrates_the_error_over_dt_from_the_next_sample_on() {
        let g = AxisGains {
            ki_nm_per_rad_s: 1000.0,
            ..only()
        };
        let (t, mut c) = one_sample(&g, 1e-3);
        assert_eq!(t, 0.0, "the integrator acts from the next sample");
        assert!(
            close(c.integral_nm(), 1000.0 * 0.25 * 1e-3),
            "{}",
            c.integral_nm()
        );
        // A longer sample integrates proportionally more; the output is the integral so far.
        let t = c.update(&g, &REF, ANGLE_RAD, VELOCITY_RAD_S, 2e-3);
        assert!(close(t, 0.25), "{t}");
        assert!(
            close(c.integral_nm(), 0.25 + 1000.0 * 0.25 * 2e-3),
            "{}",
            c.integral_nm()
        );
        // Clamped to the integral limit.
        let g = AxisGains {
            integral_limit_nm: 0.1,
            ..g
        };
        let (_, c) = one_sample(&g, 1.0);
        assert_eq!(c.integral_nm(), 0.1);
    }

    #[test]
    fn kd_acts_on_reference_minus_measured_velocity() {
        let (t, _) = one_sample(
            &AxisGains {
                kd_nm_s_per_rad: 2.0,
                ..only()
            },
            5e-4,
        );
        assert!(close(t, 2.0 * (4.0 - -1.0)), "{t}");
    }

    #[test]
    fn inertia_feed_forward_acts_on_the_reference_acceleration() {
        let (t, _) = one_sample(
            &AxisGains {
                inertia_ff_kg_m2: 0.01,
                ..only()
            },
            5e-4,
        );
        assert!(close(t, 0.01 * 300.0), "{t}");
    }

    #[test]
    fn viscous_feed_forward_acts_on_the_reference_velocity() {
        let (t, _) = one_sample(
            &AxisGains {
                viscous_ff_nm_s_per_rad: 0.5,
                ..only()
            },
            5e-4,
        );
        assert!(
            close(t, 0.5 * 4.0),
            "{t} (0.5 x the measured velocity would be -0.5)"
        );
    }

    #[test]
    fn coulomb_feed_forward_acts_on_the_reference_velocity() {
        let (t, _) = one_sample(
            &AxisGains {
                coulomb_ff_nm: 0.3,
                ..only()
            },
            5e-4,
        );
        assert!(close(t, 0.3 * 4.0 / 4.01), "{t}");
    }

    /// `f32::clamp(-limit, limit)` panics with a negative or NaN limit; the controller never
    /// does.
    #[test]
    fn absurd_limits_and_gains_never_panic_and_give_a_finite_limited_torque() {
        for limit in [-1.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 0.0] {
            for il in [-1.0, f32::NAN, f32::INFINITY, 1.0] {
                let g = AxisGains {
                    torque_limit_nm: limit,
                    integral_limit_nm: il,
                    ki_nm_per_rad_s: 1e3,
                    ..gains()
                };
                assert!(
                    g.validate().is_err() || (limit == 0.0 && il == 1.0),
                    "{limit} {il}"
                );
                let mut c = AxisController::default();
                for _ in 0..3 {
                    let t = c.update(&g, &REF, ANGLE_RAD, VELOCITY_RAD_S, 5e-4);
                    assert_eq!(
                        t, 0.0,
                        "limit {limit}: a limit that is not a non-negative number commands nothing"
                    );
                    assert!(c.integral_nm().is_finite());
                }
            }
        }
        // Terms that add up to NaN (inf - inf): zero torque, the integrator emptied, not NaN.
        let g = AxisGains {
            kp_nm_per_rad: f32::MAX,
            kd_nm_s_per_rad: f32::MAX,
            ..gains()
        };
        let r = AxisReference {
            angle_rad: 10.0,
            velocity_rad_s: -10.0,
            acceleration_rad_s2: 0.0,
        };
        let mut c = AxisController::default();
        assert_eq!(c.update(&g, &r, 0.0, 0.0, 5e-4), 0.0);
        assert_eq!(c.update(&g, &r, 0.0, f32::NAN, 5e-4), 0.0);
        assert!(c.integral_nm().is_finite());
        // A zero Coulomb turn-over speed at zero reference speed is 0/0.
        let g = AxisGains {
            coulomb_ff_nm: 0.5,
            coulomb_ff_speed_rad_s: 0.0,
            ..gains()
        };
        assert_eq!(g.validate(), Err(InvalidGain("coulomb_ff_speed_rad_s")));
        assert_eq!(
            AxisController::default().update(&g, &still(0.0), 0.0, 0.0, 5e-4),
            0.0
        );
    }

    #[test]
    fn validate_accepts_the_defaults_and_names_the_bad_field() {
        assert_eq!(gains().validate(), Ok(()));
        assert_eq!(
            AxisGains {
                kp_nm_per_rad: -1.0,
                ..gains()
            }
            .validate(),
            Err(InvalidGain("kp_nm_per_rad"))
        );
        assert_eq!(
            AxisGains {
                kd_nm_s_per_rad: f32::NAN,
                ..gains()
            }
            .validate(),
            Err(InvalidGain("kd_nm_s_per_rad"))
        );
        assert_eq!(
            AxisGains {
                inertia_ff_kg_m2: f32::INFINITY,
                ..gains()
            }
            .validate(),
            Err(InvalidGain("inertia_ff_kg_m2"))
        );
        // Feed-forward terms may be negative (a drive that pushes the axis).
        assert_eq!(
            AxisGains {
                viscous_ff_nm_s_per_rad: -0.1,
                ..gains()
            }
            .validate(),
            Ok(())
        );
    }

    #[test]
    fn feedback_adds_an_external_feed_forward_and_ignores_the_gains_own() {
        let all = AxisGains {
            kp_nm_per_rad: 200.0,
            kd_nm_s_per_rad: 2.0,
            inertia_ff_kg_m2: 0.01,
            viscous_ff_nm_s_per_rad: 0.5,
            ..only()
        };
        let mut c = AxisController::default();
        let t = c.feedback(&all, 0.25, 5.0, 1.5, 5e-4);
        assert!(close(t, 200.0 * 0.25 + 2.0 * 5.0 + 1.5), "{t}");
        // The same sample through `update` with the gains' feed-forward turned into the argument.
        let ff = 0.01 * 300.0 + 0.5 * 4.0;
        let (u, _) = one_sample(&all, 5e-4);
        let f = AxisController::default().feedback(&all, 0.25, 5.0, ff, 5e-4);
        assert!(close(u, f), "{u} vs {f}");
        let limited = AxisController::default().feedback(
            &AxisGains {
                torque_limit_nm: 7.5,
                ..all
            },
            0.25,
            5.0,
            100.0,
            5e-4,
        );
        assert_eq!(limited, 7.5);
    }

    #[test]
    fn the_terms_add_up_and_the_sum_is_limited() {
        let all = AxisGains {
            kp_nm_per_rad: 200.0,
            kd_nm_s_per_rad: 2.0,
            inertia_ff_kg_m2: 0.01,
            viscous_ff_nm_s_per_rad: 0.5,
            coulomb_ff_nm: 0.3,
            ..only()
        };
        let (t, _) = one_sample(&all, 5e-4);
        assert!(close(t, 50.0 + 10.0 + 3.0 + 2.0 + 0.3 * 4.0 / 4.01), "{t}");
        let (t, _) = one_sample(
            &AxisGains {
                torque_limit_nm: 7.5,
                ..all
            },
            5e-4,
        );
        assert_eq!(t, 7.5);
        let (t, _) = one_sample(
            &AxisGains {
                kp_nm_per_rad: -200.0,
                torque_limit_nm: 7.5,
                ..only()
            },
            5e-4,
        );
        assert_eq!(t, -7.5);
    }
}
