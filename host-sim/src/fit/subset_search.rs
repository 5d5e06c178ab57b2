//! The paper's exhaustive subset search (Sec. III-C): fit on every choice of n of the N points
//! and keep the model whose largest error over all N points is smallest.
//!
//! Why: the paper ships the subset that minimises the maximum error; we reproduce it (Table I:
//! {1, 8} for `poly`, {1, 3, 4, 8} for `ls`). Cost: C(N, n) fits and N FKs each; searches over
//! more than [`MAX_SUBSETS`] candidates are refused (ask for a `--subset-size`). Progress goes to
//! stderr about once a second. Ties on the maximum are broken by the RMS, then by the earlier
//! subset in lexicographic order, so the result is deterministic.

use anyhow::{bail, Result};
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
    mut fit: impl FnMut(&[usize]) -> Result<M>,
    mut score: impl FnMut(&M) -> Vec<f64>,
) -> Result<Best<M>> {
    let total: u128 = sizes.iter().map(|&k| binomial(n_points, k)).sum();
    if total > MAX_SUBSETS {
        bail!("subset search over {total} subsets of {n_points} points is too long (limit {MAX_SUBSETS}); give a smaller --subset-size");
    }
    let started = Instant::now();
    let mut last_report = started;
    let mut best: Option<Best<M>> = None;
    let (mut tried, mut valid) = (0u64, 0u64);
    for &k in sizes {
        if k == 0 || k > n_points {
            bail!("subset size {k} is impossible with {n_points} points");
        }
        let mut c: Vec<usize> = (0..k).collect();
        loop {
            tried += 1;
            if let Ok(model) = fit(&c) {
                let errors = score(&model);
                let (max, rms) = super::evaluate::max_rms(&errors);
                if max.is_finite() {
                    valid += 1;
                    let better = match &best {
                        None => true,
                        Some(b) => max < b.max_err_um || (max == b.max_err_um && rms < b.rms_err_um),
                    };
                    if better {
                        best = Some(Best { subset: c.clone(), model, max_err_um: max, rms_err_um: rms, tried, valid });
                    }
                }
            }
            if last_report.elapsed() > Duration::from_secs(1) {
                last_report = Instant::now();
                let b = best.as_ref().map_or(f64::NAN, |b| b.max_err_um);
                eprintln!("subset search: {tried}/{total} subsets, best max error so far {b:.1} µm");
            }
            if !next_combination(&mut c, n_points) {
                break;
            }
        }
    }
    let mut best = best.ok_or_else(|| anyhow::anyhow!("no subset of the given size gives a valid model"))?;
    best.tried = tried;
    best.valid = valid;
    eprintln!(
        "subset search: {tried} subsets tried ({valid} valid) in {:.2} s; best max error {:.1} µm",
        started.elapsed().as_secs_f64(),
        best.max_err_um
    );
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
