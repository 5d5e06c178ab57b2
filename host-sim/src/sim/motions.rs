//! Task-space setpoint trajectories for the closed loop: built-in test motions and CSV files.
//!
//! Built-ins (about the centre of the machine's workspace, [`crate::machine_spec::Workspace`];
//! inside the paper's; all starting at rest so the servo's setpoint-acceleration check never
//! trips at the start):
//! * `circle`: the slow circle, radius 40 mm about the workspace centre, 4 s per turn
//!   (63 mm/s), phase `ω·(t - τ(1 - e^(-t/τ)))` with τ = 0.3 s so the speed ramps up smoothly;
//! * `figure8`: a lemniscate of Gerono (±45 mm in x, ±60 mm in y), 2 s per loop, same ramp;
//! * `p2p`: point-to-point moves from the centre around the corners 10 mm inside the workspace
//!   and back, jerk-limited at the machine's rated acceleration (5 g, 49 m/s², on the paper
//!   machine), 1.5 m/s and [`JERK_MM_S3`] (`kinematics_core::trajectory`), 0.1 s dwell at each
//!   point (on a polygon workspace, the bounding rectangle's inset corners pulled towards the
//!   centre until they are 10 mm inside);
//! * `p2p-trapezoid`: the same moves with trapezoidal speed profiles (infinite jerk): kept for
//!   comparison with jerk-limited moves;
//! * `circle-5g`: two turns of the 40 mm circle from rest to rest at 5 g peak acceleration
//!   (`PathMotion::plan`: the ramps and the cruise within 5 g and 1.5 m/s, jerk up to 5e7
//!   mm/s³ so that the acceleration binds);
//! * `figure8-5g`: two loops of the figure-eight (±45 mm, ±60 mm) at 5 g peak acceleration (and
//!   1.5 m/s);
//! * `move-10mm`: one 10 mm move along x from the centre at 5 g, then 0.3 s at rest (the
//!   settling time);
//! * a file: CSV with header `t_s,x_mm,y_mm`, times strictly increasing, linearly interpolated;
//!   before the first and after the last sample the end points are held. A file has positions
//!   only: [`Trajectory::motion_at`] is `None` and the loop runs the servo on differences.
//!
//! Every built-in has exact derivatives ([`Trajectory::motion_at`]: velocity, acceleration and
//! jerk of the same closed form), which the servo's motion step feeds forward.
//!
//! Cost: a few transcendental calls per setpoint.

use super::knots::KnotPath;
use super::SimError;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use kinematics_core::jerk_profile::ScalarState;
use kinematics_core::path::{Circle, Figure8, Line, Path as _};
use kinematics_core::trajectory::{MotionSetpoint, PathMotion, TaskLimits};
use std::f64::consts::TAU;
use std::path::Path;

/// Jerk limit of the built-in jerk-limited motions (mm/s³): 5 g is reached in 10 ms.
pub const JERK_MM_S3: f64 = 5.0e6;
/// Turns of `circle-5g` and loops of `figure8-5g`.
const CONTOUR_TURNS: f64 = 2.0;
/// Jerk limit of the 5 g contours (mm/s³): high enough that the acceleration (and on the
/// figure-eight the speed) is what binds, as the contours are specified by their peak
/// acceleration; their actual peak jerk is 2.9e7 (circle) and 5e7 (figure-eight).
const CONTOUR_JERK_MM_S3: f64 = 5.0e7;
/// Instants sampled when a contour is scaled to its limits.
const CONTOUR_SAMPLES: usize = 20_000;
/// Rest after `move-10mm` (s).
const SETTLE_S: f64 = 0.3;

const RAMP_S: f64 = 0.3;
/// Cruise speed of the point-to-point moves (mm/s).
const P2P_SPEED_MM_S: f64 = 1_500.0;
/// How far inside the workspace's corners the point-to-point moves turn (mm).
const P2P_INSET_MM: f64 = 10.0;

#[derive(Clone, Debug)]
pub struct Move {
    t0_s: f64,
    from_mm: [f64; 2],
    to_mm: [f64; 2],
    /// Time to accelerate, cruise, total (s), and peak speed (mm/s).
    t_acc_s: f64,
    t_cruise_s: f64,
    v_peak_mm_s: f64,
}

impl Move {
    fn new(t0_s: f64, from_mm: [f64; 2], to_mm: [f64; 2], accel: f64, v_max: f64) -> Self {
        let d = (to_mm[0] - from_mm[0]).hypot(to_mm[1] - from_mm[1]);
        let (t_acc, t_cruise, v) = if d >= v_max * v_max / accel {
            (v_max / accel, (d - v_max * v_max / accel) / v_max, v_max)
        } else {
            let v = (d * accel).sqrt();
            (v / accel, 0.0, v)
        };
        Move {
            t0_s,
            from_mm,
            to_mm,
            t_acc_s: t_acc,
            t_cruise_s: t_cruise,
            v_peak_mm_s: v,
        }
    }

    fn duration_s(&self) -> f64 {
        2.0 * self.t_acc_s + self.t_cruise_s
    }

    /// The setpoint at local time `t`: position, velocity and acceleration along the line (the
    /// jerk is infinite at the phase changes and zero elsewhere).
    fn motion(&self, t: f64) -> MotionSetpoint<f64> {
        let d = (self.to_mm[0] - self.from_mm[0]).hypot(self.to_mm[1] - self.from_mm[1]);
        let u = if d > 0.0 {
            [
                (self.to_mm[0] - self.from_mm[0]) / d,
                (self.to_mm[1] - self.from_mm[1]) / d,
            ]
        } else {
            [0.0; 2]
        };
        let s = if d > 0.0 {
            self.distance_mm(t) / d
        } else {
            1.0
        };
        let a = self.v_peak_mm_s / self.t_acc_s.max(1e-12);
        let (ta, tc, total) = (self.t_acc_s, self.t_cruise_s, self.duration_s());
        let (v, acc) = if !(t > 0.0) || t >= total {
            (0.0, 0.0)
        } else if t <= ta {
            (a * t, a)
        } else if t <= ta + tc {
            (self.v_peak_mm_s, 0.0)
        } else {
            (a * (total - t), -a)
        };
        MotionSetpoint {
            position_mm: [
                self.from_mm[0] + s * (self.to_mm[0] - self.from_mm[0]),
                self.from_mm[1] + s * (self.to_mm[1] - self.from_mm[1]),
            ],
            velocity_mm_s: [v * u[0], v * u[1]],
            acceleration_mm_s2: [acc * u[0], acc * u[1]],
            jerk_mm_s3: [0.0; 2],
        }
    }

    /// Distance travelled along the move at local time `t`.
    fn distance_mm(&self, t: f64) -> f64 {
        let a = self.v_peak_mm_s / self.t_acc_s.max(1e-12);
        let (ta, tc) = (self.t_acc_s, self.t_cruise_s);
        let t = t.clamp(0.0, self.duration_s());
        if t <= ta {
            0.5 * a * t * t
        } else if t <= ta + tc {
            0.5 * a * ta * ta + self.v_peak_mm_s * (t - ta)
        } else {
            let r = self.duration_s() - t;
            let total = a * ta * ta + self.v_peak_mm_s * tc;
            total - 0.5 * a * r * r
        }
    }
}

/// One planned piece of a [`Trajectory::Planned`]: a path with its jerk-limited time law.
#[derive(Clone, Copy, Debug)]
pub enum Piece {
    Line(PathMotion<f64, Line<f64>>),
    Circle(PathMotion<f64, Circle<f64>>),
    Figure8(PathMotion<f64, Figure8<f64>>),
}

impl Piece {
    /// Duration (s).
    pub fn duration_s(&self) -> f64 {
        match self {
            Piece::Line(m) => m.duration_s(),
            Piece::Circle(m) => m.duration_s(),
            Piece::Figure8(m) => m.duration_s(),
        }
    }

    /// The setpoint `t_s` after the piece's start.
    pub fn at(&self, t_s: f64) -> MotionSetpoint<f64> {
        match self {
            Piece::Line(m) => m.at(t_s),
            Piece::Circle(m) => m.at(t_s),
            Piece::Figure8(m) => m.at(t_s),
        }
    }
}

/// A setpoint source.
#[derive(Clone, Debug)]
pub enum Trajectory {
    Circle {
        centre_mm: [f64; 2],
        radius_mm: f64,
        period_s: f64,
    },
    Figure8 {
        centre_mm: [f64; 2],
        half_x_mm: f64,
        half_y_mm: f64,
        period_s: f64,
    },
    /// Trapezoidal moves (`p2p-trapezoid`).
    PointToPoint { moves: Vec<Move>, dwell_s: f64 },
    /// Jerk-limited pieces, each starting at its time (s), at rest in between.
    Planned {
        name: String,
        pieces: Vec<(f64, Piece)>,
        duration_s: f64,
    },
    Samples {
        name: String,
        t_s: Vec<f64>,
        xy_mm: Vec<[f64; 2]>,
    },
    /// Streamed knots as the controller plays them ([`KnotPath`]), then `duration_s` in all
    /// (at rest after the last knot).
    Knots {
        name: String,
        path: KnotPath,
        duration_s: f64,
    },
}

/// The ramped phase of the periodic built-ins: starts at rest, reaches `ω` after a few τ.
fn ramped_phase(omega: f64, t: f64) -> f64 {
    omega * (t - RAMP_S * (1.0 - (-t / RAMP_S).exp()))
}

/// The `p2p` tour: the centre, the corners 10 mm inside the workspace, the centre.
fn p2p_points(spec: &MachineSpec) -> [[f64; 2]; 6] {
    let ws = &spec.workspace;
    let centre_mm = ws.centre_mm();
    let (x, y, d) = (ws.x_mm, ws.y_mm, P2P_INSET_MM);
    let (lo, hi) = ([x[0] + d, y[0] + d], [x[1] - d, y[1] - d]);
    // The inset rectangle's corners; on a polygon workspace, pulled inside it.
    let corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]].map(|p| {
        if ws.is_rectangle {
            p
        } else {
            ws.pulled_inside(p, d)
        }
    });
    [
        centre_mm, corners[0], corners[1], corners[2], corners[3], centre_mm,
    ]
}

/// The machine's rated motion: its acceleration, 1.5 m/s, [`JERK_MM_S3`].
pub fn rated_limits(spec: &MachineSpec) -> TaskLimits<f64> {
    TaskLimits {
        speed_mm_s: P2P_SPEED_MM_S,
        accel_mm_s2: spec.max_acceleration_g * STANDARD_GRAVITY_MM_S2,
        jerk_mm_s3: JERK_MM_S3,
    }
}

/// A contour test `name`: `path` planned at the contour limits, one piece, settled 50 ms.
fn contour<P: kinematics_core::path::Path<f64>>(
    name: &str,
    path: P,
    spec: &MachineSpec,
    piece: fn(PathMotion<f64, P>) -> Piece,
) -> Result<Trajectory, SimError> {
    let m = PathMotion::plan(path, &contour_limits(spec), CONTOUR_SAMPLES)
        .map_err(|e| SimError::Invalid(format!("{name}: {e}")))?;
    let duration_s = m.duration_s() + 0.05;
    Ok(Trajectory::Planned {
        name: name.into(),
        pieces: vec![(0.0, piece(m))],
        duration_s,
    })
}

/// The 5 g contours' limits: the rated ones with [`CONTOUR_JERK_MM_S3`].
fn contour_limits(spec: &MachineSpec) -> TaskLimits<f64> {
    TaskLimits {
        jerk_mm_s3: CONTOUR_JERK_MM_S3,
        ..rated_limits(spec)
    }
}

impl Trajectory {
    /// `circle`, `figure8`, `p2p` (on `spec`'s workspace) or a CSV file path.
    pub fn by_name(name: &str, spec: &MachineSpec) -> Result<Self, SimError> {
        let centre_mm = spec.workspace.centre_mm();
        match name {
            "circle" => Ok(Trajectory::Circle {
                centre_mm,
                radius_mm: 40.0,
                period_s: 4.0,
            }),
            "figure8" => Ok(Trajectory::Figure8 {
                centre_mm,
                half_x_mm: 45.0,
                half_y_mm: 60.0,
                period_s: 2.0,
            }),
            "p2p-trapezoid" => {
                let dwell = 0.1;
                let mut t = dwell;
                let mut moves = Vec::new();
                for w in p2p_points(spec).windows(2) {
                    let m = Move::new(
                        t,
                        w[0],
                        w[1],
                        spec.max_acceleration_g * STANDARD_GRAVITY_MM_S2,
                        P2P_SPEED_MM_S,
                    );
                    t += m.duration_s() + dwell;
                    moves.push(m);
                }
                Ok(Trajectory::PointToPoint {
                    moves,
                    dwell_s: dwell,
                })
            }
            "p2p" => Trajectory::tour("p2p", &p2p_points(spec), &rated_limits(spec), 0.1),
            "move-10mm" => {
                let to = [centre_mm[0] + 10.0, centre_mm[1]];
                let mut t =
                    Trajectory::tour("move-10mm", &[centre_mm, to], &rated_limits(spec), 0.05)?;
                if let Trajectory::Planned { duration_s, .. } = &mut t {
                    *duration_s += SETTLE_S - 0.05;
                }
                Ok(t)
            }
            "circle-5g" => {
                let c = Circle {
                    centre_mm,
                    radius_mm: 40.0,
                    start_rad: 0.0,
                    turns: CONTOUR_TURNS,
                };
                contour("circle-5g", c, spec, Piece::Circle)
            }
            "figure8-5g" => {
                let f = Figure8 {
                    centre_mm,
                    half_x_mm: 45.0,
                    half_y_mm: 60.0,
                    loops: CONTOUR_TURNS,
                };
                contour("figure8-5g", f, spec, Piece::Figure8)
            }
            path => {
                if !Path::new(path).exists() {
                    return Err(SimError::UnknownTrajectory(path.to_string()));
                }
                Trajectory::from_csv(path)
            }
        }
    }

    /// Jerk-limited rest-to-rest moves through `points` (the first is the start), `dwell_s`
    /// before the first move and after each.
    pub fn tour(
        name: &str,
        points: &[[f64; 2]],
        limits: &TaskLimits<f64>,
        dwell_s: f64,
    ) -> Result<Self, SimError> {
        if points.len() < 2 {
            return Err(SimError::Invalid(format!(
                "{name}: a tour needs a start and at least one point"
            )));
        }
        let mut pieces = Vec::new();
        for w in points.windows(2) {
            pieces.push(Piece::Line(
                PathMotion::line(w[0], w[1], limits)
                    .map_err(|e| SimError::Invalid(format!("{name}: {e}")))?,
            ));
        }
        Ok(Trajectory::sequence(name, pieces, dwell_s))
    }

    /// `pieces` one after the other (each must start where the last ended), `dwell_s` at rest
    /// before the first and after each.
    pub fn sequence(name: &str, pieces: Vec<Piece>, dwell_s: f64) -> Self {
        let mut t = dwell_s;
        let mut timed = Vec::new();
        for p in pieces {
            timed.push((t, p));
            t += p.duration_s() + dwell_s;
        }
        Trajectory::Planned {
            name: name.into(),
            pieces: timed,
            duration_s: t,
        }
    }

    fn from_csv(path: &str) -> Result<Self, SimError> {
        let err = |m: String| SimError::TrajectoryFile(m);
        let text = std::fs::read_to_string(path)
            .map_err(|e| err(format!("cannot read trajectory {path}: {e}")))?;
        let mut r = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .from_reader(text.as_bytes());
        let h = r
            .headers()
            .map_err(|e| err(format!("trajectory {path}: no header: {e}")))?
            .clone();
        if h.iter().collect::<Vec<_>>() != ["t_s", "x_mm", "y_mm"] {
            let found = h.iter().collect::<Vec<_>>().join(",");
            return Err(err(format!(
                "trajectory {path}: header must be 't_s,x_mm,y_mm', not '{found}'"
            )));
        }
        let (mut ts, mut xy) = (Vec::new(), Vec::new());
        for rec in r.records() {
            let rec = rec.map_err(|e| err(format!("trajectory {path}: {e}")))?;
            let line = rec.position().map(|p| p.line()).unwrap_or(0);
            let num = |k: usize| -> Result<f64, SimError> {
                let s = rec.get(k).unwrap_or("");
                let v: f64 = s.parse().map_err(|_| {
                    err(format!(
                        "trajectory {path} line {line}: '{s}' is not a number"
                    ))
                })?;
                if !v.is_finite() {
                    return Err(err(format!(
                        "trajectory {path} line {line}: '{s}' is not finite"
                    )));
                }
                Ok(v)
            };
            let t = num(0)?;
            if let Some(&last) = ts.last() {
                if !(t > last) {
                    return Err(err(format!("trajectory {path} line {line}: times must increase strictly ({t} after {last})")));
                }
            }
            ts.push(t);
            xy.push([num(1)?, num(2)?]);
        }
        if ts.len() < 2 {
            return Err(err(format!(
                "trajectory {path}: needs at least two samples"
            )));
        }
        Ok(Trajectory::Samples {
            name: path.to_string(),
            t_s: ts,
            xy_mm: xy,
        })
    }

    pub fn name(&self) -> String {
        match self {
            Trajectory::Circle { .. } => "circle".into(),
            Trajectory::Figure8 { .. } => "figure8".into(),
            Trajectory::PointToPoint { .. } => "p2p-trapezoid".into(),
            Trajectory::Planned { name, .. }
            | Trajectory::Samples { name, .. }
            | Trajectory::Knots { name, .. } => name.clone(),
        }
    }

    /// When the last motion ends (s): the settling time counts from here. `None` for a file.
    pub fn motion_end_s(&self) -> Option<f64> {
        match self {
            Trajectory::Planned { pieces, .. } => pieces.last().map(|(t0, p)| t0 + p.duration_s()),
            Trajectory::PointToPoint { moves, .. } => moves.last().map(|m| m.t0_s + m.duration_s()),
            Trajectory::Knots { path, .. } => Some(path.end_s()),
            _ => None,
        }
    }

    /// The setpoint at `t_s` with its exact velocity, acceleration and jerk; `None` for a
    /// file (positions only).
    pub fn motion_at(&self, t_s: f64) -> Option<MotionSetpoint<f64>> {
        let t = t_s.max(0.0);
        // The ramped phase and its derivatives (`ramped_phase`).
        let phase = |omega: f64| {
            let e = (-t / RAMP_S).exp();
            ScalarState {
                position: ramped_phase(omega, t),
                velocity: omega * (1.0 - e),
                acceleration: omega * e / RAMP_S,
                jerk: -omega * e / (RAMP_S * RAMP_S),
            }
        };
        match self {
            Trajectory::Circle {
                centre_mm,
                radius_mm,
                period_s,
            } => {
                let c = Circle {
                    centre_mm: *centre_mm,
                    radius_mm: *radius_mm,
                    start_rad: 0.0,
                    turns: 1.0,
                };
                let p = phase(TAU / period_s);
                let r = *radius_mm;
                let s = ScalarState {
                    position: r * p.position,
                    velocity: r * p.velocity,
                    acceleration: r * p.acceleration,
                    jerk: r * p.jerk,
                };
                Some(c.motion(&s))
            }
            Trajectory::Figure8 {
                centre_mm,
                half_x_mm,
                half_y_mm,
                period_s,
            } => {
                let f = Figure8 {
                    centre_mm: *centre_mm,
                    half_x_mm: *half_x_mm,
                    half_y_mm: *half_y_mm,
                    loops: 1.0,
                };
                Some(f.motion(&phase(TAU / period_s)))
            }
            Trajectory::PointToPoint { moves, .. } => {
                let first = moves.first()?;
                let mut m = MotionSetpoint::at_rest(first.from_mm);
                for mv in moves {
                    if t < mv.t0_s {
                        break;
                    }
                    m = mv.motion(t - mv.t0_s);
                }
                Some(m)
            }
            Trajectory::Planned { pieces, .. } => {
                let (_, first) = pieces.first()?;
                let mut m = first.at(0.0);
                for (t0, p) in pieces {
                    if t < *t0 {
                        break;
                    }
                    m = p.at(t - t0);
                }
                Some(m)
            }
            Trajectory::Samples { .. } => None,
            Trajectory::Knots { path, .. } => Some(path.motion_at(t_s)),
        }
    }

    /// How long the trajectory naturally lasts (s): the default `--seconds`.
    pub fn natural_duration_s(&self) -> f64 {
        match self {
            Trajectory::Circle { period_s, .. } => period_s + 2.0 * RAMP_S,
            Trajectory::Figure8 { period_s, .. } => 2.0 * period_s,
            Trajectory::PointToPoint { moves, dwell_s } => moves
                .last()
                .map(|m| m.t0_s + m.duration_s() + dwell_s)
                .unwrap_or(0.0),
            Trajectory::Planned { duration_s, .. } => *duration_s,
            Trajectory::Samples { t_s, .. } => *t_s.last().unwrap_or(&0.0),
            Trajectory::Knots { duration_s, .. } => *duration_s,
        }
    }

    /// The setpoint at time `t_s` (mm).
    pub fn at(&self, t_s: f64) -> [f64; 2] {
        let t = t_s.max(0.0);
        match self {
            Trajectory::Circle {
                centre_mm,
                radius_mm,
                period_s,
            } => {
                let p = ramped_phase(TAU / period_s, t);
                [
                    centre_mm[0] + radius_mm * p.cos(),
                    centre_mm[1] + radius_mm * p.sin(),
                ]
            }
            Trajectory::Figure8 {
                centre_mm,
                half_x_mm,
                half_y_mm,
                period_s,
            } => {
                let p = ramped_phase(TAU / period_s, t);
                [
                    centre_mm[0] + half_x_mm * p.sin(),
                    centre_mm[1] + half_y_mm * (2.0 * p).sin(),
                ]
            }
            Trajectory::PointToPoint { .. }
            | Trajectory::Planned { .. }
            | Trajectory::Knots { .. } => {
                self.motion_at(t).map(|m| m.position_mm).unwrap_or([0.0; 2])
            }
            Trajectory::Samples { t_s: ts, xy_mm, .. } => {
                let k = ts.partition_point(|&s| s <= t);
                if k == 0 {
                    xy_mm[0]
                } else if k >= ts.len() {
                    xy_mm[ts.len() - 1]
                } else {
                    let f = (t - ts[k - 1]) / (ts[k] - ts[k - 1]);
                    let (a, b) = (xy_mm[k - 1], xy_mm[k]);
                    [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Peak backward-difference acceleration at 2 kHz, as the servo sees it.
    fn peak_accel(tr: &Trajectory) -> f64 {
        let dt = 5e-4;
        let n = (tr.natural_duration_s() / dt) as usize;
        let mut peak: f64 = 0.0;
        for k in 2..n {
            let (p0, p1, p2) = (
                tr.at(k as f64 * dt),
                tr.at((k - 1) as f64 * dt),
                tr.at((k - 2) as f64 * dt),
            );
            let a = ((p0[0] - 2.0 * p1[0] + p2[0]).hypot(p0[1] - 2.0 * p1[1] + p2[1])) / (dt * dt);
            peak = peak.max(a);
        }
        peak
    }

    const G_MM_S2: f64 = STANDARD_GRAVITY_MM_S2;

    #[test]
    fn builtins_start_at_rest_and_respect_5g() {
        let spec = MachineSpec::paper();
        for name in ["circle", "figure8", "p2p"] {
            let tr = Trajectory::by_name(name, &spec).unwrap();
            let a = peak_accel(&tr);
            assert!(a <= 5.0 * G_MM_S2 * 1.0001, "{name}: {a}");
        }
        let p2p = Trajectory::by_name("p2p", &spec).unwrap();
        assert!(peak_accel(&p2p) > 4.9 * G_MM_S2);
        let end = p2p.at(p2p.natural_duration_s());
        assert!((end[0] - 212.132).abs() < 1e-9 && end[1].abs() < 1e-9);
    }

    /// The 5 g built-ins reach 5 g (and no more), start and end at rest, and their stated
    /// derivatives are the derivatives of their positions.
    #[test]
    fn the_5g_builtins_have_exact_derivatives() {
        let spec = MachineSpec::paper();
        for name in [
            "p2p",
            "p2p-trapezoid",
            "circle-5g",
            "figure8-5g",
            "move-10mm",
            "circle",
            "figure8",
        ] {
            let tr = Trajectory::by_name(name, &spec).unwrap();
            assert_eq!(tr.name(), name);
            let a = peak_accel(&tr);
            assert!(a <= 5.0 * G_MM_S2 * 1.001, "{name}: {a}");
            if name.ends_with("5g") || name.starts_with("p2p") || name == "move-10mm" {
                assert!(a > 4.9 * G_MM_S2, "{name}: {a}");
            }
            let start = tr.motion_at(0.0).unwrap();
            assert_eq!(start.velocity_mm_s, [0.0; 2], "{name}");
            let h = 1e-6;
            let n = (tr.natural_duration_s() / 1e-3) as usize;
            for k in 1..n {
                let t = k as f64 * 1e-3 + 0.37e-3;
                let (lo, mid, hi) = (
                    tr.motion_at(t - h).unwrap(),
                    tr.motion_at(t).unwrap(),
                    tr.motion_at(t + h).unwrap(),
                );
                for i in 0..2 {
                    let fv = (hi.position_mm[i] - lo.position_mm[i]) / (2.0 * h);
                    assert!(
                        (fv - mid.velocity_mm_s[i]).abs() < 1e-3,
                        "{name} v at {t}: {fv} {}",
                        mid.velocity_mm_s[i]
                    );
                    if name != "p2p-trapezoid" {
                        let fa = (hi.velocity_mm_s[i] - lo.velocity_mm_s[i]) / (2.0 * h);
                        assert!(
                            (fa - mid.acceleration_mm_s2[i]).abs() < 1.0,
                            "{name} a at {t}: {fa} {}",
                            mid.acceleration_mm_s2[i]
                        );
                    }
                }
            }
        }
        let m = Trajectory::by_name("move-10mm", &spec).unwrap();
        let end = m.motion_end_s().unwrap();
        assert!(
            m.natural_duration_s() >= end + 0.29,
            "{} {end}",
            m.natural_duration_s()
        );
        assert!((m.at(end)[0] - 222.132).abs() < 1e-9);
    }

    #[test]
    fn bad_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        std::fs::write(&p, "t_s,x_mm,y_mm\n0,212,0\n0,213,0\n").unwrap();
        let spec = MachineSpec::paper();
        assert!(Trajectory::by_name(p.to_str().unwrap(), &spec)
            .unwrap_err()
            .to_string()
            .contains("increase"));
        std::fs::write(&p, "t,x,y\n0,212,0\n1,213,0\n").unwrap();
        assert!(Trajectory::by_name(p.to_str().unwrap(), &spec).is_err());
        std::fs::write(&p, "t_s,x_mm,y_mm\n0,212,0\n1,214,0\n").unwrap();
        let t = Trajectory::by_name(p.to_str().unwrap(), &spec).unwrap();
        assert_eq!(t.at(0.5), [213.0, 0.0]);
        assert!(Trajectory::by_name("spiral", &spec).is_err());
    }
}
