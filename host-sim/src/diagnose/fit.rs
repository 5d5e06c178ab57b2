//! The diagnosis' fits: the effect parameter vector of a [`Problem`] solved by the crate's one
//! Levenberg–Marquardt (`crate::numeric::lm`, whose module doc states its rules), the free
//! entries being those of the active effects, all fitted jointly.
//!
//! Jacobian by central differences (the step is the forward model's, `forward_model.rs`). The
//! residual is measured − predicted
//! (µm), so the Jacobian is minus that of the prediction; only its column spaces, projections and
//! the covariance are used, none of which depend on the sign. Cost per iteration: 2k+1 residual
//! evaluations (k free parameters) plus a k×k solve; typically 3–10 iterations since every model
//! here is nearly linear in its small parameters.

use super::forward_model::Problem;
use crate::numeric::{finite_difference, levenberg_marquardt, LmFit, LmOptions};
use nalgebra::{DMatrix, DVector};

/// A fit of the diagnosis: [`LmFit`] over the [`N_PARAMS`](super::library::N_PARAMS) effect parameters (`p`, inactive
/// entries zero; `residuals` in µm, x,y interleaved; `cost` = RSS in µm²).
pub type Fit = LmFit;

/// Jacobian of the residual w.r.t. the parameters `cols`, central differences; `None` if a
/// neighbour has no forward solution.
pub fn jacobian(problem: &Problem, x: &[f64], cols: &[usize]) -> Option<DMatrix<f64>> {
    finite_difference::jacobian(problem, x, cols).ok()
}

/// Fits the free parameters starting from `x0` (entries outside `free` are set to zero). `None`
/// if the start or a finite-difference neighbour has no forward solution.
pub fn fit(problem: &Problem, x0: &[f64], free: &[usize]) -> Option<Fit> {
    let mut x = x0.to_vec();
    for (k, v) in x.iter_mut().enumerate() {
        if !free.contains(&k) {
            *v = 0.0;
        }
    }
    levenberg_marquardt(problem, &x, free, &LmOptions::default()).ok()
}

/// K-fold cross-validated RSS (µm²) of a fit: each fold's residuals as a fit to the other
/// points would leave them, `r_F⁽⁻ᶠ⁾ = (I − H_FF)⁻¹·r_F` with `H = J·(JᵀJ)⁺·Jᵀ` the fit's hat
/// matrix (J at the solution, every free parameter, nuisances included). Exact for a linear
/// least-squares problem and, the models here being nearly linear in their small parameters, a
/// held-out test without refitting: what makes it affordable inside the selection (one
/// |F|-sized solve per fold instead of an LM fit). Folds by point index (`i mod folds`), a
/// point's x and y together. `None` if a fold determines a parameter by itself (I − H_FF
/// singular).
pub fn cross_validated_rss(fit: &Fit, n_points: usize, folds: usize) -> Option<f64> {
    let k = fit.free.len();
    if k == 0 {
        return Some(fit.cost);
    }
    let mut rss = 0.0;
    for fold in 0..folds.max(1) {
        let rows: Vec<usize> = (0..n_points)
            .filter(|i| i % folds == fold)
            .flat_map(|i| [2 * i, 2 * i + 1])
            .collect();
        if rows.is_empty() {
            continue;
        }
        let jf = DMatrix::from_fn(rows.len(), k, |r, c| fit.jacobian[(rows[r], c)]);
        let h = &jf * &fit.normal_pinv * jf.transpose();
        let a = DMatrix::<f64>::identity(rows.len(), rows.len()) - h;
        let r = DVector::from_iterator(rows.len(), rows.iter().map(|&i| fit.residuals[i]));
        let held_out = a.lu().solve(&r)?;
        if !held_out.iter().all(|v| v.is_finite()) {
            return None;
        }
        rss += held_out.norm_squared();
    }
    Some(rss)
}
