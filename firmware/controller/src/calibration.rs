//! What the firmware does with the calibration image it finds in flash.
//!
//! The board reads the image's flash region (see `firmware/src/calibration.rs`); [`load`]
//! validates it (`CorrectionGrid::parse`: magic, version, header, sizes, CRC, every number) and
//! applies the policy of [`Settings::allow_uncorrected`](crate::settings::Settings): a refused
//! image keeps the drives disabled, unless running uncorrected is allowed. Calibration slots
//! (several images, one selected) will live here.
use kinematics_core::{Calibration, CorrectionGrid, FiveBar, GridError};

/// What the boot check found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalibrationState {
    /// A valid image: model and grid in use.
    Valid,
    /// The image was refused; the drives stay disabled.
    Refused(GridError),
    /// The image was refused and `allow_uncorrected` is on: nominal model, no grid.
    Uncorrected(GridError),
}

/// Validates the image in `region` (the whole flash region: bytes after the image are ignored)
/// and applies the policy. A refused image yields the paper's nominal model without grid,
/// which the servo uses only if the state is [`CalibrationState::Uncorrected`].
pub fn load(region: &[u8], allow_uncorrected: bool) -> (CalibrationState, Calibration<'_>) {
    let nominal = Calibration { model: FiveBar::<f32>::paper_nominal(), grid: None };
    match CorrectionGrid::parse(region) {
        Ok(grid) => (CalibrationState::Valid, Calibration::from_grid(grid)),
        Err(e) if allow_uncorrected => (CalibrationState::Uncorrected(e), nominal),
        Err(e) => (CalibrationState::Refused(e), nominal),
    }
}

/// The id of the image at the start of `region`: its stored CRC-32 (the image's last four
/// bytes before any dynamics block), `None` if the image is refused. What the host link
/// reports as the calibration id.
pub fn image_id(region: &[u8]) -> Option<u32> {
    let grid = CorrectionGrid::parse(region).ok()?;
    let end = grid.geometry().image_len();
    let crc = region.get(end.checked_sub(4)?..end)?;
    Some(u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{encode, GridGeometry};

    fn image() -> Vec<u8> {
        let g = GridGeometry { nx: 3, ny: 3, x0_mm: 160.0, y0_mm: -80.0, step_x_mm: 50.0, step_y_mm: 80.0 };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &[[2e-4, -1e-4]; 9]).unwrap();
        img
    }

    #[test]
    fn a_valid_image_gives_its_model_and_grid() {
        let mut region = image();
        region.extend([0xFF; 100]); // erased flash after the image
        let (state, cal) = load(&region, false);
        assert_eq!(state, CalibrationState::Valid);
        let grid = cal.grid.expect("grid in use");
        assert_eq!(grid.correction_rad([200.0, 0.0]), Ok([2e-4, -1e-4]));
    }

    #[test]
    fn a_bad_image_is_refused_unless_uncorrected_running_is_allowed() {
        let mut region = image();
        region[100] ^= 1;
        let (state, cal) = load(&region, false);
        assert_eq!(state, CalibrationState::Refused(GridError::BadCrc));
        assert!(cal.grid.is_none());
        let (state, cal) = load(&[0xFF; 4096], true);
        assert_eq!(state, CalibrationState::Uncorrected(GridError::BadMagic));
        assert!(cal.grid.is_none());
        assert_eq!(cal.model, FiveBar::paper_nominal());
    }
}
