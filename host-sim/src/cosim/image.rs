//! The calibration a machine starts with: the nominal model, zero corrections over the machine's
//! grid lattice, and its workspace block (`calib::image::finish_image`). What a co-simulation
//! flashes when it is given no image: the controller then commands the nominal model, as a
//! newly built machine's does before its first calibration.
use kinematics_core::grid::encode;

use super::CoSimError;
use crate::calib::image::finish_image;
use crate::machine_spec::MachineSpec;

/// The commissioning image of `spec`'s machine.
pub fn commissioning_image(spec: &MachineSpec) -> Result<Vec<u8>, CoSimError> {
    let geometry = spec.grid.geometry();
    let zeros = vec![[0.0f32; 2]; spec.grid.nx * spec.grid.ny];
    let mut image = vec![0u8; geometry.image_len()];
    encode(&mut image, &geometry, &spec.nominal.cast::<f32>(), &zeros).map_err(|e| {
        CoSimError::Invalid(format!(
            "machine '{}': the nominal grid image: {e}",
            spec.name
        ))
    })?;
    let (image, _) = finish_image(&image, spec)
        .map_err(|e| CoSimError::Invalid(format!("machine '{}': {e}", spec.name)))?;
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::CorrectionGrid;

    #[test]
    fn the_commissioning_image_is_the_nominal_model_without_corrections() {
        let spec = MachineSpec::paper();
        let image = commissioning_image(&spec).unwrap();
        let grid = CorrectionGrid::parse(&image).unwrap();
        assert_eq!(grid.model(), &spec.nominal.cast::<f32>());
        assert!(grid.workspace().is_some(), "the workspace block is there");
        assert_eq!(grid.correction_rad([212.132, 0.0]).unwrap(), [0.0, 0.0]);
    }
}
