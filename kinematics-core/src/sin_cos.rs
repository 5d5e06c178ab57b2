//! `sin` and `cos` of one f32 angle together, in single precision throughout.
//!
//! Why not libm: musl's `sincosf` (what the `libm` crate ports) reduces the argument and
//! evaluates its kernels in f64, which a Cortex-M4F (single-precision FPU) runs in software,
//! thousands of instructions per call. Written here in plain f32 arithmetic (no fused
//! multiply-add, no target-dependent branch), the same source rounds the same way on the MCU
//! and on the host, which `tests/tests/same_core_on_mcu.rs` checks bit for bit.
//!
//! Algorithm (Cody-Waite reduction, two polynomials):
//! * `k = round(x · 2/π)` by the `1.5·2²³` trick (exact round-to-nearest-even for the claimed
//!   range, and `k mod 4` sits in the low bits of the sum), `r = x - k·π/2` with π/2 split
//!   into three parts, the first two with 12 significant bits so that `k·P1` and `k·P2` are
//!   exact for `|k| < 4096`: `r ∈ [-π/4, π/4]` to about one ulp of `r`;
//! * `sin r = r + r³·S(r²)`, `cos r = 1 - r²/2 + r⁴·C(r²)`, `S` and `C` of degree 2:
//!   Chebyshev fits of `(sin √u - √u)/u^1.5` and `(cos √u - 1 + u/2)/u²` on `u ∈ [0, (π/4)²]`
//!   (`mpmath.chebyfit`, 40 digits), rounded to f32. In exact arithmetic their errors are
//!   1e-8 (sin) and 8e-10 (cos): below f32 rounding;
//! * the quadrant `k mod 4` swaps and negates.
//!
//! Range and error: for `|x| ≤ 4096` rad the largest error against f64 `sin`/`cos` of the
//! same f32 input is below 1.2e-7 (1 ulp of 1.0); measured by the test below over 2²¹ points
//! plus the multiples of π/4. Outside that range (and for NaN, ±∞) the call falls back to
//! libm's `sincosf` (correctly reduced for any finite input, NaN otherwise): the
//! kinematics never get there, but no input gives a wrong answer.
//!
//! Cost: the reduction (three multiply-adds), two polynomials of degree 2 and the quadrant's
//! swap; no division, no call. `BENCH sin_cos_f32` in `cargo qemu-bench` counts it on the MCU
//! (docs/validation/benchmarks.md); the FK calls it twice.

/// The claimed range: `|x| ≤ MAX_ARG_RAD` (keeps `|k| < 4096`, see the module doc).
pub const MAX_ARG_RAD: f32 = 4096.0;

const FRAC_2_PI: f32 = 0.636_619_75;
/// `1.5·2²³`: adding it rounds to an integer (ties to even) for `|y| < 2²²`.
const ROUND_MAGIC: f32 = 12_582_912.0;
/// π/2 = P1 + P2 + P3 (P1, P2 with 12 significant bits).
const PIO2_1: f32 = 1.570_800_8;
const PIO2_2: f32 = -4.453_584_6e-6;
const PIO2_3: f32 = -8.705_516e-10;
const S1: f32 = -0.166_666_64;
const S2: f32 = 0.008_332_748;
const S3: f32 = -0.000_195_878_9;
const C1: f32 = 0.041_666_664;
const C2: f32 = -0.001_388_830_2;
const C3: f32 = 2.454_794_2e-5;

/// `(sin x, cos x)` (see the module doc for range and error).
#[inline(always)]
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    // `!(a <= b)` also sends NaN to libm.
    if !(libm::fabsf(x) <= MAX_ARG_RAD) {
        return beyond_range(x);
    }
    let shifted = x * FRAC_2_PI + ROUND_MAGIC;
    let quadrant = shifted.to_bits() & 3;
    let k = shifted - ROUND_MAGIC;
    let r = ((x - k * PIO2_1) - k * PIO2_2) - k * PIO2_3;
    let r2 = r * r;
    let sin = r + r * r2 * (S1 + r2 * (S2 + r2 * S3));
    let cos = (1.0 - 0.5 * r2) + r2 * r2 * (C1 + r2 * (C2 + r2 * C3));
    match quadrant {
        0 => (sin, cos),
        1 => (cos, -sin),
        2 => (-sin, -cos),
        _ => (-cos, sin),
    }
}

/// Out of the claimed range: libm (kept out of line, so that callers need not save registers
/// for a call they never make in practice).
#[cold]
#[inline(never)]
fn beyond_range(x: f32) -> (f32, f32) {
    libm::sincosf(x)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::println;

    /// Largest `|sin_cos_f32(x) - (sin, cos)(x as f64)|` over `points` spread on `[-max, max]`.
    fn worst_error(max: f32, points: u32) -> f64 {
        let mut worst: f64 = 0.0;
        for i in 0..=points {
            let x = -max + 2.0 * max * (i as f32 / points as f32);
            let (s, c) = sin_cos_f32(x);
            let xd = f64::from(x);
            worst = worst
                .max((f64::from(s) - libm::sin(xd)).abs())
                .max((f64::from(c) - libm::cos(xd)).abs());
        }
        worst
    }

    #[test]
    fn error_is_below_one_ulp_of_one_over_the_claimed_range() {
        let near = worst_error(7.0, 1 << 20);
        let far = worst_error(MAX_ARG_RAD, 1 << 21);
        let mut at_multiples: f64 = 0.0;
        for k in -5215..=5215 {
            for x in [
                k as f32 * core::f32::consts::FRAC_PI_4,
                f32::from_bits((k as f32 * core::f32::consts::FRAC_PI_4).to_bits() + 1),
            ] {
                if libm::fabsf(x) > MAX_ARG_RAD {
                    continue;
                }
                let (s, c) = sin_cos_f32(x);
                let xd = f64::from(x);
                at_multiples = at_multiples
                    .max((f64::from(s) - libm::sin(xd)).abs())
                    .max((f64::from(c) - libm::cos(xd)).abs());
            }
        }
        println!("sin_cos_f32 worst error: {near:.2e} on |x| <= 7, {far:.2e} on |x| <= {MAX_ARG_RAD}, {at_multiples:.2e} at multiples of pi/4");
        for e in [near, far, at_multiples] {
            assert!(e < 1.2e-7, "{e:e}");
        }
    }

    #[test]
    fn outside_the_range_it_is_libm() {
        for x in [4096.5f32, -1.0e6, 3.0e38, f32::MIN_POSITIVE] {
            let (s, c) = sin_cos_f32(x);
            let (ls, lc) = libm::sincosf(x);
            assert!((s - ls).abs() <= 1.2e-7 && (c - lc).abs() <= 1.2e-7, "{x}");
        }
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let (s, c) = sin_cos_f32(x);
            assert!(s.is_nan() && c.is_nan(), "{x}");
        }
        assert_eq!(sin_cos_f32(0.0), (0.0, 1.0));
    }
}
