//! Does a named effect stand on its own beside a distal stretch of another law? The judgement
//! the shape check (`shape.rs`) and the check of the effects named in the stretch's place
//! (`stand_in.rs`) make of each named effect.
//!
//! The alternative explanation an effect is judged against is the stretch's generalised shape
//! (`shape.rs`): the library's stretch and one load law `g` of the configuration, with c
//! elongating in the design's self-stress ratio or in one **shared ratio** `r` to b. Why a
//! shared ratio and not `r = 1`: a load from outside the loops or a warming elongates two bars
//! of the same build in the ratio of their compliances or expansions, which is near 1, not 1
//! (another section, another batch of material, a joint's own give); at `r = 1` the part
//! `(r − 1)·g` that c takes alone is left over, and link lengths or offsets then take it and
//! stand. So `r` is the data's, each model's own: for the model with every named effect, and
//! for each effect judged, for the model **without** it (the alternative is judged at its best,
//! as a competing hypothesis must be), the ratio within a factor 3 either way (the compliance
//! ratio's plausibility range) that best explains the residual that model leaves, found on the
//! model linearised at the fit: the residual without the effect's contribution, the other named
//! effects' Jacobian projected out, the least squares of the generalised shape's columns at each
//! ratio of a log-spaced grid.
//!
//! The other alternative is an **external load**: the library's stretch and a constant force on
//! the platform (a hose's or a cable's drag, a weight on a tilted machine) carried by the two
//! bars as the pose's statics say, each elongating by its own compliance (`misfit_modes::load_columns`,
//! four columns outside the library stretch's span). A load stretches one bar and shortens the
//! other over much of the workspace: no shared ratio follows it, and what it leaves beside the
//! generalised shape (the bars' mean elongations, a near-constant displacement of the tool) is
//! what link lengths or an instrument frame then take and stand on.
//!
//! An effect **stands** when, with every other named effect in place and the alternative fitted
//! alongside (misfit modes charged to both models), removing it raises the BIC by more than
//! [`ADD_MARGIN`] (the add test) against each alternative law: the generalised shape with each
//! model at the data's ratio, and with both at equal elongations (ratio 1), and the external
//! load. The union of the families is the alternative; an effect must beat each, so a law the
//! data's ratio fits less well than ratio 1 (the linearised choice can miss) never lets a
//! stand-in through. An effect may be judged against the external load alone (`load_only`,
//! `stand_in.rs`' first effect). Each model without the effect is fitted from several starts
//! and the best kept ([`support_against`]).
//!
//! Cost: per effect judged, one Jacobian of the other named effects and [`RATIOS`] least-squares
//! projections (an SVD of n×20 each); per distinct ratio, one Jacobian and SVD of the generalised
//! shape and one LM fit with up to 20 more parameters; the same once for the external load (4
//! more parameters), fitted only for an effect the generalised shape leaves standing; per effect
//! judged and alternative, two LM fits, a third (from zero) when the effect stands on those.

use super::fit::{fit, Fit};
use super::forward_model::Problem;
use super::library::{idx, Effect, N_PARAMS, N_SHAPE};
use super::misfit_modes::{at_ratio, set_load_modes, set_misfit_modes, stretch_blocks};
use super::scoring::{delta_bic, Fitter, ADD_MARGIN};
use crate::numeric::finite_difference;
use crate::numeric::subspace::{orthonormal_basis, project_out};
use nalgebra::DMatrix;

/// The shared ratios tried: log-spaced over c's elongation a third to three times b's.
pub const RATIOS: usize = 25;

/// The grid's index of equal elongations (ratio 1).
const EQUAL: usize = RATIOS / 2;

/// The `k`-th ratio of the grid.
fn ratio(k: usize) -> f64 {
    let span = 3.0f64.ln();
    (-span + 2.0 * span * k as f64 / (RATIOS - 1) as f64).exp()
}

/// The index of the shared ratio (module doc) that best explains the residual of `plain` (no
/// shape misfit set) at `x` (the effect judged at zero), the effects `keep` linearised at `x`;
/// `None` when the residual or a column cannot be evaluated there.
fn best_ratio_index(plain: &Problem, x: &[f64], keep: &[&'static Effect]) -> Option<usize> {
    let xa = <[f64; N_PARAMS]>::try_from(x).ok()?;
    let res = DMatrix::from_column_slice(2 * plain.points.len(), 1, &plain.residuals_um(&xa)?);
    let free = plain.free_params(keep);
    let q = if free.is_empty() {
        DMatrix::zeros(res.nrows(), 0)
    } else {
        orthonormal_basis(&finite_difference::jacobian(plain, x, &free).ok()?)
    };
    let left = project_out(&res, &q);
    let [design, b, c] = stretch_blocks(plain, x[idx::STRETCH_RATIO])?;
    let (design, b, c) = (
        project_out(&design, &q),
        project_out(&b, &q),
        project_out(&c, &q),
    );
    (0..RATIOS)
        .map(|k| {
            let qm = orthonormal_basis(&at_ratio(&design, &b, &c, ratio(k)));
            let rest = &left - &qm * (qm.transpose() * &left);
            (k, rest.norm_squared())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, _)| k)
}

/// The parameters `p` with the shape misfit's amplitudes at zero.
fn without_misfit(p: &[f64]) -> Vec<f64> {
    let mut bare = p.to_vec();
    for v in &mut bare[idx::SHAPE..idx::SHAPE + N_SHAPE] {
        *v = 0.0;
    }
    bare
}

/// Which named effects [`judge_standing`] leaves out or judges against the external load alone.
pub struct JudgedAs<'a> {
    /// Not judged.
    pub exempt: &'a [&'static Effect],
    /// Judged against the external load alone.
    pub load_only: &'a [&'static Effect],
}

/// How much removing an effect raises the BIC against one alternative law (the fitter's
/// problem): `with` the model with it, the model without it (`trial`) fitted from `with`'s
/// parameters and from the same without the misfit amplitudes, the better kept; and when the
/// effect would stand on those, from zero too. Why: an LM fit of a set without an effect,
/// started from a model where it took part, can stall far off (a scale left at the size it had
/// beside a frame: a frame removed beside an external load's stretch stalled at 21 209 µm²
/// where the same set from zero reaches 3 544 µm²), and a stalled fit makes the effect look
/// needed. A fit that does not stand needs no other start (another start can only
/// lower its support).
fn support_against(
    fitter: &mut Fitter<'_>,
    with: &Fit,
    trial: &[&'static Effect],
    noise_um: Option<f64>,
) -> Option<f64> {
    if with.p.len() != N_PARAMS {
        return None;
    }
    let bare = without_misfit(&with.p);
    let mut best: Option<Fit> = None;
    for f in [fitter.fit(trial, &with.p), fitter.fit(trial, &bare)]
        .into_iter()
        .flatten()
    {
        if best.as_ref().is_none_or(|b| f.cost < b.cost) {
            best = Some(f);
        }
    }
    let support = delta_bic(fitter.problem, noise_um, with, &best?);
    if support < ADD_MARGIN {
        return Some(support);
    }
    // The fitter refits from a start only when it is better than its cached optimum: zero, a
    // start far off, is fitted from regardless.
    let free = fitter.problem.free_params(trial);
    Some(match fit(fitter.problem, &[0.0; N_PARAMS], &free) {
        Some(f) => support.min(delta_bic(fitter.problem, noise_um, with, &f)),
        None => support,
    })
}

/// The named effects of `set` (`judged_as.exempt` aside, `stretch` among them) judged by the
/// module doc's rule: with each its support (how much removing it raises the BIC) and whether
/// it stands; those of `judged_as.load_only` against the external load alone.
/// `plain` is the problem without a shape misfit, `cur` the fit of `set` on it or beside a
/// shape misfit (its misfit amplitudes are not used), `x_modes` where the generalised shape is
/// built (the stretch's parameters, its compliance ratio in its plausible range).
pub fn judge_standing(
    plain: &Problem,
    stretch: &'static Effect,
    x_modes: &[f64],
    set: &[&'static Effect],
    judged_as: &JudgedAs<'_>,
    cur: &Fit,
    noise_um: Option<f64>,
) -> Vec<(&'static Effect, f64, bool)> {
    let start = without_misfit(&cur.p);
    // The ratio of the model with every named effect, and each judged effect's from the model
    // without it: each hypothesis at its best.
    let Some(k_full) = best_ratio_index(plain, &start, set) else {
        return Vec::new();
    };
    let mut judged: Vec<(usize, usize)> = Vec::new();
    for (i, c) in set.iter().enumerate() {
        if judged_as.exempt.contains(c) {
            continue;
        }
        let mut x = start.clone();
        for &k in c.params {
            x[k] = 0.0;
        }
        let others: Vec<&'static Effect> = set.iter().copied().filter(|e| e != c).collect();
        judged.push((i, best_ratio_index(plain, &x, &others).unwrap_or(k_full)));
    }
    let mut ratios: Vec<usize> = judged.iter().map(|&(_, k)| k).collect();
    ratios.extend([k_full, EQUAL]);
    ratios.sort_unstable();
    ratios.dedup();
    let problems: Vec<(usize, Problem)> = ratios
        .into_iter()
        .filter_map(|k| {
            let mut with = plain.clone();
            set_misfit_modes(&mut with, stretch, x_modes, ratio(k))
                .ok()
                .map(|_| (k, with))
        })
        .collect();
    let ratios_built: Vec<usize> = problems.iter().map(|(k, _)| *k).collect();
    let mut fitters: Vec<Fitter<'_>> = problems.iter().map(|(_, p)| Fitter::new(p)).collect();
    let at = |k: usize| ratios_built.iter().position(|&r| r == k);
    // At ratio 1 the caller's misfit modes are these: its fit's amplitudes are a start there.
    let mut full_at = |k: usize| {
        let f = at(k)?;
        if k == EQUAL {
            fitters[f].fit(set, &cur.p);
        }
        fitters[f].fit(set, &start)
    };
    let (Some(full), Some(full_equal)) = (full_at(k_full), full_at(EQUAL)) else {
        return Vec::new();
    };
    // The external load's alternative: the library's stretch and a constant force on the
    // platform carried by the two bars by their own compliances (`misfit_modes::load_columns`); its
    // model with every named effect fitted when first needed.
    let mut load = plain.clone();
    let load_ok = set_load_modes(&mut load, stretch, x_modes).is_ok();
    let mut load_fitter = Fitter::new(&load);
    let mut full_load: Option<Option<Fit>> = None;
    let mut out = Vec::new();
    for (i, k) in judged {
        let mut trial = set.to_vec();
        let c = trial.remove(i);
        // Against each alternative law: the data's ratios, equal elongations, the external load
        // (only the last for an effect judged against the load alone). Once below the margin,
        // the effect does not stand whatever the rest give: the load is not fitted then.
        let mut support = f64::INFINITY;
        let shaped = [(k, &full), (EQUAL, &full_equal)];
        for (k_without, with) in shaped
            .into_iter()
            .filter(|_| !judged_as.load_only.contains(&c))
        {
            let Some(slot) = at(k_without) else {
                continue;
            };
            if let Some(v) = support_against(&mut fitters[slot], with, &trial, noise_um) {
                support = support.min(v);
            }
        }
        if load_ok && support >= ADD_MARGIN {
            let with = full_load.get_or_insert_with(|| load_fitter.fit(set, &start));
            if let Some(with) = with.as_ref() {
                if let Some(v) = support_against(&mut load_fitter, with, &trial, noise_um) {
                    support = support.min(v);
                }
            }
        }
        if support.is_finite() {
            out.push((c, support, support >= ADD_MARGIN));
        }
    }
    // In the set's order, for the log.
    out.sort_by_key(|(c, _, _)| set.iter().position(|e| e == c));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loop_closure::SixBarDesign;
    use crate::synth::other_laws::{OtherStretch, StretchLaw};
    use crate::synth::{generate, Poses, Truth};
    use kinematics_core::FiveBar;

    /// The ratio found for a warming that elongates c by `c_ratio` times b's, nothing else
    /// hidden, nothing named.
    fn found_ratio(c_ratio: f64) -> f64 {
        let truth = Truth {
            noise_um: 0.5,
            other_stretch: Some(OtherStretch {
                law: StretchLaw::Thermal { angle_rad: 0.4 },
                rms_um: 20.0,
                c_ratio,
            }),
            ..Default::default()
        };
        let data = generate(&truth, Poses::Random(120), 5);
        let problem = Problem::new(FiveBar::paper_nominal(), &SixBarDesign::paper(), &data);
        let x = [0.0; N_PARAMS];
        ratio(best_ratio_index(&problem, &x, &[]).expect("a ratio"))
    }

    /// The shared ratio is the data's: a warming that elongates c by 1.5 or 0.7 times b's is
    /// found at that ratio (to the grid's step, 9.6 %), not at 1.
    #[test]
    fn the_shared_ratio_is_the_datas() {
        for c_ratio in [1.5, 0.7] {
            let r = found_ratio(c_ratio);
            assert!(
                (r / c_ratio).ln().abs() < 0.1,
                "c elongating by {c_ratio} × b's: ratio found {r:.3}"
            );
        }
    }
}
