//! How the selection scores a model: the cached fits of effect sets ([`Fitter`]), the σ² a
//! comparison uses ([`sigma2`]), the BIC and its differences, and the held-out RSS.
//!
//! Which σ: for every comparison of models σ² = max(noise², the smallest of the models'
//! residual variances RSS/(n−k)). With the noise known this is the textbook BIC as long as the
//! model is complete; when structure no effect explains is left, it falls back to the
//! F-test-like comparison against what is actually left, so an unmodelled cyclic error does not
//! make every tweak "significant". The same σ² scales the reported standard deviations.
//!
//! Cost: an LM fit per new effect set (cached by set), K small solves per cross-validation.

use super::fit::{cross_validated_rss, fit, Fit};
use super::forward_model::Problem;
use super::library::{Effect, N_PARAMS};
use std::collections::BTreeMap;

/// BIC decrease needed to add an effect.
pub const ADD_MARGIN: f64 = 10.0;
/// Residual degrees of freedom a model must keep per parameter (on few points, e.g. Table I's
/// 18 numbers, this caps the model at 6 parameters: more would fit the noise).
pub const MIN_DOF_PER_PARAM: f64 = 2.0;
/// BIC decrease needed to swap one effect for another.
pub const SWAP_MARGIN: f64 = 2.0;
/// Folds of the held-out validation (leave-one-point-out on at most [`LOO_POINTS`] points).
pub const CV_FOLDS: usize = 5;
/// Up to this many points the validation leaves one point out at a time.
pub const LOO_POINTS: usize = 20;

/// Fits of effect sets (with the problem's nuisances), cached by the sorted names.
pub struct Fitter<'a> {
    pub problem: &'a Problem,
    cache: BTreeMap<Vec<&'static str>, Option<Fit>>,
    cv_cache: BTreeMap<Vec<&'static str>, Option<f64>>,
}

pub fn key(set: &[&'static Effect]) -> Vec<&'static str> {
    let mut key: Vec<&'static str> = set.iter().map(|e| e.name()).collect();
    key.sort();
    key
}

impl<'a> Fitter<'a> {
    pub fn new(problem: &'a Problem) -> Self {
        Fitter {
            problem,
            cache: BTreeMap::new(),
            cv_cache: BTreeMap::new(),
        }
    }

    /// The LM fit of a set of effects, starting from `start` (entries outside the set ignored).
    ///
    /// Cached by set; a cached fit is refitted from a new start when that start's own RSS is
    /// already below the cached optimum (the cached fit stalled in a poorer minimum), and the
    /// better of the two is kept (its cross-validation is then recomputed). Why: the LM from a
    /// start far from the optimum can stop early (a stretch and a scale fitted from the stretch
    /// alone stalled at 5568 µm² where the same set fitted from zero or from a neighbouring
    /// model reaches 221 µm², the noise level); cached, that stall made the true model look
    /// worse than one with an extra, absent effect, whatever start was asked for later.
    /// Cost: one residual evaluation per cache hit with a start other than the cached fit's.
    pub fn fit(&mut self, set: &[&'static Effect], start: &[f64]) -> Option<Fit> {
        let key = key(set);
        let free = self.problem.free_params(set);
        if let Some(cached) = self.cache.get(&key) {
            let Some(c) = cached else { return None };
            let x: Vec<f64> = start
                .iter()
                .enumerate()
                .map(|(k, v)| if free.contains(&k) { *v } else { 0.0 })
                .collect();
            if x.as_slice() == c.p.as_slice() {
                return Some(c.clone());
            }
            let better_start = <[f64; N_PARAMS]>::try_from(x.as_slice())
                .ok()
                .and_then(|x| self.problem.residuals_um(&x))
                .is_some_and(|r| r.iter().map(|v| v * v).sum::<f64>() < c.cost);
            if !better_start {
                return Some(c.clone());
            }
            let c = c.clone();
            return match fit(self.problem, start, &free) {
                Some(g) if g.cost < c.cost => {
                    self.cache.insert(key.clone(), Some(g.clone()));
                    self.cv_cache.remove(&key);
                    Some(g)
                }
                _ => Some(c),
            };
        }
        let f = fit(self.problem, start, &free);
        self.cache.insert(key, f.clone());
        f
    }

    /// Cross-validated RSS (µm²) of a set's fit (see [`cross_validated_rss`]); `None` if the
    /// fit fails or a fold determines a parameter by itself.
    pub fn cv_rss(&mut self, set: &[&'static Effect], start: &[f64]) -> Option<f64> {
        let key = key(set);
        if let Some(v) = self.cv_cache.get(&key) {
            return *v;
        }
        let n = self.problem.points.len();
        let folds = if n <= LOO_POINTS { n } else { CV_FOLDS };
        let v = self
            .fit(set, start)
            .and_then(|f| cross_validated_rss(&f, n, folds));
        self.cv_cache.insert(key, v);
        v
    }
}

/// Number of scalar residuals.
pub fn n_res(p: &Problem) -> f64 {
    (2 * p.points.len()) as f64
}

/// The σ² (µm²) of a comparison of fits (module doc): max(noise², the smallest residual
/// variance RSS/(n−k) of `fits`), never below 1e-12. One fit: the σ² its standard deviations
/// are scaled by.
pub fn sigma2(p: &Problem, noise_um: Option<f64>, fits: &[&Fit]) -> f64 {
    let n = n_res(p);
    fits.iter()
        .map(|f| f.cost / (n - f.free.len() as f64).max(1.0))
        .fold(f64::INFINITY, f64::min)
        .max(noise_um.map(|s| s * s).unwrap_or(0.0))
        .max(1e-12)
}

/// The common σ² of a comparison of two fits ([`sigma2`] of both).
pub fn common_s2(p: &Problem, noise_um: Option<f64>, a: &Fit, b: &Fit) -> f64 {
    sigma2(p, noise_um, &[a, b])
}

/// The BIC score `RSS/σ² + k·ln n` of a fit with σ² = `s2` on `n` scalar residuals (module doc).
pub fn bic(f: &Fit, s2: f64, n: f64) -> f64 {
    f.cost / s2 + f.free.len() as f64 * n.ln()
}

/// BIC difference `score(b) − score(a)` with the common σ² described in the module doc.
pub fn delta_bic(p: &Problem, noise_um: Option<f64>, a: &Fit, b: &Fit) -> f64 {
    let n = n_res(p);
    let (ka, kb) = (a.free.len() as f64, b.free.len() as f64);
    (b.cost - a.cost) / common_s2(p, noise_um, a, b) + (kb - ka) * n.ln()
}

/// The fit of no parameters at all (when even the base model has no forward solution).
pub fn empty_fit(problem: &Problem) -> Fit {
    let m = 2 * problem.points.len();
    let jacobian = nalgebra::DMatrix::zeros(m, 0);
    Fit {
        p: vec![0.0; N_PARAMS],
        free: vec![],
        residuals: nalgebra::DVector::zeros(m),
        cost: 0.0,
        cost_history: vec![0.0],
        iterations: 0,
        rejected_steps: 0,
        stop: crate::numeric::Stop::NoFreeParameters,
        svd: crate::numeric::ScaledSvd::new(&jacobian),
        jacobian,
        normal_pinv: nalgebra::DMatrix::zeros(0, 0),
    }
}
