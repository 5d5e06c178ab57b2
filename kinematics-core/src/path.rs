//! Tool paths with their first three derivatives: the geometry a trajectory moves along.
//!
//! A path is a curve `c(u)` on a parameter interval `[0, U]`. A time law `u(t)` (a
//! [`JerkProfile`](crate::jerk_profile::JerkProfile)) makes it a motion, and the chain rule gives
//! the motion's exact derivatives from the curve's (`crate::trajectory`):
//!
//! ```text
//! v = c'·u̇     a = c''·u̇² + c'·ü     j = c'''·u̇³ + 3·c''·u̇·ü + c'·u⃛
//! ```
//! * [`Line`]: from one point to another, `u` the arc length (`|c'| = 1`, `c'' = 0`).
//! * [`Circle`]: `turns` turns from a start angle, `u` the arc length; `|c''| = 1/R`.
//! * [`Figure8`]: the 1:2 Lissajous figure `(X·sin φ, Y·sin 2φ)` about a centre, `u = φ`
//!   (not the arc length: its speed varies along the figure, as a plotter's would).
//!
//! Cost per point: a line is a few flops; the circle and the figure-eight one and two
//! `sin_cos`.

use crate::jerk_profile::ScalarState;
use crate::real::Real;
use crate::setpoint::MotionSetpoint;

/// A point of a path and the curve's derivatives with respect to its parameter there.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PathPoint<T> {
    /// `c(u)` (mm).
    pub position_mm: [T; 2],
    /// `c'(u)`.
    pub d1: [T; 2],
    /// `c''(u)`.
    pub d2: [T; 2],
    /// `c'''(u)`.
    pub d3: [T; 2],
}

/// A curve with three derivatives on `[0, length()]` (a small value, `Copy`).
pub trait Path<T: Real>: Copy {
    /// The end of the parameter interval.
    fn length(&self) -> T;
    /// The point and derivatives at parameter `u` (callers keep `u` in `[0, length()]`).
    fn point(&self, u: T) -> PathPoint<T>;
    /// An upper bound of `|c'(u)|` over the path: planning divides the tool's limits by it.
    fn max_speed_factor(&self) -> T;

    /// The tool's position and derivatives for the parameter's state `s` (the chain rule of
    /// the module doc; a path may do it with fewer operations).
    #[inline]
    fn motion(&self, s: &ScalarState<T>) -> MotionSetpoint<T> {
        let c = self.point(s.position);
        let (ud, udd, uddd) = (s.velocity, s.acceleration, s.jerk);
        let three = T::from_f64(3.0);
        let mut m = MotionSetpoint::at_rest(c.position_mm);
        for i in 0..2 {
            m.velocity_mm_s[i] = c.d1[i] * ud;
            m.acceleration_mm_s2[i] = c.d2[i] * ud * ud + c.d1[i] * udd;
            m.jerk_mm_s3[i] = (c.d3[i] * ud * ud + three * c.d2[i] * udd) * ud + c.d1[i] * uddd;
        }
        m
    }
}

/// A straight segment, parameterised by arc length.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Line<T> {
    from_mm: [T; 2],
    direction: [T; 2],
    length_mm: T,
}

impl<T: Real> Line<T> {
    /// The segment from `from_mm` to `to_mm` (a zero-length one stays at `from_mm`).
    pub fn new(from_mm: [T; 2], to_mm: [T; 2]) -> Self {
        let d = [to_mm[0] - from_mm[0], to_mm[1] - from_mm[1]];
        let length_mm = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let direction = if length_mm > T::ZERO {
            [d[0] / length_mm, d[1] / length_mm]
        } else {
            [T::ZERO; 2]
        };
        Line {
            from_mm,
            direction,
            length_mm,
        }
    }

    /// The start point.
    pub fn from_mm(&self) -> [T; 2] {
        self.from_mm
    }

    /// The unit direction (zero for a zero-length segment).
    pub fn direction(&self) -> [T; 2] {
        self.direction
    }
}

impl<T: Real> Path<T> for Line<T> {
    fn length(&self) -> T {
        self.length_mm
    }
    #[inline]
    fn point(&self, u: T) -> PathPoint<T> {
        let (p, d) = (self.from_mm, self.direction);
        PathPoint {
            position_mm: [p[0] + u * d[0], p[1] + u * d[1]],
            d1: d,
            d2: [T::ZERO; 2],
            d3: [T::ZERO; 2],
        }
    }
    fn max_speed_factor(&self) -> T {
        T::ONE
    }
    /// Every derivative along the direction (`c'' = c''' = 0`).
    #[inline]
    fn motion(&self, s: &ScalarState<T>) -> MotionSetpoint<T> {
        let (p, d) = (self.from_mm, self.direction);
        MotionSetpoint {
            position_mm: [p[0] + s.position * d[0], p[1] + s.position * d[1]],
            velocity_mm_s: [s.velocity * d[0], s.velocity * d[1]],
            acceleration_mm_s2: [s.acceleration * d[0], s.acceleration * d[1]],
            jerk_mm_s3: [s.jerk * d[0], s.jerk * d[1]],
        }
    }
}

/// `turns` turns of a circle, counter-clockwise from `start_rad`, parameterised by arc length.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Circle<T> {
    /// Centre (mm).
    pub centre_mm: [T; 2],
    /// Radius (mm, > 0).
    pub radius_mm: T,
    /// Angle of the start point from the centre (rad).
    pub start_rad: T,
    /// Turns (> 0; fractions allowed).
    pub turns: T,
}

impl<T: Real> Path<T> for Circle<T> {
    fn length(&self) -> T {
        T::TWO * T::PI * self.radius_mm * self.turns
    }
    #[inline]
    fn point(&self, u: T) -> PathPoint<T> {
        let r = self.radius_mm;
        let (s, c) = (self.start_rad + u / r).sin_cos();
        let (k, k2) = (T::ONE / r, T::ONE / (r * r));
        PathPoint {
            position_mm: [self.centre_mm[0] + r * c, self.centre_mm[1] + r * s],
            d1: [-s, c],
            d2: [-c * k, -s * k],
            d3: [s * k2, -c * k2],
        }
    }
    fn max_speed_factor(&self) -> T {
        T::ONE
    }
}

/// `loops` loops of the figure-eight `centre + (X·sin φ, Y·sin 2φ)`, parameter `φ` from 0.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Figure8<T> {
    /// Centre, where the figure starts and crosses itself (mm).
    pub centre_mm: [T; 2],
    /// Half-width `X` (mm).
    pub half_x_mm: T,
    /// Half-height `Y` (mm).
    pub half_y_mm: T,
    /// Loops (> 0).
    pub loops: T,
}

impl<T: Real> Path<T> for Figure8<T> {
    fn length(&self) -> T {
        T::TWO * T::PI * self.loops
    }
    #[inline]
    fn point(&self, u: T) -> PathPoint<T> {
        let (x, y) = (self.half_x_mm, self.half_y_mm);
        let (s1, c1) = u.sin_cos();
        let (s2, c2) = (T::TWO * u).sin_cos();
        let four = T::from_f64(4.0);
        PathPoint {
            position_mm: [self.centre_mm[0] + x * s1, self.centre_mm[1] + y * s2],
            d1: [x * c1, T::TWO * y * c2],
            d2: [-x * s1, -four * y * s2],
            d3: [-x * c1, -T::TWO * four * y * c2],
        }
    }
    fn max_speed_factor(&self) -> T {
        (self.half_x_mm * self.half_x_mm + T::from_f64(4.0) * self.half_y_mm * self.half_y_mm)
            .sqrt()
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// Central differences of each derivative against the next one.
    fn check_derivatives(p: &impl Path<f64>) {
        let h = 1e-5 * p.length().max(1.0);
        for k in 1..50 {
            let u = p.length() * k as f64 / 50.0;
            let (a, b, c) = (p.point(u - h), p.point(u), p.point(u + h));
            for i in 0..2 {
                let fd1 = (c.position_mm[i] - a.position_mm[i]) / (2.0 * h);
                let fd2 = (c.d1[i] - a.d1[i]) / (2.0 * h);
                let fd3 = (c.d2[i] - a.d2[i]) / (2.0 * h);
                assert!(
                    (fd1 - b.d1[i]).abs() < 1e-6 * (1.0 + b.d1[i].abs()),
                    "d1 at {u}"
                );
                assert!(
                    (fd2 - b.d2[i]).abs() < 1e-5 * (1.0 + b.d2[i].abs()),
                    "d2 at {u}"
                );
                assert!(
                    (fd3 - b.d3[i]).abs() < 1e-5 * (1.0 + b.d3[i].abs()),
                    "d3 at {u}"
                );
            }
            let speed = (b.d1[0] * b.d1[0] + b.d1[1] * b.d1[1]).sqrt();
            assert!(speed <= p.max_speed_factor() * (1.0 + 1e-12));
        }
    }

    #[test]
    fn derivatives_are_the_derivatives() {
        check_derivatives(&Line::new([200.0, -10.0], [230.0, 30.0]));
        check_derivatives(&Circle {
            centre_mm: [212.0, 0.0],
            radius_mm: 40.0,
            start_rad: 0.3,
            turns: 1.5,
        });
        check_derivatives(&Figure8 {
            centre_mm: [212.0, 0.0],
            half_x_mm: 45.0,
            half_y_mm: 30.0,
            loops: 1.0,
        });
    }

    #[test]
    fn line_ends_and_arc_length() {
        let l = Line::new([200.0, -10.0], [230.0, 30.0]);
        assert_eq!(l.length(), 50.0);
        let end = l.point(50.0).position_mm;
        assert!((end[0] - 230.0).abs() < 1e-12 && (end[1] - 30.0).abs() < 1e-12);
        let z = Line::new([1.0, 2.0], [1.0, 2.0]);
        assert_eq!(
            (z.length(), z.point(0.0).position_mm, z.direction()),
            (0.0, [1.0, 2.0], [0.0; 2])
        );
        let c = Circle {
            centre_mm: [0.0, 0.0],
            radius_mm: 10.0,
            start_rad: 0.0,
            turns: 1.0,
        };
        let p = c.point(c.length() / 4.0).position_mm;
        assert!(p[0].abs() < 1e-12 && (p[1] - 10.0).abs() < 1e-12);
    }
}
