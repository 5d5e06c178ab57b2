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
//! Node `(i, j)` sits at `(x0 + i·step_x, y0 + j·step_y)`. Bytes after the CRC are ignored, so
//! the parser can be handed the whole flash region, unless they start with the dynamics
//! extension's magic.
//!
//! # Dynamics extension (optional, right after the CRC)
//! The identified dynamic parameters of the hidden robot (`crate::dynamics`, issue 14) travel
//! with the model they were identified for, in a block appended after the version-1 image.
//! Version-1 parsers (older firmware) ignore it and still read the grid; this parser reads
//! images with and without it. A version-2 header was not used because it would have changed
//! what a version-1 image with a tampered version field is refused as.
//!
//! | offset (after the image's CRC) | size | field |
//! |---:|---:|---|
//! | 0 | 4 | magic `b"HRDY"` |
//! | 4 | 2 | extension version, `1` |
//! | 6 | 2 | block length, `56` |
//! | 8 | 4 | the CRC of the image it belongs to (a block left behind by another image is refused) |
//! | 12 | 10×4 | f32 `I1, I2` (kg·m²), `m_C` (kg), `J3, J4` (kg·m²), `fv1, fv2` (N·m·s/rad), `fc1, fc2` (N·m), Coulomb speed (rad/s) |
//! | 52 | 4 | CRC-32/ISO-HDLC of the block's 52 bytes before it |
//!
//! A block that starts with the magic but fails any check (version, length, image CRC, its own
//! CRC, [`FiveBarDynamics::validate`]) refuses the whole image ([`GridError::BadDynamics`]):
//! feed-forward from a corrupt block would push the motors.
//!
//! # Outside the grid
//! A point more than [`EDGE_TOLERANCE_CELLS`] of a cell outside the node rectangle is refused
//! with [`GridError::OutsideGrid`]: an uncalibrated region is not silently extrapolated. Points
//! within that tolerance (float rounding of a target on the boundary) take the edge value.

use crate::bilinear::bilinear;
use crate::dynamics::{FiveBarDynamics, PARAMETERS};
use crate::model::{Branch, FiveBar, WorkingMode};

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

/// Magic of the dynamics extension.
pub const DYNAMICS_MAGIC: [u8; 4] = *b"HRDY";
/// The dynamics extension's version.
pub const DYNAMICS_VERSION: u16 = 1;
/// Bytes of the dynamics extension.
pub const DYNAMICS_LEN: usize = 56;

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
    /// The dynamics extension after the image is corrupt, belongs to another image or holds
    /// invalid parameters.
    BadDynamics,
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
            GridError::BadDynamics => f.write_str("the image's dynamics extension is corrupt or invalid"),
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
        [self.x0_mm + i as f32 * self.step_x_mm, self.y0_mm + j as f32 * self.step_y_mm]
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

    /// Image size with the dynamics extension.
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

/// A validated image, borrowed from flash (or any byte slice): nothing is copied, nodes are
/// decoded on demand.
#[derive(Clone, Copy, Debug)]
pub struct CorrectionGrid<'a> {
    geometry: GridGeometry,
    model: FiveBar<f32>,
    nodes: &'a [u8],
    dynamics: Option<FiveBarDynamics<f32>>,
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
        CellAxis { origin_mm, inv_step: 1.0 / step_mm, last, upper: last + EDGE_TOLERANCE_CELLS, last_cell: u32::from(n - 2) }
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
        let nodes = &bytes[HEADER_LEN..total - 4];
        if nodes.chunks_exact(4).any(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite()) {
            return Err(GridError::NonFinite);
        }
        let dynamics = parse_dynamics(&bytes[total..], stored_crc)?;
        let axes = [
            CellAxis::of(geometry.x0_mm, geometry.step_x_mm, geometry.nx),
            CellAxis::of(geometry.y0_mm, geometry.step_y_mm, geometry.ny),
        ];
        Ok(CorrectionGrid { geometry, model, nodes, dynamics, axes })
    }

    /// The identified dynamics, if the image carries the extension.
    pub fn dynamics(&self) -> Option<&FiveBarDynamics<f32>> {
        self.dynamics.as_ref()
    }

    /// Where the nodes are.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// The hidden robot this grid corrects.
    pub fn model(&self) -> &FiveBar<f32> {
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
        let (Some(r1), Some(r2)) = (self.node_pair(k), self.node_pair(k + 8 * self.geometry.nx as usize)) else {
            return Err(GridError::OutsideGrid);
        };
        Ok([bilinear(r1[0], r2[0], r1[2], r2[2], u, v), bilinear(r1[1], r2[1], r1[3], r2[3], u, v)])
    }

    /// The two nodes whose table entries start at byte `k`: `[δ1, δ2]` of each.
    #[inline]
    fn node_pair(&self, k: usize) -> Option<[f32; 4]> {
        let b = <&[u8; 16]>::try_from(self.nodes.get(k..k + 16)?).ok()?;
        Some(core::array::from_fn(|m| f32::from_le_bytes([b[4 * m], b[4 * m + 1], b[4 * m + 2], b[4 * m + 3]])))
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

/// The dynamics extension at the start of `rest` (the bytes after an image whose CRC is
/// `image_crc`): `None` if `rest` does not start with its magic.
fn parse_dynamics(rest: &[u8], image_crc: u32) -> Result<Option<FiveBarDynamics<f32>>, GridError> {
    if rest.len() < 4 || rest[0..4] != DYNAMICS_MAGIC {
        return Ok(None);
    }
    let valid = rest.len() >= DYNAMICS_LEN
        && u16_at(rest, 4) == DYNAMICS_VERSION
        && u16_at(rest, 6) as usize == DYNAMICS_LEN
        && u32_at(rest, 8) == image_crc
        && CRC32.checksum(&rest[..DYNAMICS_LEN - 4]) == u32_at(rest, DYNAMICS_LEN - 4);
    if !valid {
        return Err(GridError::BadDynamics);
    }
    let mut p = [0.0f32; PARAMETERS];
    for (k, v) in p.iter_mut().enumerate() {
        *v = f32_at(rest, 12 + 4 * k);
    }
    let d = FiveBarDynamics::from_array(p, f32_at(rest, 12 + 4 * PARAMETERS));
    d.validate().map_err(|_| GridError::BadDynamics)?;
    Ok(Some(d))
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

/// Writes an image with the dynamics extension into `out` (at least
/// [`GridGeometry::image_len_with_dynamics`] bytes) and returns its length.
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
    let image_crc = u32_at(out, total - 4);
    let block = &mut out[total..total + DYNAMICS_LEN];
    block.fill(0);
    block[0..4].copy_from_slice(&DYNAMICS_MAGIC);
    block[4..6].copy_from_slice(&DYNAMICS_VERSION.to_le_bytes());
    block[6..8].copy_from_slice(&(DYNAMICS_LEN as u16).to_le_bytes());
    block[8..12].copy_from_slice(&image_crc.to_le_bytes());
    let values = dynamics.to_array();
    for (k, v) in values.iter().chain(core::iter::once(&dynamics.coulomb_speed_rad_s)).enumerate() {
        block[12 + 4 * k..16 + 4 * k].copy_from_slice(&v.to_le_bytes());
    }
    let crc = CRC32.checksum(&block[..DYNAMICS_LEN - 4]);
    block[DYNAMICS_LEN - 4..].copy_from_slice(&crc.to_le_bytes());
    Ok(total + DYNAMICS_LEN)
}
