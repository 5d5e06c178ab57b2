//! The controlled stop: bring a moving machine to rest along its path at its deceleration
//! limit (stop categories 1 and 2 of IEC 60204-1; SS1 and SS2 of IEC 61800-5-2).
//!
//! # Where the stop goes: in task space, along the current velocity
//! The stop continues the last accepted setpoint's motion on the straight line of its velocity
//! and brakes along it. Why task space rather than braking each joint on its own: the path is
//! the one the setpoint stream was already on (for the built-in trajectory, the straight move
//! between two waypoints), and a straight segment between two points of the calibrated
//! rectangle lies inside it (the rectangle is convex), so checking the **end point** is enough
//! to keep the whole stop in the workspace. Joint-space braking curves the tool path in a way
//! that depends on the pose, and a curved path has to be checked point by point. The servo
//! still checks every stop setpoint (reach, singularity margin, grid) like any other; one it
//! refuses ends the stop in category 0 (see `servo_loop`), which the end-point check makes a
//! fallback that the workspace never needs.
//!
//! The servo loop checks, for **every** setpoint it accepts, that the stop from there would end
//! inside the workspace ([`Workspace`], the grid's rectangle less a margin); a setpoint whose
//! stop would not is refused (a limit violation: `Fault::StopOutsideWorkspace`) and the machine
//! stops from the previous one, whose stop was checked. So a stream that heads for the edge too
//! fast is stopped early enough, whatever its source.
//!
//! # The profile
//! One dimension along the unit vector `u` of the velocity, from speed `w0` and tangential
//! acceleration `α0` (the normal component of a curved path's acceleration is dropped in the
//! first sample: an acceleration step within the servo's limit, never a velocity step). The
//! deceleration is built up with jerk `J` to its peak `A` (the configured deceleration, or the
//! current one if that is already harder), held, and released with jerk `J` so that speed and
//! acceleration reach zero together:
//!
//! ```text
//!   a(t):  α0 ╲                                ╱ 0
//!               ╲ -J                       +J ╱
//!                ╲___________________________╱
//!                 -A       (t2, may be 0)
//!            t1 = (α0 + A)/J          t3 = A/J
//! ```
//! When `w0` is too small to reach `A`, the profile is triangular with peak
//! `A' = sqrt(J·w0 + α0²/2)`. When the motion is already decelerating so hard that ramping it
//! out at `J` would reverse it (`α0 < 0`, `α0² > 2·J·w0`, the end of a rest-to-rest move), the
//! jerk is raised to `α0²/(2·w0)`, which only finishes what the source started.
//!
//! # Stopping distance
//! Exact: [`StopProfile::distance_mm`]. The stated figure, [`stopping_distance_bound_mm`]: for
//! a motion not accelerating along its path (`α0 ≤ 0`) `s ≤ w0²/(2A) + w0·A/(2J)`, equal when
//! `α0 = 0`; still accelerating (`α0 > 0`), the acceleration is ramped out first, from speed
//! `w' = w0 + α0²/(2J)`: `s ≤ w0·α0/J + α0³/(3J²) + w'²/(2A) + w'·A/(2J)` (equal when the
//! deceleration reaches `A`; by the AM-GM inequality a bound when it does not). Defaults (5 g,
//! built up in 5 ms): 22.9 mm and 33 ms from the built-in tour's top speed of 1.38 m/s; 26.7 mm
//! from 1.5 m/s; 99 mm from the servo's 3 m/s limit. Cost of a plan: two square roots, a handful
//! of divisions (run once per sample in `servo_loop` for the workspace check).
use kinematics_core::{ConvexWorkspace, CorrectionGrid, GridGeometry};

/// Below this speed (mm/s) a motion is at rest: stopping it is holding its position, a velocity
/// step of at most 0.1 mm/s (0.05 µm in one 0.5 ms sample).
pub const REST_SPEED_MM_S: f32 = 0.1;

/// Limits of a controlled stop.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StopLimits {
    /// Peak deceleration along the path (mm/s²).
    pub decel_mm_s2: f32,
    /// Rate at which the deceleration is built up and released (mm/s³).
    pub jerk_mm_s3: f32,
}

/// The controlled stop's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StopSettings {
    /// Deceleration and jerk. Default 5 g (what the servo is specified to follow: it accepts
    /// setpoint sequences up to 5 g + 5 %), built up in 5 ms (jerk 9.8·10⁶ mm/s³, about 7x the
    /// built-in trajectory's).
    pub limits: StopLimits,
    /// A stop must end at least this far inside the calibrated rectangle (mm). Default 0.1 mm,
    /// well above the servo's following error (about 20 µm during a 5 g stop).
    pub workspace_margin_mm: f32,
    /// Category 1: after the profile, torque is removed once both joints are slower than this
    /// (rad/s; the encoder difference over one sample). Default 0.01 rad/s (1.5 mm/s at the
    /// 150 mm links; one count per sample is 3·10⁻³ rad/s).
    pub standstill_rad_s: f32,
    /// Category 1: ... or at the latest this long after the profile ended (s). Default 50 ms.
    pub settle_timeout_s: f32,
}

impl Default for StopSettings {
    fn default() -> Self {
        let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
        StopSettings {
            limits: StopLimits {
                decel_mm_s2: 5.0 * g,
                jerk_mm_s3: 5.0 * g / 5.0e-3,
            },
            workspace_margin_mm: 0.1,
            standstill_rad_s: 0.01,
            settle_timeout_s: 0.05,
        }
    }
}

impl StopSettings {
    /// Every field finite and positive (the margin may be zero); the deceleration within
    /// `max_accel_mm_s2 / 1.02`, the servo's acceptance limit less room for f32 rounding of the
    /// setpoints (about 120 mm/s² in a second difference near 250 mm), or the stop's own
    /// setpoints would be refused as jumps. Returns the name of the first bad field.
    pub fn validate(&self, max_accel_mm_s2: f32) -> Result<(), &'static str> {
        let positive = |v: f32| v.is_finite() && v > 0.0;
        if !positive(self.limits.decel_mm_s2)
            || !(self.limits.decel_mm_s2 * 1.02 <= max_accel_mm_s2)
        {
            return Err("stop.limits.decel_mm_s2");
        }
        if !positive(self.limits.jerk_mm_s3) {
            return Err("stop.limits.jerk_mm_s3");
        }
        if !(self.workspace_margin_mm.is_finite() && self.workspace_margin_mm >= 0.0) {
            return Err("stop.workspace_margin_mm");
        }
        if !positive(self.standstill_rad_s) {
            return Err("stop.standstill_rad_s");
        }
        if !(self.settle_timeout_s.is_finite() && self.settle_timeout_s >= 0.0) {
            return Err("stop.settle_timeout_s");
        }
        Ok(())
    }
}

/// Where the last accepted setpoint is and where it is going.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionState {
    /// Position (mm).
    pub position_mm: [f32; 2],
    /// Velocity at that position (mm/s).
    pub velocity_mm_s: [f32; 2],
    /// Acceleration (mm/s²).
    pub accel_mm_s2: [f32; 2],
}

impl MotionState {
    /// At rest at `position_mm`.
    pub fn at_rest(position_mm: [f32; 2]) -> Self {
        MotionState {
            position_mm,
            velocity_mm_s: [0.0; 2],
            accel_mm_s2: [0.0; 2],
        }
    }

    /// From the backward differences the servo computes for a setpoint
    /// (`kinematics_core::AcceptedSetpoint`): the first is the mean velocity over the last
    /// sample, i.e. the velocity half a sample ago, so the velocity at the setpoint is that plus
    /// `accel·dt/2`. With it the first stop setpoint continues the sequence without an
    /// acceleration step.
    pub fn from_differences(
        position_mm: [f32; 2],
        velocity_mm_s: [f32; 2],
        accel_mm_s2: [f32; 2],
        dt_s: f32,
    ) -> Self {
        let half = 0.5 * dt_s;
        MotionState {
            position_mm,
            velocity_mm_s: [
                velocity_mm_s[0] + accel_mm_s2[0] * half,
                velocity_mm_s[1] + accel_mm_s2[1] * half,
            ],
            accel_mm_s2,
        }
    }

    /// Speed (mm/s).
    pub fn speed_mm_s(&self) -> f32 {
        libm::hypotf(self.velocity_mm_s[0], self.velocity_mm_s[1])
    }

    /// At rest: slower than [`REST_SPEED_MM_S`] (or not a number).
    pub fn is_at_rest(&self) -> bool {
        !(self.speed_mm_s() > REST_SPEED_MM_S)
    }
}

/// Where a stop may end: the machine's workspace polygon from the calibration image's workspace
/// block (`kinematics_core::grid`, "Extension blocks"), or the grid's rectangle when the image
/// has none; less a margin. Convex either way, so a straight stop that ends inside stays inside
/// (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Workspace {
    region: ConvexWorkspace<f32>,
    /// How far inside `region` a stop must end (mm).
    margin_mm: f32,
}

impl Workspace {
    /// The rectangle a correction grid covers, shrunk by `margin_mm` on every side. `None` for a
    /// geometry without area (a validated grid always has some).
    pub fn of_grid(g: &GridGeometry, margin_mm: f32) -> Option<Self> {
        let max_x = g.x0_mm + g.step_x_mm * (g.nx.saturating_sub(1)) as f32;
        let max_y = g.y0_mm + g.step_y_mm * (g.ny.saturating_sub(1)) as f32;
        let region = ConvexWorkspace::rectangle([g.x0_mm, max_x], [g.y0_mm, max_y]).ok()?;
        Some(Workspace { region, margin_mm })
    }

    /// The workspace of a calibration image: its workspace block's polygon with the larger of
    /// the block's stop margin (the machine's soft limit) and `margin_mm` (the firmware's
    /// setting, [`StopSettings::workspace_margin_mm`]); without a block, [`Self::of_grid`].
    pub fn of_image(grid: &CorrectionGrid<'_>, margin_mm: f32) -> Option<Self> {
        match grid.workspace() {
            Some(limits) => Some(Workspace {
                region: limits.region,
                margin_mm: limits.stop_margin_mm.max(margin_mm),
            }),
            None => Self::of_grid(grid.geometry(), margin_mm),
        }
    }

    /// The workspace of a calibration image on the machine `machine` (its record's workspace,
    /// `Settings::machine`): the image's block when it has one (judged inside the machine's);
    /// without one, the machine's polygon where the grid covers it (a stop must end where the
    /// grid corrects), else the grid's rectangle ([`Self::of_image`]).
    pub fn of_machine_image(
        grid: &CorrectionGrid<'_>,
        machine: &ConvexWorkspace<f32>,
        margin_mm: f32,
    ) -> Option<Self> {
        if grid.workspace().is_none() && grid.geometry().covers(machine) {
            return Some(Workspace {
                region: *machine,
                margin_mm,
            });
        }
        Self::of_image(grid, margin_mm)
    }

    /// Whether `p_mm` is inside, at least the margin from every edge (on it counts; NaN does
    /// not).
    pub fn contains(&self, p_mm: [f32; 2]) -> bool {
        self.region.contains(p_mm, self.margin_mm)
    }

    /// The margin in force (mm).
    pub fn margin_mm(&self) -> f32 {
        self.margin_mm
    }

    /// The polygon (before the margin).
    pub fn region(&self) -> &ConvexWorkspace<f32> {
        &self.region
    }
}

/// A planned stop: positions along a straight line from the state it was planned from.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StopProfile {
    origin_mm: [f32; 2],
    direction: [f32; 2],
    speed0_mm_s: f32,
    accel0_mm_s2: f32,
    jerk_mm_s3: f32,
    peak_decel_mm_s2: f32,
    /// Phase durations (s): deceleration built up, held, released.
    t_s: [f32; 3],
    /// Distance and speed at the end of phases 1 and 2.
    s1_mm: f32,
    w1_mm_s: f32,
    s2_mm: f32,
    w2_mm_s: f32,
    distance_mm: f32,
}

impl StopProfile {
    /// The stop from `state` within `limits`. A state at rest (or not finite) gives an empty
    /// stop: hold the position.
    pub fn plan(state: &MotionState, limits: &StopLimits) -> Self {
        let mut p = StopProfile {
            origin_mm: state.position_mm,
            direction: [0.0; 2],
            speed0_mm_s: 0.0,
            accel0_mm_s2: 0.0,
            jerk_mm_s3: limits.jerk_mm_s3,
            peak_decel_mm_s2: 0.0,
            t_s: [0.0; 3],
            s1_mm: 0.0,
            w1_mm_s: 0.0,
            s2_mm: 0.0,
            w2_mm_s: 0.0,
            distance_mm: 0.0,
        };
        let w0 = state.speed_mm_s();
        let finite = w0.is_finite() && (state.accel_mm_s2[0] + state.accel_mm_s2[1]).is_finite();
        if !(w0 > REST_SPEED_MM_S)
            || !finite
            || !(limits.jerk_mm_s3 > 0.0)
            || !(limits.decel_mm_s2 > 0.0)
        {
            return p;
        }
        let u = [state.velocity_mm_s[0] / w0, state.velocity_mm_s[1] / w0];
        let a0 = state.accel_mm_s2[0] * u[0] + state.accel_mm_s2[1] * u[1];
        let mut j = limits.jerk_mm_s3;
        if a0 < 0.0 && a0 * a0 > 2.0 * j * w0 {
            j = a0 * a0 / (2.0 * w0);
        }
        let a = if -a0 > limits.decel_mm_s2 {
            -a0
        } else {
            limits.decel_mm_s2
        };
        // Speed left after building up to `a` and releasing it again, held at `a` meanwhile.
        let cruise = w0 + a0 * a0 / (2.0 * j) - a * a / j;
        let (peak, t2) = if cruise >= 0.0 {
            (a, cruise / a)
        } else {
            (libm::sqrtf(j * w0 + 0.5 * a0 * a0), 0.0)
        };
        let t1 = ((a0 + peak) / j).max(0.0);
        let t3 = peak / j;
        let w1 = w0 + a0 * t1 - 0.5 * j * t1 * t1;
        let s1 = t1 * (w0 + t1 * (0.5 * a0 - j * t1 / 6.0));
        let w2 = w1 - peak * t2;
        let s2 = s1 + t2 * (w1 - 0.5 * peak * t2);
        let s3 = s2 + t3 * (w2 + t3 * (-0.5 * peak + j * t3 / 6.0));
        p.direction = u;
        p.speed0_mm_s = w0;
        p.accel0_mm_s2 = a0;
        p.jerk_mm_s3 = j;
        p.peak_decel_mm_s2 = peak;
        p.t_s = [t1, t2, t3];
        p.s1_mm = s1;
        p.w1_mm_s = w1;
        p.s2_mm = s2;
        p.w2_mm_s = w2;
        p.distance_mm = s3;
        p
    }

    /// The distance travelled from the origin until rest (mm).
    pub fn distance_mm(&self) -> f32 {
        self.distance_mm
    }

    /// How long the stop takes (s).
    pub fn duration_s(&self) -> f32 {
        self.t_s[0] + self.t_s[1] + self.t_s[2]
    }

    /// Peak deceleration of this stop (mm/s²).
    pub fn peak_decel_mm_s2(&self) -> f32 {
        self.peak_decel_mm_s2
    }

    /// Where the stop began (the last accepted setpoint; mm).
    pub fn origin_mm(&self) -> [f32; 2] {
        self.origin_mm
    }

    /// Where it ends (mm).
    pub fn end_mm(&self) -> [f32; 2] {
        self.point_at(self.distance_mm)
    }

    /// Distance along the path `t_s` after the origin (mm); the full distance from the end on.
    pub fn distance_at(&self, t_s: f32) -> f32 {
        let [t1, t2, t3] = self.t_s;
        let (w0, a0, j, a) = (
            self.speed0_mm_s,
            self.accel0_mm_s2,
            self.jerk_mm_s3,
            self.peak_decel_mm_s2,
        );
        if !(t_s > 0.0) {
            0.0
        } else if t_s < t1 {
            t_s * (w0 + t_s * (0.5 * a0 - j * t_s / 6.0))
        } else if t_s < t1 + t2 {
            let t = t_s - t1;
            self.s1_mm + t * (self.w1_mm_s - 0.5 * a * t)
        } else if t_s < t1 + t2 + t3 {
            let t = t_s - t1 - t2;
            self.s2_mm + t * (self.w2_mm_s + t * (-0.5 * a + j * t / 6.0))
        } else {
            self.distance_mm
        }
    }

    /// The setpoint `t_s` after the origin (mm).
    pub fn at(&self, t_s: f32) -> [f32; 2] {
        self.point_at(self.distance_at(t_s))
    }

    /// Whether the stop has reached rest `t_s` after the origin.
    pub fn finished(&self, t_s: f32) -> bool {
        t_s >= self.duration_s()
    }

    fn point_at(&self, s_mm: f32) -> [f32; 2] {
        [
            self.origin_mm[0] + self.direction[0] * s_mm,
            self.origin_mm[1] + self.direction[1] * s_mm,
        ]
    }
}

/// The stated stopping distance (mm) from `speed_mm_s` with acceleration `accel_along_mm_s2`
/// along the path: `v²/(2A) + v·A/(2J)` when not accelerating (negative accelerations only
/// shorten the stop), with the acceleration ramped out first when positive (module doc).
/// [`StopProfile::distance_mm`] is at most this, and equal to it when the deceleration reaches
/// its limit.
pub fn stopping_distance_bound_mm(
    speed_mm_s: f32,
    accel_along_mm_s2: f32,
    limits: &StopLimits,
) -> f32 {
    let (v, a, j) = (speed_mm_s, limits.decel_mm_s2, limits.jerk_mm_s3);
    let up = accel_along_mm_s2.max(0.0);
    let w = v + up * up / (2.0 * j);
    v * up / j + up * up * up / (3.0 * j * j) + w * w / (2.0 * a) + w * a / (2.0 * j)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_S: f32 = crate::SAMPLE_PERIOD_S;

    fn limits() -> StopLimits {
        StopSettings::default().limits
    }

    fn moving(v: [f32; 2], a: [f32; 2]) -> MotionState {
        MotionState {
            position_mm: [212.0, 0.0],
            velocity_mm_s: v,
            accel_mm_s2: a,
        }
    }

    /// The stop's setpoints at the servo rate after the two setpoints `before` the origin.
    fn sampled(p: &StopProfile, before: [[f32; 2]; 2]) -> Vec<[f32; 2]> {
        let n = (p.duration_s() / DT_S) as usize + 20;
        let mut pts: Vec<[f32; 2]> = before.to_vec();
        pts.push(p.origin_mm());
        pts.extend((1..=n).map(|k| p.at(k as f32 * DT_S)));
        pts
    }

    /// Second differences over dt² (mm/s²), in f64 of the f32 setpoints: what the servo sees.
    fn accelerations(pts: &[[f32; 2]]) -> Vec<[f64; 2]> {
        let dt2 = (DT_S as f64) * (DT_S as f64);
        pts.windows(3)
            .map(|w| [0, 1].map(|k| (w[2][k] as f64 - 2.0 * w[1][k] as f64 + w[0][k] as f64) / dt2))
            .collect()
    }

    #[test]
    fn at_rest_is_an_empty_stop() {
        for s in [
            MotionState::at_rest([200.0, 5.0]),
            moving([0.05, -0.05], [5000.0, 0.0]),
            moving([f32::NAN, 1.0], [0.0; 2]),
        ] {
            let p = StopProfile::plan(&s, &limits());
            assert_eq!((p.distance_mm(), p.duration_s()), (0.0, 0.0), "{s:?}");
            assert_eq!(p.at(0.01), s.position_mm);
            assert!(p.finished(0.0));
        }
    }

    /// The stated figure: from 1.5 m/s without tangential acceleration, exactly
    /// v²/(2A) + vA/(2J), along the velocity, in (1.5 / 49.03 + 5 ms) s.
    #[test]
    fn top_speed_stop_is_the_stated_distance_along_the_velocity() {
        let v = [1500.0 * 0.6, -1500.0 * 0.8];
        let p = StopProfile::plan(&moving(v, [0.0; 2]), &limits());
        let bound = stopping_distance_bound_mm(1500.0, 0.0, &limits());
        assert!(
            (p.distance_mm() - bound).abs() < 1e-3 * bound,
            "{} vs {bound}",
            p.distance_mm()
        );
        assert!((bound - 26.69).abs() < 0.01, "{bound}");
        let a = limits().decel_mm_s2;
        assert!(
            (p.duration_s() - (1500.0 / a + 5e-3)).abs() < 1e-5,
            "{}",
            p.duration_s()
        );
        let end = p.end_mm();
        let along = [(end[0] - 212.0) / p.distance_mm(), end[1] / p.distance_mm()];
        assert!(
            (along[0] - 0.6).abs() < 1e-5 && (along[1] + 0.8).abs() < 1e-5,
            "{along:?}"
        );
        assert_eq!(p.peak_decel_mm_s2(), a);
        // The tour's top speed, 1.38 m/s: 22.9 mm; the servo's limit, 3 m/s: 99 mm (the figures
        // in the module doc and docs/reference/faults.md).
        assert!((stopping_distance_bound_mm(1379.4, 0.0, &limits()) - 22.85).abs() < 0.01);
        assert!((stopping_distance_bound_mm(3000.0, 0.0, &limits()) - 99.3).abs() < 0.1);
    }

    /// For every start (speed 0.2 mm/s .. 3 m/s, tangential acceleration -5 g .. +5 g, with and
    /// without a normal component), the sampled stop: never asks for more acceleration than the
    /// servo accepts (so never a velocity step); changes the acceleration by at most the jerk
    /// limit per sample, except in the first two, which also drop the normal acceleration;
    /// moves monotonically along the velocity; comes to rest and stays; ends where
    /// `distance_mm` says, within the stated bound, equal to it when the deceleration reaches
    /// its limit.
    #[test]
    fn sampled_stops_are_smooth_monotonic_and_within_their_distance() {
        let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2 as f64;
        let lim = limits();
        let servo_max = kinematics_core::ServoConfig::default().max_accel_mm_s2 as f64;
        // f32 setpoints near 212 mm carry 15 nm of rounding: ~250 mm/s² in a change of the
        // second difference.
        let rounding = 600.0;
        let (mut checked, mut reached_peak) = (0, 0);
        for &speed in &[0.2f32, 3.0, 30.0, 100.0, 500.0, 1384.0, 1500.0, 3000.0] {
            for &along_g in &[-5.0f64, -2.0, -0.5, 0.0, 0.5, 2.0, 5.0] {
                for &normal_g in &[0.0f64, 1.0] {
                    let (u, n) = ([0.6f64, 0.8], [-0.8f64, 0.6]);
                    let v = [speed as f64 * u[0], speed as f64 * u[1]];
                    let a = [0, 1].map(|k| (along_g * u[k] + normal_g * n[k]) * g);
                    // The two setpoints before the origin, consistent with (v, a) at the origin.
                    let o = [212.0f64, 0.0];
                    let back =
                        |t: f64| [0, 1].map(|k| (o[k] - v[k] * t + 0.5 * a[k] * t * t) as f32);
                    let state = MotionState {
                        position_mm: [o[0] as f32, o[1] as f32],
                        velocity_mm_s: v.map(|x| x as f32),
                        accel_mm_s2: a.map(|x| x as f32),
                    };
                    let p = StopProfile::plan(&state, &lim);
                    let dt = DT_S as f64;
                    let pts = sampled(&p, [back(2.0 * dt), back(dt)]);
                    let acc = accelerations(&pts);
                    let tag = format!("speed {speed} along {along_g} g normal {normal_g} g");
                    let norm = |x: [f64; 2]| x[0].hypot(x[1]);
                    let max_a = acc.iter().map(|&x| norm(x)).fold(0.0, f64::max);
                    assert!(max_a <= servo_max, "{tag}: acceleration {max_a}");
                    let step = p.jerk_mm_s3 as f64 * dt + rounding;
                    for (k, w) in acc.windows(2).enumerate() {
                        let change = norm([w[1][0] - w[0][0], w[1][1] - w[0][1]]);
                        // The normal acceleration is dropped over the first two second
                        // differences (each straddles the origin).
                        let allowed = if k <= 1 { step + normal_g * g } else { step };
                        assert!(change <= allowed * 1.01, "{tag}: acceleration changes {change} at sample {k} (allowed {allowed})");
                    }
                    // Monotonic along u, at rest at the end, where `distance_mm` says.
                    let along =
                        |q: &[f32; 2]| (q[0] as f64 - o[0]) * u[0] + (q[1] as f64 - o[1]) * u[1];
                    let mut last_s = 0.0f64;
                    for q in &pts[2..] {
                        let s = along(q);
                        assert!(s >= last_s - 1e-4, "{tag}: backwards {s} after {last_s}");
                        last_s = s;
                    }
                    assert_eq!(pts[pts.len() - 1], pts[pts.len() - 2], "{tag}: not at rest");
                    assert!(
                        (last_s - p.distance_mm() as f64).abs() < 1e-3,
                        "{tag}: {last_s} vs {}",
                        p.distance_mm()
                    );
                    let bound = stopping_distance_bound_mm(speed, (along_g * g) as f32, &lim);
                    assert!(
                        p.distance_mm() <= bound * 1.0001 + 1e-4,
                        "{tag}: {} > bound {bound}",
                        p.distance_mm()
                    );
                    if along_g >= 0.0 && p.peak_decel_mm_s2() == lim.decel_mm_s2 {
                        assert!(
                            p.distance_mm() >= bound * 0.9999 - 1e-4,
                            "{tag}: {} < bound {bound}",
                            p.distance_mm()
                        );
                        reached_peak += 1;
                    }
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 8 * 7 * 2);
        assert!(reached_peak >= 20, "{reached_peak}");
    }

    #[test]
    fn workspace_is_the_grid_rectangle_less_the_margin() {
        // The paper's lattice: x 162.132..262.132 mm, y -75..75 mm, 5 mm nodes.
        let g = kinematics_core::paper::grid_geometry();
        let w = Workspace::of_grid(&g, 0.1).unwrap();
        assert!(w.contains([162.24, -74.89]) && w.contains([262.02, 74.89]));
        assert!(
            !w.contains([162.2, 0.0])
                && !w.contains([200.0, 74.95])
                && !w.contains([f32::NAN, 0.0])
        );
    }

    /// An image that carries the machine's workspace: its polygon and the larger of the two
    /// margins; without the block, the grid's rectangle.
    #[test]
    fn workspace_comes_from_the_image_when_it_has_one() {
        use kinematics_core::grid::{append_workspace, encode, WorkspaceLimits, WORKSPACE_LEN};
        // The paper's lattice: x 162.132..262.132 mm, y -75..75 mm, 5 mm nodes.
        let g = kinematics_core::paper::grid_geometry();
        let mut img = std::vec![0u8; g.image_len() + WORKSPACE_LEN];
        let n = encode(
            &mut img,
            &g,
            &kinematics_core::FiveBar::paper_nominal(),
            &std::vec![[0.0; 2]; g.len()],
        )
        .unwrap();
        let plain_img = img[..n].to_vec();
        let plain = CorrectionGrid::parse(&plain_img).unwrap();
        assert_eq!(
            Workspace::of_image(&plain, 0.1),
            Workspace::of_grid(&g, 0.1)
        );
        // A hexagon: the rectangle with its upper right corner cut along x + y = 317.
        let v = [
            [162.132, -75.0],
            [262.132, -75.0],
            [262.132, 54.868],
            [242.132, 74.868],
            [162.132, 74.868],
        ];
        let limits = WorkspaceLimits {
            region: ConvexWorkspace::new(&v).unwrap(),
            stop_margin_mm: 0.5,
        };
        append_workspace(&mut img, n, n, &limits).unwrap();
        let grid = CorrectionGrid::parse(&img).unwrap();
        let w = Workspace::of_image(&grid, 0.1).unwrap();
        assert_eq!(w.margin_mm(), 0.5, "the image's soft limit is the larger");
        assert_eq!(
            Workspace::of_image(&grid, 2.0).unwrap().margin_mm(),
            2.0,
            "the setting is the larger"
        );
        assert!(w.contains([212.0, 0.0]) && w.contains([162.7, 0.0]) && !w.contains([162.5, 0.0]));
        // Inside the grid's rectangle but beyond the cut corner: refused.
        assert!(Workspace::of_grid(&g, 0.1).unwrap().contains([255.0, 70.0]));
        assert!(!w.contains([255.0, 70.0]) && !w.contains([212.0, 74.6]));
        // On a machine: the block wins; without one, the machine's polygon where the grid
        // covers it, else the grid's rectangle.
        let hexagon = limits.region;
        assert_eq!(
            Workspace::of_machine_image(&grid, &hexagon, 0.1),
            Workspace::of_image(&grid, 0.1)
        );
        let on_machine = Workspace::of_machine_image(&plain, &hexagon, 0.1).unwrap();
        assert_eq!(on_machine.region(), &hexagon);
        assert!(!on_machine.contains([255.0, 70.0]));
        let wider = ConvexWorkspace::rectangle([150.0, 270.0], [-80.0, 80.0]).unwrap();
        assert_eq!(
            Workspace::of_machine_image(&plain, &wider, 0.1),
            Workspace::of_grid(&g, 0.1)
        );
    }

    #[test]
    fn settings_validate() {
        let max = kinematics_core::ServoConfig::default().max_accel_mm_s2;
        let d = StopSettings::default();
        assert_eq!(d.validate(max), Ok(()));
        let bad = |f: fn(&mut StopSettings)| {
            let mut s = d;
            f(&mut s);
            s.validate(max)
        };
        assert_eq!(
            bad(|s| s.limits.decel_mm_s2 = f32::NAN),
            Err("stop.limits.decel_mm_s2")
        );
        assert_eq!(
            bad(|s| s.limits.decel_mm_s2 = 6.0 * 9806.65),
            Err("stop.limits.decel_mm_s2"),
            "beyond the servo's limit"
        );
        assert_eq!(
            bad(|s| s.limits.jerk_mm_s3 = 0.0),
            Err("stop.limits.jerk_mm_s3")
        );
        assert_eq!(
            bad(|s| s.workspace_margin_mm = -1.0),
            Err("stop.workspace_margin_mm")
        );
        assert_eq!(
            bad(|s| s.standstill_rad_s = f32::INFINITY),
            Err("stop.standstill_rad_s")
        );
        assert_eq!(
            bad(|s| s.settle_timeout_s = f32::NAN),
            Err("stop.settle_timeout_s")
        );
    }
}
