//! The correction grid as it lives in flash: a versioned, CRC-protected binary image.
//!
//! # What a node stores, and why
//! Each node stores the *joint* corrections `(δθ1, δθ2)` (rad, added to the hidden robot's
//! encoder angles), not the task-space errors `(δx, δy)` the paper stores and maps through
//! `J⁻¹` at run time. The host tool that builds the image maps each node's measured error
//! through `J⁻¹` once, in f64, with the fitted model; the 2 kHz loop then does two bilinear
//! interpolations and nothing else: no Jacobian, no division, no singularity case. Interpolating
//! `J⁻¹·δ` instead of `δ` differs only by the variation of `J⁻¹` across one 5 mm cell times the
//! error: a second-order term that shrinks with the error left after the model fit (measured
//! in `host-sim`: about 0.8 µm in the corners for a 0.7 mm error field, far less after a fit).
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
//! Known blocks (one match arm each in `parse_extensions`; a new block is a magic, a payload
//! spec here, an error variant and an arm):
//!
//! **`HRWS`, the workspace** (version 1, 152 bytes, [`WorkspaceLimits`]): where the machine may
//! be commanded and where a controlled stop must end (`firmware/controller/src/stop.rs`).
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 2 | vertex count `n` (3..=[`MAX_WORKSPACE_VERTICES`]) |
//! | 14 | 2 | reserved, 0 |
//! | 16 | 4 | f32 `stop_margin_mm`: the soft limit, how far inside the polygon a stop must end (≥ 0) |
//! | 20 | 16×8 | f32 pairs `(x_mm, y_mm)`: the `n` vertices, counter-clockwise, strictly convex; unused slots 0 |
//! | 148 | 4 | block CRC |
//!
//! Checks: the polygon is strictly convex and counter-clockwise ([`ConvexWorkspace::new`]) and
//! lies within the node rectangle (to [`EDGE_TOLERANCE_CELLS`]): a stop may never end where
//! the grid cannot correct. Refusal: [`GridError::BadWorkspace`].
//!
//! **`HRDY`, the identified dynamics** (version 1, 56 bytes, [`FiveBarDynamics`], issue 14):
//! what the servo feeds forward (`Servo::step_motion`). The dynamic parameters travel with the
//! model they were identified for.
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 10×4 | f32 `I1, I2` (kg·m²), `m_C` (kg), `J3, J4` (kg·m²), `fv1, fv2` (N·m·s/rad), `fc1, fc2` (N·m), Coulomb speed (rad/s) |
//! | 52 | 4 | block CRC |
//!
//! Checks: [`FiveBarDynamics::validate`] (feed-forward from a corrupt block would push the
//! motors). Refusal: [`GridError::BadDynamics`].
//!
//! **`HRBL`, the backlash** (version 1, 24 bytes, [`Backlash`], issue 13): the lost motion
//! β_j of each drive, which the servo compensates by the play operator on its joint reference
//! ([`crate::backlash`]). It travels with the model it was identified with (`diagnose
//! --out-model`'s `backlash_urad`).
//!
//! | offset (in the block) | size | field |
//! |---:|---:|---|
//! | 12 | 2×4 | f32 `β1, β2` (rad, the whole gap of motor 1 and 2) |
//! | 20 | 4 | block CRC |
//!
//! Checks: [`Backlash::new`] (finite, `0..=`[`crate::backlash::MAX_BACKLASH_RAD`]: a corrupt
//! gap would push the motor by it). Refusal: [`GridError::BadBacklash`]. Without the block
//! the servo applies no compensation (as before the block existed). A parser older than the
//! block stops its chain at the unknown magic `HRBL` and ignores it (and what follows it):
//! such firmware runs the image uncompensated, never misreads the block; the writers
//! therefore put the backlash block last.
//!
//! An image may carry any of these blocks, in any order. The writers here
//! ([`append_workspace`], [`append_dynamics`], [`append_backlash`], [`encode_with_dynamics`])
//! append a block at a given end, so a chain is built one block after the other. Compatibility: the first
//! dynamics-aware parser (before the chain) read a `HRDY` block only right after the CRC and
//! ignored everything else; images whose chain starts with `HRDY` read the same there.
//! A version-2 header was not used for these blocks because it would have changed what a
//! version-1 image with a tampered version field is refused as.
//!
//! # Outside the grid
//! A point more than [`EDGE_TOLERANCE_CELLS`] of a cell outside the node rectangle is refused
//! with [`GridError::OutsideGrid`]: an uncalibrated region is not silently extrapolated. Points
//! within that tolerance (float rounding of a target on the boundary) take the edge value.

use crate::backlash::Backlash;
use crate::bilinear::bilinear;
use crate::dynamics::{FiveBarDynamics, PARAMETERS};
use crate::model::{Branch, FiveBar, WorkingMode};
use crate::valid_model::ValidFiveBar;
use crate::workspace::{ConvexWorkspace, MAX_WORKSPACE_VERTICES};

/// Image magic.
pub const MAGIC: [u8; 4] = *b"HRCG";
/// The only version this parser reads.
pub const VERSION: u16 = 1;
/// Bytes before the node table.
pub const HEADER_LEN: usize = 72;
/// Largest node count per axis.
pub const MAX_NODES_PER_AXIS: u16 = 1024;
/// How far outside the node rectangle (in cells) a point still takes the edge value.
pub const EDGE_TOLERANCE_CELLS: f32 = 1.0e-4;

/// Bytes of an extension block's frame: magic, version, length, image CRC (12) and its CRC (4).
pub const BLOCK_FRAME_LEN: usize = 16;
/// Magic of the workspace block.
pub const WORKSPACE_MAGIC: [u8; 4] = *b"HRWS";
/// The workspace block's version.
pub const WORKSPACE_VERSION: u16 = 1;
/// Bytes of the workspace block.
pub const WORKSPACE_LEN: usize = BLOCK_FRAME_LEN + 8 + 8 * MAX_WORKSPACE_VERTICES;
/// Magic of the dynamics block.
pub const DYNAMICS_MAGIC: [u8; 4] = *b"HRDY";
/// The dynamics block's version.
pub const DYNAMICS_VERSION: u16 = 1;
/// Bytes of the dynamics block: the frame and the 9 parameters and the Coulomb speed (f32).
pub const DYNAMICS_LEN: usize = BLOCK_FRAME_LEN + 4 * (PARAMETERS + 1);
/// Magic of the backlash block.
pub const BACKLASH_MAGIC: [u8; 4] = *b"HRBL";
/// The backlash block's version.
pub const BACKLASH_VERSION: u16 = 1;
/// Bytes of the backlash block: the frame and β of both motors (f32).
pub const BACKLASH_LEN: usize = BLOCK_FRAME_LEN + 8;

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why an image was refused, or a lookup failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GridError {
    /// Fewer bytes than the header, or than the header says the image has.
    Truncated,
    /// The image does not start with [`MAGIC`] (erased flash, another file).
    BadMagic,
    /// A version this parser does not read (it reads [`VERSION`] only).
    UnsupportedVersion(u16),
    /// Header length, node counts, flags or reserved bytes are not what version 1 allows.
    BadHeader,
    /// The stored CRC does not match the contents.
    BadCrc,
    /// A header number or a node value is NaN or infinite, or a step is not positive.
    NonFinite,
    /// The model in the header is not a valid five-bar.
    BadModel,
    /// The point lies outside the calibrated rectangle.
    OutsideGrid,
    /// `encode` was given a buffer too small or a node count that does not match.
    BadEncodeInput,
    /// The workspace block after the image is corrupt, belongs to another image, repeats, or
    /// holds a polygon that is not convex or leaves the grid.
    BadWorkspace,
    /// The dynamics block after the image is corrupt, belongs to another image, repeats or
    /// holds invalid parameters.
    BadDynamics,
    /// The backlash block after the image is corrupt, belongs to another image, repeats or
    /// holds a lost motion that is not finite or outside `0..=0.01` rad.
    BadBacklash,
}

impl core::fmt::Display for GridError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GridError::Truncated => f.write_str("grid image truncated"),
            GridError::BadMagic => f.write_str("not a correction grid image (bad magic)"),
            GridError::UnsupportedVersion(v) => write!(f, "unsupported grid image version {v}"),
            GridError::BadHeader => f.write_str("malformed grid image header"),
            GridError::BadCrc => f.write_str("grid image CRC mismatch (corrupt image)"),
            GridError::NonFinite => f.write_str("grid image holds a non-finite or invalid number"),
            GridError::BadModel => f.write_str("grid image holds an invalid five-bar model"),
            GridError::OutsideGrid => f.write_str("point outside the correction grid"),
            GridError::BadEncodeInput => f.write_str("grid encode: buffer or node count mismatch"),
            GridError::BadWorkspace => {
                f.write_str("the image's workspace block is corrupt or invalid")
            }
            GridError::BadDynamics => {
                f.write_str("the image's dynamics block is corrupt or invalid")
            }
            GridError::BadBacklash => {
                f.write_str("the image's backlash block is corrupt or invalid")
            }
        }
    }
}

impl core::error::Error for GridError {}

/// Where the nodes are.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GridGeometry {
    /// Nodes along x (2..=[`MAX_NODES_PER_AXIS`]).
    pub nx: u16,
    /// Nodes along y (2..=[`MAX_NODES_PER_AXIS`]).
    pub ny: u16,
    /// x of node `(0, 0)`, the lowest x of the rectangle.
    pub x0_mm: f32,
    /// y of node `(0, 0)`, the lowest y of the rectangle.
    pub y0_mm: f32,
    /// Node spacing along x (> 0).
    pub step_x_mm: f32,
    /// Node spacing along y (> 0).
    pub step_y_mm: f32,
}

impl GridGeometry {
    /// Position of node `(i, j)`.
    pub fn node_mm(&self, i: u16, j: u16) -> [f32; 2] {
        [
            self.x0_mm + i as f32 * self.step_x_mm,
            self.y0_mm + j as f32 * self.step_y_mm,
        ]
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nx as usize * self.ny as usize
    }

    /// Never true for a valid geometry (at least 2x2 nodes).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Total image size in bytes for this geometry.
    pub fn image_len(&self) -> usize {
        HEADER_LEN + 8 * self.len() + 4
    }

    /// Whether every vertex of `region` lies in the node rectangle (to the lookup's
    /// [`EDGE_TOLERANCE_CELLS`]): the grid corrects everywhere in the region.
    pub fn covers(&self, region: &ConvexWorkspace<f32>) -> bool {
        let inside = |v: f32, origin: f32, step: f32, n: u16| {
            let t = (v - origin) / step;
            t >= -EDGE_TOLERANCE_CELLS && t <= n.saturating_sub(1) as f32 + EDGE_TOLERANCE_CELLS
        };
        region.vertices_mm().iter().all(|p| {
            inside(p[0], self.x0_mm, self.step_x_mm, self.nx)
                && inside(p[1], self.y0_mm, self.step_y_mm, self.ny)
        })
    }

    /// Image size followed by the dynamics block.
    pub fn image_len_with_dynamics(&self) -> usize {
        self.image_len() + DYNAMICS_LEN
    }

    fn validate(&self) -> Result<(), GridError> {
        let counts_ok = (2..=MAX_NODES_PER_AXIS).contains(&self.nx)
            && (2..=MAX_NODES_PER_AXIS).contains(&self.ny);
        if !counts_ok {
            return Err(GridError::BadHeader);
        }
        let finite = [self.x0_mm, self.y0_mm, self.step_x_mm, self.step_y_mm]
            .iter()
            .all(|v| v.is_finite());
        if !finite || !(self.step_x_mm > 0.0) || !(self.step_y_mm > 0.0) {
            return Err(GridError::NonFinite);
        }
        Ok(())
    }
}

/// What the workspace block holds: the polygon and the soft limit.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WorkspaceLimits {
    /// Where the machine may be commanded (mm, machine frame).
    pub region: ConvexWorkspace<f32>,
    /// How far inside `region` a controlled stop must end (mm, ≥ 0).
    pub stop_margin_mm: f32,
}

/// A validated image, borrowed from flash (or any byte slice): nothing is copied, nodes are
/// decoded on demand, and so is the workspace block (validated by [`CorrectionGrid::parse`]);
/// the dynamics block is decoded once (the servo reads it every step).
#[derive(Clone, Copy, Debug)]
pub struct CorrectionGrid<'a> {
    geometry: GridGeometry,
    /// Validated by [`CorrectionGrid::parse`].
    model: ValidFiveBar<f32>,
    nodes: &'a [u8],
    /// The workspace block's payload, if the image has one.
    workspace: Option<&'a [u8]>,
    /// The dynamics block's parameters, if the image has one.
    dynamics: Option<FiveBarDynamics<f32>>,
    /// The backlash block's lost motion, if the image has one.
    backlash: Option<Backlash<f32>>,
    /// Bytes of the image with its chain of blocks (where the chain ended).
    len: usize,
    /// The lookup's constants per axis (x, y), from the geometry.
    axes: [CellAxis; 2],
}

/// What [`CorrectionGrid::correction_rad`] needs of one axis of the geometry, computed once when
/// the image is parsed: the lookup then has no division (14 cycles each on the Cortex-M4) and
/// no integer-to-float conversion of the node count.
#[derive(Clone, Copy, Debug, PartialEq)]
struct CellAxis {
    origin_mm: f32,
    /// `1 / step`.
    inv_step: f32,
    /// `n - 1`: the last node, in cells.
    last: f32,
    /// `n - 1 + EDGE_TOLERANCE_CELLS`: the largest cell coordinate accepted.
    upper: f32,
    /// `n - 2`: the last cell's lower node.
    last_cell: u32,
}

impl CellAxis {
    fn of(origin_mm: f32, step_mm: f32, n: u16) -> Self {
        let last = (n - 1) as f32;
        CellAxis {
            origin_mm,
            inv_step: 1.0 / step_mm,
            last,
            upper: last + EDGE_TOLERANCE_CELLS,
            last_cell: u32::from(n - 2),
        }
    }
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

fn branch(flags: u32, bit: u32) -> Branch {
    if flags & (1 << bit) != 0 {
        Branch::Positive
    } else {
        Branch::Negative
    }
}

fn mode_flags(mode: WorkingMode) -> u32 {
    let bit = |b: Branch, n: u32| if b == Branch::Positive { 1 << n } else { 0 };
    bit(mode.elbow_1, 0) | bit(mode.elbow_2, 1) | bit(mode.assembly, 2)
}

impl<'a> CorrectionGrid<'a> {
    /// Validates an image: magic, version, header, sizes, CRC, then every number.
    ///
    /// The CRC is checked before any number is trusted, so a flipped bit anywhere in the image
    /// is reported as [`GridError::BadCrc`] (or as a size error if it hit a count).
    pub fn parse(bytes: &'a [u8]) -> Result<Self, GridError> {
        if bytes.len() < HEADER_LEN {
            return Err(GridError::Truncated);
        }
        if bytes[0..4] != MAGIC {
            return Err(GridError::BadMagic);
        }
        let version = u16_at(bytes, 4);
        if version != VERSION {
            return Err(GridError::UnsupportedVersion(version));
        }
        if u16_at(bytes, 6) as usize != HEADER_LEN {
            return Err(GridError::BadHeader);
        }
        let geometry = GridGeometry {
            nx: u16_at(bytes, 8),
            ny: u16_at(bytes, 10),
            x0_mm: f32_at(bytes, 16),
            y0_mm: f32_at(bytes, 20),
            step_x_mm: f32_at(bytes, 24),
            step_y_mm: f32_at(bytes, 28),
        };
        if !(2..=MAX_NODES_PER_AXIS).contains(&geometry.nx)
            || !(2..=MAX_NODES_PER_AXIS).contains(&geometry.ny)
        {
            return Err(GridError::BadHeader);
        }
        let total = geometry.image_len();
        if bytes.len() < total {
            return Err(GridError::Truncated);
        }
        let stored_crc = u32_at(bytes, total - 4);
        if CRC32.checksum(&bytes[..total - 4]) != stored_crc {
            return Err(GridError::BadCrc);
        }
        let flags = u32_at(bytes, 12);
        if flags & !0b111 != 0 {
            return Err(GridError::BadHeader);
        }
        geometry.validate()?;
        let p = |k: usize| f32_at(bytes, 32 + 4 * k);
        let model = FiveBar {
            a_mm: p(0),
            b_mm: p(1),
            c_mm: p(2),
            d_mm: p(3),
            base_a0_mm: [p(8), p(9)],
            base_b0_mm: [p(4), p(5)],
            encoder_offset_rad: [p(6), p(7)],
            mode: WorkingMode {
                elbow_1: branch(flags, 0),
                elbow_2: branch(flags, 1),
                assembly: branch(flags, 2),
            },
        };
        model.validate().map_err(|_| GridError::BadModel)?;
        let model = ValidFiveBar::from_validated(model);
        let nodes = &bytes[HEADER_LEN..total - 4];
        if nodes
            .chunks_exact(4)
            .any(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
        {
            return Err(GridError::NonFinite);
        }
        let extensions = parse_extensions(&bytes[total..], stored_crc, &geometry)?;
        let len = total + extensions.len;
        let axes = [
            CellAxis::of(geometry.x0_mm, geometry.step_x_mm, geometry.nx),
            CellAxis::of(geometry.y0_mm, geometry.step_y_mm, geometry.ny),
        ];
        Ok(CorrectionGrid {
            geometry,
            model,
            nodes,
            workspace: extensions.workspace,
            dynamics: extensions.dynamics,
            backlash: extensions.backlash,
            len,
            axes,
        })
    }

    /// Bytes of the image with its chain of extension blocks: what a copy of the image (an
    /// upload, a flash slot) must hold; the bytes after it in the region are not the image's.
    pub fn len_bytes(&self) -> usize {
        self.len
    }

    /// The identified dynamics, if the image carries the block (validated by [`Self::parse`]).
    pub fn dynamics(&self) -> Option<&FiveBarDynamics<f32>> {
        self.dynamics.as_ref()
    }

    /// The lost motion of the drives, if the image carries the block (validated by
    /// [`Self::parse`]): what the servo compensates.
    pub fn backlash(&self) -> Option<&Backlash<f32>> {
        self.backlash.as_ref()
    }

    /// The workspace limits, if the image carries the block (validated by [`Self::parse`]).
    pub fn workspace(&self) -> Option<WorkspaceLimits> {
        self.workspace.and_then(|p| decode_workspace(p).ok())
    }

    /// Where the nodes are.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// The hidden robot this grid corrects.
    pub fn model(&self) -> &FiveBar<f32> {
        self.model.model()
    }

    /// The same model as checked once by [`Self::parse`] (what the servo's IK uses).
    pub fn valid_model(&self) -> &ValidFiveBar<f32> {
        &self.model
    }

    /// The stored correction of node `(i, j)`. Callers keep `i < nx` and `j < ny` (the lookup
    /// does); an index past the end of the table reads as zero instead of panicking.
    #[inline]
    pub fn node_rad(&self, i: u16, j: u16) -> [f32; 2] {
        let k = 8 * (j as usize * self.geometry.nx as usize + i as usize);
        // One range check for the 8 bytes; the fixed-size copies then compile to two loads.
        match self.nodes.get(k..k + 8) {
            Some(n) => {
                let (mut t1, mut t2) = ([0u8; 4], [0u8; 4]);
                t1.copy_from_slice(&n[..4]);
                t2.copy_from_slice(&n[4..]);
                [f32::from_le_bytes(t1), f32::from_le_bytes(t2)]
            }
            None => [0.0; 2],
        }
    }

    /// Joint corrections at `p_mm` by bilinear interpolation (Eq. 7), to be *added* to the
    /// model's encoder angles.
    ///
    /// Cost (`BENCH grid_lookup`): the cell from one multiplication per axis by the reciprocal
    /// of the step (computed at parse), the four nodes as two rows of two (one range check
    /// each: nodes `(i, j)`, `(i+1, j)` are adjacent in the table), two bilinear sums.
    pub fn correction_rad(&self, p_mm: [f32; 2]) -> Result<[f32; 2], GridError> {
        let (i, u) = cell(p_mm[0], &self.axes[0])?;
        let (j, v) = cell(p_mm[1], &self.axes[1])?;
        let k = 8 * (j * self.geometry.nx as usize + i);
        // The cell's indices keep both pairs inside the table (checked at parse); the range
        // checks stay (no `unsafe`), and a pair past the end would refuse the point.
        let (Some(r1), Some(r2)) = (
            self.node_pair(k),
            self.node_pair(k + 8 * self.geometry.nx as usize),
        ) else {
            return Err(GridError::OutsideGrid);
        };
        Ok([
            bilinear(r1[0], r2[0], r1[2], r2[2], u, v),
            bilinear(r1[1], r2[1], r1[3], r2[3], u, v),
        ])
    }

    /// The two nodes whose table entries start at byte `k`: `[δ1, δ2]` of each.
    #[inline]
    fn node_pair(&self, k: usize) -> Option<[f32; 4]> {
        let b = <&[u8; 16]>::try_from(self.nodes.get(k..k + 16)?).ok()?;
        Some(core::array::from_fn(|m| {
            f32::from_le_bytes([b[4 * m], b[4 * m + 1], b[4 * m + 2], b[4 * m + 3]])
        }))
    }
}

/// Cell index (lower node) and cell-relative coordinate in `[0, 1]` along one axis.
#[inline]
fn cell(p: f32, axis: &CellAxis) -> Result<(usize, f32), GridError> {
    let t = (p - axis.origin_mm) * axis.inv_step;
    // `!(..)` so that NaN is refused too.
    if !(t >= -EDGE_TOLERANCE_CELLS && t <= axis.upper) {
        return Err(GridError::OutsideGrid);
    }
    // Into [0, n-1] (comparisons, not `f32::clamp`, which checks its bounds at run time).
    let t = if t > 0.0 { t } else { 0.0 };
    let t = if t < axis.last { t } else { axis.last };
    // `t` is in [0, n-1]: truncation is floor; the last node belongs to the last cell. (To
    // u32, which VCVT does alone; to u16 the cast adds its own saturation.)
    let i = (t as u32).min(axis.last_cell);
    Ok((i as usize, t - i as f32))
}

/// Writes an image into `out` and returns its length. `nodes_rad` holds `nx·ny` pairs in the
/// image order (x fastest). Used by the host tools and the tests; the firmware only parses.
pub fn encode(
    out: &mut [u8],
    geometry: &GridGeometry,
    model: &FiveBar<f32>,
    nodes_rad: &[[f32; 2]],
) -> Result<usize, GridError> {
    geometry.validate()?;
    model.validate().map_err(|_| GridError::BadModel)?;
    let total = geometry.image_len();
    if out.len() < total || nodes_rad.len() != geometry.len() {
        return Err(GridError::BadEncodeInput);
    }
    if nodes_rad.iter().flatten().any(|v| !v.is_finite()) {
        return Err(GridError::NonFinite);
    }
    let out = &mut out[..total];
    out.fill(0);
    out[0..4].copy_from_slice(&MAGIC);
    out[4..6].copy_from_slice(&VERSION.to_le_bytes());
    out[6..8].copy_from_slice(&(HEADER_LEN as u16).to_le_bytes());
    out[8..10].copy_from_slice(&geometry.nx.to_le_bytes());
    out[10..12].copy_from_slice(&geometry.ny.to_le_bytes());
    out[12..16].copy_from_slice(&mode_flags(model.mode).to_le_bytes());
    let header_f32 = [
        geometry.x0_mm,
        geometry.y0_mm,
        geometry.step_x_mm,
        geometry.step_y_mm,
        model.a_mm,
        model.b_mm,
        model.c_mm,
        model.d_mm,
        model.base_b0_mm[0],
        model.base_b0_mm[1],
        model.encoder_offset_rad[0],
        model.encoder_offset_rad[1],
        model.base_a0_mm[0],
        model.base_a0_mm[1],
    ];
    for (k, v) in header_f32.iter().enumerate() {
        out[16 + 4 * k..20 + 4 * k].copy_from_slice(&v.to_le_bytes());
    }
    for (k, v) in nodes_rad.iter().flatten().enumerate() {
        let at = HEADER_LEN + 4 * k;
        out[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }
    let crc = CRC32.checksum(&out[..total - 4]);
    out[total - 4..].copy_from_slice(&crc.to_le_bytes());
    Ok(total)
}

/// The extension blocks found after an image (see the module doc, "Extension blocks").
#[derive(Default)]
struct Extensions<'a> {
    workspace: Option<&'a [u8]>,
    dynamics: Option<FiveBarDynamics<f32>>,
    backlash: Option<Backlash<f32>>,
    /// Bytes of the chain (0 without blocks).
    len: usize,
}

/// The payload of the framed block at the start of `rest` if its frame is sound (version,
/// length, image CRC, own CRC); `None` otherwise.
fn framed_payload(rest: &[u8], version: u16, len: usize, image_crc: u32) -> Option<&[u8]> {
    let block = rest.get(..len)?;
    let sound = u16_at(block, 4) == version
        && u16_at(block, 6) as usize == len
        && u32_at(block, 8) == image_crc
        && CRC32.checksum(&block[..len - 4]) == u32_at(block, len - 4);
    sound.then(|| &block[12..len - 4])
}

/// Reads the chain of extension blocks in `rest` (the bytes after an image whose CRC is
/// `image_crc`) until bytes that are no known magic.
fn parse_extensions<'a>(
    rest: &'a [u8],
    image_crc: u32,
    geometry: &GridGeometry,
) -> Result<Extensions<'a>, GridError> {
    let mut found = Extensions::default();
    let mut at = 0;
    while let Some(magic) = rest.get(at..at + 4) {
        // One arm per known block; anything else ends the chain.
        let len = match magic {
            m if m == WORKSPACE_MAGIC => {
                let payload =
                    framed_payload(&rest[at..], WORKSPACE_VERSION, WORKSPACE_LEN, image_crc)
                        .ok_or(GridError::BadWorkspace)?;
                let limits = decode_workspace(payload)?;
                if found.workspace.is_some() || !geometry.covers(&limits.region) {
                    return Err(GridError::BadWorkspace);
                }
                found.workspace = Some(payload);
                WORKSPACE_LEN
            }
            m if m == DYNAMICS_MAGIC => {
                let payload =
                    framed_payload(&rest[at..], DYNAMICS_VERSION, DYNAMICS_LEN, image_crc)
                        .ok_or(GridError::BadDynamics)?;
                if found.dynamics.is_some() {
                    return Err(GridError::BadDynamics);
                }
                found.dynamics = Some(decode_dynamics(payload)?);
                DYNAMICS_LEN
            }
            m if m == BACKLASH_MAGIC => {
                let payload =
                    framed_payload(&rest[at..], BACKLASH_VERSION, BACKLASH_LEN, image_crc)
                        .ok_or(GridError::BadBacklash)?;
                if found.backlash.is_some() {
                    return Err(GridError::BadBacklash);
                }
                found.backlash = Some(decode_backlash(payload)?);
                BACKLASH_LEN
            }
            _ => break,
        };
        at += len;
    }
    found.len = at;
    Ok(found)
}

/// The workspace block's payload (the block without its 12-byte head and CRC) decoded and
/// checked.
fn decode_workspace(payload: &[u8]) -> Result<WorkspaceLimits, GridError> {
    if payload.len() != WORKSPACE_LEN - BLOCK_FRAME_LEN {
        return Err(GridError::BadWorkspace);
    }
    let n = u16_at(payload, 0) as usize;
    if !(3..=MAX_WORKSPACE_VERTICES).contains(&n) || u16_at(payload, 2) != 0 {
        return Err(GridError::BadWorkspace);
    }
    let stop_margin_mm = f32_at(payload, 4);
    if !(stop_margin_mm.is_finite() && stop_margin_mm >= 0.0) {
        return Err(GridError::BadWorkspace);
    }
    let mut v = [[0.0f32; 2]; MAX_WORKSPACE_VERTICES];
    for (k, p) in v.iter_mut().enumerate() {
        *p = [f32_at(payload, 8 + 8 * k), f32_at(payload, 12 + 8 * k)];
        // Unused slots are zero (bit pattern), so a block has one encoding.
        if k >= n && (u32_at(payload, 8 + 8 * k) != 0 || u32_at(payload, 12 + 8 * k) != 0) {
            return Err(GridError::BadWorkspace);
        }
    }
    let region = ConvexWorkspace::new(&v[..n]).map_err(|_| GridError::BadWorkspace)?;
    Ok(WorkspaceLimits {
        region,
        stop_margin_mm,
    })
}

/// The dynamics block's payload decoded and validated.
fn decode_dynamics(payload: &[u8]) -> Result<FiveBarDynamics<f32>, GridError> {
    if payload.len() != DYNAMICS_LEN - BLOCK_FRAME_LEN {
        return Err(GridError::BadDynamics);
    }
    let mut p = [0.0f32; PARAMETERS];
    for (k, v) in p.iter_mut().enumerate() {
        *v = f32_at(payload, 4 * k);
    }
    let d = FiveBarDynamics::from_array(p, f32_at(payload, 4 * PARAMETERS));
    d.validate().map_err(|_| GridError::BadDynamics)?;
    Ok(d)
}

/// The backlash block's payload decoded and validated.
fn decode_backlash(payload: &[u8]) -> Result<Backlash<f32>, GridError> {
    if payload.len() != BACKLASH_LEN - BLOCK_FRAME_LEN {
        return Err(GridError::BadBacklash);
    }
    Backlash::new([f32_at(payload, 0), f32_at(payload, 4)]).map_err(|_| GridError::BadBacklash)
}

/// Writes one framed extension block into `out` (exactly `len` bytes): magic, version, length,
/// the image's CRC, the payload `fill` writes into `out[12..len - 4]`, the block's CRC.
fn write_block(
    out: &mut [u8],
    magic: [u8; 4],
    version: u16,
    len: usize,
    image_crc: u32,
    fill: impl FnOnce(&mut [u8]),
) {
    out.fill(0);
    out[0..4].copy_from_slice(&magic);
    out[4..6].copy_from_slice(&version.to_le_bytes());
    out[6..8].copy_from_slice(&(len as u16).to_le_bytes());
    out[8..12].copy_from_slice(&image_crc.to_le_bytes());
    fill(&mut out[12..len - 4]);
    let crc = CRC32.checksum(&out[..len - 4]);
    out[len - 4..len].copy_from_slice(&crc.to_le_bytes());
}

/// The CRC an image of `image_len` bytes at the start of `image` carries (what its blocks
/// must repeat); `None` if `image` is shorter.
pub fn image_crc(image: &[u8], image_len: usize) -> Option<u32> {
    (image_len >= 4 && image.len() >= image_len).then(|| u32_at(image, image_len - 4))
}

/// What every block writer checks before it writes: the image's CRC (the block carries it),
/// room for a block of `block_len` bytes at `at` (not inside the image), and an image that
/// parses. Returns the CRC and the image's geometry.
fn block_slot(
    out: &[u8],
    image_len: usize,
    at: usize,
    block_len: usize,
) -> Result<(u32, GridGeometry), GridError> {
    let crc = image_crc(out, image_len).ok_or(GridError::BadEncodeInput)?;
    if at < image_len || out.len() < at + block_len {
        return Err(GridError::BadEncodeInput);
    }
    Ok((crc, CorrectionGrid::parse(&out[..image_len])?.geometry))
}

/// Appends the workspace block to the image in `out[..image_len]` (an image from [`encode`],
/// possibly followed by other blocks: `at` is where this block goes) and returns the new end.
/// `out` must hold `at + WORKSPACE_LEN` bytes. The block is checked as the parser checks it,
/// the polygon against the image's grid included.
pub fn append_workspace(
    out: &mut [u8],
    image_len: usize,
    at: usize,
    limits: &WorkspaceLimits,
) -> Result<usize, GridError> {
    let (crc, geometry) = block_slot(out, image_len, at, WORKSPACE_LEN)?;
    let margin_ok = limits.stop_margin_mm.is_finite() && limits.stop_margin_mm >= 0.0;
    if !margin_ok || !geometry.covers(&limits.region) {
        return Err(GridError::BadWorkspace);
    }
    let v = limits.region.vertices_mm();
    write_block(
        &mut out[at..at + WORKSPACE_LEN],
        WORKSPACE_MAGIC,
        WORKSPACE_VERSION,
        WORKSPACE_LEN,
        crc,
        |p| {
            p[0..2].copy_from_slice(&(v.len() as u16).to_le_bytes());
            p[4..8].copy_from_slice(&limits.stop_margin_mm.to_le_bytes());
            for (k, q) in v.iter().enumerate() {
                p[8 + 8 * k..12 + 8 * k].copy_from_slice(&q[0].to_le_bytes());
                p[12 + 8 * k..16 + 8 * k].copy_from_slice(&q[1].to_le_bytes());
            }
        },
    );
    Ok(at + WORKSPACE_LEN)
}

/// Appends the dynamics block to the image in `out[..image_len]` (an image from [`encode`],
/// possibly followed by other blocks: `at` is where this block goes) and returns the new end.
/// `out` must hold `at + DYNAMICS_LEN` bytes; the parameters are validated as the parser does.
pub fn append_dynamics(
    out: &mut [u8],
    image_len: usize,
    at: usize,
    dynamics: &FiveBarDynamics<f32>,
) -> Result<usize, GridError> {
    dynamics.validate().map_err(|_| GridError::BadDynamics)?;
    let (crc, _) = block_slot(out, image_len, at, DYNAMICS_LEN)?;
    let values = dynamics.to_array();
    write_block(
        &mut out[at..at + DYNAMICS_LEN],
        DYNAMICS_MAGIC,
        DYNAMICS_VERSION,
        DYNAMICS_LEN,
        crc,
        |p| {
            for (k, v) in values
                .iter()
                .chain(core::iter::once(&dynamics.coulomb_speed_rad_s))
                .enumerate()
            {
                p[4 * k..4 + 4 * k].copy_from_slice(&v.to_le_bytes());
            }
        },
    );
    Ok(at + DYNAMICS_LEN)
}

/// Appends the backlash block to the image in `out[..image_len]` (an image from [`encode`],
/// possibly followed by other blocks: `at` is where this block goes; put it last, see the
/// module doc) and returns the new end. `out` must hold `at + BACKLASH_LEN` bytes.
pub fn append_backlash(
    out: &mut [u8],
    image_len: usize,
    at: usize,
    backlash: &Backlash<f32>,
) -> Result<usize, GridError> {
    let (crc, _) = block_slot(out, image_len, at, BACKLASH_LEN)?;
    let beta = backlash.beta_rad();
    write_block(
        &mut out[at..at + BACKLASH_LEN],
        BACKLASH_MAGIC,
        BACKLASH_VERSION,
        BACKLASH_LEN,
        crc,
        |p| {
            p[0..4].copy_from_slice(&beta[0].to_le_bytes());
            p[4..8].copy_from_slice(&beta[1].to_le_bytes());
        },
    );
    Ok(at + BACKLASH_LEN)
}

/// Writes an image followed by the dynamics block into `out` (at least
/// [`GridGeometry::image_len_with_dynamics`] bytes) and returns its length: [`encode`] then
/// [`append_dynamics`].
pub fn encode_with_dynamics(
    out: &mut [u8],
    geometry: &GridGeometry,
    model: &FiveBar<f32>,
    nodes_rad: &[[f32; 2]],
    dynamics: &FiveBarDynamics<f32>,
) -> Result<usize, GridError> {
    dynamics.validate().map_err(|_| GridError::BadDynamics)?;
    if out.len() < geometry.image_len_with_dynamics() {
        return Err(GridError::BadEncodeInput);
    }
    let total = encode(out, geometry, model, nodes_rad)?;
    append_dynamics(out, total, total, dynamics)
}
