//! The diagnosis report: the JSON other tools and the tests read, and the gap-shrink table.
//!
//! Contract keys: `steps` (effects of the final model in the order added, each with `effect`,
//! `params`, `rms_before_um`, `rms_after_um`, `max_before_um`, `max_after_um`), `confounded`
//! (list of lists of effect names), `unexplained`, `final_rms_um` (RMS of the radial residual).
//! Everything else is explanation for people (`shape_misfits`: a named effect whose library
//! shape does not fully explain its part, and what was not named on its account). Cost:
//! negligible.

use super::confounding::{Overlap, PoseOverlap};
use super::structure::Finding;
use serde::Serialize;
use std::collections::BTreeMap;

/// A fitted parameter with its standard deviation (same unit as the name says).
#[derive(Clone, Debug, Serialize)]
pub struct Param {
    pub value: f64,
    pub std_dev: f64,
}

/// One row of the gap-shrink table.
#[derive(Clone, Debug, Serialize)]
pub struct Step {
    pub effect: String,
    /// The effect's parameters as fitted at this step (jointly with the earlier effects).
    pub params: BTreeMap<String, Param>,
    pub rms_before_um: f64,
    pub rms_after_um: f64,
    pub max_before_um: f64,
    pub max_after_um: f64,
}

/// A candidate the selection left out, fitted on top of the final model: how large it could be
/// and still hide in these data (about 3 standard deviations).
#[derive(Clone, Debug, Serialize)]
pub struct NotDetected {
    pub effect: String,
    /// False when some combination of its parameters is exactly what the final model already
    /// does (then no bound exists; the standard deviations are infinite, `null` in JSON).
    pub identifiable: bool,
    pub params: BTreeMap<String, Param>,
    /// BIC change had it been added (> −10: not significant).
    pub delta_bic: f64,
}

/// A named effect that a library alternative, put in its place, fits as well as the data can
/// tell (BIC within the margin an effect needs to be added, or a better prediction of held-out
/// points): the diagnosis names `effect` but declares the choice open.
#[derive(Clone, Debug, Serialize)]
pub struct Ambiguous {
    /// The effect of the final model (in `steps`).
    pub effect: String,
    /// The library effect that could be there instead.
    pub alternative: String,
    /// BIC of the model with `alternative` in place of `effect`, minus the final model's.
    pub delta_bic: f64,
    /// Cross-validated RSS (µm²) of the model with `alternative` in place of `effect`, minus the
    /// final model's (below the named effect's k·σ²: the alternative predicts held-out points
    /// about as well; negative: better); absent when a
    /// cross-validation fit failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delta_cv_rss_um2: Option<f64>,
    /// What measurement would separate them.
    pub separate_by: String,
}

/// Two named effects that two library alternatives, put in their place together, fit within
/// the margin an effect needs to be added: the diagnosis names `effects` but declares the
/// choice open (a trade one-for-one swaps, `ambiguous`, cannot see).
#[derive(Clone, Debug, Serialize)]
pub struct AmbiguousPair {
    /// The two effects of the final model (in `steps`).
    pub effects: Vec<String>,
    /// The two library effects that could be there instead.
    pub alternatives: Vec<String>,
    /// BIC of the model with `alternatives` in place of `effects`, minus the final model's.
    pub delta_bic: f64,
    /// Cross-validated RSS (µm²) of that model minus the final model's (negative: the
    /// alternatives predict held-out points better); absent when a cross-validation fit failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delta_cv_rss_um2: Option<f64>,
}

/// A named effect whose library shape does not fully explain its part of the residual: a
/// smooth generalisation of its physical form (`diagnose::shape`) fits what is left, and the
/// diagnosis reports that misfit instead of naming other effects on its account.
#[derive(Clone, Debug, Serialize)]
pub struct ShapeMisfit {
    /// The effect whose generalised shape is meant: a named one (in `steps`), or `link_stretch`
    /// not named when the selection named other effects where the library's stretch fitted the
    /// data as well (`effect_named` false; `diagnose::stand_in`).
    pub effect: String,
    /// Whether `effect` is named (in `steps`). False: the effects declared `open` are named, and
    /// a distal stretch by another law than the library's explains what each does as well.
    pub effect_named: bool,
    /// The misfit is significant (BIC and held-out test, every mode charged): it is fitted as a
    /// nuisance, stays in the residual and makes it `unexplained`. False: only `not_named`.
    pub significant: bool,
    /// Radial RMS (µm) of what the generalised shape fits beyond the library's (0 when not
    /// significant).
    pub rms_um: f64,
    /// BIC of the final model with the generalised shape minus without it.
    pub delta_bic: f64,
    /// Cross-validated RSS (µm²) with the generalised shape minus without it.
    pub delta_cv_rss_um2: f64,
    /// Effects the selection named without the check that do not stand on their own beside
    /// the named effect's generalised shape (not named).
    pub not_named: Vec<String>,
    /// Named effects that do not stand on their own beside the generalised shape, kept because
    /// the named model explains the data (the misfit not significant beside them): the data do
    /// not decide between each and a stretch of another law; they are declared open, not
    /// claimed.
    pub open: Vec<String>,
    /// The misfit's structure, for people.
    pub description: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub points: usize,
    /// Lines the base model could not reach (excluded).
    pub dropped_lines: Vec<usize>,
    /// The noise σ per axis used (µm), if known.
    pub noise_um: Option<f64>,
    /// Where `noise_um` came from.
    pub noise_source: String,
    /// How models were scored.
    pub score: String,
    pub initial_rms_um: f64,
    pub initial_max_um: f64,
    pub steps: Vec<Step>,
    /// Every parameter of the final model (jointly fitted).
    pub final_params: BTreeMap<String, Param>,
    pub confounded: Vec<Vec<String>>,
    /// Named effects with a library alternative the data cannot rule out (one-for-one swap
    /// within the adding margin of BIC), with the measurement that separates them.
    pub ambiguous: Vec<Ambiguous>,
    /// Pairs of named effects with a pair of library alternatives the data cannot rule out
    /// (two-for-two swap within the adding margin of BIC).
    pub ambiguous_pairs: Vec<AmbiguousPair>,
    /// Pairs whose residual signatures overlap (confounded, or partly identical), with the
    /// measurement that would separate them.
    pub overlaps: Vec<Overlap>,
    /// Candidates not in the final model, with how large they could be undetected.
    pub not_detected: Vec<NotDetected>,
    /// Pairs of candidates that share a direction (cos ≥ 0.99) on these poses, whatever the
    /// model: what this pose set cannot separate.
    pub pose_overlaps: Vec<PoseOverlap>,
    pub unexplained: bool,
    /// Why `unexplained` is what it is, and the structure of what is left.
    pub unexplained_description: String,
    /// Structure of the final residual (all tests, significant or not).
    pub final_structure: Vec<Finding>,
    /// Structure of the residual of the starting model.
    pub initial_structure: Vec<Finding>,
    pub final_rms_um: f64,
    pub final_max_um: f64,
    /// RSS / (n − k) / σ² of the final model, if σ is known.
    pub chi2_per_dof: Option<f64>,
    /// Structures outside the library (a gear tooth's periodic error, an instrument drift)
    /// fitted alongside every model so that no library effect is named on their account, with
    /// their fitted size; they stay in the residual and make it `unexplained`.
    pub nuisances: Vec<String>,
    /// Named effects whose library shape does not fully explain their part of the residual
    /// (see [`ShapeMisfit`]); they stay in the residual and make it `unexplained`.
    pub shape_misfits: Vec<ShapeMisfit>,
    pub selection_log: Vec<String>,
    pub notes: Vec<String>,
}

impl Report {
    /// Whether the report declares the named `effect` ambiguous with one of `alternatives`
    /// (`ambiguous`), or, beside another named effect, with two of them (`ambiguous_pairs`), or
    /// open beside the shape misfit of one of them (`shape_misfits`' `open`): the diagnosis
    /// then does not claim `effect` over it. The false-positive sweeps count a named effect
    /// that is not hidden as no false positive only in that case (`synth::judge`).
    pub fn declares_alternative(&self, effect: &str, alternatives: &[&str]) -> bool {
        self.ambiguous
            .iter()
            .any(|a| a.effect == effect && alternatives.contains(&a.alternative.as_str()))
            || self.shape_misfits.iter().any(|m| {
                alternatives.contains(&m.effect.as_str()) && m.open.iter().any(|o| o == effect)
            })
            || self.ambiguous_pairs.iter().any(|a| {
                a.effects.iter().any(|e| e == effect)
                    && a.alternatives
                        .iter()
                        .all(|c| alternatives.contains(&c.as_str()))
            })
    }
}

impl Report {
    /// Whether `effect` is named but declared open beside a shape misfit (`ShapeMisfit::open`):
    /// the data do not decide between it and a named effect's other law.
    pub fn declares_open(&self, effect: &str) -> bool {
        self.shape_misfits
            .iter()
            .any(|m| m.open.iter().any(|o| o == effect))
    }
}

/// The gap-shrink table as text.
pub fn table(r: &Report) -> String {
    let mut s = String::new();
    s.push_str(&format!(
        "{:<4} {:<15} {:>10} {:>10} {:>10} {:>10}  params (± 1σ)\n",
        "step", "effect", "rms_bef_um", "rms_aft_um", "max_bef_um", "max_aft_um"
    ));
    s.push_str(&format!(
        "{:<4} {:<15} {:>10} {:>10.1} {:>10} {:>10.1}\n",
        0, "(start)", "", r.initial_rms_um, "", r.initial_max_um
    ));
    for (k, st) in r.steps.iter().enumerate() {
        let params: Vec<String> = st
            .params
            .iter()
            .map(|(n, p)| format!("{n} = {:.2} ± {:.2}", p.value, p.std_dev))
            .collect();
        s.push_str(&format!(
            "{:<4} {:<15} {:>10.1} {:>10.1} {:>10.1} {:>10.1}  {}\n",
            k + 1,
            st.effect,
            st.rms_before_um,
            st.rms_after_um,
            st.max_before_um,
            st.max_after_um,
            params.join(", ")
        ));
    }
    s.push_str(&format!(
        "final radial RMS {:.2} µm, max {:.2} µm",
        r.final_rms_um, r.final_max_um
    ));
    if let Some(c) = r.chi2_per_dof {
        s.push_str(&format!(
            ", χ²/dof {:.2} (noise {:.2} µm per axis, {})",
            c,
            r.noise_um.unwrap_or(f64::NAN),
            r.noise_source
        ));
    }
    s.push('\n');
    for c in &r.confounded {
        let sep = r.overlaps.iter().find(|o| {
            (o.effect == c[0] && o.other == c[1]) || (o.effect == c[1] && o.other == c[0])
        });
        let why = match sep {
            Some(o) if o.swap_chi2 < super::confounding::SWAP_CHI2 => {
                format!(
                    "{} can reproduce what {} explains (swap costs χ² {:.1})",
                    o.other, o.effect, o.swap_chi2
                )
            }
            Some(o) => format!(
                "the part {} = {:.2} of {} (z = {:.0}) acts exactly like {}",
                o.shared_direction, o.shared_value, o.effect, o.shared_z, o.other
            ),
            None => String::new(),
        };
        s.push_str(&format!(
            "confounded: {} — {}; to separate: {}\n",
            c.join(" ~ "),
            why,
            sep.map(|o| o.separate_by.as_str()).unwrap_or("")
        ));
    }
    for a in &r.ambiguous {
        let why = if a.delta_bic < super::ambiguity::AMBIGUOUS_MARGIN {
            format!(
                "swapping them changes the BIC by {:+.1}, less than the {} an effect needs",
                a.delta_bic,
                super::ambiguity::AMBIGUOUS_MARGIN
            )
        } else {
            format!(
                "swapping them changes the BIC by {:+.1}, but {} predicts held-out points as well: cross-validated RSS {:+.1} µm², less than {}'s parameters cost",
                a.delta_bic,
                a.alternative,
                a.delta_cv_rss_um2.unwrap_or(f64::NAN),
                a.effect
            )
        };
        s.push_str(&format!(
            "ambiguous: {} or {} ({why}); to separate: {}\n",
            a.effect, a.alternative, a.separate_by
        ));
    }
    for a in &r.ambiguous_pairs {
        s.push_str(&format!(
            "ambiguous: {} or {} (swapping the two for the two changes the BIC by {:+.1}, less than the {} an effect needs{})\n",
            a.effects.join(" + "),
            a.alternatives.join(" + "),
            a.delta_bic,
            super::ambiguity::AMBIGUOUS_MARGIN,
            a.delta_cv_rss_um2.map(|d| format!("; cross-validated RSS {d:+.1} µm²")).unwrap_or_default()
        ));
    }
    for o in r.overlaps.iter().filter(|o| !o.confounded) {
        s.push_str(&format!(
            "partly indistinguishable (not significant here): {} = {:.2} (z = {:.1}) of {} acts exactly like {}; to separate: {}\n",
            o.shared_direction, o.shared_value, o.shared_z, o.effect, o.other, o.separate_by
        ));
    }
    if !r.pose_overlaps.is_empty() {
        let p: Vec<String> = r
            .pose_overlaps
            .iter()
            .map(|o| format!("{}~{} ({:.4})", o.a, o.b, o.principal_cos))
            .collect();
        s.push_str(&format!(
            "on these poses some combination of each pair acts alike (principal cos): {}\n",
            p.join(", ")
        ));
    }
    for nd in &r.not_detected {
        let p: Vec<String> = nd
            .params
            .iter()
            .map(|(n, p)| format!("{n} = {:.2} ± {:.2}", p.value, p.std_dev))
            .collect();
        if nd.identifiable {
            s.push_str(&format!(
                "not detected: {} (ΔBIC {:.1}; if present: {})\n",
                nd.effect,
                nd.delta_bic,
                p.join(", ")
            ));
        } else {
            s.push_str(&format!(
                "not detected: {} (not identifiable alongside the final model: confounded with it)\n",
                nd.effect
            ));
        }
    }
    for m in &r.shape_misfits {
        let not_named = if m.not_named.is_empty() {
            String::new()
        } else {
            format!(
                "; not named on its account: {} (each stands no more on its own beside it)",
                m.not_named.join(", ")
            )
        };
        let not_named = if m.open.is_empty() {
            not_named
        } else {
            format!(
                "{not_named}; open: {} (named, but a stretch of another law explains what each does as well; to \
                 separate: measure configurations where the two act differently, a wider motor-angle range)",
                m.open.join(", ")
            )
        };
        if !m.effect_named {
            s.push_str(&format!(
                "shape misfit: {} (not named) — {}{not_named}\n",
                m.effect, m.description
            ));
        } else if m.significant {
            s.push_str(&format!(
                "shape misfit: {} — its library shape leaves {:.2} µm RMS that its generalised shape fits (ΔBIC {:.1}, \
                 cross-validated RSS {:+.1} µm²): {}{not_named}\n",
                m.effect, m.rms_um, m.delta_bic, m.delta_cv_rss_um2, m.description
            ));
        } else {
            s.push_str(&format!(
                "shape misfit: {} — {}{not_named}\n",
                m.effect, m.description
            ));
        }
    }
    s.push_str(&format!(
        "unexplained: {} — {}\n",
        r.unexplained, r.unexplained_description
    ));
    s
}
