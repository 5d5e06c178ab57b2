//! Jerk-limited tool trajectories with exact derivatives: a [`Path`] moved along by a
//! time-optimal [`JerkProfile`], and [`Tour`]s of rest-to-rest moves through waypoints.
//!
//! Every sample is a [`MotionSetpoint`]: position, velocity, acceleration and jerk of the tool,
//! all from the same closed form (the path's derivatives through the chain rule, see
//! [`crate::path`]), so the servo's feed-forward has no finite-difference lag.
//!
//! * A straight move ([`PathMotion::line`]) is the 1-D profile along the line's unit direction:
//!   the limits on the *norm* of the tool's speed, acceleration and jerk are the profile's, and
//!   the move is time-optimal for them (both axes in phase: the tool stays on the line).
//! * A contour ([`PathMotion::plan`]: circle, figure-eight) runs the profile on the path
//!   parameter, starting and ending at rest, and is then time-scaled uniformly
//!   ([`JerkProfile::time_scaled`]) until its sampled peak speed, acceleration and jerk meet
//!   the limits with the tightest one exactly: a circle at "5 g peak acceleration" cruises just
//!   below 5 g of centripetal acceleration so that the ramps stay within 5 g too. Uniform scaling
//!   is not time-optimal along a path (that would be a path parameterisation with jerk limits,
//!   TOPP); it keeps the closed form and its exact derivatives.
//! * A [`Tour`] goes through waypoints by straight rest-to-rest moves with a dwell at each: an
//!   exact polyline can only pass a corner at rest (any speed through a corner is an infinite
//!   acceleration), and a positioning machine rests at each target anyway.
//!
//! Joint-space limits (motor speed and torque) are checked and met by the same uniform
//! time scaling in [`crate::joint_limits`].
//!
//! Cost: a [`Line`] sample is the profile (`BENCH jerk_profile_at`) plus 12 flops; `BENCH
//! trajectory_line_at` in `cargo qemu-bench`. No heap: a tour holds at most `N` moves.

use crate::jerk_profile::{JerkProfile, ProfileError, ProfileLimits};
use crate::path::{Line, Path};
use crate::real::Real;
pub use crate::setpoint::MotionSetpoint;
use crate::KinematicsError;

/// Limits on the norms of the tool's speed, acceleration and jerk (all > 0).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaskLimits<T> {
    /// Largest speed (mm/s).
    pub speed_mm_s: T,
    /// Largest acceleration (mm/s²).
    pub accel_mm_s2: T,
    /// Largest jerk (mm/s³).
    pub jerk_mm_s3: T,
}

impl<T: Real> TaskLimits<T> {
    /// The scalar limits of a parameter whose curve speed `|c'|` is at most `factor`.
    fn per_parameter(&self, factor: T) -> ProfileLimits<T> {
        ProfileLimits {
            velocity: self.speed_mm_s / factor,
            acceleration: self.accel_mm_s2 / factor,
            jerk: self.jerk_mm_s3 / factor,
        }
    }
}

/// Why a trajectory cannot be planned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TrajectoryError {
    /// A limit, point or time is not finite, or a limit not positive.
    Profile(ProfileError),
    /// More waypoints than the tour holds.
    TooManyWaypoints,
    /// A path with no length (a contour needs `length > 0`).
    EmptyPath,
    /// A joint-space limit cannot be met by slowing down (the friction alone exceeds it).
    JointLimits,
    /// The path leaves the workspace or meets a singularity.
    Kinematics(KinematicsError),
}

impl From<ProfileError> for TrajectoryError {
    fn from(e: ProfileError) -> Self {
        TrajectoryError::Profile(e)
    }
}

impl core::fmt::Display for TrajectoryError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TrajectoryError::Profile(e) => write!(f, "{e}"),
            TrajectoryError::TooManyWaypoints => f.write_str("more waypoints than the tour holds"),
            TrajectoryError::EmptyPath => f.write_str("the path has no length"),
            TrajectoryError::JointLimits => {
                f.write_str("the joint speed or torque limits cannot be met by slowing down")
            }
            TrajectoryError::Kinematics(e) => write!(f, "the path is not feasible: {e}"),
        }
    }
}

impl core::error::Error for TrajectoryError {}

/// A path moved along by a rest-to-rest jerk-limited time law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathMotion<T, P> {
    path: P,
    law: JerkProfile<T>,
}

/// Peak norms of a motion's speed (mm/s), acceleration (mm/s²) and jerk (mm/s³).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peaks<T> {
    /// Peak speed.
    pub speed_mm_s: T,
    /// Peak acceleration.
    pub accel_mm_s2: T,
    /// Peak jerk.
    pub jerk_mm_s3: T,
}

fn norm<T: Real>(v: [T; 2]) -> T {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

impl<T: Real> PathMotion<T, Line<T>> {
    /// The time-optimal straight move from `from_mm` to `to_mm` within `limits`.
    pub fn line(
        from_mm: [T; 2],
        to_mm: [T; 2],
        limits: &TaskLimits<T>,
    ) -> Result<Self, TrajectoryError> {
        if !(from_mm[0].is_finite()
            && from_mm[1].is_finite()
            && to_mm[0].is_finite()
            && to_mm[1].is_finite())
        {
            return Err(TrajectoryError::Profile(ProfileError::NonFinite));
        }
        let path = Line::new(from_mm, to_mm);
        let law = JerkProfile::plan(path.length(), &limits.per_parameter(T::ONE))?;
        Ok(PathMotion { path, law })
    }
}

impl<T: Real, P: Path<T>> PathMotion<T, P> {
    /// A path with a given time law (its distance should be the path's length).
    pub fn new(path: P, law: JerkProfile<T>) -> Self {
        PathMotion { path, law }
    }

    /// The whole path from rest to rest, uniformly time-scaled so that the peaks sampled at
    /// `samples` instants meet `limits` with the tightest one exactly (see the module doc).
    pub fn plan(path: P, limits: &TaskLimits<T>, samples: usize) -> Result<Self, TrajectoryError> {
        let length = path.length();
        if !(length > T::ZERO) {
            return Err(if length.is_finite() {
                TrajectoryError::EmptyPath
            } else {
                ProfileError::NonFinite.into()
            });
        }
        let law = JerkProfile::plan(length, &limits.per_parameter(path.max_speed_factor()))?;
        let first = PathMotion { path, law };
        let p = first.peaks(samples);
        let k = (p.speed_mm_s / limits.speed_mm_s)
            .max((p.accel_mm_s2 / limits.accel_mm_s2).sqrt())
            .max((p.jerk_mm_s3 / limits.jerk_mm_s3).cbrt());
        first.time_scaled(k)
    }

    /// The same motion `factor` times slower (speeds / k, accelerations / k², jerks / k³).
    pub fn time_scaled(&self, factor: T) -> Result<Self, TrajectoryError> {
        Ok(PathMotion {
            path: self.path,
            law: self.law.time_scaled(factor)?,
        })
    }

    /// The path.
    pub fn path(&self) -> &P {
        &self.path
    }

    /// The time law.
    pub fn law(&self) -> &JerkProfile<T> {
        &self.law
    }

    /// Duration (s).
    pub fn duration_s(&self) -> T {
        self.law.duration_s()
    }

    /// The setpoint at `t_s` (s from the start; at rest before and after).
    #[inline]
    pub fn at(&self, t_s: T) -> MotionSetpoint<T> {
        self.path.motion(&self.law.at(t_s))
    }

    /// Peak norms over `samples + 1` equally spaced instants (ends included).
    pub fn peaks(&self, samples: usize) -> Peaks<T> {
        let n = samples.max(1);
        let mut p = Peaks {
            speed_mm_s: T::ZERO,
            accel_mm_s2: T::ZERO,
            jerk_mm_s3: T::ZERO,
        };
        let step = self.duration_s() / T::from_f64(n as f64);
        for k in 0..=n {
            let m = self.at(T::from_f64(k as f64) * step);
            p.speed_mm_s = p.speed_mm_s.max(norm(m.velocity_mm_s));
            p.accel_mm_s2 = p.accel_mm_s2.max(norm(m.acceleration_mm_s2));
            p.jerk_mm_s3 = p.jerk_mm_s3.max(norm(m.jerk_mm_s3));
        }
        p
    }
}

/// Rest-to-rest straight moves through up to `N` waypoints, with a dwell after each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tour<T, const N: usize> {
    moves: [PathMotion<T, Line<T>>; N],
    len: usize,
    dwell_s: T,
    start_mm: [T; 2],
}

impl<T: Real, const N: usize> Tour<T, N> {
    /// From `start_mm` through `waypoints_mm` (at most `N`) within `limits`, resting `dwell_s`
    /// after each move.
    pub fn plan(
        start_mm: [T; 2],
        waypoints_mm: &[[T; 2]],
        limits: &TaskLimits<T>,
        dwell_s: T,
    ) -> Result<Self, TrajectoryError> {
        if waypoints_mm.len() > N {
            return Err(TrajectoryError::TooManyWaypoints);
        }
        if !(dwell_s >= T::ZERO && dwell_s.is_finite()) {
            return Err(ProfileError::NonFinite.into());
        }
        let rest = PathMotion::line(start_mm, start_mm, limits)?;
        let mut moves = [rest; N];
        let mut from = start_mm;
        for (slot, &to) in moves.iter_mut().zip(waypoints_mm) {
            *slot = PathMotion::line(from, to, limits)?;
            from = to;
        }
        Ok(Tour {
            moves,
            len: waypoints_mm.len(),
            dwell_s,
            start_mm,
        })
    }

    /// No moves: holds `start_mm` (never fails).
    pub fn hold(start_mm: [T; 2]) -> Self {
        let rest = PathMotion::new(Line::new(start_mm, start_mm), JerkProfile::rest());
        Tour {
            moves: [rest; N],
            len: 0,
            dwell_s: T::ZERO,
            start_mm,
        }
    }

    /// The moves, in order.
    pub fn moves(&self) -> &[PathMotion<T, Line<T>>] {
        &self.moves[..self.len]
    }

    /// The moves, to rescale one (`crate::joint_limits`).
    pub fn moves_mut(&mut self) -> &mut [PathMotion<T, Line<T>>] {
        &mut self.moves[..self.len]
    }

    /// The dwell after each move (s).
    pub fn dwell_s(&self) -> T {
        self.dwell_s
    }

    /// Where the tour starts.
    pub fn start_mm(&self) -> [T; 2] {
        self.start_mm
    }

    /// Where the tour ends (the start if it has no moves).
    pub fn end_mm(&self) -> [T; 2] {
        match self.moves().last() {
            Some(m) => m.at(m.duration_s()).position_mm,
            None => self.start_mm,
        }
    }

    /// Every move and dwell (s).
    pub fn duration_s(&self) -> T {
        self.moves()
            .iter()
            .fold(T::ZERO, |t, m| t + m.duration_s() + self.dwell_s)
    }

    /// The setpoint at `t_s` from the start of the tour (at rest at the end after it).
    /// Long tours in f32 lose time resolution (`t` of seconds carries 0.1 µs of rounding):
    /// the firmware counts samples per move and calls [`PathMotion::at`] of each move instead.
    pub fn at(&self, t_s: T) -> MotionSetpoint<T> {
        let mut t = t_s;
        for m in self.moves() {
            let d = m.duration_s();
            if t <= d + self.dwell_s {
                return m.at(t);
            }
            t = t - d - self.dwell_s;
        }
        MotionSetpoint::at_rest(self.end_mm())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::path::{Circle, Figure8};

    const G: f64 = 9_806.65;

    fn limits() -> TaskLimits<f64> {
        TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * G,
            jerk_mm_s3: 5e6,
        }
    }

    /// Derivatives against central differences of the next-lower one.
    fn check_derivatives<P: Path<f64>>(m: &PathMotion<f64, P>) {
        let h = 1e-6;
        for k in 1..200 {
            let t = m.duration_s() * k as f64 / 200.0;
            let (a, b, c) = (m.at(t - h), m.at(t), m.at(t + h));
            for i in 0..2 {
                let fv = (c.position_mm[i] - a.position_mm[i]) / (2.0 * h);
                let fa = (c.velocity_mm_s[i] - a.velocity_mm_s[i]) / (2.0 * h);
                assert!(
                    (fv - b.velocity_mm_s[i]).abs() < 1e-3,
                    "v at {t}: {fv} {}",
                    b.velocity_mm_s[i]
                );
                assert!(
                    (fa - b.acceleration_mm_s2[i]).abs()
                        < 1.0 + 1e-5 * b.acceleration_mm_s2[i].abs(),
                    "a at {t}"
                );
            }
        }
    }

    #[test]
    fn a_line_keeps_to_the_line_and_its_limits() {
        let m = PathMotion::line([170.0, -65.0], [250.0, 60.0], &limits()).unwrap();
        check_derivatives(&m);
        let p = m.peaks(4000);
        assert!(
            (p.speed_mm_s - 1500.0).abs() < 1e-6 && (p.accel_mm_s2 - 5.0 * G).abs() < 1e-6,
            "{p:?}"
        );
        for k in 0..=100 {
            let s = m.at(m.duration_s() * k as f64 / 100.0);
            // On the line: the offset from the start is parallel to the direction.
            let d = [s.position_mm[0] - 170.0, s.position_mm[1] + 65.0];
            assert!((d[0] * 125.0 - d[1] * 80.0).abs() < 1e-9, "{d:?}");
            assert!((s.velocity_mm_s[0] * 125.0 - s.velocity_mm_s[1] * 80.0).abs() < 1e-9);
        }
        assert_eq!(m.at(1.0).position_mm, [250.0, 60.0]);
    }

    #[test]
    fn contours_meet_their_tightest_limit_exactly() {
        let circle = Circle {
            centre_mm: [212.0, 0.0],
            radius_mm: 40.0,
            start_rad: 0.0,
            turns: 2.0,
        };
        let m = PathMotion::plan(circle, &limits(), 4000).unwrap();
        check_derivatives(&m);
        let p = m.peaks(4000);
        assert!(
            (p.accel_mm_s2 - 5.0 * G).abs() < 1e-6 * G || (p.jerk_mm_s3 - 5e6).abs() < 1.0,
            "{p:?}"
        );
        assert!(
            p.accel_mm_s2 <= 5.0 * G * (1.0 + 1e-9)
                && p.jerk_mm_s3 <= 5e6 * (1.0 + 1e-9)
                && p.speed_mm_s <= 1500.0
        );
        // On the circle.
        for k in 0..=100 {
            let s = m.at(m.duration_s() * k as f64 / 100.0);
            let r = ((s.position_mm[0] - 212.0).powi(2) + s.position_mm[1].powi(2)).sqrt();
            assert!((r - 40.0).abs() < 1e-9);
        }
        let f8 = Figure8 {
            centre_mm: [212.0, 0.0],
            half_x_mm: 45.0,
            half_y_mm: 30.0,
            loops: 1.0,
        };
        let m = PathMotion::plan(f8, &limits(), 4000).unwrap();
        check_derivatives(&m);
        let p = m.peaks(20_000);
        assert!(
            p.accel_mm_s2 <= 5.0 * G * 1.001
                && p.speed_mm_s <= 1500.0 * 1.001
                && p.jerk_mm_s3 <= 5e6 * 1.001,
            "{p:?}"
        );
        let tight = [
            p.accel_mm_s2 / (5.0 * G),
            p.speed_mm_s / 1500.0,
            p.jerk_mm_s3 / 5e6,
        ];
        assert!(tight.iter().any(|r| *r > 0.999), "{tight:?}");
        assert_eq!(
            PathMotion::plan(
                Circle {
                    turns: 0.0,
                    ..circle
                },
                &limits(),
                10
            ),
            Err(TrajectoryError::EmptyPath)
        );
    }

    #[test]
    fn a_tour_rests_at_every_waypoint() {
        let wp = [[250.0, 60.0], [180.0, 60.0], [180.0, -50.0]];
        let t: Tour<f64, 4> = Tour::plan([212.0, 0.0], &wp, &limits(), 0.1).unwrap();
        assert_eq!(t.moves().len(), 3);
        let mut at = 0.0;
        for (m, w) in t.moves().iter().zip(wp) {
            at += m.duration_s();
            for dt in [0.0, 0.05, 0.1] {
                let s = t.at(at + dt);
                assert!(
                    (s.position_mm[0] - w[0]).abs() < 1e-9
                        && (s.position_mm[1] - w[1]).abs() < 1e-9
                );
                assert!(norm(s.velocity_mm_s) < 1e-9, "{:?}", s.velocity_mm_s);
            }
            at += 0.1;
        }
        assert!((t.duration_s() - at).abs() < 1e-12);
        assert_eq!(t.at(at + 5.0).position_mm, [180.0, -50.0]);
        assert_eq!(
            Tour::<f64, 2>::plan([0.0; 2], &wp, &limits(), 0.1).err(),
            Some(TrajectoryError::TooManyWaypoints)
        );
        assert_eq!(
            Tour::<f64, 4>::plan([0.0; 2], &[[f64::NAN, 0.0]], &limits(), 0.1).err(),
            Some(ProfileError::NonFinite.into())
        );
        let empty: Tour<f64, 4> = Tour::plan([1.0, 2.0], &[], &limits(), 0.1).unwrap();
        assert_eq!((empty.duration_s(), empty.end_mm()), (0.0, [1.0, 2.0]));
        let hold: Tour<f64, 4> = Tour::hold([1.0, 2.0]);
        assert_eq!(
            (hold.duration_s(), hold.end_mm(), hold.at(3.0).position_mm),
            (0.0, [1.0, 2.0], [1.0, 2.0])
        );
    }
}
