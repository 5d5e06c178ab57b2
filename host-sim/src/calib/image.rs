//! The flash image a calibration writes, and the one reader every command uses to read one.
//!
//! An image is the correction grid's image (`super::grid`) followed by the machine's extension
//! blocks (`kinematics_core::grid`, "Extension blocks"), in this order:
//! * the workspace block (`HRWS`: the polygon and the stop margin the firmware's controlled
//!   stop keeps to), [`finish_image`];
//! * when the dynamics were identified (`dynamics.json`), the dynamics block (`HRDY`: what the
//!   servo feeds forward), [`append_dynamics_block`];
//! * when the model carries a backlash (`backlash_urad`), the backlash block (`HRBL`: what the
//!   servo's reference compensates), [`append_backlash_block`];
//! * last, the machine record (`HRMC`: the machine it was built for and the limits it is judged
//!   against), [`seal_image`], which also judges the finished image as the controller will.
//!
//! Newer blocks go after older ones so that a firmware that does not know a block still reads
//! every block before it.
//!
//! Reading: [`read_image`] (and [`judge_bytes`] for bytes in hand) parse an image and judge it
//! for the machine of `--machine` (`kinematics_core::machine::judge_image`): another machine's
//! image, or one a calibration of this machine cannot have produced, is refused naming what
//! differs with both values. `command`, `measure --grid`, `simulate --grid` and `link upload`
//! read images through it. Cost: one CRC over the image and the judgement (a few ms).
//!
//! [`commissioning_image`] is what a machine starts with: the nominal model, zero corrections,
//! the workspace block and the machine record (`host-sim grid --nominal`).

use super::backlash::Backlash;
use super::{invalid, CalibError};
use crate::io::read_bytes;
use crate::machine_spec::MachineSpec;
use kinematics_core::grid::{
    append_backlash, append_dynamics, append_machine, append_workspace, encode, BACKLASH_LEN,
    DYNAMICS_LEN, MACHINE_LEN, WORKSPACE_LEN,
};
use kinematics_core::machine::{judge_image, ImageRefusal, MachineRecord, Verdict};
use kinematics_core::{CorrectionGrid, FiveBarDynamics};
use std::path::Path;

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
    if grid.machine().is_some() {
        return Err(invalid!(
            "the grid image is sealed with its machine record (the last block): append the {name} block before seal_image"
        ));
    }
    let n = grid.geometry().image_len();
    let end = image.len();
    let mut out = image.to_vec();
    out.resize(end + block_len, 0);
    let end = write(&mut out, n, end)?;
    out.truncate(end);
    Ok(out)
}

/// `image` (a grid image with its other blocks: it must parse) with `spec`'s machine record
/// appended as the last block, judged as the controller will judge it
/// ([`judge_bytes`]): an image the controller would refuse is refused here, before it is
/// written. Refused too: an image that already carries a record.
pub fn seal_image(image: &[u8], spec: &MachineSpec) -> Result<CheckedImage, CalibError> {
    let record = spec
        .record()
        .map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    let out = append_block(
        image,
        "machine record",
        MACHINE_LEN,
        |g| g.machine().is_some(),
        |out, n, end| {
            append_machine(out, n, end, &record)
                .map_err(|e| invalid!("the machine record block: {e}"))
        },
    )?;
    let verdict = judge_bytes(&out, &record).map_err(|e| e.context("the image built"))?;
    Ok(CheckedImage {
        bytes: out,
        verdict,
    })
}

/// The commissioning image of `spec`'s machine: its nominal model, zero corrections on its grid
/// lattice, its workspace block and its machine record. What a machine starts with before any
/// calibration (`host-sim grid --nominal`).
pub fn commissioning_image(spec: &MachineSpec) -> Result<CheckedImage, CalibError> {
    let g = spec.grid.geometry();
    let mut image = vec![0u8; g.image_len()];
    encode(
        &mut image,
        &g,
        &spec.nominal.cast::<f32>(),
        &vec![[0.0; 2]; g.len()],
    )
    .map_err(|e| invalid!("machine '{}': the grid image: {e}", spec.name))?;
    let (image, _) = finish_image(&image, spec)?;
    seal_image(&image, spec)
}

/// Judges the image in `bytes` for the machine `record` (`kinematics_core::machine::judge_image`:
/// an image carrying another machine's record, a model of another machine, content a
/// calibration of this machine cannot need): the refusal names what differs with both values
/// and what to do.
pub fn judge_bytes(bytes: &[u8], record: &MachineRecord) -> Result<Verdict, CalibError> {
    let grid = CorrectionGrid::parse(bytes).map_err(|e| invalid!("{e}"))?;
    judge_image(&grid, record).map_err(|e| match e {
        ImageRefusal::OtherMachine(_) => invalid!(
            "{e}; refused (give --machine the machine file the image was built for, or rebuild the image for this machine)"
        ),
        ImageRefusal::Implausible(_) => invalid!(
            "{e}; refused: no calibration of machine '{}' needs this (rebuild the image with host-sim grid; the limits are the machine file's [controller] keys)",
            record.name
        ),
        ImageRefusal::Record(_) => invalid!("machine '{}': {e}", record.name),
    })
}

/// A calibration image read from a file and accepted for a machine.
#[derive(Clone, Debug)]
pub struct CheckedImage {
    /// The file's bytes.
    pub bytes: Vec<u8>,
    /// The judgement: the record it was judged against and how close its model is.
    pub verdict: Verdict,
}

/// Reads the image at `path` and judges it for `spec`'s machine ([`judge_bytes`]): the one
/// reader of every command that takes an image. Errors name the file.
pub fn read_image(path: &Path, spec: &MachineSpec) -> Result<CheckedImage, CalibError> {
    let record = spec
        .record()
        .map_err(|e| invalid!("machine '{}': {e}", spec.name))?;
    read_image_for(path, &record)
}

/// [`read_image`] for a machine record in hand.
pub fn read_image_for(path: &Path, record: &MachineRecord) -> Result<CheckedImage, CalibError> {
    let bytes = read_bytes(path)?;
    let verdict = judge_bytes(&bytes, record).map_err(|e| e.context(path.display().to_string()))?;
    Ok(CheckedImage { bytes, verdict })
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
    fn the_machine_record_goes_last_seals_the_image_and_judges_it() {
        let spec = MachineSpec::paper();
        let (img, _) = finish_image(&image(&spec.grid.geometry()), &spec).unwrap();
        let b = Backlash::new([20.0, 35.0]).unwrap();
        let with_backlash = append_backlash_block(&img, &b).unwrap();
        let sealed = seal_image(&with_backlash, &spec).unwrap();
        assert_eq!(&sealed.bytes[..with_backlash.len()], &with_backlash[..]);
        assert_eq!(sealed.bytes.len(), with_backlash.len() + MACHINE_LEN);
        let parsed = CorrectionGrid::parse(&sealed.bytes).unwrap();
        assert_eq!(parsed.machine(), Some(spec.record().unwrap()));
        assert!(sealed.verdict.carried && sealed.verdict.same.worst_mm < 1e-3);
        // Nothing goes after the record, and it comes once.
        let e = append_dynamics_block(&sealed.bytes, &spec.controller.nominal_dynamics)
            .unwrap_err()
            .to_string();
        assert!(e.contains("sealed"), "{e}");
        assert!(seal_image(&sealed.bytes, &spec).is_err());
        // An image the controller would refuse is not sealed: corrections of 0.05 rad.
        let g = spec.grid.geometry();
        let mut bad = vec![0u8; g.image_len()];
        encode(
            &mut bad,
            &g,
            &FiveBar::paper_nominal(),
            &vec![[0.05, 0.05]; g.len()],
        )
        .unwrap();
        let e = seal_image(&bad, &spec).unwrap_err().to_string();
        assert!(e.contains("grid node (0, 0) moves the tool by"), "{e}");
    }

    #[test]
    fn the_commissioning_image_is_the_nominal_with_zero_corrections() {
        for spec in [
            MachineSpec::paper(),
            crate::io::machine_file::read_machine(std::path::Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/machines/second.toml"
            )))
            .unwrap(),
        ] {
            let img = commissioning_image(&spec).unwrap();
            let g = CorrectionGrid::parse(&img.bytes).unwrap();
            assert_eq!(*g.model(), spec.nominal.cast::<f32>());
            assert_eq!(g.geometry(), &spec.grid.geometry());
            assert!((0..g.geometry().nx).all(|i| g.node_rad(i, 3) == [0.0; 2]));
            assert_eq!(g.workspace(), Some(spec.workspace.limits().unwrap()));
            assert_eq!(g.machine(), Some(spec.record().unwrap()));
            assert_eq!(g.len_bytes(), img.bytes.len());
        }
    }

    #[test]
    fn an_image_is_judged_for_the_machine_it_is_read_for() {
        let paper = MachineSpec::paper();
        let second = crate::io::machine_file::read_machine(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/machines/second.toml"
        )))
        .unwrap();
        let img = commissioning_image(&paper).unwrap().bytes;
        assert!(judge_bytes(&img, &paper.record().unwrap()).is_ok());
        let e = judge_bytes(&img, &second.record().unwrap())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("built for machine 'paper'") && e.contains("this is machine 'second'"),
            "{e}"
        );
        // Without a record, the model itself is judged: the paper's five-bar is not the
        // second machine's.
        let (plain, _) = finish_image(&image(&paper.grid.geometry()), &paper).unwrap();
        let e = judge_bytes(&plain, &second.record().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("another machine"), "{e}");
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
