//! The chain of extension blocks after an image: each block's frame checked, its payload
//! decoded and validated (format spec: the `grid` module doc, "Extension blocks"). One arm of
//! [`parse_extensions`] per known magic.

use super::format::{
    GridError, GridGeometry, BACKLASH_LEN, BACKLASH_MAGIC, BACKLASH_VERSION, BLOCK_FRAME_LEN,
    CRC32, DYNAMICS_LEN, DYNAMICS_MAGIC, DYNAMICS_VERSION, MACHINE_LEN, MACHINE_MAGIC,
    MACHINE_VERSION, WORKSPACE_LEN, WORKSPACE_MAGIC, WORKSPACE_VERSION,
};
use crate::backlash::Backlash;
use crate::dynamics::{FiveBarDynamics, PARAMETERS};
use crate::le_bytes::{f32_at, put_u16, put_u32, u16_at, u32_at};
use crate::machine::record::MachineRecord;
use crate::workspace::{ConvexWorkspace, WorkspaceLimits, MAX_WORKSPACE_VERTICES};

/// The extension blocks found after an image (see the module doc, "Extension blocks").
#[derive(Default)]
pub(crate) struct Extensions<'a> {
    pub(crate) workspace: Option<&'a [u8]>,
    pub(crate) dynamics: Option<FiveBarDynamics<f32>>,
    pub(crate) backlash: Option<Backlash<f32>>,
    /// The machine record block's payload (validated).
    pub(crate) machine: Option<&'a [u8]>,
    /// Bytes of the chain (0 without blocks).
    pub(crate) len: usize,
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
pub(crate) fn parse_extensions<'a>(
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
            m if m == MACHINE_MAGIC => {
                let payload = framed_payload(&rest[at..], MACHINE_VERSION, MACHINE_LEN, image_crc)
                    .ok_or(GridError::BadMachineRecord)?;
                if found.machine.is_some() || MachineRecord::parse(payload).is_err() {
                    return Err(GridError::BadMachineRecord);
                }
                found.machine = Some(payload);
                MACHINE_LEN
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
pub(crate) fn decode_workspace(payload: &[u8]) -> Result<WorkspaceLimits, GridError> {
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
pub(crate) fn write_block(
    out: &mut [u8],
    magic: [u8; 4],
    version: u16,
    len: usize,
    image_crc: u32,
    fill: impl FnOnce(&mut [u8]),
) {
    out.fill(0);
    out[0..4].copy_from_slice(&magic);
    put_u16(out, 4, version);
    put_u16(out, 6, len as u16);
    put_u32(out, 8, image_crc);
    fill(&mut out[12..len - 4]);
    let crc = CRC32.checksum(&out[..len - 4]);
    put_u32(out, len - 4, crc);
}
