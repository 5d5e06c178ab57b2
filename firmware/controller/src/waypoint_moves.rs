//! The built-in setpoint generator: rest-to-rest moves through a list of waypoints, each
//! setpoint with its exact velocity, acceleration and jerk (which the servo feeds forward).
//!
//! Two profiles ([`Profile`]):
//! * **Quintic** (the default): each move from `P` to `Q` follows `P + (Q - P)·s(τ)`,
//!   `s = 10τ³ - 15τ⁴ + 6τ⁵`, `τ = t/T`, which starts and ends with zero speed and
//!   acceleration, so the sequence never asks the servo for a jump. Peak acceleration is
//!   `10/√3 · D/T²` and peak speed `15/8 · D/T`; the duration of each move is the shortest that
//!   keeps both within the limits given. Its derivatives are the polynomial's.
//! * **Jerk-limited**: each move is the core's time-optimal straight move
//!   ([`kinematics_core::trajectory`]: speed, acceleration and jerk limited), 20-30 % shorter
//!   than the quintic at the same acceleration; what `track-5g` runs at 5 g.
//!
//! Time is an integer sample count within each move (so f32 keeps sub-nanosecond resolution
//! however long the tour runs), and the setpoints are the same on every run. During a dwell the
//! setpoint is the waypoint itself, at rest.
use heapless::Vec;
use kinematics_core::trajectory::{MotionSetpoint, TaskLimits, Tour};

use crate::setpoints::SetpointSource;

/// The jerk limit of the jerk-limited profile by default (mm/s³): 5 g is reached in 10 ms.
pub const DEFAULT_JERK_MM_S3: f32 = 5.0e6;

/// The time law of each move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Profile {
    /// `10τ³ - 15τ⁴ + 6τ⁵`: smooth, not time-optimal.
    Quintic,
    /// The time-optimal jerk-limited rest-to-rest move (`kinematics_core::jerk_profile`).
    JerkLimited,
}

/// Most waypoints a trajectory holds.
pub const MAX_WAYPOINTS: usize = 16;

/// Tool-space rest-to-rest moves, sampled at the servo rate.
#[derive(Clone, Debug)]
pub struct Trajectory {
    /// `waypoints[0]` is the start (the engaged tool position).
    waypoints: Vec<[f32; 2], MAX_WAYPOINTS>,
    /// Samples of each move (index `k` is the move from `waypoints[k]` to `waypoints[k + 1]`).
    move_samples: Vec<u32, MAX_WAYPOINTS>,
    dwell_samples: u32,
    /// Current move and the sample within move plus dwell.
    segment: usize,
    sample: u32,
    /// The planned moves of the jerk-limited profile (`None`: quintic).
    jerk_limited: Option<Tour<f32, MAX_WAYPOINTS>>,
    sample_period_s: f32,
}

impl Trajectory {
    /// Moves from `start_mm` through `waypoints_mm` (extra waypoints beyond the capacity are
    /// dropped), each limited to `accel_mm_s2` and `speed_mm_s`, resting `dwell_s` at each.
    pub fn new(
        start_mm: [f32; 2],
        waypoints_mm: &[[f32; 2]],
        accel_mm_s2: f32,
        speed_mm_s: f32,
        dwell_s: f32,
        sample_period_s: f32,
    ) -> Self {
        let mut waypoints: Vec<[f32; 2], MAX_WAYPOINTS> = Vec::new();
        let mut move_samples: Vec<u32, MAX_WAYPOINTS> = Vec::new();
        let _ = waypoints.push(start_mm);
        for w in waypoints_mm {
            let Some(&p) = waypoints.last() else { break };
            if waypoints.push(*w).is_err() {
                break;
            }
            let d = libm::hypotf(w[0] - p[0], w[1] - p[1]);
            let t_accel = libm::sqrtf(10.0 / libm::sqrtf(3.0) * d / accel_mm_s2);
            let t_speed = 15.0 / 8.0 * d / speed_mm_s;
            let t = if t_accel > t_speed { t_accel } else { t_speed };
            // Saturating: absurd limits (refused by `Settings::validate`) must not overflow.
            let _ = move_samples.push((libm::ceilf(t / sample_period_s) as u32).saturating_add(1));
        }
        Trajectory {
            waypoints,
            move_samples,
            dwell_samples: libm::ceilf(dwell_s / sample_period_s) as u32,
            segment: 0,
            sample: 0,
            jerk_limited: None,
            sample_period_s,
        }
    }

    /// Jerk-limited moves from `start_mm` through `waypoints_mm` (at most `MAX_WAYPOINTS` points
    /// including the start; later ones are dropped) within `limits`, resting `dwell_s` at each.
    /// Waypoints or limits the planner refuses (not finite, not positive) hold the start.
    pub fn jerk_limited(
        start_mm: [f32; 2],
        waypoints_mm: &[[f32; 2]],
        limits: &TaskLimits<f32>,
        dwell_s: f32,
        sample_period_s: f32,
    ) -> Self {
        let waypoints_mm = &waypoints_mm[..waypoints_mm.len().min(MAX_WAYPOINTS - 1)];
        let tour = Tour::plan(start_mm, waypoints_mm, limits, dwell_s)
            .unwrap_or_else(|_| Tour::hold(start_mm));
        let mut waypoints: Vec<[f32; 2], MAX_WAYPOINTS> = Vec::new();
        let mut move_samples: Vec<u32, MAX_WAYPOINTS> = Vec::new();
        let _ = waypoints.push(start_mm);
        for (m, w) in tour.moves().iter().zip(waypoints_mm) {
            let _ = waypoints.push(*w);
            let _ = move_samples.push(libm::ceilf(m.duration_s() / sample_period_s) as u32);
        }
        Trajectory {
            waypoints,
            move_samples,
            dwell_samples: libm::ceilf(tour.dwell_s() / sample_period_s) as u32,
            segment: 0,
            sample: 0,
            jerk_limited: Some(tour),
            sample_period_s,
        }
    }

    /// Samples until the last waypoint is reached and its dwell is over.
    pub fn total_samples(&self) -> u32 {
        self.move_samples.iter().fold(0u32, |sum, n| {
            sum.saturating_add(n.saturating_add(self.dwell_samples))
        })
    }

    /// Whether every move is done (the generator then holds the last waypoint).
    pub fn finished(&self) -> bool {
        self.segment >= self.move_samples.len()
    }

    /// The last waypoint.
    pub fn end_mm(&self) -> [f32; 2] {
        self.waypoints.last().copied().unwrap_or([0.0; 2])
    }

    /// The next setpoint's position.
    pub fn next_mm(&mut self) -> [f32; 2] {
        self.next_setpoint().position_mm
    }

    /// The next setpoint with its exact derivatives.
    pub fn next_setpoint(&mut self) -> MotionSetpoint<f32> {
        let Some(&n) = self.move_samples.get(self.segment) else {
            return MotionSetpoint::at_rest(self.end_mm());
        };
        let (p, q) = (
            self.waypoints[self.segment],
            self.waypoints[self.segment + 1],
        );
        let setpoint = match &self.jerk_limited {
            Some(tour) => match tour.moves().get(self.segment) {
                Some(m) if self.sample < n => m.at(self.sample as f32 * self.sample_period_s),
                _ => MotionSetpoint::at_rest(q),
            },
            None => {
                let tau = if self.sample >= n {
                    1.0
                } else {
                    self.sample as f32 / n as f32
                };
                // s(τ) and its derivatives in t (τ = t/T, T = n·dt).
                let s = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
                let rate = 1.0 / (n as f32 * self.sample_period_s);
                let s1 = 30.0 * tau * tau * (1.0 + tau * (-2.0 + tau)) * rate;
                let s2 = 60.0 * tau * (1.0 + tau * (-3.0 + 2.0 * tau)) * rate * rate;
                let s3 = 60.0 * (1.0 + tau * (-6.0 + 6.0 * tau)) * rate * rate * rate;
                let d = [q[0] - p[0], q[1] - p[1]];
                let in_move = self.sample < n;
                let k = |x: f32| if in_move { x } else { 0.0 };
                MotionSetpoint {
                    position_mm: [p[0] + d[0] * s, p[1] + d[1] * s],
                    velocity_mm_s: [k(d[0] * s1), k(d[1] * s1)],
                    acceleration_mm_s2: [k(d[0] * s2), k(d[1] * s2)],
                    jerk_mm_s3: [k(d[0] * s3), k(d[1] * s3)],
                }
            }
        };
        self.sample = self.sample.saturating_add(1);
        if self.sample >= n.saturating_add(self.dwell_samples) {
            self.segment += 1;
            self.sample = 0;
        }
        setpoint
    }
}

/// Never runs dry: after the last move it holds the last waypoint.
impl SetpointSource for Trajectory {
    fn next_setpoint(&mut self) -> Option<MotionSetpoint<f32>> {
        Some(Trajectory::next_setpoint(self))
    }
}

/// The test path through the paper's workspace (x 162.132..262.132 mm, y -75..75 mm): the four
/// corner regions, the diagonals and the centre, 5 mm inside the calibrated rectangle.
pub const WORKSPACE_TOUR_MM: [[f32; 2]; 8] = [
    [255.0, 68.0],
    [170.0, 68.0],
    [170.0, -68.0],
    [255.0, -68.0],
    [170.0, 68.0],
    [255.0, 0.0],
    [190.0, -30.0],
    [212.132, 0.0],
];

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::{Calibration, FiveBar, Servo};

    const DT_S: f32 = crate::SAMPLE_PERIOD_S;
    const G_MM_S2: f32 = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;

    fn tour() -> Trajectory {
        Trajectory::new(
            [212.132, 0.0],
            &WORKSPACE_TOUR_MM,
            2.0 * G_MM_S2,
            1500.0,
            0.1,
            DT_S,
        )
    }

    #[test]
    fn no_waypoints_holds_the_start() {
        let mut t = Trajectory::new([200.0, 5.0], &[], 2.0 * G_MM_S2, 1500.0, 0.1, DT_S);
        assert_eq!(t.total_samples(), 0);
        assert!(t.finished());
        for _ in 0..10 {
            assert_eq!(t.next_mm(), [200.0, 5.0]);
        }
    }

    #[test]
    fn starts_at_the_start_ends_at_the_last_waypoint_and_holds_it() {
        let mut t = tour();
        let n = t.total_samples();
        assert!(n > 1000, "{n} samples");
        assert_eq!(
            t.next_mm(),
            [212.132, 0.0],
            "the first setpoint is where the servo engaged"
        );
        for _ in 1..n {
            assert!(!t.finished());
            t.next_mm();
        }
        assert!(t.finished());
        let end = WORKSPACE_TOUR_MM[WORKSPACE_TOUR_MM.len() - 1];
        assert_eq!(t.end_mm(), end);
        for _ in 0..100 {
            assert_eq!(t.next_mm(), end);
        }
    }

    #[test]
    fn every_waypoint_is_reached_and_rested_at_for_the_dwell() {
        let mut t = tour();
        let dwell = (0.1 / DT_S) as usize;
        let points: std::vec::Vec<[f32; 2]> = (0..t.total_samples()).map(|_| t.next_mm()).collect();
        for w in WORKSPACE_TOUR_MM {
            let longest_rest = points
                .split(|p| *p != w)
                .map(|run| run.len())
                .max()
                .unwrap_or(0);
            assert!(
                longest_rest >= dwell,
                "{w:?}: rested {longest_rest} samples"
            );
        }
    }

    /// Second differences of the setpoints stay within the acceleration limit and first
    /// differences within the speed limit; the acceleration limit is what binds on the long
    /// moves (the moves are not needlessly slow).
    #[test]
    fn speed_and_acceleration_stay_within_their_limits() {
        let (accel, speed) = (2.0 * G_MM_S2, 1500.0f32);
        let mut t = tour();
        let p: std::vec::Vec<[f64; 2]> = (0..t.total_samples() + 10)
            .map(|_| t.next_mm())
            .map(|q| [q[0] as f64, q[1] as f64])
            .collect();
        let dt = DT_S as f64;
        let (mut max_v, mut max_a) = (0.0f64, 0.0f64);
        for k in 2..p.len() {
            let v = ((p[k][0] - p[k - 1][0]).powi(2) + (p[k][1] - p[k - 1][1]).powi(2)).sqrt() / dt;
            let a = ((p[k][0] - 2.0 * p[k - 1][0] + p[k - 2][0]).powi(2)
                + (p[k][1] - 2.0 * p[k - 1][1] + p[k - 2][1]).powi(2))
            .sqrt()
                / (dt * dt);
            max_v = max_v.max(v);
            max_a = max_a.max(a);
        }
        // f32 setpoints near 250 mm carry 15 nm of rounding: ~120 mm/s² in a second difference.
        assert!(
            max_a <= accel as f64 * 1.01 + 200.0,
            "peak acceleration {max_a} mm/s²"
        );
        assert!(max_v <= speed as f64 * 1.01, "peak speed {max_v} mm/s");
        assert!(
            max_a >= 0.9 * accel as f64,
            "peak acceleration only {max_a} mm/s²"
        );
    }

    #[test]
    fn waypoints_beyond_the_capacity_are_dropped() {
        let many = [[200.0f32, 0.0]; 2 * MAX_WAYPOINTS];
        let t = Trajectory::new([210.0, 0.0], &many, 2.0 * G_MM_S2, 1500.0, 0.0, DT_S);
        assert_eq!(t.move_samples.len(), MAX_WAYPOINTS - 1);
        assert_eq!(t.end_mm(), [200.0, 0.0]);
    }

    /// The servo (its jump checks at 5 g) accepts every setpoint of the tour from the engaged
    /// pose, with the encoders following the reference exactly.
    #[test]
    fn the_servo_accepts_the_whole_tour() {
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let mut servo = Servo::new(kinematics_core::ServoConfig::default()).unwrap();
        let mut encoder = cal.command_rad([212.132, 0.0], 0.05).unwrap();
        servo.engage(&cal, encoder).unwrap();
        let mut t = tour();
        for k in 0..t.total_samples() {
            let out = servo
                .step(&cal, t.next_mm(), encoder)
                .unwrap_or_else(|f| panic!("sample {k}: {f}"));
            encoder = out.reference_rad;
        }
    }

    #[test]
    fn absurd_limits_do_not_panic() {
        for (accel, speed, dwell, dt) in [
            (0.0, 1500.0, 0.1, DT_S),
            (f32::NAN, 0.0, f32::INFINITY, DT_S),
            (1.0, 1.0, 1e30, 1e-30),
        ] {
            let mut t =
                Trajectory::new([212.132, 0.0], &WORKSPACE_TOUR_MM, accel, speed, dwell, dt);
            let _ = t.total_samples();
            for _ in 0..10 {
                let _ = t.next_mm();
            }
        }
    }

    /// Both profiles' setpoints carry the derivatives of their positions (central differences
    /// of the sampled tour) within their limits, and rest where they rest.
    #[test]
    fn setpoints_carry_their_exact_derivatives() {
        let g = 5.0 * G_MM_S2;
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: g,
            jerk_mm_s3: DEFAULT_JERK_MM_S3,
        };
        for (name, mut t) in [
            (
                "quintic",
                Trajectory::new([212.132, 0.0], &WORKSPACE_TOUR_MM, g, 1500.0, 0.05, DT_S),
            ),
            (
                "jerk-limited",
                Trajectory::jerk_limited([212.132, 0.0], &WORKSPACE_TOUR_MM, &limits, 0.05, DT_S),
            ),
        ] {
            let s: std::vec::Vec<_> = (0..t.total_samples()).map(|_| t.next_setpoint()).collect();
            let (mut worst_v, mut worst_a, mut peak_a) = (0.0f32, 0.0f32, 0.0f32);
            for k in 1..s.len() - 1 {
                for i in 0..2 {
                    let fv = (s[k + 1].position_mm[i] - s[k - 1].position_mm[i]) / (2.0 * DT_S);
                    let fa = (s[k + 1].velocity_mm_s[i] - s[k - 1].velocity_mm_s[i]) / (2.0 * DT_S);
                    // The positions' f32 rounding (15 nm) over 1 ms is 15 mm/s; the jerk over a
                    // sample moves the acceleration by up to 2500 mm/s² at a switch.
                    worst_v = worst_v.max((fv - s[k].velocity_mm_s[i]).abs());
                    worst_a = worst_a.max((fa - s[k].acceleration_mm_s2[i]).abs());
                }
                peak_a = peak_a.max(libm::hypotf(
                    s[k].acceleration_mm_s2[0],
                    s[k].acceleration_mm_s2[1],
                ));
            }
            assert!(worst_v < 30.0, "{name}: {worst_v} mm/s");
            assert!(worst_a < 3000.0, "{name}: {worst_a} mm/s²");
            assert!(peak_a <= g * 1.01 && peak_a > 0.9 * g, "{name}: {peak_a}");
            assert_eq!(s[s.len() - 1].velocity_mm_s, [0.0; 2], "{name}");
        }
        // The jerk-limited tour is the shorter one at the same limits.
        let q = Trajectory::new([212.132, 0.0], &WORKSPACE_TOUR_MM, g, 1500.0, 0.05, DT_S)
            .total_samples();
        let j = Trajectory::jerk_limited([212.132, 0.0], &WORKSPACE_TOUR_MM, &limits, 0.05, DT_S)
            .total_samples();
        assert!(j < q, "{j} vs {q}");
    }
}
