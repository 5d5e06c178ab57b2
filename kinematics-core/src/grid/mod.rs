//! The correction grid as it lives in flash: a versioned, CRC-protected binary image.
//!
//! # What a node stores, and why
//! Each node stores the *joint* corrections `(δθ1, δθ2)` (rad, added to the hidden robot's
//! encoder angles), not the task-space errors `(δx, δy)` the paper stores and maps through
//! `J⁻¹` at run time. The host tool that builds the image maps each node's measured error
//! through `J⁻¹` once, in f64, with the fitted model; the 2 kHz loop then does two bilinear
//! interpolations and nothing else: no Jacobian, no division, no singularity case. Interpolating
//! `J⁻¹·δ` instead of `δ` differs only by the variation of `J⁻¹` across one cell times the
//! error: a second-order term that shrinks with the error left after the model fit.
//! Bilinear interpolation of the error field itself has the same order of error, so storing
//! task-space errors would not be more accurate, only slower.
//!
//! The image also carries the hidden robot it was built for: a grid only makes sense together
//! with the model whose IK it corrects, so flashing a new calibration replaces both at once and
//! a grid can never be paired with the wrong model.
//!
//! # Layout (version 1, little-endian, no padding)
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 4 | magic `b"HRCG"` |
//! | 4 | 2 | version, `1` |
//! | 6 | 2 | header length, `72` |
//! | 8 | 2 | `nx`, nodes along x (2..=1024) |
//! | 10 | 2 | `ny`, nodes along y (2..=1024) |
//! | 12 | 4 | flags: bit 0 elbow 1 positive, bit 1 elbow 2 positive, bit 2 assembly positive; others 0 |
//! | 16 | 4×4 | f32 `x0_mm, y0_mm, step_x_mm, step_y_mm` (steps > 0) |
//! | 32 | 8×4 | f32 model `a, b, c, d` (mm), `b0_x, b0_y` (mm, relative to A0), `offset_1, offset_2` (rad) |
//! | 64 | 2×4 | f32 model `a0_x, a0_y` (mm) |
//! | 72 | 8·nx·ny | f32 pairs `(δθ1_rad, δθ2_rad)`, node `(i, j)` at index `j·nx + i` (x fastest) |
//! | end-4 | 4 | CRC-32/ISO-HDLC (zlib's) of every byte before it |
//!
//! Node `(i, j)` sits at `(x0 + i·step_x, y0 + j·step_y)`.
//!
//! # Extension blocks (optional, a chain after the image's CRC)
//! What else the firmware needs of the machine travels with the image it belongs to, in blocks
//! appended after the version-1 image. A version-1 parser (older firmware) stops at the image's
//! CRC and still reads the grid; this parser reads the chain: at each position, the next 4
//! bytes are a known magic (the block is parsed and validated, then the next one starts right
//! after it) or they are not (erased flash `0xFF…`, the rest of the region, anything else: the
//! chain ends there, and those bytes are ignored, so the parser can be handed the whole flash
//! region). Blocks may come in any order; each magic at most once. Every block has the same
//! frame:
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 0 | 4 | magic |
//! | 4 | 2 | block version |
//! | 6 | 2 | block length in bytes, frame included (fixed per magic and version) |
//! | 8 | 4 | the CRC of the image it belongs to (a block left behind by another image is refused) |
//! | 12 | len − 16 | payload |
//! | len − 4 | 4 | CRC-32/ISO-HDLC of the block's bytes before it |
//!
//! A block with a known magic that fails any check (version, length, truncated, image CRC, its
//! own CRC, its payload's validation, a second block with the same magic) refuses the whole
//! image with that block's error: a corrupt limit must not be read as "no limit".
//!
//! Known blocks (one match arm each in `blocks::parse_extensions`; a new block is a magic, a
//! payload spec here, an error variant and an arm):
//!
//! **`HRWS`, the workspace** (version 1, 152 bytes, [`WorkspaceLimits`]): where the machine may
//! be commanded and where a controlled stop must end (`firmware/controller/src/stop.rs`).
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 2 | vertex count `n` (3..=[`crate::MAX_WORKSPACE_VERTICES`]) |
//! | 14 | 2 | reserved, 0 |
//! | 16 | 4 | f32 `stop_margin_mm`: the soft limit, how far inside the polygon a stop must end (≥ 0) |
//! | 20 | 16×8 | f32 pairs `(x_mm, y_mm)`: the `n` vertices, counter-clockwise, strictly convex; unused slots 0 |
//! | 148 | 4 | block CRC |
//!
//! Checks: the polygon is strictly convex and counter-clockwise ([`crate::ConvexWorkspace::new`]) and
//! lies within the node rectangle (to [`EDGE_TOLERANCE_CELLS`]): a stop may never end where
//! the grid cannot correct. Refusal: [`GridError::BadWorkspace`].
//!
//! **`HRDY`, the identified dynamics** (version 1, 56 bytes, [`crate::FiveBarDynamics`]):
//! what the servo feeds forward (`Servo::step_motion`). The dynamic parameters travel with the
//! model they were identified for.
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 10×4 | f32 `I1, I2` (kg·m²), `m_C` (kg), `J3, J4` (kg·m²), `fv1, fv2` (N·m·s/rad), `fc1, fc2` (N·m), Coulomb speed (rad/s) |
//! | 52 | 4 | block CRC |
//!
//! Checks: [`crate::FiveBarDynamics::validate`] (feed-forward from a corrupt block would push the
//! motors). Refusal: [`GridError::BadDynamics`].
//!
//! **`HRBL`, the backlash** (version 1, 24 bytes, [`crate::Backlash`]): the lost motion
//! β_j of each drive, which the servo compensates by the play operator on its joint reference
//! ([`crate::backlash`]). It travels with the model it was identified with (`diagnose
//! --out-model`'s `backlash_urad`).
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 2×4 | f32 `β1, β2` (rad, the whole gap of motor 1 and 2) |
//! | 20 | 4 | block CRC |
//!
//! Checks: [`crate::Backlash::new`] (finite, `0..=`[`crate::backlash::MAX_BACKLASH_RAD`]: a corrupt
//! gap would push the motor by it). Refusal: [`GridError::BadBacklash`]. Without the block
//! the servo applies no compensation.
//!
//! **`HRMC`, the machine record** (version 1, 280 bytes, [`crate::machine::MachineRecord`]):
//! the machine the image was built for (name, nominal model, encoder convention, workspace,
//! home, plausibility limits); its digest names the machine. Payload: the record's canonical
//! encoding, [`crate::machine::record::ENCODED_LEN`] bytes (layout in `crate::machine::record`).
//! Checks: [`crate::machine::MachineRecord::parse`]. Refusal: [`GridError::BadMachineRecord`].
//! Whether the image is plausible for that machine is a judgement, not a format check
//! ([`crate::machine::judge_image`]).
//!
//! An image may carry any of these blocks, in any order. The writers here
//! ([`append_workspace`], [`append_dynamics`], [`append_backlash`], [`append_machine`],
//! [`encode_with_dynamics`]) append a block at a given end, so a chain is built one block after
//! the other. A parser that does not know a block stops its chain at that block's magic and
//! ignores it and everything after it, so the writers put the newest blocks last: the
//! backlash block after the workspace and dynamics blocks, the machine record after all of them.
//!
//! # Outside the grid
//! A point more than [`EDGE_TOLERANCE_CELLS`] of a cell outside the node rectangle is refused
//! with [`GridError::OutsideGrid`]: an uncalibrated region is not silently extrapolated. Points
//! within that tolerance (float rounding of a target on the boundary) take the edge value.
//!
//! # Files
//! `format` (constants, errors, the lattice), `image` (parse, lookup, encode), `blocks` (the
//! chain's reader), `append` (the block writers). The user-facing specification, with the
//! plausibility limits an image is judged against, is `docs/reference/calibration-image.md`.
//!
//! # Example
//! ```
//! use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
//! use kinematics_core::FiveBar;
//!
//! let geometry = GridGeometry {
//!     nx: 3, ny: 3, x0_mm: 160.0, y0_mm: -80.0, step_x_mm: 50.0, step_y_mm: 80.0,
//! };
//! let mut image = vec![0u8; geometry.image_len()];
//! encode(&mut image, &geometry, &FiveBar::paper_nominal(), &[[2e-4, -1e-4]; 9]).unwrap();
//! let grid = CorrectionGrid::parse(&image).unwrap();
//! assert_eq!(grid.correction_rad([200.0, 0.0]), Ok([2e-4, -1e-4]));
//! // A flipped bit anywhere is refused, never read.
//! image[100] ^= 1;
//! assert!(CorrectionGrid::parse(&image).is_err());
//! ```

mod append;
mod blocks;
mod format;
mod image;

pub use crate::workspace::WorkspaceLimits;
pub use append::{
    append_backlash, append_dynamics, append_machine, append_workspace, encode_with_dynamics,
    image_crc,
};
pub use format::{
    GridError, GridGeometry, BACKLASH_LEN, BACKLASH_MAGIC, BACKLASH_VERSION, BLOCK_FRAME_LEN,
    DYNAMICS_LEN, DYNAMICS_MAGIC, DYNAMICS_VERSION, EDGE_TOLERANCE_CELLS, HEADER_LEN, MACHINE_LEN,
    MACHINE_MAGIC, MACHINE_VERSION, MAGIC, MAX_NODES_PER_AXIS, VERSION, WORKSPACE_LEN,
    WORKSPACE_MAGIC, WORKSPACE_VERSION,
};
pub use image::{encode, CorrectionGrid};
