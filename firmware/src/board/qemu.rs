//! The QEMU board: MPS2-AN386 (Cortex-M4F) under `qemu-system-arm -M mps2-an386`, with the
//! machine simulated inside the firmware.
//!
//! * Servo tick: CMSDK APB TIMER0 (IRQ 8, 25 MHz), reload for 2 kHz.
//! * Plant: two joint inertias driven by the commanded torques, with viscous and Coulomb
//!   friction, advanced by [`Board::simulate_period`] at the start of every servo sample (the
//!   torque written in sample k acts during period k..k+1, as on hardware). The plant's
//!   parameters are deliberately not the servo's: inertias 10 % off the feed-forward, and
//!   friction the feed-forward does not know about.
//! * "Hardware registers" between the firmware and the plant are atomics: PWM duty per axis,
//!   the drive-enable line, and the encoder counters (2^22 counts per revolution, quantised).
//! * Console, exit code and command line: ARM semihosting. defmt frames go to the host file
//!   `defmt.bin` (semihosting file I/O) so they never mix with the plain-text console;
//!   `qemu/test.sh` decodes them with `defmt-print` when it is installed.
//! * HardFault, unexpected interrupts and panics print a line and exit with failure, so a
//!   broken firmware can never hang CI.
use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU16, Ordering};

use cortex_m_semihosting::{nr, syscall, syscall1};
use embedded_hal::pwm::{ErrorType, SetDutyCycle};

use super::{counts_to_rad, duty_to_torque_nm, QuadratureEncoder, TorqueDrive};

/// The device module RTIC needs: interrupt numbers, priority bits and the vector table.
///
/// The app uses board-neutral interrupt names so that one app file serves both boards.
pub mod device {
    /// The AN386's Cortex-M4 implements 3 priority bits.
    pub const NVIC_PRIO_BITS: u8 = 3;

    /// The interrupts this firmware uses.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    #[allow(non_camel_case_types)]
    #[repr(u16)]
    pub enum Interrupt {
        /// UART2 RX (IRQ 4), unused by the board: dispatcher of the priority-1 software tasks.
        DISPATCH_1 = 4,
        /// UART2 TX (IRQ 5), unused by the board: dispatcher of the priority-2 software tasks.
        DISPATCH_2 = 5,
        /// CMSDK TIMER0 (IRQ 8): the 2 kHz servo tick.
        SERVO_TICK = 8,
    }
    pub use Interrupt as interrupt;

    // SAFETY: the numbers are the AN386's IRQ lines (all below its 32 external interrupts).
    unsafe impl cortex_m::interrupt::InterruptNumber for Interrupt {
        #[inline]
        fn number(self) -> u16 {
            self as u16
        }
    }

    extern "C" {
        fn DISPATCH_1();
        fn DISPATCH_2();
        fn SERVO_TICK();
        fn DefaultHandler();
    }

    #[doc(hidden)]
    pub union Vector {
        handler: unsafe extern "C" fn(),
        _reserved: usize,
    }

    const D: Vector = Vector { handler: DefaultHandler };

    /// External interrupt vectors 0..31 (cortex-m-rt places them after the exceptions).
    #[doc(hidden)]
    #[link_section = ".vector_table.interrupts"]
    #[no_mangle]
    pub static __INTERRUPTS: [Vector; 32] = [
        D, D, D, D,
        Vector { handler: DISPATCH_1 },
        Vector { handler: DISPATCH_2 },
        D, D,
        Vector { handler: SERVO_TICK },
        D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D, D,
    ];
}

/// Core clock and timer clock of the AN386 (QEMU's SYSCLK).
pub const TIMER_CLOCK_HZ: u32 = 25_000_000;
/// Encoder resolution of the simulated motors.
pub const COUNTS_PER_REV: u32 = 1 << 22;
/// PWM full-scale duty (the G474's 20 kHz centre-aligned TIM1 period at 170 MHz; even, so that
/// 50 % and thus zero torque is exact).
pub const PWM_MAX_DUTY: u16 = 4250;

// ---------------------------------------------------------------------------------------------
// Servo timer: CMSDK APB timer 0.

const TIMER0_BASE: usize = 0x4000_0000;
const TIMER_CTRL: usize = 0x00;
const TIMER_VALUE: usize = 0x04;
const TIMER_RELOAD: usize = 0x08;
const TIMER_INT: usize = 0x0C; // INTSTATUS on read, INTCLEAR on write
const CTRL_ENABLE: u32 = 1 << 0;
const CTRL_IRQ_ENABLE: u32 = 1 << 3;

fn timer_read(offset: usize) -> u32 {
    // SAFETY: a CMSDK timer register of the AN386 memory map.
    unsafe { core::ptr::read_volatile((TIMER0_BASE + offset) as *const u32) }
}
fn timer_write(offset: usize, value: u32) {
    // SAFETY: a CMSDK timer register of the AN386 memory map; only the servo timer owns it.
    unsafe { core::ptr::write_volatile((TIMER0_BASE + offset) as *mut u32, value) }
}

/// The 2 kHz servo tick. The timer counts down from `reload` to 0 once per period.
pub struct ServoTimer {
    reload: u32,
}

impl ServoTimer {
    fn new(rate_hz: u32) -> Self {
        let reload = TIMER_CLOCK_HZ / rate_hz - 1;
        timer_write(TIMER_CTRL, 0);
        timer_write(TIMER_RELOAD, reload);
        timer_write(TIMER_VALUE, reload);
        timer_write(TIMER_INT, 1);
        ServoTimer { reload }
    }

    /// Starts the periodic interrupt.
    pub fn start(&mut self) {
        timer_write(TIMER_CTRL, CTRL_ENABLE | CTRL_IRQ_ENABLE);
    }

    /// Acknowledges the tick (first thing in the servo task).
    #[inline]
    pub fn clear_interrupt(&mut self) {
        timer_write(TIMER_INT, 1);
    }

    /// Time since the current period started (µs).
    #[inline]
    pub fn elapsed_us(&self) -> f32 {
        let ticks = self.reload.saturating_sub(timer_read(TIMER_VALUE));
        ticks as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32)
    }

    /// Time since the tick that started this step (µs), also when the step ran past the next
    /// tick (the counter restarted then; steps longer than two periods read short).
    #[inline]
    pub fn step_time_us(&self) -> f32 {
        let elapsed_us = self.elapsed_us();
        let period_us = (self.reload + 1) as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32);
        // A pending tick with a small count means the counter already wrapped once.
        if self.next_tick_pending() && elapsed_us < 0.5 * period_us {
            period_us + elapsed_us
        } else {
            elapsed_us
        }
    }

    /// Whether the next period has already begun (its interrupt is pending): an overrun.
    #[inline]
    pub fn next_tick_pending(&self) -> bool {
        timer_read(TIMER_INT) & 1 != 0
    }

    /// Busy-waits until `us` after the current period started (deadline fault injection).
    pub fn burn_until_us(&self, us: f32) {
        while !self.next_tick_pending() && self.elapsed_us() < us {}
        // Past the period end the counter restarted: keep burning in the next period.
        if self.next_tick_pending() {
            let rest = us - (self.reload + 1) as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32);
            while self.elapsed_us() < rest {}
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Simulated hardware: PWM, drive enable, encoders, and the plant behind them.

static PWM_DUTY: [AtomicU16; 2] = [AtomicU16::new(PWM_MAX_DUTY / 2), AtomicU16::new(PWM_MAX_DUTY / 2)];
static DRIVES_ENABLED: AtomicBool = AtomicBool::new(false);
static ENCODER_COUNTS: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];

/// One PWM channel of the simulated drive.
pub struct SimPwm {
    axis: usize,
}

impl ErrorType for SimPwm {
    type Error = core::convert::Infallible;
}

impl SetDutyCycle for SimPwm {
    fn max_duty_cycle(&self) -> u16 {
        PWM_MAX_DUTY
    }
    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
        PWM_DUTY[self.axis].store(duty.min(PWM_MAX_DUTY), Ordering::Relaxed);
        Ok(())
    }
}

/// One simulated encoder counter.
pub struct SimEncoder {
    axis: usize,
}

impl QuadratureEncoder for SimEncoder {
    fn position_counts(&mut self) -> i32 {
        ENCODER_COUNTS[self.axis].load(Ordering::Relaxed)
    }
}

/// Parameters of the simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct PlantParams {
    /// Joint inertias (kg·m²): the servo's feed-forward assumes 2e-3.
    pub inertia_kg_m2: [f32; 2],
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_per_rad: f32,
    /// Coulomb friction (N·m), smoothed over [`PlantParams::coulomb_smoothing_rad_s`].
    pub coulomb_nm: f32,
    pub coulomb_smoothing_rad_s: f32,
    /// Integration sub-steps per servo period (semi-implicit Euler).
    pub substeps: u32,
}

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            inertia_kg_m2: [2.2e-3, 1.8e-3],
            viscous_nm_s_per_rad: 0.01,
            coulomb_nm: 0.03,
            coulomb_smoothing_rad_s: 1.0e-3,
            substeps: 10,
        }
    }
}

/// The simulated joints.
#[derive(Clone, Copy, Debug)]
pub struct Plant {
    pub params: PlantParams,
    pub angle_rad: [f32; 2],
    pub velocity_rad_s: [f32; 2],
    full_scale_nm: f32,
}

impl Plant {
    fn publish_encoders(&self) {
        for k in 0..2 {
            let counts = libm::roundf(self.angle_rad[k] * (COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI)));
            ENCODER_COUNTS[k].store(counts as i32, Ordering::Relaxed);
        }
    }

    /// Advances the joints by `period_s` under the torques the PWM commands now.
    pub fn advance(&mut self, period_s: f32) {
        let enabled = DRIVES_ENABLED.load(Ordering::Relaxed);
        let p = self.params;
        let h = period_s / p.substeps as f32;
        for k in 0..2 {
            let torque = if enabled {
                duty_to_torque_nm(PWM_DUTY[k].load(Ordering::Relaxed), self.full_scale_nm, PWM_MAX_DUTY)
            } else {
                0.0
            };
            let (mut angle, mut velocity) = (self.angle_rad[k], self.velocity_rad_s[k]);
            for _ in 0..p.substeps {
                let friction = p.viscous_nm_s_per_rad * velocity
                    + p.coulomb_nm * velocity / (velocity.abs() + p.coulomb_smoothing_rad_s);
                velocity += (torque - friction) / p.inertia_kg_m2[k] * h;
                angle += velocity * h;
            }
            self.angle_rad[k] = angle;
            self.velocity_rad_s[k] = velocity;
        }
        self.publish_encoders();
    }
}

/// Joint angles the simulated machine powers up at (rad): tool near (214, 3) mm.
pub const POWER_ON_ANGLES_RAD: [f32; 2] = [0.80, -0.75];

// ---------------------------------------------------------------------------------------------
// The board.

pub struct Board {
    pub timer: ServoTimer,
    pub encoders: [SimEncoder; 2],
    pub drives: [TorqueDrive<SimPwm>; 2],
    pub plant: Plant,
    period_s: f32,
}

impl Board {
    /// Brings the board up with the drives disabled and zero torque commanded.
    pub fn init(rate_hz: u32, drive_full_scale_nm: f32) -> Self {
        let plant = Plant {
            params: PlantParams::default(),
            angle_rad: POWER_ON_ANGLES_RAD,
            velocity_rad_s: [0.0; 2],
            full_scale_nm: drive_full_scale_nm,
        };
        plant.publish_encoders();
        let mut board = Board {
            timer: ServoTimer::new(rate_hz),
            encoders: [SimEncoder { axis: 0 }, SimEncoder { axis: 1 }],
            drives: [
                TorqueDrive { pwm: SimPwm { axis: 0 }, full_scale_nm: drive_full_scale_nm },
                TorqueDrive { pwm: SimPwm { axis: 1 }, full_scale_nm: drive_full_scale_nm },
            ],
            plant,
            period_s: 1.0 / rate_hz as f32,
        };
        board.disable_drives();
        board
    }

    /// Advances the simulated plant by one servo period (hardware: nothing to do).
    #[inline]
    pub fn simulate_period(&mut self) {
        let period_s = self.period_s;
        self.plant.advance(period_s);
    }

    /// Both encoder angles (rad).
    #[inline]
    pub fn encoders_rad(&mut self) -> [f32; 2] {
        [
            counts_to_rad(self.encoders[0].position_counts(), COUNTS_PER_REV),
            counts_to_rad(self.encoders[1].position_counts(), COUNTS_PER_REV),
        ]
    }

    /// Writes both torques; returns the torques commanded, or `None` if a PWM write failed.
    #[inline]
    pub fn set_torques_nm(&mut self, torque_nm: [f32; 2]) -> Option<[f32; 2]> {
        let a = self.drives[0].set_torque_nm(torque_nm[0]).ok()?;
        let b = self.drives[1].set_torque_nm(torque_nm[1]).ok()?;
        Some([a, b])
    }

    pub fn enable_drives(&mut self) {
        DRIVES_ENABLED.store(true, Ordering::SeqCst);
    }

    /// Safe state: drive-enable off, then zero torque commanded.
    pub fn disable_drives(&mut self) {
        DRIVES_ENABLED.store(false, Ordering::SeqCst);
        let _ = self.set_torques_nm([0.0; 2]);
    }
}

/// What idle does between interrupts. A busy loop, not WFI: under `-icount ...,sleep=off`
/// a WFI idle makes QEMU's periodic timer run at half rate.
#[inline]
pub fn idle_wait() {
    cortex_m::asm::nop();
}

// ---------------------------------------------------------------------------------------------
// Semihosting: command line, console, exit, defmt to a host file.

/// The semihosting command line ("<program> <scenario>"), in `buf`.
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
    let status = if pass { cortex_m_semihosting::debug::EXIT_SUCCESS } else { cortex_m_semihosting::debug::EXIT_FAILURE };
    loop {
        cortex_m_semihosting::debug::exit(status);
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    console("FAIL HardFault");
    exit(false)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    let _ = irqn;
    console("FAIL unexpected interrupt (DefaultHandler)");
    exit(false)
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    use core::fmt::Write;
    if let Ok(mut out) = cortex_m_semihosting::hio::hstdout() {
        let _ = writeln!(out, "FAIL panic: {}", info);
    }
    exit(false)
}

/// defmt logger writing each frame to the host file `defmt.bin` (opened at the first log).
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
            // Mode 5 is "wb".
            // SAFETY: SYS_OPEN reads `name` (length without the NUL).
            let h = unsafe { syscall!(OPEN, name.as_ptr(), 5, name.len() - 1) } as isize;
            s.handle = Some(if h < 0 { usize::MAX } else { h as usize });
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

/// What the benchmark counter's figures are: QEMU counts instructions, not cycles.
pub const COUNT_UNIT: &str = "instructions";

/// Free-running counter for the benchmark: SysTick counting down from 2^24 - 1 on the core
/// clock. Under `-icount shift=0` QEMU advances virtual time 1 ns per instruction, so a count
/// is a fixed number of instructions; `bench` measures that number with a loop of known
/// length instead of assuming it.
pub struct CycleCounter {
    _syst: cortex_m::peripheral::SYST,
}

impl CycleCounter {
    const MASK: u32 = (1 << 24) - 1;

    pub fn new(core: cortex_m::Peripherals) -> Self {
        let mut syst = core.SYST;
        syst.set_clock_source(cortex_m::peripheral::syst::SystClkSource::Core);
        syst.set_reload(Self::MASK);
        syst.clear_current();
        syst.enable_counter();
        CycleCounter { _syst: syst }
    }

    /// Counts since an arbitrary origin, increasing (wraps at 2^24).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        Self::MASK - cortex_m::peripheral::SYST::get_current()
    }

    /// Counts since `earlier` (modulo 2^24: measure less than 2^24 counts at a time).
    #[inline(always)]
    pub fn since(&self, earlier: u32) -> u32 {
        self.now().wrapping_sub(earlier) & Self::MASK
    }
}
