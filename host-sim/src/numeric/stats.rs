//! Summary figures of error lists, and the rounding of figures in reports.
//!
//! One max/RMS for the whole crate (fit summaries, grid nodes, the demo's accuracy, the
//! diagnosis' gap table): a struct with named fields, so the two figures cannot be swapped.
//! Cost: one pass.

use serde::Serialize;

/// The largest value and the root mean square of a list of error magnitudes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MaxRms {
    pub max: f64,
    pub rms: f64,
}

impl MaxRms {
    /// Max and RMS from squared magnitudes: the one implementation (the max is the square root
    /// of the largest square, which is exactly the largest magnitude in IEEE arithmetic).
    pub fn from_squares(squares: impl IntoIterator<Item = f64>) -> MaxRms {
        let (mut n, mut sum, mut max_sq) = (0usize, 0.0, 0.0f64);
        for q in squares {
            n += 1;
            sum += q;
            max_sq = max_sq.max(q);
        }
        MaxRms {
            max: max_sq.sqrt(),
            rms: (sum / n.max(1) as f64).sqrt(),
        }
    }
}

/// Max and RMS of error magnitudes (0, 0 for an empty list; an infinite entry makes both
/// infinite, which is how an unreachable pose shows in a fit's errors).
pub fn max_rms(errors: &[f64]) -> MaxRms {
    MaxRms::from_squares(errors.iter().map(|e| e * e))
}

/// Max and RMS of the lengths of 2-D error vectors stored x, y interleaved (the diagnosis'
/// residuals): the radial error per point, from the squared components directly.
pub fn max_rms_radial(xy: &[f64]) -> MaxRms {
    MaxRms::from_squares(xy.chunks(2).map(|c| c.iter().map(|v| v * v).sum::<f64>()))
}

/// The median of `values` (the upper one of an even count), reordering them; `None` when empty.
/// Cost: O(N) (selection, no sort).
pub fn median(values: &mut [f64]) -> Option<f64> {
    let mid = values.len() / 2;
    (!values.is_empty()).then(|| *values.select_nth_unstable_by(mid, f64::total_cmp).1)
}

/// `v` rounded to `decimals` decimals (for JSON figures: 3 for µm, 6 for mm and degrees).
pub fn round_to(v: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (v * f).round() / f
}

/// `v` to 3 decimals.
pub fn round3(v: f64) -> f64 {
    round_to(v, 3)
}

/// `v` to 6 decimals.
pub fn round6(v: f64) -> f64 {
    round_to(v, 6)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn max_and_rms() {
        assert_eq!(
            max_rms(&[3.0, 4.0]),
            MaxRms {
                max: 4.0,
                rms: 12.5f64.sqrt()
            }
        );
        assert_eq!(max_rms(&[]), MaxRms { max: 0.0, rms: 0.0 });
        assert_eq!(max_rms(&[1.0, f64::INFINITY]).max, f64::INFINITY);
        // Two points: (3, 4) and (0, 0): radial 5 and 0.
        assert_eq!(
            max_rms_radial(&[3.0, 4.0, 0.0, 0.0]),
            MaxRms {
                max: 5.0,
                rms: 12.5f64.sqrt()
            }
        );
        assert_eq!(median(&mut [5.0, 1.0, 3.0]), Some(3.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(median(&mut []), None);
        assert_eq!((round3(1.23456), round6(-0.1234564)), (1.235, -0.123456));
    }
}
