//! The judgement of an image that parses, as the controller makes it at an upload's commit and
//! at boot, and the host tools before they write or use an image: whose machine it is, then
//! whether it is a plausible calibration of it.

use super::plausible::{plausible, Margins};
use super::record::MachineRecord;
use super::refusal::{ImageRefusal, MachineMismatch};
use super::same::{same_machine, SameMachine};
use crate::grid::CorrectionGrid;

/// An image accepted for a machine.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Verdict {
    /// The record the image was judged against: its own `HRMC` record, or the one given.
    pub record: MachineRecord,
    /// Whether that is the image's own record.
    pub carried: bool,
    /// How close its model is to the nominal, and the instrument frame it was measured in.
    pub same: SameMachine,
    /// How close its content came to the plausibility limits.
    pub margins: Margins,
}

/// Judges `grid` for the machine `machine` (the controller's record in force):
///
/// 1. an image carrying a machine record (`HRMC`) must carry `machine`'s geometry (equal
///    digests; names and limits may differ) and is then judged against its own record, whose
///    limits are the machine file's as it was built; an image without one is judged against
///    `machine`;
/// 2. its model must be a model of that machine ([`same_machine`]);
/// 3. its content must be plausible for it ([`super::plausible`]).
///
/// Cost: the two judgements' (their module docs), about 0.3 M instructions for the paper's
/// image on the Cortex-M4F; not for the servo's sample.
pub fn judge_image(
    grid: &CorrectionGrid<'_>,
    machine: &MachineRecord,
) -> Result<Verdict, ImageRefusal> {
    machine.validate().map_err(ImageRefusal::Record)?;
    let own = grid.machine();
    let record = match own {
        Some(r) if r.digest() == machine.digest() => r,
        Some(r) => {
            return Err(ImageRefusal::OtherMachine(MachineMismatch::OtherRecord {
                image_name: r.name,
                image_digest: r.digest(),
                controller_name: machine.name,
                controller_digest: machine.digest(),
            }))
        }
        None => *machine,
    };
    let same = same_machine(&record, grid.model()).map_err(ImageRefusal::OtherMachine)?;
    let margins = plausible(grid, &record).map_err(ImageRefusal::Implausible)?;
    Ok(Verdict {
        record,
        carried: own.is_some(),
        same,
        margins,
    })
}
