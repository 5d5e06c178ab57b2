//! The real board: STM32G474RE (Cortex-M4F, 170 MHz), e.g. on a NUCLEO-G474RE with two
//! torque-mode servo amplifiers and two incremental encoders.
//!
//! Why this part: a Cortex-M4F with single-precision FPU (the servo step is all f32) at
//! 170 MHz, motor-control timers (TIM1/TIM8/TIM20 centre-aligned PWM with dead time and break
//! input, HRTIM at 184 ps resolution), encoder mode on every general-purpose timer, a CORDIC
//! unit for the `atan2`/`sin`/`cos` the kinematics need (not used yet), 512 KiB dual-bank
//! flash (the calibration region sits in bank 2 and can be rewritten without stalling code
//! in bank 1), and good probe-rs support. The M7 parts are faster but the loop fits in a few
//! percent of a G474 period (see docs/validation/benchmarks.md).
//!
//! **Every register this board sets is in the `g474-plan` crate** (`firmware/g474-plan/`): the
//! boot, the drive enable, the safe state and the watchdog are lists of (register, value, why)
//! that `cargo test` checks against RM0440 on the host; this file applies them
//! ([`Mmio`]) and keeps the per-sample accesses (duty, encoder counters, tick, feed).
//! Pin map and why the drive enable is a TIM1 output: `g474_plan::plan`'s doc. In short:
//! * servo tick: TIM6 update interrupt at 2 kHz (85 MHz counter, ARR 42499), `SERVO_TICK`;
//!   software-task dispatchers on the unused UART4/UART5 vectors;
//! * PWM: TIM1 CH1 (PA8) and CH2 (PA9), centre-aligned 20 kHz, duty 0..4250, 50 % = zero
//!   torque (`SetDutyCycle`; a write reports an error when TIM1's outputs are off);
//! * drive enable: PA10 = TIM1 CH3 forced active, high only while TIM1's main output enable
//!   (MOE) is set; external pull-down;
//! * safe-torque-off: PB12 = TIM1_BKIN, active low, clears MOE in hardware;
//! * encoders: TIM3 (PA6/PA7) and TIM4 (PB6/PB7) in encoder mode 3, 16-bit counters extended
//!   to 32 bits at every read (at most ±32767 counts between two reads, i.e. 98 rad/s at
//!   2^22 counts/rev), scaled per axis by `Settings::encoders`;
//! * watchdog: IWDG, 3 ms, fed by on-time servo steps; a reset's cause is read from RCC_CSR;
//! * host link: LPUART1 on PA2 (TX) / PA3 (RX), AF12, the NUCLEO-G474RE's ST-LINK virtual COM
//!   port, 115 200 Bd 8N1, receive interrupt `LINK_RX` (IRQ 91) into the link task
//!   ([`Lpuart1Link`]);
//! * clock: HSI16 → PLL (M 4, N 85, R 2) = 170 MHz, range-1 boost, 4 wait states, prefetch
//!   and caches; a PLL that does not lock stops the boot in the safe state;
//! * logging: defmt over RTT, non-blocking (feature `disable-blocking-mode`, see the bring-up
//!   guide); no semihosting on the board and no test harness.
//!
//! **Untested on hardware**: it compiles, and its register plan is host-tested against RM0440
//! and DS12288. Encoder angles are relative to the power-on position until homing (a later
//! issue) calls `EncoderScale::set_reference`.
use core::sync::atomic::{AtomicI32, Ordering};

use controller::drive::{self, DriveError, TorqueDrive};
use controller::encoder::{EncoderScale, QuadratureEncoder};
use controller::settings::Settings;
use controller::watchdog::{ResetCause, WatchdogFault};
use controller::waypoint_moves::Trajectory;
use embedded_hal::pwm::{ErrorKind, ErrorType, SetDutyCycle};
use g474_plan::map::{base, iwdg, rcc, tim1, timx};
use g474_plan::{plan, Bus, Register, Step};

use super::{Board, ServoTimer};

pub use g474_plan::plan::{PWM_MAX_DUTY, SYSCLK_HZ};

device! {
    // STM32G4 implements 4 priority bits and 102 external interrupts.
    nvic_prio_bits: 4,
    external_interrupts: 102,
    /// UART4 (52), unused: dispatcher of the priority-1 software tasks.
    DISPATCH_1 = 52,
    /// UART5 (53), unused: dispatcher of the priority-2 software tasks.
    DISPATCH_2 = 53,
    /// TIM6 update (54, `TIM6_DACUNDER`, RM0440 vector table): the 2 kHz servo tick.
    SERVO_TICK = 54,
    /// LPUART1 (91, RM0440 vector table; the `stm32g4` PAC's `Interrupt::LPUART`): the host
    /// link's receive interrupt (a byte in the RX FIFO, or an overrun).
    LINK_RX = 91,
}

// ---------------------------------------------------------------------------------------------
// Register access: the plans and the per-sample registers.

/// Volatile access to the STM32G474's registers, for `g474_plan::apply`.
pub struct Mmio;

impl Bus for Mmio {
    #[inline]
    fn read(&mut self, address: u32) -> u32 {
        // SAFETY: the plans name registers of RM0440's memory map only (host-tested); a
        // register read has no effect beyond the ones the plans intend.
        unsafe { core::ptr::read_volatile(address as *const u32) }
    }
    #[inline]
    fn write(&mut self, address: u32, value: u32) {
        // SAFETY: as in `read`; the values are RM0440's for those registers.
        unsafe { core::ptr::write_volatile(address as *mut u32, value) }
    }
    fn delay(&mut self, cycles: u32) {
        cortex_m::asm::delay(cycles);
    }
}

#[inline]
fn read(register: Register) -> u32 {
    Mmio.read(register.address)
}
#[inline]
fn write(register: Register, value: u32) {
    Mmio.write(register.address, value)
}

/// Applies a plan to the registers.
fn apply(p: &'static [Step]) -> Result<(), &'static Step> {
    g474_plan::apply(p, &mut Mmio)
}

/// The safe state from any context, fault handlers included (registers only, no waits, cannot
/// fail): duty to zero torque, TIM1's outputs off (MOE), the enable line a GPIO driven low.
pub fn safe_state() {
    let _ = apply(&plan::SAFE_STATE);
}

// ---------------------------------------------------------------------------------------------
// Servo timer: TIM6.

const TIM6_CR1: Register = timx::cr1("TIM6", base::TIM6);
const TIM6_SR: Register = timx::sr("TIM6", base::TIM6);
const TIM6_CNT: Register = timx::cnt("TIM6", base::TIM6);

/// The 2 kHz servo tick: TIM6 counting up from 0 to `TIM6_ARR` once per period (configured by
/// `plan::TICK_TIMER`).
pub struct Tim6Timer(());

impl ServoTimer for Tim6Timer {
    fn start(&mut self) {
        write(TIM6_CR1, read(TIM6_CR1) | 1);
    }

    #[inline]
    fn acknowledge_tick(&mut self) {
        write(TIM6_SR, 0);
    }

    #[inline]
    fn elapsed_us(&self) -> f32 {
        (read(TIM6_CNT) & 0xFFFF) as f32 * (1.0e6 / plan::TICK_TIMER_HZ as f32)
    }

    #[inline]
    fn period_us(&self) -> f32 {
        (plan::TIM6_ARR + 1) as f32 * (1.0e6 / plan::TICK_TIMER_HZ as f32)
    }

    #[inline]
    fn next_tick_pending(&self) -> bool {
        read(TIM6_SR) & 1 != 0
    }
}

// ---------------------------------------------------------------------------------------------
// PWM (TIM1) and encoders (TIM3, TIM4).

/// One TIM1 output-compare channel (1 or 2).
pub struct Tim1Pwm {
    channel: u8,
}

/// TIM1's main output enable is off while the drives should be on: the break input (the
/// external safe-torque-off) cleared it, or the outputs were never enabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputsOff;

impl embedded_hal::pwm::Error for OutputsOff {
    fn kind(&self) -> ErrorKind {
        ErrorKind::Other
    }
}

impl ErrorType for Tim1Pwm {
    type Error = OutputsOff;
}

impl SetDutyCycle for Tim1Pwm {
    fn max_duty_cycle(&self) -> u16 {
        PWM_MAX_DUTY
    }
    /// Writes the duty, then reports whether it can act: an error when MOE is off (the servo
    /// loop latches it as `Fault::Drive` while running).
    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), OutputsOff> {
        let duty = duty.min(PWM_MAX_DUTY) as u32;
        write(
            if self.channel == 1 {
                tim1::CCR1
            } else {
                tim1::CCR2
            },
            duty,
        );
        if read(tim1::BDTR) & tim1::BDTR_MOE == 0 {
            return Err(OutputsOff);
        }
        Ok(())
    }
}

/// A 16-bit encoder-mode timer extended to 32 bits, with channel 4 capturing the counter at
/// the encoder's index pulse (homing; `g474_plan::plan::INDEX_CCMR2`).
pub struct TimEncoder {
    cnt: Register,
    sr: Register,
    ccr4: Register,
    last: u16,
    position: AtomicI32,
    /// The extended count at the first index pulse captured.
    index: Option<i32>,
    /// `index` not handed to homing yet.
    index_new: bool,
}

impl QuadratureEncoder for TimEncoder {
    fn position_counts(&mut self) -> i32 {
        let now = (read(self.cnt) & 0xFFFF) as u16;
        let delta = now.wrapping_sub(self.last) as i16 as i32;
        self.last = now;
        let p = self.position.load(Ordering::Relaxed).wrapping_add(delta);
        self.position.store(p, Ordering::Relaxed);
        // An index captured since the last reading: its extended count is this reading minus
        // the counts since the capture (less than one sample's, far within 16 bits).
        if self.index.is_none() && read(self.sr) & plan::SR_CC4IF != 0 {
            let captured = (read(self.ccr4) & 0xFFFF) as u16;
            self.index = Some(p.wrapping_sub(now.wrapping_sub(captured) as i16 as i32));
            self.index_new = true;
            // rc_w0: writing 0 clears CC4IF, 1 leaves the other flags alone.
            write(self.sr, !plan::SR_CC4IF);
        }
        p
    }
}

// ---------------------------------------------------------------------------------------------
// The board.

/// The STM32G474 with its drives and encoders.
pub struct G474Board {
    timer: Tim6Timer,
    encoders: [TimEncoder; 2],
    /// Counts to joint angle per axis (`Settings::encoders`); homing calls
    /// `encoder_scales[k].set_reference(counts, joint_rad)`.
    encoder_scales: [EncoderScale; 2],
    drives: [TorqueDrive<Tim1Pwm>; 2],
}

/// A boot plan's wait timed out (the clock did not start): the safe state, a log line, and a
/// halt with the drive-enable line driven low (the watchdog is not running yet).
fn boot_failed(step: &'static Step) -> ! {
    safe_state();
    defmt::error!(
        "boot: {=str} {=str} not ready ({=str}): drives stay disabled, halted",
        step.register.peripheral,
        step.register.name,
        step.why
    );
    loop {
        cortex_m::asm::wfi();
    }
}

/// The host link's port on the STM32G474: LPUART1 on PA2/PA3 at 115 200 Bd, the
/// NUCLEO-G474RE's ST-LINK virtual COM port (`g474_plan::plan::HOST_LINK`; the byte logic,
/// host-tested, is `g474_plan::link_uart`). Only the link task (priority 1) uses it.
pub struct Lpuart1Link {
    uart: g474_plan::link_uart::LinkUart,
    /// The counters last logged.
    logged: g474_plan::link_uart::LinkUartCounts,
}

impl crate::link::LinkPort for Lpuart1Link {
    fn read_byte(&mut self) -> Option<u8> {
        let byte = self.uart.read_byte(&mut Mmio);
        if byte.is_none() {
            self.log_counts();
        }
        byte
    }
    fn write(&mut self, bytes: &[u8]) {
        self.uart.write(&mut Mmio, bytes);
    }
}

impl Lpuart1Link {
    /// Logs the error counters when they changed (once the port is drained, so a burst of
    /// errors makes one line).
    fn log_counts(&mut self) {
        let c = self.uart.counts();
        if c != self.logged {
            defmt::warn!(
                "host link: {} overruns, {} line errors, {} bytes dropped in, {} out (the frames they hit are rejected)",
                c.overruns, c.line_errors, c.rx_dropped, c.tx_dropped
            );
            self.logged = c;
        }
    }
}

impl Board for G474Board {
    /// No test harness on the board: the production settings, no built-in tour.
    type Setpoints = Trajectory;
    type Timer = Tim6Timer;
    type Link = Lpuart1Link;

    /// `plan::HOST_LINK`: LPUART1 at 115 200 Bd, its receive interrupt on (RTIC unmasks
    /// `LINK_RX` in the NVIC). An LPUART that does not come up is logged and leaves the board
    /// without a link (and its pins untouched); the machine itself is not affected.
    fn link(&mut self) -> Lpuart1Link {
        match apply(&plan::HOST_LINK) {
            Ok(()) => defmt::info!(
                "host link: LPUART1 (PA2 TX, PA3 RX, ST-LINK VCP), {=u32} Bd 8N1",
                plan::LINK_BAUD
            ),
            Err(step) => defmt::error!(
                "host link: LPUART1 {=str} not ready ({=str}): no link",
                step.register.name,
                step.why
            ),
        }
        let uart = g474_plan::link_uart::LinkUart::new();
        Lpuart1Link {
            logged: uart.counts(),
            uart,
        }
    }

    /// The production settings, the motion from the host link (`link_motion`): the board
    /// holds still until the host commands a move or a stream.
    fn settings() -> Settings {
        Settings {
            link_motion: true,
            ..Settings::default()
        }
    }

    /// The boot plans (`g474_plan::plan::BOOT`): enable line low, 170 MHz, debug freeze and
    /// power, TIM1 (outputs off), encoders, TIM6, pins.
    fn init(settings: &'static Settings) -> Self {
        for p in plan::BOOT {
            if let Err(step) = apply(p) {
                boot_failed(step);
            }
        }
        let encoder_scales = super::encoder_scales(settings);
        let full_scale_nm = settings.drive_full_scale_nm;
        let encoder = |tim, base| TimEncoder {
            cnt: timx::cnt(tim, base),
            sr: timx::sr(tim, base),
            ccr4: timx::ccr4(tim, base),
            last: 0,
            position: AtomicI32::new(0),
            index: None,
            index_new: false,
        };
        let mut board = G474Board {
            timer: Tim6Timer(()),
            encoders: [encoder("TIM3", base::TIM3), encoder("TIM4", base::TIM4)],
            encoder_scales,
            drives: [
                TorqueDrive {
                    pwm: Tim1Pwm { channel: 1 },
                    full_scale_nm,
                },
                TorqueDrive {
                    pwm: Tim1Pwm { channel: 2 },
                    full_scale_nm,
                },
            ],
        };
        board.disable_drives();
        board
    }

    fn setpoints(&mut self, trajectory: Trajectory) -> Trajectory {
        trajectory
    }

    #[inline]
    fn encoders_rad(&mut self) -> [f32; 2] {
        [
            self.encoder_scales[0].joint_rad(self.encoders[0].position_counts()),
            self.encoder_scales[1].joint_rad(self.encoders[1].position_counts()),
        ]
    }

    /// The index captures of TIM3/TIM4 channel 4 (read with the encoders in `encoders_rad`).
    fn index_rad(&mut self) -> [Option<f32>; 2] {
        [0, 1].map(|k| {
            let e = &mut self.encoders[k];
            let new = core::mem::take(&mut e.index_new);
            e.index
                .filter(|_| new)
                .map(|c| self.encoder_scales[k].joint_rad(c))
        })
    }

    fn reference_at_index(&mut self, index_rad: [f32; 2]) -> bool {
        let counts = [self.encoders[0].index, self.encoders[1].index];
        super::reference_scales(&mut self.encoder_scales, counts, index_rad)
    }

    #[inline]
    fn set_torques_nm(&mut self, torque_nm: [f32; 2]) -> Result<[f32; 2], DriveError> {
        drive::set_torques_nm(&mut self.drives, torque_nm)
    }

    /// PA10 to TIM1_CH3, then MOE (`plan::ENABLE_OUTPUTS`); an active break keeps MOE off.
    fn enable_drives(&mut self) {
        let _ = apply(&plan::ENABLE_OUTPUTS);
    }

    /// Zero torque, MOE off, enable line driven low (`plan::SAFE_STATE`).
    fn disable_drives(&mut self) {
        safe_state();
    }

    /// RCC_CSR's reset flags, then cleared (RMVF).
    fn reset_cause(&mut self) -> ResetCause {
        let csr = read(rcc::CSR);
        let _ = apply(&plan::CLEAR_RESET_FLAGS);
        g474_plan::reset::reset_cause(csr)
    }

    /// `plan::START_WATCHDOG`: IWDG at 3 ms (2.82 to 3.25 ms over the LSI's range).
    fn start_watchdog(&mut self) -> Result<(), WatchdogFault> {
        apply(&plan::START_WATCHDOG)
            .map(|_| ())
            .map_err(|_| WatchdogFault::NotStarted)
    }

    #[inline]
    fn feed_watchdog(&mut self) {
        write(iwdg::KR, iwdg::KEY_RELOAD);
    }

    #[inline]
    fn timer(&mut self) -> &mut Tim6Timer {
        &mut self.timer
    }

    /// Sleep until the next interrupt (DBGMCU's DBG_SLEEP keeps the debug link up).
    #[inline]
    fn idle_wait() {
        cortex_m::asm::wfi();
    }
}

/// Console lines go to defmt (RTT).
pub fn console(line: &str) {
    defmt::println!("{=str}", line);
}

/// For the benchmark (no `Board`, no RTIC): the enable line low and the clock the app runs at
/// (170 MHz, 4 wait states, prefetch and caches), so the cycle counts are the servo's. A clock
/// that does not start ends the benchmark.
pub fn bench_init() {
    for p in [&plan::SAFE_OUTPUTS[..], &plan::CLOCK[..]] {
        if let Err(step) = apply(p) {
            defmt::println!(
                "FAIL clock: {=str} {=str} not ready ({=str})",
                step.register.peripheral,
                step.register.name,
                step.why
            );
            exit(false);
        }
    }
    console("# core clock 170 MHz (PLL from HSI16, range-1 boost), flash 4 wait states, prefetch and I/D caches on");
}

/// End of a benchmark run: report over semihosting when a debugger (probe-rs) is attached,
/// otherwise stop here with the drives off.
pub fn exit(pass: bool) -> ! {
    safe_state();
    defmt::println!("exit: {}", if pass { "pass" } else { "fail" });
    if cortex_m::peripheral::DCB::is_debugger_attached() {
        let status = if pass {
            cortex_m_semihosting::debug::EXIT_SUCCESS
        } else {
            cortex_m_semihosting::debug::EXIT_FAILURE
        };
        cortex_m_semihosting::debug::exit(status);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

/// What every failure path does first: no more interrupts (nothing may run on top), then the
/// safe state. The loop after it is not fed: the watchdog resets the chip 3 ms later, and the
/// boot after it keeps the drives off (unless a debugger halted the core, which also freezes
/// TIM1 and the watchdog).
fn fail_safe() {
    cortex_m::interrupt::disable();
    safe_state();
}

hard_fault_on_fresh_stack!(hard_fault);

/// The HardFault handler, on a fresh stack (`hard_fault_on_fresh_stack!`); `faulting_sp` is
/// the stack pointer the fault was taken with. Below the stack it was a stack overflow (flip-link
/// puts the stack at the bottom of RAM: the exception frame could not be stacked); otherwise the
/// stacked PC says where.
unsafe extern "C" fn hard_fault(faulting_sp: u32) -> ! {
    fail_safe();
    let stack_bottom = core::ptr::addr_of!(_stack_end) as u32;
    let stack_top = core::ptr::addr_of!(_stack_start) as u32;
    if (stack_bottom..stack_top.saturating_sub(32)).contains(&faulting_sp) {
        // SAFETY: the exception frame (8 words) lies within the stack region; word 6 is the PC.
        let pc = unsafe { core::ptr::read_volatile((faulting_sp as *const u32).add(6)) };
        defmt::error!("HardFault at pc {=u32:#x}: drives disabled", pc);
    } else {
        defmt::error!(
            "HardFault: stack overflow (sp {=u32:#x}): drives disabled",
            faulting_sp
        );
    }
    loop {
        cortex_m::asm::wfi();
    }
}

extern "C" {
    /// Top of the stack (cortex-m-rt's link.x; flip-link moves it to the bottom of RAM).
    static _stack_start: u32;
    /// Lowest address the stack may use.
    static _stack_end: u32;
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    fail_safe();
    defmt::error!("unexpected interrupt {}: drives disabled", irqn);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    fail_safe();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    loop {
        cortex_m::asm::wfi();
    }
}

/// What the benchmark counter's figures are.
pub const COUNT_UNIT: &str = "cycles";

/// DWT cycle counter (core cycles; 170 MHz once `bench_init` set the clock).
pub struct CycleCounter {
    _dwt: cortex_m::peripheral::DWT,
}

impl CycleCounter {
    /// Starts the counter (takes the core peripherals it needs).
    pub fn new(core: cortex_m::Peripherals) -> Self {
        let (mut dcb, mut dwt) = (core.DCB, core.DWT);
        dcb.enable_trace();
        dwt.enable_cycle_counter();
        CycleCounter { _dwt: dwt }
    }

    /// Cycles since an arbitrary origin (wraps at 2^32).
    #[inline(always)]
    pub fn now(&self) -> u32 {
        cortex_m::peripheral::DWT::cycle_count()
    }

    /// Cycles since `earlier`.
    #[inline(always)]
    pub fn since(&self, earlier: u32) -> u32 {
        self.now().wrapping_sub(earlier)
    }
}
