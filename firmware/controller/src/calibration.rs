//! What the firmware does with the calibration image it finds in flash, and which machine it
//! drives.
//!
//! # The machine is the image's
//! Every image the host tools write carries, last, the machine record it was built for (block
//! `HRMC`: name, nominal model and working mode, workspace and stop margin, home position, the
//! plausibility limits; `kinematics_core::machine::MachineRecord`). **The firmware's machine is
//! the record of the image in force**: the host tools and the controller read the same record,
//! so they can never disagree about which machine they are on. An image without a record is
//! an image of the firmware's built-in machine ([`Settings::machine`], the paper's:
//! `MachineRecord::paper()`, equal to host-sim's `machines/paper.toml`).
//!
//! * **At boot** ([`load`], and the slot store's choice of the image in force) an image is
//!   judged against its own record ([`ImageCheck::judge_own`]): its model a model of that
//!   machine, its content plausible, the home position in its grid. Accepted, its record
//!   becomes the machine the controller drives until the next boot ([`Settings::for_machine`]
//!   derives the machine's settings from it). So flashing a machine's commissioning image
//!   (`host-sim grid --nominal --machine FILE`: the nominal model, zero corrections, the
//!   workspace and the record) is how a controller adopts a machine.
//! * **At an upload's commit** ([`ImageCheck::judge`]) an image is judged against the record in
//!   force (`kinematics_core::machine::judge_image`): a record of another machine (another
//!   digest: another geometry) is refused naming both machines; then its model must be a model
//!   of this machine and its content plausible. An image whose record has this machine's
//!   geometry but other settings (name, home, limits) is also judged against the limits in
//!   force, so an upload can never loosen them; the controller takes that record's settings at
//!   its next boot. Uploads never change the machine.
//!
//! "The same machine" is judged physically: the tool positions of the image's model against
//! the nominal's over the workspace, in the best-fitting rigid frame, within the record's
//! `same_machine_tolerance_mm`. A calibration measured with a laser tracker standing anywhere
//! (its offset and rotation land in the model's base and encoder offsets) is this machine's;
//! another design is centimetres off.
//!
//! On top of the machine's judgement, the servo's own check ([`crate::plausibility`]): the
//! correction's slope change from one cell to the next, bounded so that a move across the grid
//! at the servo's top speed meets no reference-speed step (a limit of the servo, not of the
//! machine file).
//!
//! A refused image at boot keeps the drives disabled, unless running uncorrected is allowed
//! ([`Settings::allow_uncorrected`](crate::settings::Settings)); the controller then drives the
//! built-in machine. Which of the region's two slots holds the image in force, and how a new one
//! is written: [`crate::calibration_slots`].
//!
//! Cost: milliseconds (about two thousand servo steps: `cargo qemu-bench`'s `judge_image` and
//! `image_commit_check`, figures in docs/validation/benchmarks.md), at boot and in the link task at a
//! commit; never in the servo task's sample.
//!
//! [`Settings::machine`]: crate::settings::Settings::machine
//! [`Settings::for_machine`]: crate::settings::Settings::for_machine
use kinematics_core::machine::{
    judge_image, plausible, same_machine, ImageRefusal, MachineMismatch, MachineRecord,
};
use kinematics_core::{Calibration, CorrectionGrid, GridError};

use crate::plausibility::{slope_change, SlopeChange};

/// How images are judged (module doc): the machine in force and the servo's own limit.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageCheck {
    /// The machine in force: what an upload is judged against; at boot, the built-in machine an
    /// image without a record is judged against.
    pub machine: MachineRecord,
    /// The servo's limit on the correction's slope change (rad/mm,
    /// [`crate::plausibility::max_slope_change_rad_per_mm`]). `None`: the machine's identity
    /// only (format, record digest), no judgement of the content: the QEMU harness's own
    /// reading of the slots, which asks which image is in force, not whether it is plausible,
    /// and runs inside a servo sample, where the judgement's milliseconds do not fit.
    pub max_slope_change_rad_per_mm: Option<f32>,
}

/// Why an image was refused: it does not parse, it is another machine's or implausible by the
/// machine's judgement, or it fails the servo's own check.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Format, CRC or numbers (`CorrectionGrid::parse`).
    Grid(GridError),
    /// Refused by the machine's judgement (`kinematics_core::machine::judge_image`): another
    /// machine's record or model, or content no calibration of the machine can need.
    Refused(ImageRefusal),
    /// The correction's slope changes too fast from one cell to the next for the servo.
    SlopeChange(SlopeChange),
}

impl core::fmt::Display for ImageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ImageError::Grid(e) => write!(f, "{e}"),
            ImageError::Refused(e) => write!(f, "{e}"),
            ImageError::SlopeChange(e) => write!(f, "{e}"),
        }
    }
}

impl ImageCheck {
    /// An upload's judgement against the machine in force (module doc); the record the image
    /// was judged by (its own, of this machine's geometry, or the one in force).
    pub fn judge(&self, grid: &CorrectionGrid<'_>) -> Result<MachineRecord, ImageError> {
        let refused = ImageError::Refused;
        let Some(max_slope_change) = self.max_slope_change_rad_per_mm else {
            return match grid.machine() {
                Some(r) if r.digest() != self.machine.digest() => Err(refused(
                    ImageRefusal::OtherMachine(other_record(&r, &self.machine)),
                )),
                own => Ok(own.unwrap_or(self.machine)),
            };
        };
        let verdict = judge_image(grid, &self.machine).map_err(refused)?;
        if verdict.record != self.machine {
            // This machine's geometry under other settings: the limits in force apply too.
            same_machine(&self.machine, grid.model())
                .map_err(|e| refused(ImageRefusal::OtherMachine(e)))?;
            plausible(grid, &self.machine).map_err(|e| refused(ImageRefusal::Implausible(e)))?;
        }
        slope_change(grid, max_slope_change).map_err(ImageError::SlopeChange)?;
        Ok(verdict.record)
    }

    /// The boot's judgement: the image against its own record (against [`Self::machine`] if it
    /// carries none); the record it defines the machine by.
    pub fn judge_own(&self, grid: &CorrectionGrid<'_>) -> Result<MachineRecord, ImageError> {
        ImageCheck {
            machine: grid.machine().unwrap_or(self.machine),
            ..*self
        }
        .judge(grid)
    }
}

fn other_record(image: &MachineRecord, controller: &MachineRecord) -> MachineMismatch {
    MachineMismatch::OtherRecord {
        image_name: image.name,
        image_digest: image.digest(),
        controller_name: controller.name,
        controller_digest: controller.digest(),
    }
}

/// An image that parsed and was accepted.
#[derive(Clone, Copy, Debug)]
pub struct ValidImage<'a> {
    /// The grid, model and blocks.
    pub grid: CorrectionGrid<'a>,
    /// The image's length in bytes, with its chain of extension blocks.
    pub len: usize,
    /// The machine record it was judged by (module doc).
    pub machine: MachineRecord,
}

/// When an image is judged (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Judged {
    /// At boot: against its own record.
    AtBoot,
    /// At an upload's commit: against the machine in force.
    AtCommit,
}

/// Parses `bytes` (bytes after the image and its blocks are ignored) and judges it
/// ([`ImageCheck::judge_own`] at boot, [`ImageCheck::judge`] at a commit).
pub fn validate_image<'a>(
    bytes: &'a [u8],
    check: &ImageCheck,
    when: Judged,
) -> Result<ValidImage<'a>, ImageError> {
    let grid = CorrectionGrid::parse(bytes).map_err(ImageError::Grid)?;
    let machine = match when {
        Judged::AtBoot => check.judge_own(&grid)?,
        Judged::AtCommit => check.judge(&grid)?,
    };
    Ok(ValidImage {
        grid,
        len: grid.len_bytes(),
        machine,
    })
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

/// What the boot found: the calibration to run with and the machine it drives.
#[derive(Clone, Copy, Debug)]
pub struct Loaded<'a> {
    /// Valid, refused or uncorrected.
    pub state: CalibrationState,
    /// The image's model and grid; refused: the machine's nominal model without grid, which
    /// the servo uses only if the state is [`CalibrationState::Uncorrected`].
    pub calibration: Calibration<'a>,
    /// The machine: the image's record, or `check.machine` (the built-in one) when the image
    /// carries none or was refused.
    pub machine: MachineRecord,
}

/// Validates the image in `region` (the image in force, or the whole flash region: bytes after
/// the image are ignored), judges it against its own record ([`Judged::AtBoot`]), and applies
/// the policy for a refused image (module doc).
pub fn load<'a>(region: &'a [u8], check: &ImageCheck, allow_uncorrected: bool) -> Loaded<'a> {
    match validate_image(region, check, Judged::AtBoot) {
        Ok(v) => Loaded {
            state: CalibrationState::Valid,
            calibration: Calibration::from_grid(v.grid),
            machine: v.machine,
        },
        Err(e) => Loaded {
            state: if allow_uncorrected {
                CalibrationState::Uncorrected(e)
            } else {
                CalibrationState::Refused(e)
            },
            calibration: Calibration {
                model: check.machine.nominal,
                grid: None,
            },
            machine: check.machine,
        },
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
mod tests;
