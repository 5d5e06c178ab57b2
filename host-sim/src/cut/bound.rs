//! A lower bound on the time of any plan of a program with the machine's limits: no split, and
//! no gantry alone, can cut the program faster (docs/design/redundant-planner.md derives it).
//!
//! Every plan follows the programmed path and rests where the program makes the tool rest
//! (`timeline`'s rules), so its time is the sum of its spans' and rests' times, and each span
//! can be bounded on its own. For span `k` (length `L`, displacement `Δ`):
//! * **Path:** the tool's acceleration is at most `A = A_micro + √2·A_gantry` (the micro's
//!   rating in any direction plus the gantry's two axes); its tangential part `s̈` and its
//!   centripetal part `v²/R` are each at most `A`. Its speed is at most the feed on feed moves,
//!   and the rapid rate `V` per axis (so `V/max(|uₓ|, |u_y|)` along a line, `√2·V` on an arc).
//!   At a junction turning by `θ` the velocity can jump at most `A·Δt` within one servo sample
//!   (`Δt`), so the speed there is at most `A·Δt / (2 sin(θ/2))`. The fastest motion under
//!   these (no jerk limit at all) is the classic two-pass profile `v*(s) = min(cap(s),
//!   √(c_i² + 2A·|s − s_i|))`, integrated in closed form: `∫ ds / v*`.
//! * **Axes:** each axis moves `|Δᵢ|` from rest to rest with at most `V` (and the feed) and
//!   `A_micro + A_gantry`: the time-optimal profile with the two stages' accelerations added.
//! * **Gantry:** the micro absorbs at most the width `wᵢ` of its workspace (less the margin),
//!   so the gantry moves at least `|Δᵢ| − wᵢ` at most at `V`.
//!
//! The gantry term also holds for a *group* of consecutive steps (their displacement less `wᵢ`,
//! from rest at the program's start), which a row of small holes across the sheet needs: the
//! bound is the best split of the program into groups (dynamic programming over groups of up to
//! [`GROUP_STEPS`] steps), each worth the larger of its steps' sum and its gantry term.

use super::limits::PathLimits;
use super::path::Segment;
use super::timeline::{Layout, Step};
use serde::Serialize;

/// Longest group of consecutive steps the gantry term is computed over.
pub const GROUP_STEPS: usize = 400;

/// The machine's limits as the bound uses them (full limits, no planning headroom).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundLimits {
    /// The rapid rate of each axis: the gantry's speed (mm/s).
    pub axis_speed_mm_s: f64,
    /// The micro's rated acceleration (mm/s², any direction).
    pub micro_accel_mm_s2: f64,
    /// The gantry's acceleration per axis (mm/s²).
    pub gantry_accel_mm_s2: f64,
    /// Widths of the micro's workspace less the margin along x and y (mm).
    pub micro_width_mm: [f64; 2],
    /// The servo sample period (s).
    pub sample_period_s: f64,
}

/// The bound and its parts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Bound {
    /// The lower bound (s).
    pub bound_s: f64,
    /// The sum of the steps' own bounds (path, axes, rests), before grouping (s).
    pub steps_s: f64,
    /// Dwells and beam switches (s).
    pub rests_s: f64,
}

/// The accel-limited time over a segment entered at `w0`, left at `w1`, capped at `cap`
/// (`w0, w1 ≤ cap`, `L > 0`).
fn segment_time_s(len: f64, w0: f64, w1: f64, cap: f64, a: f64) -> f64 {
    let xa = (cap * cap - w0 * w0) / (2.0 * a);
    let xd = len - (cap * cap - w1 * w1) / (2.0 * a);
    if xa <= xd {
        (cap - w0) / a + (xd - xa) / cap + (cap - w1) / a
    } else {
        let x = (w1 * w1 - w0 * w0 + 2.0 * a * len) / (4.0 * a);
        let u = (w0 * w0 + 2.0 * a * x).max(0.0).sqrt();
        ((u - w0) + (u - w1)).max(0.0) / a
    }
}

/// Rest-to-rest time-optimal time over `d` with speed `v` and acceleration `a` (no jerk).
fn rest_to_rest_s(d: f64, v: f64, a: f64) -> f64 {
    if d <= 0.0 {
        0.0
    } else if d >= v * v / a {
        d / v + v / a
    } else {
        2.0 * (d / a).sqrt()
    }
}

/// The time to cover `d` from rest with speed `v` and acceleration `a`, ending at any speed.
fn from_rest_s(d: f64, v: f64, a: f64) -> f64 {
    if d <= 0.0 {
        0.0
    } else if d >= v * v / (2.0 * a) {
        d / v + v / (2.0 * a)
    } else {
        (2.0 * d / a).sqrt()
    }
}

impl BoundLimits {
    fn tool_accel_mm_s2(&self) -> f64 {
        self.micro_accel_mm_s2 + std::f64::consts::SQRT_2 * self.gantry_accel_mm_s2
    }

    /// The path term of span `k` (module doc).
    fn path_s(&self, layout: &Layout, k: usize) -> f64 {
        let span = &layout.spans[k];
        let a = self.tool_accel_mm_s2();
        let moves: Vec<_> = span.moves.iter().map(|&i| &layout.moves[i]).collect();
        let caps: Vec<f64> = moves
            .iter()
            .map(|m| {
                let feed = match m.kind {
                    super::gcode::MoveKind::Rapid => f64::INFINITY,
                    super::gcode::MoveKind::Feed { feed_mm_s } => feed_mm_s,
                };
                match m.segment {
                    Segment::Line { dir, .. } => {
                        feed.min(self.axis_speed_mm_s / dir[0].abs().max(dir[1].abs()).max(1e-12))
                    }
                    Segment::Arc { radius_mm, .. } => feed
                        .min(std::f64::consts::SQRT_2 * self.axis_speed_mm_s)
                        .min((a * radius_mm).sqrt()),
                }
            })
            .collect();
        let n = moves.len();
        // Junction caps: the velocity jump one sample of the full acceleration allows.
        let kink = PathLimits {
            axis_speed_mm_s: self.axis_speed_mm_s,
            accel_mm_s2: a,
            jerk_mm_s3: f64::INFINITY,
            per_axis: false,
            curvature_jerk: false,
            kink_dv_mm_s: a * self.sample_period_s,
        };
        let mut w = vec![0.0; n + 1];
        for i in 1..n {
            w[i] = caps[i - 1]
                .min(caps[i])
                .min(kink.junction(&moves[i - 1].segment, &moves[i].segment));
        }
        for i in 0..n {
            let l = moves[i].segment.length_mm();
            w[i + 1] = w[i + 1].min((w[i] * w[i] + 2.0 * a * l).sqrt());
        }
        for i in (0..n).rev() {
            let l = moves[i].segment.length_mm();
            w[i] = w[i].min((w[i + 1] * w[i + 1] + 2.0 * a * l).sqrt());
        }
        (0..n)
            .map(|i| segment_time_s(moves[i].segment.length_mm(), w[i], w[i + 1], caps[i], a))
            .sum()
    }

    /// The axes term of span `k`.
    fn axes_s(&self, layout: &Layout, k: usize) -> f64 {
        let span = &layout.spans[k];
        let feed = span
            .moves
            .iter()
            .map(|&i| match layout.moves[i].kind {
                super::gcode::MoveKind::Rapid => f64::INFINITY,
                super::gcode::MoveKind::Feed { feed_mm_s } => feed_mm_s,
            })
            .fold(0.0, f64::max);
        let (Some(&first), Some(&last)) = (span.moves.first(), span.moves.last()) else {
            return 0.0;
        };
        let (p, q) = (
            layout.moves[first].segment.start_mm(),
            layout.moves[last].segment.end_mm(),
        );
        let v = self.axis_speed_mm_s.min(feed);
        let a = self.micro_accel_mm_s2 + self.gantry_accel_mm_s2;
        (0..2)
            .map(|i| rest_to_rest_s((q[i] - p[i]).abs(), v, a))
            .fold(0.0, f64::max)
    }

    /// The gantry term of a displacement `d` (from rest if `from_rest`).
    fn gantry_s(&self, d: [f64; 2], from_rest: bool) -> f64 {
        (0..2)
            .map(|i| {
                let x = (d[i].abs() - self.micro_width_mm[i]).max(0.0);
                if from_rest {
                    from_rest_s(x, self.axis_speed_mm_s, self.gantry_accel_mm_s2)
                } else {
                    x / self.axis_speed_mm_s
                }
            })
            .fold(0.0, f64::max)
    }

    /// The bound of a program (module doc).
    pub fn bound(&self, layout: &Layout) -> Bound {
        let mut own = Vec::with_capacity(layout.steps.len());
        let mut ends = Vec::with_capacity(layout.steps.len() + 1);
        ends.push(layout.start_mm);
        let mut rests_s = 0.0;
        let mut at = layout.start_mm;
        for step in &layout.steps {
            match *step {
                Step::Span(k) => {
                    let sp = &layout.spans[k];
                    let end = sp
                        .moves
                        .last()
                        .map_or(at, |&i| layout.moves[i].segment.end_mm());
                    let d = [end[0] - at[0], end[1] - at[1]];
                    let t = self
                        .path_s(layout, k)
                        .max(self.axes_s(layout, k))
                        .max(self.gantry_s(d, false));
                    own.push(t);
                    at = end;
                }
                Step::Rest { seconds, .. } => {
                    own.push(seconds);
                    rests_s += seconds;
                }
            }
            ends.push(at);
        }
        let steps_s: f64 = own.iter().sum();
        // best[m]: the bound of the first m steps.
        let n = own.len();
        let mut prefix = vec![0.0; n + 1];
        for i in 0..n {
            prefix[i + 1] = prefix[i] + own[i];
        }
        let mut best = vec![0.0f64; n + 1];
        for m in 1..=n {
            let mut b = best[m - 1] + own[m - 1];
            let lo = m.saturating_sub(GROUP_STEPS);
            for a in lo..m {
                let d = [ends[m][0] - ends[a][0], ends[m][1] - ends[a][1]];
                let g = self.gantry_s(d, a == 0);
                let group = (prefix[m] - prefix[a]).max(g);
                b = b.max(best[a] + group);
            }
            best[m] = b;
        }
        Bound {
            bound_s: best[n],
            steps_s,
            rests_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cut::gcode::parse_program;
    use crate::gantry_spec::GantrySpec;

    fn limits() -> BoundLimits {
        BoundLimits {
            axis_speed_mm_s: 1500.0,
            micro_accel_mm_s2: 5.0 * 9806.65,
            gantry_accel_mm_s2: 9806.65,
            micro_width_mm: [96.0, 146.0],
            sample_period_s: 0.0005,
        }
    }

    fn bound(text: &str) -> Bound {
        let p = parse_program(text, &GantrySpec::paper()).unwrap();
        limits().bound(&Layout::new(&p))
    }

    #[test]
    fn a_long_cut_is_bounded_by_its_length_over_the_feed() {
        // 1000 mm at 100 mm/s: 10 s plus the ramps at 6.4 g (negligible).
        let b = bound("G0 X100 Y100\nM3\nG1 X1100 F6000\nM5\n");
        let a = 5.0 * 9806.65 + 2f64.sqrt() * 9806.65;
        // Along the diagonal the per-axis rapid rate allows 1500·√2.
        let rapid = rest_to_rest_s(100.0 * 2f64.sqrt(), 1500.0 * 2f64.sqrt(), a);
        // Along x the axis term binds: x's acceleration is the micro's plus the gantry's x.
        let cut = 10.0 + 100.0 / (6.0 * 9806.65);
        assert!(
            (b.bound_s - (rapid + cut)).abs() < 1e-6,
            "{b:?} {rapid} {cut}"
        );
    }

    #[test]
    fn long_moves_are_bounded_by_the_gantry_and_rests_count() {
        // 1400 mm along y: the axis term (6 g) against the gantry's 1254 mm from rest.
        let b = bound("G0 Y1400\nG4 P0.5\n");
        let axis: f64 = 1400.0 / 1500.0 + 1500.0 / (6.0 * 9806.65);
        let gantry = 1254.0 / 1500.0 + 1500.0 / (2.0 * 9806.65);
        let want = axis.max(gantry) + 0.5;
        assert!((b.bound_s - want).abs() < 1e-9, "{b:?}");
        assert_eq!(b.rests_s, 0.5);
        // A row of small moves across the sheet: the group's gantry term binds.
        let mut row = String::new();
        for k in 1..=40 {
            row.push_str(&format!("G0 X{}\nG4 P0.001\n", 25 * k));
        }
        let b = bound(&row);
        assert!(b.bound_s > b.steps_s, "{b:?}");
        assert!(b.bound_s >= (1000.0 - 96.0) / 1500.0);
    }

    #[test]
    fn a_sharp_corner_is_nearly_a_stop() {
        let corner = bound("G0 X10 Y10\nM3\nG1 X60 F30000\nY60\nM5\n");
        let straight = bound("G0 X10 Y10\nM3\nG1 X60 F30000\nM5\nM3\nG1 Y60\nM5\n");
        assert!(corner.bound_s <= straight.bound_s + 1e-12);
        assert!(
            straight.bound_s - corner.bound_s < 2e-3,
            "{corner:?} {straight:?}"
        );
    }
}
