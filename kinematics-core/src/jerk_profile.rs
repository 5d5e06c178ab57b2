//! The time-optimal jerk-limited rest-to-rest motion of one coordinate (the "7-segment
//! S-curve"), with exact position, velocity, acceleration and jerk at any time.
//!
//! ```text
//! jerk   +j ┌─┐               ┌─┐ +j           phases: Tj  Ta-2Tj  Tj | Tv | Tj  Ta-2Tj  Tj
//!           │ │    ┌─┐   ┌─┐  │ │                      (acceleration) (cruise) (deceleration)
//!   0  ─────┘ └────┘ └───┘ └──┘ └─────
//!                 -j   -j
//! ```
//! From rest to rest over a distance `D` with `|v| ≤ V`, `|a| ≤ A`, `|j| ≤ J`: the
//! acceleration phase takes the motion from rest to the peak speed `vp` in `Ta`, the deceleration
//! phase mirrors it, and the cruise `Tv` covers the rest. Closed form, in order:
//! 1. `vp = V` if the two ramps to `V` fit in `D`: `Tj = A/J`, `Ta = Tj + V/A` when `V·J ≥ A²`
//!    (the acceleration limit is reached), else `Tj = √(V/J)`, `Ta = 2Tj`; `Tv = D/V - Ta`.
//! 2. Otherwise no cruise. With the acceleration limit reached (`Tj = A/J`) the distance is
//!    `A·(Ta - Tj)·Ta`, so `Ta = (Tj + √(Tj² + 4D/A))/2`, valid if `Ta ≥ 2Tj`;
//! 3. else neither limit: `D = 2J·Tj³`, `Tj = ∛(D/2J)`, `Ta = 2Tj`.
//!
//! Each case makes the binding limits tight for the whole phase that can use them, which is the
//! time-optimal rest-to-rest profile (the solution Ruckig finds for zero boundary states;
//! `cargo bench -p host-sim --bench trajectory` compares the durations with the reference
//! Ruckig). The profile is point-symmetric about `(T/2, D/2)`: the second half is evaluated as
//! the mirror of the first, `s(t) = D - s(T - t)`, so the end is exactly `D` whatever the
//! rounding of the phases.
//!
//! # Why not a crate
//! `rsruckig` (the Rust port of Ruckig) solves the general state-to-state problem per axis with
//! box limits: ~9,000 lines of f64 root finding (software double precision on the Cortex-M4F,
//! about 20-60 cycles per operation), `arrayvec` storage, and trajectories whose evaluation is
//! also f64. The machine needs less and something else: rest-to-rest moves and contours along a
//! *path* (a line, a circle, a figure-eight) with limits on the *norm* of the tool's speed,
//! acceleration and jerk, evaluated in f32 in the 2 kHz step; a straight rest-to-rest move is
//! this closed form, a contour is this profile on the path parameter (`crate::trajectory`).
//!
//! # Cost
//! Planning: one `sqrt` or `cbrt`, a few divisions (not in the 2 kHz step). Evaluation: a
//! comparison chain and one cubic, about 30 flops; `BENCH jerk_profile_at` in
//! `cargo qemu-bench`. Error: the polynomials are exact; f32 rounds them to a few ulp of `D`.

use crate::real::Real;

/// Limits of a scalar motion (all > 0, finite).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProfileLimits<T> {
    /// Largest |velocity| (units/s).
    pub velocity: T,
    /// Largest |acceleration| (units/s²).
    pub acceleration: T,
    /// Largest |jerk| (units/s³).
    pub jerk: T,
}

/// Position, velocity, acceleration and jerk of a scalar motion at one instant.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ScalarState<T> {
    /// Position (units).
    pub position: T,
    /// Velocity (units/s).
    pub velocity: T,
    /// Acceleration (units/s²).
    pub acceleration: T,
    /// Jerk (units/s³).
    pub jerk: T,
}

/// Why a profile cannot be planned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ProfileError {
    /// The distance or a limit is NaN or infinite, or a result overflowed.
    NonFinite,
    /// A limit is zero or negative.
    NonPositiveLimit,
}

impl core::fmt::Display for ProfileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ProfileError::NonFinite => f.write_str("trajectory input is not finite"),
            ProfileError::NonPositiveLimit => {
                f.write_str("a speed, acceleration or jerk limit is not positive")
            }
        }
    }
}

impl core::error::Error for ProfileError {}

/// A planned rest-to-rest profile from 0 to `distance` (negative distances run backwards).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JerkProfile<T> {
    /// |distance|.
    distance: T,
    /// +1 or -1.
    sign: T,
    jerk: T,
    t_j: T,
    t_a: T,
    t_v: T,
    /// `2·t_a + t_v`.
    total: T,
    /// States (position, velocity) at the ends of the first three phases; acceleration `a_p`.
    p1: T,
    v1: T,
    p2: T,
    v2: T,
    p3: T,
    v3: T,
    a_p: T,
}

impl<T: Real> JerkProfile<T> {
    /// The time-optimal rest-to-rest profile over `distance` within `limits`.
    pub fn plan(distance: T, limits: &ProfileLimits<T>) -> Result<Self, ProfileError> {
        let ProfileLimits {
            velocity: v,
            acceleration: a,
            jerk: j,
        } = *limits;
        if !(distance.is_finite() && v.is_finite() && a.is_finite() && j.is_finite()) {
            return Err(ProfileError::NonFinite);
        }
        if !(v > T::ZERO && a > T::ZERO && j > T::ZERO) {
            return Err(ProfileError::NonPositiveLimit);
        }
        let d = distance.abs();
        let sign = if distance < T::ZERO { -T::ONE } else { T::ONE };
        // 1. Cruise at V if both ramps to V fit.
        let (t_j, t_a) = if v * j >= a * a {
            (a / j, a / j + v / a)
        } else {
            ((v / j).sqrt(), T::TWO * (v / j).sqrt())
        };
        let (t_j, t_a, t_v) = if v * t_a <= d {
            (t_j, t_a, d / v - t_a)
        } else {
            // 2. No cruise; the acceleration limit reached?
            let t_j = a / j;
            let t_a = (t_j + (t_j * t_j + T::from_f64(4.0) * d / a).sqrt()) * T::HALF;
            if t_a >= T::TWO * t_j {
                (t_j, t_a, T::ZERO)
            } else {
                // 3. Neither limit.
                let t_j = (d / (T::TWO * j)).cbrt();
                (t_j, T::TWO * t_j, T::ZERO)
            }
        };
        let profile = Self::from_phases(d, sign, j, t_j, t_a, t_v);
        if !(profile.duration_s().is_finite() && profile.p3.is_finite()) {
            return Err(ProfileError::NonFinite);
        }
        Ok(profile)
    }

    /// No motion at all (zero duration).
    pub fn rest() -> Self {
        Self::from_phases(T::ZERO, T::ONE, T::ZERO, T::ZERO, T::ZERO, T::ZERO)
    }

    /// The profile with jerk `jerk` and phases `t_j`, `t_a`, `t_v` (the boundary states).
    fn from_phases(distance: T, sign: T, jerk: T, t_j: T, t_a: T, t_v: T) -> Self {
        let six = T::from_f64(6.0);
        let a_p = jerk * t_j;
        let p1 = jerk * t_j * t_j * t_j / six;
        let v1 = a_p * t_j * T::HALF;
        let dt = t_a - T::TWO * t_j;
        let p2 = p1 + v1 * dt + a_p * dt * dt * T::HALF;
        let v2 = v1 + a_p * dt;
        let p3 = p2 + v2 * t_j + a_p * t_j * t_j * T::HALF - p1;
        let v3 = v2 + v1;
        JerkProfile {
            distance,
            sign,
            jerk,
            t_j,
            t_a,
            t_v,
            total: T::TWO * t_a + t_v,
            p1,
            v1,
            p2,
            v2,
            p3,
            v3,
            a_p,
        }
    }

    /// The same profile run `factor` times slower (`factor > 1`) or faster: `s_k(t) = s(t/k)`,
    /// i.e. the time-optimal profile for the limits `(V/k, A/k², J/k³)`.
    pub fn time_scaled(&self, factor: T) -> Result<Self, ProfileError> {
        if !factor.is_finite() {
            return Err(ProfileError::NonFinite);
        }
        if !(factor > T::ZERO) {
            return Err(ProfileError::NonPositiveLimit);
        }
        let k3 = factor * factor * factor;
        let p = Self::from_phases(
            self.distance,
            self.sign,
            self.jerk / k3,
            self.t_j * factor,
            self.t_a * factor,
            self.t_v * factor,
        );
        if !(p.duration_s().is_finite() && p.jerk.is_finite()) {
            return Err(ProfileError::NonFinite);
        }
        Ok(p)
    }

    /// Total duration (s).
    pub fn duration_s(&self) -> T {
        self.total
    }

    /// The signed distance covered.
    pub fn distance(&self) -> T {
        self.sign * self.distance
    }

    /// Peak |velocity| reached.
    pub fn peak_velocity(&self) -> T {
        self.v3
    }

    /// Peak |acceleration| reached.
    pub fn peak_acceleration(&self) -> T {
        self.a_p
    }

    /// The phase durations `(Tj, Ta, Tv)` (s): jerk phase, whole acceleration phase, cruise.
    pub fn phases_s(&self) -> (T, T, T) {
        (self.t_j, self.t_a, self.t_v)
    }

    /// The state at `t_s` (s from the start); before the start and after the end it is at rest.
    #[inline]
    pub fn at(&self, t_s: T) -> ScalarState<T> {
        let total = self.duration_s();
        // `!(t > 0)` also takes NaN to the start.
        let t = if !(t_s > T::ZERO) {
            T::ZERO
        } else if t_s > total {
            total
        } else {
            t_s
        };
        let back = total - t;
        let s = if t <= back {
            self.first_half(t)
        } else {
            let m = self.first_half(back);
            ScalarState {
                position: self.distance - m.position,
                velocity: m.velocity,
                acceleration: -m.acceleration,
                jerk: m.jerk,
            }
        };
        let g = self.sign;
        ScalarState {
            position: g * s.position,
            velocity: g * s.velocity,
            acceleration: g * s.acceleration,
            jerk: g * s.jerk,
        }
    }

    /// The accelerating half (and the first half of the cruise), `0 ≤ t ≤ T/2`, unsigned.
    #[inline(always)]
    fn first_half(&self, t: T) -> ScalarState<T> {
        let (j, a_p) = (self.jerk, self.a_p);
        let half = T::HALF;
        let sixth = T::from_f64(1.0 / 6.0);
        if t < self.t_j {
            let t2 = t * t;
            ScalarState {
                position: j * t2 * t * sixth,
                velocity: j * t2 * half,
                acceleration: j * t,
                jerk: j,
            }
        } else if t < self.t_a - self.t_j {
            let u = t - self.t_j;
            ScalarState {
                position: self.p1 + (self.v1 + a_p * u * half) * u,
                velocity: self.v1 + a_p * u,
                acceleration: a_p,
                jerk: T::ZERO,
            }
        } else if t < self.t_a {
            let u = t - (self.t_a - self.t_j);
            let ju = j * u;
            ScalarState {
                position: self.p2 + (self.v2 + (a_p * half - ju * sixth) * u) * u,
                velocity: self.v2 + (a_p - ju * half) * u,
                acceleration: a_p - ju,
                jerk: -j,
            }
        } else {
            let u = t - self.t_a;
            ScalarState {
                position: self.p3 + self.v3 * u,
                velocity: self.v3,
                acceleration: T::ZERO,
                jerk: T::ZERO,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    fn limits(v: f64, a: f64, j: f64) -> ProfileLimits<f64> {
        ProfileLimits {
            velocity: v,
            acceleration: a,
            jerk: j,
        }
    }

    /// Samples the profile finely and integrates jerk → acceleration → velocity → position
    /// numerically: the stated derivatives must be the derivatives of the stated position.
    fn check_consistent(p: &JerkProfile<f64>, lim: &ProfileLimits<f64>) {
        let n = 20_000;
        let total = p.duration_s();
        let dt = total / n as f64;
        let mut prev = p.at(0.0);
        assert_eq!(prev.position, 0.0);
        assert_eq!((prev.velocity, prev.acceleration), (0.0, 0.0));
        let (mut peak_v, mut peak_a) = (0.0f64, 0.0f64);
        for k in 1..=n {
            let s = p.at(k as f64 * dt);
            // Trapezoidal integration of the derivatives, each from the next one.
            let dv = (prev.acceleration + s.acceleration) * 0.5 * dt;
            let dp = (prev.velocity + s.velocity) * 0.5 * dt
                + (prev.acceleration - s.acceleration) * dt * dt / 12.0;
            assert!(
                (s.velocity - prev.velocity - dv).abs() <= 1e-6 * lim.velocity + lim.jerk * dt * dt,
                "v at {k}"
            );
            assert!(
                (s.position - prev.position - dp).abs()
                    <= 1e-9 * p.distance.abs() + lim.jerk * dt.powi(4),
                "p at {k}"
            );
            assert!(s.velocity.abs() <= lim.velocity * (1.0 + 1e-12));
            assert!(s.acceleration.abs() <= lim.acceleration * (1.0 + 1e-12));
            assert!(s.jerk.abs() <= lim.jerk);
            peak_v = peak_v.max(s.velocity.abs());
            peak_a = peak_a.max(s.acceleration.abs());
            prev = s;
        }
        assert_eq!(prev.position, p.distance(), "ends exactly at the distance");
        assert!(
            prev.velocity.abs() < 1e-9 * lim.velocity
                && prev.acceleration.abs() < 1e-9 * lim.acceleration
        );
        assert!((peak_v - p.peak_velocity()).abs() <= 1e-9 * lim.velocity + lim.acceleration * dt);
        assert!((peak_a - p.peak_acceleration()).abs() <= lim.jerk * dt);
    }

    #[test]
    fn every_case_is_consistent_and_within_its_limits() {
        let g = 9_806.65;
        for (d, lim, case) in [
            (
                100.0,
                limits(1500.0, 5.0 * g, 5e6),
                "cruise, acceleration limit reached",
            ),
            (
                100.0,
                limits(300.0, 5.0 * g, 5e5),
                "cruise, acceleration limit not reached",
            ),
            (
                10.0,
                limits(1500.0, 5.0 * g, 1e7),
                "no cruise, acceleration limit reached",
            ),
            (0.1, limits(1500.0, 5.0 * g, 1e6), "neither"),
            (-37.5, limits(800.0, 2.0 * g, 2e6), "backwards"),
        ] {
            let p = JerkProfile::plan(d, &lim).unwrap();
            let (t_j, t_a, t_v) = p.phases_s();
            assert!(
                t_j >= 0.0 && t_a >= 2.0 * t_j * (1.0 - 1e-12) && t_v >= 0.0,
                "{case}: {:?}",
                p.phases_s()
            );
            check_consistent(&p, &lim);
        }
    }

    /// At least one limit is tight in every phase that can use it: if it were not, a faster
    /// profile would exist. Cases: the speed is at its limit when there is a cruise, the
    /// acceleration when there is a constant-acceleration phase, the jerk always.
    #[test]
    fn the_binding_limits_are_tight() {
        let g = 9_806.65;
        let lim = limits(1500.0, 5.0 * g, 5e6);
        for d in [0.01, 0.5, 5.0, 20.0, 45.0, 200.0] {
            let p = JerkProfile::plan(d, &lim).unwrap();
            let (t_j, t_a, t_v) = p.phases_s();
            if t_v > 0.0 {
                assert!(
                    (p.peak_velocity() - lim.velocity).abs() < 1e-9 * lim.velocity,
                    "{d}"
                );
            }
            if t_a > 2.0 * t_j * (1.0 + 1e-9) {
                assert!(
                    (p.peak_acceleration() - lim.acceleration).abs() < 1e-9 * lim.acceleration,
                    "{d}"
                );
            }
            assert!(
                p.peak_velocity() <= lim.velocity * (1.0 + 1e-12)
                    && p.peak_acceleration() <= lim.acceleration * (1.0 + 1e-12)
            );
        }
    }

    #[test]
    fn durations_grow_with_distance_and_shrink_with_limits() {
        let g = 9_806.65;
        let lim = limits(1500.0, 5.0 * g, 5e6);
        let mut last = 0.0;
        for k in 1..400 {
            let t = JerkProfile::plan(k as f64 * 0.5, &lim)
                .unwrap()
                .duration_s();
            assert!(t > last, "{k}");
            last = t;
        }
        let slow = JerkProfile::plan(50.0, &limits(1500.0, 2.0 * g, 5e6))
            .unwrap()
            .duration_s();
        let fast = JerkProfile::plan(50.0, &limits(1500.0, 5.0 * g, 5e6))
            .unwrap()
            .duration_s();
        assert!(fast < slow);
    }

    #[test]
    fn time_scaling_is_the_profile_of_the_scaled_limits() {
        let lim = limits(1200.0, 40_000.0, 4e6);
        let p = JerkProfile::plan(30.0, &lim).unwrap();
        let k = 1.7;
        let s = p.time_scaled(k).unwrap();
        let q = JerkProfile::plan(
            30.0,
            &limits(1200.0 / k, 40_000.0 / (k * k), 4e6 / (k * k * k)),
        )
        .unwrap();
        assert!((s.duration_s() - k * p.duration_s()).abs() < 1e-12);
        assert!((q.duration_s() - s.duration_s()).abs() < 1e-9);
        for i in 0..=100 {
            let t = s.duration_s() * i as f64 / 100.0;
            let (a, b, c) = (s.at(t), q.at(t), p.at(t / k));
            assert!(
                (a.position - b.position).abs() < 1e-9 && (a.position - c.position).abs() < 1e-9
            );
            assert!((a.velocity - c.velocity / k).abs() < 1e-9);
            assert!((a.acceleration - c.acceleration / (k * k)).abs() < 1e-6);
        }
    }

    #[test]
    fn zero_distance_stays_at_rest_and_bad_input_is_refused() {
        let lim = limits(1.0, 1.0, 1.0);
        let p = JerkProfile::plan(0.0, &lim).unwrap();
        assert_eq!(p.duration_s(), 0.0);
        assert_eq!(
            p.at(1.0),
            ScalarState {
                position: 0.0,
                velocity: 0.0,
                acceleration: 0.0,
                jerk: 0.0
            }
        );
        assert_eq!(
            JerkProfile::plan(f64::NAN, &lim),
            Err(ProfileError::NonFinite)
        );
        assert_eq!(
            JerkProfile::plan(1.0, &limits(1.0, f64::INFINITY, 1.0)),
            Err(ProfileError::NonFinite)
        );
        assert_eq!(
            JerkProfile::plan(1.0, &limits(1.0, 0.0, 1.0)),
            Err(ProfileError::NonPositiveLimit)
        );
        assert_eq!(
            JerkProfile::plan(1.0, &limits(-1.0, 1.0, 1.0)),
            Err(ProfileError::NonPositiveLimit)
        );
        assert_eq!(p.time_scaled(0.0), Err(ProfileError::NonPositiveLimit));
        assert_eq!(p.time_scaled(f64::NAN), Err(ProfileError::NonFinite));
        // NaN time: the start.
        let p = JerkProfile::plan(5.0, &lim).unwrap();
        assert_eq!(p.at(f64::NAN).position, 0.0);
        assert_eq!(p.at(-1.0).position, 0.0);
        assert_eq!(p.at(1e9).position, 5.0);
    }

    #[test]
    fn f32_profile_follows_the_f64_one() {
        let g = 9_806.65;
        let p64 = JerkProfile::plan(85.0, &limits(1500.0, 5.0 * g, 5e6)).unwrap();
        let p32 = JerkProfile::<f32>::plan(
            85.0,
            &ProfileLimits {
                velocity: 1500.0,
                acceleration: 5.0 * g as f32,
                jerk: 5e6,
            },
        )
        .unwrap();
        let mut worst = 0.0f64;
        for k in 0..=1000 {
            let t = p64.duration_s() * k as f64 / 1000.0;
            let e = (p32.at(t as f32).position as f64 - p64.at(t).position).abs();
            worst = worst.max(e);
        }
        // 85 mm in f32: ulp 7.6e-6 mm; the phases and the time carry a few ulp each.
        assert!(worst < 2e-4, "{worst} mm");
        assert_eq!(p32.at(1.0).position, 85.0);
    }
}
