//! The choices the data leave open, declared rather than decided: every named effect that a
//! library twin, swapped in one for one ([`ambiguities`]) or two for two
//! ([`pair_ambiguities`]), fits within [`AMBIGUOUS_MARGIN`] of BIC or predicts held-out points
//! about as well. The report lists them (`ambiguous`, `ambiguous_pairs`) with the measurement
//! that would separate them; `steps` keeps the best-scoring model.

use super::fit::Fit;
use super::library::Effect;
use super::plausible::plausible;
use super::scoring::{common_s2, delta_bic, n_res, Fitter, ADD_MARGIN, MIN_DOF_PER_PARAM};

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
    let out = super::library::outside(candidates, set);
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
