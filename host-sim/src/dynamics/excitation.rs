//! The excitation motion: what the machine runs so that its telemetry separates every dynamic
//! parameter and every effect of the diagnosis' library, as knots a controller accepts.
//!
//! **Shape.** Sums of sinusoids in task space about the workspace's centre (the classic
//! "periodic excitation" of robot identification: smooth, its spectrum chosen, every instant
//! informative), in sections, each faded in and out (sin² over 0.5 s) so that it starts and
//! ends at rest at the centre:
//!
//! | section | frequencies x / y (Hz) | what it separates |
//! |---|---|---|
//! | slow sweep, 8 s | 0.19, 0.43 / 0.27, 0.53 | large excursions over the workspace at low speed (tens of mm/s): Coulomb friction against viscous, the configurations the tool mass and inertias act in |
//! | fast, 8 s | 1.3, 2.3, 3.7 / 1.1, 2.9, 3.4 | the acceleration limit reached on both axes at many configurations and speeds: inertias, tool mass, velocity products, viscous friction, a torque-constant error against an inertia error (friction is not scaled by an inertia) |
//!
//! Each section's amplitude is the largest (down from the workspace's half extents, in steps
//! of 3 %) at which its speed, acceleration and jerk stay within [`ExcitationOptions`]'s
//! limits with 10 % to spare, and a controlled stop from any instant (the stop's deceleration
//! built up at its jerk) ends inside the workspace less the stop margin and [`MARGIN_MM`].
//!
//! **Knots.** The motion is sampled every `knot_s` (50 ms by default: a QEMU UART and a
//! 115 200 Bd link both keep up) and the knot velocities are those of the cubic spline through
//! the sampled positions with zero end velocities, so that the controller's Hermite segments
//! join with continuous acceleration (no torque steps at the knots). The knots, as the
//! controller will play them (`sim::knots::KnotPath`), are then checked exactly: the jerk of
//! every segment, the acceleration at its ends (where a cubic's is largest), the speed and the
//! stop sampled finely. Knot positions are the f32 values streamed.
//!
//! The default limits (2 g, 1.5 m/s, 5·10⁶ mm/s³) are within the controller's stream limits
//! as shipped (5 g for knots, 1.5 m/s, 5·10⁶ mm/s³: `controller::settings`), so a controller
//! as shipped accepts the excitation; `--accel-g` runs it faster. The parameters are linear in the torques: the 5 g
//! feed-forward is identified at 2 g as well.
//!
//! Cost: a few thousand evaluations of the sinusoids per amplitude tried; milliseconds.

use super::DynError;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use crate::sim::knots::KnotPath;
use crate::sim::motions::Trajectory;
use link_protocol::Knot;
use std::f64::consts::{PI, TAU};

/// How far inside the workspace (beyond its stop margin) every stop of the excitation ends (mm).
pub const MARGIN_MM: f64 = 2.0;
/// Share of each limit the sections are designed to (the rest is the spline's and rounding's).
const DESIGN_SHARE: f64 = 0.9;
/// Fade in and out of each section (s).
const FADE_S: f64 = 0.5;
/// Rest after the last knot in the simulated trajectory (s).
const REST_S: f64 = 0.2;

/// The limits and spacing of the excitation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExcitationOptions {
    /// Peak tool acceleration (mm/s²). Default 2 g.
    pub accel_mm_s2: f64,
    /// Peak tool speed (mm/s). Default 1500.
    pub speed_mm_s: f64,
    /// Peak tool jerk (mm/s³). Default 5·10⁶.
    pub jerk_mm_s3: f64,
    /// Knot spacing (s). Default 0.05.
    pub knot_s: f64,
    /// The controlled stop's deceleration (mm/s²) and jerk (mm/s³) the stop-inside check
    /// assumes. Default 5 g built up in 5 ms (the controller's).
    pub stop_decel_mm_s2: f64,
    pub stop_jerk_mm_s3: f64,
    /// Length of each section (s). Default 8.
    pub section_s: f64,
}

impl Default for ExcitationOptions {
    fn default() -> Self {
        let g = STANDARD_GRAVITY_MM_S2;
        ExcitationOptions {
            accel_mm_s2: 2.0 * g,
            speed_mm_s: 1500.0,
            jerk_mm_s3: 5.0e6,
            knot_s: 0.05,
            stop_decel_mm_s2: 5.0 * g,
            stop_jerk_mm_s3: 5.0 * g / 0.005,
            section_s: 8.0,
        }
    }
}

/// One section: frequencies and relative weights per axis.
struct Section<'a> {
    freq_hz: [&'a [f64]; 2],
    weight: [&'a [f64]; 2],
}

const SECTIONS: [Section<'static>; 2] = [
    Section {
        freq_hz: [&[0.19, 0.43], &[0.27, 0.53]],
        weight: [&[1.0, 0.35], &[1.0, 0.35]],
    },
    Section {
        freq_hz: [&[1.3, 2.3, 3.7], &[1.1, 2.9, 3.4]],
        weight: [&[1.0, 0.7, 0.5], &[1.0, 0.7, 0.5]],
    },
];

/// The excitation (see the module doc).
#[derive(Clone, Debug)]
pub struct Excitation {
    /// Where it starts and ends, at rest (mm): the workspace's centre.
    pub start_mm: [f64; 2],
    /// The knots as streamed.
    pub knots: Vec<Knot>,
    /// The same as the controller plays them.
    pub path: KnotPath,
    /// Peaks of the played motion: speed (mm/s), acceleration (mm/s²), jerk (mm/s³).
    pub peak_speed_mm_s: f64,
    pub peak_accel_mm_s2: f64,
    pub peak_jerk_mm_s3: f64,
    /// Each section's amplitude along x and y (mm).
    pub amplitudes_mm: Vec<[f64; 2]>,
}

impl Excitation {
    /// The motion's length (s).
    pub fn duration_s(&self) -> f64 {
        self.path.end_s()
    }

    /// The host loop's trajectory: the knots played as the controller plays them, then at rest.
    pub fn trajectory(&self) -> Trajectory {
        Trajectory::Knots {
            name: "excitation".into(),
            path: self.path.clone(),
            duration_s: self.path.end_s() + REST_S,
        }
    }
}

/// Position, velocity, acceleration and jerk of a faded sum of sinusoids at `t` in a section
/// of length `len_s` (the fade's derivatives included).
fn section_state(s: &Section<'_>, amp_mm: [f64; 2], len_s: f64, t: f64) -> [[f64; 4]; 2] {
    // Fade: e(t) = sin²(πt/2F) rising over [0, F], falling over [len - F, len], 1 between.
    let fade = |u: f64| -> [f64; 4] {
        let w = PI / (2.0 * FADE_S);
        if u <= 0.0 {
            return [0.0; 4];
        }
        if u >= FADE_S {
            return [1.0, 0.0, 0.0, 0.0];
        }
        let sn = (w * u).sin();
        let (s2, c2) = (2.0 * w * u).sin_cos();
        [sn * sn, w * s2, 2.0 * w * w * c2, -4.0 * w * w * w * s2]
    };
    let (a, b) = (fade(t), fade(len_s - t));
    // e = a·b (b's derivatives change sign with the reversed time).
    let bb = [b[0], -b[1], b[2], -b[3]];
    let e = [
        a[0] * bb[0],
        a[1] * bb[0] + a[0] * bb[1],
        a[2] * bb[0] + 2.0 * a[1] * bb[1] + a[0] * bb[2],
        a[3] * bb[0] + 3.0 * a[2] * bb[1] + 3.0 * a[1] * bb[2] + a[0] * bb[3],
    ];
    let mut out = [[0.0; 4]; 2];
    for k in 0..2 {
        // m(t) = Σ w sin(ωt) and its derivatives.
        let mut m = [0.0; 4];
        for (f, w) in s.freq_hz[k].iter().zip(s.weight[k]) {
            let om = TAU * f;
            let (sn, cs) = (om * t).sin_cos();
            m[0] += w * sn;
            m[1] += w * om * cs;
            m[2] -= w * om * om * sn;
            m[3] -= w * om * om * om * cs;
        }
        // Leibniz: (e·m)^(n).
        let d = [
            e[0] * m[0],
            e[1] * m[0] + e[0] * m[1],
            e[2] * m[0] + 2.0 * e[1] * m[1] + e[0] * m[2],
            e[3] * m[0] + 3.0 * e[2] * m[1] + 3.0 * e[1] * m[2] + e[0] * m[3],
        ];
        out[k] = d.map(|v| amp_mm[k] * v);
    }
    out
}

/// Where a controlled stop from (p, v, a) ends at the latest, along v (mm): the speed's
/// distance over the deceleration's build-up (the acceleration still acting) plus the
/// constant-deceleration stop from there. Conservative against the controller's planner.
fn stop_end_mm(p: [f64; 2], v: [f64; 2], a: [f64; 2], o: &ExcitationOptions) -> [f64; 2] {
    let speed = v[0].hypot(v[1]);
    if speed == 0.0 {
        return p;
    }
    let t_ramp = o.stop_decel_mm_s2 / o.stop_jerk_mm_s3;
    let a_along = (a[0] * v[0] + a[1] * v[1]) / speed;
    let v_after = speed + a_along.max(0.0) * t_ramp;
    let d = speed * t_ramp
        + 0.5 * a_along.max(0.0) * t_ramp * t_ramp
        + v_after * v_after / (2.0 * o.stop_decel_mm_s2);
    [p[0] + d * v[0] / speed, p[1] + d * v[1] / speed]
}

/// Whether a section at `amp_mm` keeps the design limits and stays inside (sampled every ms).
fn section_fits(
    s: &Section<'_>,
    amp: [f64; 2],
    c: [f64; 2],
    spec: &MachineSpec,
    o: &ExcitationOptions,
) -> bool {
    let margin = spec.workspace.stop_margin_mm + MARGIN_MM;
    let n = (o.section_s * 1000.0) as usize;
    for i in 0..=n {
        let t = i as f64 * 1e-3;
        let st = section_state(s, amp, o.section_s, t);
        let p = [c[0] + st[0][0], c[1] + st[1][0]];
        let v = [st[0][1], st[1][1]];
        let a = [st[0][2], st[1][2]];
        let j = [st[0][3], st[1][3]];
        if v[0].hypot(v[1]) > DESIGN_SHARE * o.speed_mm_s
            || a[0].hypot(a[1]) > DESIGN_SHARE * o.accel_mm_s2
            || j[0].hypot(j[1]) > DESIGN_SHARE * o.jerk_mm_s3
            || !spec.workspace.region.contains(p, margin)
            || !spec
                .workspace
                .region
                .contains(stop_end_mm(p, v, a, o), margin)
        {
            return false;
        }
    }
    true
}

/// Knot velocities of the cubic spline through `p` (uniform spacing `h`, zero end velocities):
/// `v[i-1] + 4v[i] + v[i+1] = 3(p[i+1] - p[i-1])/h` (continuous acceleration), by the Thomas
/// algorithm.
fn spline_velocities(p: &[f64], h: f64) -> Vec<f64> {
    let n = p.len();
    let mut v = vec![0.0; n];
    if n < 3 {
        return v;
    }
    let m = n - 2;
    let (mut c, mut d) = (vec![0.0; m], vec![0.0; m]);
    for i in 0..m {
        let rhs = 3.0 * (p[i + 2] - p[i]) / h;
        if i == 0 {
            c[0] = 1.0 / 4.0;
            d[0] = rhs / 4.0;
        } else {
            let den = 4.0 - c[i - 1];
            c[i] = 1.0 / den;
            d[i] = (rhs - d[i - 1]) / den;
        }
    }
    for i in (0..m).rev() {
        let next = if i + 1 < m { v[i + 2] } else { 0.0 };
        v[i + 1] = d[i] - c[i] * next;
    }
    v
}

/// Checks `ex`'s played motion against the limits exactly (jerk per segment, acceleration at
/// the segment ends), the speed and the stop every 0.5 ms; returns the peaks.
fn played_peaks(
    path: &KnotPath,
    spec: &MachineSpec,
    o: &ExcitationOptions,
) -> Result<[f64; 3], DynError> {
    let margin = spec.workspace.stop_margin_mm;
    let (mut vmax, mut amax, mut jmax) = (0.0f64, 0.0f64, 0.0f64);
    let n = (path.end_s() / 5e-4).ceil() as usize;
    for i in 0..=n {
        let t = i as f64 * 5e-4;
        let s = path.motion_at(t);
        let v = s.velocity_mm_s[0].hypot(s.velocity_mm_s[1]);
        let a = s.acceleration_mm_s2[0].hypot(s.acceleration_mm_s2[1]);
        vmax = vmax.max(v);
        amax = amax.max(a);
        jmax = jmax.max(s.jerk_mm_s3[0].hypot(s.jerk_mm_s3[1]));
        let end = stop_end_mm(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, o);
        if !spec.workspace.region.contains(end, margin) {
            return Err(DynError::Invalid(format!(
                "the excitation's stop from t = {t:.3} s ends at ({:.2}, {:.2}) mm, outside the workspace",
                end[0], end[1]
            )));
        }
    }
    // A cubic's acceleration is largest at a segment's end: every knot.
    for k in path.knots() {
        let t = f64::from(k.t_us) * 1e-6;
        for s in [path.motion_at(t), path.motion_at(t + 1e-9)] {
            amax = amax.max(s.acceleration_mm_s2[0].hypot(s.acceleration_mm_s2[1]));
            jmax = jmax.max(s.jerk_mm_s3[0].hypot(s.jerk_mm_s3[1]));
        }
    }
    for (what, peak, limit) in [
        ("speed (mm/s)", vmax, o.speed_mm_s),
        ("acceleration (mm/s²)", amax, o.accel_mm_s2),
        ("jerk (mm/s³)", jmax, o.jerk_mm_s3),
    ] {
        if !(peak <= limit) {
            return Err(DynError::Invalid(format!(
                "the excitation's {what} reaches {peak:.4e}, over the limit {limit:.4e}"
            )));
        }
    }
    Ok([vmax, amax, jmax])
}

/// The excitation for `spec`'s machine (see the module doc).
pub fn excitation(spec: &MachineSpec, o: &ExcitationOptions) -> Result<Excitation, DynError> {
    of_sections(spec, o, &SECTIONS)
}

/// The moving machine's check motion: a figure-eight about the workspace's centre (x at
/// [`figure_eight_hz`], y at twice that), faded in and out as the excitation's sections and
/// built the same way (its size the largest within `o`'s limits, its knots checked as the
/// controller plays them), one section of `o.section_s`. Another motion than the excitation's:
/// the following error it shows is not one the identification was fitted to.
pub fn figure_eight(spec: &MachineSpec, o: &ExcitationOptions) -> Result<Excitation, DynError> {
    let hz = figure_eight_hz(o);
    let (x, y) = ([hz], [2.0 * hz]);
    let section = Section {
        freq_hz: [&x, &y],
        weight: [&[1.0], &[1.0]],
    };
    of_sections(spec, o, &[section])
}

/// The figure-eight's lowest frequency along x (Hz): at the 2 g stream limit on the paper
/// machine its size is the acceleration's (1.8 g peak, 870 mm/s).
pub const FIGURE_EIGHT_HZ: f64 = 1.6;

/// The figure-eight's frequency along x (Hz): [`FIGURE_EIGHT_HZ`], or faster where `o`'s
/// acceleration could not be reached within its speed (y, at twice the frequency, peaks at
/// `A·ω` of speed and `A·ω²` of acceleration: both limits meet at `ω = a / v`), so that a
/// figure-eight at 5 g is one (2.6 Hz at 1.5 m/s), not a large slow one the speed limit keeps
/// at 2 g.
pub fn figure_eight_hz(o: &ExcitationOptions) -> f64 {
    FIGURE_EIGHT_HZ.max(o.accel_mm_s2 / (2.0 * TAU * o.speed_mm_s))
}

/// The knot spacing (s) at which the check motion's spline follows the figure-eight:
/// `o.knot_s` at [`FIGURE_EIGHT_HZ`] (a slow link's spacing kept), and at most 1/16 of the
/// faster (y) component's period when the acceleration asks for a faster figure-eight.
pub fn figure_eight_knot_s(o: &ExcitationOptions) -> f64 {
    let hz = figure_eight_hz(o);
    if hz > FIGURE_EIGHT_HZ {
        o.knot_s.min(1.0 / (2.0 * hz * 16.0))
    } else {
        o.knot_s
    }
}

/// The motion of `sections` one after the other (see the module doc).
fn of_sections(
    spec: &MachineSpec,
    o: &ExcitationOptions,
    sections: &[Section<'_>],
) -> Result<Excitation, DynError> {
    for (name, v, lo, hi) in [
        (
            "acceleration (mm/s²)",
            o.accel_mm_s2,
            0.05 * STANDARD_GRAVITY_MM_S2,
            20.0 * STANDARD_GRAVITY_MM_S2,
        ),
        ("speed (mm/s)", o.speed_mm_s, 50.0, 10_000.0),
        ("jerk (mm/s³)", o.jerk_mm_s3, 1e4, 1e9),
        ("knot spacing (s)", o.knot_s, 0.005, 0.2),
        (
            "stop deceleration (mm/s²)",
            o.stop_decel_mm_s2,
            1.0 * STANDARD_GRAVITY_MM_S2,
            100.0 * STANDARD_GRAVITY_MM_S2,
        ),
        ("stop jerk (mm/s³)", o.stop_jerk_mm_s3, 1e4, 1e10),
        ("section length (s)", o.section_s, 2.0 * FADE_S + 0.5, 600.0),
    ] {
        if !(v >= lo && v <= hi) {
            return Err(DynError::Invalid(format!(
                "excitation {name} {v}: must be in [{lo}, {hi}]"
            )));
        }
    }
    let c = spec.workspace.centre_mm();
    if !spec
        .workspace
        .region
        .contains(c, spec.workspace.stop_margin_mm + MARGIN_MM)
    {
        return Err(DynError::Invalid(
            "the workspace's centre is not inside it".into(),
        ));
    }
    let half = spec.workspace.half_mm();
    let mut amplitudes = Vec::new();
    for s in sections {
        // The weights' sum is the peak excursion per unit amplitude.
        let reach = [0, 1].map(|k| half[k] / s.weight[k].iter().sum::<f64>());
        let mut scale = 1.0;
        while !section_fits(s, [reach[0] * scale, reach[1] * scale], c, spec, o) {
            scale *= 0.97;
            if scale < 0.01 {
                return Err(DynError::Invalid(format!(
                    "no excitation fits {}'s workspace within these limits",
                    spec.name
                )));
            }
        }
        amplitudes.push([reach[0] * scale, reach[1] * scale]);
    }
    // Sample the sections one after the other at the knot times (the start, t = 0, is implied).
    let n_per = (o.section_s / o.knot_s).round() as usize;
    let h = o.section_s / n_per as f64;
    let mut pos: [Vec<f64>; 2] = [vec![c[0]], vec![c[1]]];
    for (s, amp) in sections.iter().zip(&amplitudes) {
        for i in 1..=n_per {
            let st = section_state(s, *amp, o.section_s, i as f64 * h);
            for k in 0..2 {
                // The positions streamed are f32; the spline goes through those.
                pos[k].push(f64::from((c[k] + st[k][0]) as f32));
            }
        }
    }
    let vel = [spline_velocities(&pos[0], h), spline_velocities(&pos[1], h)];
    let knots: Vec<Knot> = (1..pos[0].len())
        .map(|i| Knot {
            t_us: (i as f64 * h * 1e6).round() as u32,
            position_mm: [pos[0][i] as f32, pos[1][i] as f32],
            velocity_mm_s: if i + 1 == pos[0].len() {
                [0.0; 2]
            } else {
                [vel[0][i] as f32, vel[1][i] as f32]
            },
        })
        .collect();
    let path = KnotPath::new(c, &knots)?;
    let [vmax, amax, jmax] = played_peaks(&path, spec, o)?;
    Ok(Excitation {
        start_mm: c,
        knots,
        path,
        peak_speed_mm_s: vmax,
        peak_accel_mm_s2: amax,
        peak_jerk_mm_s3: jmax,
        amplitudes_mm: amplitudes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spline_has_continuous_acceleration() {
        let p: Vec<f64> = (0..40).map(|i| (i as f64 * 0.3).sin() * 10.0).collect();
        let v = spline_velocities(&p, 0.05);
        assert_eq!((v[0], v[39]), (0.0, 0.0));
        // The Hermite accelerations at both sides of each interior knot agree.
        for i in 1..39 {
            let acc_end = |j: usize| {
                // Segment j..j+1 at its end: 2c + 6dh.
                let h = 0.05;
                let slope = (p[j + 1] - p[j]) / h;
                let c = (3.0 * slope - 2.0 * v[j] - v[j + 1]) / h;
                let d = (v[j] + v[j + 1] - 2.0 * slope) / (h * h);
                (2.0 * c + 6.0 * d * h, 2.0 * c)
            };
            let (left_end, _) = acc_end(i - 1);
            let (_, right_start) = acc_end(i);
            assert!(
                (left_end - right_start).abs() < 1e-9 * (1.0 + left_end.abs()),
                "{i}"
            );
        }
    }

    /// The excitation reaches the limits it is designed to (within 10 %), stays within them
    /// and the workspace, starts and ends at rest at the centre, on both machines.
    #[test]
    fn the_excitation_uses_and_keeps_the_limits_on_both_machines() {
        for spec in [
            MachineSpec::paper(),
            crate::io::machine_file::parse_machine(include_str!("../../machines/second.toml"))
                .unwrap(),
        ] {
            let o = ExcitationOptions::default();
            let ex = excitation(&spec, &o).unwrap();
            eprintln!(
                "{}: {} knots, {:.1} s, peaks {:.0} mm/s, {:.2} g, {:.2e} mm/s³, amplitudes {:?}",
                spec.name,
                ex.knots.len(),
                ex.duration_s(),
                ex.peak_speed_mm_s,
                ex.peak_accel_mm_s2 / STANDARD_GRAVITY_MM_S2,
                ex.peak_jerk_mm_s3,
                ex.amplitudes_mm
            );
            assert!(ex.peak_accel_mm_s2 <= o.accel_mm_s2);
            // The paper's workspace leaves room for the limit; the second machine's, 80 mm
            // wide, binds first (a stop from speed must end inside it).
            let reached = if spec.name == "paper" { 0.8 } else { 0.4 };
            assert!(
                ex.peak_accel_mm_s2 > reached * o.accel_mm_s2,
                "{}",
                ex.peak_accel_mm_s2
            );
            assert_eq!(ex.knots.last().unwrap().velocity_mm_s, [0.0; 2]);
            let end = ex.path.motion_at(ex.duration_s() + 1.0).position_mm;
            let c = spec.workspace.centre_mm();
            assert!((end[0] - c[0]).hypot(end[1] - c[1]) < 1e-3, "{end:?} {c:?}");
        }
        let tight = ExcitationOptions {
            accel_mm_s2: 1e9,
            ..ExcitationOptions::default()
        };
        assert!(excitation(&MachineSpec::paper(), &tight).is_err());
    }

    /// The check motion: within the limits (checked as played), near the acceleration limit
    /// on both machines, at 2 g and at the rated 5 g (its size set by it: 1.8 g of 2 on the
    /// paper machine), back at rest at
    /// the centre, another motion than the excitation's.
    #[test]
    fn the_figure_eight_keeps_the_limits_and_ends_at_rest() {
        for spec in [
            MachineSpec::paper(),
            crate::io::machine_file::parse_machine(include_str!("../../machines/second.toml"))
                .unwrap(),
        ] {
            let o = ExcitationOptions {
                section_s: 4.0,
                ..ExcitationOptions::default()
            };
            let f = figure_eight(&spec, &o).unwrap();
            assert!(f.peak_accel_mm_s2 <= o.accel_mm_s2);
            assert!(f.peak_accel_mm_s2 > 0.8 * o.accel_mm_s2, "{}", spec.name);
            // At the machine's rated 5 g, with the knots the check motion uses.
            let rated = ExcitationOptions {
                accel_mm_s2: 5.0 * STANDARD_GRAVITY_MM_S2,
                ..o
            };
            let rated = ExcitationOptions {
                knot_s: figure_eight_knot_s(&rated),
                ..rated
            };
            let f5 = figure_eight(&spec, &rated).unwrap();
            eprintln!(
                "FIGURE_EIGHT {}: {:.2} Hz, knots {:.1} ms, peak {:.2} g, {:.0} mm/s",
                spec.name,
                figure_eight_hz(&rated),
                rated.knot_s * 1e3,
                f5.peak_accel_mm_s2 / STANDARD_GRAVITY_MM_S2,
                f5.peak_speed_mm_s
            );
            assert!(f5.peak_accel_mm_s2 <= rated.accel_mm_s2);
            assert!(
                f5.peak_accel_mm_s2 > 0.8 * rated.accel_mm_s2,
                "{}",
                spec.name
            );
            assert!((f.duration_s() - 4.0).abs() < 1e-9);
            let end = f.path.motion_at(f.duration_s() + 1.0).position_mm;
            let c = spec.workspace.centre_mm();
            assert!((end[0] - c[0]).hypot(end[1] - c[1]) < 1e-3, "{end:?} {c:?}");
            assert_ne!(f.knots, excitation(&spec, &o).unwrap().knots);
        }
    }
}
