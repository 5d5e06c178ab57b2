//! The paper's exhaustive subset search (Sec. III-C): fit on every choice of n of the N points
//! and keep the model whose largest error over all N points is smallest.
//!
//! Why: the paper ships the subset that minimises the maximum error; we reproduce it (Table I:
//! {1, 8} for `poly`, {1, 3, 4, 8} for `ls`). Cost: C(N, n) fits and N FKs each; searches over
//! more than [`MAX_SUBSETS`] candidates are refused (ask for a `--subset-size`). Progress goes to
//! stderr about once a second. Ties on the maximum are broken by the RMS, then by the earlier
//! subset in lexicographic order, so the result is deterministic.
//!
//! Progress (about once a second, and once at the end) goes to a callback ([`Progress`]): the
//! command line prints it on stderr.

use crate::calib::{invalid, CalibError};
use std::time::{Duration, Instant};

/// The largest number of candidate subsets a search may try.
pub const MAX_SUBSETS: u128 = 20_000_000;

/// The winner of a search.
#[derive(Clone, Debug)]
pub struct Best<M> {
    /// 0-based indices of the chosen points.
    pub subset: Vec<usize>,
    pub model: M,
    pub max_err_um: f64,
    pub rms_err_um: f64,
    /// How many subsets gave a model at all (others were degenerate or unreachable).
    pub tried: u64,
    pub valid: u64,
    /// Wall time of the search (s).
    pub elapsed_s: f64,
}

/// Which long step a [`Progress`] is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The subset search: `tried` of `total` subsets.
    SubsetSearch,
    /// Leave-one-out refits: `tried` of `total` points.
    LeaveOneOut,
}

/// Where a running search (or another long step of a fit, see [`Stage`]) is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    pub stage: Stage,
    pub tried: u64,
    pub total: u128,
    /// Best maximum error so far (µm; NaN before the first valid model).
    pub best_max_um: f64,
}

/// `C(n, k)` without overflow for the sizes we accept.
pub fn binomial(n: usize, k: usize) -> u128 {
    if k > n {
        return 0;
    }
    let k = k.min(n - k);
    (0..k).fold(1u128, |acc, i| acc * (n - i) as u128 / (i + 1) as u128)
}

/// Advances `c` (strictly increasing indices < n) to the next combination; false at the end.
pub fn next_combination(c: &mut [usize], n: usize) -> bool {
    let k = c.len();
    for i in (0..k).rev() {
        if c[i] < n - k + i {
            c[i] += 1;
            for j in i + 1..k {
                c[j] = c[j - 1] + 1;
            }
            return true;
        }
    }
    false
}

/// Tries every subset of every size in `sizes` of `n_points` points. `fit` returns the model
/// of a subset (or an error: degenerate subset, skipped); `score` the N errors (µm) of a model.
pub fn search<M: Clone>(
    n_points: usize,
    sizes: &[usize],
    mut fit: impl FnMut(&[usize]) -> Result<M, CalibError>,
    mut score: impl FnMut(&M) -> Vec<f64>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Best<M>, CalibError> {
    let total: u128 = sizes.iter().map(|&k| binomial(n_points, k)).sum();
    if total > MAX_SUBSETS {
        return Err(invalid!("subset search over {total} subsets of {n_points} points is too long (limit {MAX_SUBSETS}); give a smaller subset size"));
    }
    let started = Instant::now();
    let mut last_report = started;
    let mut best: Option<Best<M>> = None;
    let (mut tried, mut valid) = (0u64, 0u64);
    for &k in sizes {
        if k == 0 || k > n_points {
            return Err(invalid!(
                "subset size {k} is impossible with {n_points} points"
            ));
        }
        let mut c: Vec<usize> = (0..k).collect();
        loop {
            tried += 1;
            if let Ok(model) = fit(&c) {
                let errors = score(&model);
                let super::evaluate::MaxRms { max, rms } = super::evaluate::max_rms(&errors);
                if max.is_finite() {
                    valid += 1;
                    let better = match &best {
                        None => true,
                        Some(b) => {
                            max < b.max_err_um || (max == b.max_err_um && rms < b.rms_err_um)
                        }
                    };
                    if better {
                        best = Some(Best {
                            subset: c.clone(),
                            model,
                            max_err_um: max,
                            rms_err_um: rms,
                            tried,
                            valid,
                            elapsed_s: 0.0,
                        });
                    }
                }
            }
            if last_report.elapsed() > Duration::from_secs(1) {
                last_report = Instant::now();
                progress(Progress {
                    stage: Stage::SubsetSearch,
                    tried,
                    total,
                    best_max_um: best.as_ref().map_or(f64::NAN, |b| b.max_err_um),
                });
            }
            if !next_combination(&mut c, n_points) {
                break;
            }
        }
    }
    let mut best =
        best.ok_or_else(|| invalid!("no subset of the given size gives a valid model"))?;
    best.tried = tried;
    best.valid = valid;
    best.elapsed_s = started.elapsed().as_secs_f64();
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn enumerates_all_combinations() {
        let mut c = vec![0, 1, 2];
        let mut count = 1;
        while next_combination(&mut c, 6) {
            count += 1;
        }
        assert_eq!(count, 20);
        assert_eq!(binomial(9, 2), 36);
        assert_eq!(binomial(9, 4), 126);
    }
}
