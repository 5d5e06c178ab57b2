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

use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{Effect, LIBRARY, N_PARAMS};
use super::moves::{pair_replacement, replacement};
use super::plausible::plausible;
use super::scoring::{common_s2, empty_fit, key, n_res};

pub use super::ambiguity::{
    ambiguities, pair_ambiguities, Ambiguity, PairAmbiguity, AMBIGUOUS_MARGIN,
};
pub use super::scoring::{
    delta_bic, Fitter, ADD_MARGIN, CV_FOLDS, LOO_POINTS, MIN_DOF_PER_PARAM, SWAP_MARGIN,
};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::library::effect;
    use crate::loop_closure::SixBarDesign;
    use crate::synth::{generate, Poses, Truth};
    use kinematics_core::FiveBar;

    /// The final check drops a member that does not pass the add test given the others (a gear
    /// ratio the data do not have, beside the link lengths they do), logs the drop, and keeps
    /// the member that does.
    #[test]
    fn the_final_check_drops_a_member_without_support_and_keeps_the_rest() {
        let truth = Truth {
            noise_um: 1.0,
            link_delta_um: [40.0, -25.0, 30.0, -60.0],
            ..Default::default()
        };
        let data = generate(&truth, Poses::Random(80), 3);
        let problem = Problem::new(FiveBar::paper_nominal(), &SixBarDesign::paper(), &data);
        let mut fitter = Fitter::new(&problem);
        let (links, gear) = (
            effect("link_lengths").expect("in the library"),
            effect("gear_ratio").expect("in the library"),
        );
        let mut set = vec![links, gear];
        let mut cur = fitter.fit(&set, &[0.0; N_PARAMS]).expect("a fit");
        let mut log = Vec::new();
        prune_weak(&mut fitter, &mut set, &mut cur, Some(1.0), &mut log);
        assert_eq!(
            set.iter().map(|e| e.name()).collect::<Vec<_>>(),
            ["link_lengths"],
            "{log:#?}"
        );
        assert!(
            log.len() == 1 && log[0].starts_with("drop gear_ratio"),
            "{log:#?}"
        );
        // What is left is the link lengths' fit: the gear ratio's parameters are free no more.
        assert!(
            gear.params.iter().all(|k| !cur.free.contains(k)),
            "{:?}",
            cur.free
        );
    }
}
