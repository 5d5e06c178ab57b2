//! A streamed trajectory as the controller plays it: knots (time, position, velocity in task
//! space, `link_protocol::Knot`) joined by cubic Hermite segments, sampled with their exact
//! derivatives.
//!
//! Why here: the host loop must run the very reference the firmware runs when the same knots
//! are streamed to it (`controller::motion_stream`), so that a telemetry log of the host loop
//! and one of the controller are the same kind of record, and so that a log can be matched
//! with the knots that produced it. The segment polynomial is the controller's own
//! (`kinematics_core::hermite`: `p(τ) = a + bτ + cτ² + dτ³` from the two knots' positions and
//! velocities), evaluated in f64 from the knots' f32 values; the controller evaluates the same
//! function in f32.
//!
//! The stream starts at rest at `start_mm` at time 0 (the first knot's time is after it);
//! after the last knot the path holds the last knot's position at rest (a stream whose last
//! knot moves would underrun on a controller: [`KnotPath::new`] refuses it).
//!
//! Cost: a binary search and one cubic per evaluation.

use super::SimError;
use kinematics_core::hermite::HermiteCubic;
use kinematics_core::trajectory::MotionSetpoint;
use link_protocol::Knot;

/// One Hermite segment over `[t0, t1]` (s): the controller's cubic
/// (`kinematics_core::hermite`), in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Segment {
    t0_s: f64,
    t1_s: f64,
    cubic: HermiteCubic<f64>,
}

impl Segment {
    /// The controller's segment between two knots (times in s, values as streamed).
    fn between(
        t0_s: f64,
        p0: [f64; 2],
        v0: [f64; 2],
        t1_s: f64,
        p1: [f64; 2],
        v1: [f64; 2],
    ) -> Self {
        Segment {
            t0_s,
            t1_s,
            cubic: HermiteCubic::between(t1_s - t0_s, p0, v0, p1, v1),
        }
    }

    fn at(&self, t_s: f64) -> MotionSetpoint<f64> {
        self.cubic.at(t_s - self.t0_s)
    }
}

/// Knots joined as the controller joins them (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct KnotPath {
    start_mm: [f64; 2],
    knots: Vec<Knot>,
    segments: Vec<Segment>,
}

impl KnotPath {
    /// The path from rest at `start_mm` through `knots` (times from the stream's start,
    /// strictly increasing, the first after 0; finite numbers; the last at rest).
    pub fn new(start_mm: [f64; 2], knots: &[Knot]) -> Result<Self, SimError> {
        let bad = |m: String| SimError::Invalid(format!("knots: {m}"));
        if !(start_mm[0].is_finite() && start_mm[1].is_finite()) {
            return Err(bad(format!("the start {start_mm:?} is not finite")));
        }
        let last = knots.last().ok_or_else(|| bad("there are none".into()))?;
        if last.velocity_mm_s != [0.0; 2] {
            return Err(bad(format!(
                "the last knot (t = {} s) moves at {:?} mm/s: a stream must end at rest",
                f64::from(last.t_us) * 1e-6,
                last.velocity_mm_s
            )));
        }
        let mut segments = Vec::with_capacity(knots.len());
        let (mut t0, mut p0, mut v0) = (0.0, start_mm, [0.0; 2]);
        let mut t0_us = 0u32;
        for (i, k) in knots.iter().enumerate() {
            let p1 = k.position_mm.map(f64::from);
            let v1 = k.velocity_mm_s.map(f64::from);
            if !(p1.iter().chain(&v1).all(|v| v.is_finite())) {
                return Err(bad(format!("knot {i} is not finite")));
            }
            if k.t_us <= t0_us {
                return Err(bad(format!(
                    "knot {i}: times must increase strictly from 0 ({} us after {} us)",
                    k.t_us, t0_us
                )));
            }
            let t1 = f64::from(k.t_us) / 1e6;
            segments.push(Segment::between(t0, p0, v0, t1, p1, v1));
            (t0, p0, v0, t0_us) = (t1, p1, v1, k.t_us);
        }
        Ok(KnotPath {
            start_mm,
            knots: knots.to_vec(),
            segments,
        })
    }

    /// Where the stream starts, at rest (mm).
    pub fn start_mm(&self) -> [f64; 2] {
        self.start_mm
    }

    /// The knots, as streamed.
    pub fn knots(&self) -> &[Knot] {
        &self.knots
    }

    /// The last knot's time (s): where the motion ends.
    pub fn end_s(&self) -> f64 {
        self.segments.last().map_or(0.0, |s| s.t1_s)
    }

    /// The setpoint at `t_s` from the stream's start, with its exact derivatives: at rest at the
    /// start before 0, at rest at the last knot after the end.
    pub fn motion_at(&self, t_s: f64) -> MotionSetpoint<f64> {
        if !(t_s > 0.0) {
            return MotionSetpoint::at_rest(self.start_mm);
        }
        let k = self.segments.partition_point(|s| s.t1_s < t_s);
        match self.segments.get(k) {
            Some(s) => s.at(t_s),
            None => {
                let last = self
                    .knots
                    .last()
                    .map_or(self.start_mm, |k| k.position_mm.map(f64::from));
                MotionSetpoint::at_rest(last)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn knot(t_s: f64, p: [f64; 2], v: [f64; 2]) -> Knot {
        Knot {
            t_us: (t_s * 1e6).round() as u32,
            position_mm: p.map(|x| x as f32),
            velocity_mm_s: v.map(|x| x as f32),
        }
    }

    #[test]
    fn segments_pass_through_the_knots_with_their_velocities_and_hold_at_the_ends() {
        let knots = [
            knot(0.05, [201.0, 1.0], [20.0, 30.0]),
            knot(0.10, [202.0, 3.0], [10.0, 0.0]),
            knot(0.20, [202.5, 3.0], [0.0, 0.0]),
        ];
        let p = KnotPath::new([200.0, 0.0], &knots).unwrap();
        assert_eq!(p.motion_at(-1.0).position_mm, [200.0, 0.0]);
        for k in &knots {
            let t = f64::from(k.t_us) * 1e-6;
            // Both segments meeting at a knot give its position and velocity.
            for s in [p.motion_at(t - 1e-12), p.motion_at(t)] {
                for i in 0..2 {
                    assert!((s.position_mm[i] - f64::from(k.position_mm[i])).abs() < 1e-6);
                    assert!((s.velocity_mm_s[i] - f64::from(k.velocity_mm_s[i])).abs() < 1e-3);
                }
            }
        }
        let end = p.motion_at(5.0);
        assert_eq!(end.position_mm, [202.5, 3.0]);
        assert_eq!(end.velocity_mm_s, [0.0; 2]);
        assert_eq!(p.end_s(), 0.2);
        // The derivatives are the derivatives.
        let (t, h) = (0.073, 1e-6);
        let (lo, mid, hi) = (p.motion_at(t - h), p.motion_at(t), p.motion_at(t + h));
        for i in 0..2 {
            let v = (hi.position_mm[i] - lo.position_mm[i]) / (2.0 * h);
            let a = (hi.velocity_mm_s[i] - lo.velocity_mm_s[i]) / (2.0 * h);
            assert!((v - mid.velocity_mm_s[i]).abs() < 1e-4, "{v} {mid:?}");
            assert!((a - mid.acceleration_mm_s2[i]).abs() < 1e-2, "{a} {mid:?}");
        }
    }

    #[test]
    fn bad_knots_are_refused() {
        let ok = knot(0.1, [1.0, 1.0], [0.0, 0.0]);
        assert!(KnotPath::new([0.0, 0.0], &[]).is_err());
        assert!(KnotPath::new([f64::NAN, 0.0], &[ok]).is_err());
        let moving = knot(0.1, [1.0, 1.0], [1.0, 0.0]);
        let e = KnotPath::new([0.0, 0.0], &[moving])
            .unwrap_err()
            .to_string();
        assert!(e.contains("end at rest"), "{e}");
        let e = KnotPath::new([0.0, 0.0], &[ok, ok])
            .unwrap_err()
            .to_string();
        assert!(e.contains("increase"), "{e}");
        let mut nan = ok;
        nan.velocity_mm_s[0] = f32::NAN;
        assert!(KnotPath::new([0.0, 0.0], &[nan]).is_err());
    }
}
