//! The servo's feed-forward for one sample: the torque that keeps the motors on the trajectory
//! over the coming sample period, from the setpoint's exact derivatives.
//!
//! The torque computed at `t_k` is held until `t_k + dt` (zero-order hold), while the
//! configuration, the velocities and the acceleration move on. The torque that brings the
//! machine to the trajectory's state at `t_k + dt` is, to second order in `dt`, the inverse
//! dynamics at the *middle* of that interval: its configuration, its velocity and its
//! acceleration. The setpoint carries the exact position, velocity, acceleration and jerk at
//! `t_k`, and within a jerk phase the trajectory is a cubic, so the mid-interval state
//! (`h = dt/2`) is exact:
//!
//! ```text
//! p_m = p + v·h + a·h²/2 + j·h³/6     v_m = v + a·h + j·h²/2     a_m = a + j·h
//! ```
//! One [`FiveBar::inverse_motion`] there gives the joint motion for the inverse dynamics, and
//! the reference angle at `t_k` follows back along the same motion,
//! `θ(t_k) = θ_m - θ̇_m·h + θ̈_m·h²/2` (the dropped third-order term is below 1e-7 rad at 5 g
//! with a jerk of 5e6 mm/s³; at rest it is exactly the IK of the setpoint).
//!
//! Measured on the five-bar with exact dynamics (ideal plant, 5 g tour, 160 Hz loop): 1.6 µm
//! worst following error this way; 9.5 µm with the same derivatives evaluated at `t_k`'s
//! configuration; 0.25 µm with an exact one-sample look-ahead (what remains here is the jerk
//! switching inside an interval, which the cubic cannot see). Without any dynamics
//! feed-forward: over 300 µm.
//!
//! Without identified dynamics the per-axis constant feed-forward of [`AxisGains`] is applied
//! to the same mid-interval joint motion.
//!
//! Cost: one `inverse_motion` (`BENCH inverse_motion_f32`), the inverse dynamics (`BENCH
//! inverse_dynamics_f32`) and about 30 flops.

use crate::dynamics::FiveBarDynamics;
use crate::joint_motion::JointMotion;
use crate::model::FiveBar;
use crate::pid::AxisGains;
use crate::real::Real;
use crate::trajectory::MotionSetpoint;
use crate::KinematicsError;

/// The motion over one hold interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HoldInterval<T> {
    /// The model's encoder angles at the setpoint's instant (no grid correction).
    pub angle_rad: [T; 2],
    /// The joint motion at the middle of the interval.
    pub mid: JointMotion<T>,
}

/// The hold interval of length `dt_s` that starts at `setpoint`.
#[inline]
pub fn hold_interval<T: Real>(
    model: &FiveBar<T>,
    setpoint: &MotionSetpoint<T>,
    dt_s: T,
    min_transmission: T,
) -> Result<HoldInterval<T>, KinematicsError> {
    let h = dt_s * T::HALF;
    let (half, sixth) = (T::HALF, T::from_f64(1.0 / 6.0));
    let (p, v, a, j) = (setpoint.position_mm, setpoint.velocity_mm_s, setpoint.acceleration_mm_s2, setpoint.jerk_mm_s3);
    let mut pm = [T::ZERO; 2];
    let mut vm = [T::ZERO; 2];
    let mut am = [T::ZERO; 2];
    for i in 0..2 {
        pm[i] = p[i] + (v[i] + (a[i] * half + j[i] * sixth * h) * h) * h;
        vm[i] = v[i] + (a[i] + j[i] * half * h) * h;
        am[i] = a[i] + j[i] * h;
    }
    let mid = model.inverse_motion(pm, vm, am, min_transmission)?;
    let mut angle_rad = [T::ZERO; 2];
    for (i, angle) in angle_rad.iter_mut().enumerate() {
        *angle = mid.angle_rad[i] - (mid.velocity_rad_s[i] - mid.acceleration_rad_s2[i] * half * h) * h;
    }
    Ok(HoldInterval { angle_rad, mid })
}

/// The feed-forward torque (N·m) over `interval`: the identified inverse dynamics if given,
/// else each axis' constant inertia, viscous and Coulomb feed-forward from its gains.
#[inline]
pub fn feed_forward_nm(
    interval: &HoldInterval<f32>,
    dynamics: Option<&FiveBarDynamics<f32>>,
    axes: &[AxisGains; 2],
) -> Result<[f32; 2], KinematicsError> {
    match dynamics {
        Some(d) => d.torque_nm(&interval.mid),
        None => {
            let m = &interval.mid;
            let mut tau = [0.0f32; 2];
            for (i, (t, g)) in tau.iter_mut().zip(axes).enumerate() {
                let w = m.velocity_rad_s[i];
                *t = g.inertia_ff_kg_m2 * m.acceleration_rad_s2[i]
                    + g.viscous_ff_nm_s_per_rad * w
                    + g.coulomb_ff_nm * w / (w.abs() + g.coulomb_ff_speed_rad_s);
            }
            Ok(tau)
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::path::Circle;
    use crate::trajectory::{PathMotion, TaskLimits};

    /// The reference angle is the IK at the setpoint's instant, the mid-interval motion the
    /// exact one half a sample later.
    #[test]
    fn the_interval_is_the_trajectory_half_a_sample_ahead() {
        let m = FiveBar::<f64>::paper_nominal();
        let limits = TaskLimits { speed_mm_s: 1500.0, accel_mm_s2: 5.0 * 9_806.65, jerk_mm_s3: 5e6 };
        let c = Circle { centre_mm: [212.0, 0.0], radius_mm: 40.0, start_rad: 1.0, turns: 1.0 };
        let traj = PathMotion::plan(c, &limits, 2000).unwrap();
        let dt = 5e-4;
        let (mut worst_angle, mut worst_rate) = (0.0f64, 0.0f64);
        for k in 0..200 {
            let t = traj.duration_s() * k as f64 / 200.0;
            let iv = hold_interval(&m, &traj.at(t), dt, 0.05).unwrap();
            let at_t = m.inverse(traj.at(t).position_mm, 0.05).unwrap();
            let s = traj.at(t + dt / 2.0);
            let mid = m.inverse_motion(s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, 0.05).unwrap();
            for (i, want) in at_t.iter().enumerate() {
                worst_angle = worst_angle.max((iv.angle_rad[i] - want).abs());
                worst_rate = worst_rate.max((iv.mid.velocity_rad_s[i] - mid.velocity_rad_s[i]).abs());
            }
        }
        // Third-order remainder of the back-shift; the cubic is exact except across a switch.
        assert!(worst_angle < 1e-7, "{worst_angle}");
        assert!(worst_rate < 1e-3, "{worst_rate}");
        // At rest: exactly the IK.
        let rest = MotionSetpoint::at_rest([200.0, 10.0]);
        let iv = hold_interval(&m, &rest, dt, 0.05).unwrap();
        assert_eq!(iv.angle_rad, m.inverse([200.0, 10.0], 0.05).unwrap());
    }

    #[test]
    fn without_dynamics_the_gains_feed_forward_acts_on_the_mid_interval_motion() {
        let m = FiveBar::<f32>::paper_nominal();
        let s = MotionSetpoint { position_mm: [210.0, 5.0], velocity_mm_s: [300.0, -200.0], acceleration_mm_s2: [10_000.0, 20_000.0], jerk_mm_s3: [0.0; 2] };
        let iv = hold_interval(&m, &s, 5e-4, 0.05).unwrap();
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
        };
        let tau = feed_forward_nm(&iv, None, &[g; 2]).unwrap();
        for (i, t) in tau.iter().enumerate() {
            let want = 0.01 * iv.mid.acceleration_rad_s2[i] + 0.1 * iv.mid.velocity_rad_s[i];
            assert!((t - want).abs() < 1e-6 * (1.0 + want.abs()));
        }
    }
}
