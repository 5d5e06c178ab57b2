//! `host-sim diagnose` on data from the simulated machine (docs/design/diagnosis.md): the plant of `src/plant/`
//! measured by the `host-sim measure` protocols (its library function [`measure`], and once the
//! binary itself through a CSV file), with one plant effect switched on at a time, two at once,
//! none (noise only), and a gear-tooth cyclic error that is in no library. The diagnosis sees
//! only the measurements and the noise figure; the truth stays here.
//!
//! What the plant's effects should come out as:
//! * encoder offsets → `encoder_offset` (their common part is reported confounded with `frame`);
//! * backlash (random approach directions) → `backlash`;
//! * instrument frame → `frame` (its rotation is reported confounded with `encoder_offset`);
//! * instrument scale → `scale` (at some seeds `link_lengths`, a common change of all four:
//!   exactly the same thing), the pair reported confounded;
//! * six-bar link and pin errors → the hidden robot's own parameters (`link_lengths`,
//!   `base_offset`, `frame`, ...) take the five-bar part, the six-bar's own effects
//!   (`parallelogram_mismatch`, `link_stretch`, from its linearised loop closure) the rest, down
//!   to the noise. The same plant solved as its effective five-bar names no six-bar effect;
//! * clearances and encoder quantization of the `paper` plant: below a 1 µm noise, nothing named;
//! * gear cyclic error → nothing named, `unexplained`, its period found.
//!
//! Noise: 1 µm per axis (the `measure --noise-um` override). Cost: ~30 diagnoses of 150–651
//! points, a few seconds in the dev profile.

use host_sim::calib::measure::{measure, MeasureOptions};
use host_sim::calib::protocol::Protocol;
use host_sim::diagnose::report::{table, Report};
use host_sim::diagnose::{diagnose, DiagnoseOptions};
use host_sim::effect::PhysicalEffect;
use host_sim::io::measurement_csv::{read_measurements, Measurement};
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{PlantConfig, PlantModel};
use kinematics_core::{Calibration, FiveBar};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const NOISE_UM: f64 = 1.0;

/// `host-sim measure --protocol P --seed S --noise-um 1` with the nominal hidden robot.
fn measured(plant: &PlantConfig, protocol: Protocol, seed: u64) -> Vec<Measurement> {
    let cal = Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    };
    measure(
        plant,
        &cal,
        &MeasureOptions {
            protocol,
            seed,
            noise_um: Some(NOISE_UM),
            spec: MachineSpec::paper(),
        },
    )
    .expect("measure runs")
}

fn diagnosed(data: &[Measurement]) -> Report {
    diagnose(
        data,
        &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(NOISE_UM)),
    )
    .expect("diagnosis runs")
}

fn named(r: &Report) -> Vec<&str> {
    let mut n: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
    n.sort();
    n
}

fn pair(a: &str, b: &str) -> Vec<String> {
    vec![a.to_string(), b.to_string()]
}

/// Exactly `expected` named, residual at the noise level, every step shrinks the gap.
fn check_explained(r: &Report, expected: &[&str], what: &str) {
    let context = format!("{what}:\n{}", table(r));
    let mut want = expected.to_vec();
    want.sort();
    assert_eq!(named(r), want, "wrong effects named for {context}");
    assert!(!r.unexplained, "unexplained for {context}");
    let c = r.chi2_per_dof.expect("noise given");
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
    for s in &r.steps {
        assert!(
            s.rms_after_um <= s.rms_before_um + 1e-9,
            "step {} made it worse: {context}",
            s.effect
        );
    }
    if !expected.is_empty() {
        assert!(
            r.initial_rms_um > 5.0 * r.final_rms_um,
            "the gap did not shrink: {context}"
        );
    }
}

/// A magnitude in `lo..hi` with a random sign.
fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = rng.random_range(lo..hi);
    if rng.random_bool(0.5) {
        v
    } else {
        -v
    }
}

fn with_encoder_offsets(p: &mut PlantConfig, rng: &mut ChaCha8Rng) {
    p.drive_1.encoder_offset_deg = signed(rng, 100.0, 400.0) * 1e-6f64.to_degrees();
    p.drive_2.encoder_offset_deg = signed(rng, 100.0, 400.0) * 1e-6f64.to_degrees();
}

fn with_backlash(p: &mut PlantConfig, rng: &mut ChaCha8Rng) {
    p.drive_1.backlash_urad = rng.random_range(60.0..200.0);
    p.drive_2.backlash_urad = rng.random_range(60.0..200.0);
}

/// Only pairs the physics makes confounded are allowed in `confounded`.
fn only_confounded(r: &Report, allowed: &[Vec<String>], what: &str) {
    for c in &r.confounded {
        assert!(
            allowed.contains(c),
            "{what}: unexpected confounded pair {c:?}\n{}",
            table(r)
        );
    }
}

#[test]
fn encoder_offsets_are_named_and_their_common_part_is_confounded_with_a_frame_rotation() {
    let mut cases = Vec::new();
    for seed in 0..2u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(10 + seed);
        let mut p = PlantConfig::ideal();
        with_encoder_offsets(&mut p, &mut rng);
        cases.push((p, seed));
    }
    // The paper plant's own offsets (−0.013°, +0.027°).
    cases.push((
        PlantConfig::paper()
            .with_only(PhysicalEffect::EncoderOffset)
            .unwrap(),
        2,
    ));
    for (p, seed) in cases {
        let protocol = if seed == 1 {
            Protocol::Grid
        } else {
            Protocol::Random(150)
        };
        let r = diagnosed(&measured(&p, protocol, seed));
        let what = format!(
            "encoder offsets {:.1}, {:.1} µrad, {protocol:?}",
            p.drive_1.encoder_offset_deg.to_radians() * 1e6,
            p.drive_2.encoder_offset_deg.to_radians() * 1e6
        );
        check_explained(&r, &["encoder_offset"], &what);
        only_confounded(&r, &[pair("encoder_offset", "frame")], &what);
        // The fitted offsets are the plant's (geometric = encoder + offset).
        for (k, d) in [("dtheta1_urad", &p.drive_1), ("dtheta2_urad", &p.drive_2)] {
            let f = &r.steps[0].params[k];
            let truth = d.encoder_offset_deg.to_radians() * 1e6;
            assert!(
                (f.value - truth).abs() < 5.0 * f.std_dev + 2.0,
                "{what}: {k} {f:?} vs {truth}"
            );
        }
        // A significant common part is an instrument rotation as much as a common offset.
        let common = (p.drive_1.encoder_offset_deg + p.drive_2.encoder_offset_deg).to_radians()
            * 1e6
            / 2f64.sqrt();
        if common.abs() > 30.0 {
            assert!(
                r.confounded.contains(&pair("encoder_offset", "frame")),
                "{what}: {:?}",
                r.confounded
            );
        }
    }
}

#[test]
fn backlash_with_random_approach_directions_is_named() {
    for seed in 0..2u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(20 + seed);
        let mut p = PlantConfig::ideal();
        with_backlash(&mut p, &mut rng);
        let r = diagnosed(&measured(&p, Protocol::Random(150), seed));
        let what = format!(
            "backlash {:.0}, {:.0} µrad",
            p.drive_1.backlash_urad, p.drive_2.backlash_urad
        );
        check_explained(&r, &["backlash"], &what);
        assert!(r.confounded.is_empty(), "{what}: {:?}", r.confounded);
        for (k, d) in [("beta1_urad", &p.drive_1), ("beta2_urad", &p.drive_2)] {
            let f = &r.steps[0].params[k];
            assert!(
                (f.value - d.backlash_urad).abs() < 5.0 * f.std_dev + 2.0,
                "{what}: {k} {f:?}"
            );
        }
    }
}

#[test]
fn instrument_frame_and_scale_are_named() {
    for seed in 0..2u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(30 + seed);
        let mut p = PlantConfig::ideal();
        let (r_um, a) = (
            rng.random_range(30.0..120.0),
            rng.random_range(0.0..std::f64::consts::TAU),
        );
        p.instrument.frame_offset_mm = [r_um * 1e-3 * a.cos(), r_um * 1e-3 * a.sin()];
        p.instrument.frame_rotation_deg = signed(&mut rng, 100.0, 400.0) * 1e-6f64.to_degrees();
        let protocol = if seed == 1 {
            Protocol::Grid
        } else {
            Protocol::Random(150)
        };
        let r = diagnosed(&measured(&p, protocol, seed));
        let what = format!(
            "frame {:?} mm, {:.4}°",
            p.instrument.frame_offset_mm, p.instrument.frame_rotation_deg
        );
        check_explained(&r, &["frame"], &what);
        // A frame rotation about A0 is exactly a common encoder offset.
        assert_eq!(
            r.confounded,
            vec![pair("encoder_offset", "frame")],
            "{what}"
        );
        let rot = &r.steps[0].params["rot_urad"];
        let truth = p.instrument.frame_rotation_deg.to_radians() * 1e6;
        assert!(
            (rot.value - truth).abs() < 5.0 * rot.std_dev + 2.0,
            "{what}: {rot:?} vs {truth}"
        );
    }
    // The paper plant's instrument: zeroed at Table I's point 1 (an offset of 3.2 mm).
    let p = PlantConfig::paper()
        .with_only(PhysicalEffect::Frame)
        .unwrap();
    let r = diagnosed(&measured(&p, Protocol::Random(150), 3));
    check_explained(&r, &["frame"], "paper instrument frame");
    for (seed, ppm) in [(4u64, 300.0), (5, -180.0)] {
        let mut p = PlantConfig::ideal();
        p.instrument.scale_error_ppm = ppm;
        let r = diagnosed(&measured(&p, Protocol::Random(150), seed));
        let what = format!("scale {ppm} ppm");
        // A common scale of all links is exactly the same thing: either name may come out (on
        // the synthetic data it is always `scale`; on the plant's readings, at some seeds, the
        // four link changes fit a hair better), but the pair is always reported, not decided.
        let is_scale = named(&r) == ["scale"];
        check_explained(
            &r,
            if is_scale {
                &["scale"]
            } else {
                &["link_lengths"]
            },
            &what,
        );
        assert_eq!(r.confounded, vec![pair("link_lengths", "scale")], "{what}");
        if is_scale {
            let s = &r.steps[0].params["scale_ppm"];
            assert!(
                (s.value - ppm).abs() < 5.0 * s.std_dev + 1.0,
                "{what}: {s:?}"
            );
        } else {
            // Every link changed by the scale times its 150 mm.
            for k in ["da_um", "db_um", "dc_um", "dd_um"] {
                let l = &r.steps[0].params[k];
                assert!(
                    (l.value - 0.150 * ppm).abs() < 5.0 * l.std_dev + 2.0,
                    "{what}: {k} {l:?}"
                );
            }
        }
    }
}

#[test]
fn noise_and_sub_noise_plant_effects_name_nothing() {
    let cases = [
        (
            "noise only",
            PlantConfig::ideal(),
            Protocol::Random(150),
            40u64,
        ),
        ("noise only, grid", PlantConfig::ideal(), Protocol::Grid, 41),
        (
            "noise only, other seed",
            PlantConfig::ideal(),
            Protocol::Random(150),
            42,
        ),
        // 3 µm pin and 2 µm bar-end clearance without link errors: no stress takes them up.
        (
            "paper clearances",
            PlantConfig::paper()
                .with_only(PhysicalEffect::Clearance)
                .unwrap(),
            Protocol::Random(150),
            43,
        ),
        // 2^20 counts per motor rev × 10: 0.6 µrad steps.
        (
            "paper encoder quantization",
            PlantConfig::paper()
                .with_only(PhysicalEffect::EncoderQuantization)
                .unwrap(),
            Protocol::Random(150),
            44,
        ),
    ];
    for (what, p, protocol, seed) in cases {
        let r = diagnosed(&measured(&p, protocol, seed));
        check_explained(&r, &[], what);
        assert!(r.confounded.is_empty(), "{what}: {:?}", r.confounded);
    }
}

#[test]
fn two_plant_effects_at_once_are_both_named() {
    for seed in 0..2u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(50 + seed);
        let mut p = PlantConfig::ideal();
        with_encoder_offsets(&mut p, &mut rng);
        with_backlash(&mut p, &mut rng);
        let r = diagnosed(&measured(&p, Protocol::Random(150), seed));
        let what = format!("encoder offsets + backlash, seed {seed}");
        check_explained(&r, &["encoder_offset", "backlash"], &what);
        only_confounded(&r, &[pair("encoder_offset", "frame")], &what);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(52);
    let mut p = PlantConfig::ideal();
    with_backlash(&mut p, &mut rng);
    p.instrument.scale_error_ppm = 250.0;
    let r = diagnosed(&measured(&p, Protocol::Random(150), 2));
    check_explained(&r, &["scale", "backlash"], "scale + backlash");
    only_confounded(&r, &[pair("link_lengths", "scale")], "scale + backlash");
}

/// Six-bar link and pin errors: the hidden robot's own parameters take the five-bar
/// part, the six-bar's own effects (`parallelogram_mismatch`, `link_stretch`, derived from its
/// loop closure) the rest, and the residual falls to the instrument noise. Never a direction
/// effect, nothing left unexplained.
#[test]
fn six_bar_link_errors_name_the_six_bars_own_effects_down_to_the_noise() {
    let hidden_robot = [
        "link_lengths",
        "base_offset",
        "frame",
        "encoder_offset",
        "gear_ratio",
        "scale",
    ];
    let six_bar = ["link_stretch", "parallelogram_mismatch"];
    let cases = [
        (
            "paper link errors",
            PlantConfig::paper()
                .with_only(PhysicalEffect::LinkGeometry)
                .unwrap(),
            60u64,
        ),
        (
            "random link errors σ 50 µm",
            PlantConfig::ideal().with_random_errors(11, 0.05, 0.0),
            61,
        ),
        (
            "random link errors σ 50 µm",
            PlantConfig::ideal().with_random_errors(12, 0.05, 0.0),
            62,
        ),
    ];
    for (k, (what, p, seed)) in cases.into_iter().enumerate() {
        let data = measured(&p, Protocol::Random(200), seed);
        let r = diagnosed(&data);
        let context = format!("{what} (plant seed {seed}):\n{}", table(&r));
        let n = named(&r);
        assert!(
            n.iter()
                .all(|e| hidden_robot.contains(e) || six_bar.contains(e)),
            "{context}"
        );
        assert!(
            n.iter().any(|e| six_bar.contains(e)),
            "the six-bar's own effects not named: {context}"
        );
        if k == 0 {
            // The paper's millimetre length errors, and its parallelogram mismatch.
            assert!(
                n.contains(&"link_lengths") && n.contains(&"parallelogram_mismatch"),
                "{context}"
            );
        }
        // Down to the noise: 1 µm per axis, radial RMS √2 µm.
        assert!(
            !r.unexplained && r.chi2_per_dof.unwrap() < 1.21,
            "{context}"
        );
        assert!(r.final_rms_um < 1.1 * NOISE_UM * 2f64.sqrt(), "{context}");
        for s in &r.steps {
            assert!(
                s.rms_after_um <= s.rms_before_um + 1e-9,
                "step {} made it worse: {context}",
                s.effect
            );
        }

        // The same plant solved as its effective five-bar (same arms, no parallelograms): the
        // hidden robot's parameters alone, never the six-bar's effects.
        let mut five = p.clone();
        five.sixbar.model = PlantModel::Fivebar;
        let r5 = diagnosed(&measured(&five, Protocol::Random(200), seed));
        let context5 = format!("{what} as a five-bar:\n{}", table(&r5));
        assert!(
            !r5.unexplained && r5.chi2_per_dof.unwrap() < 1.21,
            "{context5}"
        );
        assert!(
            named(&r5).iter().all(|e| hidden_robot.contains(e)),
            "{context5}"
        );
    }
}

#[test]
fn gear_tooth_cyclic_error_is_unexplained_with_its_period() {
    // (motor, cycles per motor rev, amplitude µrad, protocol); gear ratio 10: 50 and 90 cycles
    // per revolution of the link angle.
    for (seed, (motor, per_motor_rev, amp, protocol)) in [
        (0usize, 5.0, 40.0, Protocol::Grid),
        (1, 9.0, 30.0, Protocol::Random(300)),
    ]
    .into_iter()
    .enumerate()
    {
        let mut p = PlantConfig::ideal();
        let d = if motor == 0 {
            &mut p.drive_1
        } else {
            &mut p.drive_2
        };
        d.cyclic_error_urad = amp;
        d.cyclic_error_cycles_per_motor_rev = per_motor_rev;
        d.cyclic_error_phase_deg = 40.0 * seed as f64;
        let cycles = per_motor_rev * d.gear_ratio;
        let r = diagnosed(&measured(&p, protocol, 70 + seed as u64));
        let context = format!(
            "cyclic error motor {} {cycles} cycles/rev:\n{}",
            motor + 1,
            table(&r)
        );
        assert!(r.steps.is_empty(), "named: {context}");
        assert!(r.unexplained, "{context}");
        let f = r
            .final_structure
            .iter()
            .find(|f| f.kind == format!("periodic_theta{}", motor + 1))
            .expect("tested");
        assert!(
            f.significant && f.cycles_per_rev == Some(cycles),
            "{f:?}\n{context}"
        );
        assert!(
            r.unexplained_description
                .contains(&format!("{cycles} cycles/rev")),
            "{context}"
        );
    }
}

/// The binary end to end: a plant TOML, `host-sim measure` writing the CSV, the diagnosis on
/// the file. Hidden: backlash and a 50-cycle gear error on motor 2.
#[test]
fn measure_command_csv_backlash_named_and_cyclic_error_unexplained() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = PlantConfig::ideal();
    p.drive_1.backlash_urad = 120.0;
    p.drive_2.backlash_urad = 80.0;
    p.drive_2.cyclic_error_urad = 40.0;
    p.drive_2.cyclic_error_cycles_per_motor_rev = 5.0;
    let toml = dir.path().join("plant.toml");
    std::fs::write(&toml, p.to_toml()).unwrap();
    let csv = dir.path().join("m.csv");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["measure", "--plant"])
        .arg(&toml)
        .args([
            "--protocol",
            "random:300",
            "--seed",
            "8",
            "--noise-um",
            "1",
            "--out",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let data = read_measurements(&csv).unwrap();
    assert_eq!(data.len(), 300);
    let r = diagnosed(&data);
    let context = table(&r);
    assert_eq!(named(&r), ["backlash"], "{context}");
    assert!(r.unexplained, "{context}");
    assert!(
        r.final_structure.iter().any(|f| f.kind == "periodic_theta2"
            && f.significant
            && f.cycles_per_rev == Some(50.0)),
        "{context}"
    );
}

/// The gap-shrink workflow of docs/guides/diagnose.md ("Close the loop"), through the binary: measure the
/// `paper` six-bar plant from random approach directions, fit, diagnose against the fit and
/// write the extended model, then measure the grid nodes commanded with it (backlash corrected
/// by direction) and build the grid from link angles. The diagnosis names the plant's backlash
/// (20 µrad per drive, docs/reference/plant-file.md) and the six-bar's mismatch, each step shrinks the residual to
/// the noise, and the extended model carries the backlash the commands then correct.
#[test]
fn gap_shrink_workflow_writes_the_extended_model_and_the_commands_use_it() {
    let dir = tempfile::tempdir().unwrap();
    let p = |name: &str| dir.path().join(name);
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    run(&[
        "measure",
        "--plant",
        "paper",
        "--protocol",
        "random:400",
        "--seed",
        "1",
        "--noise-um",
        "1",
        "--out",
        "m1.csv",
    ]);
    run(&[
        "fit", "--data", "m1.csv", "--method", "full", "--out", "fit.json",
    ]);
    let table = run(&[
        "diagnose",
        "--data",
        "m1.csv",
        "--model",
        "fit.json",
        "--noise-um",
        "1",
        "--out",
        "report.json",
        "--plots",
        "plots",
        "--out-model",
        "model.json",
    ]);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p("report.json")).unwrap()).unwrap();
    let steps = report["steps"].as_array().unwrap();
    let named: Vec<&str> = steps
        .iter()
        .map(|s| s["effect"].as_str().unwrap())
        .collect();
    assert!(
        named.contains(&"backlash") && named.contains(&"parallelogram_mismatch"),
        "{table}"
    );
    for s in steps {
        assert!(
            s["rms_after_um"].as_f64().unwrap() < s["rms_before_um"].as_f64().unwrap(),
            "{table}"
        );
    }
    assert!(
        report["unexplained"] == false
            && report["final_rms_um"].as_f64().unwrap() < 1.1 * 2f64.sqrt(),
        "{table}"
    );
    assert!(p("plots").join("residual_start.png").exists());
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(p("model.json")).unwrap()).unwrap();
    let beta: Vec<f64> = model["backlash_urad"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(beta.iter().all(|b| (b - 20.0).abs() < 4.0), "{beta:?}");
    assert!(
        model["diagnosed"]["effects"]
            .get("parallelogram_mismatch")
            .is_some(),
        "{model}"
    );
    // The tools use it: grid nodes commanded with the backlash correction, the grid from link
    // angles; `command` writes each target's approach directions and the corrected angles.
    run(&[
        "measure",
        "--plant",
        "paper",
        "--protocol",
        "grid",
        "--seed",
        "2",
        "--noise-um",
        "1",
        "--model",
        "model.json",
        "--out",
        "g.csv",
    ]);
    run(&[
        "grid",
        "--model",
        "model.json",
        "--data",
        "g.csv",
        "--out",
        "grid.bin",
    ]);
    // A second round through that grid, pooled with the first (`grid --data` several files):
    // each file is turned into link angles, every node read twice, and the two rounds agree to
    // the 1 µm instrument once each reading is referred to its node's command.
    run(&[
        "measure",
        "--plant",
        "paper",
        "--protocol",
        "grid",
        "--seed",
        "3",
        "--noise-um",
        "1",
        "--model",
        "model.json",
        "--grid",
        "grid.bin",
        "--out",
        "g2.csv",
    ]);
    let pooled: serde_json::Value = serde_json::from_str(&run(&[
        "grid",
        "--model",
        "model.json",
        "--data",
        "g.csv",
        "g2.csv",
        "--out",
        "grid2.bin",
    ]))
    .unwrap();
    let noise = &pooled["noise"];
    assert_eq!(
        (
            noise["readings_per_node_min"].as_u64(),
            noise["readings_per_node_max"].as_u64()
        ),
        (Some(2), Some(2)),
        "{pooled}"
    );
    let sigma = noise["repeats_sigma_um"].as_f64().unwrap();
    assert!(
        sigma > 0.5 && sigma < 1.5,
        "the two rounds scatter by {sigma} µm per axis with a 1 µm instrument: {pooled}"
    );
    std::fs::write(p("targets.csv"), "x_mm,y_mm\n200,0\n210,10\n205,-5\n").unwrap();
    run(&[
        "command",
        "--model",
        "model.json",
        "--grid",
        "grid.bin",
        "--targets",
        "targets.csv",
        "--out",
        "cmd.csv",
    ]);
    run(&[
        "command",
        "--model",
        "fit.json",
        "--targets",
        "targets.csv",
        "--out",
        "cmd_plain.csv",
    ]);
    let cmd = std::fs::read_to_string(p("cmd.csv")).unwrap();
    assert!(
        cmd.starts_with("x_mm,y_mm,theta1_deg,theta2_deg,dir1,dir2\n"),
        "{cmd}"
    );
    assert!(std::fs::read_to_string(p("cmd_plain.csv"))
        .unwrap()
        .starts_with("x_mm,y_mm,theta1_deg,theta2_deg\n"));
    // Each corrected angle is the uncorrected one (model + grid) moved by dir·β/2.
    let mut plain_model = model.clone();
    plain_model.as_object_mut().unwrap().remove("backlash_urad");
    std::fs::write(p("model_plain.json"), plain_model.to_string()).unwrap();
    run(&[
        "command",
        "--model",
        "model_plain.json",
        "--grid",
        "grid.bin",
        "--targets",
        "targets.csv",
        "--out",
        "cmd_nb.csv",
    ]);
    let rows = |text: &str| -> Vec<Vec<f64>> {
        text.lines()
            .skip(1)
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect()
    };
    let (with, without) = (
        rows(&cmd),
        rows(&std::fs::read_to_string(p("cmd_nb.csv")).unwrap()),
    );
    assert_eq!(with.len(), 3);
    for (w, n) in with.iter().zip(&without) {
        for j in 0..2 {
            let shift_urad = (w[2 + j] - n[2 + j]).to_radians() * 1e6;
            let want = w[4 + j] * beta[j] / 2.0;
            assert!(
                (shift_urad - want).abs() < 0.05,
                "{w:?} vs {n:?}: {shift_urad} µrad, want {want}"
            );
        }
    }
}
