//! The simulated hardware registers between the firmware and the plant: PWM duty per axis, the
//! drive-enable line, the encoder counters, and a reset-cause flag. They are atomics, written
//! by the board's drivers ([`SimPwm`], [`QemuBoard::enable_drives`](super::QemuBoard)) and read
//! by the plant and by the test harness, which checks what the hardware shows rather than what
//! the firmware says. The harness can also make an encoder counter lie ([`inject_encoder`]:
//! frozen, or offset).
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicI32, AtomicU16, Ordering};

use controller::drive::duty_to_torque_nm;
use controller::encoder::QuadratureEncoder;
use controller::watchdog::ResetCause;
use embedded_hal::pwm::{ErrorType, SetDutyCycle};

use super::PWM_MAX_DUTY;

static PWM_DUTY: [AtomicU16; 2] = [
    AtomicU16::new(PWM_MAX_DUTY / 2),
    AtomicU16::new(PWM_MAX_DUTY / 2),
];
static DRIVE_ENABLE: AtomicBool = AtomicBool::new(false);
/// Sticky: the enable line went high at least once since power-on (a probe on the line).
static DRIVE_ENABLE_EVER: AtomicBool = AtomicBool::new(false);
static ENCODER_COUNTS: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];
/// Encoder fault injection: the counter stops following the plant / shows this many counts more.
static ENCODER_FROZEN: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];
static ENCODER_OFFSET_COUNTS: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];
/// An incremental encoder's counter reads 0 at power-on: the plant's count there, subtracted
/// from every count (0: the counter shows the absolute angle, an absolute encoder).
static COUNTER_ZERO: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];
/// The counter's value at the first index pulse (the encoder timer's index capture).
static INDEX_COUNTS: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];
static INDEX_LATCHED: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];
/// A latched index not read yet by [`take_index`].
static INDEX_NEW: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];

/// The safe state, from any context (the watchdog's NMI, fault handlers): duty to zero torque
/// (50 %), then the enable line low.
pub fn safe_state() {
    for duty in &PWM_DUTY {
        duty.store(PWM_MAX_DUTY / 2, Ordering::SeqCst);
    }
    set_drive_enable(false);
}

/// Drives the enable line.
pub fn set_drive_enable(on: bool) {
    DRIVE_ENABLE.store(on, Ordering::SeqCst);
    if on {
        DRIVE_ENABLE_EVER.store(true, Ordering::SeqCst);
    }
}

/// The enable line now.
pub fn drive_enable() -> bool {
    DRIVE_ENABLE.load(Ordering::SeqCst)
}

/// Whether the enable line was ever high.
pub fn drive_enable_ever() -> bool {
    DRIVE_ENABLE_EVER.load(Ordering::SeqCst)
}

/// The duty register of `axis`.
pub fn pwm_duty(axis: usize) -> u16 {
    PWM_DUTY[axis].load(Ordering::Relaxed)
}

/// The torques the duty registers command (N·m) for a drive of `full_scale_nm`, whether or not
/// the drives are enabled.
pub fn commanded_torque_nm(full_scale_nm: f32) -> [f32; 2] {
    [
        duty_to_torque_nm(pwm_duty(0), full_scale_nm, PWM_MAX_DUTY),
        duty_to_torque_nm(pwm_duty(1), full_scale_nm, PWM_MAX_DUTY),
    ]
}

/// Sets the encoder counter of `axis` (the plant does, from its joint angle), unless the
/// counter is frozen; plus the injected offset.
pub fn set_encoder_counts(axis: usize, counts: i32) {
    if !ENCODER_FROZEN[axis].load(Ordering::Relaxed) {
        let counts = counts.wrapping_sub(COUNTER_ZERO[axis].load(Ordering::Relaxed));
        let shown = counts.wrapping_add(ENCODER_OFFSET_COUNTS[axis].load(Ordering::Relaxed));
        ENCODER_COUNTS[axis].store(shown, Ordering::Relaxed);
    }
}

/// Makes `axis`'s counter incremental: it reads 0 where the plant's count is `plant_counts`
/// (the power-on position).
pub fn set_counter_zero(axis: usize, plant_counts: i32) {
    COUNTER_ZERO[axis].store(plant_counts, Ordering::Relaxed);
}

/// The plant crossed `axis`'s index mark, at plant count `plant_counts`: the counter's value
/// there is captured (the first pulse only, as the encoder timer's capture with first-index
/// mode does).
pub fn index_pulse(axis: usize, plant_counts: i32) {
    if !INDEX_LATCHED[axis].swap(true, Ordering::SeqCst) {
        INDEX_COUNTS[axis].store(
            plant_counts.wrapping_sub(COUNTER_ZERO[axis].load(Ordering::Relaxed)),
            Ordering::SeqCst,
        );
        INDEX_NEW[axis].store(true, Ordering::SeqCst);
    }
}

/// The captured counter value at `axis`'s index, once per capture.
pub fn take_index(axis: usize) -> Option<i32> {
    INDEX_NEW[axis]
        .swap(false, Ordering::SeqCst)
        .then(|| INDEX_COUNTS[axis].load(Ordering::SeqCst))
}

/// The captured counter value at `axis`'s index, if there was one.
pub fn index_counts(axis: usize) -> Option<i32> {
    INDEX_LATCHED[axis]
        .load(Ordering::SeqCst)
        .then(|| INDEX_COUNTS[axis].load(Ordering::SeqCst))
}

/// Encoder fault injection (the test harness), for the plant's next update of the counter:
/// `frozen` keeps the counter at what it shows now; `offset_counts` is added to the plant's
/// count.
pub fn inject_encoder(axis: usize, frozen: bool, offset_counts: i32) {
    ENCODER_FROZEN[axis].store(frozen, Ordering::Relaxed);
    ENCODER_OFFSET_COUNTS[axis].store(offset_counts, Ordering::Relaxed);
}

/// One PWM channel of the simulated drive.
pub struct SimPwm {
    /// 0 or 1.
    pub axis: usize,
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
    /// 0 or 1.
    pub axis: usize,
}

impl QuadratureEncoder for SimEncoder {
    fn position_counts(&mut self) -> i32 {
        ENCODER_COUNTS[self.axis].load(Ordering::Relaxed)
    }
}

/// The reset-cause flag (the MPS2 has no reset-cause register QEMU models): the watchdog's
/// interrupt sets it, since the CMSDK watchdog resets the machine at its next expiry; the boot
/// reads and clears it. It lives in `.uninit` RAM, which neither QEMU's system reset nor
/// cortex-m-rt's start-up clears; a fresh QEMU's RAM reads 0, i.e. power-on.
#[link_section = ".uninit.reset_flag"]
static mut RESET_FLAG: MaybeUninit<u32> = MaybeUninit::uninit();
/// [`RESET_FLAG`]'s value for "the watchdog is about to reset the machine".
const WATCHDOG_RESET: u32 = 0x5744_5253;

fn reset_flag() -> *mut u32 {
    core::ptr::addr_of_mut!(RESET_FLAG).cast::<u32>()
}

/// Marks the coming reset as the watchdog's.
pub fn note_watchdog_reset() {
    // SAFETY: a word of RAM reserved for this flag; volatile, as it must survive a reset.
    unsafe { reset_flag().write_volatile(WATCHDOG_RESET) };
}

/// The last reset's cause, without clearing it.
pub fn peek_reset_cause() -> ResetCause {
    // SAFETY: as in `note_watchdog_reset`; any bit pattern is a valid u32.
    match unsafe { reset_flag().read_volatile() } {
        WATCHDOG_RESET => ResetCause::Watchdog,
        _ => ResetCause::PowerOnOrBrownOut,
    }
}

/// The last reset's cause; clears the flag (as RCC_CSR's RMVF does on the STM32G474).
pub fn take_reset_cause() -> ResetCause {
    let cause = peek_reset_cause();
    // SAFETY: as in `note_watchdog_reset`.
    unsafe { reset_flag().write_volatile(0) };
    cause
}
