//! Which model parameters the data can identify: the column-scaled SVD of the identification
//! Jacobian (`crate::numeric::svd`: `J·D⁻¹`, D = column norms, so mm and rad compare), rank and
//! condition number.
//!
//! Why: a confounded combination (e.g. with all data at one θ2 only the elbow B is seen, so
//! d, the encoder offset 2 and B0 trade off) makes the normal equations singular; fitting it
//! anyway returns arbitrary values with huge variances. We name the combination from the
//! smallest singular vector and fix one of its parameters at its nominal value, the one latest
//! in [`FIX_ORDER`] (base offset first, links last: the links are what the user asked for), then
//! repeat until the rest is identifiable.
//!
//! Cost: one SVD of a 2N x 8 matrix per fixed parameter. A relative singular value below
//! [`RANK_TOL`] counts as zero (finite-difference noise is ~1e-10); above it but with a condition
//! number over [`WARN_CONDITION`] the fit runs but is reported as poorly conditioned.

use super::params::{NAMES, N_PARAMS};
use crate::numeric::ScaledSvd;
use nalgebra::DMatrix;

/// Relative singular value treated as zero (the crate's one rank tolerance).
pub use crate::numeric::RANK_TOL;
/// Condition number above which the fit is reported as poorly conditioned.
pub const WARN_CONDITION: f64 = 1e4;
/// Which parameter to fix first when a combination is confounded (indices into `NAMES`).
pub const FIX_ORDER: [usize; N_PARAMS] = [5, 4, 9, 8, 7, 6, 3, 2, 1, 0];

/// The outcome of the check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Identifiability {
    /// Parameters fitted (indices into `NAMES`).
    pub free: Vec<usize>,
    /// `(parameter fixed, the confounded combination it was part of)`.
    pub fixed: Vec<(usize, String)>,
    /// Condition number of the scaled Jacobian of the free parameters.
    pub condition_number: f64,
    /// Rank of the scaled Jacobian of all parameters.
    pub rank_all: usize,
    /// Relative singular values of all parameters' scaled Jacobian, largest first.
    pub singular_values_rel: Vec<f64>,
}

/// Relative singular values (descending) and the scaled right singular vector of the smallest
/// one, of the columns `cols` of `j` ([`ScaledSvd`]: a zero column is its own null vector).
fn smallest(j: &DMatrix<f64>, cols: &[usize]) -> (Vec<f64>, Vec<f64>) {
    let svd = ScaledSvd::new(&j.select_columns(cols));
    (svd.relative(), svd.smallest_direction().to_vec())
}

/// Describes a null vector: `"+0.71·d_mm −0.71·base_b0_x_mm"` (scaled units).
fn describe(cols: &[usize], v: &[f64]) -> String {
    let mut terms: Vec<(usize, f64)> = cols
        .iter()
        .copied()
        .zip(v.iter().copied())
        .filter(|(_, c)| c.abs() > 0.05)
        .collect();
    terms.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    terms
        .iter()
        .map(|(k, c)| format!("{c:+.2}·{}", NAMES[*k]))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Checks `j` (2N x 8, see `params::jacobian`) with the parameters `fixed_by_user` held fixed.
pub fn check(j: &DMatrix<f64>, fixed_by_user: &[usize]) -> Identifiability {
    let all: Vec<usize> = (0..N_PARAMS).collect();
    let (rel_all, _) = smallest(j, &all);
    let rank_all = rel_all.iter().filter(|&&s| s > RANK_TOL).count();
    let mut free: Vec<usize> = all
        .iter()
        .copied()
        .filter(|k| !fixed_by_user.contains(k))
        .collect();
    let mut fixed = Vec::new();
    loop {
        let (rel, v) = smallest(j, &free);
        let min = rel.last().copied().unwrap_or(1.0);
        if min > RANK_TOL || free.is_empty() {
            let condition_number = if free.is_empty() { 1.0 } else { 1.0 / min };
            return Identifiability {
                free,
                fixed,
                condition_number,
                rank_all,
                singular_values_rel: rel_all,
            };
        }
        let combination = describe(&free, &v);
        let involved: Vec<usize> = free
            .iter()
            .copied()
            .zip(v.iter())
            .filter(|(_, c)| c.abs() > 0.05)
            .map(|(k, _)| k)
            .collect();
        let victim = FIX_ORDER
            .iter()
            .copied()
            .find(|k| involved.contains(k))
            .unwrap_or(free[free.len() - 1]);
        free.retain(|&k| k != victim);
        fixed.push((victim, combination));
    }
}
