//! Studies of `host-sim diagnose` on the synthetic generator (`diagnose::synth`): figures for
//! DIAGNOSIS.md, not pass/fail tests (the tests are `tests/diagnose.rs` and
//! `tests/diagnose_plant.rs`).
//!
//! ```text
//! cargo bench -p host-sim --bench diagnose_study                    # sweep, then table1_power
//! cargo bench -p host-sim --bench diagnose_study -- sweep           # robustness sweep only
//! cargo bench -p host-sim --bench diagnose_study -- table1_power    # what 9 points can tell
//! cargo bench -p host-sim --bench diagnose_study -- plant           # the plant outputs of DIAGNOSIS.md
//! cargo bench -p host-sim --bench diagnose_study -- example FILE    # DIAGNOSIS.md's example CSV
//! ```
//!
//! `cargo test -p host-sim --bench diagnose_study -- sweep` runs the same in the dev profile
//! (no release build; the sweep then takes about a minute).

use host_sim::diagnose::report::table;
use host_sim::diagnose::synth::{generate, Cyclic, Poses, Truth};
use host_sim::calib::measure::{measure, MeasureOptions};
use host_sim::calib::protocol::Protocol;
use host_sim::diagnose::{diagnose, effects::LIBRARY, DiagnoseOptions};
use host_sim::effect::PhysicalEffect;
use host_sim::io::measurement_csv::format_measurements;
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{PlantConfig, PlantModel};
use kinematics_core::Calibration;
use kinematics_core::FiveBar;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

const NOISE_UM: f64 = 2.0;

fn truth_with(effects: &[&str], rng: &mut ChaCha8Rng) -> Truth {
    let mut t = Truth { noise_um: NOISE_UM, ..Default::default() };
    for e in effects {
        t.add_random(PhysicalEffect::from_name(e).expect("an effect name"), rng).expect("a library effect");
    }
    t
}

fn main() {
    // `cargo bench` passes `--bench` to a harness-less target: ignore flags.
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    match args.first().map(String::as_str) {
        None => {
            sweep();
            table1_power();
        }
        Some("sweep") => sweep(),
        Some("table1_power") => table1_power(),
        Some("plant") => plant_outputs(),
        Some("example") => write_example(args.get(1).map(String::as_str).unwrap_or("diagnose_example.csv")),
        Some(other) => {
            eprintln!("unknown study '{other}' (known: sweep, table1_power, plant, example FILE)");
            std::process::exit(2);
        }
    }
}

/// Robustness sweep: many random magnitudes and seeds per single effect and for harder pairs;
/// prints the failures. Env: SWEEP_N (seeds, 20), SWEEP_SCALE (magnitude factor, 1),
/// SWEEP_ONLY (one case, e.g. `encoder_offset,frame`), SWEEP_VERBOSE (tables of the misses).
fn sweep() {
    let n: u64 = std::env::var("SWEEP_N").ok().and_then(|v| v.parse().ok()).unwrap_or(20);
    let mut cases: Vec<Vec<&str>> = LIBRARY.iter().map(|e| vec![e.name()]).collect();
    cases.push(vec![]);
    for extra in [
        ["encoder_offset", "frame"],
        ["base_offset", "frame"],
        ["link_lengths", "base_offset"],
        ["link_stretch", "backlash"],
        ["scale", "frame"],
        ["gear_ratio", "backlash"],
        ["link_lengths", "encoder_offset"],
    ] {
        cases.push(extra.to_vec());
    }
    cases.push(vec!["link_lengths", "encoder_offset", "backlash", "base_offset"]);
    cases.push(vec!["link_lengths", "encoder_offset", "backlash", "frame", "gear_ratio"]);
    if let Ok(only) = std::env::var("SWEEP_ONLY") {
        cases.retain(|c| c.join(",") == only);
    }
    for case in &cases {
        let mut fails = Vec::new();
        for seed in 0..n {
            let mut rng = ChaCha8Rng::seed_from_u64(99_000 + seed);
            let f: f64 = std::env::var("SWEEP_SCALE").ok().and_then(|v| v.parse().ok()).unwrap_or(1.0);
            let truth = truth_with(case, &mut rng).scaled(f);
            let poses = if seed % 2 == 1 { Poses::Random(400) } else { Poses::Grid5mm };
            let data = generate(&truth, poses, 5000 + seed);
            let r = diagnose(&data, &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(NOISE_UM))).unwrap();
            let mut named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
            named.sort();
            let mut want: Vec<&str> = case.clone();
            if case.contains(&"link_stretch") {
                for extra in ["link_lengths", "encoder_offset"] {
                    if named.contains(&extra) && !want.contains(&extra) {
                        want.push(extra);
                    }
                }
            }
            want.sort();
            let at_noise = r.chi2_per_dof.unwrap_or(9.0) < 1.21;
            if named != want || r.unexplained || !at_noise {
                fails.push(format!(
                    "seed {seed}: named {named:?} χ²/dof {:.2} confounded {:?}",
                    r.chi2_per_dof.unwrap_or(f64::NAN),
                    r.confounded
                ));
                if std::env::var("SWEEP_VERBOSE").is_ok() {
                    fails.push(format!("truth {truth:?}\n{}", table(&r)));
                }
            }
        }
        println!("{case:?}: {}/{n} ok", n as usize - fails.len());
        for f in fails {
            println!("    {f}");
        }
    }
}

/// Writes the synthetic example measurement file of DIAGNOSIS.md (hidden link lengths, backlash
/// and a 50-tooth cyclic error on motor 1, σ = 2 µm) to `path`.
fn write_example(path: &str) {
    let truth = Truth {
        noise_um: NOISE_UM,
        link_delta_um: [40.0, -25.0, 30.0, -60.0],
        backlash_urad: [120.0, 80.0],
        cyclic: Some(Cyclic { motor: 0, cycles: 50.0, amplitude_urad: 40.0, phase_rad: 0.3 }),
        ..Default::default()
    };
    std::fs::write(path, format_measurements(&generate(&truth, Poses::Grid5mm, 42))).unwrap();
    println!("{truth:?}");
}

/// What 9 points at 20 µm can tell (for DIAGNOSIS.md): each effect hidden at the Table I poses,
/// without dir/time columns (the paper has none), at 1× and 5× the magnitudes of the tests.
fn table1_power() {
    let n = 20u64;
    for f in [1.0, 5.0] {
        for effect in LIBRARY.iter().map(|e| e.name()).chain(["none"]) {
            let mut exact = 0;
            let mut other: std::collections::BTreeMap<String, usize> = Default::default();
            for seed in 0..n {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let mut truth = Truth { noise_um: 20.0, ..Default::default() };
                if effect != "none" {
                    truth.add_random(PhysicalEffect::from_name(effect).expect("an effect name"), &mut rng).expect("a library effect");
                }
                let mut truth = truth.scaled(f);
                truth.noise_um = 20.0;
                let mut data = generate(&truth, Poses::Table1, seed);
                for m in data.iter_mut() {
                    m.dir = None;
                    m.t_s = None;
                }
                let r = diagnose(&data, &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(20.0))).unwrap();
                let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
                let want: Vec<&str> = if effect == "none" { vec![] } else { vec![effect] };
                if named == want {
                    exact += 1;
                } else {
                    *other.entry(format!("{named:?}")).or_default() += 1;
                }
            }
            println!("×{f} {effect}: named exactly {exact}/{n}; otherwise {other:?}");
        }
    }
}

/// `host-sim measure` on the paper machine.
fn measured(p: &PlantConfig, cal: &Calibration<'_>, protocol: Protocol, seed: u64, noise_um: Option<f64>) -> Vec<host_sim::io::measurement_csv::Measurement> {
    measure(p, cal, &MeasureOptions { protocol, seed, noise_um, spec: MachineSpec::paper() }).unwrap()
}

/// The plant outputs of DIAGNOSIS.md: the six-bar plant measured by `host-sim measure` at 1 µm
/// noise (the noise, `paper` and link-error cases are the plants and seeds of
/// `tests/diagnose_plant.rs`), one line per case, the full
/// report for the six-bar's link errors and, for comparison, the same plant solved as its
/// effective five-bar.
fn plant_outputs() {
    let cal = Calibration { model: FiveBar::<f32>::paper_nominal(), grid: None };
    let run = |p: &PlantConfig, protocol: Protocol, seed: u64| {
        let data = measured(p, &cal, protocol, seed, Some(1.0));
        diagnose(&data, &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(1.0))).unwrap()
    };
    let mut cyclic = PlantConfig::ideal();
    cyclic.drive_1.cyclic_error_urad = 40.0;
    cyclic.drive_1.cyclic_error_cycles_per_motor_rev = 5.0;
    let mut both = PlantConfig::paper().with_only(PhysicalEffect::EncoderOffset).unwrap();
    both.drive_1.backlash_urad = 120.0;
    both.drive_2.backlash_urad = 80.0;
    let mut scale = PlantConfig::ideal();
    scale.instrument.scale_error_ppm = 300.0;
    let mut frame = PlantConfig::ideal();
    frame.instrument.frame_offset_mm = [0.06, -0.04];
    frame.instrument.frame_rotation_deg = 0.015;
    let mut backlash = PlantConfig::ideal();
    backlash.drive_1.backlash_urad = 150.0;
    backlash.drive_2.backlash_urad = 90.0;
    let paper_links = PlantConfig::paper().with_only(PhysicalEffect::LinkGeometry).unwrap();
    let mut paper_links_five = paper_links.clone();
    paper_links_five.sixbar.model = PlantModel::Fivebar;
    let cases: Vec<(&str, PlantConfig, Protocol, u64)> = vec![
        ("noise only", PlantConfig::ideal(), Protocol::Random(150), 40),
        ("paper clearances", PlantConfig::paper().with_only(PhysicalEffect::Clearance).unwrap(), Protocol::Random(150), 43),
        ("paper quantization", PlantConfig::paper().with_only(PhysicalEffect::EncoderQuantization).unwrap(), Protocol::Random(150), 44),
        ("paper encoder offsets", PlantConfig::paper().with_only(PhysicalEffect::EncoderOffset).unwrap(), Protocol::Random(150), 2),
        ("backlash 150/90 µrad", backlash, Protocol::Random(150), 2),
        ("frame 72 µm, 262 µrad", frame, Protocol::Random(150), 3),
        ("paper instrument frame", PlantConfig::paper().with_only(PhysicalEffect::Frame).unwrap(), Protocol::Random(150), 3),
        ("scale 300 ppm", scale, Protocol::Random(150), 4),
        ("paper offsets + backlash 120/80", both, Protocol::Random(150), 7),
        ("cyclic 40 µrad, 5/motor rev, motor 1", cyclic, Protocol::Grid, 70),
        ("paper link errors (six-bar)", paper_links.clone(), Protocol::Random(200), 60),
        ("paper link errors (effective five-bar)", paper_links_five.clone(), Protocol::Random(200), 60),
        ("random link errors σ 50 µm, seed 11", PlantConfig::ideal().with_random_errors(11, 0.05, 0.0), Protocol::Random(200), 61),
        ("random link errors σ 50 µm, seed 12", PlantConfig::ideal().with_random_errors(12, 0.05, 0.0), Protocol::Random(200), 62),
    ];
    println!("| plant (1 µm noise) | protocol | named | confounded | start RMS µm | final RMS µm | χ²/dof | unexplained |");
    println!("|---|---|---|---|---|---|---|---|");
    for (what, p, protocol, seed) in &cases {
        let r = run(p, *protocol, *seed);
        let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
        let conf: Vec<String> = r.confounded.iter().map(|c| c.join("~")).collect();
        println!(
            "| {what} | {protocol:?} | {} | {} | {:.1} | {:.2} | {:.2} | {} |",
            if named.is_empty() { "—".to_string() } else { named.join(", ") },
            if conf.is_empty() { "—".to_string() } else { conf.join(", ") },
            r.initial_rms_um,
            r.final_rms_um,
            r.chi2_per_dof.unwrap_or(f64::NAN),
            r.unexplained
        );
    }
    // The non-five-bar part of the six-bar: the same commands on both plant models, no noise.
    let six = measured(&paper_links, &cal, Protocol::Grid, 1, Some(0.0));
    let five = measured(&paper_links_five, &cal, Protocol::Grid, 1, Some(0.0));
    let d: Vec<f64> = six
        .iter()
        .zip(&five)
        .map(|(a, b)| (a.measured_mm[0] - b.measured_mm[0]).hypot(a.measured_mm[1] - b.measured_mm[1]) * 1e3)
        .collect();
    let m = host_sim::numeric::max_rms(&d);
    println!(
        "\nparallelogram mismatch of the paper's link errors (six-bar − effective five-bar, 5 mm grid): min {:.1}, RMS {:.1}, max {:.1} µm",
        d.iter().cloned().fold(f64::INFINITY, f64::min),
        m.rms,
        m.max
    );
    for (what, p) in [("six-bar", &paper_links), ("effective five-bar", &paper_links_five)] {
        println!("\n== paper link errors, {what}, random:200 seed 60\n{}", table(&run(p, Protocol::Random(200), 60)));
    }
}
