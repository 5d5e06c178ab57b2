//! The built-in setpoint generator: rest-to-rest quintic moves through a list of waypoints.
//!
//! Each move from `P` to `Q` follows `P + (Q - P)·s(τ)`, `s = 10τ³ - 15τ⁴ + 6τ⁵`, `τ = t/T`,
//! which starts and ends with zero speed and acceleration, so the sequence never asks the servo
//! for a jump. Peak acceleration is `10/√3 · D/T²` and peak speed `15/8 · D/T`; the duration of
//! each move is the shortest that keeps both within the limits given. Time is an integer sample
//! count, so the setpoints are the same on every run.
use heapless::Vec;

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
            let _ = move_samples.push(libm::ceilf(t / sample_period_s) as u32 + 1);
        }
        Trajectory {
            waypoints,
            move_samples,
            dwell_samples: libm::ceilf(dwell_s / sample_period_s) as u32,
            segment: 0,
            sample: 0,
        }
    }

    /// Samples until the last waypoint is reached and its dwell is over.
    pub fn total_samples(&self) -> u32 {
        self.move_samples.iter().map(|n| n + self.dwell_samples).sum()
    }

    /// Whether every move is done (the generator then holds the last waypoint).
    pub fn finished(&self) -> bool {
        self.segment >= self.move_samples.len()
    }

    /// The last waypoint.
    pub fn end_mm(&self) -> [f32; 2] {
        self.waypoints.last().copied().unwrap_or([0.0; 2])
    }

    /// The next setpoint.
    pub fn next_mm(&mut self) -> [f32; 2] {
        let Some(&n) = self.move_samples.get(self.segment) else {
            return self.end_mm();
        };
        let (p, q) = (self.waypoints[self.segment], self.waypoints[self.segment + 1]);
        let tau = if self.sample >= n { 1.0 } else { self.sample as f32 / n as f32 };
        let s = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
        self.sample += 1;
        if self.sample >= n + self.dwell_samples {
            self.segment += 1;
            self.sample = 0;
        }
        [p[0] + (q[0] - p[0]) * s, p[1] + (q[1] - p[1]) * s]
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
