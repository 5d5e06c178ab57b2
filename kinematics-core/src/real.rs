//! The scalar type the kinematics are written over: `f32` on the MCU, `f64` in the host tools.
//!
//! One generic source serves both so that the firmware and the calibration tools cannot drift
//! apart. Only the handful of operations the kinematics need are here, each the same routine on
//! every target so that host and MCU round the same way: `libm` for f64 and for the f32
//! rounding helpers; for f32 `atan2` and `sin_cos` the core's own single-precision routines
//! ([`crate::atan2`], [`crate::sin_cos`]: libm's f32 `atan2f` is slower and its `sincosf`
//! computes in f64, software on the MCU); and `sqrt` on a Cortex-M with an FPU, where the
//! `VSQRT.F32` instruction is both exact (IEEE-754 correctly rounded, like libm's) and much
//! cheaper than libm's software `sqrtf` (a loop of tens of instructions on the Cortex-M4F).

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
    /// `∛EPSILON`: the smallest transmission the IK accepts whatever the margin asked. Near a
    /// singularity FK's own estimate of the transmission loses relative accuracy (f32 near a
    /// folded arm: ~10 % at 4e-4), so IK stops well above where FK does
    /// ([`Real::FK_MIN_TRANSMISSION`]): a pose IK accepts is one FK returns.
    const IK_MIN_TRANSMISSION: Self;
    /// `√EPSILON`: the smallest transmission FK accepts whatever the margin asked (below it the
    /// circle intersection can round onto the other side of the singularity).
    const FK_MIN_TRANSMISSION: Self;

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
    /// Hyperbolic tangent (libm's; the six-bar's clearances, not in the 2 kHz step).
    fn tanh(self) -> Self;
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
    const IK_MIN_TRANSMISSION: Self = 6.055_454_452_393_343e-6;
    const FK_MIN_TRANSMISSION: Self = 1.490_116_119_384_765_6e-8;

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
    fn tanh(self) -> Self {
        libm::tanh(self)
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
    const IK_MIN_TRANSMISSION: Self = 4.921_566e-3;
    const FK_MIN_TRANSMISSION: Self = 3.452_669_8e-4;

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
    fn tanh(self) -> Self {
        libm::tanhf(self)
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
/// `VMOV`s on each side (1 cycle each) around the 14-cycle `VSQRT`, against libm's software
/// `sqrtf`, tens of instructions. `tests/run-all.sh` checks that the benchmark's IK executes VSQRT.
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

/// The margin the kinematics apply: the caller's, raised to `floor`
/// ([`Real::IK_MIN_TRANSMISSION`] or [`Real::FK_MIN_TRANSMISSION`]; a negative margin or 0
/// included); a NaN margin stays NaN and refuses every pose.
#[inline(always)]
pub(crate) fn effective_margin<T: Real>(min_transmission: T, floor: T) -> T {
    if min_transmission < floor {
        floor
    } else {
        min_transmission
    }
}

/// Wraps an angle into `(-π, π]`, right for every finite input.
///
/// An angle already in range (an `atan2` minus a small encoder offset, the IK's case) is
/// returned as it is after one comparison. Up to 4π away (a difference of two wrapped angles,
/// the feed-forward's case) one or two turns are taken off with 2π split in two parts
/// (Cody–Waite: the high part's multiples are exact, so the result is off by at most an ulp
/// of itself). Beyond that `wrap_far_rad` reduces exactly. A non-finite angle stays
/// non-finite (NaN).
#[inline]
pub fn wrap_angle_rad<T: Real>(angle_rad: T) -> T {
    if angle_rad.abs() < T::PI {
        return angle_rad;
    }
    wrap_outside_rad(angle_rad)
}

/// [`wrap_angle_rad`] for `|angle| ≥ π`: out of line, so that the IK's inlined fast path stays
/// one comparison.
#[cold]
#[inline(never)]
fn wrap_outside_rad<T: Real>(angle_rad: T) -> T {
    if angle_rad.abs() < T::from_f64(4.0 * core::f64::consts::PI) {
        wrap_near_rad(angle_rad)
    } else {
        wrap_far_rad(angle_rad)
    }
}

/// [`wrap_angle_rad`] without its far path, for the IK's 2 kHz path: right for `|angle| < 4π`
/// (an `atan2` minus an encoder offset of a plausible model), **NaN** beyond, so that an
/// absurd encoder offset makes the IK refuse the pose (non-finite) instead of calling the far
/// path's software double precision (whose mere presence costs the inlined IK a register
/// spill: 6 instructions on every call).
#[inline(always)]
pub(crate) fn wrap_near_rad<T: Real>(angle_rad: T) -> T {
    let a = angle_rad.abs();
    if a < T::PI {
        return angle_rad;
    }
    if !(a < T::from_f64(4.0 * core::f64::consts::PI)) {
        return T::from_f64(f64::NAN);
    }
    // 2π = HI + LO with HI an f32: `k·HI` (k ≤ 2) is exact in either type and so is
    // `x - k·HI` (Sterbenz's lemma: x within a factor 2 of k·HI for x in [π, 4π)); LO carries
    // the rest.
    let hi = T::from_f64(TWO_PI_HI);
    let lo = T::from_f64(TWO_PI_LO);
    let sign = if angle_rad < T::ZERO { -T::ONE } else { T::ONE };
    let turns = if a < T::from_f64(3.0 * core::f64::consts::PI) {
        T::ONE
    } else {
        T::TWO
    };
    let k = sign * turns;
    finish_wrap((angle_rad - k * hi) - k * lo)
}

/// `2π` rounded to f32 (24 bits, exact in both types) and the remainder `2π - TWO_PI_HI`
/// (-1.75e-7, itself rounded to the type).
const TWO_PI_HI: f64 = 6.283_185_482_025_146_5;
const TWO_PI_LO: f64 = 2.0 * core::f64::consts::PI - TWO_PI_HI;

/// The exact reduction of any finite angle: its sine and cosine, whose argument reduction in
/// `libm` is exact for every `f64` (Payne–Hanek with 2/π to 1,200 bits), give the angle back
/// through `atan2` to within an ulp of π. An `f32` widens to `f64` exactly. About 2,000
/// instructions on the Cortex-M4F (software double precision): only absurd angles come here.
fn wrap_far_rad<T: Real>(angle_rad: T) -> T {
    let x = angle_rad.to_f64();
    let wrapped = libm::atan2(libm::sin(x), libm::cos(x));
    finish_wrap(T::from_f64(wrapped))
}

/// Moves the lower end of `[-π, π]` (rounding can land there) to the upper one.
#[inline(always)]
fn finish_wrap<T: Real>(wrapped: T) -> T {
    if wrapped <= -T::PI {
        wrapped + T::TWO * T::PI
    } else if wrapped > T::PI {
        T::PI
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
        assert_eq!(
            wrap_angle_rad(-core::f64::consts::PI),
            core::f64::consts::PI
        );
        assert!((wrap_angle_rad(368.689f64.to_radians()) - 8.689f64.to_radians()).abs() < 1e-12);
    }

    /// Large angles against their remainders computed to 700 digits (mpmath:
    /// `fmod(x, 2π)` moved into (-π, π]): before, `wrap_angle_rad(1e9)` lost the turns'
    /// rounding (the product 2π·k carries k times the error of 2π).
    #[test]
    fn wrap_angle_is_right_for_huge_angles() {
        let cases: [(f64, f64); 4] = [
            (1e9, 0.577_395_423_501_385_2),
            (1e22, -1.020_177_392_559_087),
            (f64::MAX, 3.136_630_678_439_006),
            (f32::MAX as f64, -0.549_049_329_957_454_2),
        ];
        for (x, want) in cases {
            for sign in [1.0, -1.0] {
                let got = wrap_angle_rad(sign * x);
                assert!(
                    (got - sign * want).abs() < 1e-15,
                    "f64 wrap({}) = {got}, want {}",
                    sign * x,
                    sign * want
                );
            }
        }
        // f32: 1e9 and f32::MAX are exact f32 values; the answer rounded to f32.
        for (x, want) in [
            (1e9f32, 0.577_395_423_501_385_2f64),
            (f32::MAX, -0.549_049_329_957_454_2),
        ] {
            let got = wrap_angle_rad(x);
            assert!(
                (f64::from(got) - want).abs() < 1e-7,
                "f32 wrap({x}) = {got}, want {want}"
            );
        }
    }

    /// Every path (in range, one or two turns off, far) lands in (-π, π] on an angle whose
    /// sine and cosine are the input's, for f64 and f32 over 40 orders of magnitude.
    #[test]
    fn wrap_angle_keeps_the_direction_everywhere() {
        let mut checked = 0;
        for e in -3..=38 {
            for m in [
                1.0,
                1.234_567,
                2.5,
                core::f64::consts::PI,
                4.7,
                core::f64::consts::TAU,
                7.9,
                9.999,
            ] {
                for sign in [1.0f64, -1.0] {
                    let x = sign * m * 10f64.powi(e);
                    let w = wrap_angle_rad(x);
                    assert!(
                        w > -core::f64::consts::PI && w <= core::f64::consts::PI,
                        "wrap({x}) = {w}"
                    );
                    assert!(
                        (libm::sin(w) - libm::sin(x)).abs() < 1e-12
                            && (libm::cos(w) - libm::cos(x)).abs() < 1e-12,
                        "wrap({x}) = {w}"
                    );
                    let xf = x as f32;
                    if !xf.is_finite() {
                        continue;
                    }
                    let wf = wrap_angle_rad(xf);
                    assert!(
                        wf > -core::f32::consts::PI && wf <= core::f32::consts::PI,
                        "wrap({xf}) = {wf}"
                    );
                    let xd = f64::from(xf);
                    let (ws, wc) = (libm::sin(f64::from(wf)), libm::cos(f64::from(wf)));
                    assert!(
                        (ws - libm::sin(xd)).abs() < 1e-6 && (wc - libm::cos(xd)).abs() < 1e-6,
                        "wrap({xf}) = {wf}"
                    );
                    checked += 1;
                }
            }
        }
        // 672 cases less the 8 whose f32 overflows (e = 38, m > 3.4).
        assert_eq!(checked, 664);
        assert!(wrap_angle_rad(f64::NAN).is_nan() && wrap_angle_rad(f32::INFINITY).is_nan());
    }
}
