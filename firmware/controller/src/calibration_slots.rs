//! Two calibration slots in the CALIBRATION flash region: a new image is written to the slot
//! not in force, validated, then switched to by one commit record written last, so a power cut
//! at any byte of an upload leaves the old image in force.
//!
//! # Layout
//! The region (64 KiB on both boards, `memory.x`) is split in two equal slots, A at offset 0
//! and B at half the region (32 KiB each; 16 pages of 2 KiB on the STM32G474):
//!
//! | slot offset | size | contents |
//! |---:|---:|---|
//! | 0 | up to `slot_len - 32` | the image (`kinematics_core::grid` format), as uploaded |
//! | `slot_len - 32` | 32 | the commit record, written after the image has been validated |
//!
//! The commit record (little-endian):
//!
//! | offset | size | field |
//! |---:|---:|---|
//! | 0 | 4 | magic `b"HRCR"` |
//! | 4 | 2 | record version, `1` |
//! | 6 | 2 | 0 |
//! | 8 | 4 | sequence number (the previous image's plus one) |
//! | 12 | 4 | image length (bytes) |
//! | 16 | 4 | CRC-32C (Castagnoli) of the image's bytes: the [`CalibrationId`]'s `crc32` |
//! | 20 | 4 | 0 |
//! | 24 | 4 | CRC-32/ISO-HDLC of the record's bytes 0..24 |
//! | 28 | 4 | commit marker `b"DONE"`, in the last write unit programmed |
//!
//! # Which image is in force
//! At boot ([`SlotStore::open`]) a slot counts if its record is complete (magic, version,
//! record CRC, marker), its image's bytes match the record's length and CRC, and the image
//! passes [`validate_image`](crate::calibration::validate_image) judged against its own machine
//! record (format, grid CRC, its model a model of its machine, plausible). Of the slots that
//! count, the one with the highest sequence number is in force, and its record is the machine
//! the controller drives ([`SlotStore::machine`]); an upload's commit judges the new image
//! against that machine (`crate::calibration`, "The machine is the image's").
//! The record's image CRC is not redundant with the grid's own: a probe that reflashes a slot's
//! start with another image of the same length leaves the old record behind, and that image
//! parses with the record's length; only the record's CRC-32C tells it is not the committed one
//! (test `a_record_left_behind_by_another_image_does_not_count`).
//! If neither has a record, an image at the start of slot A is in force with sequence 0: that
//! is what flashing the region with a probe (`probe-rs download ... calibration.bin`, the
//! bring-up path) or the QEMU board's bundled image leaves. (So after an upload, reflash the
//! region by probe with the whole 64 KiB erased, or slot B's record keeps winning.)
//!
//! # The upload and the power-cut guarantee
//! [`SlotStore::begin`] erases the slot not in force (all of it, its record too);
//! [`SlotStore::write`] programs the image into it in order; [`SlotStore::commit`] reads the
//! slot back, validates it, and only then programs the record, marker last. Until the marker's
//! write unit is complete, the new slot has no valid record and the old one is in force; once it
//! is, the new one has the higher sequence. Flash programming only clears bits, so a torn write
//! unit can only leave a record whose marker or CRC does not match. Nothing is ever written to
//! the slot in force. `tests` cut the power after every byte of every erase and program of an
//! upload (and after every write unit) and reboot: the old image, or after a completed commit the
//! new one, is in force every time.
//!
//! Hardware caveat (STM32G474): a double word torn by a power cut can hold a double ECC error,
//! whose read raises an NMI (RM0440, FLASH ECC). The board's flash driver must treat ECCD on a
//! read of the inactive slot as "no record"; see docs/design/firmware-architecture.md.
//!
//! Cost: `open` computes two CRCs over the images and judges the images that count (a few ms
//! at boot); `write` copies the bytes; `commit` one CRC, a parse and the judgement
//! (`cargo qemu-bench`'s `image_commit_check`, figure in docs/validation/benchmarks.md). None of it runs
//! in the servo task: the app calls it from a low-priority task, and on the G474 the
//! calibration region is in bank 2 while the program runs from bank 1.
use crate::calibration::{validate_image, ImageCheck, ImageError, Judged};
use kinematics_core::machine::MachineRecord;

/// The record's own CRC (CRC-32/ISO-HDLC, zlib's, as the grid format uses).
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
/// The image's CRC in the record and the [`CalibrationId`]: the link's calibration id, CRC-32C
/// ([`link_protocol::calibration_image_id`], which says why not the grid format's CRC).
fn image_crc(image: &[u8]) -> u32 {
    link_protocol::calibration_image_id(image)
}

/// Commit record magic.
pub const RECORD_MAGIC: [u8; 4] = *b"HRCR";
/// Commit record version.
pub const RECORD_VERSION: u16 = 1;
/// Commit record length (bytes), at the end of each slot.
pub const RECORD_LEN: usize = 32;
/// The marker the record's last write unit ends with.
pub const COMMIT_MARKER: [u8; 4] = *b"DONE";

/// Why the board's flash refused an operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashError {
    /// Offset or length not aligned to the erase or write unit, or outside the region.
    Alignment,
    /// The controller reported an error (G474: PROGERR, WRPERR, PGAERR, SIZERR, PGSERR...), or
    /// a read back differed from what was programmed.
    Hardware,
    /// The flash controller stayed busy past its timeout.
    Timeout,
}

/// The calibration region's flash, as the slot store needs it. NOR semantics: erase sets a
/// page to 0xFF, programming only clears bits, one write unit at a time.
///
/// Own trait rather than `embedded-storage`'s `NorFlash`: the store reads the region in place
/// (the servo uses the image where it lies, nothing is copied), which `ReadNorFlash` does not
/// offer, and the power-cut tests need nothing more than these three calls.
pub trait SlotFlash {
    /// The write unit (bytes; 8 on the STM32G474, a double word).
    const WRITE_SIZE: usize;
    /// The erase unit (bytes; a 2 KiB page on the STM32G474).
    const ERASE_SIZE: usize;
    /// The whole region, memory-mapped.
    fn region(&self) -> &[u8];
    /// Erases `[offset, offset + len)`, both multiples of [`SlotFlash::ERASE_SIZE`].
    fn erase(&mut self, offset: usize, len: usize) -> Result<(), FlashError>;
    /// Programs `data` (a multiple of [`SlotFlash::WRITE_SIZE`]) at `offset` (aligned).
    fn program(&mut self, offset: usize, data: &[u8]) -> Result<(), FlashError>;
}

/// The region read-only (a memory-mapped view): [`SlotStore::open`] over it finds the image in
/// force without being able to change anything (the QEMU harness's independent reading, host
/// tools inspecting a dump). Erase and program fail.
pub struct ReadOnly<'a>(pub &'a [u8]);

impl SlotFlash for ReadOnly<'_> {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = 2048;
    fn region(&self) -> &[u8] {
        self.0
    }
    fn erase(&mut self, _: usize, _: usize) -> Result<(), FlashError> {
        Err(FlashError::Hardware)
    }
    fn program(&mut self, _: usize, _: &[u8]) -> Result<(), FlashError> {
        Err(FlashError::Hardware)
    }
}

/// Which image is in force: the host compares `crc32` with its file's CRC-32.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CalibrationId {
    /// 0 (slot A) or 1 (slot B).
    pub slot: u8,
    /// The commit's sequence number (0: an image flashed by probe, without record).
    pub sequence: u32,
    /// CRC-32C (Castagnoli, `crc::CRC_32_ISCSI`) of the image's bytes: the host computes it
    /// over its file (`link_protocol::calibration_image_id`; not zlib's CRC-32, see there).
    pub crc32: u32,
    /// The image's length (bytes).
    pub len: u32,
}

/// Why an upload step was refused. After any error but [`SlotError::NoUpload`] and
/// [`SlotError::OutOfOrder`] the upload is abandoned (start again with `begin`); the image in
/// force is untouched in every case.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotError {
    /// `write` or `commit` without a `begin`.
    NoUpload,
    /// The image would not fit a slot (or is shorter than a grid header): the largest is given.
    BadLength {
        /// Largest image a slot holds (bytes).
        max: u32,
    },
    /// `write` at another offset than the next expected one (chunks go in order; a repeated
    /// chunk is refused, not rewritten): the offset expected.
    OutOfOrder {
        /// The next offset the store expects.
        expected: u32,
    },
    /// `write` past the length given to `begin`.
    TooMuchData,
    /// `commit` before every byte was written.
    Incomplete {
        /// Bytes received.
        received: u32,
    },
    /// The flash refused an operation, or read back something else.
    Flash(FlashError),
    /// The uploaded image is not a valid image for this machine.
    Image(ImageError),
    /// A committed image waits for the servo to switch to it: no upload until it has.
    SwitchPending,
}

impl core::fmt::Display for SlotError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SlotError::NoUpload => f.write_str("no upload under way"),
            SlotError::BadLength { max } => {
                write!(f, "image length not between 76 and {max} bytes")
            }
            SlotError::OutOfOrder { expected } => {
                write!(f, "chunk out of order (expected offset {expected})")
            }
            SlotError::TooMuchData => f.write_str("more data than announced"),
            SlotError::Incomplete { received } => {
                write!(f, "image incomplete ({received} bytes received)")
            }
            SlotError::Flash(e) => write!(f, "flash error: {e:?}"),
            SlotError::Image(e) => write!(f, "image refused: {e}"),
            SlotError::SwitchPending => f.write_str(
                "a committed image waits for the servo to switch to it at rest (no upload until it has)",
            ),
        }
    }
}

impl From<FlashError> for SlotError {
    fn from(e: FlashError) -> Self {
        SlotError::Flash(e)
    }
}

/// Largest write unit the store handles (bytes).
const MAX_WRITE_SIZE: usize = 16;

#[derive(Clone, Copy, Debug)]
struct Upload {
    slot: u8,
    len: u32,
    /// Bytes received (programmed, or pending in `tail`).
    received: u32,
    /// Bytes received past the last whole write unit.
    tail: [u8; MAX_WRITE_SIZE],
    tail_len: usize,
}

/// The two slots over a board's flash: which image is in force, and the upload into the other.
pub struct SlotStore<F: SlotFlash> {
    flash: F,
    check: ImageCheck,
    active: Option<CalibrationId>,
    upload: Option<Upload>,
}

impl<F: SlotFlash> SlotStore<F> {
    /// Scans both slots and picks the image in force (module doc). `check` judges each image
    /// (`Settings::image_check`: its machine is the built-in one an image without a record is
    /// judged against); the machine in force becomes the record of the image in force.
    pub fn open(flash: F, check: ImageCheck) -> Self {
        let mut store = SlotStore {
            flash,
            check,
            active: None,
            upload: None,
        };
        let committed = [0u8, 1].map(|slot| store.committed(slot));
        let active = match committed {
            [Some(a), Some(b)] => Some(if b.0.sequence.wrapping_sub(a.0.sequence) as i32 > 0 {
                b
            } else {
                a
            }),
            [Some(a), None] => Some(a),
            [None, Some(b)] => Some(b),
            [None, None] => store.probe_flashed(),
        };
        if let Some((id, machine)) = active {
            store.active = Some(id);
            store.check.machine = machine;
        }
        store
    }

    /// The machine in force: the record of the image in force at boot (the built-in one when
    /// it carries none, or when no image is in force). Uploads are judged against it and never
    /// change it.
    pub fn machine(&self) -> &MachineRecord {
        &self.check.machine
    }

    /// Bytes per slot.
    pub fn slot_len(&self) -> usize {
        // Whole erase pages per slot.
        let half = self.flash.region().len() / 2;
        half - half % F::ERASE_SIZE
    }

    /// Largest image a slot holds (bytes).
    pub fn capacity(&self) -> usize {
        self.slot_len().saturating_sub(RECORD_LEN)
    }

    /// The image in force and its id; `None` if neither slot holds a valid image.
    pub fn active(&self) -> Option<(&[u8], CalibrationId)> {
        let id = self.active?;
        let start = id.slot as usize * self.slot_len();
        Some((&self.flash.region()[start..start + id.len as usize], id))
    }

    /// The id of the image in force.
    pub fn active_id(&self) -> Option<CalibrationId> {
        self.active
    }

    /// The slot the next upload goes to: the one not in force (A if none is).
    pub fn inactive_slot(&self) -> u8 {
        match self.active {
            Some(id) => 1 - id.slot,
            None => 0,
        }
    }

    /// Whether an upload is under way, and the bytes it has received.
    pub fn upload_progress(&self) -> Option<(u32, u32)> {
        self.upload.map(|u| (u.received, u.len))
    }

    /// Starts an upload of `len` bytes into the slot the servo does not use (`in_use`: the id
    /// of the image the servo runs with, `None` without one) and erases it. Refused with
    /// [`SlotError::SwitchPending`] while the newest committed image is not the one in use (a
    /// switch is pending: the other slot is the one the servo still reads, and the committed
    /// one must not be erased either). An upload already under way is abandoned.
    pub fn begin(&mut self, len: usize, in_use: Option<CalibrationId>) -> Result<(), SlotError> {
        self.upload = None;
        if self.active.is_some() && self.active != in_use {
            return Err(SlotError::SwitchPending);
        }
        let max = self.capacity();
        if !(kinematics_core::grid::HEADER_LEN + 4..=max).contains(&len) {
            return Err(SlotError::BadLength { max: max as u32 });
        }
        if F::WRITE_SIZE == 0 || F::WRITE_SIZE > MAX_WRITE_SIZE || RECORD_LEN % F::WRITE_SIZE != 0 {
            return Err(SlotError::Flash(FlashError::Alignment));
        }
        let slot = self.inactive_slot();
        let slot_len = self.slot_len();
        self.flash.erase(slot as usize * slot_len, slot_len)?;
        self.upload = Some(Upload {
            slot,
            len: len as u32,
            received: 0,
            tail: [0xFF; MAX_WRITE_SIZE],
            tail_len: 0,
        });
        Ok(())
    }

    /// Appends `data` at `offset` (the next byte expected); returns the bytes received so far.
    pub fn write(&mut self, offset: usize, data: &[u8]) -> Result<u32, SlotError> {
        let Some(mut up) = self.upload else {
            return Err(SlotError::NoUpload);
        };
        if offset != up.received as usize {
            return Err(SlotError::OutOfOrder {
                expected: up.received,
            });
        }
        if data.len() > (up.len - up.received) as usize {
            self.upload = None;
            return Err(SlotError::TooMuchData);
        }
        let base = up.slot as usize * self.slot_len();
        let w = F::WRITE_SIZE;
        for &byte in data {
            up.tail[up.tail_len] = byte;
            up.tail_len += 1;
            up.received += 1;
            if up.tail_len == w {
                let at = base + up.received as usize - w;
                if let Err(e) = self.flash.program(at, &up.tail[..w]) {
                    self.upload = None;
                    return Err(e.into());
                }
                up.tail_len = 0;
            }
        }
        self.upload = Some(up);
        Ok(up.received)
    }

    /// Finishes the upload: programs the last partial write unit (padded with 0xFF), reads the
    /// slot back, validates the image ([`validate_image`] at a commit: format, CRC, the machine
    /// in force's, plausible), then
    /// programs the commit record, marker last. On success the new image is in force (the
    /// caller switches the servo to it, see the app) and its id is returned; on any error the
    /// old image stays in force.
    pub fn commit(&mut self) -> Result<CalibrationId, SlotError> {
        let Some(up) = self.upload.take() else {
            return Err(SlotError::NoUpload);
        };
        if up.received != up.len {
            return Err(SlotError::Incomplete {
                received: up.received,
            });
        }
        let w = F::WRITE_SIZE;
        let slot_len = self.slot_len();
        let base = up.slot as usize * slot_len;
        if up.tail_len > 0 {
            let mut unit = [0xFFu8; MAX_WRITE_SIZE];
            unit[..up.tail_len].copy_from_slice(&up.tail[..up.tail_len]);
            self.flash
                .program(base + up.len as usize - up.tail_len, &unit[..w])?;
        }
        let image = &self.flash.region()[base..base + up.len as usize];
        let parsed_len = validate_image(image, &self.check, Judged::AtCommit)
            .map_err(SlotError::Image)?
            .len;
        // The image must be exactly what was announced (no trailing bytes a CRC does not cover).
        if parsed_len != up.len as usize {
            return Err(SlotError::BadLength {
                max: self.capacity() as u32,
            });
        }
        let crc32 = image_crc(image);
        let sequence = self.active.map_or(1, |a| a.sequence.wrapping_add(1));
        let record = encode_record(sequence, up.len, crc32);
        let at = base + slot_len - RECORD_LEN;
        for (k, unit) in record.chunks(w).enumerate() {
            self.flash.program(at + k * w, unit)?;
        }
        let id = CalibrationId {
            slot: up.slot,
            sequence,
            crc32,
            len: up.len,
        };
        // Read back: the record as the next boot will see it (the image was judged above).
        if self.recorded(up.slot) != Some(id) {
            return Err(SlotError::Flash(FlashError::Hardware));
        }
        self.active = Some(id);
        Ok(id)
    }

    /// A committed image the servo refused to switch to (`SwitchOutcome::Refused`): its slot is
    /// erased, so that the image in use (`in_use`) stays in force, at the next boot too, and the
    /// next upload may go there. Nothing happens unless the newest committed image is `refused`
    /// and not the one in use.
    pub fn withdraw(
        &mut self,
        refused: CalibrationId,
        in_use: Option<CalibrationId>,
    ) -> Result<(), SlotError> {
        if self.active != Some(refused) || in_use == Some(refused) {
            return Ok(());
        }
        let slot_len = self.slot_len();
        self.upload = None;
        self.flash
            .erase(refused.slot as usize * slot_len, slot_len)?;
        self.active = in_use;
        Ok(())
    }

    /// Abandons the upload under way (the half-written slot stays without record).
    pub fn abort(&mut self) {
        self.upload = None;
    }

    /// The board's flash (for the app to hand out the active slot's bytes).
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// `slot`'s record and image, if they count (module doc), and the machine the image
    /// defines.
    fn committed(&self, slot: u8) -> Option<(CalibrationId, MachineRecord)> {
        let id = self.recorded(slot)?;
        let start = slot as usize * self.slot_len();
        let image = self.flash.region().get(start..start + id.len as usize)?;
        let valid = validate_image(image, &self.check, Judged::AtBoot).ok()?;
        (valid.len == id.len as usize).then_some((id, valid.machine))
    }

    /// `slot`'s complete record whose image bytes have the record's length and CRC (the image
    /// not judged).
    fn recorded(&self, slot: u8) -> Option<CalibrationId> {
        let slot_len = self.slot_len();
        let bytes = self
            .flash
            .region()
            .get(slot as usize * slot_len..(slot as usize + 1) * slot_len)?;
        let (sequence, len, crc32) = decode_record(&bytes[slot_len - RECORD_LEN..])?;
        let image = bytes
            .get(..len as usize)
            .filter(|_| len as usize <= slot_len - RECORD_LEN)?;
        (image_crc(image) == crc32).then_some(CalibrationId {
            slot,
            sequence,
            crc32,
            len,
        })
    }

    /// An image at the start of slot A without any record (flashed by probe), sequence 0, and
    /// the machine it defines.
    fn probe_flashed(&self) -> Option<(CalibrationId, MachineRecord)> {
        let a = self.flash.region().get(..self.capacity())?;
        let valid = validate_image(a, &self.check, Judged::AtBoot).ok()?;
        let id = CalibrationId {
            slot: 0,
            sequence: 0,
            crc32: image_crc(&a[..valid.len]),
            len: valid.len as u32,
        };
        Some((id, valid.machine))
    }
}

fn encode_record(sequence: u32, len: u32, crc32: u32) -> [u8; RECORD_LEN] {
    let mut r = [0u8; RECORD_LEN];
    r[0..4].copy_from_slice(&RECORD_MAGIC);
    r[4..6].copy_from_slice(&RECORD_VERSION.to_le_bytes());
    r[8..12].copy_from_slice(&sequence.to_le_bytes());
    r[12..16].copy_from_slice(&len.to_le_bytes());
    r[16..20].copy_from_slice(&crc32.to_le_bytes());
    let own = CRC32.checksum(&r[..24]);
    r[24..28].copy_from_slice(&own.to_le_bytes());
    r[28..32].copy_from_slice(&COMMIT_MARKER);
    r
}

/// (sequence, length, image CRC) of a complete record.
fn decode_record(r: &[u8]) -> Option<(u32, u32, u32)> {
    let word = |at: usize| u32::from_le_bytes([r[at], r[at + 1], r[at + 2], r[at + 3]]);
    let ok = r.len() == RECORD_LEN
        && r[0..4] == RECORD_MAGIC
        && r[4..6] == RECORD_VERSION.to_le_bytes()
        && r[28..32] == COMMIT_MARKER
        && CRC32.checksum(&r[..24]) == word(24);
    ok.then(|| (word(8), word(12), word(16)))
}

/// A NOR flash in RAM for tests (host) and for the QEMU board: erase sets 0xFF, programming
/// ANDs the data in (only clears bits), and an optional power budget in byte operations cuts
/// the power in the middle of an erase or a write unit, leaving it torn.
#[cfg(any(test, feature = "qemu-harness"))]
pub mod sim {
    use super::{FlashError, SlotFlash};

    /// The simulated flash over a caller's buffer.
    pub struct SimFlash<'a, const W: usize, const E: usize> {
        /// The region's bytes.
        pub bytes: &'a mut [u8],
        /// Byte operations (one erased or programmed byte each) left before the power fails;
        /// `None`: no power cut.
        pub budget: Option<usize>,
        /// Byte operations done so far.
        pub ops: usize,
        /// Write units programmed so far.
        pub units: usize,
    }

    impl<'a, const W: usize, const E: usize> SimFlash<'a, W, E> {
        /// Over `bytes`, no power cut.
        pub fn new(bytes: &'a mut [u8]) -> Self {
            SimFlash {
                bytes,
                budget: None,
                ops: 0,
                units: 0,
            }
        }

        /// Spends one byte operation; `Err` once the power is gone.
        fn spend(&mut self) -> Result<(), FlashError> {
            if let Some(b) = self.budget.as_mut() {
                if *b == 0 {
                    return Err(FlashError::Hardware);
                }
                *b -= 1;
            }
            self.ops += 1;
            Ok(())
        }
    }

    impl<const W: usize, const E: usize> SlotFlash for SimFlash<'_, W, E> {
        const WRITE_SIZE: usize = W;
        const ERASE_SIZE: usize = E;

        fn region(&self) -> &[u8] {
            self.bytes
        }

        fn erase(&mut self, offset: usize, len: usize) -> Result<(), FlashError> {
            if offset % E != 0 || len % E != 0 || offset + len > self.bytes.len() {
                return Err(FlashError::Alignment);
            }
            for k in offset..offset + len {
                self.spend()?;
                self.bytes[k] = 0xFF;
            }
            Ok(())
        }

        fn program(&mut self, offset: usize, data: &[u8]) -> Result<(), FlashError> {
            if offset % W != 0 || data.len() % W != 0 || offset + data.len() > self.bytes.len() {
                return Err(FlashError::Alignment);
            }
            for (k, &d) in data.iter().enumerate() {
                self.spend()?;
                self.bytes[offset + k] &= d;
            }
            self.units += data.len() / W;
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests;
