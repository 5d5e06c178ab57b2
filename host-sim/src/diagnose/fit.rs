//! The diagnosis' fits: the effect parameter vector of a [`Problem`] solved by the crate's one
//! Levenberg–Marquardt (`crate::numeric::lm`, whose module doc states its rules), the free
//! entries being those of the active effects, all fitted jointly.
//!
//! Jacobian by central differences (step 1e-2 in internal units: 10 nm, 10 nrad, 0.01 ppm —
//! far below every effect, far above rounding at 200 mm). The residual is measured − predicted
//! (µm), so the Jacobian is minus that of the prediction; only its column spaces, projections and
//! the covariance are used, none of which depend on the sign. Cost per iteration: 2k+1 residual
//! evaluations (k free parameters) plus a k×k solve; typically 3–10 iterations since every model
//! here is nearly linear in its small parameters.

use super::effects::{Problem, N_PARAMS};
use crate::numeric::{finite_difference, levenberg_marquardt, LmFit, LmOptions, Residuals};
use nalgebra::{DMatrix, DVector};

/// A fit of the diagnosis: [`LmFit`] over the [`N_PARAMS`] effect parameters (`p`, inactive
/// entries zero; `residuals` in µm, x,y interleaved; `cost` = RSS in µm²).
pub type Fit = LmFit;

const STEP: f64 = 1e-2;

impl Residuals for Problem {
    fn n_params(&self) -> usize {
        N_PARAMS
    }

    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
        let x: &[f64; N_PARAMS] = p.try_into().ok()?;
        self.residuals_um(x).map(DVector::from_vec)
    }

    fn fd_step(&self, _k: usize) -> f64 {
        STEP
    }
}

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
