//! A named effect whose library shape does not fully explain its part of the residual: the shape
//! misfit, reported as such, so that the rest is not handed to unrelated effects.
//!
//! A real machine never matches a library shape exactly. The distal bars' stretch, for one, is
//! the library's self-stress modes of the six-bar as drawn (`link_stretch`), but a machine whose
//! bars stiffen or slip under load, whose compliance changes across the workspace, stretches its
//! bars by another law of the configuration. What the library shape leaves is smooth and large
//! next to a micrometre of noise, and effects whose signatures overlap it (on the paper
//! machine's poses the stretch is within a principal cosine of 0.999 of link lengths and of
//! encoder offsets: the report's `pose_overlaps`) each pass the add test on its account: the selection names
//! `link_stretch` + `encoder_offset` + `link_lengths` with neither of the last two there.
//!
//! The rule: an effect named beside a generalisable effect E must stand on its own against E's
//! **generalised shape**, E's physical form with a smooth law of the configuration instead of the
//! library's. For `link_stretch` that is one load law `g` of the link angles (a cubic
//! polynomial, centred and scaled over the data: 10 terms) in place of the linearised loop
//! closure's five modes, elongating b by `g` and c by `r·g`, the ratio `r` a combination of the
//! design's (`(1 + kc/100)·α(θ)`, α the two bars' elongation ratio under the loops'
//! self-stress at the point, the library modes' own, kc the fitted compliance ratio) and of
//! one shared ratio (a load or a warming the two bars share, in the ratio of their compliances
//! or expansions: 1 for the misfit itself; near 1, within a factor 3 either way, the data's, when
//! an effect's standing is judged, `standing.rs`): 20 columns. Their part outside E's own span
//! at the fitted model, reduced by SVD to at most [`N_SHAPE`](super::library::N_SHAPE) unit-RMS
//! modes, is the **shape misfit**, fitted as a nuisance: in every model, never named, what it
//! explains staying in the residual the report prints. The columns and the modes are built in
//! [`super::misfit_modes`].
//!
//! The check ([`check_shapes`], after the selection and its nuisances, for each generalisable
//! effect E named): with E's misfit modes fitted alongside, does every other named effect still
//! lower the BIC by more than [`ADD_MARGIN`] (the add test)? The weakest that does not is set
//! aside, the rest refitted, until every one does. No effect the selection did not name comes in
//! (the question is which of the named ones stand, not a new search). Then: is E's misfit
//! significant beside **every** named effect (the BIC lower by more than [`ADD_MARGIN`] with
//! every mode charged, the cross-validated RSS lower by more than the modes cost, k·σ²)?
//! * If so, the named model leaves a misfit: the effects set aside are **not named**
//!   (`not_named`), and the misfit is **kept** (a nuisance: reported, `unexplained`, described
//!   by the law it fits) when it is significant beside what is left; otherwise the final model
//!   is the one left, refitted without it.
//! * If not, the named model explains the data and stays: each named effect that does not lower
//!   the BIC by more than [`ADD_MARGIN`] beside E's misfit modes with every other named effect in
//!   place (the model that stays; no effect set aside first, so that one stand-in cannot carry
//!   another's part and stand in its place) is **declared open** (`open`), named but not
//!   claimed, as an ambiguous pair is. Why not drop them here
//!   too: the generalised shape, flexible as it is, can stand in for a real frame or base
//!   offset beside a library-shaped stretch on sparse data, and dropping them would trade a
//!   false name for a miss; only a misfit the named model leaves is a reason to drop them.
//!
//! Why a generalised shape and not a test of the newcomer's contribution alone: a newcomer's
//! evidence is all in its part orthogonal to the named effects (that is what the joint least
//! squares measure), so orthogonality cannot tell a real encoder offset from one carrying the
//! stretch's misfit; only an alternative explanation of the same residual can. Why the misfit is
//! not charged when the newcomers are judged: the question is what they explain that the named
//! effect's other laws cannot, not whether another law is proven. Why one law for both bars: an
//! arbitrary elongation of each bar reproduces any tool displacement field (two lengths, two
//! coordinates), so it would stand in for every effect; one law with c's ratio in a
//! two-dimensional family leaves a large part of the signature beyond the library's stretch of
//! link lengths, encoder offsets, a base offset, a frame or a gear ratio outside it, so a real
//! one of those of some size stays named. What it costs: an
//! instrument scale, whose signature beyond the stretch lies wholly in it (the stretch alone is
//! within a principal cosine of 0.9988 of it), is not named beside a stretch whose shape
//! misfits, and is listed under `not_named`. Why not the design's ratio alone (10 columns,
//! nearly orthogonal to every five-bar effect): a stiffening or slipping bar changes the ratio
//! with the load, and the part it leaves, c's alone, is what link lengths then take.
//!
//! Cost: when a generalisable effect is named, one Jacobian of its parameters, an SVD of n×20,
//! and one LM fit per named effect and per effect not named (with up to 20 more parameters),
//! two cross-validations.

use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{Effect, LIBRARY};
use super::misfit_modes::{describe, misfit_rms_um, set_misfit_modes};
use super::report::ShapeMisfit;
use super::scoring::{delta_bic, sigma2, Fitter, ADD_MARGIN};
use super::selection::Selection;
use super::standing::{judge_standing, JudgedAs};
use crate::effect::PhysicalEffect;

/// Effects with a generalised shape.
pub const GENERALISED: [PhysicalEffect; 1] = [PhysicalEffect::LinkStretch];

/// The shape-misfit check of the module doc on the selection `sel` (its nuisances set in
/// `problem`). Returns the selection to report, the misfit for the report (when an effect was
/// not named on its account or the misfit is kept) and log lines; when the misfit is kept,
/// `problem` has it as a nuisance.
pub fn check_shapes(
    problem: &mut Problem,
    sel: Selection,
    noise_um: Option<f64>,
) -> (Selection, Option<ShapeMisfit>, Vec<String>) {
    let mut log = Vec::new();
    for kind in GENERALISED {
        let Some(e) = LIBRARY.iter().find(|e| e.kind == kind) else {
            continue;
        };
        if !sel.effects.contains(&e) || problem.available(e).is_err() {
            continue;
        }
        match check_one(problem, &sel, e, noise_um, &mut log) {
            Some((Some((with, p)), misfit)) => {
                *problem = p;
                return (with, Some(misfit), log);
            }
            Some((None, misfit)) => return (sel, Some(misfit), log),
            None => {}
        }
    }
    (sel, None, log)
}

/// [`check_shapes`] for one named generalisable effect `e`: `Some` with the selection, the misfit
/// and the problem to report when the misfit changes the outcome (an effect not named, or the
/// misfit kept).
fn check_one(
    problem: &Problem,
    sel: &Selection,
    e: &'static Effect,
    noise_um: Option<f64>,
    log: &mut Vec<String>,
) -> Option<(Option<(Selection, Problem)>, ShapeMisfit)> {
    // The misfit the named model leaves is judged, and kept, at equal elongations of the two
    // bars (a shared ratio fitted beside every named effect can run to the end of its range and
    // trade hundreds of micrometres with them); each effect's standing at the ratio the data
    // give without it (`standing.rs`).
    let mut with = problem.clone();
    with.nuisance.shape = None;
    let modes = match set_misfit_modes(&mut with, e, &sel.fit.p, 1.0) {
        Ok(m) => m,
        Err(why) => {
            log.push(format!("{}: no shape-misfit check: {why}", e.name()));
            return None;
        }
    };
    let k_modes = with.nuisance.shape.map_or(0, |(_, k)| k);
    let mut plain = with.clone();
    plain.nuisance.shape = None;
    let mut fitter = Fitter::new(&with);
    let mut set = sel.effects.clone();
    let mut cur = fitter.fit(&set, &sel.fit.p)?;
    // First: does the named model leave a misfit at all? Judged with every named effect in
    // place, so that a model that explains the data (the library's own stretch beside a real
    // frame, to the noise) is left alone: the generalised shape could stand in for those
    // effects too, and only a misfit the named model cannot explain is a reason to doubt them.
    let first = significance(&with, &plain, &set, &sel.fit, &cur, noise_um, k_modes)?;
    if !first.significant {
        // The named model explains the data: it stays, but each named effect that does not stand
        // beside the generalised shape, judged with every other named effect in place (the model
        // that stays), is declared open (a stretch of another law explains what it does as well),
        // not claimed.
        let judged = judge_standing(
            &plain,
            e,
            &sel.fit.p,
            &set,
            &JudgedAs {
                exempt: &[e],
                load_only: &[],
            },
            &cur,
            noise_um,
        );
        let supports = supports_text(&judged);
        let open: Vec<String> = judged
            .iter()
            .filter(|(_, _, stands)| !stands)
            .map(|(c, _, _)| c.name().to_string())
            .collect();
        if open.is_empty() {
            log.push(format!(
                "{}'s shape misfit not significant beside the named effects ({}) and every named effect stands \
                 beside its generalised shape (lowering the BIC by {supports})",
                e.name(),
                first.text()
            ));
            return None;
        }
        log.push(format!(
            "{}'s shape misfit not significant beside the named effects ({}): they stay named; open: {} (beside \
             {}'s generalised shape and the other named effects they do not lower the BIC by > {ADD_MARGIN}: \
             {supports})",
            e.name(),
            first.text(),
            open.join(", "),
            e.name()
        ));
        let description = describe(&with, &modes, &cur.p);
        return Some((
            None,
            ShapeMisfit {
                effect: e.name().to_string(),
                effect_named: true,
                significant: false,
                rms_um: 0.0,
                delta_bic: first.delta_bic,
                delta_cv_rss_um2: first.cv_with - first.cv_without,
                not_named: Vec::new(),
                open,
                description: format!(
                    "not significant beside the named effects; what the effects declared open explain, a stretch of \
                     another law explains as well ({description})"
                ),
            },
        ));
    }
    // The named model leaves a misfit: does every other named effect stand on its own beside
    // e's generalised shape? The weakest that does not is dropped, the rest refitted, until every
    // one does.
    loop {
        let mut weakest: Option<(f64, usize, Fit)> = None;
        for (i, c) in set.iter().enumerate() {
            if *c == e {
                continue;
            }
            let mut trial = set.clone();
            trial.remove(i);
            let Some(f) = fitter.fit(&trial, &cur.p) else {
                continue;
            };
            let support = delta_bic(&with, noise_um, &cur, &f);
            if support < ADD_MARGIN && weakest.as_ref().is_none_or(|w| support < w.0) {
                weakest = Some((support, i, f));
            }
        }
        let Some((support, i, f)) = weakest else {
            break;
        };
        log.push(format!(
            "beside {}'s generalised shape ({k_modes} modes) {} lowers the BIC by {support:.1} (an effect needs > \
             {ADD_MARGIN}): not named",
            e.name(),
            set[i].name()
        ));
        set.remove(i);
        cur = f;
    }
    let mut outcome = Selection {
        effects: set,
        fit: cur,
        log: Vec::new(),
        skipped: Vec::new(),
    };
    let not_named: Vec<String> = sel
        .effects
        .iter()
        .filter(|c| !outcome.effects.contains(c))
        .map(|c| c.name().to_string())
        .collect();
    // Is the misfit itself significant beside what is left, every mode charged?
    let without = Fitter::new(&plain).fit(&outcome.effects, &outcome.fit.p)?;
    let last = significance(
        &with,
        &plain,
        &outcome.effects,
        &without,
        &outcome.fit,
        noise_um,
        k_modes,
    )?;
    let (significant, d_misfit) = (last.significant, last.delta_bic);
    let (cv_without, cv_with) = (last.cv_without, last.cv_with);
    if not_named.is_empty() {
        log.push(format!(
            "{}'s shape misfit ({}): every named effect stands beside it",
            e.name(),
            last.text()
        ));
        if !significant {
            return None;
        }
    }
    let rms_um = misfit_rms_um(&with, &outcome.fit.p);
    let description = describe(&with, &modes, &outcome.fit.p);
    let why_not = if not_named.is_empty() {
        String::new()
    } else {
        format!(
            "; not named: {} (beside {}'s generalised shape they do not lower the BIC by > {ADD_MARGIN})",
            not_named.join(", "),
            e.name()
        )
    };
    let mut first_log = sel.log.clone();
    first_log.append(&mut outcome.log);
    outcome.log = first_log;
    outcome.skipped = sel.skipped.clone();
    let report_problem = if significant {
        log.push(format!(
            "{}'s shape misfit kept as a nuisance ({k_modes} modes, {rms_um:.2} µm RMS; ΔBIC {d_misfit:.1}, \
             cross-validated RSS {cv_without:.1} → {cv_with:.1} µm²){why_not}",
            e.name()
        ));
        with
    } else {
        log.push(format!(
            "{}'s shape misfit not significant on its own (ΔBIC {d_misfit:.1}, cross-validated RSS {cv_without:.1} → \
             {cv_with:.1} µm²): not kept{why_not}",
            e.name()
        ));
        outcome.fit = without;
        plain
    };
    let misfit = ShapeMisfit {
        effect: e.name().to_string(),
        effect_named: true,
        significant,
        rms_um: if significant { rms_um } else { 0.0 },
        delta_bic: d_misfit,
        delta_cv_rss_um2: cv_with - cv_without,
        not_named,
        open: Vec::new(),
        description: if significant {
            description
        } else {
            format!(
                "not significant on its own; what the effects not named explain, a stretch of another law explains as \
                 well ({description})"
            )
        },
    };
    Some((Some((outcome, report_problem)), misfit))
}

/// Each judged effect's support (how much it lowers the BIC beside the generalised shape), for
/// the log.
pub(super) fn supports_text(judged: &[(&'static Effect, f64, bool)]) -> String {
    judged
        .iter()
        .map(|(c, s, _)| format!("{} {s:.1}", c.name()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The misfit's significance: the BIC lower by more than [`ADD_MARGIN`] with every mode charged,
/// and the cross-validated RSS lower by more than the modes cost (k·σ²).
struct Significance {
    significant: bool,
    delta_bic: f64,
    cv_without: f64,
    cv_with: f64,
    margin: f64,
}

impl Significance {
    fn text(&self) -> String {
        format!(
            "ΔBIC {:.1}, needs < −{ADD_MARGIN}; cross-validated RSS {:.1} → {:.1} µm², needs a drop > {:.1}",
            self.delta_bic, self.cv_without, self.cv_with, self.margin
        )
    }
}

/// [`Significance`] of the misfit modes of `with` for the effects `set`, fitted without them
/// (`plain`, `fit_plain`) and with them (`fit_with`).
fn significance(
    with: &Problem,
    plain: &Problem,
    set: &[&'static Effect],
    fit_plain: &Fit,
    fit_with: &Fit,
    noise_um: Option<f64>,
    k_modes: usize,
) -> Option<Significance> {
    let delta_bic = delta_bic(with, noise_um, fit_plain, fit_with);
    let s2 = sigma2(with, noise_um, &[fit_plain, fit_with]);
    let cv_without = Fitter::new(plain).cv_rss(set, &fit_plain.p)?;
    let cv_with = Fitter::new(with).cv_rss(set, &fit_with.p)?;
    let margin = k_modes as f64 * s2;
    Some(Significance {
        significant: delta_bic < -ADD_MARGIN && cv_with < cv_without - margin,
        delta_bic,
        cv_without,
        cv_with,
        margin,
    })
}
