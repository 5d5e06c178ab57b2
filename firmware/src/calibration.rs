//! The correction grid image in its own flash region (`CALIBRATION` in `memory.x`).
//!
//! The region is read by address, through the linker symbols `__calibration_start` and
//! `__calibration_end`, not through a Rust static: whatever was flashed there is what the
//! firmware validates, so a new calibration needs no rebuild. The QEMU build also links a
//! valid image into the region (built by `build.rs`); the real board's build does not.
//!
//! Validation and the policy for a bad or missing image: `controller::calibration::load`.

/// The image bundled into the QEMU firmware (see `build.rs`).
#[cfg(feature = "board-qemu")]
#[link_section = ".calibration"]
#[used]
static BUNDLED_IMAGE: [u8; include_bytes!(concat!(env!("OUT_DIR"), "/calibration.bin")).len()] =
    *include_bytes!(concat!(env!("OUT_DIR"), "/calibration.bin"));

extern "C" {
    static __calibration_start: u8;
    static __calibration_end: u8;
}

/// The whole calibration region as a byte slice (erased flash reads 0xFF).
pub fn region() -> &'static [u8] {
    // SAFETY: the linker script defines both symbols as the bounds of a flash region that is
    // mapped for the whole run and never written by the firmware.
    unsafe {
        let start = core::ptr::addr_of!(__calibration_start);
        let end = core::ptr::addr_of!(__calibration_end);
        let len = (end as usize).saturating_sub(start as usize);
        // Read through a volatile pointer first so the compiler cannot assume the bundled
        // static's contents: the region may have been reflashed.
        core::ptr::read_volatile(start);
        core::slice::from_raw_parts(start, len)
    }
}
