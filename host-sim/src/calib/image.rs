//! The flash image a calibration writes: the correction grid's image (`super::grid`) followed by
//! the machine's extension blocks (`kinematics_core::grid`, "Extension blocks"): the workspace
//! block (`HRWS`: the workspace polygon and the stop margin the firmware's controlled stop
//! keeps to) and, when the dynamics were identified (`host-sim simulate`/`calib::dynamics`,
//! `dynamics.json`), the dynamics block (`HRDY`: what the servo feeds forward) and, when the
//! model carries a backlash (`backlash_urad`: `diagnose --out-model`, the demo's estimate),
//! the backlash block last (`HRBL`: what the servo's reference compensates; last, so that a
//! firmware older than the block still reads the blocks before it).
//!
//! Why a step of its own: the grid is built from measurements, the blocks from the machine
//! file and the identification; `host-sim grid` and the demo's pipeline both finish an image
//! here, so the firmware gets the same image from either. Cost: one CRC over the image.

use super::backlash::Backlash;
use super::{invalid, CalibError};
use crate::machine_spec::MachineSpec;
use kinematics_core::grid::{
    append_backlash, append_dynamics, append_workspace, BACKLASH_LEN, DYNAMICS_LEN, WORKSPACE_LEN,
};
use kinematics_core::{CorrectionGrid, FiveBarDynamics};

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
    let g = *CorrectionGrid::parse(image)
        .map_err(|e| invalid!("the grid image: {e}"))?
        .geometry();
    let limits = spec
        .workspace
        .limits()
        .map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    Ok(g.covers(&limits.region))
}

/// The grid image `image` with `spec`'s workspace block appended when its grid covers the
/// workspace (see [`WorkspaceBlock`]).
pub fn finish_image(
    image: &[u8],
    spec: &MachineSpec,
) -> Result<(Vec<u8>, WorkspaceBlock), CalibError> {
    if !covers_workspace(image, spec)? {
        return Ok((image.to_vec(), WorkspaceBlock::GridDoesNotCoverTheWorkspace));
    }
    let limits = spec
        .workspace
        .limits()
        .map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    let n = image.len();
    let mut out = image.to_vec();
    out.resize(n + WORKSPACE_LEN, 0);
    let end = append_workspace(&mut out, n, n, &limits)
        .map_err(|e| invalid!("the workspace block of machine '{}': {e}", spec.name))?;
    out.truncate(end);
    Ok((out, WorkspaceBlock::Written))
}

/// `image` (a grid image, possibly with blocks already: it must parse) with the dynamics block
/// appended at the end of its chain. Refused: an image that already carries one, parameters
/// that do not validate in f32 (what the firmware reads).
pub fn append_dynamics_block(
    image: &[u8],
    dynamics: &FiveBarDynamics<f64>,
) -> Result<Vec<u8>, CalibError> {
    append_block(
        image,
        "dynamics",
        DYNAMICS_LEN,
        |g| g.dynamics().is_some(),
        |out, n, end| {
            append_dynamics(out, n, end, &dynamics.cast::<f32>())
                .map_err(|e| invalid!("the dynamics block: {e}"))
        },
    )
}

/// `image` (a grid image, possibly with blocks already: it must parse) with the backlash
/// block appended at the end of its chain (so after every other block). Refused: an image that
/// already carries one, a lost motion the firmware would refuse (in f32).
pub fn append_backlash_block(image: &[u8], backlash: &Backlash) -> Result<Vec<u8>, CalibError> {
    append_block(
        image,
        "backlash",
        BACKLASH_LEN,
        |g| g.backlash().is_some(),
        |out, n, end| {
            let beta_rad = backlash.lost_motion_urad.map(|b| (b * 1e-6) as f32);
            let block = kinematics_core::Backlash::new(beta_rad)
                .map_err(|e| invalid!("the backlash block: {e}"))?;
            append_backlash(out, n, end, &block).map_err(|e| invalid!("the backlash block: {e}"))
        },
    )
}

/// What both block appenders share: `image` must parse and not carry the block yet
/// (`carries`); `write` gets a copy with `block_len` bytes of room after the image's end, the
/// image's own length and that end, and returns the new end.
fn append_block(
    image: &[u8],
    name: &str,
    block_len: usize,
    carries: impl FnOnce(&CorrectionGrid<'_>) -> bool,
    write: impl FnOnce(&mut [u8], usize, usize) -> Result<usize, CalibError>,
) -> Result<Vec<u8>, CalibError> {
    let grid = CorrectionGrid::parse(image).map_err(|e| invalid!("the grid image: {e}"))?;
    if carries(&grid) {
        return Err(invalid!("the grid image already carries a {name} block"));
    }
    let n = grid.geometry().image_len();
    let end = image.len();
    let mut out = image.to_vec();
    out.resize(end + block_len, 0);
    let end = write(&mut out, n, end)?;
    out.truncate(end);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{encode, GridGeometry};
    use kinematics_core::FiveBar;

    fn image(g: &GridGeometry) -> Vec<u8> {
        let mut img = vec![0u8; g.image_len()];
        encode(
            &mut img,
            g,
            &FiveBar::paper_nominal(),
            &vec![[1e-5, 0.0]; g.len()],
        )
        .unwrap();
        img
    }

    #[test]
    fn the_backlash_block_goes_last_and_comes_once() {
        let spec = MachineSpec::paper();
        let (img, _) = finish_image(&image(&spec.grid.geometry()), &spec).unwrap();
        let b = Backlash::new([20.0, 35.0]).unwrap();
        let out = append_backlash_block(&img, &b).unwrap();
        assert_eq!(&out[..img.len()], &img[..]);
        let parsed = CorrectionGrid::parse(&out).unwrap();
        assert_eq!(parsed.backlash().unwrap().beta_rad(), [20e-6f32, 35e-6]);
        assert!(parsed.workspace().is_some());
        assert!(append_backlash_block(&out, &b)
            .unwrap_err()
            .to_string()
            .contains("already"));
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
        let part = image(&GridGeometry {
            nx: 6,
            ny: 7,
            x0_mm: 180.0,
            y0_mm: -15.0,
            step_x_mm: 5.0,
            step_y_mm: 5.0,
        });
        let (out, block) = finish_image(&part, &spec).unwrap();
        assert_eq!(
            (block, out),
            (WorkspaceBlock::GridDoesNotCoverTheWorkspace, part)
        );
    }

    #[test]
    fn the_dynamics_block_follows_the_workspace_block_and_comes_once() {
        let spec = MachineSpec::paper();
        let (img, _) = finish_image(&image(&spec.grid.geometry()), &spec).unwrap();
        let d = FiveBarDynamics {
            motor_inertia_kg_m2: [3e-3, 2.9e-3],
            tool_mass_kg: 0.1,
            distal_inertia_kg_m2: [-2e-4, -2e-4],
            viscous_nm_s_per_rad: [0.02; 2],
            coulomb_nm: [0.05; 2],
            coulomb_speed_rad_s: 0.01,
        };
        let out = append_dynamics_block(&img, &d).unwrap();
        assert_eq!(out.len(), img.len() + DYNAMICS_LEN);
        let g = CorrectionGrid::parse(&out).unwrap();
        assert_eq!(g.dynamics(), Some(&d.cast::<f32>()));
        assert_eq!(g.workspace(), Some(spec.workspace.limits().unwrap()));
        assert!(append_dynamics_block(&out, &d)
            .unwrap_err()
            .to_string()
            .contains("already"));
        let bad = FiveBarDynamics {
            tool_mass_kg: -1.0,
            ..d
        };
        assert!(append_dynamics_block(&img, &bad).is_err());
        // In f64 positive, in f32 zero: refused as the firmware would refuse it.
        let tiny = FiveBarDynamics {
            motor_inertia_kg_m2: [1e-60, 1e-3],
            ..d
        };
        assert!(append_dynamics_block(&img, &tiny).is_err());
    }
}
