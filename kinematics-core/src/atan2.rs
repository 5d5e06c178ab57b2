//! `atan2(y, x)` in single precision with one division and a degree-11 polynomial.
//!
//! Why not libm: `atan2f` is correct but general (special cases first, a five-way range
//! split, branches per octant, a call into `atanf`), and the IK calls it twice. This one has
//! no call and no branch on the way (the octant picks a table entry), in plain f32
//! arithmetic (no fused multiply-add), so the MCU and the host round identically
//! (`tests/tests/same_core_on_mcu.rs`).
//!
//! Algorithm: with `ax = |x|`, `ay = |y|`, the angle of `(ax, ay)` in `[0, π/2]` is brought
//! into `[0, π/4]` by swapping the legs (`π/2 - φ`), then into `[-π/8, π/8]` by rotating the
//! vector by -π/4 when `num > tan(π/8)·den` (`t = (num - den)/(num + den)` instead of
//! `num/den`: still one division). There `atan t = t + t³·P(t²)`, `P` of degree 3: a
//! Chebyshev fit of `(atan √u - √u)/u^1.5` on `u ∈ [0, tan²(π/8)]` (`mpmath.chebyfit`,
//! 40 digits), rounded to f32; 3e-8 in exact arithmetic. The result is `n·π/4 ± atan t`
//! (`n` from the octant and the sign of `x`), added once with `n·π/4` carried as two f32
//! parts (the nearest f32 to π alone is off by 9e-8), then the sign of `y`. No branch but
//! the octant's table entry, no call.
//!
//! Error: at most 2.0e-7 rad against f64 `atan2` of the same f32 inputs, over all finite
//! inputs (measured by the test below over 2²⁰ directions at magnitudes from 1e-30 to 1e30,
//! and on the axes and diagonals): under one ulp of results beyond π/2 in magnitude (2.4e-7
//! there), where the final rounding alone costs up to 1.2e-7. libm's `atan2f` is off by up to
//! 2.5e-7 on the same inputs. Zero, infinite and NaN inputs give IEEE's results (the
//! nearest f32 to them, tested).
//!
//! Cost: one division (VDIV on the Cortex-M4F), the octant's table lookup and eight
//! multiply-adds; no call, no branch. `BENCH atan2_f32` in `cargo qemu-bench` counts it on the
//! MCU (docs/validation/benchmarks.md); inlined into the IK, where its loads and constants are
//! shared, it costs less.

const TAN_PI_8: f32 = 0.414_213_57;
const P1: f32 = -0.333_332_87;
const P2: f32 = 0.199_912_38;
const P3: f32 = -0.140_241_43;
const P4: f32 = 0.085_204_92;

/// The angle is `±(n·π/4 ± atan t)`; per case (bit 0: rotated by π/4, bit 1: legs swapped,
/// bit 2: x negative, bit 3: y negative) `[hi, lo, ±1, 0]` with `hi + lo = ±n·π/4` (`hi` the
/// nearest f32, `lo` the nearest f32 to the rest). Rotating adds π/4, swapping gives
/// π/2 - angle, a negative x gives π - angle, a negative y the opposite angle (negating every
/// term rounds the same). Padded to 16 bytes per entry for the addressing; a `static`, so
/// that indexing reads flash instead of copying the table to the stack.
static CASES: [[f32; 4]; 16] = {
    use core::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI as PI_F32};
    const PI_4: (f32, f32) = (FRAC_PI_4, -2.185_569_4e-8);
    const PI_2: (f32, f32) = (FRAC_PI_2, -4.371_139e-8);
    const PI3_4: (f32, f32) = (2.356_194_5, -5.962_440_3e-9);
    const PI: (f32, f32) = (PI_F32, -8.742_278e-8);
    let octants = [
        (0.0, 0.0, 1.0),
        (PI_4.0, PI_4.1, 1.0),
        (PI_2.0, PI_2.1, -1.0),
        (PI_4.0, PI_4.1, -1.0),
        (PI.0, PI.1, -1.0),
        (PI3_4.0, PI3_4.1, -1.0),
        (PI_2.0, PI_2.1, 1.0),
        (PI3_4.0, PI3_4.1, 1.0),
    ];
    let mut cases = [[0.0f32; 4]; 16];
    let mut i = 0;
    while i < 16 {
        let (hi, lo, sign) = octants[i & 7];
        let y_sign: f32 = if i < 8 { 1.0 } else { -1.0 };
        cases[i] = [y_sign * hi, y_sign * lo, y_sign * sign, 0.0];
        i += 1;
    }
    cases
};

/// The angle of `(x, y)` from the +x axis, in `[-π, π]` (see the module doc for the error).
#[inline(always)]
pub fn atan2_f32(y: f32, x: f32) -> f32 {
    let (ax, ay) = (libm::fabsf(x), libm::fabsf(y));
    let swap = ay > ax;
    let (mut num, mut den) = if swap { (ax, ay) } else { (ay, ax) };
    // `den` is the larger leg: 0 only at the origin, ∞ or NaN only with such an input. For
    // those, IEEE's atan2 is the limit of the same octant logic with `t = 0` (a zero or an
    // infinite leg against a finite one), `t = 1` (two infinite legs) or NaN. The test is one
    // integer comparison: the bits of a positive finite non-zero f32 minus 1 are below
    // those of f32::MAX.
    if den.to_bits().wrapping_sub(1) >= f32::MAX.to_bits() {
        (num, den) = if den == 0.0 {
            (num, 1.0) // num is 0 too, or NaN
        } else if den == f32::INFINITY {
            // `num * 0` is 0 for a finite leg and keeps a NaN.
            (if num == f32::INFINITY { 1.0 } else { num * 0.0 }, 1.0)
        } else {
            (den, den)
        };
    }
    let rotate = num > TAN_PI_8 * den;
    let (n, d) = if rotate {
        (num - den, num + den)
    } else {
        (num, den)
    };
    let t = n / d;
    let t2 = t * t;
    let poly = t + t * t2 * (P1 + t2 * (P2 + t2 * (P3 + t2 * P4)));
    // The sign bits, not `< 0`: atan2(±0, -0) is ±π, atan2(-0, x) is -0 or -π.
    let case = rotate as usize
        | (swap as usize) << 1
        | ((x.to_bits() >> 31) as usize) << 2
        | ((y.to_bits() >> 31) as usize) << 3;
    let [hi, lo, sign, _] = CASES[case];
    hi + (lo + sign * poly)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::println;

    fn error(y: f32, x: f32) -> f64 {
        (f64::from(atan2_f32(y, x)) - libm::atan2(f64::from(y), f64::from(x))).abs()
    }

    #[test]
    fn error_is_below_2e_7_for_every_finite_input() {
        let mut worst: f64 = 0.0;
        let mut libm_worst: f64 = 0.0;
        let n = 1 << 20;
        for i in 0..n {
            let phi =
                -core::f64::consts::PI + 2.0 * core::f64::consts::PI * (i as f64 + 0.5) / n as f64;
            for radius in [1e-30, 1e-3, 1.0, 150.0, 3.7e4, 1e30] {
                let (y, x) = ((radius * phi.sin()) as f32, (radius * phi.cos()) as f32);
                worst = worst.max(error(y, x));
                libm_worst = libm_worst.max(
                    (f64::from(libm::atan2f(y, x)) - libm::atan2(f64::from(y), f64::from(x))).abs(),
                );
            }
        }
        // The axes, the diagonals and their neighbours, where the octant logic switches.
        let mut edges: f64 = 0.0;
        for v in [1.0f32, 150.0, 1e-20] {
            for (y, x) in [
                (0.0, v),
                (v, 0.0),
                (v, v),
                (v, v * TAN_PI_8),
                (v * TAN_PI_8, v),
            ] {
                for (dy, dx) in [(0, 0), (1, 0), (0, 1)] {
                    let (y, x) = (
                        f32::from_bits(f32::to_bits(y) + dy),
                        f32::from_bits(f32::to_bits(x) + dx),
                    );
                    for (sy, sx) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
                        edges = edges.max(error(sy * y, sx * x));
                    }
                }
            }
        }
        println!(
            "atan2_f32 worst error: {worst:.3e} rad over 2^20 directions x 6 radii ({libm_worst:.3e} for libm's atan2f), \
             {edges:.3e} on axes and diagonals"
        );
        assert!(worst < 2.0e-7 && edges < 2.0e-7, "{worst:e} {edges:e}");
    }

    #[test]
    fn special_inputs_are_ieee() {
        for (y, x) in [
            (0.0, 0.0),
            (-0.0, 0.0),
            (0.0, -0.0),
            (-0.0, -0.0),
            (1.0, f32::INFINITY),
            (-1.0, f32::INFINITY),
            (f32::INFINITY, f32::INFINITY),
            (f32::INFINITY, f32::NEG_INFINITY),
            (f32::NEG_INFINITY, f32::INFINITY),
            (f32::NEG_INFINITY, f32::NEG_INFINITY),
            (1.0, f32::NEG_INFINITY),
            (-1.0, f32::NEG_INFINITY),
            (f32::INFINITY, 1.0),
            (f32::NEG_INFINITY, -1.0),
            (0.0, -1.0),
            (-0.0, -1.0),
            (1.0, 0.0),
            (-1.0, -0.0),
            (f32::NAN, f32::INFINITY),
            (f32::INFINITY, f32::NAN),
            (f32::NAN, 0.0),
            (f32::NAN, 1.0),
            (1.0, f32::NAN),
        ] {
            // IEEE's exact result (a multiple of π/4, 0 or NaN) rounded to f32. libm's `atan2f`
            // agrees except for a finite leg against an infinite one, where it rounds π/2 down.
            let (got, want) = (
                atan2_f32(y, x),
                libm::atan2(f64::from(y), f64::from(x)) as f32,
            );
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "atan2({y}, {x}) = {got}, not {want}"
            );
        }
        assert_eq!(atan2_f32(-0.0, 1.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(atan2_f32(-0.0, -1.0), -core::f32::consts::PI);
        assert_eq!(atan2_f32(1.0, -0.0), core::f32::consts::FRAC_PI_2);
    }
}
