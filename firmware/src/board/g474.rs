//! The real board: STM32G474RE (Cortex-M4F, 170 MHz), e.g. on a NUCLEO-G474RE with two
//! torque-mode servo amplifiers and two incremental encoders.
//!
//! Why this part: a Cortex-M4F with single-precision FPU (the servo step is all f32) at
//! 170 MHz, motor-control timers (TIM1/TIM8/TIM20 centre-aligned PWM with dead time and break
//! input, HRTIM at 184 ps resolution), encoder mode on every general-purpose timer, a CORDIC
//! unit for the `atan2`/`sin`/`cos` the kinematics need (not used yet), 512 KiB dual-bank
//! flash (the calibration region sits in bank 2 and can be rewritten without stalling code
//! in bank 1), and good probe-rs and PAC support. The M7 parts are faster but the loop fits
//! in a few percent of a G474 period (see README, "Benchmarks").
//!
//! Pin and peripheral map (**untested on hardware**; it compiles, and follows RM0440 and the
//! STM32G474 datasheet's alternate-function table):
//! * servo tick: TIM6 update interrupt at 2 kHz (85 MHz counter, ARR 42499), `SERVO_TICK`;
//!   software-task dispatchers on the unused UART4/UART5 vectors;
//! * PWM: TIM1 CH1 (PA8, AF6) and CH2 (PA9, AF6), centre-aligned 20 kHz, duty 0..4250, 50 %
//!   = zero torque (`SetDutyCycle`);
//! * encoders: TIM3 (PA6/PA7, AF2) and TIM4 (PB6/PB7, AF2) in encoder mode 3, 16-bit counters
//!   extended to 32 bits in software at every read (at most ±32767 counts between two reads,
//!   i.e. 98 rad/s at 2^22 counts/rev);
//! * drive enable: PB0, active high; the safe state drives it low and disables TIM1's outputs;
//! * clock: HSI16 → PLL (M 4, N 85, R 2) = 170 MHz, range-1 boost mode, 4 flash wait states;
//! * logging: defmt over RTT (probe-rs); no semihosting on the board and no test harness.
//!
//! Encoder angles are relative to the power-on position: a homing or absolute-encoder step that
//! sets `zero_counts` is still to be written (see README, "What is untested").
use core::sync::atomic::{AtomicI32, Ordering};

use controller::drive::{self, DriveError, TorqueDrive};
use controller::encoder::{counts_to_rad, QuadratureEncoder};
use controller::settings::Settings;
use controller::trajectory::Trajectory;
use controller::SAMPLE_RATE_HZ;
use embedded_hal::pwm::{ErrorType, SetDutyCycle};
use stm32g4::stm32g474 as pac;

use super::{Board, ServoTimer};

device! {
    // STM32G4 implements 4 priority bits and 102 external interrupts.
    nvic_prio_bits: 4,
    external_interrupts: 102,
    /// UART4 (52), unused: dispatcher of the priority-1 software tasks.
    DISPATCH_1 = 52,
    /// UART5 (53), unused: dispatcher of the priority-2 software tasks.
    DISPATCH_2 = 53,
    /// TIM6 update (54, `TIM6_DACUNDER`, RM0440 table 97): the 2 kHz servo tick.
    SERVO_TICK = 54,
}

/// Core clock.
pub const SYSCLK_HZ: u32 = 170_000_000;
/// TIM6 counter clock (prescaler 2).
const TICK_TIMER_HZ: u32 = SYSCLK_HZ / 2;
/// Encoder resolution assumed (interpolated quadrature output); set for the motors fitted.
pub const COUNTS_PER_REV: u32 = 1 << 22;
/// TIM1 period: 170 MHz / (2 · 20 kHz), centre-aligned.
pub const PWM_MAX_DUTY: u16 = 4250;

// ---------------------------------------------------------------------------------------------
// Servo timer: TIM6.

/// The 2 kHz servo tick: TIM6 counting up from 0 to `reload` once per period.
pub struct Tim6Timer {
    tim: pac::TIM6,
    reload: u32,
}

impl Tim6Timer {
    fn new(tim: pac::TIM6, rate_hz: u32) -> Self {
        let reload = TICK_TIMER_HZ / rate_hz - 1;
        // SAFETY (all `bits` writes below): values from RM0440 for these registers.
        tim.cr1().write(|w| unsafe { w.bits(1 << 2) }); // URS: only overflow sets UIF
        tim.psc().write(|w| unsafe { w.bits(1) });
        tim.arr().write(|w| unsafe { w.bits(reload) });
        tim.egr().write(|w| unsafe { w.bits(1) }); // UG: load PSC/ARR
        tim.sr().write(|w| unsafe { w.bits(0) });
        tim.dier().write(|w| unsafe { w.bits(1) }); // UIE
        Tim6Timer { tim, reload }
    }
}

impl ServoTimer for Tim6Timer {
    fn start(&mut self) {
        // SAFETY: CEN set, the other CR1 bits kept.
        self.tim.cr1().modify(|r, w| unsafe { w.bits(r.bits() | 1) });
    }

    #[inline]
    fn acknowledge_tick(&mut self) {
        // SAFETY: clearing UIF, the only flag of TIM6's SR.
        self.tim.sr().write(|w| unsafe { w.bits(0) });
    }

    #[inline]
    fn elapsed_us(&self) -> f32 {
        (self.tim.cnt().read().bits() & 0xFFFF) as f32 * (1.0e6 / TICK_TIMER_HZ as f32)
    }

    #[inline]
    fn period_us(&self) -> f32 {
        (self.reload + 1) as f32 * (1.0e6 / TICK_TIMER_HZ as f32)
    }

    #[inline]
    fn next_tick_pending(&self) -> bool {
        self.tim.sr().read().bits() & 1 != 0
    }
}

// ---------------------------------------------------------------------------------------------
// PWM (TIM1) and encoders (TIM3, TIM4).

/// One TIM1 output-compare channel (1 or 2).
pub struct Tim1Pwm {
    channel: u8,
}

impl ErrorType for Tim1Pwm {
    type Error = core::convert::Infallible;
}

impl SetDutyCycle for Tim1Pwm {
    fn max_duty_cycle(&self) -> u16 {
        PWM_MAX_DUTY
    }
    fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
        // SAFETY: TIM1 is only written here and in `Board::init`; CCRx takes any 16-bit value.
        let tim = unsafe { pac::TIM1::steal() };
        let duty = duty.min(PWM_MAX_DUTY) as u32;
        match self.channel {
            1 => tim.ccr1().write(|w| unsafe { w.bits(duty) }),
            _ => tim.ccr2().write(|w| unsafe { w.bits(duty) }),
        };
        Ok(())
    }
}

/// A 16-bit encoder-mode timer extended to 32 bits.
pub struct TimEncoder {
    /// TIM4 if set, else TIM3 (one register-block type serves both).
    tim4: bool,
    last: u16,
    position: AtomicI32,
}

impl TimEncoder {
    fn regs(&self) -> &'static pac::tim3::RegisterBlock {
        // SAFETY: the PAC's register blocks live at fixed addresses for the whole run; this
        // encoder owns its timer.
        unsafe { &*(if self.tim4 { pac::TIM4::ptr() } else { pac::TIM3::ptr() }) }
    }
}

impl QuadratureEncoder for TimEncoder {
    fn position_counts(&mut self) -> i32 {
        let now = (self.regs().cnt().read().bits() & 0xFFFF) as u16;
        let delta = now.wrapping_sub(self.last) as i16 as i32;
        self.last = now;
        let p = self.position.load(Ordering::Relaxed).wrapping_add(delta);
        self.position.store(p, Ordering::Relaxed);
        p
    }
}

fn encoder_timer(tim: &pac::tim3::RegisterBlock) {
    // SAFETY: values from RM0440 (general-purpose timer encoder interface).
    tim.cr1().write(|w| unsafe { w.bits(0) });
    tim.smcr().write(|w| unsafe { w.bits(0b011) }); // SMS: encoder mode 3 (both edges of both inputs)
    tim.ccmr1_input().write(|w| unsafe { w.bits(0b01 | (0b0011 << 4) | (0b01 << 8) | (0b0011 << 12)) }); // TI1, TI2, filter N=8
    tim.ccer().write(|w| unsafe { w.bits(0) });
    tim.arr().write(|w| unsafe { w.bits(0xFFFF) });
    tim.cnt().write(|w| unsafe { w.bits(0) });
    tim.cr1().write(|w| unsafe { w.bits(1) });
}

// ---------------------------------------------------------------------------------------------
// The board.

/// The STM32G474 with its drives and encoders.
pub struct G474Board {
    timer: Tim6Timer,
    encoders: [TimEncoder; 2],
    drives: [TorqueDrive<Tim1Pwm>; 2],
    /// Encoder counts at the machine's zero (set by homing; 0 = power-on position).
    pub zero_counts: [i32; 2],
}

fn set_bits(r: u32, mask: u32, value: u32) -> u32 {
    (r & !mask) | value
}

impl Board for G474Board {
    /// No test harness on the board: the production settings, no built-in tour.
    type Setpoints = Trajectory;
    type Timer = Tim6Timer;

    fn settings() -> Settings {
        Settings::default()
    }

    /// Clocks, pins and timers; drives disabled, zero torque commanded.
    fn init(settings: &'static Settings) -> Self {
        let drive_full_scale_nm = settings.drive_full_scale_nm;
        // SAFETY: RTIC runs with `peripherals = false`; this is the only owner of the PAC.
        let dp = unsafe { pac::Peripherals::steal() };
        let (rcc, pwr, flash) = (&dp.RCC, &dp.PWR, &dp.FLASH);
        // SAFETY (all `bits` writes below): values from RM0440 for these registers.
        unsafe {
            // 170 MHz: PWR clock, range-1 boost, 4 wait states, PLL from HSI16.
            rcc.apb1enr1().modify(|r, w| w.bits(r.bits() | (1 << 28)));
            pwr.cr5().modify(|r, w| w.bits(r.bits() & !(1 << 8)));
            flash.acr().modify(|r, w| w.bits(set_bits(r.bits(), 0xF, 4) | (1 << 8) | (1 << 9) | (1 << 10)));
            while flash.acr().read().bits() & 0xF != 4 {}
            rcc.cr().modify(|r, w| w.bits(r.bits() | (1 << 8)));
            while rcc.cr().read().bits() & (1 << 10) == 0 {}
            rcc.pllcfgr().write(|w| w.bits(2 | (3 << 4) | (85 << 8) | (1 << 24)));
            rcc.cr().modify(|r, w| w.bits(r.bits() | (1 << 24)));
            while rcc.cr().read().bits() & (1 << 25) == 0 {}
            // AHB /2 across the switch (RM0440 6.1.5), then /1.
            rcc.cfgr().modify(|r, w| w.bits(set_bits(r.bits(), 0xF0, 0b1000 << 4)));
            rcc.cfgr().modify(|r, w| w.bits(set_bits(r.bits(), 0b11, 0b11)));
            while (rcc.cfgr().read().bits() >> 2) & 0b11 != 0b11 {}
            cortex_m::asm::delay(200);
            rcc.cfgr().modify(|r, w| w.bits(set_bits(r.bits(), 0xF0, 0)));

            // Clocks of GPIOA/B, TIM1, TIM3, TIM4, TIM6.
            rcc.ahb2enr().modify(|r, w| w.bits(r.bits() | 0b11));
            rcc.apb2enr().modify(|r, w| w.bits(r.bits() | (1 << 11)));
            rcc.apb1enr1().modify(|r, w| w.bits(r.bits() | (1 << 1) | (1 << 2) | (1 << 4)));

            // PB0 drive enable: output, low first.
            let (ga, gb) = (&dp.GPIOA, &dp.GPIOB);
            gb.bsrr().write(|w| w.bits(1 << 16));
            gb.moder().modify(|r, w| w.bits(set_bits(r.bits(), 0b11, 0b01)));
            // PA6/PA7 AF2 (TIM3), PA8/PA9 AF6 (TIM1), PB6/PB7 AF2 (TIM4).
            ga.afrl().modify(|r, w| w.bits(set_bits(r.bits(), 0xFF << 24, 0x22 << 24)));
            ga.afrh().modify(|r, w| w.bits(set_bits(r.bits(), 0xFF, 0x66)));
            ga.moder().modify(|r, w| w.bits(set_bits(r.bits(), 0xFF << 12, 0b1010_1010 << 12)));
            gb.afrl().modify(|r, w| w.bits(set_bits(r.bits(), 0xFF << 24, 0x22 << 24)));
            gb.moder().modify(|r, w| w.bits(set_bits(r.bits(), 0xF << 12, 0b1010 << 12)));

            // TIM1: centre-aligned 20 kHz PWM on CH1/CH2 at 50 % (zero torque), outputs on.
            let t1 = &dp.TIM1;
            t1.psc().write(|w| w.bits(0));
            t1.arr().write(|w| w.bits(PWM_MAX_DUTY as u32));
            t1.ccr1().write(|w| w.bits(PWM_MAX_DUTY as u32 / 2));
            t1.ccr2().write(|w| w.bits(PWM_MAX_DUTY as u32 / 2));
            t1.ccmr1_output().write(|w| w.bits((0b110 << 4) | (1 << 3) | (0b110 << 12) | (1 << 11)));
            t1.ccer().write(|w| w.bits(1 | (1 << 4)));
            t1.cr1().write(|w| w.bits((0b01 << 5) | (1 << 7)));
            t1.egr().write(|w| w.bits(1));
            t1.bdtr().modify(|r, w| w.bits(r.bits() | (1 << 15)));
            t1.cr1().modify(|r, w| w.bits(r.bits() | 1));
        }
        encoder_timer(&dp.TIM3);
        encoder_timer(&dp.TIM4);

        let timer = Tim6Timer::new(dp.TIM6, SAMPLE_RATE_HZ);
        let mut board = G474Board {
            timer,
            encoders: [
                TimEncoder { tim4: false, last: 0, position: AtomicI32::new(0) },
                TimEncoder { tim4: true, last: 0, position: AtomicI32::new(0) },
            ],
            drives: [
                TorqueDrive { pwm: Tim1Pwm { channel: 1 }, full_scale_nm: drive_full_scale_nm },
                TorqueDrive { pwm: Tim1Pwm { channel: 2 }, full_scale_nm: drive_full_scale_nm },
            ],
            zero_counts: [0; 2],
        };
        board.disable_drives();
        board
    }

    fn setpoints(&mut self, trajectory: Trajectory) -> Trajectory {
        trajectory
    }

    #[inline]
    fn encoders_rad(&mut self) -> [f32; 2] {
        let a = self.encoders[0].position_counts().wrapping_sub(self.zero_counts[0]);
        let b = self.encoders[1].position_counts().wrapping_sub(self.zero_counts[1]);
        [counts_to_rad(a, COUNTS_PER_REV), counts_to_rad(b, COUNTS_PER_REV)]
    }

    #[inline]
    fn set_torques_nm(&mut self, torque_nm: [f32; 2]) -> Result<[f32; 2], DriveError> {
        drive::set_torques_nm(&mut self.drives, torque_nm)
    }

    fn enable_drives(&mut self) {
        // SAFETY: PB0 is the drive-enable line, owned by the board.
        unsafe { pac::GPIOB::steal().bsrr().write(|w| w.bits(1)) };
    }

    /// Safe state: drive-enable low, then zero torque commanded.
    fn disable_drives(&mut self) {
        safe_state();
        let _ = self.set_torques_nm([0.0; 2]);
    }

    #[inline]
    fn timer(&mut self) -> &mut Tim6Timer {
        &mut self.timer
    }

    /// Sleep until the next interrupt.
    #[inline]
    fn idle_wait() {
        cortex_m::asm::wfi();
    }
}

/// Drive-enable low; usable from fault handlers.
fn safe_state() {
    // SAFETY: a write to PB0's reset bit only.
    unsafe { pac::GPIOB::steal().bsrr().write(|w| w.bits(1 << 16)) };
}

/// Console lines go to defmt (RTT).
pub fn console(line: &str) {
    defmt::println!("{=str}", line);
}

/// End of a benchmark run: report over semihosting when a debugger (probe-rs) is attached,
/// otherwise stop here with the drives off.
pub fn exit(pass: bool) -> ! {
    safe_state();
    defmt::println!("exit: {}", if pass { "pass" } else { "fail" });
    if cortex_m::peripheral::DCB::is_debugger_attached() {
        let status = if pass { cortex_m_semihosting::debug::EXIT_SUCCESS } else { cortex_m_semihosting::debug::EXIT_FAILURE };
        cortex_m_semihosting::debug::exit(status);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    safe_state();
    defmt::error!("HardFault: drives disabled");
    loop {
        cortex_m::asm::wfi();
    }
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    safe_state();
    defmt::error!("unexpected interrupt {}: drives disabled", irqn);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    safe_state();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    loop {
        cortex_m::asm::wfi();
    }
}

/// What the benchmark counter's figures are.
pub const COUNT_UNIT: &str = "cycles";

/// DWT cycle counter (core cycles at 170 MHz).
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
