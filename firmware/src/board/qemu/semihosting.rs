//! ARM semihosting on the QEMU board: command line, plain-text console, exit code, and the
//! defmt logger writing its frames to the host file `defmt.bin` (so they never mix with the
//! console; `qemu/test.sh` decodes them with `defmt-print` when it is installed).
//!
//! HardFault, unexpected interrupts and panics disable interrupts, put the simulated hardware in
//! the safe state (zero torque, enable line low), print a `FAIL ...` line and exit with
//! failure, so a broken firmware can never hang CI; `qemu/test.sh`'s self-test runs match those
//! lines.
use cortex_m_semihosting::{nr, syscall, syscall1};

use super::hardware;

/// The semihosting command line (`"<program> <scenario>"`), in `buf`.
pub fn command_line(buf: &mut [u8]) -> &str {
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE writes at most `buf.len()` bytes into `buf` and the length into
    // `block[1]`; both live across the call.
    let rc = unsafe { syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    if rc != 0 {
        return "";
    }
    let len = block[1].min(buf.len());
    core::str::from_utf8(&buf[..len]).unwrap_or("")
}

/// Writes a line of plain text to the host console (errors are ignored).
pub fn console(line: &str) {
    if let Ok(mut out) = cortex_m_semihosting::hio::hstdout() {
        let _ = out.write_all(line.as_bytes());
        let _ = out.write_all(b"\n");
    }
}

/// Ends the QEMU run: exit code 0 on `pass`, 1 otherwise.
pub fn exit(pass: bool) -> ! {
    let status = if pass {
        cortex_m_semihosting::debug::EXIT_SUCCESS
    } else {
        cortex_m_semihosting::debug::EXIT_FAILURE
    };
    loop {
        cortex_m_semihosting::debug::exit(status);
    }
}

/// What every failure path does first.
fn fail_safe() {
    cortex_m::interrupt::disable();
    hardware::safe_state();
}

hard_fault_on_fresh_stack!(hard_fault);

/// The HardFault handler, on a fresh stack (`hard_fault_on_fresh_stack!`, as on the STM32G474).
unsafe extern "C" fn hard_fault(_faulting_sp: u32) -> ! {
    fail_safe();
    console("FAIL HardFault");
    exit(false)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    let _ = irqn;
    fail_safe();
    console("FAIL unexpected interrupt (DefaultHandler)");
    exit(false)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    use core::fmt::Write;
    fail_safe();
    if let Ok(mut out) = cortex_m_semihosting::hio::hstdout() {
        let _ = writeln!(out, "FAIL panic: {}", info);
    }
    exit(false)
}

/// defmt logger appending each frame to the host file `defmt.bin` (opened at the first log;
/// appended, so that the log of a boot after a watchdog reset follows the first boot's;
/// `qemu/run-one.sh` removes the file before a run).
mod logger {
    use core::cell::UnsafeCell;
    use core::sync::atomic::{AtomicBool, Ordering};

    use super::syscall;

    #[defmt::global_logger]
    struct Logger;

    struct State {
        restore: critical_section::RestoreState,
        encoder: defmt::Encoder,
        /// Semihosting file handle; `usize::MAX` when the file could not be opened.
        handle: Option<usize>,
        buf: [u8; 256],
        len: usize,
    }

    struct Cell(UnsafeCell<State>);
    // SAFETY: only touched between `acquire` and `release`, inside a critical section.
    unsafe impl Sync for Cell {}

    static TAKEN: AtomicBool = AtomicBool::new(false);
    static STATE: Cell = Cell(UnsafeCell::new(State {
        restore: critical_section::RestoreState::invalid(),
        encoder: defmt::Encoder::new(),
        handle: None,
        buf: [0; 256],
        len: 0,
    }));

    fn flush(s: &mut State) {
        if s.handle.is_none() {
            let name = b"defmt.bin\0";
            // Mode 9 is "ab".
            // SAFETY: SYS_OPEN reads `name` (length without the NUL).
            let h = unsafe { syscall!(OPEN, name.as_ptr(), 9, name.len() - 1) } as isize;
            s.handle = Some(if h < 0 { usize::MAX } else { h as usize });
            if h >= 0 {
                // QEMU 7.2 opens "ab" at offset 0: seek to the end explicitly.
                // SAFETY: SYS_FLEN and SYS_SEEK take the handle just opened.
                let len = unsafe { syscall!(FLEN, h as usize) } as isize;
                if len > 0 {
                    // SAFETY: as above.
                    unsafe { syscall!(SEEK, h as usize, len as usize) };
                }
            }
        }
        if let Some(h) = s.handle {
            if h != usize::MAX && s.len > 0 {
                // SAFETY: SYS_WRITE reads `len` bytes of `buf`.
                unsafe { syscall!(WRITE, h, s.buf.as_ptr(), s.len) };
            }
        }
        s.len = 0;
    }

    fn push(s: &mut State, bytes: &[u8]) {
        for &b in bytes {
            if s.len == s.buf.len() {
                flush(s);
            }
            s.buf[s.len] = b;
            s.len += 1;
        }
    }

    // SAFETY: `acquire`/`release` bracket every frame in a critical section; re-entry is refused.
    unsafe impl defmt::Logger for Logger {
        fn acquire() {
            // SAFETY: paired with `critical_section::release` in `release`.
            let restore = unsafe { critical_section::acquire() };
            if TAKEN.swap(true, Ordering::Relaxed) {
                // Re-entered from within a frame: cannot happen with one critical section.
                super::console("FAIL defmt logger re-entered");
                super::exit(false);
            }
            // SAFETY: exclusive inside the critical section.
            let s = unsafe { &mut *STATE.0.get() };
            s.restore = restore;
            let State { encoder, .. } = s;
            let mut tmp = [0u8; 16];
            let mut n = 0;
            encoder.start_frame(|b| {
                for &x in b {
                    if n < tmp.len() {
                        tmp[n] = x;
                        n += 1;
                    }
                }
            });
            push(s, &tmp[..n]);
        }

        unsafe fn flush() {}

        unsafe fn release() {
            // SAFETY: inside the critical section taken by `acquire`.
            let s = unsafe { &mut *STATE.0.get() };
            let mut tmp = [0u8; 16];
            let mut n = 0;
            s.encoder.end_frame(|b| {
                for &x in b {
                    if n < tmp.len() {
                        tmp[n] = x;
                        n += 1;
                    }
                }
            });
            push(s, &tmp[..n]);
            flush(s);
            let restore = s.restore;
            TAKEN.store(false, Ordering::Relaxed);
            // SAFETY: paired with `acquire`.
            unsafe { critical_section::release(restore) };
        }

        unsafe fn write(bytes: &[u8]) {
            // SAFETY: inside the critical section taken by `acquire`.
            let s = unsafe { &mut *STATE.0.get() };
            let State { encoder, .. } = s;
            // The encoder may emit more bytes than it is given (rzCOBS); stage in chunks.
            let encoder: *mut defmt::Encoder = encoder;
            for chunk in bytes.chunks(8) {
                let mut tmp = [0u8; 32];
                let mut n = 0;
                // SAFETY: `encoder` points into `STATE`, exclusively ours here.
                unsafe { &mut *encoder }.write(chunk, |b| {
                    for &x in b {
                        if n < tmp.len() {
                            tmp[n] = x;
                            n += 1;
                        }
                    }
                });
                push(s, &tmp[..n]);
            }
        }
    }
}
