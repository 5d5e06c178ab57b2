//! The image's constants, its errors and its node lattice: what the parser, the block chain
//! and the writers share (format spec: the `grid` module doc).

use crate::dynamics::PARAMETERS;
use crate::machine::record::ENCODED_LEN;
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
/// Magic of the machine record block.
pub const MACHINE_MAGIC: [u8; 4] = *b"HRMC";
/// The machine record block's version.
pub const MACHINE_VERSION: u16 = 1;
/// Bytes of the machine record block: the frame and the record's canonical encoding.
pub const MACHINE_LEN: usize = BLOCK_FRAME_LEN + ENCODED_LEN;

/// The image's and the blocks' CRC (zlib's).
pub(crate) const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

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
    /// The machine record block after the image is corrupt, belongs to another image, repeats
    /// or holds a record that does not validate (`crate::machine::MachineRecord::parse`).
    BadMachineRecord,
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
            GridError::BadMachineRecord => {
                f.write_str("the image's machine record block is corrupt or invalid")
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

    pub(crate) fn validate(&self) -> Result<(), GridError> {
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
