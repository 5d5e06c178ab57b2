//! The servo's gains for an identified machine: the default design (`ServoConfig::default`:
//! position bandwidth ω = 1000 rad/s, ζ = 0.7, integral at ω/4, the disturbance observer's
//! nominal inertia the axis') applied to each axis' identified inertia instead of the paper
//! machine's 7.4e-3 kg·m².
//!
//! Why: the gains are designed for an inertia. A heavier tool raises it (a 0.3 kg cutting head
//! instead of 0.04 kg takes the paper machine's diagonal from 7.3e-3 to 13.2e-3 kg·m²), and
//! with the default gains the loop is then no longer stable: measured on the `paper` plant with
//! that tool and its exact dynamics fed forward, the disturbance observer and the PID together
//! oscillate against the torque limit (170 µm of following error on the slow circle); with the
//! observer off, or its nominal inertia and the PID's scaled to the axis', it follows the 5 g
//! figure-eight within 1.4 µm. The identified dynamics say what the inertia is; these gains
//! follow from them, so a commissioning sets both.
//!
//! The inertia of an axis: the diagonal of the identified inertia matrix
//! (`FiveBarDynamics::mass_matrix_and_bias`), averaged over a 5 × 5 lattice of the workspace
//! (constant over the workspace on the paper machine, whose diagonal does not depend on the
//! configuration; it varies on others).

use super::DynError;
use crate::machine_spec::MachineSpec;
use kinematics_core::{FiveBar, FiveBarDynamics, ServoConfig};

/// Position bandwidth of the design (rad/s).
pub const BANDWIDTH_RAD_S: f64 = 1000.0;
/// Damping ratio of the design.
pub const DAMPING: f64 = 0.7;

/// Each axis' inertia (kg·m²): the identified inertia matrix's diagonal averaged over the
/// workspace (see the module doc).
pub fn axis_inertia_kg_m2(
    d: &FiveBarDynamics<f64>,
    model: &FiveBar<f64>,
    spec: &MachineSpec,
) -> Result<[f64; 2], DynError> {
    let ws = &spec.workspace;
    let (mut sum, mut n) = ([0.0; 2], 0usize);
    for i in 0..5 {
        for j in 0..5 {
            let p = [
                ws.x_mm[0] + (ws.x_mm[1] - ws.x_mm[0]) * i as f64 / 4.0,
                ws.y_mm[0] + (ws.y_mm[1] - ws.y_mm[0]) * j as f64 / 4.0,
            ];
            let p = ws.pulled_inside(p, ws.stop_margin_mm);
            let Ok(pose) = model.inverse_pose(p, spec.min_transmission) else {
                continue;
            };
            let Ok((m, _)) = d.mass_matrix_and_bias(&pose, [0.0; 2]) else {
                continue;
            };
            sum[0] += m[0][0];
            sum[1] += m[1][1];
            n += 1;
        }
    }
    let j = sum.map(|s| s / n.max(1) as f64);
    if n == 0 || !(j[0] > 0.0 && j[1] > 0.0 && j.iter().all(|v| v.is_finite())) {
        return Err(DynError::Invalid(format!(
            "the identified dynamics give no positive inertia over {}'s workspace: {j:?}",
            spec.name
        )));
    }
    Ok(j)
}

/// `base` with each axis' PID gains, constant feed-forward inertia and observer nominal inertia
/// designed for the identified inertia (see the module doc); the other settings kept.
pub fn servo_config_for(
    d: &FiveBarDynamics<f64>,
    model: &FiveBar<f64>,
    spec: &MachineSpec,
    base: ServoConfig,
) -> Result<ServoConfig, DynError> {
    let j = axis_inertia_kg_m2(d, model, spec)?;
    let mut c = base;
    let w = BANDWIDTH_RAD_S;
    for (a, j) in c.axes.iter_mut().zip(j) {
        let kp = j * w * w;
        a.kp_nm_per_rad = kp as f32;
        a.ki_nm_per_rad_s = (kp * w / 4.0) as f32;
        a.kd_nm_s_per_rad = (2.0 * DAMPING * j * w) as f32;
        a.inertia_ff_kg_m2 = j as f32;
        a.observer_inertia_kg_m2 = j as f32;
    }
    c.validate().map_err(|e| {
        DynError::Invalid(format!(
            "the servo refuses the gains for {j:?} kg·m²: {e:?}"
        ))
    })?;
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::{Plant, PlantConfig};

    /// For the machine the defaults were designed for, the design gives the defaults (within
    /// the 1 % its identified diagonal differs from 7.4e-3).
    #[test]
    fn the_design_reproduces_the_defaults_on_the_paper_machine() {
        let spec = MachineSpec::paper();
        let d = Plant::new(&PlantConfig::paper(), 1).true_dynamics();
        let c = servo_config_for(&d, &spec.nominal, &spec, ServoConfig::default()).unwrap();
        let def = ServoConfig::default();
        for (a, b) in c.axes.iter().zip(def.axes) {
            assert!(
                (a.kp_nm_per_rad / b.kp_nm_per_rad - 1.0).abs() < 0.02,
                "{a:?} {b:?}"
            );
            assert!((a.observer_inertia_kg_m2 / b.observer_inertia_kg_m2 - 1.0).abs() < 0.02);
            assert_eq!(a.observer_bandwidth_rad_s, b.observer_bandwidth_rad_s);
        }
        let mut heavy = PlantConfig::paper();
        heavy.linkage.tool_mass_kg = 0.3;
        let h = Plant::new(&heavy, 1).true_dynamics();
        let j = axis_inertia_kg_m2(&h, &spec.nominal, &spec).unwrap();
        assert!(j[0] > 0.012 && j[0] < 0.0145, "{j:?}");
    }
}
