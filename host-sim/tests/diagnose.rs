//! Tests of `host-sim diagnose` on data whose truth is hidden from the workflow.
//!
//! The data come from `host_sim::diagnose::synth` (a five-bar truth with effects generated, where
//! physics allows, in a different form from the library; see its module doc): every library
//! effect, including those the plant has no switch for. The same workflow on the six-bar plant
//! through `host-sim measure` is tested in `tests/diagnose_plant.rs`; the studies (robustness
//! sweep, Table I's power, the example file) are `benches/diagnose_study.rs`.
//!
//! Cost: each diagnosis is 0.1–0.5 s in the dev profile; the whole file runs in well under a
//! minute on one core.

use host_sim::diagnose::report::{table, Report};
use host_sim::diagnose::synth::{generate, Cyclic, Poses, Truth};
use host_sim::diagnose::{effects::LIBRARY, DiagnoseOptions};
use host_sim::effect::PhysicalEffect;
use host_sim::io::measurement_csv::{format_measurements, Measurement};
use kinematics_core::FiveBar;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const NOISE_UM: f64 = 2.0;

/// Diagnoses `data` against the nominal model and checks that exactly `expected` effects are
/// named (any order), that the residual is at the noise level (unless `expect_unexplained`),
/// and that `unexplained` is what it should be. Returns the report for further checks.
fn check(
    data: Vec<Measurement>,
    noise_um: Option<f64>,
    expected: &[&str],
    expect_unexplained: bool,
    what: &str,
) -> Report {
    let r = diagnose(&data, &FiveBar::paper_nominal(), noise_um).expect("diagnosis runs");
    let mut named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    named.sort();
    let mut want = expected.to_vec();
    want.sort();
    let context = format!("{what}:\n{}\nlog: {:#?}", table(&r), r.selection_log);
    assert_eq!(named, want, "wrong effects named for {context}");
    assert_eq!(r.unexplained, expect_unexplained, "unexplained flag for {context}");
    if !expect_unexplained {
        let c = r.chi2_per_dof.expect("noise known");
        assert!(c < 1.21, "residual not at the noise level (χ²/dof {c}) for {context}");
        // Radial RMS of 2-D Gaussian noise with σ per axis is σ·√2.
        assert!(r.final_rms_um < 1.1 * NOISE_UM * 2f64.sqrt(), "final RMS {} for {context}", r.final_rms_um);
    }
    for s in &r.steps {
        assert!(s.rms_after_um <= s.rms_before_um + 1e-9, "step {} made it worse: {context}", s.effect);
    }
    r
}

/// The diagnosis of `data` against `base` with noise σ `noise_um`.
fn diagnose(data: &[Measurement], base: &FiveBar<f64>, noise_um: Option<f64>) -> Result<Report, host_sim::diagnose::DiagnoseError> {
    host_sim::diagnose::diagnose(data, &DiagnoseOptions { base: *base, noise_um })
}

fn truth_with(effects: &[&str], rng: &mut ChaCha8Rng) -> Truth {
    let mut t = Truth { noise_um: NOISE_UM, ..Default::default() };
    for e in effects {
        t.add_random(PhysicalEffect::from_name(e).expect("an effect name"), rng).expect("a library effect");
    }
    t
}

/// On this machine (A0 = B0, a rhombus), a shape-dependent distal stretch is partly exactly
/// what constant link lengths and encoder offsets do (see effects.rs), so those two may be named
/// alongside it: the library's stretch keeps only the part they cannot reproduce.
fn expected_for(effect: &str, named: &[&str]) -> Vec<&'static str> {
    let lib = |n: &str| LIBRARY.iter().find(|e| e.name() == n).map(|e| e.name()).expect("library name");
    let mut want = vec![lib(effect)];
    if effect == "link_stretch" {
        for extra in ["link_lengths", "encoder_offset"] {
            if named.contains(&extra) {
                want.push(lib(extra));
            }
        }
    }
    want
}

#[test]
fn each_effect_alone_is_named_exactly_and_the_gap_closes() {
    for (k, effect) in LIBRARY.iter().enumerate() {
        for seed in 0..3u64 {
            let mut rng = ChaCha8Rng::seed_from_u64(100 * k as u64 + seed);
            let truth = truth_with(&[effect.name()], &mut rng);
            let poses = if seed == 1 { Poses::Random(400) } else { Poses::Grid5mm };
            let data = generate(&truth, poses, 1000 + seed);
            let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).expect("diagnosis runs");
            let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
            let want = expected_for(effect.name(), &named);
            let r = check(
                data,
                Some(NOISE_UM),
                &want,
                false,
                &format!("{} alone, seed {seed}, truth {truth:?}", effect.name()),
            );
            assert!(r.initial_rms_um > 3.0 * r.final_rms_um, "{}: the gap did not shrink", effect.name());
            if effect.name() == "scale" {
                assert!(
                    r.confounded.contains(&vec!["link_lengths".to_string(), "scale".to_string()]),
                    "{:?}",
                    r.confounded
                );
            }
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
        let data = generate(&truth, Poses::Grid5mm, 77 + k as u64);
        check(data, Some(NOISE_UM), pair, false, &format!("{pair:?}, truth {truth:?}"));
    }
}

#[test]
fn noise_only_names_nothing() {
    for seed in 0..6u64 {
        let truth = Truth { noise_um: NOISE_UM, ..Default::default() };
        let poses = if seed % 2 == 0 { Poses::Grid5mm } else { Poses::Random(300) };
        let r = check(generate(&truth, poses, seed), Some(NOISE_UM), &[], false, &format!("noise only, seed {seed}"));
        assert!(r.confounded.is_empty());
    }
}

#[test]
fn hidden_gear_tooth_error_is_unexplained_and_described() {
    for (seed, (motor, cycles, amp)) in [(0usize, 50.0, 40.0), (1, 36.0, 30.0), (0, 90.0, 40.0)].into_iter().enumerate()
    {
        let truth = Truth {
            noise_um: NOISE_UM,
            cyclic: Some(Cyclic { motor, cycles, amplitude_urad: amp, phase_rad: 0.7 * seed as f64 }),
            ..Default::default()
        };
        let r = check(
            generate(&truth, Poses::Grid5mm, 300 + seed as u64),
            Some(NOISE_UM),
            &[],
            true,
            &format!("cyclic {truth:?}"),
        );
        let kind = format!("periodic_theta{}", motor + 1);
        let f = r.final_structure.iter().find(|f| f.kind == kind).expect("periodogram ran");
        assert!(f.significant, "{f:?}");
        assert_eq!(f.cycles_per_rev, Some(cycles), "{f:?}");
        assert!(r.unexplained_description.contains(&format!("{} cycles/rev", cycles)), "{}", r.unexplained_description);
        // Never named: no library effect claims it.
        assert!(r.steps.is_empty());
    }
    // Together with a library effect: the effect is named, the cyclic error is left unexplained.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut truth = truth_with(&["backlash"], &mut rng);
    truth.cyclic = Some(Cyclic { motor: 1, cycles: 60.0, amplitude_urad: 40.0, phase_rad: 0.1 });
    let r = check(generate(&truth, Poses::Grid5mm, 9), Some(NOISE_UM), &["backlash"], true, "backlash + cyclic");
    assert!(r
        .final_structure
        .iter()
        .any(|f| f.kind == "periodic_theta2" && f.significant && f.cycles_per_rev == Some(60.0)));
}

#[test]
fn hidden_drift_is_unexplained_and_described() {
    // 6 nm/s over the 1300 s of a grid run: 7.8 µm at the end, in x. Its mean over the run is a
    // constant instrument offset, which `frame` takes (rightly: the data cannot tell them apart).
    let truth = Truth { noise_um: NOISE_UM, drift_um_per_s: [0.006, 0.0], ..Default::default() };
    let r = check(generate(&truth, Poses::Grid5mm, 31), Some(NOISE_UM), &["frame"], true, "drift");
    let f = r.final_structure.iter().find(|f| f.kind == "drift_time").expect("time tested");
    assert!(f.significant, "{f:?}");
    assert!(r.unexplained_description.contains("drift_time"), "{}", r.unexplained_description);
}

#[test]
fn confounded_pairs_are_reported_with_a_separating_measurement() {
    // A common motor offset turns the mechanism about A0 like an instrument rotation.
    let truth = Truth { noise_um: NOISE_UM, encoder_offset_urad: [250.0, 250.0], ..Default::default() };
    let r = check(generate(&truth, Poses::Grid5mm, 1), Some(NOISE_UM), &["encoder_offset"], false, "common offset");
    assert!(r.confounded.contains(&vec!["encoder_offset".to_string(), "frame".to_string()]), "{:?}", r.confounded);
    let o = r.overlaps.iter().find(|o| o.confounded && o.other == "frame").expect("overlap listed");
    assert!(o.separate_by.contains("instrument rotated"), "{}", o.separate_by);
    // A common scale of all links scales every point about A0 like the instrument scale: the
    // workflow names the simpler one and reports the pair.
    let d = 150.0 * 300e-6 * 1e3; // 300 ppm of every link, µm
    let truth = Truth { noise_um: NOISE_UM, link_delta_um: [d; 4], ..Default::default() };
    let r = check(generate(&truth, Poses::Grid5mm, 2), Some(NOISE_UM), &["scale"], false, "common link scale");
    assert!(r.confounded.contains(&vec!["link_lengths".to_string(), "scale".to_string()]), "{:?}", r.confounded);
    let o = r.overlaps.iter().find(|o| o.confounded).expect("overlap listed");
    assert!(o.separate_by.contains("reference length"), "{}", o.separate_by);
    // Distinct offsets: their common part (here (250 − 150)/√2 = 70.7 along (1, 1)/√2) is still
    // an instrument rotation, significant, so the pair is reported with that part.
    let truth = Truth { noise_um: NOISE_UM, encoder_offset_urad: [250.0, -150.0], ..Default::default() };
    let r = check(generate(&truth, Poses::Grid5mm, 3), Some(NOISE_UM), &["encoder_offset"], false, "distinct offsets");
    assert!(r.confounded.contains(&vec!["encoder_offset".to_string(), "frame".to_string()]), "{:?}", r.confounded);
    let o = r.overlaps.iter().find(|o| o.other == "frame").unwrap();
    assert!((o.shared_value - 70.7).abs() < 5.0, "{o:?}");
    // Opposite offsets have no common part: no rotation hides in them; only a partial overlap.
    let truth = Truth { noise_um: NOISE_UM, encoder_offset_urad: [200.0, -200.0], ..Default::default() };
    let r = check(generate(&truth, Poses::Grid5mm, 4), Some(NOISE_UM), &["encoder_offset"], false, "opposite offsets");
    assert!(r.confounded.is_empty(), "{:?}", r.confounded);
    assert!(r.overlaps.iter().any(|o| o.other == "frame" && !o.confounded && o.principal_cos > 0.999999));
}

#[test]
fn noise_is_estimated_from_repeats_and_backlash_needs_directions() {
    // Two runs over the same poses: σ from the repeats, no --noise-um.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let truth = truth_with(&["base_offset"], &mut rng);
    let clean = generate(&Truth { noise_um: 0.0, ..truth.clone() }, Poses::Random(250), 4);
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
    let r = check(data.clone(), None, &["base_offset"], false, "noise from repeats");
    let s = r.noise_um.expect("estimated");
    assert!((s - NOISE_UM).abs() < 0.2 * NOISE_UM, "σ from repeats {s}");
    assert!(r.noise_source.contains("repeated"));
    // Without dir columns backlash is skipped with a note, not an error.
    for m in data.iter_mut() {
        m.dir = None;
    }
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(NOISE_UM)).unwrap();
    assert!(r.notes.iter().any(|n| n.contains("backlash skipped")), "{:?}", r.notes);
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
    let r = diagnose(&generate(&truth, Poses::Grid5mm, 21), &FiveBar::paper_nominal(), None).unwrap();
    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    assert_eq!(named, ["gear_ratio"], "{}", table(&r));
    assert!(!r.unexplained && r.noise_um.is_none() && r.chi2_per_dof.is_none());
    let truth = Truth {
        noise_um: NOISE_UM,
        cyclic: Some(Cyclic { motor: 1, cycles: 45.0, amplitude_urad: 40.0, phase_rad: 0.0 }),
        ..Default::default()
    };
    let r = diagnose(&generate(&truth, Poses::Grid5mm, 22), &FiveBar::paper_nominal(), None).unwrap();
    assert!(r.steps.is_empty() && r.unexplained, "{}", table(&r));
    assert!(r.unexplained_description.contains("45 cycles/rev"), "{}", r.unexplained_description);
}

#[test]
fn paper_table_1_runs_and_says_what_nine_points_cannot_tell() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/table1.csv");
    let data = host_sim::io::measurement_csv::read_measurements(&path).unwrap();
    let r = diagnose(&data, &FiveBar::paper_nominal(), Some(20.0)).unwrap();
    println!("{}", table(&r));
    assert_eq!(r.points, 9);
    assert!(r.unexplained, "1.5 mm errors at 20 µm noise are not explained by 9 points");
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
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let stdout = String::from_utf8_lossy(&status.stdout);
    assert!(stdout.contains("rms_bef_um") && stdout.contains("backlash"), "{stdout}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for key in ["steps", "confounded", "unexplained", "final_rms_um"] {
        assert!(v.get(key).is_some(), "report lacks {key}");
    }
    for step in v["steps"].as_array().unwrap() {
        for key in ["effect", "params", "rms_before_um", "rms_after_um", "max_before_um", "max_after_um"] {
            assert!(step.get(key).is_some(), "step lacks {key}");
        }
    }
    assert!(plots.join("residual_start.png").exists());
    assert!(plots.join("residual_step1_").parent().unwrap().read_dir().unwrap().any(|e| e
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
