//! The flash image a calibration writes: the correction grid's image (`super::grid`) followed by
//! the machine's extension blocks (`kinematics_core::grid`, "Extension blocks"): today the
//! workspace block (`HRWS`: the workspace polygon and the stop margin the firmware's controlled
//! stop keeps to).
//!
//! Why a step of its own: the grid is built from measurements, the blocks from the machine
//! file; `host-sim grid` and the demo's pipeline both finish an image here, so the firmware gets
//! the same image from either. Cost: one CRC over the image.

use super::{invalid, CalibError};
use crate::machine_spec::MachineSpec;
use kinematics_core::grid::{append_workspace, WORKSPACE_LEN};
use kinematics_core::CorrectionGrid;

/// What [`finish_image`] appended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WorkspaceBlock {
    /// The machine's workspace block is in the image.
    Written,
    /// The grid does not cover the machine's workspace (a partial grid): no block, so the
    /// firmware keeps its stops inside the grid's own rectangle.
    GridDoesNotCoverTheWorkspace,
}

/// Whether the grid of `image` covers `spec`'s workspace polygon.
pub fn covers_workspace(image: &[u8], spec: &MachineSpec) -> Result<bool, CalibError> {
    let g = *CorrectionGrid::parse(image).map_err(|e| invalid!("the grid image: {e}"))?.geometry();
    let limits = spec.workspace.limits().map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    Ok(g.covers(&limits.region))
}

/// The grid image `image` with `spec`'s workspace block appended when its grid covers the
/// workspace (see [`WorkspaceBlock`]).
pub fn finish_image(image: &[u8], spec: &MachineSpec) -> Result<(Vec<u8>, WorkspaceBlock), CalibError> {
    if !covers_workspace(image, spec)? {
        return Ok((image.to_vec(), WorkspaceBlock::GridDoesNotCoverTheWorkspace));
    }
    let limits = spec.workspace.limits().map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    let n = image.len();
    let mut out = image.to_vec();
    out.resize(n + WORKSPACE_LEN, 0);
    let end = append_workspace(&mut out, n, n, &limits)
        .map_err(|e| invalid!("the workspace block of machine '{}': {e}", spec.name))?;
    out.truncate(end);
    Ok((out, WorkspaceBlock::Written))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{encode, GridGeometry};
    use kinematics_core::FiveBar;

    fn image(g: &GridGeometry) -> Vec<u8> {
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, g, &FiveBar::paper_nominal(), &vec![[1e-5, 0.0]; g.len()]).unwrap();
        img
    }

    #[test]
    fn a_covering_grid_gets_the_workspace_block_and_a_partial_one_does_not() {
        let spec = MachineSpec::paper();
        let full = image(&spec.grid.geometry());
        let (out, block) = finish_image(&full, &spec).unwrap();
        assert_eq!(block, WorkspaceBlock::Written);
        assert_eq!(out.len(), full.len() + WORKSPACE_LEN);
        let w = CorrectionGrid::parse(&out).unwrap().workspace().unwrap();
        assert_eq!(w, spec.workspace.limits().unwrap());
        let part = image(&GridGeometry { nx: 6, ny: 7, x0_mm: 180.0, y0_mm: -15.0, step_x_mm: 5.0, step_y_mm: 5.0 });
        let (out, block) = finish_image(&part, &spec).unwrap();
        assert_eq!((block, out), (WorkspaceBlock::GridDoesNotCoverTheWorkspace, part));
    }
}
