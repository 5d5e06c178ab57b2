//! The servo's feed-forward for one sample: the torque that keeps the motors on the trajectory
//! over the coming sample period, from the setpoints' exact derivatives.
//!
//! The torque computed at `t_k` is held until `t_k+1 = t_k + dt` (zero-order hold) while the
//! configuration, the velocities and the acceleration move on. What that torque must achieve is
//! the trajectory's velocity change over the interval, so the feed-forward is the inverse
//! dynamics of the interval's *mean* motion, from the joint states at both of its ends
//! ([`JointSample`]: angles and exact velocities `J⁻¹·v` from the setpoints' positions and
//! velocities):
//!
//! ```text
//! θ̈ = (θ̇(t_k+1) - θ̇(t_k)) / dt      θ̇ = (θ(t_k+1) - θ(t_k)) / dt       (exact means)
//! C̈ = (v(t_k+1) - v(t_k)) / dt       Ċ = (p(t_k+1) - p(t_k)) / dt        link vectors: the mean
//! ```
//! The means are exact however the jerk switches inside the interval; the configuration and the
//! velocity products are taken at the interval's middle (second order in `dt`). The setpoint
//! at `t_k+1` is the next one queued; without it (the last one queued) it is predicted from
//! the setpoint's own acceleration and jerk, `p + v·dt + a·dt²/2 + j·dt³/6`, exact within a jerk
//! phase of a straight move ([`predict`]).
//!
//! What each choice leaves: with the next setpoint the interval's mean is exact; the
//! prediction misses only the jerk switches inside the interval; derivatives taken at `t_k`
//! alone lag the interval by half a sample, and no dynamics feed-forward at all leaves the
//! whole inertial torque to the PID. `tests/servo.rs` (module `motion`) bounds the following
//! error of 5 g moves with it; `cargo bench -p host-sim --bench following` prints it on the
//! plants.
//!
//! Without identified dynamics the per-axis constant feed-forward of [`AxisGains`] is applied
//! to the same mean joint motion.
//!
//! Cost: one [`JointSample`] per step (the next one; the current one is the previous step's
//! next, kept by the servo): an IK and the rows of `J⁻¹` (`BENCH inverse_motion_f32`), the
//! means (about 30 flops), the inverse dynamics (`BENCH inverse_dynamics_f32`).

use crate::dynamics::FiveBarDynamics;
use crate::joint_motion::JointMotion;
use crate::model::FiveBar;
use crate::pid::AxisGains;
use crate::real::{wrap_angle_rad, Real};
use crate::trajectory::MotionSetpoint;
use crate::valid_model::{IkMargin, ValidFiveBar};
use crate::KinematicsError;

/// The five-bar at one setpoint: the setpoint's position and velocity, the encoder angles and
/// their rates, the link vectors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointSample<T> {
    /// The setpoint's position (mm).
    pub position_mm: [T; 2],
    /// The setpoint's velocity (mm/s).
    pub velocity_mm_s: [T; 2],
    /// The model's encoder angles there (rad; no grid correction).
    pub angle_rad: [T; 2],
    /// Their rates, `J⁻¹·v` (rad/s).
    pub velocity_rad_s: [T; 2],
    /// Proximal links `A - A0`, `B - B0` (mm).
    pub proximal_mm: [[T; 2]; 2],
    /// Distal links `C - A`, `C - B` (mm).
    pub distal_mm: [[T; 2]; 2],
}

impl<T: Real> JointSample<T> {
    /// All zero (a slot to [`JointSample::solve`] into).
    pub fn zero() -> Self {
        let z = [T::ZERO; 2];
        JointSample {
            position_mm: z,
            velocity_mm_s: z,
            angle_rad: z,
            velocity_rad_s: z,
            proximal_mm: [z; 2],
            distal_mm: [z; 2],
        }
    }

    /// The joint state at `setpoint` (its acceleration and jerk are not needed); the IK's
    /// checks.
    pub fn at(
        model: &FiveBar<T>,
        setpoint: &MotionSetpoint<T>,
        min_transmission: T,
    ) -> Result<Self, KinematicsError> {
        let mut s = Self::zero();
        s.solve(model, setpoint, min_transmission)?;
        Ok(s)
    }

    /// [`JointSample::at`] in place (the servo keeps two slots and avoids copying them); on
    /// `Err` the slot is left as it was.
    #[inline]
    pub fn solve(
        &mut self,
        model: &FiveBar<T>,
        setpoint: &MotionSetpoint<T>,
        min_transmission: T,
    ) -> Result<(), KinematicsError> {
        let m = model.inverse_rates(
            setpoint.position_mm,
            setpoint.velocity_mm_s,
            min_transmission,
        )?;
        self.set(setpoint, &m);
        Ok(())
    }

    /// [`JointSample::solve`] with a model and margin checked once ([`ValidFiveBar::inverse_rates`]).
    #[inline]
    pub fn solve_valid(
        &mut self,
        model: &ValidFiveBar<T>,
        setpoint: &MotionSetpoint<T>,
        margin: IkMargin<T>,
    ) -> Result<(), KinematicsError> {
        let m = model.inverse_rates(setpoint.position_mm, setpoint.velocity_mm_s, margin)?;
        self.set(setpoint, &m);
        Ok(())
    }

    /// Stores a solved IK's joint state for `setpoint`.
    #[inline(always)]
    fn set(&mut self, setpoint: &MotionSetpoint<T>, m: &JointMotion<T>) {
        self.position_mm = setpoint.position_mm;
        self.velocity_mm_s = setpoint.velocity_mm_s;
        self.angle_rad = m.angle_rad;
        self.velocity_rad_s = m.velocity_rad_s;
        self.proximal_mm = m.proximal_mm;
        self.distal_mm = m.distal_mm;
    }

    /// Whether it was computed for `setpoint` (bit for bit: position and velocity).
    pub fn is_for(&self, setpoint: &MotionSetpoint<T>) -> bool {
        #[allow(clippy::float_cmp)] // the same numbers, not close ones
        let same = self.position_mm == setpoint.position_mm
            && self.velocity_mm_s == setpoint.velocity_mm_s;
        same
    }
}

/// The setpoint `dt_s` after `setpoint`, from its own derivatives (exact within a jerk phase of
/// a straight move, to fourth order in `dt_s` on a contour).
#[inline]
pub fn predict<T: Real>(setpoint: &MotionSetpoint<T>, dt_s: T) -> MotionSetpoint<T> {
    let (half, sixth) = (T::HALF, T::from_f64(1.0 / 6.0));
    let (p, v, a, j) = (
        setpoint.position_mm,
        setpoint.velocity_mm_s,
        setpoint.acceleration_mm_s2,
        setpoint.jerk_mm_s3,
    );
    let mut next = *setpoint;
    for i in 0..2 {
        next.position_mm[i] = p[i] + (v[i] + (a[i] * half + j[i] * sixth * dt_s) * dt_s) * dt_s;
        next.velocity_mm_s[i] = v[i] + (a[i] + j[i] * half * dt_s) * dt_s;
        next.acceleration_mm_s2[i] = a[i] + j[i] * dt_s;
    }
    next
}

/// The mean joint motion over the interval from `now` to `next`, `1 / rate_hz` apart (module
/// doc). The servo passes the reciprocal of its sample period, computed once (no division here).
#[inline]
pub fn interval_motion<T: Real>(
    now: &JointSample<T>,
    next: &JointSample<T>,
    rate_hz: T,
) -> JointMotion<T> {
    let rate = rate_hz;
    let half = T::HALF;
    let mean = |a: [T; 2], b: [T; 2]| [(a[0] + b[0]) * half, (a[1] + b[1]) * half];
    let diff = |a: [T; 2], b: [T; 2]| [(b[0] - a[0]) * rate, (b[1] - a[1]) * rate];
    JointMotion {
        angle_rad: now.angle_rad,
        velocity_rad_s: [
            wrap_angle_rad(next.angle_rad[0] - now.angle_rad[0]) * rate,
            wrap_angle_rad(next.angle_rad[1] - now.angle_rad[1]) * rate,
        ],
        acceleration_rad_s2: diff(now.velocity_rad_s, next.velocity_rad_s),
        proximal_mm: [
            mean(now.proximal_mm[0], next.proximal_mm[0]),
            mean(now.proximal_mm[1], next.proximal_mm[1]),
        ],
        distal_mm: [
            mean(now.distal_mm[0], next.distal_mm[0]),
            mean(now.distal_mm[1], next.distal_mm[1]),
        ],
        // The mean velocity: the inverse dynamics do not use it (the velocity products are in
        // the accelerations), kept for a complete motion.
        tool_velocity_mm_s: diff(now.position_mm, next.position_mm),
        tool_acceleration_mm_s2: diff(now.velocity_mm_s, next.velocity_mm_s),
    }
}

/// The feed-forward torque (N·m) for the mean motion of an interval: the identified inverse
/// dynamics if given, else each axis' constant inertia, viscous and Coulomb feed-forward.
#[inline]
pub fn feed_forward_nm(
    motion: &JointMotion<f32>,
    dynamics: Option<&FiveBarDynamics<f32>>,
    axes: &[AxisGains; 2],
) -> Result<[f32; 2], KinematicsError> {
    match dynamics {
        Some(d) => d.torque_nm(motion),
        None => {
            let (w, a) = (motion.velocity_rad_s, motion.acceleration_rad_s2);
            Ok([
                axes[0].feed_forward_nm(w[0], a[0]),
                axes[1].feed_forward_nm(w[1], a[1]),
            ])
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::path::Circle;
    use crate::trajectory::{PathMotion, TaskLimits};

    /// The mean joint velocity and acceleration over an interval are what the trajectory's
    /// joint motion averages to (integrated finely), and the prediction is exact inside a jerk
    /// phase.
    #[test]
    fn interval_means_are_the_exact_averages() {
        let m = FiveBar::<f64>::paper_nominal();
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * 9_806.65,
            jerk_mm_s3: 3e7,
        };
        let c = Circle {
            centre_mm: [212.0, 0.0],
            radius_mm: 40.0,
            start_rad: 1.0,
            turns: 1.0,
        };
        let traj = PathMotion::plan(c, &limits, 4000).unwrap();
        let dt = 5e-4;
        let (mut worst_acc, mut scale) = (0.0f64, 0.0f64);
        for k in 0..150 {
            let t = traj.duration_s() * k as f64 / 150.0;
            let (a, b) = (traj.at(t), traj.at(t + dt));
            let now = JointSample::at(&m, &a, 0.05).unwrap();
            let next = JointSample::at(&m, &b, 0.05).unwrap();
            let mean = interval_motion(&now, &next, 1.0 / dt);
            // The average of θ̈ over the interval, by fine quadrature.
            let n = 64;
            let mut avg = [0.0; 2];
            for q in 0..n {
                let s = traj.at(t + (q as f64 + 0.5) / n as f64 * dt);
                let j = m
                    .inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.05)
                    .unwrap();
                for (sum, a) in avg.iter_mut().zip(j.acceleration_rad_s2) {
                    *sum += a / n as f64;
                }
            }
            for (i, want) in avg.iter().enumerate() {
                worst_acc = worst_acc.max((mean.acceleration_rad_s2[i] - want).abs());
                scale = scale.max(want.abs());
            }
            assert_eq!(now.angle_rad, m.inverse(a.position_mm, 0.05).unwrap());
        }
        assert!(
            scale > 100.0 && worst_acc < 1e-3 * scale,
            "{worst_acc} of {scale}"
        );
        // Prediction: on the circle to fourth order in dt, on a straight move exact inside a
        // jerk phase.
        let t = 0.1;
        let (p, q) = (predict(&traj.at(t), dt), traj.at(t + dt));
        assert!(
            (p.position_mm[0] - q.position_mm[0]).abs() < 1e-6
                && (p.velocity_mm_s[1] - q.velocity_mm_s[1]).abs() < 1e-2,
            "{p:?} {q:?}"
        );
        let line = PathMotion::line([170.0, -60.0], [250.0, 60.0], &limits).unwrap();
        let t = 0.5 * line.law().phases_s().0;
        let (p, q) = (predict(&line.at(t), dt), line.at(t + dt));
        for i in 0..2 {
            assert!(
                (p.position_mm[i] - q.position_mm[i]).abs() < 1e-12
                    && (p.velocity_mm_s[i] - q.velocity_mm_s[i]).abs() < 1e-9
            );
        }
        assert!(JointSample::at(&m, &traj.at(t), 0.05)
            .unwrap()
            .is_for(&traj.at(t)));
        assert!(!JointSample::at(&m, &traj.at(t), 0.05).unwrap().is_for(&q));
    }

    #[test]
    fn without_dynamics_the_gains_feed_forward_acts_on_the_mean_motion() {
        let m = FiveBar::<f32>::paper_nominal();
        let a = MotionSetpoint {
            position_mm: [210.0, 5.0],
            velocity_mm_s: [300.0, -200.0],
            acceleration_mm_s2: [10_000.0, 20_000.0],
            jerk_mm_s3: [0.0; 2],
        };
        let now = JointSample::at(&m, &a, 0.05).unwrap();
        let next = JointSample::at(&m, &predict(&a, 5e-4), 0.05).unwrap();
        let mean = interval_motion(&now, &next, 1.0 / 5e-4);
        let g = AxisGains {
            kp_nm_per_rad: 0.0,
            ki_nm_per_rad_s: 0.0,
            kd_nm_s_per_rad: 0.0,
            inertia_ff_kg_m2: 0.01,
            viscous_ff_nm_s_per_rad: 0.1,
            coulomb_ff_nm: 0.0,
            coulomb_ff_speed_rad_s: 0.01,
            torque_limit_nm: 8.0,
            integral_limit_nm: 1.0,
            observer_bandwidth_rad_s: 0.0,
            observer_inertia_kg_m2: 0.0,
        };
        let tau = feed_forward_nm(&mean, None, &[g; 2]).unwrap();
        for (i, t) in tau.iter().enumerate() {
            let want = 0.01 * mean.acceleration_rad_s2[i] + 0.1 * mean.velocity_rad_s[i];
            assert!((t - want).abs() < 1e-6 * (1.0 + want.abs()));
        }
    }
}
