//! The time law along one span of the path (rest to rest): the path speed as fast as each
//! segment's limits allow, jerk-limited, with exact speed, acceleration and jerk at any time.
//!
//! A span is a chain of segments, each with a speed cap and its own tangential acceleration and
//! jerk limits, and speed caps at the junctions between them (a corner, a change of curvature:
//! [`super::limits`]). The law is the classic look-ahead of a CNC's interpolator:
//! 1. junction speeds start at the smaller cap of the two segments and the junction's own;
//! 2. a backward pass lowers each so that the next one can still be reached within its
//!    segment, a forward pass so that it can be reached from the previous one;
//! 3. inside each segment the speed rises to the highest peak (at most its cap) from which the
//!    exit speed is still reached: rise, cruise, fall.
//!
//! Every change of speed is the time-optimal jerk-limited change between two speeds
//! (trapezoidal or triangular acceleration: `kinematics_core::jerk_profile`'s phases, from one
//! moving state to another), and happens inside one segment, so each segment's limits hold for
//! the whole of it. The result is a list of constant-jerk phases: position, speed,
//! acceleration and jerk are exact polynomials at any time.
//!
//! Why not `kinematics_core::trajectory`: its pieces are rest to rest (a tour stops at every
//! waypoint); a contour runs through its junctions at speed. `JerkProfile` is the special case
//! of one segment from rest to rest (a test checks the two agree).
//!
//! Cost: per segment a few bisections of 60 steps (planning, not per sample).

/// Limits of one segment of a span.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentLimits {
    /// Length (mm, > 0).
    pub length_mm: f64,
    /// Speed cap (mm/s, > 0).
    pub speed_mm_s: f64,
    /// Tangential acceleration limit (mm/s², > 0).
    pub accel_mm_s2: f64,
    /// Tangential jerk limit (mm/s³, > 0).
    pub jerk_mm_s3: f64,
}

/// One phase of constant jerk.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Phase {
    t0_s: f64,
    duration_s: f64,
    s0_mm: f64,
    v0_mm_s: f64,
    a0_mm_s2: f64,
    jerk_mm_s3: f64,
}

/// Path position, speed, acceleration and jerk at one instant.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct PathState {
    pub s_mm: f64,
    pub v_mm_s: f64,
    pub a_mm_s2: f64,
    pub j_mm_s3: f64,
}

/// A span's time law: constant-jerk phases from rest at `s = 0` to rest at its length.
#[derive(Clone, Debug, PartialEq)]
pub struct SpanLaw {
    phases: Vec<Phase>,
    duration_s: f64,
    length_mm: f64,
}

/// Time of the jerk-limited change between speeds differing by `dv` (s).
fn change_time_s(dv: f64, a: f64, j: f64) -> f64 {
    if dv <= 0.0 {
        0.0
    } else if dv >= a * a / j {
        dv / a + a / j
    } else {
        2.0 * (dv / j).sqrt()
    }
}

/// Distance of the change from `v0` to `v1` (mm): the mean speed times its time (the
/// acceleration profile is symmetric).
pub fn change_distance_mm(v0: f64, v1: f64, a: f64, j: f64) -> f64 {
    0.5 * (v0 + v1) * change_time_s((v1 - v0).abs(), a, j)
}

/// The largest speed from which `v_end` is reached within `length` (or reachable from
/// `v_end` within it: the change is symmetric).
fn reachable_mm_s(v_end: f64, length: f64, a: f64, j: f64) -> f64 {
    let (mut lo, mut hi) = (v_end, v_end + (2.0 * a * length).sqrt() * 1.01 + 1e-9);
    if change_distance_mm(v_end, hi, a, j) <= length {
        return hi;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if change_distance_mm(v_end, mid, a, j) <= length {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Appends the phases of the change from `v0` to `v1` starting at `(t, s)`; returns the end.
fn push_change(
    phases: &mut Vec<Phase>,
    t: f64,
    s: f64,
    v0: f64,
    v1: f64,
    a: f64,
    j: f64,
) -> (f64, f64) {
    let dv = (v1 - v0).abs();
    if dv <= 0.0 {
        return (t, s);
    }
    let sign = if v1 > v0 { 1.0 } else { -1.0 };
    let (tj, tc) = if dv >= a * a / j {
        (a / j, dv / a - a / j)
    } else {
        ((dv / j).sqrt(), 0.0)
    };
    let mut state = (t, s, v0, 0.0);
    for (dur, jerk) in [(tj, sign * j), (tc, 0.0), (tj, -sign * j)] {
        if dur <= 0.0 {
            continue;
        }
        let (t0, s0, v, acc) = state;
        phases.push(Phase {
            t0_s: t0,
            duration_s: dur,
            s0_mm: s0,
            v0_mm_s: v,
            a0_mm_s2: acc,
            jerk_mm_s3: jerk,
        });
        let e = eval(&phases[phases.len() - 1], dur);
        state = (t0 + dur, e.s_mm, e.v_mm_s, e.a_mm_s2);
    }
    // End exactly at v1 with zero acceleration (the phases are exact up to rounding).
    (state.0, state.1)
}

fn eval(p: &Phase, u: f64) -> PathState {
    let j = p.jerk_mm_s3;
    PathState {
        s_mm: p.s0_mm + u * (p.v0_mm_s + u * (0.5 * p.a0_mm_s2 + u * j / 6.0)),
        v_mm_s: p.v0_mm_s + u * (p.a0_mm_s2 + 0.5 * u * j),
        a_mm_s2: p.a0_mm_s2 + u * j,
        j_mm_s3: j,
    }
}

impl SpanLaw {
    /// The law through `segments` with `junction_caps[k]` the speed cap between segment `k`
    /// and `k + 1` (see the module doc). Segments of no length are not allowed (the caller
    /// drops them); an empty span rests.
    pub fn plan(segments: &[SegmentLimits], junction_caps: &[f64]) -> SpanLaw {
        let n = segments.len();
        let length_mm: f64 = segments.iter().map(|s| s.length_mm).sum();
        if n == 0 {
            return SpanLaw {
                phases: Vec::new(),
                duration_s: 0.0,
                length_mm: 0.0,
            };
        }
        // 1. Junction speeds w[0] = 0 .. w[n] = 0.
        let mut w = vec![0.0; n + 1];
        for k in 1..n {
            w[k] = segments[k - 1]
                .speed_mm_s
                .min(segments[k].speed_mm_s)
                .min(junction_caps.get(k - 1).copied().unwrap_or(0.0))
                .max(0.0);
        }
        // 2. Backward, then forward.
        for k in (0..n).rev() {
            let s = &segments[k];
            w[k] = w[k].min(reachable_mm_s(
                w[k + 1],
                s.length_mm,
                s.accel_mm_s2,
                s.jerk_mm_s3,
            ));
        }
        for k in 0..n {
            let s = &segments[k];
            w[k + 1] = w[k + 1].min(reachable_mm_s(
                w[k],
                s.length_mm,
                s.accel_mm_s2,
                s.jerk_mm_s3,
            ));
        }
        // 3. Each segment: rise, cruise, fall.
        let mut phases = Vec::with_capacity(7 * n);
        let (mut t, mut s0) = (0.0, 0.0);
        for (k, seg) in segments.iter().enumerate() {
            let (a, j, len) = (seg.accel_mm_s2, seg.jerk_mm_s3, seg.length_mm);
            let (win, wout) = (w[k], w[k + 1]);
            let need =
                |u: f64| change_distance_mm(win, u, a, j) + change_distance_mm(u, wout, a, j);
            let floor = win.max(wout);
            let peak = if need(seg.speed_mm_s) <= len {
                seg.speed_mm_s.max(floor)
            } else {
                let (mut lo, mut hi) = (floor, seg.speed_mm_s.max(floor));
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if need(mid) <= len {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                lo
            };
            let (t1, _) = push_change(&mut phases, t, s0, win, peak, a, j);
            let d_up = change_distance_mm(win, peak, a, j);
            let d_down = change_distance_mm(peak, wout, a, j);
            let cruise = if peak > 0.0 {
                ((len - d_up - d_down) / peak).max(0.0)
            } else {
                0.0
            };
            let mut t2 = t1;
            if cruise > 0.0 {
                phases.push(Phase {
                    t0_s: t1,
                    duration_s: cruise,
                    s0_mm: s0 + d_up,
                    v0_mm_s: peak,
                    a0_mm_s2: 0.0,
                    jerk_mm_s3: 0.0,
                });
                t2 += cruise;
            }
            let (t3, _) = push_change(&mut phases, t2, s0 + len - d_down, peak, wout, a, j);
            t = t3;
            s0 += len;
        }
        SpanLaw {
            phases,
            duration_s: t,
            length_mm,
        }
    }

    /// Duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// Length (mm).
    pub fn length_mm(&self) -> f64 {
        self.length_mm
    }

    /// The state at `t_s` from the span's start (at rest before and after), with `hint` the
    /// phase index to search from (returned updated: samples in time order cost O(1)).
    pub fn at(&self, t_s: f64, hint: &mut usize) -> PathState {
        if self.phases.is_empty() || !(t_s > 0.0) {
            return PathState::default();
        }
        if t_s >= self.duration_s {
            return PathState {
                s_mm: self.length_mm,
                ..PathState::default()
            };
        }
        let mut i = (*hint).min(self.phases.len() - 1);
        if self.phases[i].t0_s > t_s {
            i = 0;
        }
        while i + 1 < self.phases.len() && self.phases[i + 1].t0_s <= t_s {
            i += 1;
        }
        *hint = i;
        let p = &self.phases[i];
        let mut e = eval(p, (t_s - p.t0_s).min(p.duration_s));
        e.s_mm = e.s_mm.clamp(0.0, self.length_mm);
        e.v_mm_s = e.v_mm_s.max(0.0);
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::jerk_profile::{JerkProfile, ProfileLimits};

    fn seg(length_mm: f64, speed: f64, accel: f64, jerk: f64) -> SegmentLimits {
        SegmentLimits {
            length_mm,
            speed_mm_s: speed,
            accel_mm_s2: accel,
            jerk_mm_s3: jerk,
        }
    }

    /// Samples a law and checks it is continuous, within every segment's limits, and ends at
    /// rest at the span's length.
    fn check(law: &SpanLaw, segs: &[SegmentLimits], caps: &[f64]) {
        let n = 20_000;
        let dt = law.duration_s() / n as f64;
        let mut hint = 0;
        let mut prev = law.at(0.0, &mut hint);
        let bounds: Vec<f64> = segs
            .iter()
            .scan(0.0, |acc, s| {
                *acc += s.length_mm;
                Some(*acc)
            })
            .collect();
        for k in 1..=n {
            let st = law.at(k as f64 * dt, &mut hint);
            let idx = bounds
                .iter()
                .position(|&b| st.s_mm <= b + 1e-9)
                .unwrap_or(segs.len() - 1);
            let sg = &segs[idx];
            assert!(
                st.v_mm_s <= sg.speed_mm_s * (1.0 + 1e-9) + 1e-9,
                "speed at {k}"
            );
            assert!(
                st.a_mm_s2.abs() <= sg.accel_mm_s2 * (1.0 + 1e-9),
                "accel at {k}"
            );
            assert!(st.s_mm >= prev.s_mm - 1e-12, "monotone at {k}");
            assert!((st.v_mm_s - prev.v_mm_s).abs() <= sg.accel_mm_s2 * dt * 1.01 + 1e-9);
            prev = st;
        }
        assert!((prev.s_mm - law.length_mm()).abs() < 1e-9);
        assert_eq!(prev.v_mm_s, 0.0);
        // At each junction the speed is within its cap.
        let mut hint = 0;
        for (k, &b) in bounds.iter().take(caps.len()).enumerate() {
            // Find the crossing time by bisection.
            let (mut lo, mut hi) = (0.0, law.duration_s());
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if law.at(mid, &mut hint).s_mm < b {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let v = law.at(hi, &mut hint).v_mm_s;
            assert!(
                v <= caps[k] * (1.0 + 1e-6) + 1e-6,
                "junction {k}: {v} > {}",
                caps[k]
            );
        }
    }

    #[test]
    fn one_segment_rest_to_rest_is_the_time_optimal_profile() {
        for (len, v, a, j) in [
            (100.0, 1500.0, 9806.65, 2e5),
            (5.0, 1500.0, 44_000.0, 5e7),
            (0.01, 300.0, 9806.65, 2e5),
            (800.0, 1200.0, 30_000.0, 1e6),
        ] {
            let law = SpanLaw::plan(&[seg(len, v, a, j)], &[]);
            let want = JerkProfile::plan(
                len,
                &ProfileLimits {
                    velocity: v,
                    acceleration: a,
                    jerk: j,
                },
            )
            .unwrap()
            .duration_s();
            assert!(
                (law.duration_s() - want).abs() < 1e-9 * want + 1e-12,
                "{len}: {} vs {want}",
                law.duration_s()
            );
            check(&law, &[seg(len, v, a, j)], &[]);
        }
    }

    #[test]
    fn chains_keep_every_segment_and_junction_limit() {
        let segs = [
            seg(30.0, 500.0, 20_000.0, 1e6),
            seg(4.0, 80.0, 5_000.0, 2e5),
            seg(60.0, 800.0, 30_000.0, 2e6),
            seg(0.5, 800.0, 30_000.0, 2e6),
            seg(25.0, 300.0, 10_000.0, 5e5),
        ];
        let caps = [40.0, f64::INFINITY, 10.0, 200.0];
        let law = SpanLaw::plan(&segs, &caps);
        check(&law, &segs, &caps);
        // Faster than stopping at every junction.
        let stops: f64 = segs
            .iter()
            .map(|s| SpanLaw::plan(&[*s], &[]).duration_s())
            .sum();
        assert!(law.duration_s() < stops);
        // A zero cap is a stop, and equals planning the two parts apart.
        let law0 = SpanLaw::plan(&segs[..2], &[0.0]);
        let apart = SpanLaw::plan(&segs[..1], &[]).duration_s()
            + SpanLaw::plan(&segs[1..2], &[]).duration_s();
        assert!((law0.duration_s() - apart).abs() < 1e-9);
    }
}
