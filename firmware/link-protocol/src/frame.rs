//! The frame: `COBS(postcard(message) ‖ CRC-32 LE) ‖ 0x00`, at most [`MAX_FRAME_LEN`] bytes.
//!
//! Encoding and decoding work in caller-provided buffers (no heap); decoding is in place.
//! Cost: one pass of postcard, one of CRC-32 (table-driven, 256-entry table in flash), one of
//! COBS per frame; a 256-byte frame is a few thousand instructions on the Cortex-M4, in the
//! link's low-priority task, never in the servo task.
use serde::{Deserialize, Serialize};

use crate::{FrameError, MAX_FRAME_LEN, MAX_PAYLOAD_LEN, PROTOCOL_VERSION};

/// The frame check: CRC-32/ISO-HDLC, the same as the grid image's.
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
const CRC_LEN: usize = 4;

/// Encodes `message` as one frame into `out`, delimiter included; returns its length.
/// [`FrameError::Overflow`] if it does not fit [`MAX_FRAME_LEN`] or `out`.
pub fn encode<T: Serialize>(message: &T, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_PAYLOAD_LEN + CRC_LEN];
    let n = postcard::to_slice(message, &mut raw[..MAX_PAYLOAD_LEN])
        .map_err(|_| FrameError::Overflow)?
        .len();
    let crc = CRC32.checksum(&raw[..n]);
    raw[n..n + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let limit = out.len().min(MAX_FRAME_LEN);
    // Room for the delimiter after the COBS bytes.
    let body = out
        .get_mut(..limit.saturating_sub(1))
        .ok_or(FrameError::Overflow)?;
    let len = cobs::try_encode(&raw[..n + CRC_LEN], body).map_err(|_| FrameError::Overflow)?;
    out[len] = 0;
    Ok(len + 1)
}

/// Decodes one frame in place: `frame` is the bytes between two delimiters (a trailing
/// delimiter is allowed). Checks, in order: length, COBS, CRC, protocol version, message.
/// Never panics, whatever the bytes.
pub fn decode<T>(frame: &mut [u8]) -> Result<T, FrameError>
where
    T: for<'de> Deserialize<'de>,
{
    if frame.len() > MAX_FRAME_LEN {
        return Err(FrameError::TooLong);
    }
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    if n < CRC_LEN {
        return Err(FrameError::Short);
    }
    let (payload, crc) = frame[..n].split_at(n - CRC_LEN);
    let stored = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if CRC32.checksum(payload) != stored {
        return Err(FrameError::Crc);
    }
    // Every message starts with its version: read it before believing the rest.
    let (version, _) =
        postcard::take_from_bytes::<u16>(payload).map_err(|_| FrameError::Malformed)?;
    if version != PROTOCOL_VERSION {
        return Err(FrameError::Version(version));
    }
    match postcard::take_from_bytes::<T>(payload) {
        Ok((message, [])) => Ok(message),
        _ => Err(FrameError::Malformed),
    }
}

/// What [`FrameReader::push`] found at a delimiter.
#[derive(Debug, PartialEq, Eq)]
pub enum Received<'a> {
    /// The bytes of a frame, ready for [`decode`] (in place).
    Frame(&'a mut [u8]),
    /// The bytes since the last delimiter were longer than a frame and were dropped.
    TooLong,
}

/// Collects bytes from the wire into frames. A frame longer than [`MAX_FRAME_LEN`] is dropped
/// up to its delimiter and reported once ([`Received::TooLong`]); empty frames (consecutive
/// zeros, e.g. a host's leading zero to flush a half-sent frame) are skipped.
#[derive(Debug)]
pub struct FrameReader {
    buf: [u8; MAX_FRAME_LEN],
    len: usize,
    overflow: bool,
}

impl Default for FrameReader {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameReader {
    /// An empty reader.
    pub const fn new() -> Self {
        FrameReader {
            buf: [0; MAX_FRAME_LEN],
            len: 0,
            overflow: false,
        }
    }

    /// Takes one byte; at a delimiter, returns the frame it ended (or that it was too long).
    pub fn push(&mut self, byte: u8) -> Option<Received<'_>> {
        if byte != 0 {
            // The delimiter counts towards the frame's length.
            if self.len + 1 < MAX_FRAME_LEN {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflow) {
            return Some(Received::TooLong);
        }
        (len > 0).then(|| Received::Frame(&mut self.buf[..len]))
    }

    /// Bytes held of an unfinished frame.
    pub fn pending(&self) -> usize {
        self.len
    }
}
