//! The block writers: each appends one framed extension block after an image (host tools and
//! tests; the firmware only parses). Format spec: the `grid` module doc.

use super::blocks::write_block;
use super::format::{
    GridError, GridGeometry, BACKLASH_LEN, BACKLASH_MAGIC, BACKLASH_VERSION, DYNAMICS_LEN,
    DYNAMICS_MAGIC, DYNAMICS_VERSION, MACHINE_LEN, MACHINE_MAGIC, MACHINE_VERSION, WORKSPACE_LEN,
    WORKSPACE_MAGIC, WORKSPACE_VERSION,
};
use super::image::{encode, CorrectionGrid};
use crate::backlash::Backlash;
use crate::dynamics::FiveBarDynamics;
use crate::le_bytes::{put_f32, put_u16, u32_at};
use crate::machine::record::{MachineRecord, ENCODED_LEN};
use crate::model::FiveBar;
use crate::workspace::WorkspaceLimits;

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
    Ok((crc, *CorrectionGrid::parse(&out[..image_len])?.geometry()))
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
            put_u16(p, 0, v.len() as u16);
            put_f32(p, 4, limits.stop_margin_mm);
            for (k, q) in v.iter().enumerate() {
                put_f32(p, 8 + 8 * k, q[0]);
                put_f32(p, 12 + 8 * k, q[1]);
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
                put_f32(p, 4 * k, *v);
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
            put_f32(p, 0, beta[0]);
            put_f32(p, 4, beta[1]);
        },
    );
    Ok(at + BACKLASH_LEN)
}

/// Appends the machine record block to the image in `out[..image_len]` (an image from
/// [`encode`], possibly followed by other blocks: `at` is where this block goes; put it last,
/// so that a parser older than the block reads every block before it) and returns the new end.
/// `out` must hold `at + MACHINE_LEN` bytes; the record is validated as the parser does.
pub fn append_machine(
    out: &mut [u8],
    image_len: usize,
    at: usize,
    record: &MachineRecord,
) -> Result<usize, GridError> {
    let mut payload = [0u8; ENCODED_LEN];
    record
        .encode(&mut payload)
        .map_err(|_| GridError::BadMachineRecord)?;
    let (crc, _) = block_slot(out, image_len, at, MACHINE_LEN)?;
    write_block(
        &mut out[at..at + MACHINE_LEN],
        MACHINE_MAGIC,
        MACHINE_VERSION,
        MACHINE_LEN,
        crc,
        |p| p.copy_from_slice(&payload),
    );
    Ok(at + MACHINE_LEN)
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
