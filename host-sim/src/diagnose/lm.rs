//! A small Levenberg–Marquardt for the diagnosis fits: the free entries of the effect parameter
//! vector, all active effects jointly.
//!
//! Why its own: the diagnosis fits many small models (one per candidate per selection round) and
//! needs the Jacobian at the solution for standard deviations and the confounding analysis.
//! The calibration's `fit --method full` has its own; the lead will unify them later.
//!
//! Jacobian by central differences (step 1e-2 in internal units: 10 nm, 10 nrad, 0.01 ppm —
//! far below every effect, far above rounding at 200 mm). Damping: Marquardt's diagonal scaling,
//! λ ×10 on a rejected step, ÷10 on an accepted one. Cost per iteration: 2k+1 residual
//! evaluations (k free parameters) plus a k×k solve; typically 3–10 iterations since every model
//! here is nearly linear in its small parameters.

use super::effects::{Problem, N_PARAMS};
use nalgebra::{DMatrix, DVector};

/// The result of one fit.
#[derive(Clone, Debug)]
pub struct Fit {
    /// Full parameter vector (inactive entries zero).
    pub x: [f64; N_PARAMS],
    /// Indices of the free parameters.
    pub free: Vec<usize>,
    /// Residuals at the solution (µm, x,y interleaved).
    pub residual_um: Vec<f64>,
    /// Sum of squared residuals (µm²).
    pub rss: f64,
    /// Jacobian of the *prediction* w.r.t. the free parameters at the solution (rows as residuals).
    pub jacobian: DMatrix<f64>,
    /// (JᵀJ)⁻¹ (pseudo-inverse when singular); multiply by σ² for the covariance.
    pub jtj_inv: DMatrix<f64>,
    /// Smallest singular value of the column-normalised Jacobian (0 = not identifiable).
    pub min_singular: f64,
}

const STEP: f64 = 1e-2;

/// Jacobian of the prediction (= −∂residual) w.r.t. the free parameters, central differences.
pub fn jacobian(problem: &Problem, x: &[f64; N_PARAMS], free: &[usize]) -> Option<DMatrix<f64>> {
    let m = 2 * problem.points.len();
    let mut j = DMatrix::zeros(m, free.len());
    for (col, &k) in free.iter().enumerate() {
        let mut xp = *x;
        let mut xm = *x;
        xp[k] += STEP;
        xm[k] -= STEP;
        let rp = problem.residuals_um(&xp)?;
        let rm = problem.residuals_um(&xm)?;
        for i in 0..m {
            // prediction = measured − residual
            j[(i, col)] = -(rp[i] - rm[i]) / (2.0 * STEP);
        }
    }
    Some(j)
}

/// Fits the free parameters starting from `x0`. `None` if the start has no forward solution.
pub fn fit(problem: &Problem, x0: &[f64; N_PARAMS], free: &[usize]) -> Option<Fit> {
    let mut x = *x0;
    for k in 0..N_PARAMS {
        if !free.contains(&k) {
            x[k] = 0.0;
        }
    }
    let mut r = problem.residuals_um(&x)?;
    let mut rss: f64 = r.iter().map(|v| v * v).sum();
    let mut lambda = 1e-3;
    if !free.is_empty() {
        for _iter in 0..50 {
            let j = jacobian(problem, &x, free)?;
            let jtj = j.transpose() * &j;
            let g = j.transpose() * DVector::from_column_slice(&r);
            let mut accepted = false;
            for _ in 0..12 {
                let mut a = jtj.clone();
                for d in 0..free.len() {
                    a[(d, d)] += lambda * jtj[(d, d)].max(1e-12);
                }
                let Some(step) = a.clone().cholesky().map(|c| c.solve(&g)) else {
                    lambda *= 10.0;
                    continue;
                };
                let mut xn = x;
                for (col, &k) in free.iter().enumerate() {
                    xn[k] += step[col];
                }
                if let Some(rn) = problem.residuals_um(&xn) {
                    let rssn: f64 = rn.iter().map(|v| v * v).sum();
                    if rssn <= rss {
                        let rel = (rss - rssn) / rss.max(1e-300);
                        x = xn;
                        r = rn;
                        rss = rssn;
                        lambda = (lambda / 10.0).max(1e-12);
                        accepted = true;
                        if rel < 1e-10 {
                            return finish(problem, x, free, r, rss);
                        }
                        break;
                    }
                }
                lambda *= 10.0;
            }
            if !accepted {
                break;
            }
        }
    }
    finish(problem, x, free, r, rss)
}

fn finish(problem: &Problem, x: [f64; N_PARAMS], free: &[usize], r: Vec<f64>, rss: f64) -> Option<Fit> {
    let j = jacobian(problem, &x, free)?;
    let jtj = j.transpose() * &j;
    let jtj_inv = if free.is_empty() {
        DMatrix::zeros(0, 0)
    } else {
        jtj.clone().pseudo_inverse(1e-12).unwrap_or_else(|_| DMatrix::zeros(free.len(), free.len()))
    };
    let min_singular = if free.is_empty() {
        f64::INFINITY
    } else {
        let mut jn = j.clone();
        for mut c in jn.column_iter_mut() {
            let n = c.norm();
            if n > 0.0 {
                c /= n;
            }
        }
        jn.singular_values().min()
    };
    Some(Fit { x, free: free.to_vec(), residual_um: r, rss, jacobian: j, jtj_inv, min_singular })
}
