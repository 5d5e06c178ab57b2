//! Board support behind small traits; exactly one board is compiled in (feature `board-*`).
//!
//! What the app needs from a board, and nothing more:
//! * a servo timer that interrupts at 2 kHz (`SERVO_TICK` in the board's `device` module) and
//!   tells how long after its tick we are and whether the next tick already came (overrun);
//! * two quadrature encoders ([`QuadratureEncoder`], our own trait: embedded-hal 1.0 has none);
//! * two PWM outputs (`embedded_hal::pwm::SetDutyCycle`) driving torque-mode amplifiers through
//!   [`TorqueDrive`], plus a drive-enable line;
//! * a console and an exit code for tests (QEMU only), and `simulate_period`, which advances
//!   the simulated plant on QEMU and does nothing on hardware.
//!
//! Both boards export the same names: `device` (for RTIC), `Board`, `ServoTimer`,
//! `COUNTS_PER_REV`, `idle_wait`, `command_line`, `console`, `exit`.
use embedded_hal::pwm::SetDutyCycle;

#[cfg(all(feature = "board-qemu", feature = "board-g474"))]
compile_error!("enable exactly one of the features `board-qemu` and `board-g474`");

#[cfg(feature = "board-g474")]
pub mod g474;
#[cfg(feature = "board-g474")]
pub use g474::*;

#[cfg(feature = "board-qemu")]
pub mod qemu;
#[cfg(feature = "board-qemu")]
pub use qemu::*;

/// A quadrature encoder read through a hardware counter.
pub trait QuadratureEncoder {
    /// Position in counts, extended to 32 bits (no wrap within the machine's travel).
    fn position_counts(&mut self) -> i32;
}

/// Encoder angle (rad) of a count, for `counts_per_rev` counts per motor revolution.
#[inline]
pub fn counts_to_rad(counts: i32, counts_per_rev: u32) -> f32 {
    counts as f32 * (2.0 * core::f32::consts::PI / counts_per_rev as f32)
}

/// A torque-mode amplifier commanded by PWM duty: 50 % is zero torque, 0 % and 100 % are
/// minus and plus `full_scale_nm` (locked anti-phase, or an amplifier's PWM torque input).
pub struct TorqueDrive<P> {
    pub pwm: P,
    pub full_scale_nm: f32,
}

/// Duty for a torque (clamped to full scale), rounded to the nearest step.
#[inline]
pub fn torque_to_duty(torque_nm: f32, full_scale_nm: f32, max_duty: u16) -> u16 {
    let fraction = (0.5 + 0.5 * torque_nm / full_scale_nm).clamp(0.0, 1.0);
    // `fraction` is in [0, 1] (NaN turns into 0 via the cast, but the servo never emits NaN).
    (fraction * max_duty as f32 + 0.5) as u16
}

/// Torque that a duty commands (the inverse of [`torque_to_duty`]).
#[inline]
pub fn duty_to_torque_nm(duty: u16, full_scale_nm: f32, max_duty: u16) -> f32 {
    (2.0 * duty as f32 / max_duty as f32 - 1.0) * full_scale_nm
}

impl<P: SetDutyCycle> TorqueDrive<P> {
    /// Commands `torque_nm`; returns the torque actually commanded after duty rounding.
    pub fn set_torque_nm(&mut self, torque_nm: f32) -> Result<f32, P::Error> {
        let max = self.pwm.max_duty_cycle();
        let duty = torque_to_duty(torque_nm, self.full_scale_nm, max);
        self.pwm.set_duty_cycle(duty)?;
        Ok(duty_to_torque_nm(duty, self.full_scale_nm, max))
    }
}
