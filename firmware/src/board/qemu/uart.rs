//! The host link's port on the QEMU board: CMSDK APB UART0 of the MPS2-AN386 (0x4000_4000,
//! receive interrupt IRQ 0), which QEMU connects to its first `-serial` (the link runner mode
//! maps it to a TCP socket: `firmware/qemu/run-one.sh`, `QEMU_SERIAL`). The console is
//! semihosting, so the UART carries nothing but link frames.
//!
//! QEMU's CMSDK UART holds one received byte and asks the socket for the next only once it is
//! read, so no byte is lost however slowly the link task drains it.
use crate::link::LinkPort;

use super::TIMER_CLOCK_HZ;

const UART0_BASE: usize = 0x4000_4000;
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INT: usize = 0x0C; // INTSTATUS on read, INTCLEAR on write
const BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_ENABLE: u32 = 1 << 0;
const CTRL_RX_ENABLE: u32 = 1 << 1;
const CTRL_RX_IRQ: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;
/// Link baud rate (QEMU ignores it beyond requiring a divider of at least 16).
pub const BAUD: u32 = 115_200;
/// Polls of a full transmitter before a write gives up.
const TX_PATIENCE: u32 = 100_000;

fn read(offset: usize) -> u32 {
    // SAFETY: a CMSDK UART0 register of the AN386 memory map, owned by the link task.
    unsafe { core::ptr::read_volatile((UART0_BASE + offset) as *const u32) }
}
fn write(offset: usize, value: u32) {
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile((UART0_BASE + offset) as *mut u32, value) }
}

/// UART0, receive interrupt on.
pub struct CmsdkUart {
    /// Bytes dropped because the transmitter stayed full.
    pub dropped: u32,
}

impl CmsdkUart {
    /// Configures UART0 (receive interrupt enabled). Not `new`/`Default`: it writes the
    /// peripheral's registers.
    pub fn open() -> Self {
        write(CTRL, 0);
        write(BAUDDIV, TIMER_CLOCK_HZ / BAUD);
        write(INT, 0b11);
        write(CTRL, CTRL_TX_ENABLE | CTRL_RX_ENABLE | CTRL_RX_IRQ);
        CmsdkUart { dropped: 0 }
    }
}

impl LinkPort for CmsdkUart {
    fn read_byte(&mut self) -> Option<u8> {
        write(INT, INT_RX);
        (read(STATE) & STATE_RX_FULL != 0).then(|| read(DATA) as u8)
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            let mut patience = TX_PATIENCE;
            while read(STATE) & STATE_TX_FULL != 0 && patience > 0 {
                patience -= 1;
            }
            if patience == 0 {
                self.dropped = self.dropped.wrapping_add(1);
                continue;
            }
            write(DATA, u32::from(b));
        }
    }
}
