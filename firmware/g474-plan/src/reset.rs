//! The reset cause from `RCC_CSR` (RM0440 "Reset and clock control (RCC)", RCC_CSR).
//!
//! Every internal reset also pulls NRST low, so `PINRSTF` accompanies the others; a power-on
//! sets `BORRSTF`. The flags stay until `RMVF` clears them ([`crate::plan::CLEAR_RESET_FLAGS`]),
//! so the board reads them once at boot and clears them.
use controller::watchdog::ResetCause;

/// RCC_CSR: option-byte loader reset.
pub const OBLRSTF: u32 = 1 << 25;
/// RCC_CSR: NRST pin reset.
pub const PINRSTF: u32 = 1 << 26;
/// RCC_CSR: brown-out (or power-on) reset.
pub const BORRSTF: u32 = 1 << 27;
/// RCC_CSR: software reset.
pub const SFTRSTF: u32 = 1 << 28;
/// RCC_CSR: independent watchdog reset.
pub const IWDGRSTF: u32 = 1 << 29;
/// RCC_CSR: window watchdog reset.
pub const WWDGRSTF: u32 = 1 << 30;
/// RCC_CSR: illegal low-power entry reset.
pub const LPWRRSTF: u32 = 1 << 31;

/// The cause of the last reset from the flags in `csr`: the most specific flag wins (a
/// watchdog reset also shows the pin flag).
pub fn reset_cause(csr: u32) -> ResetCause {
    if csr & (IWDGRSTF | WWDGRSTF) != 0 {
        ResetCause::Watchdog
    } else if csr & LPWRRSTF != 0 {
        ResetCause::LowPower
    } else if csr & BORRSTF != 0 {
        ResetCause::PowerOnOrBrownOut
    } else if csr & SFTRSTF != 0 {
        ResetCause::Software
    } else if csr & OBLRSTF != 0 {
        ResetCause::OptionByteLoad
    } else if csr & PINRSTF != 0 {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    }
}
