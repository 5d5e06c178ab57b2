//! The QEMU board: MPS2-AN386 (Cortex-M4F) under `qemu-system-arm -M mps2-an386`, with the
//! machine simulated inside the firmware and the test harness hooked in.
//!
//! * Servo tick: CMSDK APB TIMER0 (IRQ 8, 25 MHz), reload for 2 kHz.
//! * [`watchdog`]: the CMSDK APB watchdog, fed by on-time servo steps; its NMI removes torque.
//! * [`hardware`]: the "registers" between the firmware and the plant (PWM duty per axis, the
//!   drive-enable line, the encoder counters, the reset-cause flag), atomics.
//! * [`plant`]: the five-bar linkage's rigid-body dynamics on two rotors ([`machine`]'s
//!   numbers), with friction and the drives' dynamic braking, advanced in
//!   [`Board::begin_sample`]; the harness reads its true state.
//! * [`across_reset`]: the plant's state kept across a reset of the controller (the machine
//!   does not stop with it).
//! * [`harness`]: the test harness (scenario from the command line, self-tests at boot,
//!   setpoint and deadline fault injection, the stalled servo task, the checks at the end of
//!   every sample and at the watchdog's interrupt that end the run with PASS or FAIL; its own
//!   clock on TIMER1). Only this board has it.
//! * [`uart`]: the host link's port (CMSDK UART0 on QEMU's first `-serial`).
//! * [`semihosting`]: command line, console, exit code, defmt to a host file, and the
//!   HardFault / unexpected interrupt / panic handlers (print `FAIL ...`, exit 1).
//! * [`cosim`]: co-simulation (`firmware cosim`): host-sim's plant instead of [`plant`], the
//!   host link inside the per-sample exchange, no harness.
use controller::drive::{self, DriveError, TorqueDrive};
use controller::encoder::{EncoderScale, QuadratureEncoder};
use controller::homing::HomingSettings;
use controller::settings::Settings;
use controller::status::Status;
use controller::watchdog::{ResetCause, WatchdogFault};
use controller::waypoint_moves::{Trajectory, WORKSPACE_TOUR_MM};
use controller::SAMPLE_RATE_HZ;

use super::{Board, ServoTimer};

pub mod across_reset;
pub mod cosim;
pub mod hardware;
pub mod harness;
/// The simulated machine's true dynamic parameters and the calibration image's (shared with
/// `build.rs`).
pub mod machine;
pub mod plant;
pub mod semihosting;
pub mod uart;
pub mod watchdog;

pub use semihosting::{console, exit};

use hardware::{SimEncoder, SimPwm};
use harness::{Harness, Injected};
use plant::Plant;

device! {
    // The AN386's Cortex-M4 implements 3 priority bits and 32 external interrupts.
    nvic_prio_bits: 3,
    external_interrupts: 32,
    /// UART0 RX (IRQ 0): the host link's receive interrupt ([`uart`]).
    LINK_RX = 0,
    /// UART2 RX (IRQ 4), unused by the board: dispatcher of the priority-1 software tasks.
    DISPATCH_1 = 4,
    /// UART2 TX (IRQ 5), unused by the board: dispatcher of the priority-2 software tasks.
    DISPATCH_2 = 5,
    /// CMSDK TIMER0 (IRQ 8): the 2 kHz servo tick.
    SERVO_TICK = 8,
}

/// Core clock and timer clock of the AN386 (QEMU's SYSCLK).
pub const TIMER_CLOCK_HZ: u32 = 25_000_000;
/// Encoder resolution of the simulated motors (the simulated hardware; the firmware reads them
/// through `Settings::encoders`, whose default is the same).
pub const COUNTS_PER_REV: u32 = 1 << 22;
/// `nop`s per idle loop iteration ([`QemuBoard::idle_wait`]).
const IDLE_UNROLL: u32 = 64;
/// PWM full-scale duty (the G474's 20 kHz centre-aligned TIM1 period at 170 MHz; even, so that
/// 50 % and thus zero torque is exact).
pub const PWM_MAX_DUTY: u16 = 4250;

// ---------------------------------------------------------------------------------------------
// CMSDK APB timers: TIMER0 is the servo tick, TIMER1 the harness's free-running clock.

const TIMER0_BASE: usize = 0x4000_0000;
const TIMER1_BASE: usize = 0x4000_1000;
const TIMER_CTRL: usize = 0x00;
const TIMER_VALUE: usize = 0x04;
const TIMER_RELOAD: usize = 0x08;
const TIMER_INT: usize = 0x0C; // INTSTATUS on read, INTCLEAR on write
const CTRL_ENABLE: u32 = 1 << 0;
const CTRL_IRQ_ENABLE: u32 = 1 << 3;

fn cmsdk_timer_read(base: usize, offset: usize) -> u32 {
    // SAFETY: a CMSDK timer register of the AN386 memory map.
    unsafe { core::ptr::read_volatile((base + offset) as *const u32) }
}
fn cmsdk_timer_write(base: usize, offset: usize, value: u32) {
    // SAFETY: a CMSDK timer register of the AN386 memory map; TIMER0 is owned by the servo
    // timer, TIMER1 by the harness's clock.
    unsafe { core::ptr::write_volatile((base + offset) as *mut u32, value) }
}
fn timer_read(offset: usize) -> u32 {
    cmsdk_timer_read(TIMER0_BASE, offset)
}
fn timer_write(offset: usize, value: u32) {
    cmsdk_timer_write(TIMER0_BASE, offset, value)
}

/// TIMER1 counting down from 2^32 - 1 at 25 MHz, no interrupt: a clock independent of the
/// servo timer and the watchdog (wraps after 171 s).
pub mod clock {
    use super::{cmsdk_timer_read, cmsdk_timer_write, CTRL_ENABLE, TIMER1_BASE, TIMER_CLOCK_HZ};
    use super::{TIMER_CTRL, TIMER_RELOAD, TIMER_VALUE};

    /// Starts the clock at 0.
    pub fn start() {
        cmsdk_timer_write(TIMER1_BASE, TIMER_CTRL, 0);
        cmsdk_timer_write(TIMER1_BASE, TIMER_RELOAD, u32::MAX);
        cmsdk_timer_write(TIMER1_BASE, TIMER_VALUE, u32::MAX);
        cmsdk_timer_write(TIMER1_BASE, TIMER_CTRL, CTRL_ENABLE);
    }

    /// Ticks (25 MHz) since [`start`].
    #[inline]
    pub fn now_ticks() -> u32 {
        u32::MAX - cmsdk_timer_read(TIMER1_BASE, TIMER_VALUE)
    }

    /// Microseconds of a tick count.
    pub fn ticks_to_us(ticks: u32) -> f32 {
        ticks as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32)
    }
}

/// The 2 kHz servo tick. The timer counts down from `reload` to 0 once per period.
pub struct CmsdkTimer {
    reload: u32,
}

impl CmsdkTimer {
    fn new(rate_hz: u32) -> Self {
        let reload = TIMER_CLOCK_HZ / rate_hz - 1;
        timer_write(TIMER_CTRL, 0);
        timer_write(TIMER_RELOAD, reload);
        timer_write(TIMER_VALUE, reload);
        timer_write(TIMER_INT, 1);
        CmsdkTimer { reload }
    }

    /// Busy-waits until `us` after the current period started (deadline fault injection).
    pub fn burn_until_us(&self, us: f32) {
        while !self.next_tick_pending() && self.elapsed_us() < us {}
        // Past the period end the counter restarted: keep burning in the next period.
        if self.next_tick_pending() {
            let rest = us - self.period_us();
            while self.elapsed_us() < rest {}
        }
    }
}

impl ServoTimer for CmsdkTimer {
    fn start(&mut self) {
        timer_write(TIMER_CTRL, CTRL_ENABLE | CTRL_IRQ_ENABLE);
    }

    #[inline]
    fn acknowledge_tick(&mut self) {
        timer_write(TIMER_INT, 1);
    }

    #[inline]
    fn elapsed_us(&self) -> f32 {
        let ticks = self.reload.saturating_sub(timer_read(TIMER_VALUE));
        ticks as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32)
    }

    #[inline]
    fn period_us(&self) -> f32 {
        (self.reload + 1) as f32 * (1.0e6 / TIMER_CLOCK_HZ as f32)
    }

    #[inline]
    fn next_tick_pending(&self) -> bool {
        timer_read(TIMER_INT) & 1 != 0
    }
}

// ---------------------------------------------------------------------------------------------
// The board.

/// The MPS2-AN386 with its simulated machine and the test harness.
pub struct QemuBoard {
    timer: CmsdkTimer,
    encoders: [SimEncoder; 2],
    encoder_scales: [EncoderScale; 2],
    drives: [TorqueDrive<SimPwm>; 2],
    plant: Plant,
    period_s: f32,
    harness: Harness,
    /// Co-simulation: the exchange with host-sim's plant replaces `plant` and `harness`.
    cosim: Option<cosim::Exchange>,
}

impl Board for QemuBoard {
    type Setpoints = Injected;
    type Timer = CmsdkTimer;
    type Link = cosim::Port;

    fn link(&mut self) -> cosim::Port {
        match self.cosim {
            Some(_) => cosim::Port::Exchange(cosim::ExchangePort::new()),
            None => cosim::Port::Uart(uart::CmsdkUart::open()),
        }
    }

    /// The production settings with the built-in tour on (the simulated machine may move by
    /// itself), the tour, its profile and its acceleration adapted to the harness's scenario.
    fn settings() -> Settings {
        let production = Settings::default();
        if cosim::requested() {
            return cosim::settings(production);
        }
        let scenario = Harness::scenario();
        let (trajectory_profile, trajectory_accel_mm_s2) = scenario.trajectory((
            production.trajectory_profile,
            production.trajectory_accel_mm_s2,
        ));
        // The simulated encoders are absolute (the counters show the joint angle) except in the
        // homing scenarios and `link`, where they are incremental with an index mark; the homing
        // scenarios home at boot, `link` when the host sends Home.
        let homes = scenario.homing_sim().is_some();
        let homing = HomingSettings {
            absolute_encoders: !homes,
            at_boot: scenario.home_at_boot(),
            ..production.homing
        };
        Settings {
            link_motion: scenario.link_motion(),
            builtin_tour_mm: scenario.tour_mm(&WORKSPACE_TOUR_MM),
            trajectory_profile,
            trajectory_accel_mm_s2,
            homing,
            ..production
        }
    }

    fn init(settings: &'static Settings) -> Self {
        // The self-tests of the failure paths run first, as at the top of `init`.
        let harness = Harness::boot(settings);
        let full_scale_nm = settings.drive_full_scale_nm;
        let encoder_scales = super::encoder_scales(settings);
        let mut board = QemuBoard {
            timer: CmsdkTimer::new(SAMPLE_RATE_HZ),
            encoders: [SimEncoder { axis: 0 }, SimEncoder { axis: 1 }],
            encoder_scales,
            drives: [
                TorqueDrive {
                    pwm: SimPwm { axis: 0 },
                    full_scale_nm,
                },
                TorqueDrive {
                    pwm: SimPwm { axis: 1 },
                    full_scale_nm,
                },
            ],
            plant: Plant::power_on(full_scale_nm),
            period_s: 1.0 / SAMPLE_RATE_HZ as f32,
            harness,
            cosim: cosim::take(),
        };
        board.disable_drives();
        // The machine does not stop with its controller: after a reset in the middle of a
        // coast (the boot after `stalled-task`'s watchdog reset) it is where the coast was.
        if let Some(state) = across_reset::take() {
            board.plant.resume(state);
            board.harness.resumed(state);
        }
        if let Some(sim) = Harness::scenario().homing_sim() {
            board.plant.power_on_incremental(sim.power_on_mm, sim.index);
        }
        board
    }

    fn setpoints(&mut self, trajectory: Trajectory) -> Injected {
        self.harness.setpoints(trajectory, self.plant.coast_model())
    }

    #[inline]
    fn encoders_rad(&mut self) -> [f32; 2] {
        [
            self.encoder_scales[0].joint_rad(self.encoders[0].position_counts()),
            self.encoder_scales[1].joint_rad(self.encoders[1].position_counts()),
        ]
    }

    #[inline]
    fn set_torques_nm(&mut self, torque_nm: [f32; 2]) -> Result<[f32; 2], DriveError> {
        drive::set_torques_nm(&mut self.drives, torque_nm)
    }

    fn enable_drives(&mut self) {
        hardware::set_drive_enable(true);
    }

    fn index_rad(&mut self) -> [Option<f32>; 2] {
        [0, 1].map(|k| hardware::take_index(k).map(|c| self.encoder_scales[k].joint_rad(c)))
    }

    fn reference_at_index(&mut self, index_rad: [f32; 2]) -> bool {
        let counts = [hardware::index_counts(0), hardware::index_counts(1)];
        super::reference_scales(&mut self.encoder_scales, counts, index_rad)
    }

    /// Duty to zero torque, then the enable line low (`hardware::safe_state`, also what the
    /// watchdog's NMI and the fault handlers do).
    fn disable_drives(&mut self) {
        hardware::safe_state();
    }

    /// The simulated reset-cause flag (set by the watchdog's NMI before its reset).
    fn reset_cause(&mut self) -> ResetCause {
        hardware::take_reset_cause()
    }

    fn start_watchdog(&mut self) -> Result<(), WatchdogFault> {
        watchdog::start();
        Ok(())
    }

    #[inline]
    fn feed_watchdog(&mut self) {
        watchdog::feed();
        harness::note_feed();
    }

    #[inline]
    fn timer(&mut self) -> &mut CmsdkTimer {
        &mut self.timer
    }

    /// A busy loop, not WFI: under `-icount ...,sleep=off` a WFI idle makes QEMU's periodic
    /// timer run at half rate. Unrolled: under `-icount` every instruction is 8 ns of virtual
    /// time whichever it is, and QEMU takes an interrupt at the exact instruction its deadline
    /// falls on, so the run is the same; but QEMU executes a block of 64 `nop`s several times
    /// faster than 64 one-`nop` loop iterations (idle is most of a sample's instructions).
    #[inline]
    fn idle_wait() {
        for _ in 0..IDLE_UNROLL {
            cortex_m::asm::nop();
        }
    }

    /// The harness's fault injection first (it decides what the encoder counters show), then
    /// the plant moves under the torques of the last sample and updates the counters.
    #[inline]
    fn begin_sample(&mut self) {
        if let Some(exchange) = &mut self.cosim {
            return exchange.sample();
        }
        self.harness.begin_sample(&self.timer, &mut self.plant);
        self.plant.advance(self.period_s);
    }

    #[inline]
    fn end_sample(&mut self, status: &Status) {
        if let Some(exchange) = &mut self.cosim {
            return exchange.note_status(status);
        }
        self.harness.end_sample(status, self.plant.state());
    }

    fn bundled_upload_due(&mut self, ticks: u32) -> Option<(&'static [u8], bool)> {
        self.harness
            .upload_due(ticks)
            .map(|corrupt| (crate::calibration::BUNDLED_UPLOAD, corrupt))
    }
}

/// For the benchmark: nothing to set up (QEMU counts instructions at any clock).
pub fn bench_init() {}

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

    /// Starts the counter (takes the core peripherals it needs).
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
