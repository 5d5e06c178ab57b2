//! THE Levenberg–Marquardt solver: minimises `Σ r(p)²` over the free entries of a parameter
//! vector, for the calibration's `fit --method full` and every fit of the diagnosis.
//!
//! Method: damped Gauss–Newton with Marquardt's diagonal scaling,
//! `(JᵀJ + λ·diag(JᵀJ)) δ = −Jᵀr`, J by central differences ([`super::finite_difference`]).
//! λ starts at 1e-3, is divided by 10 (down to 1e-12) after an accepted step and multiplied by
//! 10 after a rejected one. Cost per iteration: one Jacobian (2k residual evaluations for k free
//! parameters), a k × k Cholesky per trial, one residual evaluation per trial.
//!
//! Behaviour, each chosen deliberately when the two loops this replaces (`fit/
//! levenberg_marquardt.rs` and `diagnose/lm.rs`) disagreed:
//! * **Acceptance: the cost must strictly decrease** (`c_trial < c`, which also refuses NaN).
//!   Accepting equal costs (`<=`) lets the iterate wander along a plateau at rounding level and
//!   makes "the accepted cost never increases" a property of luck; strict decrease makes the
//!   cost history a strictly decreasing sequence (asserted by `tests/lm.rs`).
//! * **Stopping: relative cost decrease below 1e-14 on an accepted step, or a step below 1e-6 of
//!   every parameter's finite-difference step, or no decrease found.** 1e-14 is the rounding
//!   level of a sum of squares; the diagnosis' former 1e-10 stopped ~3e-4 standard deviations
//!   short of the optimum (harmless, but not the optimum). The price, measured on the
//!   diagnosis tests (dev profile, CPU time): `tests/diagnose.rs` 16 → 17.7 s,
//!   `tests/diagnose_plant.rs` 2.8 → 3.7 s. The step test is relative to each parameter's own scale (its
//!   finite-difference step: 1e-12 mm and 1e-14 rad for the five-bar, as before, 1e-8 µm for
//!   the diagnosis' µm units) instead of one absolute norm mixing millimetres and radians.
//! * **Retries: up to 30 λ increases per iteration**, but a rejected step already below the step
//!   tolerance ends the search at once (further damping only shrinks it: the point is
//!   stationary to rounding). 30 (a factor 1e30 on λ) lets a start far from the optimum, where
//!   Gauss–Newton steps overshoot by orders of magnitude, find its way (the Rosenbrock test);
//!   the early exit keeps the cost of convergence at rounding level to one or two trials.
//! * **Diagonal floor: `max(JᵀJ_dd, 1e-12·max_d JᵀJ_dd)`**, relative, so a parameter with no
//!   effect still gets damped, in any units (the former floors, 1e-30 and 1e-12 absolute, meant
//!   different things in mm and in µm).
//! * **Covariance: the pseudo-inverse `(JᵀJ)⁺` from the column-scaled SVD** of J at the
//!   solution ([`super::svd`], relative tolerance [`super::svd::RANK_TOL`]), not `inverse(JᵀJ)`:
//!   no squared condition number, and a rank-deficient solution still has a defined covariance
//!   within its identified subspace. The result says its rank and smallest singular value; the
//!   callers decide (the `full` fit refuses a deficient rank, the diagnosis reports the effect
//!   as not identifiable). Multiply by the σ² of the caller's choice ([`LmFit::covariance`]).
//! * Iteration limit 200 (neither caller comes near it); reaching it is reported in
//!   [`LmFit::stop`], not an error.

use super::finite_difference::jacobian;
use super::svd::{ScaledSvd, RANK_TOL};
use super::NumericError;
use nalgebra::{DMatrix, DVector};

/// A least-squares problem: residuals of a parameter vector.
pub trait Residuals {
    /// Length of the parameter vector.
    fn n_params(&self) -> usize;
    /// The residual vector at `p` (any sign convention, used consistently); `None` where the
    /// model is not defined (an unreachable pose, an invalid parameter set).
    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>>;
    /// Central-difference step of parameter `k`, in its own units (see
    /// [`super::finite_difference`]); also the scale of the step tolerance.
    fn fd_step(&self, k: usize) -> f64;
    /// The residuals at the neighbours of `at` (points that differ from it in one parameter,
    /// the finite-difference Jacobian's): a function of the neighbour `q` and the parameter `k`
    /// it differs in, which must return exactly what `residuals(q)` returns. A problem whose
    /// parameters leave part of its work unchanged does that part once for all of them; the
    /// default evaluates [`Residuals::residuals`].
    fn neighbours<'a>(&'a self, at: &[f64]) -> Neighbours<'a> {
        let _ = at;
        Box::new(move |q, _k| self.residuals(q))
    }
}

/// What [`Residuals::neighbours`] returns: residuals of a neighbour `q` differing in `k`.
pub type Neighbours<'a> = Box<dyn FnMut(&[f64], usize) -> Option<DVector<f64>> + 'a>;

/// The solver's settings (defaults: the behaviour documented in the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// λ increases tried per iteration before giving up on a decrease.
    pub max_retries: usize,
    pub initial_lambda: f64,
    pub min_lambda: f64,
    /// Stop after an accepted step that lowered the cost by less than this fraction.
    pub cost_rel_tol: f64,
    /// Stop when no parameter moves by more than this fraction of its finite-difference step.
    pub step_rel_tol: f64,
    /// Floor of the damping diagonal, relative to the largest diagonal entry of `JᵀJ`.
    pub diag_floor_rel: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 200,
            max_retries: 30,
            initial_lambda: 1e-3,
            min_lambda: 1e-12,
            cost_rel_tol: 1e-14,
            step_rel_tol: 1e-6,
            diag_floor_rel: 1e-12,
        }
    }
}

/// Why the iteration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// Nothing to fit.
    NoFreeParameters,
    /// An accepted step lowered the cost by less than `cost_rel_tol`.
    CostTolerance,
    /// The step fell below `step_rel_tol` of every parameter's scale.
    StepTolerance,
    /// No trial in `max_retries` lowered the cost: stationary to rounding.
    NoDecrease,
    /// `max_iterations` reached.
    MaxIterations,
}

/// A solution with what is needed to judge it.
#[derive(Clone, Debug)]
pub struct LmFit {
    /// The whole parameter vector (entries outside `free` as given at the start).
    pub p: Vec<f64>,
    /// Indices of the fitted parameters.
    pub free: Vec<usize>,
    /// Residuals at the solution.
    pub residuals: DVector<f64>,
    /// `Σ r²` at the solution.
    pub cost: f64,
    /// The start's cost, then the cost after every accepted step: strictly decreasing.
    pub cost_history: Vec<f64>,
    /// Jacobians evaluated (outer iterations).
    pub iterations: usize,
    /// Trial steps refused because they did not lower the cost (or left the domain).
    pub rejected_steps: usize,
    pub stop: Stop,
    /// `∂r/∂p` at the solution, one column per free parameter.
    pub jacobian: DMatrix<f64>,
    /// The column-scaled SVD of `jacobian`.
    pub svd: ScaledSvd,
    /// `(JᵀJ)⁺` (free parameters, the order of `free`): the covariance for σ² = 1.
    pub normal_pinv: DMatrix<f64>,
}

impl LmFit {
    /// Residual degrees of freedom `n − k` (at least 1).
    pub fn dof(&self) -> usize {
        self.residuals.len().saturating_sub(self.free.len()).max(1)
    }

    /// `cost / (n − k)`: the residual variance per residual, the textbook σ² estimate.
    pub fn residual_variance(&self) -> f64 {
        self.cost / self.dof() as f64
    }

    /// `σ²·(JᵀJ)⁺` of the free parameters.
    pub fn covariance(&self, sigma2: f64) -> DMatrix<f64> {
        &self.normal_pinv * sigma2
    }

    /// One standard deviation of parameter `k` of the full vector with residual variance
    /// `sigma2`; `None` if `k` was not fitted.
    pub fn std_dev(&self, k: usize, sigma2: f64) -> Option<f64> {
        let c = self.free.iter().position(|&f| f == k)?;
        Some((self.normal_pinv[(c, c)] * sigma2).max(0.0).sqrt())
    }

    /// Rank of the Jacobian at the solution (relative tolerance [`RANK_TOL`]).
    pub fn rank(&self) -> usize {
        self.svd.rank(RANK_TOL)
    }
}

/// Fits the parameters `free` of `problem` from `p0` (see the module doc).
pub fn levenberg_marquardt<R: Residuals + ?Sized>(
    problem: &R,
    p0: &[f64],
    free: &[usize],
    opts: &LmOptions,
) -> Result<LmFit, NumericError> {
    let mut p = p0.to_vec();
    let mut r = problem
        .residuals(&p)
        .ok_or(NumericError::StartOutsideDomain)?;
    let mut cost = r.norm_squared();
    if !cost.is_finite() {
        return Err(NumericError::StartOutsideDomain);
    }
    let mut history = vec![cost];
    let (mut iterations, mut rejected) = (0usize, 0usize);
    let mut lambda = opts.initial_lambda;
    let h: Vec<f64> = free.iter().map(|&k| problem.fd_step(k)).collect();
    let mut stop = if free.is_empty() {
        Stop::NoFreeParameters
    } else {
        Stop::MaxIterations
    };
    while !free.is_empty() && iterations < opts.max_iterations {
        iterations += 1;
        let j = jacobian(problem, &p, free)?;
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let floor = opts.diag_floor_rel * jtj.diagonal().max();
        let (mut accepted, mut outcome) = (false, None);
        for _ in 0..opts.max_retries {
            let mut a = jtj.clone();
            for d in 0..free.len() {
                a[(d, d)] += lambda * jtj[(d, d)].max(floor);
            }
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = chol.solve(&(-&g));
            let small = delta
                .iter()
                .zip(&h)
                .all(|(d, h)| d.abs() <= opts.step_rel_tol * h);
            let mut trial = p.clone();
            for (d, &k) in free.iter().enumerate() {
                trial[k] += delta[d];
            }
            let trial_r = problem.residuals(&trial);
            let trial_cost = trial_r.as_ref().map_or(f64::INFINITY, |t| t.norm_squared());
            if trial_cost < cost {
                let rel = (cost - trial_cost) / cost;
                p = trial;
                r = trial_r.expect("a finite cost has residuals");
                cost = trial_cost;
                history.push(cost);
                lambda = (lambda / 10.0).max(opts.min_lambda);
                accepted = true;
                outcome = if small {
                    Some(Stop::StepTolerance)
                } else if rel < opts.cost_rel_tol {
                    Some(Stop::CostTolerance)
                } else {
                    None
                };
                break;
            }
            rejected += 1;
            if small {
                outcome = Some(Stop::NoDecrease);
                break;
            }
            lambda *= 10.0;
        }
        if let Some(s) = outcome {
            stop = s;
            break;
        }
        if !accepted {
            stop = Stop::NoDecrease;
            break;
        }
    }
    let jacobian = jacobian(problem, &p, free)?;
    let svd = ScaledSvd::new(&jacobian);
    let normal_pinv = svd.normal_pseudo_inverse(RANK_TOL);
    Ok(LmFit {
        p,
        free: free.to_vec(),
        residuals: r,
        cost,
        cost_history: history,
        iterations,
        rejected_steps: rejected,
        stop,
        jacobian,
        svd,
        normal_pinv,
    })
}
