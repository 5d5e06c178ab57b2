//! The servo's gains for an identified machine, as the controller designs them when it
//! engages an image with this dynamics block: `kinematics_core::gain_design` (the settings'
//! gains, designed for 7.4e-3 kg·m², scaled to each axis' identified inertia; the same
//! bandwidth ω = 1000 rad/s and damping ζ = 0.7, the observer's nominal inertia the axis').
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
//! The inertia of an axis: the diagonal of the identified inertia matrix averaged over the
//! machine's workspace at the core's points (`gain_design::inertia_points`: its centroid and
//! four midpoints; constant over the workspace on the paper machine, whose diagonal does not
//! depend on the configuration; it varies on others), in f32 as the controller computes it.

use super::DynError;
use crate::machine_spec::MachineSpec;
use kinematics_core::gain_design;
use kinematics_core::{FiveBar, FiveBarDynamics, ServoConfig};

/// Each axis' inertia (kg·m²) by the identified dynamics, as the controller computes it (see
/// the module doc).
pub fn axis_inertia_kg_m2(
    d: &FiveBarDynamics<f64>,
    model: &FiveBar<f64>,
    spec: &MachineSpec,
) -> Result<[f64; 2], DynError> {
    let region = spec
        .record()
        .map_err(|e| DynError::Invalid(format!("machine '{}': {e}", spec.name)))?
        .workspace
        .region;
    gain_design::axis_inertia_kg_m2(
        &d.cast::<f32>(),
        &model.cast::<f32>(),
        &region,
        spec.min_transmission as f32,
    )
    .filter(|j| j.iter().all(|v| v.is_finite() && *v > 0.0))
    .map(|j| j.map(f64::from))
    .ok_or_else(|| {
        DynError::Invalid(format!(
            "the identified dynamics give no positive inertia over {}'s workspace",
            spec.name
        ))
    })
}

/// `base` with each axis' PID gains, constant feed-forward inertia and observer nominal inertia
/// designed for the identified inertia, as the controller designs them (see the module doc);
/// the other settings kept. Refused when an axis' inertia is beyond the design's range
/// (`gain_design::MAX_INERTIA_RATIO`): the controller would run that axis without its observer.
pub fn servo_config_for(
    d: &FiveBarDynamics<f64>,
    model: &FiveBar<f64>,
    spec: &MachineSpec,
    base: ServoConfig,
) -> Result<ServoConfig, DynError> {
    let j = axis_inertia_kg_m2(d, model, spec)?;
    let mut c = base;
    for (a, j) in c.axes.iter_mut().zip(j) {
        *a = gain_design::scaled_for_inertia(a, j as f32).ok_or_else(|| {
            DynError::Invalid(format!(
                "an axis inertia of {j:.3e} kg·m² is beyond {}x the {:.3e} the gains are designed for",
                gain_design::MAX_INERTIA_RATIO,
                a.inertia_ff_kg_m2
            ))
        })?;
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
