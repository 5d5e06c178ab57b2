//! Stepwise selection of effects: forward (add the best candidate that passes every test), then
//! backward and swap passes while the score improves, repeated until nothing changes.
//!
//! Why not forward only: one flexible effect can soak up parts of two simple ones early on; the
//! removal and swap passes undo that once the simple ones are in.
//!
//! An effect is added (or swapped in) only when it passes all three tests:
//! 1. **Information criterion**: BIC = RSS/σ² + k·ln n (n scalar residuals, k free parameters).
//!    Which σ: for every comparison of two models σ² = max(noise², the smaller of the two models'
//!    residual variances RSS/(n−k)). With the noise known this is the textbook BIC as long as the
//!    model is complete; when structure no effect explains is left, it falls back to the
//!    F-test-like comparison against what is actually left, so an unmodelled cyclic error does
//!    not make every tweak "significant". BIC rather than AIC: its penalty (7 per parameter at
//!    n ≈ 1300) keeps false positives on clean data rare; an effect must lower the BIC by more
//!    than [`ADD_MARGIN`] ("very strong" evidence on the Kass–Raftery scale).
//! 2. **Held-out validation**: the model with the effect must predict points it was not fitted
//!    to better than the model without it: K-fold cross-validated RSS ([`CV_FOLDS`] folds, by
//!    point index; leave-one-point-out on ≤ [`LOO_POINTS`] points; each fold's held-out residuals
//!    from the fit's hat matrix, `fit::cross_validated_rss`) must drop by more than k_effect·σ²
//!    (what k useless parameters cost a prediction on average). The in-sample fit alone always
//!    improves; this asks whether the improvement is real on new poses.
//! 3. **Physical plausibility** ([`plausible`]): the fitted values must be something a machine
//!    can have — backlash not significantly negative, link changes within 5 % of the link,
//!    stretch within 0.1 % strain and c's compliance not significantly (3σ) beyond a factor 3
//!    of b's, the mismatch's effective part errors within 1 % of a link,
//!    encoder offsets and frame rotation within 0.1 rad, gear ratio within 1 %, scale within
//!    2000 ppm, B0 within 10 % of a link.
//!
//! Moves: add one effect (the best that passes all three tests); remove one (while the BIC
//! improves); **replace**: add one candidate and then drop, one at a time, members that have
//! become redundant, kept if the BIC improves by more than [`SWAP_MARGIN`] and the candidate passes
//! the held-out and plausibility tests. Why the last: the six-bar's loop effects reproduce
//! combinations of simple ones (a stretch is mostly link lengths, a gear ratio and a frame on
//! these poses; a flexible stretch can fit an encoder offset plus a base offset), so the greedy
//! forward step can take the wrong side of such a trade; one-for-one swaps cannot undo a
//! one-for-several choice, the replacement can, in either direction. Its held-out test is
//! charged by the move's net parameters (a move that saves parameters may raise the
//! cross-validated RSS by what they cost). When no one-candidate move helps, the **pair
//! replacement** ([`pair_replacement`]) adds two candidates at once (a frame and a gear ratio
//! first fitted as link lengths and a base offset: neither alone beats the members it would
//! replace), scored on the model linearised about the current fit and checked by real fits.
//! A pair move that grows the set (one member out, two in) competes with the forward step's
//! one-effect extension and must beat the best plausible one by [`SWAP_MARGIN`] too: on a tie
//! the forward step keeps what the data have already established (the sweep: a base offset
//! replaced by link lengths and a gear ratio that tied with base offset + stretch, the truth,
//! on BIC and predicted held-out points worse).
//!
//! **Final check** ([`prune_weak`]): every named effect must still lower the BIC by more than
//! [`ADD_MARGIN`] given the others, or it is dropped (the weakest first), so that a member a
//! move carried in beside the one it was about is held to the add test too.
//!
//! After the selection, [`ambiguities`] lists every named effect that a one-for-one swap with a
//! library twin fits within [`AMBIGUOUS_MARGIN`] of BIC, or that the twin predicts held-out
//! points better than (the two tests an effect must pass disagree on the pair): the report
//! declares those choices open rather than picking one silently; [`pair_ambiguities`] does the
//! same for two-for-two swaps.
//!
//! Structures outside the library (a gear tooth's periodic error, an instrument drift) are found
//! by `structure.rs` on the final residual and then fitted as nuisances in every model
//! (`Problem::nuisance`, set by the caller, who re-runs the selection): what they explain can
//! then not be credited to a library effect. Cost: each round fits every remaining candidate
//! (≤ 9 LM fits), plus K fits for each effect that passes the BIC; results are cached by effect
//! set.

use super::fit::{cross_validated_rss, fit, Fit};
use super::forward_model::Problem;
use super::library::{idx, Effect, LIBRARY, N_PARAMS};
use crate::effect::PhysicalEffect;
use nalgebra::{DMatrix, DVector};
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

/// Fits of effect sets (with the problem's nuisances), cached by the sorted names.
pub struct Fitter<'a> {
    pub problem: &'a Problem,
    cache: BTreeMap<Vec<&'static str>, Option<Fit>>,
    cv_cache: BTreeMap<Vec<&'static str>, Option<f64>>,
}

fn key(set: &[&'static Effect]) -> Vec<&'static str> {
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
fn n_res(p: &Problem) -> f64 {
    (2 * p.points.len()) as f64
}

/// The common σ² (µm²) of a comparison of two fits (module doc).
fn common_s2(p: &Problem, noise_um: Option<f64>, a: &Fit, b: &Fit) -> f64 {
    let n = n_res(p);
    let va = a.cost / (n - a.free.len() as f64).max(1.0);
    let vb = b.cost / (n - b.free.len() as f64).max(1.0);
    va.min(vb)
        .max(noise_um.map(|s| s * s).unwrap_or(0.0))
        .max(1e-12)
}

/// The BIC score `RSS/σ² + k·ln n` of a fit with σ² = `s2` on `n` scalar residuals (module doc).
fn bic(f: &Fit, s2: f64, n: f64) -> f64 {
    f.cost / s2 + f.free.len() as f64 * n.ln()
}

/// BIC difference `score(b) − score(a)` with the common σ² described in the module doc.
pub fn delta_bic(p: &Problem, noise_um: Option<f64>, a: &Fit, b: &Fit) -> f64 {
    let n = n_res(p);
    let (ka, kb) = (a.free.len() as f64, b.free.len() as f64);
    (b.cost - a.cost) / common_s2(p, noise_um, a, b) + (kb - ka) * n.ln()
}

/// Whether an effect's fitted values are something a machine can have (module doc); the error
/// says which value is not. `s2` scales the standard deviations (µm²).
pub fn plausible(problem: &Problem, e: &Effect, f: &Fit, s2: f64) -> Result<(), String> {
    let m = &problem.base;
    let links = [m.a_mm, m.b_mm, m.c_mm, m.d_mm];
    let mean_link_um = 250.0 * (m.a_mm + m.b_mm + m.c_mm + m.d_mm);
    let x = &f.p;
    let sd = |k: usize| {
        f.free
            .iter()
            .position(|&c| c == k)
            .map(|c| (f.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
            .unwrap_or(0.0)
    };
    let within = |k: usize, limit: f64, what: &str| -> Result<(), String> {
        if x[k].abs() <= limit {
            Ok(())
        } else {
            Err(format!(
                "{} = {:.1} is beyond a plausible {what} ({limit:.0})",
                super::library::PARAM_NAMES[k],
                x[k]
            ))
        }
    };
    match e.kind {
        PhysicalEffect::LinkLengths => (0..4).try_for_each(|k| within(idx::LINKS + k, 0.05 * links[k] * 1e3, "5 % of the link")),
        PhysicalEffect::EncoderOffset => (0..2).try_for_each(|k| within(idx::OFFSETS + k, 1e5, "0.1 rad")),
        PhysicalEffect::BaseOffset => (0..2).try_for_each(|k| within(idx::BASE + k, 0.1 * mean_link_um, "10 % of a link")),
        PhysicalEffect::Backlash => (0..2).try_for_each(|k| {
            let (v, s) = (x[idx::BACKLASH + k], sd(idx::BACKLASH + k));
            if v < -3.0 * s - 1e-9 {
                Err(format!(
                    "{} = {v:.1} ± {s:.1}: negative lost motion (the link ahead of its motor) is not backlash",
                    super::library::PARAM_NAMES[idx::BACKLASH + k]
                ))
            } else {
                within(idx::BACKLASH + k, 1e4, "0.01 rad of lost motion")
            }
        }),
        PhysicalEffect::LinkStretch => {
            let n = super::sixbar_modes::N_STRETCH;
            (0..n).try_for_each(|k| within(idx::STRETCH + k, 1e-3 * links[1].min(links[2]) * 1e3, "0.1 % strain of a distal bar"))?;
            // c's compliance within a factor of 3 of the design's (the two bars are alike), or
            // not significantly outside (3σ, as the backlash's sign): on a small stretch the
            // ratio is poorly determined (the sweep: −73 ± 28 % at half magnitude beside a base
            // offset and a frame, the truth's ratio being −40 to +60 %), and a hard bound on an
            // uncertain value rejected the true effect for link lengths. Never a negative
            // compliance nor more than 5×, whatever the uncertainty: a fit that runs the ratio
            // off (ks → 0, kc → 10⁶ ± 10⁹: c stretching alone) is degenerate, not uncertain.
            let (r, s) = (x[idx::STRETCH_RATIO], sd(idx::STRETCH_RATIO));
            if (-100.0..=400.0).contains(&r) && r + 3.0 * s >= -67.0 && r - 3.0 * s <= 200.0 {
                Ok(())
            } else {
                Err(format!("kc_compliance_pct = {r:.0} ± {s:.0}: c would be {:.2}× as compliant as designed", 1.0 + r / 100.0))
            }
        }
        PhysicalEffect::Frame => within(idx::FRAME + 2, 1e5, "0.1 rad"),
        PhysicalEffect::Scale => within(idx::SCALE, 2000.0, "instrument scale error (ppm)"),
        PhysicalEffect::GearRatio => (0..2).try_for_each(|k| within(idx::GEAR + k, 1e4, "1 % ratio error (ppm)")),
        PhysicalEffect::ParallelogramMismatch => {
            let worst = problem
                .effective_sixbar(x)
                .map(|eff| eff.mismatch_raw_um.iter().fold(0.0f64, |a, v| a.max(v.abs())))
                .unwrap_or(f64::INFINITY);
            let limit = 0.01 * mean_link_um;
            if worst <= limit {
                Ok(())
            } else {
                Err(format!("the mismatch needs part errors of {worst:.0} µm, beyond a plausible 1 % of a link ({limit:.0} µm)"))
            }
        }
        _ => Ok(()),
    }
}

/// The held-out test: does adding `c` to `set` predict unseen points better by more than its
/// parameters cost? Returns the two cross-validated RSS on success, the reason otherwise.
fn validates(
    fitter: &mut Fitter<'_>,
    set: &[&'static Effect],
    c: &'static Effect,
    cur: &Fit,
    new: &Fit,
    noise_um: Option<f64>,
) -> Result<(f64, f64), String> {
    let problem = fitter.problem;
    let Some(before) = fitter.cv_rss(set, &cur.p) else {
        return Err("cross-validation fit of the current model failed".into());
    };
    let mut trial = set.to_vec();
    trial.push(c);
    let Some(after) = fitter.cv_rss(&trial, &new.p) else {
        return Err(format!(
            "cross-validation fit with {} failed (a point left the workspace)",
            c.name()
        ));
    };
    let s2 = common_s2(problem, noise_um, cur, new);
    let margin = c.params.len() as f64 * s2;
    if after < before - margin {
        Ok((before, after))
    } else {
        Err(format!(
            "{} does not predict held-out points better (cross-validated RSS {:.1} → {:.1} µm², needs a drop > {:.1})",
            c.name(),
            before,
            after,
            margin
        ))
    }
}

/// Runs the stepwise selection from the empty set (the base model, with the problem's
/// nuisances).
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
            return Selection {
                effects: set,
                fit: empty_fit(problem),
                log,
                skipped,
            };
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
        // Forward: every candidate, best score first. One σ² for the whole round (the smallest
        // residual variance among the candidates, or the noise): scores that each used their own
        // would rank two near-equal fits of a large residual by rounding-level differences of σ².
        let mut fitted: Vec<(&'static Effect, Fit)> = Vec::new();
        let mut tried = Vec::new();
        for &c in &candidates {
            if set.contains(&c) {
                continue;
            }
            let k_new = (cur.free.len() + c.params.len()) as f64;
            if n - k_new < MIN_DOF_PER_PARAM * k_new {
                tried.push(format!(
                    "{} not tried: {} parameters on {} residuals",
                    c.name(),
                    k_new,
                    n
                ));
                continue;
            }
            let mut trial = set.clone();
            trial.push(c);
            match fitter.fit(&trial, &cur.p) {
                Some(f) => fitted.push((c, f)),
                None => tried.push(format!(
                    "{} fit failed (a point left the model's workspace)",
                    c.name()
                )),
            }
        }
        let s2_round = fitted
            .iter()
            .map(|(_, f)| common_s2(problem, noise_um, &cur, f))
            .fold(f64::INFINITY, f64::min);
        let mut ranked: Vec<(f64, &'static Effect, Fit)> = Vec::new();
        for (c, f) in fitted {
            let d = (f.cost - cur.cost) / s2_round
                + (f.free.len() as f64 - cur.free.len() as f64) * n.ln();
            tried.push(format!(
                "{} rms {:.1} µm ΔBIC {:.1}",
                c.name(),
                (2.0 * f.cost / n).sqrt(),
                d
            ));
            ranked.push((d, c, f));
        }
        log.push(format!(
            "candidates on top of [{}]: {}",
            set.iter().map(|e| e.name()).collect::<Vec<_>>().join(", "),
            tried.join("; ")
        ));
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut chosen = None;
        for (d, c, f) in ranked {
            if d > -ADD_MARGIN {
                log.push(format!(
                    "no further candidate significant (best left {} ΔBIC {:.1} > −{ADD_MARGIN})",
                    c.name(),
                    d
                ));
                break;
            }
            if let Err(why) = plausible(problem, c, &f, common_s2(problem, noise_um, &cur, &f)) {
                log.push(format!(
                    "{} not added (ΔBIC {d:.1}): implausible: {why}",
                    c.name()
                ));
                continue;
            }
            match validates(&mut fitter, &set, c, &cur, &f, noise_um) {
                Ok((before, after)) => {
                    log.push(format!(
                        "add {} (ΔBIC {d:.1}; cross-validated RSS {before:.1} → {after:.1} µm²)",
                        c.name()
                    ));
                    chosen = Some((c, f));
                    break;
                }
                Err(why) => log.push(format!("{} not added (ΔBIC {d:.1}): {why}", c.name())),
            }
        }
        let Some((c, f)) = chosen else {
            log.push("stop".into());
            break;
        };
        set.push(c);
        cur = f;
        // Backward and replacement passes while they improve the score (never back to a set
        // already left: each move's score uses its own σ², so a cycle is not excluded otherwise).
        let mut changed = true;
        let mut seen = std::collections::BTreeSet::from([key(&set)]);
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
                    if d < 0.0 && seen.insert(key(&trial)) {
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
            let single = replacement(&mut fitter, &candidates, &set, &cur, noise_um);
            let mv = match single {
                Some(m) if !seen.contains(&key(&m.0)) => Some(m),
                _ => pair_replacement(&mut fitter, &candidates, &set, &cur, noise_um),
            };
            if let Some((new_set, f, line)) = mv {
                if seen.insert(key(&new_set)) {
                    log.push(line);
                    set = new_set;
                    cur = f;
                    changed = true;
                }
            }
        }
    }
    prune_weak(&mut fitter, &mut set, &mut cur, noise_um, &mut log);
    Selection {
        effects: set,
        fit: cur,
        log,
        skipped,
    }
}

/// The final check: every named effect must still pass the add test given the
/// others, or it is dropped (the weakest first, refitted, repeated). Why: a replacement move is
/// judged as a whole (its BIC gain over [`SWAP_MARGIN`], its held-out test by the net
/// parameters), so a member can enter beside the one the move is really about without the
/// evidence an effect needs on its own (the sweep: a base offset carried into [backlash, scale]
/// with a drift by a pair replacement, lowering the BIC by 0.3 where an effect needs 10), and
/// the removal pass only drops what *raises* the BIC. A set the selection reached by a series of
/// moves is thus held to the same standard as one it reached by adding alone.
fn prune_weak(
    fitter: &mut Fitter<'_>,
    set: &mut Vec<&'static Effect>,
    cur: &mut Fit,
    noise_um: Option<f64>,
    log: &mut Vec<String>,
) {
    let problem = fitter.problem;
    while !set.is_empty() {
        // (the member's support, its index, the fit without it)
        let mut weakest: Option<(f64, usize, Fit)> = None;
        for i in 0..set.len() {
            let mut trial = set.clone();
            trial.remove(i);
            let Some(f) = fitter.fit(&trial, &cur.p) else {
                continue;
            };
            // How much the member lowers the BIC, given the others (positive: it helps).
            let support = delta_bic(problem, noise_um, cur, &f);
            if support < ADD_MARGIN && weakest.as_ref().is_none_or(|w| support < w.0) {
                weakest = Some((support, i, f));
            }
        }
        let Some((support, i, f)) = weakest else {
            break;
        };
        log.push(format!(
            "drop {}: in the final model it lowers the BIC by {support:.1} given the others (an effect needs > {ADD_MARGIN})",
            set[i].name()
        ));
        set.remove(i);
        *cur = f;
    }
}

/// The best replacement move (module doc): a candidate added and the members it makes redundant
/// dropped. Returns the new set (the newcomer last), its fit and a log line.
fn replacement(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Option<(Vec<&'static Effect>, Fit, String)> {
    let problem = fitter.problem;
    let n = n_res(problem);
    let mut moves: Vec<(f64, Vec<&'static Effect>, Fit, &'static Effect, f64)> = Vec::new();
    for &c in candidates {
        if set.contains(&c) || set.is_empty() {
            continue;
        }
        let mut trial: Vec<&'static Effect> = set.to_vec();
        trial.push(c);
        let Some(mut f) = fitter.fit(&trial, &cur.p) else {
            continue;
        };
        // One σ² for the whole move: the scores of its sets are then comparable.
        let s2 = common_s2(problem, noise_um, cur, &f);
        let score = |f: &Fit| bic(f, s2, n);
        let mut removed = 0;
        loop {
            let mut step: Option<(f64, usize, Fit)> = None;
            for i in 0..trial.len() {
                if trial[i].name() == c.name() {
                    continue;
                }
                let mut t = trial.clone();
                t.remove(i);
                if let Some(g) = fitter.fit(&t, &f.p) {
                    let sc = score(&g);
                    if sc < score(&f) && step.as_ref().is_none_or(|b| sc < b.0) {
                        step = Some((sc, i, g));
                    }
                }
            }
            let Some((_, i, g)) = step else { break };
            trial.remove(i);
            f = g;
            removed += 1;
        }
        let gain = score(cur) - score(&f);
        if removed == 0 || gain <= SWAP_MARGIN {
            continue;
        }
        let k_new = f.free.len() as f64;
        if n - k_new < MIN_DOF_PER_PARAM * k_new || plausible(problem, c, &f, s2).is_err() {
            continue;
        }
        moves.push((gain, trial, f, c, s2));
    }
    // Best gain first; the first that also predicts held-out points well enough is taken (a
    // move that fails the held-out test must not hide the next one).
    moves.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (gain, trial, f, c, s2) in moves {
        let Some(line) = move_validates(fitter, set, cur, &trial, &f, s2, c.name(), gain) else {
            continue;
        };
        let mut ordered: Vec<&'static Effect> =
            trial.into_iter().filter(|e| e.name() != c.name()).collect();
        ordered.push(c);
        return Some((ordered, f, line));
    }
    None
}

/// The held-out test of a replacement move from `set` (fitted as `cur`) to `trial` (fitted as
/// `f`), charged by the net parameters it adds (the add test's k_effect·σ², [`validates`]): a
/// move that adds parameters must lower the cross-validated RSS by that much; one that saves
/// parameters may raise it by as much as they cost (a strict drop would keep the larger of two
/// equally predictive models). Returns the log line if it passes.
#[allow(clippy::too_many_arguments)]
fn move_validates(
    fitter: &mut Fitter<'_>,
    set: &[&'static Effect],
    cur: &Fit,
    trial: &[&'static Effect],
    f: &Fit,
    s2: f64,
    added: &str,
    gain: f64,
) -> Option<String> {
    let cv_old = fitter.cv_rss(set, &cur.p)?;
    let cv_new = fitter.cv_rss(trial, &f.p)?;
    let allowed = cv_old - (f.free.len() as f64 - cur.free.len() as f64) * s2;
    if cv_new >= allowed {
        return None;
    }
    let dropped: Vec<&str> = set
        .iter()
        .filter(|e| !trial.contains(e))
        .map(|e| e.name())
        .collect();
    Some(format!(
        "replace [{}] by {added} (BIC −{gain:.1}; cross-validated RSS {cv_old:.1} → {cv_new:.1} µm², allowed {allowed:.1})",
        dropped.join(", ")
    ))
}

/// Pair moves whose linearised score is checked by a real fit, best first.
const PAIR_MOVES_FITTED: usize = 3;

/// The **pair replacement** (module doc): two candidates added together and any members they
/// make redundant dropped, for the trades a one-candidate move cannot make — two simple effects
/// that together do what one flexible effect and another do (e.g. a frame and a gear ratio
/// fitted as link lengths and a base offset), where neither newcomer alone improves on the
/// members it would replace. Every pair and every non-empty subset of members to drop is
/// scored on the model linearised about the current fit (one Jacobian of all candidates' and
/// nuisances' parameters; the residual with the dropped members' parameters set to zero
/// predicted as r − J_D·p_D; its least-squares RSS on the kept and new columns from the
/// normal equations), and the [`PAIR_MOVES_FITTED`] best that beat the current score by more
/// than [`SWAP_MARGIN`] are fitted for real. A move is taken under the replacement's tests:
/// the real BIC gain over [`SWAP_MARGIN`], residual degrees of freedom, both newcomers
/// plausible, and the held-out test charged by the net parameters. Cost: one Jacobian
/// (2 residual evaluations per parameter), ≤ 21·(2^|set| − 1) solves of ≤ 16×16 normal
/// equations, ≤ 3 LM fits.
fn pair_replacement(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Option<(Vec<&'static Effect>, Fit, String)> {
    let problem = fitter.problem;
    let n = n_res(problem);
    let out: Vec<&'static Effect> = candidates
        .iter()
        .copied()
        .filter(|c| !set.contains(c))
        .collect();
    if set.is_empty() || set.len() > 5 || out.len() < 2 {
        return None;
    }
    // Columns: every candidate's parameters, then the nuisances'.
    let mut cols: Vec<usize> = candidates
        .iter()
        .flat_map(|e| e.params.iter().copied())
        .collect();
    cols.extend(problem.nuisance.params());
    let j = super::fit::jacobian(problem, &cur.p, &cols)?;
    // Column-normalised Gram matrix and projections of the residual (scales differ by units).
    let norms: Vec<f64> = (0..cols.len())
        .map(|c| j.column(c).norm().max(1e-300))
        .collect();
    let jn = DMatrix::from_fn(j.nrows(), j.ncols(), |r, c| j[(r, c)] / norms[c]);
    let gram = jn.transpose() * &jn;
    let r = &cur.residuals;
    let jr = jn.transpose() * r;
    let rr = r.norm_squared();
    let col_of = |k: usize| cols.iter().position(|&c| c == k);
    let s2 = common_s2(problem, noise_um, cur, cur);
    let score_cur = bic(cur, s2, n);
    let mut moves: Vec<(f64, Vec<&'static Effect>, &'static Effect, &'static Effect)> = Vec::new();
    for a in 0..out.len() {
        for b in a + 1..out.len() {
            for mask in 1u32..(1 << set.len()) {
                let kept: Vec<&'static Effect> = set
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| mask & (1 << i) == 0)
                    .map(|(_, e)| *e)
                    .collect();
                let dropped: Vec<usize> = set
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| mask & (1 << i) != 0)
                    .flat_map(|(_, e)| e.params.iter().copied())
                    .collect();
                let mut trial = kept.clone();
                trial.extend([out[a], out[b]]);
                let free: Vec<usize> = problem
                    .free_params(&trial)
                    .into_iter()
                    .filter_map(col_of)
                    .collect();
                let k_new = free.len() as f64;
                if n - k_new < MIN_DOF_PER_PARAM * k_new {
                    continue;
                }
                // Residual with the dropped parameters at zero (normalised coordinates):
                // r' = r − J_D·p_D.
                let d: Vec<(usize, f64)> = dropped
                    .iter()
                    .filter_map(|&k| col_of(k).map(|c| (c, cur.p[k] * norms[c])))
                    .collect();
                let mut rr_d = rr;
                for &(c, v) in &d {
                    rr_d -= 2.0 * v * jr[c];
                    for &(c2, v2) in &d {
                        rr_d += v * v2 * gram[(c, c2)];
                    }
                }
                let g = DMatrix::from_fn(free.len(), free.len(), |x, y| gram[(free[x], free[y])]);
                let rhs = DVector::from_fn(free.len(), |x, _| {
                    jr[free[x]] - d.iter().map(|&(c, v)| v * gram[(free[x], c)]).sum::<f64>()
                });
                let Ok(beta) = g.clone().svd(true, true).solve(&rhs, 1e-12) else {
                    continue;
                };
                let rss = (rr_d - rhs.dot(&beta)).max(0.0);
                let score = rss / s2 + k_new * n.ln();
                if score < score_cur - SWAP_MARGIN {
                    moves.push((score, trial, out[a], out[b]));
                }
            }
        }
    }
    moves.sort_by(|x, y| x.0.total_cmp(&y.0));
    for (_, trial, ca, cb) in moves.into_iter().take(PAIR_MOVES_FITTED) {
        let Some(f) = fitter.fit(&trial, &cur.p) else {
            continue;
        };
        let s2f = common_s2(problem, noise_um, cur, &f);
        let gain =
            (cur.cost - f.cost) / s2f - (f.free.len() as f64 - cur.free.len() as f64) * n.ln();
        let k_new = f.free.len() as f64;
        if gain <= SWAP_MARGIN
            || n - k_new < MIN_DOF_PER_PARAM * k_new
            || plausible(problem, ca, &f, s2f).is_err()
            || plausible(problem, cb, &f, s2f).is_err()
        {
            continue;
        }
        // A move that grows the set by one effect competes with the forward step that adds one:
        // it must beat the best plausible extension of the current set by the swap margin.
        let score = |g: &Fit| bic(g, s2f, n);
        let mut versus_add = String::new();
        if trial.len() > set.len() {
            let best_add = best_extension(fitter, &out, set, cur, s2f);
            if let Some((c, add_score)) = best_add {
                if score(&f) >= add_score - SWAP_MARGIN {
                    continue;
                }
                versus_add = format!(", {:.1} below adding {}", add_score - score(&f), c.name());
            }
        }
        let added = format!("{} and {}", ca.name(), cb.name());
        let Some(mut line) = move_validates(fitter, set, cur, &trial, &f, s2f, &added, gain) else {
            continue;
        };
        if !versus_add.is_empty() {
            line.pop();
            line.push_str(&versus_add);
            line.push(')');
        }
        return Some((trial, f, line));
    }
    None
}

/// The best plausible one-effect extension of `set` (fitted as `cur`): the candidate whose fit on
/// top of the set scores lowest, with its score (`cost/s2 + k·ln n`, the caller's σ²), or
/// `None` when no extension fits plausibly. The alternative a set-growing pair move must beat
/// ([`pair_replacement`]). Cost: the forward step's fits (cached).
fn best_extension(
    fitter: &mut Fitter<'_>,
    out: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    s2: f64,
) -> Option<(&'static Effect, f64)> {
    let problem = fitter.problem;
    let n = n_res(problem);
    let mut best: Option<(&'static Effect, f64)> = None;
    for &c in out {
        let mut trial = set.to_vec();
        trial.push(c);
        let k = problem.free_params(&trial).len() as f64;
        if n - k < MIN_DOF_PER_PARAM * k {
            continue;
        }
        let Some(g) = fitter.fit(&trial, &cur.p) else {
            continue;
        };
        if plausible(problem, c, &g, s2).is_err() {
            continue;
        }
        let sc = bic(&g, s2, n);
        if best.is_none_or(|b| sc < b.1) {
            best = Some((c, sc));
        }
    }
    best
}

/// BIC margin within which a one-for-one swap of a named effect leaves the choice open: the
/// evidence an effect needs to be added at all ([`ADD_MARGIN`]). The selection names an effect
/// only on that much evidence, so it must not claim one effect over its twin on less.
pub const AMBIGUOUS_MARGIN: f64 = ADD_MARGIN;

/// A named effect the data cannot tell from a library alternative (see [`ambiguities`]).
pub struct Ambiguity {
    /// The effect of the final model.
    pub effect: &'static Effect,
    /// The candidate that, put in its place, fits within [`AMBIGUOUS_MARGIN`].
    pub alternative: &'static Effect,
    /// BIC of the swapped model minus the final model's (common σ², [`delta_bic`]); negative
    /// when the alternative scores better but no move could take it (the replacement needs a
    /// gain > [`SWAP_MARGIN`], plausibility and the held-out test).
    pub delta_bic: f64,
    /// Cross-validated RSS (µm²) of the swapped model minus the final model's ([`Fitter::cv_rss`]);
    /// `None` when a cross-validation fit failed. Negative: the alternative predicts held-out
    /// points better.
    pub delta_cv_rss_um2: Option<f64>,
}

/// Every one-for-one swap of a member of `set` (fitted as `cur`) with a candidate outside it
/// whose fitted values are plausible and that either scores within [`AMBIGUOUS_MARGIN`] of the
/// final model's BIC or predicts held-out points about as well: the named effect's
/// cross-validated RSS is not lower than the swapped model's by more than k·σ² (k the named
/// effect's parameters: the held-out test it passed to be added, now against the twin instead
/// of its absence). These are the pairs the report must call ambiguous rather than pick one
/// silently. Why the second: an effect is named only when the information criterion *and* the
/// held-out test both support it; when the held-out test cannot tell the twin from it, the
/// BIC's preference may rest on the parameter count alone (the sweep's stretch beside link
/// lengths at half magnitude: the 2-parameter gear ratio is named by ΔBIC 12–18 while the
/// 6-parameter stretch, the truth, predicts held-out points as well, within 1 σ²), so the
/// choice is open. Best alternative (lowest ΔBIC) first. Cost: |set|·|candidates left| LM fits
/// and their cross-validations (cached).
pub fn ambiguities(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Vec<Ambiguity> {
    let problem = fitter.problem;
    let mut out = Vec::new();
    for (i, &m) in set.iter().enumerate() {
        for &c in candidates.iter().filter(|c| !set.contains(c)) {
            let mut trial = set.to_vec();
            trial[i] = c;
            let Some(f) = fitter.fit(&trial, &cur.p) else {
                continue;
            };
            let d = delta_bic(problem, noise_um, cur, &f);
            let s2 = common_s2(problem, noise_um, cur, &f);
            if plausible(problem, c, &f, s2).is_err() {
                continue;
            }
            let cv = fitter
                .cv_rss(set, &cur.p)
                .zip(fitter.cv_rss(&trial, &f.p))
                .map(|(a, b)| b - a);
            // The held-out test an effect passed to be added, applied against its twin: the
            // named effect must predict held-out points better than the twin in its place by
            // more than its parameters cost (k·σ², as against its absence).
            let held_out_open = cv.is_some_and(|dcv| dcv < m.params.len() as f64 * s2);
            if d < AMBIGUOUS_MARGIN || held_out_open {
                out.push(Ambiguity {
                    effect: m,
                    alternative: c,
                    delta_bic: d,
                    delta_cv_rss_um2: cv,
                });
            }
        }
    }
    out.sort_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
    out
}

/// Two named effects that two library alternatives, put in their place together, fit within
/// [`AMBIGUOUS_MARGIN`] of BIC (see [`pair_ambiguities`]).
pub struct PairAmbiguity {
    /// The two effects of the final model.
    pub effects: [&'static Effect; 2],
    /// The two candidates that could be there instead.
    pub alternatives: [&'static Effect; 2],
    /// BIC of the swapped model minus the final model's ([`delta_bic`]).
    pub delta_bic: f64,
    /// Cross-validated RSS (µm²) of the swapped model minus the final model's; `None` when a
    /// cross-validation fit failed.
    pub delta_cv_rss_um2: Option<f64>,
}

/// Every two-for-two swap of members of `set` (fitted as `cur`) with two candidates outside it
/// whose fitted values are plausible and whose BIC is within [`AMBIGUOUS_MARGIN`] of the final
/// model's: the choices [`ambiguities`]' one-for-one swaps cannot see. Why: two simple effects
/// can together do what two others do, where neither alone stands in for either (the sweep:
/// base offset + stretch at half magnitude, the truth, and link lengths + a gear ratio within
/// 0.6 of BIC, the stepwise path reaching the latter); the selection names one side on no
/// evidence, so the report must say the other is as good. Best alternative first. Cost:
/// C(|set|, 2)·C(|candidates left|, 2) LM fits (cached) and the cross-validations of those
/// within the margin.
pub fn pair_ambiguities(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Vec<PairAmbiguity> {
    let problem = fitter.problem;
    let n = n_res(problem);
    let out: Vec<&'static Effect> = candidates
        .iter()
        .copied()
        .filter(|c| !set.contains(c))
        .collect();
    let mut found = Vec::new();
    for i in 0..set.len() {
        for j in i + 1..set.len() {
            for a in 0..out.len() {
                for b in a + 1..out.len() {
                    let mut trial = set.to_vec();
                    trial[i] = out[a];
                    trial[j] = out[b];
                    let k = problem.free_params(&trial).len() as f64;
                    if n - k < MIN_DOF_PER_PARAM * k {
                        continue;
                    }
                    let Some(f) = fitter.fit(&trial, &cur.p) else {
                        continue;
                    };
                    let d = delta_bic(problem, noise_um, cur, &f);
                    let s2 = common_s2(problem, noise_um, cur, &f);
                    if d >= AMBIGUOUS_MARGIN
                        || [out[a], out[b]]
                            .iter()
                            .any(|c| plausible(problem, c, &f, s2).is_err())
                    {
                        continue;
                    }
                    let cv = fitter
                        .cv_rss(set, &cur.p)
                        .zip(fitter.cv_rss(&trial, &f.p))
                        .map(|(x, y)| y - x);
                    found.push(PairAmbiguity {
                        effects: [set[i], set[j]],
                        alternatives: [out[a], out[b]],
                        delta_bic: d,
                        delta_cv_rss_um2: cv,
                    });
                }
            }
        }
    }
    found.sort_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic));
    found
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
