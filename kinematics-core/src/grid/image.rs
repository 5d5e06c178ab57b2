//! The image itself: [`CorrectionGrid::parse`] (every check of the format), the node lookup
//! the servo runs each sample, and [`encode`] (format spec: the `grid` module doc).

use super::blocks::{decode_workspace, parse_extensions};
use super::format::{
    GridError, GridGeometry, CRC32, EDGE_TOLERANCE_CELLS, HEADER_LEN, MAGIC, MAX_NODES_PER_AXIS,
    VERSION,
};
use crate::backlash::Backlash;
use crate::bilinear::bilinear;
use crate::dynamics::FiveBarDynamics;
use crate::le_bytes::{f32_at, put_f32, put_u16, put_u32, u16_at, u32_at};
use crate::machine::record::MachineRecord;
use crate::model::{FiveBar, WorkingMode};
use crate::valid_model::ValidFiveBar;
use crate::workspace::WorkspaceLimits;

/// A validated image, borrowed from flash (or any byte slice): nothing is copied, nodes are
/// decoded on demand, and so are the workspace and machine record blocks (validated by
/// [`CorrectionGrid::parse`]); the dynamics and backlash blocks are decoded once (the servo
/// reads them every step).
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
    /// The machine record block's payload, if the image has one.
    machine: Option<&'a [u8]>,
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
            mode: WorkingMode::from_flags(flags),
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
            machine: extensions.machine,
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

    /// The machine this image was built for, if it carries the machine record block
    /// (validated by [`Self::parse`]; decoded on each call, about 300 bytes).
    pub fn machine(&self) -> Option<MachineRecord> {
        self.machine.and_then(|p| MachineRecord::parse(p).ok())
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
    put_u16(out, 4, VERSION);
    put_u16(out, 6, HEADER_LEN as u16);
    put_u16(out, 8, geometry.nx);
    put_u16(out, 10, geometry.ny);
    put_u32(out, 12, model.mode.to_flags());
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
        put_f32(out, 16 + 4 * k, *v);
    }
    for (k, v) in nodes_rad.iter().flatten().enumerate() {
        put_f32(out, HEADER_LEN + 4 * k, *v);
    }
    let crc = CRC32.checksum(&out[..total - 4]);
    put_u32(out, total - 4, crc);
    Ok(total)
}
