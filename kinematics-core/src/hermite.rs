//! The cubic Hermite segment that joins two streamed knots (time, position, velocity in task
//! space): the controller's motion stream plays it in f32 and the host loop plays the same
//! knots through it in f64, so the two references are one formula, not two copies that can
//! drift apart. Cost: 12 multiply-adds to build, 16 to evaluate.

use crate::real::Real;
use crate::setpoint::MotionSetpoint;

/// `p(τ) = a + bτ + cτ² + dτ³` per axis, `τ` the time since the segment's start (s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HermiteCubic<T> {
    /// Position at the start (mm).
    pub a: [T; 2],
    /// Velocity at the start (mm/s).
    pub b: [T; 2],
    /// Half the acceleration at the start (mm/s²).
    pub c: [T; 2],
    /// A sixth of the (constant) jerk (mm/s³).
    pub d: [T; 2],
}

impl<T: Real> HermiteCubic<T> {
    /// The cubic from position `p0_mm` and velocity `v0_mm_s` to `p1_mm`, `v1_mm_s` in
    /// `duration_s` (positive; the callers check it).
    pub fn between(
        duration_s: T,
        p0_mm: [T; 2],
        v0_mm_s: [T; 2],
        p1_mm: [T; 2],
        v1_mm_s: [T; 2],
    ) -> Self {
        let h = duration_s;
        let three = T::from_f64(3.0);
        let (mut c, mut d) = ([T::ZERO; 2], [T::ZERO; 2]);
        for k in 0..2 {
            let slope = (p1_mm[k] - p0_mm[k]) / h;
            c[k] = (three * slope - T::TWO * v0_mm_s[k] - v1_mm_s[k]) / h;
            d[k] = (v0_mm_s[k] + v1_mm_s[k] - T::TWO * slope) / (h * h);
        }
        HermiteCubic {
            a: p0_mm,
            b: v0_mm_s,
            c,
            d,
        }
    }

    /// The setpoint `tau_s` after the start, with its exact derivatives.
    pub fn at(&self, tau_s: T) -> MotionSetpoint<T> {
        let (three, six) = (T::from_f64(3.0), T::from_f64(6.0));
        let mut s = MotionSetpoint::at_rest([T::ZERO; 2]);
        for k in 0..2 {
            let (a, b, c, d) = (self.a[k], self.b[k], self.c[k], self.d[k]);
            s.position_mm[k] = a + tau_s * (b + tau_s * (c + tau_s * d));
            s.velocity_mm_s[k] = b + tau_s * (T::TWO * c + tau_s * three * d);
            s.acceleration_mm_s2[k] = T::TWO * c + tau_s * six * d;
            s.jerk_mm_s3[k] = six * d;
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cubic meets both knots' positions and velocities, and its derivatives are those of
    /// its position (central differences).
    #[test]
    fn the_cubic_joins_the_knots_with_its_exact_derivatives() {
        let (p0, v0, p1, v1) = ([1.0, -2.0], [30.0, 5.0], [4.0, 1.5], [-10.0, 20.0]);
        let h = 0.08;
        let cubic = HermiteCubic::<f64>::between(h, p0, v0, p1, v1);
        let (start, end) = (cubic.at(0.0), cubic.at(h));
        for k in 0..2 {
            assert!((start.position_mm[k] - p0[k]).abs() < 1e-12);
            assert!((start.velocity_mm_s[k] - v0[k]).abs() < 1e-9);
            assert!((end.position_mm[k] - p1[k]).abs() < 1e-12);
            assert!((end.velocity_mm_s[k] - v1[k]).abs() < 1e-9);
        }
        let (t, dt) = (0.03, 1e-6);
        let (before, here, after) = (cubic.at(t - dt), cubic.at(t), cubic.at(t + dt));
        for k in 0..2 {
            let v = (after.position_mm[k] - before.position_mm[k]) / (2.0 * dt);
            let a = (after.velocity_mm_s[k] - before.velocity_mm_s[k]) / (2.0 * dt);
            let j = (after.acceleration_mm_s2[k] - before.acceleration_mm_s2[k]) / (2.0 * dt);
            assert!((v - here.velocity_mm_s[k]).abs() < 1e-6, "velocity {k}");
            assert!(
                (a - here.acceleration_mm_s2[k]).abs() < 1e-3,
                "acceleration {k}"
            );
            assert!((j - here.jerk_mm_s3[k]).abs() < 1e-1, "jerk {k}");
        }
    }
}
