//! The boards, behind one [`Board`] trait; exactly one is compiled in (feature `board-*`) and
//! exported as [`Selected`].
//!
//! What the app needs from a board, and nothing more:
//! * a servo timer that interrupts at 2 kHz (`SERVO_TICK` in the board's [`device`] module) and
//!   tells how long after its tick we are and whether the next tick already came (overrun);
//! * two quadrature encoders ([`QuadratureEncoder`](controller::encoder::QuadratureEncoder));
//! * two PWM outputs (embedded-hal's `SetDutyCycle`) driving torque-mode amplifiers through
//!   [`TorqueDrive`](controller::drive::TorqueDrive), plus a drive-enable line;
//! * an independent watchdog, fed by the servo task only after an on-time step
//!   ([`controller::watchdog`]), and the cause of the last reset;
//! * the host link's byte port ([`crate::link::LinkPort`], a UART with its receive interrupt);
//! * an idle wait, and two per-sample hooks that do nothing on hardware: the QEMU board advances
//!   its simulated plant and runs its test harness (scenarios, fault injection, checks) there.
//!
//! Each board also exports, for the bare-metal benchmark and golden binaries (no RTIC, no
//! `Board`): `console`, `exit`, `bench_init` (the clock the app runs at), `CycleCounter` and
//! `COUNT_UNIT`.
use controller::deadline::step_time_us;
use controller::drive::DriveError;
use controller::encoder::EncoderScale;
use controller::servo_loop::IndexCapture;
use controller::setpoints::SetpointSource;
use controller::settings::Settings;
use controller::status::Status;
use controller::watchdog::{ResetCause, WatchdogFault};
use controller::waypoint_moves::Trajectory;

#[cfg(all(feature = "board-qemu", feature = "board-g474"))]
compile_error!("enable exactly one of the features `board-qemu` and `board-g474`");

#[macro_use]
mod device_macro;
#[macro_use]
mod hard_fault_macro;

#[cfg(feature = "board-g474")]
pub mod g474;
#[cfg(feature = "board-g474")]
pub use g474::{
    bench_init, console, device, exit, CycleCounter, G474Board as Selected, COUNT_UNIT,
};
/// What the host link's `Identify` reports as the board.
#[cfg(feature = "board-g474")]
pub const BOARD_ID: link_protocol::Board = link_protocol::Board::Stm32G474;

#[cfg(feature = "board-qemu")]
pub mod qemu;
#[cfg(feature = "board-qemu")]
pub use qemu::{
    bench_init, console, device, exit, CycleCounter, QemuBoard as Selected, COUNT_UNIT,
};
/// What the host link's `Identify` reports as the board.
#[cfg(feature = "board-qemu")]
pub const BOARD_ID: link_protocol::Board = link_protocol::Board::Qemu;

/// Sets both scales' zero at the captured index counts `counts` (rad `index_rad`), both or
/// neither. For the boards' `reference_at_index`.
fn reference_scales(
    scales: &mut [EncoderScale; 2],
    counts: [Option<i32>; 2],
    index_rad: [f32; 2],
) -> bool {
    let [Some(c0), Some(c1)] = counts else {
        return false;
    };
    let mut next = *scales;
    let ok = next[0].set_reference(c0, index_rad[0]).is_ok()
        && next[1].set_reference(c1, index_rad[1]).is_ok();
    if ok {
        *scales = next;
    }
    ok
}

/// Both axes' counts-to-angle scales from `Settings::encoders`; a refused configuration is
/// logged and reads NaN (the servo then refuses to engage). For the boards' `init`.
fn encoder_scales(settings: &Settings) -> [EncoderScale; 2] {
    let (scales, errors) = EncoderScale::both(&settings.encoders);
    for (axis, e) in errors.iter().enumerate() {
        if let Some(e) = e {
            defmt::error!("encoder {}: {} (reads NaN: the drives stay off)", axis, e);
        }
    }
    scales
}

/// The timer whose interrupt (`SERVO_TICK`) starts every servo sample, 2 kHz.
pub trait ServoTimer {
    /// Starts the periodic interrupt.
    fn start(&mut self);

    /// Acknowledges the tick (first thing in the servo task).
    fn acknowledge_tick(&mut self);

    /// Time since the current period began (µs).
    fn elapsed_us(&self) -> f32;

    /// Length of a period (µs).
    fn period_us(&self) -> f32;

    /// Whether the next period has already begun (its interrupt is pending): an overrun.
    fn next_tick_pending(&self) -> bool;

    /// Time since the tick that started this step (µs), also when the step ran past the next
    /// tick (`controller::deadline::step_time_us`).
    #[inline]
    fn step_time_us(&self) -> f32 {
        let elapsed_us = self.elapsed_us();
        step_time_us(elapsed_us, self.period_us(), self.next_tick_pending())
    }
}

/// A board the app runs on. All methods are called from the app's tasks: `init` (boot), the
/// servo task (every sample) and `idle`.
pub trait Board: Sized {
    /// What fills the setpoint queue: the built-in trajectory on hardware; on QEMU the same
    /// trajectory through the harness's setpoint fault injection.
    type Setpoints: SetpointSource;

    /// The servo tick's timer.
    type Timer: ServoTimer;

    /// The host link's byte port (a UART; its receive interrupt is `LINK_RX` in [`device`]).
    type Link: crate::link::LinkPort;

    /// Takes the host link's port, configured, its receive interrupt enabled at the device.
    fn link(&mut self) -> Self::Link;

    /// The settings this board runs with: [`Settings::default`] on hardware; the QEMU board
    /// runs the built-in tour, and its harness adapts the tour to its scenario.
    fn settings() -> Settings;

    /// Brings the board up: clocks, pins, servo timer configured but not started, drives
    /// disabled with zero torque commanded.
    fn init(settings: &'static Settings) -> Self;

    /// The setpoint source the intake task fills the queue from.
    fn setpoints(&mut self, trajectory: Trajectory) -> Self::Setpoints;

    /// Both encoder angles (rad).
    fn encoders_rad(&mut self) -> [f32; 2];

    /// Writes both torques; returns the torques commanded after duty rounding.
    fn set_torques_nm(&mut self, torque_nm: [f32; 2]) -> Result<[f32; 2], DriveError>;

    /// Drive enable on.
    fn enable_drives(&mut self);

    /// Safe state: zero torque commanded (50 % duty), then the outputs and the drive enable
    /// off. The boards' fault handlers (HardFault, panic, unexpected interrupt, the QEMU
    /// watchdog's NMI) do the same without the `Board`.
    fn disable_drives(&mut self);

    /// Why the controller last reset: reads the board's reset flags and clears them (call once,
    /// at boot).
    fn reset_cause(&mut self) -> ResetCause;

    /// Starts the independent watchdog (it cannot be stopped afterwards) with
    /// [`controller::watchdog::TIMEOUT_US`]. From then on the servo task must feed it after
    /// every on-time step.
    fn start_watchdog(&mut self) -> Result<(), WatchdogFault>;

    /// Feeds the watchdog. Only the servo task calls it, last, when
    /// `Sample::feed_watchdog` says the step was on time.
    fn feed_watchdog(&mut self);

    /// The encoder reading (rad) at an index pulse captured since the last call, per axis
    /// (homing). Hardware without index capture returns none (homing then ends in
    /// `IndexNotFound`).
    fn index_rad(&mut self) -> [Option<f32>; 2] {
        [None; 2]
    }

    /// Homing's reference: ties each axis's counter value at its captured index pulse to the
    /// joint angle `index_rad` (`EncoderScale::set_reference`), both axes or neither. `false`:
    /// an axis has no capture, or the scale refused the reference.
    fn reference_at_index(&mut self, index_rad: [f32; 2]) -> bool {
        let _ = index_rad;
        false
    }

    /// The servo tick's timer (configured by `init`, started by the app at the end of boot).
    fn timer(&mut self) -> &mut Self::Timer;

    /// What idle does between interrupts.
    fn idle_wait();

    /// Start of every sample, right after the tick is acknowledged and before the encoders are
    /// read. QEMU: advances the simulated plant by one period under the torques the drive
    /// registers hold, and injects the harness's deadline faults. Hardware: nothing.
    #[inline(always)]
    fn begin_sample(&mut self) {}

    /// End of every sample, after the status is published. QEMU: the test harness checks the
    /// drive registers and `status`, and ends the run with its verdict. Hardware: nothing.
    #[inline(always)]
    fn end_sample(&mut self, status: &Status) {
        let _ = status;
    }

    /// An image the board wants uploaded now through the calibration slots, as the host link's
    /// upload would (and whether to corrupt it on the way): the QEMU upload scenarios' bundled
    /// second image, once. Hardware: never (uploads come over the link).
    #[inline(always)]
    fn bundled_upload_due(&mut self, ticks: u32) -> Option<(&'static [u8], bool)> {
        let _ = ticks;
        None
    }
}

/// A board's index capture, as the servo loop's homing step reads it
/// (`controller::servo_loop::IndexCapture`).
pub struct IndexOf<'b, B>(pub &'b mut B);

impl<B: Board> IndexCapture for IndexOf<'_, B> {
    fn index_rad(&mut self) -> [Option<f32>; 2] {
        self.0.index_rad()
    }
    fn reference_at_index(&mut self, index_rad: [f32; 2]) -> bool {
        self.0.reference_at_index(index_rad)
    }
}
