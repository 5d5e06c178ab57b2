//! The selection's replacement moves (`selection.rs`'s module doc says when they run): a
//! candidate added and the members it makes redundant dropped ([`replacement`]), and two
//! candidates added together ([`pair_replacement`]), each judged as a whole by the BIC gain over
//! [`SWAP_MARGIN`], residual degrees of freedom, plausibility of the newcomers and the held-out
//! test charged by the net parameters ([`move_validates`]).
//!
//! Cost: see each function; fits are cached by the [`Fitter`].

use super::fit::Fit;
use super::library::Effect;
use super::plausible::plausible;
use super::scoring::{bic, common_s2, n_res, Fitter, MIN_DOF_PER_PARAM, SWAP_MARGIN};
use nalgebra::{DMatrix, DVector};

/// The best replacement move (module doc): a candidate added and the members it makes redundant
/// dropped. Returns the new set (the newcomer last), its fit and a log line.
pub fn replacement(
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
/// `f`), charged by the net parameters it adds (the add test's k_effect·σ², `selection::validates`): a
/// move that adds parameters must lower the cross-validated RSS by that much; one that saves
/// parameters may raise it by as much as they cost (a strict drop would keep the larger of two
/// equally predictive models). Returns the log line if it passes.
#[allow(clippy::too_many_arguments)]
pub fn move_validates(
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
pub fn pair_replacement(
    fitter: &mut Fitter<'_>,
    candidates: &[&'static Effect],
    set: &[&'static Effect],
    cur: &Fit,
    noise_um: Option<f64>,
) -> Option<(Vec<&'static Effect>, Fit, String)> {
    let problem = fitter.problem;
    let n = n_res(problem);
    let out = super::library::outside(candidates, set);
    if set.is_empty() || set.len() > 5 || out.len() < 2 {
        return None;
    }
    // Columns: every candidate's parameters, then the nuisances'.
    let mut cols = super::library::params_of(candidates);
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
