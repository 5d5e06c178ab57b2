//! Effects named where a distal stretch of another law could have been: the shape check
//! (`shape.rs`) for the case the library's stretch is not named.
//!
//! A distal stretch by another law of the configuration than the library's (a spring between
//! the elbows, a hose pulling on the platform) can leave the library's stretch behind: on the
//! paper machine's poses the stretch is within a principal cosine of 0.9997 of link lengths and
//! of 0.9988 of encoder offsets, so link lengths plus encoder offsets fit such a stretch to the
//! noise, better than the library's stretch does, and the selection names them (or it names the
//! stretch first and then replaces it by them). Without a check both are claimed, neither there.
//!
//! The rule ([`check_stand_ins`], after the selection and its nuisances, when `link_stretch` is
//! not named): each named effect that **joins after another** must stand on its own beside the
//! stretch's generalised shape (the library stretch and its shape-misfit modes, `shape.rs`),
//! with every other named effect in place: lower the BIC by more than [`ADD_MARGIN`] (the
//! alternatives of `standing.rs`: the generalised shape at two shared ratios, and an external
//! load on the platform carried by the two bars by their own compliances). The first named
//! effect is judged against every alternative too when the library's stretch alone fits the
//! data as well as it alone (within [`ADD_MARGIN`] of BIC, or better): then the data could not
//! decide between it and a stretch from the first step on. Otherwise, when another effect joins
//! it, the first is judged against the external load alone. An effect that does not stand is
//! **declared open** (`shape_misfits[].open` beside `link_stretch`, `effect_named` false):
//! named, in the model, but not claimed, as an ambiguous pair is; the model itself is left as
//! the selection chose it.
//!
//! Why open and not dropped: the named model explains the data without the stretch (the
//! selection preferred it, with fewer parameters); only the claim is in doubt. Why the first
//! effect, clearly ahead of a stretch, is judged against the external load alone: what the data
//! name first is what they say most plainly, and the generalised shape (20 modes) can stand in
//! for much of a real effect's signature; but a constant load stretches one bar and shortens
//! the other by laws no shared ratio follows, and link lengths then come first carrying the two
//! bars' mean elongation, ahead of the library's stretch. The load's compliance shape is four
//! columns of the pose's statics, too narrow to reproduce a real effect's proximal or
//! instrument part. An effect named alone is not judged: nothing joined it that a misfit could
//! have brought in.
//!
//! What it costs: a real effect that joins after another and whose signature a stretch of
//! another law reproduces at its fitted size (a small encoder offset beside link lengths) is
//! declared open too: the data do not decide, and the report says so.
//!
//! Cost: when it runs, one fit alone of the first effect and of the stretch, then
//! `standing.rs`'s (per named effect a few LM fits with up to 20 more parameters), two
//! cross-validations.

use super::forward_model::Problem;
use super::library::{idx, Effect, LIBRARY, N_PARAMS};
use super::misfit_modes::{describe, set_misfit_modes};
use super::report::ShapeMisfit;
use super::scoring::{delta_bic, Fitter, ADD_MARGIN};
use super::selection::Selection;
use super::shape::supports_text;
use super::standing::{judge_standing, JudgedAs};
use crate::effect::PhysicalEffect;

/// The compliance ratio range (%) the generalised shape is built at: the plausibility range of
/// `kc_compliance_pct` (c within a factor 3 of b's compliance). A stretch fitted beside effects
/// that already explain the data can run its ratio off; the shape is built at the nearest
/// plausible one.
const KC_PCT: (f64, f64) = (-67.0, 200.0);

/// The check of the module doc on the selection `sel` (its nuisances set in `problem`): the
/// misfit entry declaring open the named effects that do not stand beside a stretch of another
/// law, if any, and log lines.
pub fn check_stand_ins(
    problem: &Problem,
    sel: &Selection,
    noise_um: Option<f64>,
) -> (Option<ShapeMisfit>, Vec<String>) {
    let mut log = Vec::new();
    let Some(stretch) = LIBRARY
        .iter()
        .find(|e| e.kind == PhysicalEffect::LinkStretch)
    else {
        return (None, log);
    };
    let Some(&first) = sel.effects.first() else {
        return (None, log);
    };
    if sel.effects.contains(&stretch) || problem.available(stretch).is_err() {
        return (None, log);
    }
    let misfit = judge(problem, sel, stretch, first, noise_um, &mut log);
    (misfit, log)
}

/// [`check_stand_ins`] once it applies: `stretch` not named, `first` the first named effect.
fn judge(
    problem: &Problem,
    sel: &Selection,
    stretch: &'static Effect,
    first: &'static Effect,
    noise_um: Option<f64>,
    log: &mut Vec<String>,
) -> Option<ShapeMisfit> {
    let mut plain = Fitter::new(problem);
    let zero = [0.0; N_PARAMS];
    let alone = plain.fit(&[first], &zero)?;
    let stretch_alone = plain.fit(&[stretch], &zero)?;
    let d_alone = delta_bic(problem, noise_um, &alone, &stretch_alone);
    // The first effect clearly ahead of the library's stretch alone is judged against an
    // external load's stretch only (module doc); otherwise against every alternative.
    let load_only: Vec<&'static Effect> = if d_alone < ADD_MARGIN {
        Vec::new()
    } else {
        vec![first]
    };
    let exempt = [stretch];
    if sel
        .effects
        .iter()
        .all(|c| exempt.contains(c) || load_only.contains(c))
    {
        return None;
    }
    let mut set = sel.effects.clone();
    set.push(stretch);
    let beside = plain.fit(&set, &sel.fit.p)?;
    let mut x = beside.p.clone();
    x[idx::STRETCH_RATIO] = x[idx::STRETCH_RATIO].clamp(KC_PCT.0, KC_PCT.1);
    let mut with = problem.clone();
    let modes = match set_misfit_modes(&mut with, stretch, &x, 1.0) {
        Ok(m) => m,
        Err(why) => {
            log.push(format!(
                "{}: no check of the effects named in its place: {why}",
                stretch.name()
            ));
            return None;
        }
    };
    let k_modes = with.nuisance.shape.map_or(0, |(_, k)| k);
    let mut fitter = Fitter::new(&with);
    let full = fitter.fit(&set, &beside.p)?;
    let judged = judge_standing(
        problem,
        stretch,
        &x,
        &set,
        &JudgedAs {
            exempt: &exempt,
            load_only: &load_only,
        },
        &full,
        noise_um,
    );
    let open: Vec<(&'static Effect, f64)> = judged
        .iter()
        .filter(|(_, _, stands)| !stands)
        .map(|&(c, s, _)| (c, s))
        .collect();
    let first_text = if load_only.contains(&first) {
        format!(
            "{} first, ahead of {} alone by {:.1} of BIC (judged beside an external load only)",
            first.name(),
            stretch.name(),
            d_alone
        )
    } else {
        format!(
            "{} alone fits the data as well as {} alone (ΔBIC {:.1}): judged too",
            stretch.name(),
            first.name(),
            d_alone
        )
    };
    if open.is_empty() {
        log.push(format!(
            "{} not named; {first_text}; every named effect judged stands beside its generalised shape ({k_modes} \
             modes; lowering the BIC by {})",
            stretch.name(),
            supports_text(&judged)
        ));
        return None;
    }
    let supports: Vec<String> = open
        .iter()
        .map(|(c, s)| format!("{} {s:.1}", c.name()))
        .collect();
    log.push(format!(
        "{} not named; {first_text}; beside its generalised shape ({k_modes} modes) and the other named effects \
         these lower the BIC by (an effect needs > {ADD_MARGIN}): {}: open",
        stretch.name(),
        supports.join(", ")
    ));
    let delta_bic_shape = delta_bic(&with, noise_um, &sel.fit, &full);
    let cv_without = plain.cv_rss(&sel.effects, &sel.fit.p);
    let cv_with = fitter.cv_rss(&set, &full.p);
    let description = describe(&with, &modes, &full.p);
    Some(ShapeMisfit {
        effect: stretch.name().to_string(),
        effect_named: false,
        significant: false,
        rms_um: 0.0,
        delta_bic: delta_bic_shape,
        delta_cv_rss_um2: match (cv_with, cv_without) {
            (Some(w), Some(wo)) => w - wo,
            _ => f64::NAN,
        },
        not_named: Vec::new(),
        open: open.iter().map(|(c, _)| c.name().to_string()).collect(),
        description: format!(
            "the distal bars' stretch is not named: the named effects fit the data, but what those declared open do, \
             a stretch by another law than the library's explains as well (fitted beside them: {description})"
        ),
    })
}
