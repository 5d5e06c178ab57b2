//! The images the journey uploads: a fitted model without corrections (what the first grid
//! round is commanded through, so that the nodes' readings are a grid's first order away from
//! the model), and the grid rounds' images, each finished with the machine's blocks and sealed
//! with its record (`calib::image`), judged as the controller will judge it before it goes.

use crate::calib::backlash::Backlash;
use crate::calib::grid::unmeasured::{build_filling, Filled};
use crate::calib::grid::GridOptions;
use crate::calib::image::{append_backlash_block, append_dynamics_block, finish_image, seal_image};
use crate::calib::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::machine_spec::MachineSpec;
use kinematics_core::grid::encode;
use kinematics_core::{FiveBar, FiveBarDynamics};

/// The blocks an image carries besides its grid.
#[derive(Clone, Copy, Debug, Default)]
pub struct Extras<'a> {
    pub dynamics: Option<&'a FiveBarDynamics<f64>>,
    pub backlash: Option<&'a Backlash>,
}

/// `image` (a grid image) finished: workspace block, the extras, the machine record.
fn finish(image: &[u8], spec: &MachineSpec, extras: Extras<'_>) -> Result<Vec<u8>, CalibError> {
    let (mut image, _) = finish_image(image, spec)?;
    if let Some(d) = extras.dynamics {
        image = append_dynamics_block(&image, d)?;
    }
    if let Some(b) = extras.backlash {
        image = append_backlash_block(&image, b)?;
    }
    Ok(seal_image(&image, spec)?.bytes)
}

/// The image of `model` with zero corrections on the machine's lattice.
pub fn model_image(
    model: &FiveBar<f64>,
    spec: &MachineSpec,
    extras: Extras<'_>,
) -> Result<Vec<u8>, CalibError> {
    let g = spec.grid.geometry();
    let mut image = vec![0u8; g.image_len()];
    encode(
        &mut image,
        &g,
        &model.cast::<f32>(),
        &vec![[0.0; 2]; g.len()],
    )
    .map_err(|e| invalid!("machine '{}': the model's image: {e}", spec.name))?;
    finish(&image, spec, extras)
}

/// Whether the controller can be driven to the grid node `p` (mm): inside the machine's
/// workspace (on its edge included; the session moves such a target in by the stop margin and
/// records it at its node).
pub fn node_reachable(spec: &MachineSpec, p: [f64; 2]) -> bool {
    spec.workspace.contains(p, 1e-9)
}

/// The grid of `data` (node readings in the machine frame, pooled over rounds) on `model`,
/// the lattice's nodes outside the workspace estimated from the others
/// (`calib::grid::unmeasured`), its image finished and sealed.
pub fn grid_image(
    model: &FiveBar<f64>,
    data: &[Measurement],
    spec: &MachineSpec,
    extras: Extras<'_>,
) -> Result<(Filled, Vec<u8>), CalibError> {
    let filled = build_filling(
        model,
        data,
        &spec.grid_nodes_mm(),
        &GridOptions::for_machine(spec),
        |p| node_reachable(spec, p),
    )?;
    let image = finish(&filled.built.image, spec, extras)?;
    Ok((filled, image))
}
