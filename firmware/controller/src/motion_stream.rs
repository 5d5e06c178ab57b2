//! The host link's motion: a planned point-to-point move or a streamed trajectory, played as
//! 2 kHz setpoints with their exact derivatives (a [`SetpointSource`]).
//!
//! # Streamed motion
//! The host sends knots (time, position, velocity in task space: [`Knot`]); between two knots
//! the buffer interpolates a cubic Hermite, whose velocity is quadratic, acceleration linear
//! and jerk constant in the segment, and samples it every 500 µs with those exact derivatives
//! (the servo feeds them forward). The stream starts at the setpoint the machine rests at, at
//! time 0; the first setpoint is one sample later.
//!
//! **Depth and latency.** The buffer holds [`KNOT_SLOTS`] knots (64). A knot moves the machine
//! once the intake has turned its segment into setpoints, at most
//! [`QUEUE_SLOTS`](crate::setpoints::QUEUE_SLOTS)` - 1` = 63 samples = 31.5 ms ahead of the
//! servo: a knot whose time is more than 31.5 ms after the sample it arrives in is never late.
//! The host keeps the buffer ahead by its own latency plus that; with 10 ms segments a full
//! buffer is 640 ms of motion.
//!
//! **Validation, whole.** [`MotionStream::push`] checks every knot of a frame against the one
//! before it before it queues any: finite numbers, strictly increasing time, a segment at most
//! [`MAX_SEGMENT_US`] long, the jerk (constant: exact), the acceleration (linear: its norm is
//! largest at an end, exact), the speed (its norm sampled at [`CHECK_POINTS`] + 1 instants plus
//! the most it can grow between two of them, `a_max·δ/2`: a bound, never an under-estimate),
//! the workspace (per axis the cubic's extremes, exact for the rectangle) and that a controlled
//! stop from each sampled instant ends inside the workspace (the servo loop checks that again
//! at every sample). One bad knot refuses the frame, nothing of it is queued.
//!
//! **End and underrun.** A stream whose last knot has zero velocity ends there at rest (the
//! buffer then holds that point). A stream that runs out of knots while its last knot moves is
//! starved: the source returns `None`, the setpoint queue drains, and the servo loop makes the
//! category-2 controlled stop of [`Fault::Underrun`](crate::fault::Fault::Underrun) (the stop
//! limits) and reports it; the starved stream refuses further knots until
//! [`MotionStream::hold`] (after the fault is reset).
//!
//! # Planned move
//! [`MotionStream::move_to`] plans the time-optimal jerk-limited straight move (kinematics-core's
//! [`PathMotion::line`]) within the stream limits, refused if the target or the path leaves the
//! workspace.
//!
//! Cost: a setpoint is one cubic evaluation (~40 flops); a frame's validation is
//! `8 × 33` stop plans at most. Both run in the intake and link tasks, never in the servo task.
use heapless::Deque;
use kinematics_core::hermite::HermiteCubic;
use kinematics_core::path::Line;
use kinematics_core::trajectory::{MotionSetpoint, PathMotion, TaskLimits};
use link_protocol::{Knot, SegmentRefusal, MAX_SEGMENT_US};

use crate::setpoints::SetpointSource;
use crate::stop::{MotionState, StopLimits, StopProfile, Workspace};

/// Knots the buffer holds (the protocol states it, so that the host knows it).
pub const KNOT_SLOTS: usize = link_protocol::STREAM_BUFFER_KNOTS;
/// Intervals at which a segment's speed and stop are checked.
pub const CHECK_POINTS: u32 = 32;
/// Sample period (µs).
const SAMPLE_US: u32 = 500;

/// What the link's motion must stay within.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StreamLimits {
    /// Speed, acceleration and jerk norms of a planned move (`Settings::stream_limits`).
    pub task: TaskLimits<f32>,
    /// Speed, acceleration and jerk norms of the streamed knots' segments
    /// (`Settings::knot_limits`: the machine's rated acceleration).
    pub knots: TaskLimits<f32>,
    /// The controlled stop (where a stop from any instant must end inside `workspace`).
    pub stop: StopLimits,
    /// Where the tool may go; `None` when running uncorrected (no grid: only the servo's reach
    /// checks bound the motion).
    pub workspace: Option<Workspace>,
}

/// Why a move was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MoveRefusal {
    /// A move or stream is under way, or the stream is starved.
    Busy,
    /// The target is not finite, outside the workspace, or the move cannot be planned.
    Target,
}

/// Why knots were refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PushRefusal {
    /// A knot is invalid: its index in the stream and why.
    Knot(u32, SegmentRefusal),
    /// `first_index` is not the next expected (the expected index).
    Index(u32),
    /// Not enough free slots (the free slots).
    Full(u16),
    /// A move is under way, or the stream starved or was paused (the fault must be reset
    /// first).
    Busy,
}

/// A cubic Hermite segment between two knots, a polynomial in the time since its start
/// (`kinematics_core::hermite`, the formula the host loop plays the same knots with).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Segment {
    t0_us: u32,
    t1_us: u32,
    cubic: HermiteCubic<f32>,
}

impl Segment {
    fn between(from: &Knot, to: &Knot) -> Self {
        let h = (to.t_us - from.t_us) as f32 * 1.0e-6;
        Segment {
            t0_us: from.t_us,
            t1_us: to.t_us,
            cubic: HermiteCubic::between(
                h,
                from.position_mm,
                from.velocity_mm_s,
                to.position_mm,
                to.velocity_mm_s,
            ),
        }
    }

    fn duration_s(&self) -> f32 {
        (self.t1_us - self.t0_us) as f32 * 1.0e-6
    }

    /// The setpoint `tau_s` after the segment's start, with its exact derivatives.
    fn at(&self, tau_s: f32) -> MotionSetpoint<f32> {
        self.cubic.at(tau_s)
    }

    /// Checks the segment against `limits` (see the module doc).
    fn check(&self, limits: &StreamLimits) -> Result<(), SegmentRefusal> {
        let h = self.duration_s();
        let norm = |v: [f32; 2]| libm::hypotf(v[0], v[1]);
        let (start, end) = (self.at(0.0), self.at(h));
        let task = &limits.knots;
        if !(norm(start.jerk_mm_s3) <= task.jerk_mm_s3) {
            return Err(SegmentRefusal::Jerk);
        }
        let accel_max = norm(start.acceleration_mm_s2).max(norm(end.acceleration_mm_s2));
        if !(accel_max <= task.accel_mm_s2) {
            return Err(SegmentRefusal::Acceleration);
        }
        if let Some(w) = &limits.workspace {
            // The segment's bounding box (per axis, the extremes of the cubic: the ends and where
            // its velocity is zero) must lie inside: the workspace is convex, so its four corners
            // inside put the whole box, and the curve in it, inside. Exact for a rectangular
            // workspace; conservative next to a slanted edge of a polygon.
            let ([x0, x1], [y0, y1]) = (self.axis_range(0).into(), self.axis_range(1).into());
            if ![[x0, y0], [x1, y0], [x0, y1], [x1, y1]]
                .iter()
                .all(|&p| w.contains(p))
            {
                return Err(SegmentRefusal::Workspace);
            }
        }
        let step_s = h / CHECK_POINTS as f32;
        let mut speed_max = 0.0f32;
        for i in 0..=CHECK_POINTS {
            let s = self.at(i as f32 * step_s);
            speed_max = speed_max.max(norm(s.velocity_mm_s));
            if let Some(w) = &limits.workspace {
                let state = MotionState {
                    position_mm: s.position_mm,
                    velocity_mm_s: s.velocity_mm_s,
                    accel_mm_s2: s.acceleration_mm_s2,
                };
                if !w.contains(StopProfile::plan(&state, &limits.stop).end_mm()) {
                    return Err(SegmentRefusal::Workspace);
                }
            }
        }
        // Between two checked instants the speed grows by at most accel_max·step/2.
        if !(speed_max + 0.5 * accel_max * step_s <= task.speed_mm_s) {
            return Err(SegmentRefusal::Speed);
        }
        Ok(())
    }

    /// Least and greatest position of axis `k` over the segment (mm).
    fn axis_range(&self, k: usize) -> (f32, f32) {
        let h = self.duration_s();
        let HermiteCubic { a, b, c, d } = &self.cubic;
        let p = |t: f32| a[k] + t * (b[k] + t * (c[k] + t * d[k]));
        let (mut lo, mut hi) = (p(0.0).min(p(h)), p(0.0).max(p(h)));
        // v(τ) = b + 2cτ + 3dτ² = 0.
        let (qa, qb, qc) = (3.0 * d[k], 2.0 * c[k], b[k]);
        let mut roots = [f32::NAN; 2];
        if qa.abs() > f32::EPSILON * (qb.abs() + qc.abs()) {
            let disc = qb * qb - 4.0 * qa * qc;
            if disc >= 0.0 {
                let r = libm::sqrtf(disc);
                roots = [(-qb - r) / (2.0 * qa), (-qb + r) / (2.0 * qa)];
            }
        } else if qb != 0.0 {
            roots[0] = -qc / qb;
        }
        for t in roots {
            if t > 0.0 && t < h {
                lo = lo.min(p(t));
                hi = hi.max(p(t));
            }
        }
        (lo, hi)
    }
}

/// What the link's motion is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Play {
    /// At rest at the knot's position.
    Hold,
    /// A planned move, `sample` samples in.
    Move {
        motion: PathMotion<f32, Line<f32>>,
        target_mm: [f32; 2],
        sample: u32,
    },
    /// Playing knots; `segment` is the one under way (from the last consumed knot to the
    /// buffer's front), `sample` the samples since the stream started.
    Stream {
        segment: Option<Segment>,
        sample: u32,
    },
    /// The stream ran out of knots while moving: no setpoints until [`MotionStream::hold`].
    Starved,
    /// Stopped by the link (a stop, disable or reset was requested): no setpoints until
    /// [`MotionStream::hold`] at the point where the servo loop then is.
    Paused,
}

/// The link's motion source (see the module doc).
#[derive(Clone, Debug)]
pub struct MotionStream {
    limits: StreamLimits,
    knots: Deque<Knot, KNOT_SLOTS>,
    /// The last knot consumed (the start of the segment under way), or the hold point.
    from: Knot,
    /// The last knot accepted (what the next pushed knot continues from).
    tail: Knot,
    /// Knots received in this stream.
    received: u32,
    play: Play,
    underruns: u32,
}

impl MotionStream {
    /// Holding at `position_mm`.
    pub fn new(limits: StreamLimits, position_mm: [f32; 2]) -> Self {
        let rest = Knot {
            t_us: 0,
            position_mm,
            velocity_mm_s: [0.0; 2],
        };
        MotionStream {
            limits,
            knots: Deque::new(),
            from: rest,
            tail: rest,
            received: 0,
            play: Play::Hold,
            underruns: 0,
        }
    }

    /// Drops any move or stream and holds at `position_mm` (after a stop, a reset, an enable:
    /// where the servo loop's setpoint is).
    pub fn hold(&mut self, position_mm: [f32; 2]) {
        *self = MotionStream {
            underruns: self.underruns,
            ..MotionStream::new(self.limits, position_mm)
        };
    }

    /// A move or stream is under way (or starved, or paused).
    pub fn is_moving(&self) -> bool {
        !matches!(self.play, Play::Hold)
    }

    /// Drops any move or stream and produces no setpoints until [`MotionStream::hold`]: the
    /// servo loop is about to stop or re-engage somewhere this source does not know yet.
    pub fn pause(&mut self) {
        self.knots.clear();
        self.received = 0;
        self.play = Play::Paused;
    }

    /// A move or stream is under way or starved (not holding, not paused).
    pub fn is_playing(&self) -> bool {
        matches!(
            self.play,
            Play::Move { .. } | Play::Stream { .. } | Play::Starved
        )
    }

    /// Where it holds, when it holds: the point its last setpoint handed to the queue and
    /// every later one repeats exactly (the servo loop reaches it up to
    /// [`QUEUE_SLOTS`](crate::setpoints::QUEUE_SLOTS) samples later).
    pub fn hold_point_mm(&self) -> Option<[f32; 2]> {
        (self.play == Play::Hold).then_some(self.from.position_mm)
    }

    /// Paused (see [`MotionStream::pause`]).
    pub fn is_paused(&self) -> bool {
        self.play == Play::Paused
    }

    /// The stream ran dry while moving and waits for [`MotionStream::hold`].
    pub fn is_starved(&self) -> bool {
        self.play == Play::Starved
    }

    /// Times a stream ran dry while moving.
    pub fn underruns(&self) -> u32 {
        self.underruns
    }

    /// Knots queued.
    pub fn queued(&self) -> usize {
        self.knots.len()
    }

    /// Free knot slots.
    pub fn free(&self) -> usize {
        KNOT_SLOTS - self.knots.len()
    }

    /// Knots received in this stream (the next `first_index`).
    pub fn next_index(&self) -> u32 {
        self.received
    }

    /// Plans the jerk-limited straight move from the hold point to `target_mm`; returns its
    /// duration (s).
    pub fn move_to(&mut self, target_mm: [f32; 2]) -> Result<f32, MoveRefusal> {
        if self.is_moving() {
            return Err(MoveRefusal::Busy);
        }
        if let Some(w) = &self.limits.workspace {
            // A straight line between two points of a rectangle stays in it.
            if !w.contains(target_mm) {
                return Err(MoveRefusal::Target);
            }
        }
        let motion = PathMotion::line(self.from.position_mm, target_mm, &self.limits.task)
            .map_err(|_| MoveRefusal::Target)?;
        let duration_s = motion.duration_s();
        if !duration_s.is_finite() {
            return Err(MoveRefusal::Target);
        }
        self.play = Play::Move {
            motion,
            target_mm,
            sample: 0,
        };
        Ok(duration_s)
    }

    /// Validates `knots` whole and queues them (see the module doc); `first_index` 0 starts a
    /// stream (from the hold point, only at rest).
    pub fn push(&mut self, first_index: u32, knots: &[Knot]) -> Result<(), PushRefusal> {
        let starting = first_index == 0;
        match self.play {
            Play::Hold if starting => {}
            Play::Stream { .. } if !starting && first_index == self.received => {}
            Play::Hold | Play::Stream { .. } => {
                return Err(PushRefusal::Index(if matches!(self.play, Play::Hold) {
                    0
                } else {
                    self.received
                }))
            }
            Play::Move { .. } | Play::Starved | Play::Paused => return Err(PushRefusal::Busy),
        }
        if knots.len() > self.free() {
            return Err(PushRefusal::Full(self.free() as u16));
        }
        let mut prev = if starting {
            Knot {
                t_us: 0,
                velocity_mm_s: [0.0; 2],
                ..self.from
            }
        } else {
            self.tail
        };
        for (i, k) in knots.iter().enumerate() {
            let index = first_index.saturating_add(i as u32);
            let refuse = |r| PushRefusal::Knot(index, r);
            if !k
                .position_mm
                .iter()
                .chain(k.velocity_mm_s.iter())
                .all(|v| v.is_finite())
            {
                return Err(refuse(SegmentRefusal::NotFinite));
            }
            if k.t_us <= prev.t_us {
                return Err(refuse(SegmentRefusal::Time));
            }
            if k.t_us - prev.t_us > MAX_SEGMENT_US {
                return Err(refuse(SegmentRefusal::TooLong));
            }
            Segment::between(&prev, k)
                .check(&self.limits)
                .map_err(refuse)?;
            prev = *k;
        }
        // All good: queue them.
        if starting {
            self.from = Knot {
                t_us: 0,
                velocity_mm_s: [0.0; 2],
                ..self.from
            };
            self.received = 0;
            self.play = Play::Stream {
                segment: None,
                sample: 0,
            };
        }
        for k in knots {
            // Room was checked above.
            let _ = self.knots.push_back(*k);
        }
        self.tail = prev;
        self.received = self.received.saturating_add(knots.len() as u32);
        Ok(())
    }

    /// The next stream setpoint, at `sample` samples after the stream's start.
    fn stream_setpoint(
        &mut self,
        segment: Option<Segment>,
        sample: u32,
    ) -> Option<MotionSetpoint<f32>> {
        let t_us = sample.saturating_add(1).saturating_mul(SAMPLE_US);
        let mut segment = segment;
        // Advance to the segment containing t (knots are consumed as their time passes).
        loop {
            if let Some(s) = segment {
                if t_us <= s.t1_us {
                    self.play = Play::Stream {
                        segment,
                        sample: sample + 1,
                    };
                    return Some(s.at((t_us - s.t0_us) as f32 * 1.0e-6));
                }
            }
            match self.knots.pop_front() {
                Some(next) => {
                    segment = Some(Segment::between(&self.from, &next));
                    self.from = next;
                }
                None if self.from.velocity_mm_s == [0.0; 2] => {
                    // Ended at rest on the last knot.
                    let end = self.from.position_mm;
                    self.hold(end);
                    return Some(MotionSetpoint::at_rest(end));
                }
                None => {
                    self.play = Play::Starved;
                    self.underruns = self.underruns.saturating_add(1);
                    return None;
                }
            }
        }
    }
}

impl SetpointSource for MotionStream {
    fn next_setpoint(&mut self) -> Option<MotionSetpoint<f32>> {
        match self.play {
            Play::Hold => Some(MotionSetpoint::at_rest(self.from.position_mm)),
            Play::Move {
                motion,
                target_mm,
                sample,
            } => {
                let t_s = (sample + 1) as f32 * (SAMPLE_US as f32 * 1.0e-6);
                if t_s >= motion.duration_s() {
                    self.hold(target_mm);
                    return Some(MotionSetpoint::at_rest(target_mm));
                }
                self.play = Play::Move {
                    motion,
                    target_mm,
                    sample: sample + 1,
                };
                Some(motion.at(t_s))
            }
            Play::Stream { segment, sample } => self.stream_setpoint(segment, sample),
            Play::Starved | Play::Paused => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::settings::Settings;

    const START_MM: [f32; 2] = [212.0, 0.0];

    fn limits() -> StreamLimits {
        let s = Settings::default();
        // As `Settings`: planned moves at 2 g, knots at the rated 5 g.
        StreamLimits {
            task: TaskLimits {
                speed_mm_s: 1500.0,
                accel_mm_s2: 19_620.0,
                jerk_mm_s3: 5.0e6,
            },
            knots: TaskLimits {
                speed_mm_s: 1500.0,
                accel_mm_s2: 49_050.0,
                jerk_mm_s3: 5.0e6,
            },
            stop: s.stop.limits,
            workspace: Workspace::of_grid(
                &kinematics_core::grid::GridGeometry {
                    nx: 2,
                    ny: 2,
                    x0_mm: 167.0,
                    y0_mm: -70.0,
                    step_x_mm: 90.0,
                    step_y_mm: 140.0,
                },
                0.0,
            ),
        }
    }

    fn knot(t_ms: u32, p: [f32; 2], v: [f32; 2]) -> Knot {
        Knot {
            t_us: t_ms * 1000,
            position_mm: p,
            velocity_mm_s: v,
        }
    }

    /// A smooth back-and-forth along x: p = START + A sin²(πt/T), as knots every 10 ms.
    fn sine_knots(n: u32) -> Vec<Knot> {
        let (amp, period_s) = (20.0f32, 0.4f32);
        (1..=n)
            .map(|i| {
                let t = i as f32 * 0.01;
                let w = core::f32::consts::PI / period_s;
                let x = START_MM[0] + amp * libm::sinf(w * t).powi(2);
                let v = amp * w * libm::sinf(2.0 * w * t);
                knot(i * 10, [x, START_MM[1]], [v, 0.0])
            })
            .collect()
    }

    fn drain(s: &mut MotionStream, n: usize) -> Vec<Option<MotionSetpoint<f32>>> {
        (0..n).map(|_| s.next_setpoint()).collect()
    }

    #[test]
    fn hermite_passes_through_the_knots_with_their_velocity_and_exact_derivatives() {
        let mut s = MotionStream::new(limits(), START_MM);
        let k = [
            knot(20, [213.0, 0.5], [100.0, 50.0]),
            knot(40, [214.0, 1.0], [0.0, 0.0]),
        ];
        s.push(0, &k).unwrap();
        let sp: Vec<_> = drain(&mut s, 80).into_iter().map(Option::unwrap).collect();
        // Sample 39 is t = 20 ms (the first knot), sample 79 is 40 ms.
        for (i, kn) in [(39, k[0]), (79, k[1])] {
            for a in 0..2 {
                assert!(
                    (sp[i].position_mm[a] - kn.position_mm[a]).abs() < 1e-4,
                    "{i} {:?}",
                    sp[i]
                );
                assert!(
                    (sp[i].velocity_mm_s[a] - kn.velocity_mm_s[a]).abs() < 1e-2,
                    "{i} {:?}",
                    sp[i]
                );
            }
        }
        // Derivatives: central differences of the positions agree with the velocities, of the
        // velocities with the accelerations (inside a segment).
        let dt = 5.0e-4;
        for i in [5, 22, 45, 70] {
            for a in 0..2 {
                let v = (sp[i + 1].position_mm[a] - sp[i - 1].position_mm[a]) / (2.0 * dt);
                assert!(
                    (v - sp[i].velocity_mm_s[a]).abs() < 0.5,
                    "{i}: {v} vs {:?}",
                    sp[i]
                );
                let acc = (sp[i + 1].velocity_mm_s[a] - sp[i - 1].velocity_mm_s[a]) / (2.0 * dt);
                assert!(
                    (acc - sp[i].acceleration_mm_s2[a]).abs() < 50.0,
                    "{i}: {acc} vs {:?}",
                    sp[i]
                );
            }
        }
        // Ended at rest: holds the last knot.
        assert_eq!(
            s.next_setpoint(),
            Some(MotionSetpoint::at_rest([214.0, 1.0]))
        );
        assert!(!s.is_moving());
    }

    #[test]
    fn a_stream_fed_in_frames_plays_through_and_one_that_runs_dry_moving_starves() {
        let knots = sine_knots(40);
        let mut s = MotionStream::new(limits(), START_MM);
        for (i, chunk) in knots.chunks(8).take(2).enumerate() {
            s.push(i as u32 * 8, chunk).unwrap();
        }
        assert_eq!(s.next_index(), 16);
        // 16 knots = 160 ms = 320 samples; the 16th knot moves (sin(2wt) at 0.16 s != 0).
        let sp = drain(&mut s, 320);
        assert!(sp.iter().all(Option::is_some));
        assert_eq!(s.next_setpoint(), None, "starved while moving");
        assert!(s.is_starved() && s.is_moving());
        assert_eq!(s.underruns(), 1);
        assert_eq!(
            s.push(16, &knots[16..24]),
            Err(PushRefusal::Busy),
            "a starved stream takes no more knots"
        );
        s.hold([213.0, 0.0]);
        assert!(!s.is_moving());
        assert_eq!(
            s.next_setpoint(),
            Some(MotionSetpoint::at_rest([213.0, 0.0]))
        );
    }

    #[test]
    fn knots_are_refused_whole_before_any_is_queued() {
        let mut s = MotionStream::new(limits(), START_MM);
        let good = sine_knots(8);
        let mut cases: Vec<(Vec<Knot>, SegmentRefusal)> = Vec::new();
        let mut bad = good.clone();
        bad[5].position_mm[0] = f32::NAN;
        cases.push((bad, SegmentRefusal::NotFinite));
        let mut bad = good.clone();
        bad[5].t_us = bad[4].t_us;
        cases.push((bad, SegmentRefusal::Time));
        let mut bad = good.clone();
        bad[5].t_us = bad[4].t_us + MAX_SEGMENT_US + 1;
        cases.push((bad, SegmentRefusal::TooLong));
        // A pure parabola (no jerk) at 80 000 mm/s² over the 10 ms segment.
        let mut bad = good.clone();
        let (p4, v4, c) = (bad[4].position_mm[0], bad[4].velocity_mm_s[0], 40_000.0);
        bad[5].position_mm[0] = p4 + v4 * 0.01 + c * 1.0e-4;
        bad[5].velocity_mm_s[0] = v4 + 2.0 * c * 0.01;
        cases.push((bad, SegmentRefusal::Acceleration));
        let mut bad = good.clone();
        bad[5].position_mm[0] = 300.0;
        bad[5].t_us = bad[4].t_us + 900_000; // slow, but outside
        cases.push((bad, SegmentRefusal::Workspace));
        for (bad, why) in cases {
            assert_eq!(s.push(0, &bad), Err(PushRefusal::Knot(5, why)), "{why:?}");
            assert_eq!((s.queued(), s.is_moving()), (0, false), "nothing queued");
            assert_eq!(
                s.next_setpoint(),
                Some(MotionSetpoint::at_rest(START_MM)),
                "nothing moved"
            );
        }
        s.push(0, &good).unwrap();
        assert_eq!(s.queued(), 8);
    }

    #[test]
    fn speed_and_jerk_limits_are_enforced() {
        let mut l = limits();
        let good = sine_knots(8);
        l.knots.speed_mm_s = 100.0; // the sine peaks at 20·π/0.4 = 157 mm/s
        let mut s = MotionStream::new(l, START_MM);
        assert!(matches!(
            s.push(0, &good),
            Err(PushRefusal::Knot(_, SegmentRefusal::Speed))
        ));
        l.knots.speed_mm_s = 1500.0;
        l.knots.jerk_mm_s3 = 1.0e3;
        let mut s = MotionStream::new(l, START_MM);
        assert!(matches!(
            s.push(0, &good),
            Err(PushRefusal::Knot(0, SegmentRefusal::Jerk))
        ));
    }

    #[test]
    fn a_stop_that_would_leave_the_workspace_is_refused() {
        // At 1000 mm/s towards the edge 10 mm away: the stop (5 g) needs ~10 mm more.
        let mut s = MotionStream::new(limits(), [245.0, 0.0]);
        let k = [
            knot(20, [250.0, 0.0], [500.0, 0.0]),
            knot(25, [253.0, 0.0], [700.0, 0.0]),
        ];
        assert_eq!(
            s.push(0, &k),
            Err(PushRefusal::Knot(1, SegmentRefusal::Workspace))
        );
    }

    #[test]
    fn frames_must_follow_on_and_fit() {
        let knots = sine_knots(80);
        let mut s = MotionStream::new(limits(), START_MM);
        assert_eq!(s.push(3, &knots[..8]), Err(PushRefusal::Index(0)));
        s.push(0, &knots[..8]).unwrap();
        assert_eq!(
            s.push(0, &knots[8..16]),
            Err(PushRefusal::Index(8)),
            "no restart while streaming"
        );
        assert_eq!(
            s.push(9, &knots[8..16]),
            Err(PushRefusal::Index(8)),
            "a lost frame is detected"
        );
        for i in 1..8 {
            s.push(i * 8, &knots[i as usize * 8..(i as usize + 1) * 8])
                .unwrap();
        }
        assert_eq!(s.free(), 0);
        assert_eq!(s.push(64, &knots[64..72]), Err(PushRefusal::Full(0)));
        assert_eq!(s.move_to([220.0, 0.0]), Err(MoveRefusal::Busy));
    }

    /// Streamed knots keep the knots' acceleration limit (the machine's rated 5 g), not the
    /// planned moves' (2 g): a sine at about 3.5 g is accepted, and refused for its
    /// acceleration once the knots' limit is the moves'.
    #[test]
    fn knots_keep_their_own_acceleration_limit() {
        // x = 10·(1 − cos 2ωt) mm: peak acceleration 10·(2ω)² ≈ 34 000 mm/s² for ω = π/0.107 s.
        let w = core::f32::consts::PI / 0.107;
        let knots: Vec<Knot> = (1..=20u32)
            .map(|i| {
                let t = i as f32 * 0.01;
                let x = START_MM[0] + 20.0 * libm::sinf(w * t).powi(2);
                let v = 20.0 * w * libm::sinf(2.0 * w * t);
                knot(i * 10, [x, START_MM[1]], [v, 0.0])
            })
            .collect();
        let mut l = limits();
        assert!(l.task.accel_mm_s2 < 25_000.0 && l.knots.accel_mm_s2 > 45_000.0);
        let mut s = MotionStream::new(l, START_MM);
        s.push(0, &knots).unwrap();
        l.knots.accel_mm_s2 = l.task.accel_mm_s2;
        let mut s = MotionStream::new(l, START_MM);
        assert!(matches!(
            s.push(0, &knots),
            Err(PushRefusal::Knot(_, SegmentRefusal::Acceleration))
        ));
    }

    #[test]
    fn a_planned_move_reaches_its_target_within_the_limits() {
        let mut s = MotionStream::new(limits(), START_MM);
        assert_eq!(s.move_to([400.0, 0.0]), Err(MoveRefusal::Target));
        assert_eq!(s.move_to([f32::NAN, 0.0]), Err(MoveRefusal::Target));
        let d = s.move_to([240.0, 30.0]).unwrap();
        assert!(d > 0.0 && d < 1.0, "{d}");
        assert_eq!(s.push(0, &sine_knots(2)), Err(PushRefusal::Busy));
        let n = (d / 5e-4) as usize + 2;
        let sp: Vec<_> = drain(&mut s, n).into_iter().map(Option::unwrap).collect();
        let l = limits().task;
        for p in &sp {
            let v = libm::hypotf(p.velocity_mm_s[0], p.velocity_mm_s[1]);
            let a = libm::hypotf(p.acceleration_mm_s2[0], p.acceleration_mm_s2[1]);
            assert!(
                v <= l.speed_mm_s * 1.001 && a <= l.accel_mm_s2 * 1.001,
                "{p:?}"
            );
        }
        assert_eq!(*sp.last().unwrap(), MotionSetpoint::at_rest([240.0, 30.0]));
        assert!(!s.is_moving());
        // The next stream starts from there.
        s.push(0, &[knot(100, [240.0, 31.0], [0.0, 0.0])]).unwrap();
        let first = s.next_setpoint().unwrap();
        assert!(
            (first.position_mm[0] - 240.0).abs() < 1e-3
                && (first.position_mm[1] - 30.0).abs() < 1e-3
        );
    }
}
