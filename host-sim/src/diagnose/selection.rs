//! Stepwise selection of effects: forward (add the best significant candidate), then backward and
//! swap passes while the score improves, repeated until nothing changes.
//!
//! Why not forward only: one flexible effect can soak up parts of two simple ones early on; the
//! removal and swap passes undo that once the simple ones are in.
//!
//! Score: BIC = RSS/σ² + k·ln n (n scalar residuals, k free parameters). Which σ: for every
//! comparison of two models σ² = max(noise², the smaller of the two models' residual variances
//! RSS/(n−k)). With the noise known this is the textbook BIC as long as the model is complete;
//! when structure no effect explains is left, it falls back to the F-test-like comparison against
//! what is actually left, so an unmodelled cyclic error does not make every tweak "significant".
//! BIC rather than AIC: its penalty (7 per parameter at n ≈ 1300) keeps false positives on clean
//! data rare; an effect is added only if it lowers the BIC by more than [`ADD_MARGIN`] ("very
//! strong" evidence on the Kass–Raftery scale). Cost: each round fits every remaining candidate
//! (≤ 8 LM fits); results are cached by effect set.

use super::effects::{free_params, Effect, Problem, LIBRARY, N_PARAMS};
use super::fit::{fit, Fit};
use std::collections::BTreeMap;

/// BIC decrease needed to add an effect.
pub const ADD_MARGIN: f64 = 10.0;
/// Residual degrees of freedom a model must keep per parameter (on few points, e.g. Table I's
/// 18 numbers, this caps the model at 6 parameters: more would fit the noise).
pub const MIN_DOF_PER_PARAM: f64 = 2.0;
/// BIC decrease needed to swap one effect for another.
pub const SWAP_MARGIN: f64 = 2.0;

/// What the selection decided.
pub struct Selection {
    /// Effects of the final model, in the order they were (last) added.
    pub effects: Vec<&'static Effect>,
    /// The fit of the final model.
    pub fit: Fit,
    /// Human-readable decisions, in order.
    pub log: Vec<String>,
    /// Effects that could not be tried (with the reason).
    pub skipped: Vec<String>,
}

/// Fits of effect sets, cached by the sorted names.
pub struct Fitter<'a> {
    pub problem: &'a Problem,
    cache: BTreeMap<Vec<&'static str>, Option<Fit>>,
}

impl<'a> Fitter<'a> {
    pub fn new(problem: &'a Problem) -> Self {
        Fitter { problem, cache: BTreeMap::new() }
    }

    /// The LM fit of a set of effects, starting from `start` (entries outside the set ignored).
    pub fn fit(&mut self, set: &[&'static Effect], start: &[f64]) -> Option<Fit> {
        let mut key: Vec<&'static str> = set.iter().map(|e| e.name()).collect();
        key.sort();
        if let Some(f) = self.cache.get(&key) {
            return f.clone();
        }
        let f = fit(self.problem, start, &free_params(set));
        self.cache.insert(key, f.clone());
        f
    }
}

/// Number of scalar residuals.
fn n_res(p: &Problem) -> f64 {
    (2 * p.points.len()) as f64
}

/// BIC difference `score(b) − score(a)` with the common σ² described in the module doc.
pub fn delta_bic(p: &Problem, noise_um: Option<f64>, a: &Fit, b: &Fit) -> f64 {
    let n = n_res(p);
    let (ka, kb) = (a.free.len() as f64, b.free.len() as f64);
    let va = a.cost / (n - ka).max(1.0);
    let vb = b.cost / (n - kb).max(1.0);
    let s2 = va.min(vb).max(noise_um.map(|s| s * s).unwrap_or(0.0)).max(1e-12);
    (b.cost - a.cost) / s2 + (kb - ka) * n.ln()
}

/// Runs the stepwise selection from the empty set (the base model).
pub fn select(problem: &Problem, noise_um: Option<f64>) -> Selection {
    let mut fitter = Fitter::new(problem);
    let mut log = Vec::new();
    let mut skipped = Vec::new();
    let candidates: Vec<&'static Effect> = LIBRARY
        .iter()
        .filter(|e| match problem.available(e) {
            Ok(()) => true,
            Err(why) => {
                skipped.push(why);
                false
            }
        })
        .collect();
    let n = n_res(problem);
    let zero = [0.0; N_PARAMS];
    let mut set: Vec<&'static Effect> = Vec::new();
    // The base model always has a forward solution at the kept points (Problem drops the others).
    let mut cur = match fitter.fit(&set, &zero) {
        Some(f) => f,
        None => {
            log.push("the base model has no forward solution at some point".into());
            return Selection { effects: set, fit: empty_fit(problem), log, skipped };
        }
    };
    for _round in 0..3 * LIBRARY.len() {
        if let Some(s) = noise_um {
            let k = cur.free.len() as f64;
            if cur.cost / (n - k).max(1.0) < s * s {
                log.push(format!(
                    "residual at the noise level ({:.2} µm RMS per axis ≤ {s} µm): stop",
                    (cur.cost / n).sqrt()
                ));
                break;
            }
        }
        // Forward: best candidate.
        let mut best: Option<(f64, &'static Effect, Fit)> = None;
        let mut tried = Vec::new();
        for &c in &candidates {
            if set.contains(&c) {
                continue;
            }
            let k_new = (cur.free.len() + c.params.len()) as f64;
            if n - k_new < MIN_DOF_PER_PARAM * k_new {
                tried.push(format!("{} not tried: {} parameters on {} residuals", c.name(), k_new, n));
                continue;
            }
            let mut trial = set.clone();
            trial.push(c);
            let Some(f) = fitter.fit(&trial, &cur.p) else {
                tried.push(format!("{} fit failed (a point left the model's workspace)", c.name()));
                continue;
            };
            {
                let d = delta_bic(problem, noise_um, &cur, &f);
                tried.push(format!("{} rms {:.1} µm ΔBIC {:.1}", c.name(), (2.0 * f.cost / n).sqrt(), d));
                if best.as_ref().is_none_or(|b| d < b.0) {
                    best = Some((d, c, f));
                }
            }
        }
        log.push(format!(
            "candidates on top of [{}]: {}",
            set.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
            tried.join("; ")
        ));
        let Some((d, c, f)) = best else { break };
        if d > -ADD_MARGIN {
            log.push(format!("no candidate significant (best {} ΔBIC {:.1} > −{ADD_MARGIN}): stop", c.name(), d));
            break;
        }
        log.push(format!("add {} (ΔBIC {:.1})", c.name(), d));
        set.push(c);
        cur = f;
        // Backward and swap passes while they improve the score.
        let mut changed = true;
        while changed {
            changed = false;
            for i in 0..set.len() {
                if set.len() < 2 {
                    break;
                }
                let mut trial = set.clone();
                let removed = trial.remove(i);
                if let Some(f) = fitter.fit(&trial, &cur.p) {
                    let d = delta_bic(problem, noise_um, &cur, &f);
                    if d < 0.0 {
                        log.push(format!("remove {} (ΔBIC {:.1})", removed.name(), d));
                        set = trial;
                        cur = f;
                        changed = true;
                        break;
                    }
                }
            }
            if changed {
                continue;
            }
            'swap: for i in 0..set.len() {
                for &c in &candidates {
                    if set.contains(&c) {
                        continue;
                    }
                    let mut trial = set.clone();
                    let old = std::mem::replace(&mut trial[i], c);
                    let k_new = trial.iter().map(|e| e.params.len()).sum::<usize>() as f64;
                    if n - k_new < MIN_DOF_PER_PARAM * k_new {
                        continue;
                    }
                    if let Some(f) = fitter.fit(&trial, &cur.p) {
                        let d = delta_bic(problem, noise_um, &cur, &f);
                        if d < -SWAP_MARGIN {
                            log.push(format!("swap {} for {} (ΔBIC {:.1})", old.name(), c.name(), d));
                            // The newcomer counts as added last.
                            trial.remove(i);
                            trial.push(c);
                            set = trial;
                            cur = f;
                            changed = true;
                            break 'swap;
                        }
                    }
                }
            }
        }
    }
    Selection { effects: set, fit: cur, log, skipped }
}

fn empty_fit(problem: &Problem) -> Fit {
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
