//! The split: the programmed path timed as the combined machine can follow it, the gantry's
//! share a low-pass filtered copy of it, the micro's the remainder, checked and slowed where
//! the micro would leave its workspace or its limits (the filter-and-reach-check family of
//! splits; docs/design/redundant-planner.md compares it with the others).
//!
//! 1. **Tool.** Every span is timed ([`SpanLaw`]) with the tool's limits: the micro's
//!    acceleration, the feed, the gantry's rapid rate per axis, a corner passed nearly at rest.
//!    Sampled every servo period `Δt`.
//! 2. **Gantry.** Per axis, the tool's sampled motion through two centred moving averages of
//!    `n₁` and `n₂` samples (a FIR filter, zero phase: the gantry is where the tool is on
//!    average over the window around now, so it starts a move before the tool and ends after
//!    it). A moving average of `n` samples bounds its output's change per sample by the input's
//!    range over `n` samples: speed ≤ the tool's, acceleration ≤ (range of speed)/(n₁Δt), jerk
//!    ≤ (range of that acceleration)/(n₂Δt). The windows are the smallest that keep the gantry
//!    within its limits on this plan (grown until the filtered motion's speed, acceleration and
//!    jerk, as sampled, are within them; at worst the ranges' bound, which guarantees it). The
//!    gantry stays in the convex hull of the tool's path, so in its travel, and ends exactly
//!    where the tool ends (a moving average keeps the sum of the steps).
//! 3. **Micro = tool − gantry**, checked at every sample: inside its workspace less the margin
//!    (and [`PLAN_EXTRA_MARGIN_MM`] for the executed motion's error), within its speed and
//!    acceleration. Where it is not, the spans around the sample (within the filter's reach)
//!    are slowed ([`Scale`]: a reach or acceleration violation lowers the acceleration, then
//!    the speed; a speed violation the speed) and the plan is made again. Few spans, few rounds.
//! 4. If it does not converge in [`MAX_ROUNDS`], or is not faster than the gantry alone, the
//!    plan is the gantry alone (the micro then only compensates the gantry's following error).
//!
//! Cost per round: one evaluation of the tool per sample, four running sums per axis, one
//! polygon test per sample: ~0.1 s per 100 s of program.

use super::limits::{PathLimits, Scale};
use super::micro::MicroLimits;
use super::profile::SpanLaw;
use super::timeline::{laws, Cursor, Layout, Timeline};
use serde::Serialize;

/// Extra margin the plan keeps inside the micro's margin for the executed motion (mm).
pub const PLAN_EXTRA_MARGIN_MM: f64 = 0.25;
/// Rounds of slowing down before the plan falls back to the gantry alone.
pub const MAX_ROUNDS: usize = 30;

/// Per-axis limits of the gantry as planned (with headroom).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AxisLimits {
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    pub jerk_mm_s3: f64,
}

/// What the split needs.
#[derive(Clone, Debug)]
pub struct SplitOptions {
    /// The servo period: the plan's sample period (s).
    pub dt_s: f64,
    /// The combined tool's limits along the path.
    pub tool: PathLimits,
    /// The gantry alone's limits along the path (the baseline, and the fallback).
    pub gantry_only: PathLimits,
    /// The gantry's per-axis limits the filter keeps.
    pub gantry: AxisLimits,
    pub micro: MicroLimits,
    /// The micro's speed and acceleration the plan keeps (mm/s, mm/s²).
    pub micro_speed_mm_s: f64,
    pub micro_accel_mm_s2: f64,
}

/// Which plan the machine runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlanMode {
    /// Gantry and micro share the motion.
    Split,
    /// The gantry carries the whole path; the micro only compensates.
    GantryOnly,
}

/// A plan on the servo's time base: sample `k` is at `k·dt_s`; the tool's program time is
/// `(k − lead)·dt_s`.
#[derive(Clone, Debug)]
pub struct Plan {
    pub mode: PlanMode,
    /// Why the plan is the gantry alone (`None` for a split).
    pub fallback: Option<String>,
    pub timeline: Timeline,
    pub dt_s: f64,
    /// Samples the gantry starts before the tool.
    pub lead: usize,
    /// The tool's position at every sample (mm).
    pub tool_mm: Vec<[f64; 2]>,
    /// The gantry's reference at every sample (mm).
    pub gantry_mm: Vec<[f64; 2]>,
    /// The filter's windows per axis `[x, y]`, each `[n₁, n₂]` in seconds.
    pub windows_s: [[f64; 2]; 2],
    /// Rounds of slowing down it took.
    pub rounds: usize,
    /// Spans slowed down.
    pub slowed_spans: usize,
}

impl Plan {
    /// When the tool's program ends (s): the lead and the tool's time.
    pub fn completion_s(&self) -> f64 {
        self.lead as f64 * self.dt_s + self.timeline.duration_s()
    }

    /// When the gantry is at rest at the end too (s).
    pub fn samples(&self) -> usize {
        self.gantry_mm.len()
    }

    /// The gantry's reference velocity, acceleration and jerk at sample `k` (central
    /// differences of the reference, mm/s, mm/s², mm/s³).
    pub fn gantry_derivatives(&self, k: usize) -> [[f64; 2]; 3] {
        derivatives(&self.gantry_mm, k, self.dt_s)
    }
}

/// Central differences of `x` at `k` (held at the ends).
pub fn derivatives(x: &[[f64; 2]], k: usize, dt: f64) -> [[f64; 2]; 3] {
    let n = x.len();
    let at = |i: isize| x[i.clamp(0, n as isize - 1) as usize];
    let k = k as isize;
    let (m2, m1, p0, p1, p2) = (at(k - 2), at(k - 1), at(k), at(k + 1), at(k + 2));
    let mut out = [[0.0; 2]; 3];
    for i in 0..2 {
        out[0][i] = (p1[i] - m1[i]) / (2.0 * dt);
        out[1][i] = (p1[i] - 2.0 * p0[i] + m1[i]) / (dt * dt);
        out[2][i] = (p2[i] - 2.0 * p1[i] + 2.0 * m1[i] - m2[i]) / (2.0 * dt * dt * dt);
    }
    out
}

/// A centred moving average of `n` (odd) samples, zero outside `x`.
fn boxcar(x: &[f64], n: usize) -> Vec<f64> {
    let m = n / 2;
    let len = x.len();
    let mut out = vec![0.0; len];
    let mut sum: f64 = x.iter().take(m.min(len)).sum();
    for k in 0..len {
        if k + m < len {
            sum += x[k + m];
        }
        if k > m {
            sum -= x[k - m - 1];
        }
        out[k] = sum / n as f64;
    }
    out
}

fn odd(n: f64) -> usize {
    let n = n.ceil().max(1.0) as usize;
    n | 1
}

/// The tool sampled from program time 0 to its end: positions, velocities, accelerations.
struct Sampled {
    pos: Vec<[f64; 2]>,
    acc: Vec<[f64; 2]>,
    vel: Vec<[f64; 2]>,
}

fn sample_tool(layout: &Layout, tl: &Timeline, dt: f64) -> Sampled {
    let n = (tl.duration_s() / dt).ceil() as usize + 1;
    let mut s = Sampled {
        pos: Vec::with_capacity(n),
        acc: Vec::with_capacity(n),
        vel: Vec::with_capacity(n),
    };
    let mut c = Cursor::default();
    for k in 0..n {
        let t = tl.at(layout, k as f64 * dt, &mut c);
        s.pos.push(t.position_mm);
        s.vel.push(t.velocity_mm_s);
        s.acc.push(t.accel_mm_s2);
    }
    s
}

/// The filtered gantry of one axis from the tool's per-sample steps `d` (with the lead's rests
/// on both sides): its steps.
fn filter_axis(d: &[f64], n1: usize, n2: usize) -> Vec<f64> {
    boxcar(&boxcar(d, n1), n2)
}

/// Peak |speed|, |acceleration|, |jerk| of a motion given by its per-sample steps.
fn peaks(e: &[f64], dt: f64) -> [f64; 3] {
    let mut p = [0.0f64; 3];
    for k in 0..e.len() {
        p[0] = p[0].max(e[k].abs() / dt);
        if k >= 1 {
            p[1] = p[1].max((e[k] - e[k - 1]).abs() / (dt * dt));
        }
        if k >= 2 {
            p[2] = p[2].max((e[k] - 2.0 * e[k - 1] + e[k - 2]).abs() / (dt * dt * dt));
        }
    }
    p
}

/// The windows `(n₁, n₂)` of one axis for the tool's steps `d` (module doc, step 2).
fn windows(d: &[f64], dt: f64, lim: &AxisLimits) -> (usize, usize) {
    let v: Vec<f64> = d.iter().map(|x| x / dt).collect();
    let vmax = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let (vlo, vhi) = v
        .iter()
        .fold((0.0f64, 0.0f64), |(lo, hi), x| (lo.min(*x), hi.max(*x)));
    // Rest on both sides, as far as the windows reach (the gantry moves before and after).
    let padded = |n: usize| {
        let mut v = vec![0.0; n];
        v.extend_from_slice(d);
        v.extend(std::iter::repeat_n(0.0, n));
        v
    };
    let n2_for = |n1: usize| {
        let h = boxcar(&padded(n1), n1);
        let (alo, ahi) = h.windows(2).fold((0.0f64, 0.0f64), |(lo, hi), w| {
            let a = (w[1] - w[0]) / (dt * dt);
            (lo.min(a), hi.max(a))
        });
        (
            odd(ahi.abs().max(alo.abs()) / (lim.jerk_mm_s3 * dt)),
            odd((ahi - alo) / (lim.jerk_mm_s3 * dt)),
        )
    };
    let mut n1 = odd(vmax / (lim.accel_mm_s2 * dt));
    let mut n2 = n2_for(n1).0;
    for _ in 0..12 {
        let p = peaks(&filter_axis(&padded(n1 + n2), n1, n2), dt);
        if p[1] <= lim.accel_mm_s2 && p[2] <= lim.jerk_mm_s3 {
            return (n1, n2);
        }
        if p[1] > lim.accel_mm_s2 {
            n1 = odd(n1 as f64 * (p[1] / lim.accel_mm_s2).min(2.0) * 1.02);
            n2 = n2_for(n1).0;
        } else {
            n2 = odd(n2 as f64 * (p[2] / lim.jerk_mm_s3).min(2.0) * 1.02);
        }
    }
    // The ranges' bound: guaranteed.
    let n1 = odd((vhi - vlo) / (lim.accel_mm_s2 * dt));
    (n1, n2_for(n1).1)
}

/// The gantry for the sampled tool, and the windows and lead.
struct Filtered {
    gantry: Vec<[f64; 2]>,
    tool: Vec<[f64; 2]>,
    lead: usize,
    win: [(usize, usize); 2],
}

fn filter(tool: &[[f64; 2]], dt: f64, lim: &AxisLimits) -> Filtered {
    let steps = |i: usize| -> Vec<f64> {
        let mut d = vec![0.0; tool.len()];
        for k in 1..tool.len() {
            d[k] = tool[k][i] - tool[k - 1][i];
        }
        d
    };
    let (dx, dy) = (steps(0), steps(1));
    let win = [windows(&dx, dt, lim), windows(&dy, dt, lim)];
    let lead = win.iter().map(|(a, b)| a / 2 + b / 2).max().unwrap_or(0);
    let pad = |d: &[f64]| {
        let mut v = vec![0.0; lead];
        v.extend_from_slice(d);
        v.extend(std::iter::repeat_n(0.0, lead));
        v
    };
    let ex = filter_axis(&pad(&dx), win[0].0, win[0].1);
    let ey = filter_axis(&pad(&dy), win[1].0, win[1].1);
    let n = ex.len();
    let (first, last) = (tool[0], tool[tool.len() - 1]);
    let mut gantry = Vec::with_capacity(n);
    let mut g = first;
    for k in 0..n {
        g[0] += ex[k];
        g[1] += ey[k];
        gantry.push(g);
    }
    // The sums of the steps are the tool's displacement: the gantry ends on the tool's end
    // (to rounding, which this removes).
    if let Some(end) = gantry.last_mut() {
        *end = last;
    }
    let mut full = Vec::with_capacity(n);
    full.extend(std::iter::repeat_n(first, lead));
    full.extend_from_slice(tool);
    full.extend(std::iter::repeat_n(last, lead));
    Filtered {
        gantry,
        tool: full,
        lead,
        win,
    }
}

/// What was wrong at a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Violation {
    Reach,
    Accel,
    Speed,
}

/// Checks the micro = tool − gantry at every sample; the violations found (sample, kind).
fn check_micro(f: &Filtered, s: &Sampled, opts: &SplitOptions) -> Vec<(usize, Violation)> {
    let dt = opts.dt_s;
    let mut out = Vec::new();
    let n = f.gantry.len();
    for k in 0..n {
        let (p, g) = (f.tool[k], f.gantry[k]);
        let m = [p[0] - g[0], p[1] - g[1]];
        if !opts.micro.holds(m, PLAN_EXTRA_MARGIN_MM) {
            out.push((k, Violation::Reach));
            continue;
        }
        let d = derivatives(&f.gantry, k, dt);
        let ti = k.checked_sub(f.lead).filter(|&i| i < s.pos.len());
        let (tv, ta) = ti.map_or(([0.0; 2], [0.0; 2]), |i| (s.vel[i], s.acc[i]));
        let ma = [ta[0] - d[1][0], ta[1] - d[1][1]];
        let mv = [tv[0] - d[0][0], tv[1] - d[0][1]];
        if ma[0].hypot(ma[1]) > opts.micro_accel_mm_s2 {
            out.push((k, Violation::Accel));
        } else if mv[0].hypot(mv[1]) > opts.micro_speed_mm_s {
            out.push((k, Violation::Speed));
        }
    }
    out
}

/// The gantry alone: the tool timed with the gantry's limits, the gantry on the tool.
pub fn gantry_only(layout: &Layout, opts: &SplitOptions, reason: Option<String>) -> Plan {
    let tl = Timeline::new(layout, laws(layout, &opts.gantry_only, None));
    let s = sample_tool(layout, &tl, opts.dt_s);
    Plan {
        mode: PlanMode::GantryOnly,
        fallback: reason,
        timeline: tl,
        dt_s: opts.dt_s,
        lead: 0,
        gantry_mm: s.pos.clone(),
        tool_mm: s.pos,
        windows_s: [[0.0; 2]; 2],
        rounds: 0,
        slowed_spans: 0,
    }
}

/// The split plan of `layout` (module doc), or the gantry alone where the split cannot be made
/// or is not faster; `gantry_only_s` is the gantry alone's time.
pub fn plan(layout: &Layout, opts: &SplitOptions, gantry_only_s: f64) -> Plan {
    let dt = opts.dt_s;
    let n_spans = layout.spans.len();
    let mut scales = vec![Scale::default(); n_spans];
    let mut span_laws: Vec<SpanLaw> = laws(layout, &opts.tool, Some(&scales));
    let mut slowed = vec![false; n_spans];
    for round in 0..MAX_ROUNDS {
        let tl = Timeline::new(layout, span_laws.clone());
        let completion_guess = tl.duration_s();
        if completion_guess >= gantry_only_s {
            break;
        }
        let s = sample_tool(layout, &tl, dt);
        let f = filter(&s.pos, dt, &opts.gantry);
        let bad = check_micro(&f, &s, opts);
        if bad.is_empty() {
            let plan = Plan {
                mode: PlanMode::Split,
                fallback: None,
                dt_s: dt,
                lead: f.lead,
                windows_s: [
                    [f.win[0].0 as f64 * dt, f.win[0].1 as f64 * dt],
                    [f.win[1].0 as f64 * dt, f.win[1].1 as f64 * dt],
                ],
                timeline: tl,
                tool_mm: f.tool,
                gantry_mm: f.gantry,
                rounds: round,
                slowed_spans: slowed.iter().filter(|s| **s).count(),
            };
            if plan.completion_s() < gantry_only_s {
                return plan;
            }
            break;
        }
        // Slow the spans around each violation.
        let times = tl.span_times_s();
        let reach_s = f.lead as f64 * dt;
        let mut mark = vec![None; n_spans];
        for &(k, v) in &bad {
            let t = (k as f64 - f.lead as f64) * dt;
            let (lo, hi) = match v {
                Violation::Accel => (t - dt, t + dt),
                Violation::Reach | Violation::Speed => (t - reach_s, t + reach_s),
            };
            let first = times.partition_point(|&(_, t0, d)| t0 + d < lo);
            for &(span, t0, _) in times[first..].iter().take_while(|(_, t0, _)| *t0 <= hi) {
                let _ = t0;
                let worst = match (mark[span], v) {
                    (Some(Violation::Reach), _) | (_, Violation::Reach) => Violation::Reach,
                    (Some(Violation::Accel), _) | (_, Violation::Accel) => Violation::Accel,
                    _ => Violation::Speed,
                };
                mark[span] = Some(worst);
            }
        }
        let mut any = false;
        for (k, m) in mark.iter().enumerate() {
            let Some(v) = m else { continue };
            let sc = &mut scales[k];
            match v {
                Violation::Reach => {
                    if sc.accel > 0.3 {
                        sc.accel *= 0.7;
                    } else {
                        sc.speed *= 0.85;
                    }
                }
                Violation::Accel => sc.accel *= 0.85,
                Violation::Speed => sc.speed *= 0.85,
            }
            sc.accel = sc.accel.max(1e-3);
            sc.speed = sc.speed.max(1e-3);
            span_laws[k] = layout.law(k, &opts.tool, *sc);
            slowed[k] = true;
            any = true;
        }
        if !any {
            // A violation no span can answer (the micro at rest while the gantry moves).
            return gantry_only(
                layout,
                opts,
                Some("the micro's limits cannot be met by slowing the tool".into()),
            );
        }
    }
    gantry_only(
        layout,
        opts,
        Some("the split is not faster than the gantry alone".into()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_boxcar_keeps_the_sum_and_bounds_the_differences() {
        // Zeros on both ends: the average spreads each value over 21 samples.
        let x: Vec<f64> = (0..200)
            .map(|k| {
                if (20..180).contains(&k) {
                    ((k * 37) % 11) as f64 - 5.0
                } else {
                    0.0
                }
            })
            .collect();
        let y = boxcar(&x, 21);
        let (sx, sy): (f64, f64) = (x.iter().sum(), y.iter().sum());
        assert!((sx - sy).abs() < 1e-9);
        let range = 10.0;
        for w in y.windows(2) {
            assert!((w[1] - w[0]).abs() <= range / 21.0 + 1e-12);
        }
        assert_eq!(boxcar(&[1.0, 2.0, 3.0], 1), vec![1.0, 2.0, 3.0]);
    }

    #[test]
    fn central_differences_of_a_cubic_are_exact() {
        let dt = 1e-3;
        let x: Vec<[f64; 2]> = (0..20)
            .map(|k| {
                let t = k as f64 * dt;
                [t * t * t, 2.0 * t]
            })
            .collect();
        let d = derivatives(&x, 10, dt);
        let t = 10.0 * dt;
        assert!((d[0][0] - (3.0 * t * t + dt * dt)).abs() < 1e-9);
        assert!((d[1][0] - 6.0 * t).abs() < 1e-6);
        assert!((d[2][0] - 6.0).abs() < 1e-3);
        assert!((d[0][1] - 2.0).abs() < 1e-9);
    }
}
