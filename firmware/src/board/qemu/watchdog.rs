//! The QEMU board's independent watchdog: the MPS2-AN386's CMSDK APB watchdog (`0x4000_8000`,
//! clocked at 25 MHz like the rest of the FPGA; QEMU 7.2 wires its interrupt to the NMI).
//!
//! At the first expiry it raises its interrupt, the NMI; at the second, with the interrupt
//! still pending, it resets the machine (`RESEN`). The NMI handler is the board's reaction:
//! it removes torque (duty to zero torque, enable line low), marks the coming reset as the
//! watchdog's ([`hardware::note_watchdog_reset`]) and hands over to the test harness, which
//! judges it ([`harness::watchdog_fired`]) and waits for the reset. It never clears the
//! interrupt, so the second expiry resets the machine.
//!
//! Timeout: [`controller::watchdog::TIMEOUT_US`] (3 ms) after the last feed. The registers are
//! locked between feeds (`WDOGLOCK`), so a stray write cannot stop it.
use controller::watchdog::TIMEOUT_US;

use super::{hardware, harness, TIMER_CLOCK_HZ};

const BASE: usize = 0x4000_8000;
const WDOGLOAD: usize = 0x000;
const WDOGCONTROL: usize = 0x008;
const WDOGINTCLR: usize = 0x00C;
const WDOGLOCK: usize = 0xC00;
/// Writing this to `WDOGLOCK` unlocks the other registers; anything else locks them.
const UNLOCK: u32 = 0x1ACC_E551;
/// `WDOGCONTROL`: counter and interrupt enable, reset enable.
const INTEN: u32 = 1 << 0;
const RESEN: u32 = 1 << 1;
/// Counts of the 25 MHz watchdog clock to the first expiry: the timeout.
pub const LOAD: u32 = (TIMEOUT_US * (TIMER_CLOCK_HZ as f32 / 1.0e6)) as u32 - 1;

fn write(offset: usize, value: u32) {
    // SAFETY: a register of the CMSDK watchdog in the AN386 memory map; only this module
    // touches it.
    unsafe { core::ptr::write_volatile((BASE + offset) as *mut u32, value) }
}

/// Starts the watchdog: the timeout, interrupt (NMI) and reset enabled, registers locked.
pub fn start() {
    write(WDOGLOCK, UNLOCK);
    write(WDOGLOAD, LOAD);
    write(WDOGCONTROL, INTEN | RESEN);
    write(WDOGLOCK, 0);
}

/// Feeds it: the counter reloads the timeout.
#[inline]
pub fn feed() {
    write(WDOGLOCK, UNLOCK);
    write(WDOGINTCLR, 1);
    write(WDOGLOCK, 0);
}

/// The watchdog's first expiry: the servo task stopped feeding it. Removes torque, then the
/// harness judges and waits for the reset (never returns).
///
/// # Safety
/// cortex-m-rt requires an NMI handler to be `unsafe`: it may preempt anything, critical
/// sections included. It touches only atomics (the simulated hardware, the harness's
/// records), the reset flag and semihosting; it never returns into what it preempted.
#[cortex_m_rt::exception]
unsafe fn NonMaskableInt() {
    let drive_enable_at_fire = hardware::drive_enable();
    hardware::safe_state();
    hardware::note_watchdog_reset();
    harness::watchdog_fired(drive_enable_at_fire)
}
