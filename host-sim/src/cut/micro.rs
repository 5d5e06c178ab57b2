//! The micro's limits, from its own model: its workspace less the margin, the task-space speed
//! at which a joint reaches its speed limit (the worst point and direction of the workspace),
//! its rated acceleration (checked against the drives' torque through the inverse dynamics),
//! and the joint limits the executed motion is checked against.
//!
//! Why derived and not stated: a tool speed of 1.5 m/s is a different motor speed in every
//! corner of a five-bar's workspace, and a 5 g acceleration a different torque. The split
//! plans in task space (the micro's offset is the tool minus the gantry), so it needs task-space
//! limits that hold everywhere: the smallest over a lattice of the workspace and 16 directions.

use super::CutError;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use crate::plant::{Plant, PlantConfig};
use kinematics_core::{ConvexWorkspace, FiveBar, FiveBarDynamics};
use serde::Serialize;

/// The share of the drives' torque a plan may use (the rest is the feedback's).
pub const TORQUE_SHARE: f64 = 0.8;
/// The largest tool speed the servo accepts is 3 m/s; the micro is planned within 90 % of it.
const SERVO_SPEED_MM_S: f64 = 3000.0 * 0.9;

/// The micro's limits (see the module doc).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MicroLimits {
    /// Its workspace (micro frame, mm).
    #[serde(skip)]
    pub region: ConvexWorkspace<f64>,
    /// The workspace's centre: where the micro sits when the tool is on the gantry's point.
    pub centre_mm: [f64; 2],
    /// How far inside the workspace it must stay (mm).
    pub margin_mm: f64,
    /// The width of the workspace less twice the margin along x and y (mm).
    pub width_mm: [f64; 2],
    /// The rated acceleration (mm/s²), within the torque limits everywhere.
    pub accel_mm_s2: f64,
    /// The task-space speed within which no joint exceeds its speed limit (mm/s).
    pub speed_mm_s: f64,
    /// Joint speed limit (rad/s).
    pub joint_speed_rad_s: f64,
    /// The drives' torque limits (N·m).
    pub torque_limit_nm: [f64; 2],
    /// The largest torque the rated acceleration at the speed limit needs anywhere (N·m).
    pub torque_at_rating_nm: f64,
}

/// Points of the workspace `margin` inside it: a lattice of `n × n` over its bounding box.
fn lattice(region: &ConvexWorkspace<f64>, margin: f64, n: usize) -> Vec<[f64; 2]> {
    let (x, y) = region.bounds_mm();
    let (lo, hi) = ([x[0], y[0]], [x[1], y[1]]);
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = [
                lo[0] + (hi[0] - lo[0]) * i as f64 / (n - 1) as f64,
                lo[1] + (hi[1] - lo[1]) * j as f64 / (n - 1) as f64,
            ];
            if region.contains(p, margin) {
                out.push(p);
            }
        }
    }
    out
}

impl MicroLimits {
    /// The limits of the micro of `spec` as `plant` builds it (see the module doc).
    pub fn derive(spec: &MachineSpec, plant: &PlantConfig) -> Result<MicroLimits, CutError> {
        let region = spec.workspace.region;
        let margin = spec.gantry.micro_margin_mm;
        let (x, y) = region.bounds_mm();
        let width_mm = [x[1] - x[0] - 2.0 * margin, y[1] - y[0] - 2.0 * margin];
        if !(width_mm[0] > 0.0 && width_mm[1] > 0.0) {
            return Err(CutError::Invalid(format!(
                "'gantry.micro_margin_mm' = {margin} leaves nothing of the micro's workspace"
            )));
        }
        let model: FiveBar<f64> = spec.nominal;
        let dynamics: FiveBarDynamics<f64> = Plant::new(plant, 1).true_dynamics();
        let points = lattice(&region, margin, 9);
        if points.is_empty() {
            return Err(CutError::Invalid(
                "no point of the micro's workspace lies inside the margin".into(),
            ));
        }
        let joint = spec.gantry.micro_joint_speed_rad_s;
        let dirs: Vec<[f64; 2]> = (0..16)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 16.0;
                [a.cos(), a.sin()]
            })
            .collect();
        let mut speed = SERVO_SPEED_MM_S;
        for p in &points {
            for u in &dirs {
                let m = model
                    .inverse_motion(*p, *u, [0.0; 2], spec.min_transmission)
                    .map_err(|e| CutError::Invalid(format!("the micro at {p:?} mm: {e}")))?;
                let w = m.velocity_rad_s[0].abs().max(m.velocity_rad_s[1].abs());
                if w > 0.0 {
                    speed = speed.min(joint / w);
                }
            }
        }
        let torque_limit_nm = [plant.drive_1.torque_limit_nm, plant.drive_2.torque_limit_nm];
        // The rating at the speed limit must fit the torque share everywhere: the speed is
        // lowered first (the velocity-product torques grow with its square), the rating only
        // if even slow motion cannot have it.
        let rated = spec.max_acceleration_g * STANDARD_GRAVITY_MM_S2;
        let peak_torque = |speed: f64, accel: f64| -> Result<f64, CutError> {
            let mut worst = 0.0f64;
            for p in &points {
                for u in dirs.iter().step_by(2) {
                    for w in dirs.iter().step_by(2) {
                        let v = [u[0] * speed, u[1] * speed];
                        let a = [w[0] * accel, w[1] * accel];
                        let m = model
                            .inverse_motion(*p, v, a, spec.min_transmission)
                            .map_err(|e| {
                                CutError::Invalid(format!("the micro at {p:?} mm: {e}"))
                            })?;
                        let tau = dynamics
                            .torque_nm(&m)
                            .map_err(|e| CutError::Invalid(format!("the micro's dynamics: {e}")))?;
                        for (k, t) in tau.iter().enumerate() {
                            worst = worst.max(t.abs() / torque_limit_nm[k]);
                        }
                    }
                }
            }
            Ok(worst)
        };
        let mut accel = rated;
        let floor_speed = 0.1 * speed;
        while peak_torque(floor_speed, accel)? > TORQUE_SHARE {
            accel *= 0.9;
            if accel < 0.05 * rated {
                return Err(CutError::Invalid(format!(
                    "the micro's drives cannot accelerate it even at {:.2} g",
                    accel / STANDARD_GRAVITY_MM_S2
                )));
            }
        }
        if peak_torque(speed, accel)? > TORQUE_SHARE {
            let (mut lo, mut hi) = (floor_speed, speed);
            for _ in 0..30 {
                let mid = 0.5 * (lo + hi);
                if peak_torque(mid, accel)? <= TORQUE_SHARE {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            speed = lo;
        }
        let share = peak_torque(speed, accel)?;
        Ok(MicroLimits {
            region,
            centre_mm: spec.workspace.centre_mm(),
            margin_mm: margin,
            width_mm,
            accel_mm_s2: accel,
            speed_mm_s: speed,
            joint_speed_rad_s: joint,
            torque_limit_nm,
            torque_at_rating_nm: share * torque_limit_nm[0].min(torque_limit_nm[1]),
        })
    }

    /// Whether the offset `m_mm` from the centre keeps the micro `extra_mm` inside the margin.
    pub fn holds(&self, m_mm: [f64; 2], extra_mm: f64) -> bool {
        self.region.contains(
            [self.centre_mm[0] + m_mm[0], self.centre_mm[1] + m_mm[1]],
            self.margin_mm + extra_mm,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_micro_is_rated_5g_and_fast_enough() {
        let spec = MachineSpec::paper();
        let m = MicroLimits::derive(&spec, &PlantConfig::ideal()).unwrap();
        assert_eq!(m.accel_mm_s2, 5.0 * STANDARD_GRAVITY_MM_S2, "{m:?}");
        assert!(m.speed_mm_s > 1500.0 && m.speed_mm_s <= 2700.0, "{m:?}");
        assert!(m.torque_at_rating_nm < 0.8 * 8.0, "{m:?}");
        assert_eq!(m.width_mm, [96.0, 146.0]);
        assert!(m.holds([0.0, 0.0], 0.0) && !m.holds([48.5, 0.0], 0.0));
        // Weak drives lower the rating.
        let mut weak = PlantConfig::ideal();
        weak.drive_1.torque_limit_nm = 1.0;
        weak.drive_2.torque_limit_nm = 1.0;
        let w = MicroLimits::derive(&spec, &weak).unwrap();
        assert!(w.accel_mm_s2 < m.accel_mm_s2, "{w:?}");
    }
}
