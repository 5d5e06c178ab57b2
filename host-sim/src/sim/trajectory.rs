//! Task-space setpoint trajectories for the closed loop: built-in test motions and CSV files.
//!
//! Built-ins (about the centre of the machine's workspace, [`crate::machine_spec::Workspace`];
//! inside the paper's; all starting at rest so the servo's setpoint-acceleration check never
//! trips at the start):
//! * `circle`: the slow circle, radius 40 mm about the workspace centre, 4 s per turn
//!   (63 mm/s), phase `ω·(t - τ(1 - e^(-t/τ)))` with τ = 0.3 s so the speed ramps up smoothly;
//! * `figure8`: a lemniscate of Gerono (±45 mm in x, ±60 mm in y), 2 s per loop, same ramp;
//! * `p2p`: point-to-point moves from the centre around the corners 10 mm inside the workspace
//!   and back, trapezoidal speed profiles at exactly the machine's rated acceleration (5 g,
//!   49 m/s², on the paper machine) and 1.5 m/s, 0.1 s dwell at each point (on a polygon
//!   workspace, the bounding rectangle's inset corners pulled towards the centre until they
//!   are 10 mm inside);
//! * a file: CSV with header `t_s,x_mm,y_mm`, times strictly increasing, linearly interpolated;
//!   before the first and after the last sample the end points are held.
//!
//! Cost: a few transcendental calls per setpoint.

use super::SimError;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use std::f64::consts::TAU;
use std::path::Path;

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
        Move { t0_s, from_mm, to_mm, t_acc_s: t_acc, t_cruise_s: t_cruise, v_peak_mm_s: v }
    }

    fn duration_s(&self) -> f64 {
        2.0 * self.t_acc_s + self.t_cruise_s
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

/// A setpoint source.
#[derive(Clone, Debug)]
pub enum Trajectory {
    Circle { centre_mm: [f64; 2], radius_mm: f64, period_s: f64 },
    Figure8 { centre_mm: [f64; 2], half_x_mm: f64, half_y_mm: f64, period_s: f64 },
    PointToPoint { moves: Vec<Move>, dwell_s: f64 },
    Samples { name: String, t_s: Vec<f64>, xy_mm: Vec<[f64; 2]> },
}

/// The ramped phase of the periodic built-ins: starts at rest, reaches `ω` after a few τ.
fn ramped_phase(omega: f64, t: f64) -> f64 {
    omega * (t - RAMP_S * (1.0 - (-t / RAMP_S).exp()))
}

impl Trajectory {
    /// `circle`, `figure8`, `p2p` (on `spec`'s workspace) or a CSV file path.
    pub fn by_name(name: &str, spec: &MachineSpec) -> Result<Self, SimError> {
        let centre_mm = spec.workspace.centre_mm();
        match name {
            "circle" => Ok(Trajectory::Circle { centre_mm, radius_mm: 40.0, period_s: 4.0 }),
            "figure8" => Ok(Trajectory::Figure8 { centre_mm, half_x_mm: 45.0, half_y_mm: 60.0, period_s: 2.0 }),
            "p2p" => {
                let (x, y, d) = (spec.workspace.x_mm, spec.workspace.y_mm, P2P_INSET_MM);
                let (lo, hi) = ([x[0] + d, y[0] + d], [x[1] - d, y[1] - d]);
                // The inset rectangle's corners; on a polygon workspace, pulled inside it.
                let ws = &spec.workspace;
                let corners = [lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]].map(|p| if ws.is_rectangle { p } else { ws.pulled_inside(p, d) });
                let pts = [centre_mm, corners[0], corners[1], corners[2], corners[3], centre_mm];
                let dwell = 0.1;
                let mut t = dwell;
                let mut moves = Vec::new();
                for w in pts.windows(2) {
                    let m = Move::new(t, w[0], w[1], spec.max_acceleration_g * STANDARD_GRAVITY_MM_S2, P2P_SPEED_MM_S);
                    t += m.duration_s() + dwell;
                    moves.push(m);
                }
                Ok(Trajectory::PointToPoint { moves, dwell_s: dwell })
            }
            path => {
                if !Path::new(path).exists() {
                    return Err(SimError::UnknownTrajectory(path.to_string()));
                }
                Trajectory::from_csv(path)
            }
        }
    }

    fn from_csv(path: &str) -> Result<Self, SimError> {
        let err = |m: String| SimError::TrajectoryFile(m);
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read trajectory {path}: {e}")))?;
        let mut r = csv::ReaderBuilder::new().trim(csv::Trim::All).comment(Some(b'#')).from_reader(text.as_bytes());
        let h = r.headers().map_err(|e| err(format!("trajectory {path}: no header: {e}")))?.clone();
        if h.iter().collect::<Vec<_>>() != ["t_s", "x_mm", "y_mm"] {
            let found = h.iter().collect::<Vec<_>>().join(",");
            return Err(err(format!("trajectory {path}: header must be 't_s,x_mm,y_mm', not '{found}'")));
        }
        let (mut ts, mut xy) = (Vec::new(), Vec::new());
        for rec in r.records() {
            let rec = rec.map_err(|e| err(format!("trajectory {path}: {e}")))?;
            let line = rec.position().map(|p| p.line()).unwrap_or(0);
            let num = |k: usize| -> Result<f64, SimError> {
                let s = rec.get(k).unwrap_or("");
                let v: f64 = s.parse().map_err(|_| err(format!("trajectory {path} line {line}: '{s}' is not a number")))?;
                if !v.is_finite() {
                    return Err(err(format!("trajectory {path} line {line}: '{s}' is not finite")));
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
            return Err(err(format!("trajectory {path}: needs at least two samples")));
        }
        Ok(Trajectory::Samples { name: path.to_string(), t_s: ts, xy_mm: xy })
    }

    pub fn name(&self) -> String {
        match self {
            Trajectory::Circle { .. } => "circle".into(),
            Trajectory::Figure8 { .. } => "figure8".into(),
            Trajectory::PointToPoint { .. } => "p2p".into(),
            Trajectory::Samples { name, .. } => name.clone(),
        }
    }

    /// How long the trajectory naturally lasts (s): the default `--seconds`.
    pub fn natural_duration_s(&self) -> f64 {
        match self {
            Trajectory::Circle { period_s, .. } => period_s + 2.0 * RAMP_S,
            Trajectory::Figure8 { period_s, .. } => 2.0 * period_s,
            Trajectory::PointToPoint { moves, dwell_s } => moves.last().map(|m| m.t0_s + m.duration_s() + dwell_s).unwrap_or(0.0),
            Trajectory::Samples { t_s, .. } => *t_s.last().unwrap_or(&0.0),
        }
    }

    /// The setpoint at time `t_s` (mm).
    pub fn at(&self, t_s: f64) -> [f64; 2] {
        let t = t_s.max(0.0);
        match self {
            Trajectory::Circle { centre_mm, radius_mm, period_s } => {
                let p = ramped_phase(TAU / period_s, t);
                [centre_mm[0] + radius_mm * p.cos(), centre_mm[1] + radius_mm * p.sin()]
            }
            Trajectory::Figure8 { centre_mm, half_x_mm, half_y_mm, period_s } => {
                let p = ramped_phase(TAU / period_s, t);
                [centre_mm[0] + half_x_mm * p.sin(), centre_mm[1] + half_y_mm * (2.0 * p).sin()]
            }
            Trajectory::PointToPoint { moves, .. } => {
                let Some(first) = moves.first() else { return [0.0; 2] };
                let mut pos = first.from_mm;
                for m in moves {
                    if t < m.t0_s {
                        break;
                    }
                    let d = (m.to_mm[0] - m.from_mm[0]).hypot(m.to_mm[1] - m.from_mm[1]);
                    let s = if d > 0.0 { m.distance_mm(t - m.t0_s) / d } else { 1.0 };
                    pos = [m.from_mm[0] + s * (m.to_mm[0] - m.from_mm[0]), m.from_mm[1] + s * (m.to_mm[1] - m.from_mm[1])];
                }
                pos
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
            let (p0, p1, p2) = (tr.at(k as f64 * dt), tr.at((k - 1) as f64 * dt), tr.at((k - 2) as f64 * dt));
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

    #[test]
    fn bad_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        std::fs::write(&p, "t_s,x_mm,y_mm\n0,212,0\n0,213,0\n").unwrap();
        let spec = MachineSpec::paper();
        assert!(Trajectory::by_name(p.to_str().unwrap(), &spec).unwrap_err().to_string().contains("increase"));
        std::fs::write(&p, "t,x,y\n0,212,0\n1,213,0\n").unwrap();
        assert!(Trajectory::by_name(p.to_str().unwrap(), &spec).is_err());
        std::fs::write(&p, "t_s,x_mm,y_mm\n0,212,0\n1,214,0\n").unwrap();
        let t = Trajectory::by_name(p.to_str().unwrap(), &spec).unwrap();
        assert_eq!(t.at(0.5), [213.0, 0.0]);
        assert!(Trajectory::by_name("spiral", &spec).is_err());
    }
}
