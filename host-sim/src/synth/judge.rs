//! A diagnosis judged against the truth it was run on: what the false-positive sweeps
//! (`benches/diagnose_study.rs`) and the tests count.
//!
//! Rules (the physics' exact twins are not errors): a hidden `scale` may be named as a common
//! change of all links (`link_lengths`, with the pair reported confounded); a gear ratio about a
//! fixed reference angle is, in the library's terms, its ratio about the data's mean angle plus an
//! encoder offset, so an `encoder_offset` beside a hidden gear ratio is part of the truth. A
//! named effect that is neither hidden nor a twin is a *false positive*, unless the report
//! declares it ambiguous with a hidden effect (or that twin), or open beside a hidden effect's shape
//! misfit: then the report names the truth as the alternative and the measurement that
//! separates them, and it is counted *declared*. A
//! *miss* is a hidden effect not named (a hidden scale named as its twin is not a miss).

use crate::diagnose::report::Report;

/// What a report names, against the hidden effects.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Judgement {
    /// Named, not hidden, not a twin, not declared ambiguous with the truth.
    pub false_positives: Vec<String>,
    /// Named, not hidden, not a twin, declared ambiguous with a hidden effect.
    pub declared: Vec<String>,
    /// Hidden and not named.
    pub missed: Vec<String>,
}

/// Judges `r` against the effects `hidden` (names of the library's effects) by the module
/// doc's rules.
pub fn judge(hidden: &[&str], r: &Report) -> Judgement {
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    let twin = |e: &str| {
        (e == "link_lengths"
            && hidden.contains(&"scale")
            && r.confounded
                .contains(&vec!["link_lengths".to_string(), "scale".to_string()]))
            || (e == "encoder_offset" && hidden.contains(&"gear_ratio"))
    };
    let mut truth_terms: Vec<&str> = hidden.to_vec();
    if hidden.contains(&"gear_ratio") {
        truth_terms.push("encoder_offset");
    }
    let mut j = Judgement::default();
    for &e in named.iter().filter(|e| !hidden.contains(e) && !twin(e)) {
        if r.declares_alternative(e, &truth_terms) {
            j.declared.push(e.to_string());
        } else {
            j.false_positives.push(e.to_string());
        }
    }
    j.missed = hidden
        .iter()
        .filter(|e| !(named.contains(e) || (**e == "scale" && named.contains(&"link_lengths"))))
        .map(|e| e.to_string())
        .collect();
    j
}
