//! Joint-space limits of a tool trajectory: the motors' speed and torque, checked through the
//! Jacobian and the inverse dynamics, and met by slowing the trajectory down uniformly.
//!
//! A tool speed of 1.5 m/s is a different motor speed in every corner of the workspace, and a
//! 5 g acceleration a different torque (the inertia matrix changes with the configuration and
//! the velocity-product terms with the speed squared). [`joint_peaks`] samples a planned
//! [`PathMotion`] and returns the peak joint speed ([`FiveBar::inverse_motion`], the rows of
//! `J⁻¹`) and the peak torque ([`FiveBarDynamics::torque_nm`]) of each motor.
//! [`meet_joint_limits`] then time-scales the motion by the smallest factor `k ≥ 1` that keeps
//! both within the limits: speeds scale with `1/k`, inertial and velocity-product torques with
//! `1/k²`, viscous friction with `1/k`, Coulomb friction not at all, so the factor is found by
//! iterating `k ← k·max(speed ratio, √torque ratio)` on the resampled motion (a few rounds;
//! it converges from below, the last round is verified).
//!
//! Cost: `samples + 1` IKs and inverse dynamics per round, at planning time (host tools, or the
//! firmware's setpoint task when a move starts), never in the 2 kHz step.

use crate::dynamics::FiveBarDynamics;
use crate::model::FiveBar;
use crate::path::Path;
use crate::real::Real;
use crate::trajectory::{PathMotion, TrajectoryError};

/// Largest motor speed and torque (joint side), per motor.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointLimits<T> {
    /// Largest |θ̇| (rad/s).
    pub speed_rad_s: [T; 2],
    /// Largest |τ| the trajectory may ask for (N·m): leave the feedback some headroom below the
    /// drive's limit.
    pub torque_nm: [T; 2],
}

/// Peak |speed| and |torque| of each motor along a motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointPeaks<T> {
    /// Peak |θ̇| (rad/s).
    pub speed_rad_s: [T; 2],
    /// Peak |τ| (N·m).
    pub torque_nm: [T; 2],
}

/// Peak joint speeds and torques over `samples + 1` equally spaced instants of `motion`.
pub fn joint_peaks<T: Real, P: Path<T>>(
    motion: &PathMotion<T, P>,
    model: &FiveBar<T>,
    dynamics: &FiveBarDynamics<T>,
    min_transmission: T,
    samples: usize,
) -> Result<JointPeaks<T>, TrajectoryError> {
    let n = samples.max(1);
    let step = motion.duration_s() / T::from_f64(n as f64);
    let mut peaks = JointPeaks {
        speed_rad_s: [T::ZERO; 2],
        torque_nm: [T::ZERO; 2],
    };
    for k in 0..=n {
        let s = motion.at(T::from_f64(k as f64) * step);
        let j = model
            .inverse_motion(
                s.position_mm,
                s.velocity_mm_s,
                s.acceleration_mm_s2,
                min_transmission,
            )
            .map_err(TrajectoryError::Kinematics)?;
        let tau = dynamics
            .torque_nm(&j)
            .map_err(TrajectoryError::Kinematics)?;
        for (i, t) in tau.iter().enumerate() {
            peaks.speed_rad_s[i] = peaks.speed_rad_s[i].max(j.velocity_rad_s[i].abs());
            peaks.torque_nm[i] = peaks.torque_nm[i].max(t.abs());
        }
    }
    Ok(peaks)
}

/// `motion` slowed down uniformly by the smallest factor (≥ 1) that keeps every motor within
/// `limits` at the sampled instants; `motion` itself if it already does.
pub fn meet_joint_limits<T: Real, P: Path<T>>(
    motion: &PathMotion<T, P>,
    model: &FiveBar<T>,
    dynamics: &FiveBarDynamics<T>,
    limits: &JointLimits<T>,
    min_transmission: T,
    samples: usize,
) -> Result<PathMotion<T, P>, TrajectoryError> {
    let positive = limits
        .speed_rad_s
        .iter()
        .chain(limits.torque_nm.iter())
        .all(|v| *v > T::ZERO && v.is_finite());
    if !positive {
        return Err(crate::jerk_profile::ProfileError::NonPositiveLimit.into());
    }
    let mut current = *motion;
    let mut k = T::ONE;
    for _ in 0..16 {
        let p = joint_peaks(&current, model, dynamics, min_transmission, samples)?;
        let mut speed = T::ZERO;
        let mut torque = T::ZERO;
        for i in 0..2 {
            speed = speed.max(p.speed_rad_s[i] / limits.speed_rad_s[i]);
            torque = torque.max(p.torque_nm[i] / limits.torque_nm[i]);
        }
        let ratio = speed.max(torque.sqrt());
        if !(ratio > T::ONE) {
            return Ok(current);
        }
        // A hair more than the ratio, so that the iteration ends on the feasible side.
        k = k * ratio * T::from_f64(1.0 + 1e-6);
        current = motion.time_scaled(k)?;
    }
    Err(TrajectoryError::JointLimits)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::path::Line;
    use crate::trajectory::TaskLimits;

    fn dynamics() -> FiveBarDynamics<f64> {
        FiveBarDynamics {
            motor_inertia_kg_m2: [4e-3, 4e-3],
            tool_mass_kg: 0.15,
            distal_inertia_kg_m2: [-3e-4, -3e-4],
            viscous_nm_s_per_rad: [0.02, 0.02],
            coulomb_nm: [0.05, 0.05],
            coulomb_speed_rad_s: 0.01,
        }
    }

    fn move_5g() -> PathMotion<f64, Line<f64>> {
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * 9_806.65,
            jerk_mm_s3: 5e6,
        };
        PathMotion::line([170.0, -65.0], [255.0, 68.0], &limits).unwrap()
    }

    #[test]
    fn a_tight_torque_limit_slows_the_move_until_it_holds() {
        let model = FiveBar::paper_nominal();
        let m = move_5g();
        let free = joint_peaks(&m, &model, &dynamics(), 0.05, 500).unwrap();
        assert!(free.torque_nm[0] > 1.0, "{free:?}");
        // Half the peak torque of either motor, speeds unlimited.
        let limit = 0.5 * free.torque_nm[0].max(free.torque_nm[1]);
        let limits = JointLimits {
            speed_rad_s: [1e3; 2],
            torque_nm: [limit; 2],
        };
        let slow = meet_joint_limits(&m, &model, &dynamics(), &limits, 0.05, 500).unwrap();
        let p = joint_peaks(&slow, &model, &dynamics(), 0.05, 500).unwrap();
        assert!(p.torque_nm[0] <= limit && p.torque_nm[1] <= limit, "{p:?}");
        // Not needlessly slow: the binding motor is within 1 % of its limit.
        assert!(p.torque_nm[0].max(p.torque_nm[1]) > 0.99 * limit, "{p:?}");
        // Inertial torques scale with 1/k²: about √2 slower.
        let k = slow.duration_s() / m.duration_s();
        assert!(k > 1.3 && k < 1.5, "{k}");
        // The path is the same.
        assert_eq!(
            slow.at(slow.duration_s()).position_mm,
            m.at(m.duration_s()).position_mm
        );
    }

    #[test]
    fn a_speed_limit_slows_by_its_ratio_and_loose_limits_change_nothing() {
        let model = FiveBar::paper_nominal();
        let m = move_5g();
        let free = joint_peaks(&m, &model, &dynamics(), 0.05, 500).unwrap();
        let w = free.speed_rad_s[0].max(free.speed_rad_s[1]);
        let limits = JointLimits {
            speed_rad_s: [0.5 * w; 2],
            torque_nm: [100.0; 2],
        };
        let slow = meet_joint_limits(&m, &model, &dynamics(), &limits, 0.05, 500).unwrap();
        let p = joint_peaks(&slow, &model, &dynamics(), 0.05, 500).unwrap();
        assert!(p.speed_rad_s[0].max(p.speed_rad_s[1]) <= 0.5 * w);
        let loose = JointLimits {
            speed_rad_s: [1e3; 2],
            torque_nm: [100.0; 2],
        };
        assert_eq!(
            meet_joint_limits(&m, &model, &dynamics(), &loose, 0.05, 500).unwrap(),
            m
        );
    }

    #[test]
    fn friction_above_the_limit_and_paths_out_of_reach_are_refused() {
        let model = FiveBar::paper_nominal();
        let limits = JointLimits {
            speed_rad_s: [1e3; 2],
            torque_nm: [0.04; 2],
        };
        assert_eq!(
            meet_joint_limits(&move_5g(), &model, &dynamics(), &limits, 0.05, 200),
            Err(TrajectoryError::JointLimits)
        );
        let far = PathMotion::line(
            [212.0, 0.0],
            [320.0, 0.0],
            &TaskLimits {
                speed_mm_s: 1.0,
                accel_mm_s2: 1.0,
                jerk_mm_s3: 1.0,
            },
        )
        .unwrap();
        let ok = JointLimits {
            speed_rad_s: [1e3; 2],
            torque_nm: [100.0; 2],
        };
        assert!(matches!(
            meet_joint_limits(&far, &model, &dynamics(), &ok, 0.05, 50),
            Err(TrajectoryError::Kinematics(_))
        ));
    }
}
