//! The diagnosis on plants whose effects follow other laws than the library's: a distal stretch
//! whose compliance stiffens with the load, saturates, or varies across the workspace
//! (`host_sim::synth::other_laws`, written from the physics of the cause, never from the
//! library's bases). The diagnosis must name the stretch and claim no other effect on its
//! misfit's account: an effect that only stands in for the misfit is either not named (the
//! misfit then reported and kept, `unexplained`) or, when the named model explains the data,
//! declared open beside the misfit (`shape_misfits[].open`). On the library's own stretch the
//! check changes nothing (`tests/diagnose.rs` holds those cases).
//!
//! The sweep over every law, companion effect, out-of-library effect and magnitude is the
//! benchmark `cargo bench -p host-sim --bench diagnose_study -- shape`.
//!
//! Cost: each diagnosis is a few seconds in the dev profile (200 poses, up to 20 more
//! parameters while the check runs).

use host_sim::diagnose::report::{table, Report};
use host_sim::diagnose::{diagnose, DiagnoseOptions};
use host_sim::synth::judge::judge;
use host_sim::synth::other_laws::{OtherStretch, StretchLaw};
use host_sim::synth::{generate, Poses, Truth};
use kinematics_core::FiveBar;

const NOISE_UM: f64 = 2.0;

/// The diagnosis of a plant whose distal bars stretch by the law `name` (drawn with `k`, RMS
/// `rms_um` over the poses and both bars), on 200 random poses from random approach directions.
fn diagnosed(name: &str, k: u64, rms_um: f64, seed: u64) -> Report {
    let law = StretchLaw::all(k)
        .into_iter()
        .find(|l| l.name() == name)
        .expect("the law exists");
    let truth = Truth {
        noise_um: NOISE_UM,
        other_stretch: Some(OtherStretch {
            law,
            rms_um,
            c_ratio: 1.0,
        }),
        ..Default::default()
    };
    let data = generate(&truth, Poses::Random(200), seed);
    diagnose(
        &data,
        &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(NOISE_UM)),
    )
    .expect("the diagnosis runs")
}

/// The stretch named, nothing else claimed: every other named effect declared open beside the
/// stretch's shape misfit.
fn check(r: &Report, what: &str) {
    let context = format!("{what}:\n{}\nlog: {:#?}", table(r), r.selection_log);
    let j = judge(&["link_stretch"], r);
    assert!(j.missed.is_empty(), "the stretch not named: {context}");
    assert!(
        j.false_positives.is_empty(),
        "claimed on the misfit's account: {context}"
    );
    for s in r.steps.iter().filter(|s| s.effect != "link_stretch") {
        assert!(r.declares_open(&s.effect), "{}: {context}", s.effect);
    }
}

/// A stretch through a compliance that stiffens with the load (`t + t²/t_rms`): on its own the
/// library's stretch leaves a misfit that encoder offsets, link lengths and a parallelogram
/// mismatch each take a part of, down to the noise; none of them is claimed.
#[test]
fn a_stiffening_stretch_claims_no_effect_on_its_misfits_account() {
    let r = diagnosed("stiffening", 0, 20.0, 11);
    check(&r, "stiffening");
    let m = r
        .shape_misfits
        .iter()
        .find(|m| m.effect == "link_stretch")
        .expect("the misfit is reported");
    assert!(
        !(m.open.is_empty() && m.not_named.is_empty()),
        "the check did nothing: {}",
        table(&r)
    );
}

/// A stretch that saturates (a joint slipping beyond a friction force), and one whose
/// compliance varies with the lever's angle.
#[test]
fn saturating_and_varying_stretches_claim_no_effect_on_their_misfits_account() {
    for name in ["saturating", "varying_compliance"] {
        let r = diagnosed(name, 0, 20.0, 21);
        check(&r, name);
    }
}

/// A stretch beyond the generalised shape's law: the distal bars' tension follows the levers'
/// opening angle (a preloaded spring between the elbows). On these poses link lengths plus
/// encoder offsets fit it to the noise, better than the library's stretch, and the selection
/// names them in its place: neither may be claimed. Each is declared open beside a stretch of
/// another law (`link_stretch`, not named), since the library's stretch alone fits the data as
/// well as the first of them alone.
#[test]
fn a_stretch_beyond_the_generalised_shape_claims_none_of_its_stand_ins() {
    let r = diagnosed("opening", 0, 20.0, 31);
    let context = format!("opening:\n{}\nlog: {:#?}", table(&r), r.selection_log);
    let j = judge(&["link_stretch"], &r);
    assert!(
        j.false_positives.is_empty(),
        "claimed in the stretch's place: {context}"
    );
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert!(
        !named.contains(&"link_stretch"),
        "the case this test is about (the stretch replaced by its stand-ins) did not arise: {context}"
    );
    let m = r
        .shape_misfits
        .iter()
        .find(|m| m.effect == "link_stretch" && !m.effect_named)
        .unwrap_or_else(|| panic!("no stretch of another law reported: {context}"));
    assert!(!m.open.is_empty(), "{context}");
    for e in &named {
        assert!(r.declares_open(e), "{e} claimed: {context}");
    }
}
