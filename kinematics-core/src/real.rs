//! The scalar type the kinematics are written over: `f32` on the MCU, `f64` in the host tools.
//!
//! One generic source serves both so that the firmware and the calibration tools cannot drift
//! apart. Only the handful of operations the kinematics need are here, each the same routine on
//! every target so that host and MCU round the same way: `libm` for f64 and for the f32
//! rounding helpers; for f32 `atan2` and `sin_cos` the core's own single-precision routines
//! ([`crate::atan2`], [`crate::sin_cos`]: libm's f32 `atan2f` is slower and its `sincosf`
//! computes in f64, software on the MCU); and `sqrt` on a Cortex-M with an FPU, where the
//! `VSQRT.F32` instruction is both exact (IEEE-754 correctly rounded, like libm's) and much
//! cheaper than libm's software `sqrtf` (about 56 instructions a call on the Cortex-M4F).

use core::ops::{Add, Div, Mul, Neg, Sub};

/// A floating-point scalar: `f32` or `f64`.
pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + core::fmt::Debug
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// 2.
    const TWO: Self;
    /// 0.5.
    const HALF: Self;
    /// π, rounded to the type.
    const PI: Self;
    /// Machine epsilon of the type.
    const EPSILON: Self;

    /// Converts from `f64`, rounding to nearest.
    fn from_f64(v: f64) -> Self;
    /// Widens to `f64` (exact for both implementations).
    fn to_f64(self) -> f64;
    /// Square root, correctly rounded (NaN below zero).
    fn sqrt(self) -> Self;
    /// Cube root (libm's `cbrt`; used when planning a trajectory, not in the 2 kHz step).
    fn cbrt(self) -> Self;
    /// Angle of the point `(x, self)` in `(-π, π]` (libm's `atan2`).
    fn atan2(self, x: Self) -> Self;
    /// `(sin, cos)` of the angle (libm's `sincos`).
    fn sin_cos(self) -> (Self, Self);
    /// Absolute value.
    fn abs(self) -> Self;
    /// Neither NaN nor infinite.
    fn is_finite(self) -> bool;
    /// Nearest integer, halfway cases away from zero.
    fn round(self) -> Self;
    /// `self * a + b`, deliberately *unfused* (two roundings) on every target: the Cortex-M4F
    /// and x86 must round the same way for the bit-identical MCU/host results the golden
    /// test requires, and a fused multiply-add would round once on one and twice on the other.
    fn mul_add(self, a: Self, b: Self) -> Self;

    /// The smaller of the two; `self` when they do not compare (a NaN).
    fn min(self, other: Self) -> Self {
        if other < self {
            other
        } else {
            self
        }
    }
    /// The larger of the two; `self` when they do not compare (a NaN).
    fn max(self, other: Self) -> Self {
        if other > self {
            other
        } else {
            self
        }
    }
    /// Clamps into `[lo, hi]` (callers guarantee `lo <= hi`).
    fn clamp(self, lo: Self, hi: Self) -> Self {
        self.max(lo).min(hi)
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
    const HALF: Self = 0.5;
    const PI: Self = core::f64::consts::PI;
    const EPSILON: Self = f64::EPSILON;

    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn sqrt(self) -> Self {
        libm::sqrt(self)
    }
    fn cbrt(self) -> Self {
        libm::cbrt(self)
    }
    fn atan2(self, x: Self) -> Self {
        libm::atan2(self, x)
    }
    fn sin_cos(self) -> (Self, Self) {
        libm::sincos(self)
    }
    fn abs(self) -> Self {
        libm::fabs(self)
    }
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }
    fn round(self) -> Self {
        libm::round(self)
    }
    fn mul_add(self, a: Self, b: Self) -> Self {
        self * a + b
    }
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const TWO: Self = 2.0;
    const HALF: Self = 0.5;
    const PI: Self = core::f32::consts::PI;
    const EPSILON: Self = f32::EPSILON;

    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn sqrt(self) -> Self {
        sqrt_f32(self)
    }
    fn cbrt(self) -> Self {
        libm::cbrtf(self)
    }
    // Always inlined: their callers are the IK and FK of the 2 kHz step, where a call would
    // cost its own instructions and force the caller to save FPU registers around it.
    #[inline(always)]
    fn atan2(self, x: Self) -> Self {
        crate::atan2::atan2_f32(self, x)
    }
    #[inline(always)]
    fn sin_cos(self) -> (Self, Self) {
        crate::sin_cos::sin_cos_f32(self)
    }
    fn abs(self) -> Self {
        libm::fabsf(self)
    }
    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
    fn round(self) -> Self {
        libm::roundf(self)
    }
    fn mul_add(self, a: Self, b: Self) -> Self {
        self * a + b
    }
}

/// `sqrtf` with the FPU's `VSQRT.F32` where there is one (correctly rounded, like libm).
///
/// The cfg: ARM target features are not visible to `cfg` on stable Rust
/// (`rustc --print cfg --target thumbv7em-none-eabihf` lists none), so
/// `target_feature = "vfp2"` is never true; `target_abi = "eabihf"` (floats passed in FPU
/// registers) is, and implies an FPU with VSQRT on every ARM target that has it. For the same
/// reason the operand cannot use the `sreg` register class (it requires the unstable `vfp2`
/// feature): it goes through a core register and `s0`, declared clobbered. That costs two
/// `VMOV`s on each side (1 cycle each) around the 14-cycle `VSQRT`, against ~40 instructions of
/// libm's software `sqrtf`. `tests/run-all.sh` checks that the benchmark's IK executes VSQRT.
#[inline(always)]
fn sqrt_f32(v: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let out: u32;
        // SAFETY: VSQRT.F32 reads one S register and writes one; `s0` is declared clobbered,
        // no memory is touched and no flags are changed.
        unsafe {
            core::arch::asm!(
                "vmov s0, {i}",
                "vsqrt.f32 s0, s0",
                "vmov {o}, s0",
                i = in(reg) v.to_bits(),
                o = lateout(reg) out,
                out("s0") _,
                options(pure, nomem, nostack),
            );
        }
        f32::from_bits(out)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(v)
    }
}

/// Wraps an angle into `(-π, π]`.
///
/// An angle already in range (an `atan2` minus a small encoder offset, the IK's case) is
/// returned as it is after one comparison; others (and ±π exactly) take a division and a
/// rounding.
#[inline]
pub fn wrap_angle_rad<T: Real>(angle_rad: T) -> T {
    if angle_rad.abs() < T::PI {
        return angle_rad;
    }
    let two_pi = T::TWO * T::PI;
    let wrapped = angle_rad - two_pi * (angle_rad / two_pi).round();
    if wrapped <= -T::PI {
        wrapped + two_pi
    } else {
        wrapped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_lands_in_half_open_interval() {
        for k in -5..=5 {
            let base = 0.3f64;
            let w = wrap_angle_rad(base + k as f64 * 2.0 * core::f64::consts::PI);
            assert!((w - base).abs() < 1e-12, "k={k} w={w}");
        }
        assert_eq!(wrap_angle_rad(core::f64::consts::PI), core::f64::consts::PI);
        assert_eq!(wrap_angle_rad(-core::f64::consts::PI), core::f64::consts::PI);
        assert!((wrap_angle_rad(368.689f64.to_radians()) - 8.689f64.to_radians()).abs() < 1e-12);
    }
}
