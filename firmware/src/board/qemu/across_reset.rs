//! The simulated machine outlives a reset of its controller: its state, kept in RAM that a
//! reset does not clear, for the boot after it.
//!
//! A real machine does not stop when its controller resets: after the watchdog's reset in
//! `stalled-task` it is still moving, its drives off. The QEMU plant lives in the firmware's
//! RAM, which the boot re-initialises; so while the servo task is stalled the harness keeps the
//! plant moving and [`keep`]s its state after every step, and the boot after the reset
//! [`take`]s it and resumes the plant there (`Plant::resume`). Between the watchdog's interrupt
//! and the first sample after the reset the plant stands still; its drives are off then, so the
//! coast is only delayed, not changed. What the last step before the interrupt would have
//! moved (under 50 µs of the last torque) is lost.
//!
//! The record lives in `.uninit` RAM (like the reset flag, `hardware::note_watchdog_reset`),
//! which neither QEMU's system reset nor cortex-m-rt's start-up clears; a fresh QEMU's RAM
//! reads 0, i.e. nothing kept. Two slots and an index written last: the watchdog's interrupt
//! may come in the middle of a [`keep`], and the index then still names the complete slot.
use core::mem::MaybeUninit;

use controller::scenario::stop_check::PlantState;

/// A slot holding a state: this value in its first word.
const KEPT: u32 = 0x504C_4E54;
/// The index word's value when nothing is kept (any value but 0 or 1 reads so).
const NOTHING: u32 = u32::MAX;

#[derive(Clone, Copy)]
#[repr(C)]
struct Slot {
    magic: u32,
    joint_rad: [f32; 2],
    joint_rad_s: [f32; 2],
}

#[link_section = ".uninit.across_reset"]
static mut SLOTS: MaybeUninit<[Slot; 2]> = MaybeUninit::uninit();
#[link_section = ".uninit.across_reset"]
static mut CURRENT: MaybeUninit<u32> = MaybeUninit::uninit();

fn slot(i: usize) -> *mut Slot {
    // In bounds: i is 0 or 1.
    core::ptr::addr_of_mut!(SLOTS)
        .cast::<Slot>()
        .wrapping_add(i & 1)
}

fn current() -> *mut u32 {
    core::ptr::addr_of_mut!(CURRENT).cast::<u32>()
}

/// Keeps `state` for the boot after a reset (the harness, while the servo task is stalled).
pub fn keep(state: PlantState) {
    // SAFETY: RAM reserved for this record, written only here (from the stalled servo task;
    // the watchdog's interrupt never touches it) and read at boot; volatile, as it must survive
    // a reset. Any bit pattern is a valid u32.
    unsafe {
        let next = (current().read_volatile() ^ 1) as usize & 1;
        slot(next).write_volatile(Slot {
            magic: KEPT,
            joint_rad: state.joint_rad,
            joint_rad_s: state.joint_rad_s,
        });
        current().write_volatile(next as u32);
    }
}

/// The state kept before the last reset, if any; forgets it.
pub fn take() -> Option<PlantState> {
    // SAFETY: as in `keep`; at boot, before any `keep`. Any bit pattern of the slot is a valid
    // `Slot` (u32 and f32 fields).
    unsafe {
        let i = current().read_volatile();
        current().write_volatile(NOTHING);
        if i > 1 {
            return None;
        }
        let s = slot(i as usize).read_volatile();
        slot(i as usize).write_volatile(Slot { magic: 0, ..s });
        (s.magic == KEPT).then_some(PlantState {
            joint_rad: s.joint_rad,
            joint_rad_s: s.joint_rad_s,
        })
    }
}
