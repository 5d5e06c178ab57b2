//! Tests of `host-sim diagnose` on data whose truth is hidden from the workflow.
//!
//! The data come from `host_sim::synth`, which measures the six-bar plant through
//! THE measurement path (`calib::measure`, as `host-sim measure`) for every effect the plant has
//! (link lengths, base offset, encoder offsets, backlash, instrument frame and scale, gear-tooth
//! cyclic error) and adds independent formulas for the rest (the distal bars' stretch from the
//! plant's own bar tensions, a gear ratio about a fixed reference angle, an instrument drift):
//! never the library's own effect functions. The same workflow on six-bar plants with
//! part errors is tested in `tests/diagnose_plant.rs`; the studies (the false-positive sweep,
//! Table I's power, the example file) are `benches/diagnose_study.rs`.
//!
//! Exact confoundings the physics makes (reported, not decided) are accepted as such: an
//! instrument scale may come out as a common change of all four links; a gear ratio about a
//! fixed reference angle is the library's ratio (about the data's mean angle) plus an encoder
//! offset `g·(θ̄ − θ_ref)`, checked to its value.
//!
//! Cost: each diagnosis is 0.2–1 s in the dev profile.

use host_sim::diagnose::report::{table, Report};
use host_sim::diagnose::{library::LIBRARY, DiagnoseOptions};
use host_sim::effect::PhysicalEffect;
use host_sim::io::measurement_csv::{format_measurements, Measurement};
use host_sim::machine_spec::MachineSpec;
use host_sim::synth::{generate, Cyclic, Poses, Truth};
use kinematics_core::FiveBar;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const NOISE_UM: f64 = 2.0;

/// The encoder offsets (µrad) a gear ratio about the workspace centre's motor angles adds on
/// these data: the library's ratio is about the data's circular mean angle.
fn gear_offset_urad(truth: &Truth, data: &[Measurement]) -> [f64; 2] {
    let spec = MachineSpec::paper();
    let reference = spec
        .nominal
        .inverse(spec.workspace.centre_mm(), 0.0)
        .unwrap();
    [0, 1].map(|j| {
        let (s, c) = data.iter().fold((0.0, 0.0), |(s, c), m| {
            let t = m.theta_rad()[j];
            (s + t.sin(), c + t.cos())
        });
        truth.gear_ppm[j] * (s.atan2(c) - reference[j])
    })
}

/// The named effects, with the physics' exact twins mapped onto the hidden set: `link_lengths`
/// for a hidden `scale` (a common link change: the pair must then be reported confounded), and
/// an `encoder_offset` beside a hidden gear ratio when it is the ratio's offset (checked).
fn named_as_hidden(
    r: &Report,
    truth: &Truth,
    data: &[Measurement],
    hidden: &[&str],
    what: &str,
) -> Vec<String> {
    let mut named: Vec<String> = r.steps.iter().map(|s| s.effect.clone()).collect();
    if hidden.contains(&"gear_ratio") && !hidden.contains(&"encoder_offset") {
        if let Some(step) = r.steps.iter().find(|s| s.effect == "encoder_offset") {
            let want = gear_offset_urad(truth, data);
            for (k, name) in ["dtheta1_urad", "dtheta2_urad"].iter().enumerate() {
                let p = &r.final_params[*name];
                assert!(
                    (p.value - want[k]).abs() < 5.0 * p.std_dev + 3.0,
                    "{what}: encoder_offset beside the gear ratio is not its offset: {name} {p:?} vs {:.1}\n{}",
                    want[k],
                    table(r)
                );
            }
            let _ = step;
            named.retain(|n| n != "encoder_offset");
        }
    }
    if hidden.contains(&"scale")
        && !hidden.contains(&"link_lengths")
        && named.iter().any(|n| n == "link_lengths")
    {
        assert!(
            r.confounded
                .contains(&vec!["link_lengths".to_string(), "scale".to_string()]),
            "{what}: {:?}",
            r.confounded
        );
        named.retain(|n| n != "link_lengths");
        if !named.iter().any(|n| n == "scale") {
            named.push("scale".into());
        }
    }
    named.sort();
    named
}

/// Diagnoses the truth's data against the nominal model and checks that exactly `expected`
/// effects are named (any order; twins as above), that the residual is at the noise level
/// (unless `expect_unexplained`), and that `unexplained` is what it should be. Returns the
/// report and the data for further checks.
fn check(
    truth: &Truth,
    poses: Poses,
    seed: u64,
    expected: &[&str],
    expect_unexplained: bool,
    what: &str,
) -> (Report, Vec<Measurement>) {
    let data = generate(truth, poses, seed);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).expect("diagnosis runs");
    let context = format!(
        "{what}, truth {truth:?}:\n{}\nlog: {:#?}",
        table(&r),
        r.selection_log
    );
    let named = named_as_hidden(&r, truth, &data, expected, &context);
    let mut want: Vec<String> = expected.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(named, want, "wrong effects named for {context}");
    assert_eq!(
        r.unexplained, expect_unexplained,
        "unexplained flag for {context}"
    );
    if !expect_unexplained {
        let c = r.chi2_per_dof.expect("noise known");
        assert!(
            c < 1.21,
            "residual not at the noise level (χ²/dof {c}) for {context}"
        );
        // Radial RMS of 2-D Gaussian noise with σ per axis is σ·√2.
        assert!(
            r.final_rms_um < 1.1 * NOISE_UM * 2f64.sqrt(),
            "final RMS {} for {context}",
            r.final_rms_um
        );
    }
    for s in &r.steps {
        assert!(
            s.rms_after_um <= s.rms_before_um + 1e-9,
            "step {} made it worse: {context}",
            s.effect
        );
    }
    (r, data)
}

/// The diagnosis of `data` against `base` with noise σ `noise_um`.
fn diagnose(
    data: &[Measurement],
    base: &FiveBar<f64>,
    noise_um: Option<f64>,
) -> Result<Report, host_sim::diagnose::DiagnoseError> {
    host_sim::diagnose::diagnose(data, &DiagnoseOptions::paper(*base, noise_um))
}

fn truth_with(effects: &[&str], rng: &mut ChaCha8Rng) -> Truth {
    let mut t = Truth {
        noise_um: NOISE_UM,
        ..Default::default()
    };
    for e in effects {
        t.add_random(PhysicalEffect::from_name(e).expect("an effect name"), rng)
            .expect("a library effect");
    }
    t
}

/// The false-positive sweep's truth for `hidden` on its data id (`1000·magnitude index + seed`,
/// benches/diagnose_study.rs) with instrument σ `sigma_um`, before its magnitude factor.
fn sweep_case_truth(hidden: &[&str], id: u64, sigma_um: f64) -> Truth {
    let mut rng = ChaCha8Rng::seed_from_u64(99_000 + id + 7919 * hidden.len() as u64);
    let mut truth = Truth {
        noise_um: sigma_um,
        ..Default::default()
    };
    for e in hidden {
        truth
            .add_random(PhysicalEffect::from_name(e).unwrap(), &mut rng)
            .unwrap();
    }
    truth
}

#[test]
fn each_effect_alone_is_named_exactly_and_the_gap_closes() {
    // Every library effect the generator has (parallelogram_mismatch needs the six-bar's part
    // errors: tests/diagnose_plant.rs), two seeds, random and grid poses.
    for (k, effect) in LIBRARY
        .iter()
        .enumerate()
        .filter(|(_, e)| e.name() != "parallelogram_mismatch")
    {
        for seed in 0..2u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 * k as u64 + seed);
            let truth = truth_with(&[effect.name()], &mut rng);
            let poses = if seed == 1 {
                Poses::Random(300)
            } else {
                Poses::Grid5mm
            };
            let what = format!("{} alone, seed {seed}", effect.name());
            let (r, _) = check(&truth, poses, 1000 + seed, &[effect.name()], false, &what);
            assert!(
                r.initial_rms_um > 3.0 * r.final_rms_um,
                "{}: the gap did not shrink",
                effect.name()
            );
            if effect.name() == "scale" {
                assert!(
                    r.confounded
                        .contains(&vec!["link_lengths".to_string(), "scale".to_string()]),
                    "{:?}",
                    r.confounded
                );
            }
        }
    }
}

/// The loops' stress: the distal bars' stretch from the plant's six-bar tensions, alone and
/// beside link-length errors, encoder offsets or backlash, is named exactly: nothing
/// false on its account (no base_offset, frame or gear_ratio).
#[test]
fn link_stretch_alone_and_beside_other_effects_is_named_exactly() {
    let cases: [&[&str]; 4] = [
        &["link_stretch"],
        &["link_stretch", "link_lengths"],
        &["link_stretch", "encoder_offset"],
        &["link_stretch", "backlash"],
    ];
    for (k, hidden) in cases.iter().enumerate() {
        for seed in 0..2u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(3300 + 10 * k as u64 + seed);
            let truth = truth_with(hidden, &mut rng);
            let (r, _) = check(
                &truth,
                Poses::Random(300),
                330 + seed,
                hidden,
                false,
                &format!("{hidden:?}, seed {seed}"),
            );
            assert!(
                r.initial_rms_um > 3.0 * r.final_rms_um,
                "{hidden:?}: the gap did not shrink"
            );
        }
    }
}

#[test]
fn two_effects_at_once_are_both_named() {
    let pairs = [
        ["link_lengths", "backlash"],
        ["encoder_offset", "base_offset"],
        ["frame", "backlash"],
        ["gear_ratio", "base_offset"],
        ["scale", "backlash"],
        ["encoder_offset", "gear_ratio"],
        ["link_lengths", "frame"],
    ];
    for (k, pair) in pairs.iter().enumerate() {
        let mut rng = ChaCha8Rng::seed_from_u64(7000 + k as u64);
        let truth = truth_with(pair, &mut rng);
        let (r, _) = check(
            &truth,
            Poses::Random(300),
            77 + k as u64,
            pair,
            false,
            &format!("{pair:?}"),
        );
        // Confounded pairs: the exact twins, or pairs within the final model (whose shared part
        // the report states); never one effect of the model and an absent one otherwise, but
        // for the small encoder offset a gear ratio about a fixed reference angle leaves beside
        // it (checked to its value by `named_as_hidden`): tens of µrad, which constant link
        // changes can reproduce on these poses.
        let in_model = |e: &String| r.steps.iter().any(|s| &s.effect == e);
        let gear_offset = pair.contains(&"gear_ratio") && !pair.contains(&"encoder_offset");
        for c in &r.confounded {
            assert!(
                c == &["encoder_offset", "frame"]
                    || c == &["link_lengths", "scale"]
                    || c.iter().all(in_model)
                    || (gear_offset && c.contains(&"encoder_offset".to_string())),
                "{pair:?}: unexpected confounded pair {c:?}\n{}",
                table(&r)
            );
        }
    }
}

/// The sweep's truth for a case (benches/diagnose_study.rs: seed 0 of the first magnitude).
fn sweep_truth(effects: &[&str], magnitude: f64) -> Truth {
    sweep_case_truth(effects, 0, NOISE_UM).scaled(magnitude)
}

/// A former false positive of the sweep (docs/design/diagnosis.md): base offset and
/// gear ratio at half the magnitude, random poses. The selection used to keep an extra
/// `link_lengths` (it stood in for the encoder offset the gear ratio about a fixed angle
/// leaves, at the same held-out error: the replacement demanded a strict cross-validated drop
/// even for a move that saves two parameters). Now: exactly the hidden pair (the ratio's offset
/// checked to its value), residual at the noise level.
#[test]
fn base_offset_and_gear_ratio_at_half_magnitude_name_no_link_lengths() {
    let truth = sweep_truth(&["base_offset", "gear_ratio"], 0.5);
    let (r, _) = check(
        &truth,
        Poses::Random(400),
        5000,
        &["base_offset", "gear_ratio"],
        false,
        "sweep pair at 0.5×",
    );
    assert!(
        r.steps.iter().all(|s| s.effect != "link_lengths"),
        "{}",
        table(&r)
    );
}

/// Another former false positive, a two-for-two trade: frame and gear ratio at half the
/// magnitude were named link_lengths + base_offset (the first forward step takes link_lengths,
/// and neither newcomer alone beats the member it would replace). The pair replacement makes
/// the trade: exactly the hidden pair.
#[test]
fn frame_and_gear_ratio_at_half_magnitude_are_not_traded_for_link_lengths_and_base_offset() {
    let truth = sweep_truth(&["frame", "gear_ratio"], 0.5);
    check(
        &truth,
        Poses::Random(400),
        5000,
        &["frame", "gear_ratio"],
        false,
        "sweep pair at 0.5×",
    );
}

/// A former false positive of the sweep: the stretch beside link lengths at half magnitude
/// (random poses, with and without a drift) is named link_lengths + gear_ratio. On these poses
/// the data's BIC prefers the 2-parameter ratio (by 12–18) over the 6-parameter stretch, the
/// truth, which predicts held-out points as well (cross-validated RSS within the ratio's
/// 2·σ²): the two tests an effect must pass disagree, and the report now declares the ratio
/// ambiguous with the stretch (before, it named the ratio with no declaration).
#[test]
fn stretch_beside_link_lengths_at_half_magnitude_declares_the_gear_ratio_open() {
    for drift in [false, true] {
        let mut truth = sweep_truth(&["link_lengths", "link_stretch"], 0.5);
        if drift {
            truth.drift_um_per_s = [0.012, -0.008];
        }
        let data = generate(&truth, Poses::Random(400), 5000);
        let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).expect("diagnosis runs");
        let context = format!("drift {drift}:\n{}\nlog: {:#?}", table(&r), r.selection_log);
        let hidden = ["link_lengths", "link_stretch"];
        let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
        assert!(named.contains(&"link_lengths"), "{context}");
        for e in named.iter().filter(|e| !hidden.contains(e)) {
            assert!(
                r.declares_alternative(e, &hidden),
                "{e} named without declaring a hidden alternative: {context}"
            );
            let a = r
                .ambiguous
                .iter()
                .find(|a| a.effect == *e && hidden.contains(&a.alternative.as_str()))
                .unwrap();
            assert!(a.delta_cv_rss_um2.is_some(), "{context}");
            assert!(
                table(&r).contains(&format!("ambiguous: {e} or {}", a.alternative)),
                "{context}"
            );
        }
    }
}

/// The other former false positive: frame + gear ratio at 1.5× beside a drift (random poses)
/// named an extra base_offset, declared ambiguous with encoder_offset (ΔBIC ≈ −0.5): the
/// encoder offset that a gear ratio about a fixed angle carries in the library's terms (the
/// module doc), i.e. part of the truth. Every named effect is hidden, that offset, or declared
/// ambiguous with one of them (the sweep's rule since this case).
#[test]
fn frame_and_gear_ratio_beside_a_drift_name_nothing_undeclared() {
    let mut truth = sweep_case_truth(&["frame", "gear_ratio"], 1000, NOISE_UM).scaled(1.5);
    truth.drift_um_per_s = [0.012, -0.008];
    let data = generate(&truth, Poses::Random(400), 6000);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    let truth_terms = ["frame", "gear_ratio", "encoder_offset"];
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert!(
        named.contains(&"frame") && named.contains(&"gear_ratio"),
        "{context}"
    );
    for e in named.iter().filter(|e| !truth_terms.contains(e)) {
        assert!(
            r.declares_alternative(e, &truth_terms),
            "{e} named without a declared alternative: {context}"
        );
    }
    assert!(r.unexplained, "the drift is outside the library: {context}");
}

/// A true tie of twins is reported, not picked silently: encoder offsets and a base offset at
/// half the magnitude beside an instrument drift (a sweep case, random poses; before the pair
/// replacement named base offset + frame) fit as well with `frame` in place of
/// `encoder_offset` (a common motor offset *is* a frame rotation about A0; within 1 of BIC), and
/// the report declares the pair ambiguous, whichever is named, with the measurement that
/// separates them (table line and `ambiguous` key). The sweep counts such a declared
/// alternative as no false positive; an effect named without that declaration stays one
/// (`declares_alternative` is false for any other pair).
#[test]
fn a_twin_named_within_the_adding_margin_is_declared_ambiguous() {
    let mut truth = sweep_truth(&["encoder_offset", "base_offset"], 0.5);
    truth.drift_um_per_s = [0.012, -0.008];
    let data = generate(&truth, Poses::Random(400), 5000);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert!(named.contains(&"base_offset"), "{context}");
    for e in &named {
        if *e != "base_offset" && *e != "encoder_offset" {
            assert!(
                r.declares_alternative(e, &["encoder_offset"]),
                "{e} named without declaring the hidden twin: {context}"
            );
        }
    }
    // Whichever twin is named, the other is declared.
    let a = r
        .ambiguous
        .iter()
        .find(|a| {
            (a.effect == "frame" && a.alternative == "encoder_offset")
                || (a.effect == "encoder_offset" && a.alternative == "frame")
        })
        .unwrap_or_else(|| panic!("encoder_offset ~ frame not declared ambiguous: {context}"));
    assert!(
        a.delta_bic.abs() < host_sim::diagnose::selection::AMBIGUOUS_MARGIN,
        "{context}"
    );
    assert!(a.separate_by.contains("rotated"), "{context}");
    assert!(
        table(&r).contains(&format!("ambiguous: {} or {}", a.effect, a.alternative)),
        "{context}"
    );
    assert!(
        !r.declares_alternative(&a.effect, &["link_lengths", "backlash"]),
        "{context}"
    );
    let json = serde_json::to_value(&r).expect("report serialises");
    assert!(json["ambiguous"].is_array(), "report has the ambiguous key");
}

#[test]
fn noise_only_names_nothing() {
    for seed in 0..4u64 {
        let truth = Truth {
            noise_um: NOISE_UM,
            ..Default::default()
        };
        let poses = if seed % 2 == 0 {
            Poses::Grid5mm
        } else {
            Poses::Random(300)
        };
        let (r, _) = check(
            &truth,
            poses,
            seed,
            &[],
            false,
            &format!("noise only, seed {seed}"),
        );
        assert!(r.confounded.is_empty());
    }
}

#[test]
fn hidden_gear_tooth_error_is_unexplained_and_described() {
    for (seed, (motor, cycles, amp)) in [(0usize, 50.0, 40.0), (1, 36.0, 30.0), (0, 90.0, 40.0)]
        .into_iter()
        .enumerate()
    {
        let truth = Truth {
            noise_um: NOISE_UM,
            cyclic: Some(Cyclic {
                motor,
                cycles,
                amplitude_urad: amp,
                phase_rad: 0.7 * seed as f64,
            }),
            ..Default::default()
        };
        let (r, _) = check(
            &truth,
            Poses::Grid5mm,
            300 + seed as u64,
            &[],
            true,
            &format!("cyclic {truth:?}"),
        );
        let kind = format!("periodic_theta{}", motor + 1);
        let f = r
            .final_structure
            .iter()
            .find(|f| f.kind == kind)
            .expect("periodogram ran");
        assert!(f.significant, "{f:?}");
        assert_eq!(f.cycles_per_rev, Some(cycles), "{f:?}");
        assert!(
            r.unexplained_description
                .contains(&format!("{} cycles/rev", cycles)),
            "{}",
            r.unexplained_description
        );
        // Fitted as a nuisance, never named: no library effect claims it.
        assert!(r.steps.is_empty());
        assert!(
            r.nuisances
                .iter()
                .any(|n| n.contains(&format!("{cycles} cycles/rev"))),
            "{:?}",
            r.nuisances
        );
    }
    // Together with library effects: those are named, the cyclic error is left unexplained.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut truth = truth_with(&["backlash", "link_lengths"], &mut rng);
    truth.cyclic = Some(Cyclic {
        motor: 1,
        cycles: 60.0,
        amplitude_urad: 40.0,
        phase_rad: 0.1,
    });
    let (r, _) = check(
        &truth,
        Poses::Random(400),
        9,
        &["backlash", "link_lengths"],
        true,
        "backlash + links + cyclic",
    );
    assert!(r
        .final_structure
        .iter()
        .any(|f| f.kind == "periodic_theta2" && f.significant && f.cycles_per_rev == Some(60.0)));
}

#[test]
fn hidden_drift_is_unexplained_and_described() {
    // 15 nm/s over the 400 s of a random run (one reading a second): 6 µm at the end, in x,
    // zero at the start. Its mean must not be named `frame` (a constant offset): the
    // drift is fitted as a nuisance and nothing is named on its account.
    let truth = Truth {
        noise_um: NOISE_UM,
        drift_um_per_s: [0.015, 0.0],
        ..Default::default()
    };
    let (r, _) = check(&truth, Poses::Random(400), 31, &[], true, "drift");
    let f = r
        .final_structure
        .iter()
        .find(|f| f.kind == "drift_time")
        .expect("time tested");
    assert!(f.significant, "{f:?}");
    assert!(
        r.unexplained_description.contains("drift"),
        "{}",
        r.unexplained_description
    );
    assert!(
        r.nuisances.iter().any(|n| n.contains("drift")),
        "{:?}",
        r.nuisances
    );
    // With a library effect beside it: that effect only.
    let truth = Truth {
        noise_um: NOISE_UM,
        drift_um_per_s: [0.01, -0.01],
        backlash_urad: [150.0, 90.0],
        ..Default::default()
    };
    check(
        &truth,
        Poses::Random(400),
        32,
        &["backlash"],
        true,
        "drift + backlash",
    );
}

/// Sparse data (120 random poses from random approach directions, a
/// 1 µm instrument) with the sweep's drift (12 / −8 nm/s, one reading a second: 1.4 µm at the
/// end of the run). The frame's translation (or encoder offsets, or a scale) takes the drift's
/// mean, and the ramp left about it is below the drift test's |z| > 5 on 120 points: before
/// the model comparison of `diagnose::suspected_drift`, 4 of these 5 noise-only data sets and
/// 4 of the 5 with backlash named `frame`, `encoder_offset` or `scale` beside it with
/// `unexplained: false` (the sweep, `SWEEP_POSES=120 SWEEP_NOISE_UM=1`). Now the drift is
/// fitted as a nuisance and nothing else is named.
#[test]
fn a_weak_drift_on_120_points_at_1_um_names_nothing_on_its_account() {
    let sigma = 1.0;
    for hidden in [&[][..], &["backlash"][..]] {
        for seed in 0..5u64 {
            // The sweep's truth and data for this case (benches/diagnose_study.rs, scale 1).
            let mut truth = sweep_case_truth(hidden, seed, sigma);
            truth.drift_um_per_s = [0.012, -0.008];
            let data = generate(&truth, Poses::Random(120), 5000 + seed);
            let r =
                diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
            let context = format!(
                "{hidden:?}, seed {seed}:\n{}\nlog: {:#?}",
                table(&r),
                r.selection_log
            );
            let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
            assert_eq!(named, hidden.to_vec(), "{context}");
            assert!(r.unexplained, "the drift is outside the library: {context}");
            assert!(
                r.nuisances.iter().any(|n| n.contains("drift")),
                "{:?}: {context}",
                r.nuisances
            );
        }
    }
}

/// A false positive of the sweep on sparse data (120 random poses, 1 µm): the
/// loops' stretch beside an instrument scale (seed 2 of the sweep at scale 1) was named
/// stretch, base_offset and scale in all three variants (none, cyclic, drift). The true set had been
/// fitted once from the stretch-only fit, where the LM stalled at 5568 µm² (from zero or from
/// stretch + link lengths it reaches 221 µm², the noise level), and the cache kept that stall:
/// the true model looked far worse than one with an absent base offset. Now a cached fit is
/// refitted when a later start is already better than it: exactly the hidden pair (the scale
/// possibly as its exact twin, a common link change reported confounded).
#[test]
fn stretch_and_scale_on_120_points_at_1_um_name_no_base_offset() {
    use host_sim::diagnose::forward_model::Problem;
    use host_sim::diagnose::library::N_PARAMS;
    use host_sim::diagnose::selection::Fitter;
    use host_sim::loop_closure::SixBarDesign;
    let sigma = 1.0;
    let hidden = ["link_stretch", "scale"];
    let truth = sweep_case_truth(&hidden, 2, sigma);
    let data = generate(&truth, Poses::Random(120), 5002);
    // The mechanism: the fit of a set from a poor start stalls; asked again from a better
    // start, the fitter returns (and keeps) the better fit.
    let problem = Problem::new(FiveBar::paper_nominal(), &SixBarDesign::paper(), &data);
    let effect = |n: &str| LIBRARY.iter().find(|e| e.name() == n).unwrap();
    let mut fitter = Fitter::new(&problem);
    let zero = [0.0; N_PARAMS];
    let stretch = fitter.fit(&[effect("link_stretch")], &zero).unwrap();
    let stalled = fitter
        .fit(&[effect("link_stretch"), effect("scale")], &stretch.p)
        .unwrap();
    let good = Fitter::new(&problem)
        .fit(&[effect("link_stretch"), effect("scale")], &zero)
        .unwrap();
    assert!(
        good.cost < 2.0 * 240.0 * sigma * sigma,
        "fit from zero {}",
        good.cost
    );
    let again = fitter
        .fit(&[effect("link_stretch"), effect("scale")], &good.p)
        .unwrap();
    assert!(
        again.cost <= good.cost + 1e-6,
        "stalled {} , from zero {}, asked again {}",
        stalled.cost,
        good.cost,
        again.cost
    );
    assert!(
        fitter
            .fit(&[effect("link_stretch"), effect("scale")], &zero)
            .unwrap()
            .cost
            <= good.cost + 1e-6
    );
    // The diagnosis: exactly the hidden pair.
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    let named = named_as_hidden(&r, &truth, &data, &hidden, &context);
    assert_eq!(
        named,
        vec!["link_stretch".to_string(), "scale".to_string()],
        "{context}"
    );
    assert!(!r.unexplained, "{context}");
}

/// The two false positives among single and paired effects of the sweep at half and 1.5×
/// magnitude on sparse data (`SWEEP_POSES=120 SWEEP_NOISE_UM=1 SWEEP_N=5
/// SWEEP_SCALES=0.5,1.5 SWEEP_MAX_HIDDEN=2`), both beside the drift:
/// * base offset + stretch at 0.5× (seed 1): the base offset was added, then a pair move
///   replaced it by link lengths and a gear ratio, which tie with the truth on BIC (+0.5) and
///   predict held-out points worse; the truth was one forward step away. Now a move that grows
///   the set must beat the best one-effect extension by the swap margin.
/// * backlash + scale at 1.5× (seed 4): a pair move carried a base offset in beside the scale
///   that lowers the BIC by 0.3 (an effect needs 10). Now every named effect must pass the add
///   test given the others at the end (`selection::prune_weak`).
///
/// And base offset + stretch at 1.5× without the drift (seed 3), which the stretch's
/// compliance-ratio allowance (`a_small_stretch_is_not_rejected_on_an_uncertain_compliance_ratio`)
/// must not break.
#[test]
fn paired_effects_beside_a_drift_at_other_magnitudes_name_exactly_the_pair() {
    let sigma = 1.0;
    // (hidden, magnitude, the sweep's data id, with the drift)
    let cases = [
        (["base_offset", "link_stretch"], 0.5, 1u64, true),
        (["backlash", "scale"], 1.5, 1004, true),
        // A stretch fit that runs its compliance ratio off (kc → 10⁶ ± 10⁹ %: c stretching
        // alone) is degenerate: the ratio's 3σ allowance must not admit it (an extra `frame`).
        (["base_offset", "link_stretch"], 1.5, 1003, false),
    ];
    for (hidden, scale, id, drift) in cases {
        // The sweep's truth and data for this case (benches/diagnose_study.rs).
        let mut truth = sweep_case_truth(&hidden, id, sigma).scaled(scale);
        if drift {
            truth.drift_um_per_s = [0.012, -0.008];
        }
        let data = generate(&truth, Poses::Random(120), 5000 + id);
        let r = diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
        let context = format!(
            "{hidden:?} × {scale}:\n{}\nlog: {:#?}",
            table(&r),
            r.selection_log
        );
        let named = named_as_hidden(&r, &truth, &data, &hidden, &context);
        let mut want: Vec<String> = hidden.iter().map(|s| s.to_string()).collect();
        want.sort();
        assert_eq!(named, want, "{context}");
        assert_eq!(
            r.unexplained, drift,
            "the drift is outside the library: {context}"
        );
    }
}

/// The same base offset + stretch at half magnitude (seed 1) without the drift: link lengths +
/// a gear ratio and the truth tie on BIC (+0.6), and the stepwise path reaches the former
/// (link lengths first by ΔBIC 10 over the stretch, then the ratio). No rule that follows the
/// BIC can pick the truth here; the report must say so: the two-for-two swap is declared
/// ambiguous (`ambiguous_pairs`, which one-for-one swaps cannot see), so neither named effect is
/// claimed over the hidden pair.
#[test]
fn a_two_for_two_tie_is_declared_ambiguous() {
    let sigma = 1.0;
    let hidden = ["base_offset", "link_stretch"];
    let truth = sweep_case_truth(&hidden, 1, sigma).scaled(0.5);
    let data = generate(&truth, Poses::Random(120), 5001);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    for e in named.iter().filter(|e| !hidden.contains(e)) {
        assert!(
            r.declares_alternative(e, &hidden),
            "{e} named, not hidden, not declared ambiguous with the hidden pair: {context}"
        );
    }
    if named.len() == 2 && named.iter().all(|e| !hidden.contains(e)) {
        let pair = r
            .ambiguous_pairs
            .iter()
            .find(|a| hidden.iter().all(|h| a.alternatives.iter().any(|c| c == h)))
            .expect("declared");
        assert!(
            pair.delta_bic.abs() < host_sim::diagnose::selection::AMBIGUOUS_MARGIN,
            "{context}"
        );
        assert!(table(&r).contains("ambiguous: "), "{context}");
    }
}

/// The sweep's last triple false positive at half magnitude (sparse data, seed 4 with
/// the cyclic error): base offset + stretch + frame was named base offset + frame + link
/// lengths. The stretch was fitted (ΔBIC −55 over the frame and base offset) but rejected as
/// implausible, c's compliance ratio at −73 % against a hard bound of −67 %, though it was
/// −73 ± 28 %: on a small stretch the ratio is poorly determined. Now the bound is on the
/// value less 3σ (as the backlash's sign): exactly the hidden three.
#[test]
fn a_small_stretch_is_not_rejected_on_an_uncertain_compliance_ratio() {
    let sigma = 1.0;
    let hidden = ["base_offset", "link_stretch", "frame"];
    let id = 4u64;
    let mut truth = sweep_case_truth(&hidden, id, sigma).scaled(0.5);
    truth.cyclic = Some(Cyclic {
        motor: (id % 2) as usize,
        cycles: [36.0, 50.0, 72.0][(id % 3) as usize],
        amplitude_urad: 35.0,
        phase_rad: 0.4 * id as f64,
    });
    let data = generate(&truth, Poses::Random(120), 5000 + id);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    let named = named_as_hidden(&r, &truth, &data, &hidden, &context);
    let mut want: Vec<String> = hidden.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(named, want, "{context}");
    assert!(
        r.unexplained,
        "the cyclic error is outside the library: {context}"
    );
}

#[test]
fn confounded_pairs_are_reported_with_a_separating_measurement() {
    // A common motor offset turns the mechanism about A0 like an instrument rotation.
    let truth = Truth {
        noise_um: NOISE_UM,
        encoder_offset_urad: [250.0, 250.0],
        ..Default::default()
    };
    let (r, _) = check(
        &truth,
        Poses::Grid5mm,
        1,
        &["encoder_offset"],
        false,
        "common offset",
    );
    assert!(
        r.confounded
            .contains(&vec!["encoder_offset".to_string(), "frame".to_string()]),
        "{:?}",
        r.confounded
    );
    let o = r
        .overlaps
        .iter()
        .find(|o| o.confounded && o.other == "frame")
        .expect("overlap listed");
    assert!(
        o.separate_by.contains("instrument rotated"),
        "{}",
        o.separate_by
    );
    // A common scale of all links scales every point about A0 like the instrument scale: the
    // workflow names one of them and reports the pair.
    let d = 150.0 * 300e-6 * 1e3; // 300 ppm of every link, µm
    let truth = Truth {
        noise_um: NOISE_UM,
        link_delta_um: [d; 4],
        ..Default::default()
    };
    let data = generate(&truth, Poses::Grid5mm, 2);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).unwrap();
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert!(
        named == ["scale"] || named == ["link_lengths"],
        "{}",
        table(&r)
    );
    assert!(
        r.confounded
            .contains(&vec!["link_lengths".to_string(), "scale".to_string()]),
        "{:?}",
        r.confounded
    );
    let o = r
        .overlaps
        .iter()
        .find(|o| o.confounded)
        .expect("overlap listed");
    assert!(
        o.separate_by.contains("reference length"),
        "{}",
        o.separate_by
    );
    // Distinct offsets: their common part (here (250 − 150)/√2 = 70.7 along (1, 1)/√2) is still
    // an instrument rotation, significant, so the pair is reported with that part.
    let truth = Truth {
        noise_um: NOISE_UM,
        encoder_offset_urad: [250.0, -150.0],
        ..Default::default()
    };
    let (r, _) = check(
        &truth,
        Poses::Grid5mm,
        3,
        &["encoder_offset"],
        false,
        "distinct offsets",
    );
    assert!(
        r.confounded
            .contains(&vec!["encoder_offset".to_string(), "frame".to_string()]),
        "{:?}",
        r.confounded
    );
    let o = r.overlaps.iter().find(|o| o.other == "frame").unwrap();
    assert!((o.shared_value - 70.7).abs() < 5.0, "{o:?}");
    // Opposite offsets have no common part: no rotation hides in them; only a partial overlap.
    let truth = Truth {
        noise_um: NOISE_UM,
        encoder_offset_urad: [200.0, -200.0],
        ..Default::default()
    };
    let (r, _) = check(
        &truth,
        Poses::Grid5mm,
        4,
        &["encoder_offset"],
        false,
        "opposite offsets",
    );
    assert!(r.confounded.is_empty(), "{:?}", r.confounded);
    assert!(r
        .overlaps
        .iter()
        .any(|o| o.other == "frame" && !o.confounded && o.principal_cos > 0.999999));
}

#[test]
fn noise_is_estimated_from_repeats_and_backlash_needs_directions() {
    // Two runs over the same poses: σ from the repeats, no --noise-um.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let truth = truth_with(&["base_offset"], &mut rng);
    let clean = generate(
        &Truth {
            noise_um: 0.0,
            ..truth.clone()
        },
        Poses::Random(250),
        4,
    );
    let normal = rand_distr::Normal::new(0.0, NOISE_UM * 1e-3).unwrap();
    let mut data = Vec::new();
    for run in 0..2u32 {
        for m in &clean {
            let mut m = m.clone();
            m.run = Some(run);
            for v in m.measured_mm.iter_mut() {
                *v += rand_distr::Distribution::sample(&normal, &mut rng);
            }
            data.push(m);
        }
    }
    let r = diagnose(&data, &FiveBar::paper_nominal(), None).unwrap();
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert_eq!(named, ["base_offset"], "{}", table(&r));
    assert!(
        !r.unexplained && r.chi2_per_dof.is_some_and(|c| c < 1.21),
        "{}",
        table(&r)
    );
    let s = r.noise_um.expect("estimated");
    assert!((s - NOISE_UM).abs() < 0.2 * NOISE_UM, "σ from repeats {s}");
    assert!(r.noise_source.contains("repeated"));
    // Without dir columns backlash is skipped with a note, not an error.
    for m in data.iter_mut() {
        m.dir = None;
    }
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).unwrap();
    assert!(
        r.notes.iter().any(|n| n.contains("backlash skipped")),
        "{:?}",
        r.notes
    );
}

#[test]
fn the_current_model_is_the_starting_point() {
    // The model already has the right link lengths: only what is still missing is named.
    let truth = Truth {
        noise_um: NOISE_UM,
        link_delta_um: [60.0, -40.0, 30.0, -50.0],
        backlash_urad: [150.0, 90.0],
        ..Default::default()
    };
    let data = generate(&truth, Poses::Grid5mm, 8);
    let mut model = FiveBar::<f64>::paper_nominal();
    model.a_mm += 0.060;
    model.b_mm -= 0.040;
    model.c_mm += 0.030;
    model.d_mm -= 0.050;
    let r = diagnose(&data, &model, Some(NOISE_UM)).unwrap();
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert_eq!(named, ["backlash"], "{}", table(&r));
    let b = &r.steps[0].params["beta1_urad"];
    assert!((b.value - 150.0).abs() < 4.0 * b.std_dev + 1.0, "{b:?}");
}

#[test]
fn without_a_noise_figure_the_structure_decides() {
    // No --noise-um, no repeats: scores compare against what is left; unexplained needs structure.
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let truth = truth_with(&["gear_ratio"], &mut rng);
    let data = generate(&truth, Poses::Grid5mm, 21);
    let r = diagnose(&data, &FiveBar::paper_nominal(), None).unwrap();
    assert_eq!(
        named_as_hidden(&r, &truth, &data, &["gear_ratio"], "no noise figure"),
        ["gear_ratio"],
        "{}",
        table(&r)
    );
    assert!(!r.unexplained && r.noise_um.is_none() && r.chi2_per_dof.is_none());
    let truth = Truth {
        noise_um: NOISE_UM,
        cyclic: Some(Cyclic {
            motor: 1,
            cycles: 45.0,
            amplitude_urad: 40.0,
            phase_rad: 0.0,
        }),
        ..Default::default()
    };
    let r = diagnose(
        &generate(&truth, Poses::Grid5mm, 22),
        &FiveBar::paper_nominal(),
        None,
    )
    .unwrap();
    assert!(r.steps.is_empty() && r.unexplained, "{}", table(&r));
    assert!(
        r.unexplained_description.contains("45 cycles/rev"),
        "{}",
        r.unexplained_description
    );
}

#[test]
fn paper_table_1_runs_and_says_what_nine_points_cannot_tell() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/table1.csv");
    let data = host_sim::io::measurement_csv::read_measurements(&path).unwrap();
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(20.0)).unwrap();
    println!("{}", table(&r));
    assert_eq!(r.points, 9);
    assert!(
        r.unexplained,
        "1.5 mm errors at 20 µm noise are not explained by 9 points"
    );
    assert!(r.unexplained_description.contains("Too few points"));
    assert!(r.notes.iter().any(|n| n.contains("backlash skipped")));
}

#[test]
fn command_writes_report_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let truth = truth_with(&["encoder_offset", "backlash"], &mut rng);
    let data = generate(&truth, Poses::Random(200), 3);
    let csv = dir.path().join("m.csv");
    std::fs::write(&csv, format_measurements(&data)).unwrap();
    let out = dir.path().join("report.json");
    let plots = dir.path().join("plots");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["diagnose", "--data"])
        .arg(&csv)
        .args(["--noise-um", "2"])
        .arg("--out")
        .arg(&out)
        .arg("--plots")
        .arg(&plots)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let stdout = String::from_utf8_lossy(&status.stdout);
    assert!(
        stdout.contains("rms_bef_um") && stdout.contains("backlash"),
        "{stdout}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for key in ["steps", "confounded", "unexplained", "final_rms_um"] {
        assert!(v.get(key).is_some(), "report lacks {key}");
    }
    for step in v["steps"].as_array().unwrap() {
        for key in [
            "effect",
            "params",
            "rms_before_um",
            "rms_after_um",
            "max_before_um",
            "max_after_um",
        ] {
            assert!(step.get(key).is_some(), "step lacks {key}");
        }
    }
    assert!(plots.join("residual_start.png").exists());
    assert!(plots
        .join("residual_step1_")
        .parent()
        .unwrap()
        .read_dir()
        .unwrap()
        .any(|e| e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .starts_with("residual_step2_")));
    // A bad noise figure is refused, naming the option.
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["diagnose", "--data"])
        .arg(&csv)
        .args(["--noise-um=-1", "--out"])
        .arg(dir.path().join("x.json"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--noise-um"));
}

/// The final check at work (`diagnose::selection`, `prune_weak`): on these data (a scale and a
/// gear ratio at half the sweep's magnitude beside a drift, 120 random poses, 1 µm) a move of
/// the search carries an encoder offset in beside the effect it is about, which lowers the BIC
/// by only 4 given the others (an effect needs 10). The final check must drop it, say so in the
/// selection log, and leave it out of the named effects.
#[test]
fn the_final_check_drops_what_a_move_carried_in_without_support() {
    let sigma = 1.0;
    let hidden = ["scale", "gear_ratio"];
    let mut truth = sweep_case_truth(&hidden, 1004, sigma).scaled(0.5);
    truth.drift_um_per_s = [0.012, -0.008];
    let data = generate(&truth, Poses::Random(120), 5000 + 1004);
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(sigma)).expect("diagnosis runs");
    let context = format!("{}\nlog: {:#?}", table(&r), r.selection_log);
    assert!(
        r.selection_log
            .iter()
            .any(|l| l.starts_with("drop encoder_offset")),
        "the final check dropped nothing: {context}"
    );
    assert!(
        r.steps.iter().all(|s| s.effect != "encoder_offset"),
        "a member without support is named: {context}"
    );
}
