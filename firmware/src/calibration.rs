//! The calibration region (`CALIBRATION` in `memory.x`): its bytes, its two slots, and the
//! board's flash driver the slot store writes through (`controller::calibration_slots`).
//!
//! The region is read by address, through the linker symbols `__calibration_start` and
//! `__calibration_end`, not through a Rust static: whatever was flashed there is what the
//! firmware validates, so a new calibration needs no rebuild. The QEMU build also links a
//! valid image into the region (built by `build.rs`); the real board's build does not.
//!
//! Validation and the policy for a bad or missing image: `controller::calibration::load`; which
//! slot is in force and how an upload switches: `controller::calibration_slots`.
//!
//! **Aliasing.** The servo borrows the image in force for the whole run ([`slot_bytes`], a
//! `&'static [u8]` of that slot only); the flash driver writes only the other slot, through raw
//! pointers, and the slot store never writes the slot in force. Nothing borrows the slot being
//! written while it is written.
use controller::calibration_slots::{CalibrationId, FlashError, SlotFlash};
use kinematics_core::{Calibration, CorrectionGrid};

/// The image bundled into the QEMU firmware (see `build.rs`).
#[cfg(feature = "board-qemu")]
#[link_section = ".calibration"]
#[used]
static BUNDLED_IMAGE: [u8; include_bytes!(concat!(env!("OUT_DIR"), "/calibration.bin")).len()] =
    *include_bytes!(concat!(env!("OUT_DIR"), "/calibration.bin"));

/// The second image the QEMU upload scenarios upload at run time (in the program, not the
/// region; the host link's upload is the real path).
#[cfg(feature = "board-qemu")]
pub static BUNDLED_UPLOAD: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/calibration-2.bin"));

extern "C" {
    static __calibration_start: u8;
    static __calibration_end: u8;
}

fn bounds() -> (*const u8, usize) {
    // Only the symbols' addresses are taken (safe for an extern static); the linker script
    // defines both.
    let start = core::ptr::addr_of!(__calibration_start);
    let end = core::ptr::addr_of!(__calibration_end);
    (start, (end as usize).saturating_sub(start as usize))
}

/// The whole calibration region as a byte slice (erased flash reads 0xFF). For boot-time
/// reading (the boot check when no slot counts, the benchmark, the harness at boot).
pub fn region() -> &'static [u8] {
    let (start, len) = bounds();
    // SAFETY: the linker script defines the symbols as the bounds of a region that is mapped
    // for the whole run. Read through a volatile pointer first so the compiler cannot assume
    // the bundled static's contents: the region may have been reflashed.
    unsafe {
        core::ptr::read_volatile(start);
        core::slice::from_raw_parts(start, len)
    }
}

/// The bytes of the image `id` names (its slot, its length): what the servo borrows for the
/// run. Empty if `id` does not fit the region.
pub fn slot_bytes(id: CalibrationId) -> &'static [u8] {
    let (start, len) = bounds();
    let slot_len = (len / 2) - (len / 2) % RegionFlash::ERASE_SIZE;
    let offset = id.slot as usize * slot_len;
    if id.slot > 1 || id.len as usize > slot_len {
        return &[];
    }
    // SAFETY: within the region (checked above); the slot store never writes the slot in
    // force, so the slice is not mutated while borrowed.
    unsafe { core::slice::from_raw_parts(start.add(offset), id.len as usize) }
}

/// The image `id` names, committed a moment ago, parsed for the servo task (which switches to it
/// at rest, `ServoLoop::switch_calibration`). Both upload paths hand it over this way: the host
/// link's commit and the QEMU upload scenarios' task. `None` (logged) if it does not parse,
/// which the store's validation before the commit rules out.
pub fn committed(id: CalibrationId) -> Option<(Calibration<'static>, CalibrationId)> {
    match CorrectionGrid::parse(slot_bytes(id)) {
        Ok(grid) => Some((Calibration::from_grid(grid), id)),
        Err(e) => {
            defmt::error!("committed image does not parse ({})", e);
            None
        }
    }
}

/// The calibration region's flash driver for the slot store.
///
/// QEMU (MPS2-AN386): the region lies in SSRAM1, which QEMU maps as RAM the core can write;
/// this driver gives it NOR semantics in software (erase sets 0xFF in 2 KiB pages, programming
/// ANDs in 8-byte units, as the STM32G474's double words), so the slot store runs the same
/// code as on the real board.
///
/// STM32G474: the FLASH controller (RM0440 §3.3.7-3.3.8): unlock with the KEYR sequence, page
/// erase in bank 2 (PER, BKER, PNB, STRT), double-word programming (PG, two word writes),
/// BSY polled, errors from SR; locked again after every operation. The region is in bank 2
/// and the program in bank 1, so the program's fetches never stall; the servo's reads of the
/// image in force (also bank 2) do stall during an erase or a write (see firmware/README.md,
/// "Calibration slots": not yet solved on the G474).
pub struct RegionFlash {
    _private: (),
}

/// The region's flash driver (one per run: the app owns it through the slot store).
pub fn flash() -> RegionFlash {
    RegionFlash { _private: () }
}

fn check(offset: usize, len: usize, unit: usize, region_len: usize) -> Result<(), FlashError> {
    if offset % unit != 0
        || len % unit != 0
        || offset.checked_add(len).is_none_or(|end| end > region_len)
    {
        return Err(FlashError::Alignment);
    }
    Ok(())
}

#[cfg(feature = "board-qemu")]
impl SlotFlash for RegionFlash {
    const WRITE_SIZE: usize = 8;
    const ERASE_SIZE: usize = 2048;

    fn region(&self) -> &[u8] {
        region()
    }

    fn erase(&mut self, offset: usize, len: usize) -> Result<(), FlashError> {
        let (start, region_len) = bounds();
        check(offset, len, Self::ERASE_SIZE, region_len)?;
        let base = start as *mut u8;
        for k in offset..offset + len {
            // SAFETY: within the region (checked); RAM under QEMU; not the slot in force.
            unsafe { base.add(k).write_volatile(0xFF) };
        }
        Ok(())
    }

    fn program(&mut self, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        let (start, region_len) = bounds();
        check(offset, data.len(), Self::WRITE_SIZE, region_len)?;
        let base = start as *mut u8;
        for (k, &d) in data.iter().enumerate() {
            // SAFETY: as in `erase`. NOR: programming only clears bits.
            unsafe {
                let p = base.add(offset + k);
                p.write_volatile(p.read_volatile() & d);
            }
        }
        Ok(())
    }
}

#[cfg(feature = "board-g474")]
mod g474 {
    //! The STM32G474's FLASH controller, RM0440 chapter 3 (dual-bank mode, DBANK = 1).
    use super::{bounds, check, region, RegionFlash};
    use controller::calibration_slots::{FlashError, SlotFlash};

    const FLASH_BASE: usize = 0x4002_2000;
    const KEYR: usize = FLASH_BASE + 0x08;
    const SR: usize = FLASH_BASE + 0x10;
    const CR: usize = FLASH_BASE + 0x14;
    const KEY1: u32 = 0x4567_0123;
    const KEY2: u32 = 0xCDEF_89AB;
    const SR_EOP: u32 = 1 << 0;
    /// OPERR, PROGERR, WRPERR, PGAERR, SIZERR, PGSERR, MISERR, FASTERR, RDERR, OPTVERR.
    const SR_ERRORS: u32 = (1 << 1) | (0x7F << 3) | (1 << 14) | (1 << 15);
    const SR_BSY: u32 = 1 << 16;
    const CR_PG: u32 = 1 << 0;
    const CR_PER: u32 = 1 << 1;
    const CR_PNB_SHIFT: u32 = 3;
    const CR_BKER: u32 = 1 << 11;
    const CR_STRT: u32 = 1 << 16;
    const CR_LOCK: u32 = 1 << 31;
    /// Bank 2 starts here in dual-bank mode; pages are 2 KiB.
    const BANK2: usize = 0x0804_0000;
    const PAGE: usize = 2048;
    /// Longest page erase (RM0440 / datasheet tERASE max 40 ms) in polling iterations, with margin.
    const BUSY_POLLS: u32 = 20_000_000;

    fn rd(a: usize) -> u32 {
        // SAFETY: a FLASH controller register (RM0440 §3.7).
        unsafe { core::ptr::read_volatile(a as *const u32) }
    }
    fn wr(a: usize, v: u32) {
        // SAFETY: as in `rd`; the slot store is the only user of the FLASH controller.
        unsafe { core::ptr::write_volatile(a as *mut u32, v) }
    }

    fn wait() -> Result<(), FlashError> {
        let mut n = 0;
        while rd(SR) & SR_BSY != 0 {
            n += 1;
            if n > BUSY_POLLS {
                return Err(FlashError::Timeout);
            }
        }
        let sr = rd(SR);
        // Clear EOP and the error flags (write 1 to clear).
        wr(SR, sr & (SR_EOP | SR_ERRORS));
        if sr & SR_ERRORS != 0 {
            return Err(FlashError::Hardware);
        }
        Ok(())
    }

    fn unlock() -> Result<(), FlashError> {
        wait()?;
        if rd(CR) & CR_LOCK != 0 {
            wr(KEYR, KEY1);
            wr(KEYR, KEY2);
        }
        if rd(CR) & CR_LOCK != 0 {
            return Err(FlashError::Hardware);
        }
        Ok(())
    }

    fn lock() {
        wr(CR, CR_LOCK);
    }

    impl SlotFlash for RegionFlash {
        const WRITE_SIZE: usize = 8;
        const ERASE_SIZE: usize = PAGE;

        fn region(&self) -> &[u8] {
            region()
        }

        fn erase(&mut self, offset: usize, len: usize) -> Result<(), FlashError> {
            let (start, region_len) = bounds();
            check(offset, len, PAGE, region_len)?;
            unlock()?;
            let mut result = Ok(());
            for page_start in (offset..offset + len).step_by(PAGE) {
                let address = start as usize + page_start;
                let Some(page) = address.checked_sub(BANK2).map(|a| (a / PAGE) as u32) else {
                    result = Err(FlashError::Alignment);
                    break;
                };
                wr(CR, CR_PER | CR_BKER | (page << CR_PNB_SHIFT));
                wr(CR, CR_PER | CR_BKER | (page << CR_PNB_SHIFT) | CR_STRT);
                result = wait();
                if result.is_err() {
                    break;
                }
            }
            lock();
            result
        }

        fn program(&mut self, offset: usize, data: &[u8]) -> Result<(), FlashError> {
            let (start, region_len) = bounds();
            check(offset, data.len(), 8, region_len)?;
            unlock()?;
            wr(CR, CR_PG);
            let mut result = Ok(());
            for (k, dw) in data.chunks_exact(8).enumerate() {
                let address = start as usize + offset + 8 * k;
                let lo = u32::from_le_bytes([dw[0], dw[1], dw[2], dw[3]]);
                let hi = u32::from_le_bytes([dw[4], dw[5], dw[6], dw[7]]);
                // SAFETY: a double word of the region (checked), erased by the slot store's
                // `begin`; the first word then the second, as RM0440 §3.3.7 requires.
                unsafe {
                    core::ptr::write_volatile(address as *mut u32, lo);
                    core::ptr::write_volatile((address + 4) as *mut u32, hi);
                }
                result = wait();
                // SAFETY: reading back the double word just programmed (within the region).
                let back = unsafe { core::slice::from_raw_parts(address as *const u8, 8) };
                if result.is_ok() && back != dw {
                    result = Err(FlashError::Hardware);
                }
                if result.is_err() {
                    break;
                }
            }
            lock();
            result
        }
    }
}
