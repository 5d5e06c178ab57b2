//! What the firmware does with the calibration image it finds in flash.
//!
//! The board reads the image's flash region (see `firmware/src/calibration.rs`); [`load`]
//! validates it (`CorrectionGrid::parse`: magic, version, header, sizes, CRC, every number),
//! checks that it was built for this machine ([`MachineIdentity::check`]) and applies the
//! policy of [`Settings::allow_uncorrected`](crate::settings::Settings): a refused image keeps
//! the drives disabled, unless running uncorrected is allowed. Which of the region's two slots
//! holds the image in force, and how a new one is written: [`crate::calibration_slots`].
//!
//! # "Built for this machine"
//! An image carries the hidden robot it corrects (link lengths, base, encoder offsets, working
//! mode; see `kinematics_core::grid`). A calibration identifies *small* deviations of one
//! machine from its nominal design; an image whose model is far from the nominal geometry in
//! the settings ([`MachineIdentity`]) was built for another machine (another design, another
//! scale), or is garbage that happens to carry a valid CRC. It is refused if:
//! * its working mode (both elbows and the assembly branch) differs from the settings' (the
//!   IK would pick another solution: the motors would swing to a mirrored pose);
//! * any link length differs from the nominal by more than `max_length_deviation_mm`;
//! * either base position differs by more than `max_base_deviation_mm`;
//! * either encoder offset differs by more than `max_offset_deviation_rad` (the offsets tie the
//!   model to the encoder zero homing establishes: an image identified against another zero
//!   reference would place the tool elsewhere);
//! * the home position (`Settings::homing.home_mm`) lies outside its grid.
//!
//! Defaults: the paper's machine, 2 mm, 2 mm, 0.05 rad (an identified machine differs from its
//! drawing by tenths of a millimetre and milliradians; a different design by centimetres).
use kinematics_core::{Branch, Calibration, CorrectionGrid, FiveBar, GridError, WorkingMode};
use link_protocol::ImageParameter;

use crate::plausibility::{ImageLimits, Implausible};

/// The machine the firmware runs: its nominal geometry and how far an image's model may be
/// from it and still be this machine's calibration (module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MachineIdentity {
    /// The design's nominal model (working mode included).
    pub nominal: FiveBar<f32>,
    /// Largest |a, b, c, d - nominal| (mm).
    pub max_length_deviation_mm: f32,
    /// Largest deviation of either base position, per coordinate (mm).
    pub max_base_deviation_mm: f32,
    /// Largest |encoder offset - nominal| (rad).
    pub max_offset_deviation_rad: f32,
}

impl Default for MachineIdentity {
    fn default() -> Self {
        MachineIdentity {
            nominal: FiveBar::paper_nominal(),
            max_length_deviation_mm: 2.0,
            max_base_deviation_mm: 2.0,
            max_offset_deviation_rad: 0.05,
        }
    }
}

/// Why an image that parses was not built for this machine: `parameter` of its model is
/// `image`, this machine's is `machine`, and they may differ by `tolerance` at most.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MachineMismatch {
    /// What differs.
    pub parameter: ImageParameter,
    /// The image's value.
    pub image: f32,
    /// This machine's.
    pub machine: f32,
    /// The largest difference accepted (0: must be equal).
    pub tolerance: f32,
}

impl core::fmt::Display for MachineMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "another machine's image: {:?} is {} in the image, {} on this machine (tolerance {})",
            self.parameter, self.image, self.machine, self.tolerance
        )
    }
}

/// Why an image was refused: it does not parse, it is another machine's, or it carries what
/// no calibration of this machine can need.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Format, CRC or numbers (`CorrectionGrid::parse`).
    Grid(GridError),
    /// Parses, but was built for another machine.
    OtherMachine(MachineMismatch),
    /// This machine's, but implausible ([`crate::plausibility`]).
    Implausible(Implausible),
}

impl core::fmt::Display for ImageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ImageError::Grid(e) => write!(f, "{e}"),
            ImageError::OtherMachine(e) => write!(f, "{e}"),
            ImageError::Implausible(e) => write!(f, "{e}"),
        }
    }
}

impl MachineIdentity {
    /// Whether `grid` was built for this machine (module doc); `home_mm` must lie in its grid.
    /// A refusal names the first parameter that differs and both values.
    pub fn check(
        &self,
        grid: &CorrectionGrid<'_>,
        home_mm: [f32; 2],
    ) -> Result<(), MachineMismatch> {
        let (m, n) = (grid.model(), &self.nominal);
        let mode = |w: WorkingMode| {
            let bit = |b: Branch, k: u32| if b == Branch::Positive { 1 << k } else { 0 };
            (bit(w.elbow_1, 0) | bit(w.elbow_2, 1) | bit(w.assembly, 2)) as f32
        };
        let differs = |parameter, image: f32, machine: f32, tolerance: f32| {
            // `!(d <= max)` also refuses NaN.
            let mismatch = MachineMismatch {
                parameter,
                image,
                machine,
                tolerance,
            };
            if (image - machine).abs() <= tolerance {
                Ok(())
            } else {
                Err(mismatch)
            }
        };
        differs(ImageParameter::WorkingMode, mode(m.mode), mode(n.mode), 0.0)?;
        let (dl, db, doff) = (
            self.max_length_deviation_mm,
            self.max_base_deviation_mm,
            self.max_offset_deviation_rad,
        );
        differs(ImageParameter::LinkAMm, m.a_mm, n.a_mm, dl)?;
        differs(ImageParameter::LinkBMm, m.b_mm, n.b_mm, dl)?;
        differs(ImageParameter::LinkCMm, m.c_mm, n.c_mm, dl)?;
        differs(ImageParameter::LinkDMm, m.d_mm, n.d_mm, dl)?;
        differs(
            ImageParameter::BaseA0XMm,
            m.base_a0_mm[0],
            n.base_a0_mm[0],
            db,
        )?;
        differs(
            ImageParameter::BaseA0YMm,
            m.base_a0_mm[1],
            n.base_a0_mm[1],
            db,
        )?;
        differs(
            ImageParameter::BaseB0XMm,
            m.base_b0_mm[0],
            n.base_b0_mm[0],
            db,
        )?;
        differs(
            ImageParameter::BaseB0YMm,
            m.base_b0_mm[1],
            n.base_b0_mm[1],
            db,
        )?;
        let (mo, no) = (m.encoder_offset_rad, n.encoder_offset_rad);
        differs(ImageParameter::EncoderOffset1Rad, mo[0], no[0], doff)?;
        differs(ImageParameter::EncoderOffset2Rad, mo[1], no[1], doff)?;
        if grid.correction_rad(home_mm).is_err() {
            // The coordinate outside, against the grid's nearest edge along it.
            let g = grid.geometry();
            let x1 = g.x0_mm + g.step_x_mm * f32::from(g.nx - 1);
            let y1 = g.y0_mm + g.step_y_mm * f32::from(g.ny - 1);
            let nearest = |v: f32, lo: f32, hi: f32| if v < lo { lo } else { hi };
            let inside_x = (g.x0_mm..=x1).contains(&home_mm[0]);
            return Err(if inside_x {
                MachineMismatch {
                    parameter: ImageParameter::HomeYMm,
                    image: nearest(home_mm[1], g.y0_mm, y1),
                    machine: home_mm[1],
                    tolerance: 0.0,
                }
            } else {
                MachineMismatch {
                    parameter: ImageParameter::HomeXMm,
                    image: nearest(home_mm[0], g.x0_mm, x1),
                    machine: home_mm[0],
                    tolerance: 0.0,
                }
            });
        }
        Ok(())
    }
}

/// What an image must be to be used on this machine: its machine ([`MachineIdentity`]), the
/// home position its grid must contain, and the plausibility limits
/// ([`crate::plausibility`]). One call judges an image ([`ImageCheck::judge`]) at boot and at
/// an upload's commit (`Settings::image_check` builds it from the settings).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageCheck {
    /// The machine.
    pub machine: MachineIdentity,
    /// The home position (mm).
    pub home_mm: [f32; 2],
    /// What a calibration of it can need (`None`: not judged; only the QEMU harness's own
    /// reading of the slots, which asks which image is in force, not whether it is plausible,
    /// and runs inside a servo sample, where the plausibility check's milliseconds do not fit).
    pub limits: Option<ImageLimits>,
}

impl ImageCheck {
    /// This machine's and plausible: the "same machine" check, then the plausibility limits.
    pub fn judge(&self, grid: &CorrectionGrid<'_>) -> Result<(), ImageError> {
        self.machine
            .check(grid, self.home_mm)
            .map_err(ImageError::OtherMachine)?;
        match &self.limits {
            Some(limits) => limits.check(grid).map_err(ImageError::Implausible),
            None => Ok(()),
        }
    }
}

/// Parses `bytes` and judges it ([`ImageCheck::judge`]): the validation of a boot and of an
/// upload's commit. Returns the grid and the image's length in bytes (with its chain of
/// extension blocks: workspace, dynamics).
pub fn validate_image<'a>(
    bytes: &'a [u8],
    check: &ImageCheck,
) -> Result<(CorrectionGrid<'a>, usize), ImageError> {
    let grid = CorrectionGrid::parse(bytes).map_err(ImageError::Grid)?;
    check.judge(&grid)?;
    let len = grid.len_bytes();
    Ok((grid, len))
}

/// What the boot check found.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalibrationState {
    /// A valid image: model and grid in use.
    Valid,
    /// The image was refused; the drives stay disabled.
    Refused(ImageError),
    /// The image was refused and `allow_uncorrected` is on: nominal model, no grid.
    Uncorrected(ImageError),
}

/// Validates the image in `region` (the image in force, or the whole flash region: bytes after
/// the image are ignored), judges it ([`ImageCheck::judge`]), and applies the policy. A refused image yields the paper's nominal model without grid, which
/// the servo uses only if the state is [`CalibrationState::Uncorrected`].
pub fn load<'a>(
    region: &'a [u8],
    check: &ImageCheck,
    allow_uncorrected: bool,
) -> (CalibrationState, Calibration<'a>) {
    let nominal = Calibration {
        model: check.machine.nominal,
        grid: None,
    };
    match validate_image(region, check) {
        Ok((grid, _)) => (CalibrationState::Valid, Calibration::from_grid(grid)),
        Err(e) if allow_uncorrected => (CalibrationState::Uncorrected(e), nominal),
        Err(e) => (CalibrationState::Refused(e), nominal),
    }
}

/// The id of the image at the start of `region` (bytes after it ignored): the link's
/// calibration id ([`link_protocol::calibration_image_id`], CRC-32C) of the image's own bytes,
/// grid and extension blocks, as the slot store records it; `None` if the image does not parse.
pub fn image_id(region: &[u8]) -> Option<u32> {
    let grid = CorrectionGrid::parse(region).ok()?;
    Some(link_protocol::calibration_image_id(
        region.get(..grid.len_bytes())?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{encode, GridGeometry};
    use kinematics_core::Branch;

    const HOME_MM: [f32; 2] = [212.132, 0.0];

    /// The paper's machine with its default tolerances and the default servo's limits.
    fn check() -> ImageCheck {
        ImageCheck {
            machine: MachineIdentity::default(),
            home_mm: HOME_MM,
            limits: Some(ImageLimits::of(
                &FiveBar::paper_nominal(),
                2.0,
                &kinematics_core::ServoConfig::default(),
                100.0,
            )),
        }
    }

    fn image() -> Vec<u8> {
        let g = GridGeometry {
            nx: 3,
            ny: 3,
            x0_mm: 160.0,
            y0_mm: -80.0,
            step_x_mm: 50.0,
            step_y_mm: 80.0,
        };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &[[2e-4, -1e-4]; 9]).unwrap();
        img
    }

    #[test]
    fn a_valid_image_gives_its_model_and_grid() {
        let mut region = image();
        region.extend([0xFF; 100]); // erased flash after the image
        let (state, cal) = load(&region, &check(), false);
        assert_eq!(state, CalibrationState::Valid);
        let grid = cal.grid.expect("grid in use");
        assert_eq!(grid.correction_rad([200.0, 0.0]), Ok([2e-4, -1e-4]));
    }

    /// The image's length (what an upload commits and a slot holds) ends with its chain of
    /// blocks, whichever it has, not with the grid's CRC nor the region.
    #[test]
    fn the_image_length_includes_its_chain_of_blocks() {
        use kinematics_core::grid::{
            append_dynamics, append_workspace, WorkspaceLimits, DYNAMICS_LEN, WORKSPACE_LEN,
        };
        use kinematics_core::{ConvexWorkspace, FiveBarDynamics};
        let plain = image();
        let n = plain.len();
        let mut img = plain.clone();
        img.resize(n + WORKSPACE_LEN + DYNAMICS_LEN, 0);
        let region = ConvexWorkspace::rectangle([165.0, 255.0], [-75.0, 75.0]).unwrap();
        let end = append_workspace(
            &mut img,
            n,
            n,
            &WorkspaceLimits {
                region,
                stop_margin_mm: 0.1,
            },
        )
        .unwrap();
        let d = FiveBarDynamics {
            motor_inertia_kg_m2: [5e-3; 2],
            tool_mass_kg: 0.2,
            distal_inertia_kg_m2: [0.0; 2],
            viscous_nm_s_per_rad: [0.01; 2],
            coulomb_nm: [0.02; 2],
            coulomb_speed_rad_s: 0.01,
        };
        let end = append_dynamics(&mut img, n, end, &d).unwrap();
        let mut region = img.clone();
        region.extend([0xFF; 64]);
        let (grid, len) = validate_image(&region, &check()).unwrap();
        assert_eq!(len, end);
        assert!(grid.workspace().is_some() && grid.dynamics().is_some());
        // Cut to that length, the image still has both blocks.
        let (grid, _) = validate_image(&region[..len], &check()).unwrap();
        assert!(grid.workspace().is_some() && grid.dynamics().is_some());
        assert_eq!(validate_image(&plain, &check()).unwrap().1, n);
    }

    #[test]
    fn a_bad_image_is_refused_unless_uncorrected_running_is_allowed() {
        let mut region = image();
        region[100] ^= 1;
        let (state, cal) = load(&region, &check(), false);
        assert_eq!(
            state,
            CalibrationState::Refused(ImageError::Grid(GridError::BadCrc))
        );
        assert!(cal.grid.is_none());
        let (state, cal) = load(&[0xFF; 4096], &check(), true);
        assert_eq!(
            state,
            CalibrationState::Uncorrected(ImageError::Grid(GridError::BadMagic))
        );
        assert!(cal.grid.is_none());
        assert_eq!(cal.model, FiveBar::paper_nominal());
    }

    fn image_of(model: &FiveBar<f32>, x0_mm: f32) -> Vec<u8> {
        let g = GridGeometry {
            nx: 3,
            ny: 3,
            x0_mm,
            y0_mm: -80.0,
            step_x_mm: 50.0,
            step_y_mm: 80.0,
        };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, model, &[[0.0; 2]; 9]).unwrap();
        img
    }

    /// Each way an image can be another machine's is refused with its reason; a model within
    /// the tolerances (an identified machine) is accepted.
    #[test]
    fn an_image_built_for_another_machine_is_refused() {
        let m = check();
        let n = FiveBar::paper_nominal();
        let identified = FiveBar {
            a_mm: 150.4,
            d_mm: 149.7,
            base_b0_mm: [0.3, -0.2],
            encoder_offset_rad: [2e-3, -1e-3],
            ..n
        };
        assert!(validate_image(&image_of(&identified, 160.0), &m).is_ok());
        let mut mirrored = n;
        mirrored.mode.assembly = match n.mode.assembly {
            Branch::Positive => Branch::Negative,
            Branch::Negative => Branch::Positive,
        };
        for (model, x0, why) in [
            (mirrored, 160.0, ImageParameter::WorkingMode, 1.0, 5.0, 0.0),
            (
                FiveBar { c_mm: 153.0, ..n },
                160.0,
                ImageParameter::LinkCMm,
                153.0,
                150.0,
                2.0,
            ),
            (
                FiveBar {
                    base_a0_mm: [0.0, 2.5],
                    ..n
                },
                160.0,
                ImageParameter::BaseA0YMm,
                2.5,
                0.0,
                2.0,
            ),
            (
                FiveBar {
                    encoder_offset_rad: [0.0, 0.1],
                    ..n
                },
                160.0,
                ImageParameter::EncoderOffset2Rad,
                0.1,
                0.0,
                0.05,
            ),
            (n, 220.0, ImageParameter::HomeXMm, 220.0, 212.132, 0.0),
        ]
        .map(|(model, x0, p, image, machine, tolerance)| {
            (model, x0, (p, image, machine, tolerance))
        }) {
            let img = image_of(&model, x0);
            // The refusal names the parameter and both values.
            let want = ImageError::OtherMachine(MachineMismatch {
                parameter: why.0,
                image: why.1,
                machine: why.2,
                tolerance: why.3,
            });
            assert_eq!(validate_image(&img, &m).err(), Some(want), "{why:?}");
            let (state, cal) = load(&img, &m, false);
            assert_eq!(state, CalibrationState::Refused(want));
            assert!(cal.grid.is_none());
        }
    }
}
