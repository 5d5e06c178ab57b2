//! Studies of `host-sim diagnose` on the synthetic generator (`synth`): figures for
//! docs/design/diagnosis.md, not pass/fail tests (the tests are `tests/diagnose.rs` and
//! `tests/diagnose_plant.rs`).
//!
//! ```text
//! cargo bench -p host-sim --bench diagnose_study                    # sweep, shape, then table1_power
//! cargo bench -p host-sim --bench diagnose_study -- sweep           # robustness sweep only
//! cargo bench -p host-sim --bench diagnose_study -- shape           # effects of other laws
//! cargo bench -p host-sim --bench diagnose_study -- table1_power    # what 9 points can tell
//! cargo bench -p host-sim --bench diagnose_study -- plant           # the plant outputs of the design doc
//! cargo bench -p host-sim --bench diagnose_study -- example FILE    # the guide's example CSV
//! ```
//!
//! `cargo test -p host-sim --bench diagnose_study -- sweep` runs the same in the dev profile
//! (no release build; slower). The sweep is ~600 diagnoses: minutes in release.

use host_sim::calib::measure::{measure, MeasureOptions};
use host_sim::calib::protocol::Protocol;
use host_sim::diagnose::report::table;
use host_sim::diagnose::{diagnose, library::LIBRARY, DiagnoseOptions};
use host_sim::effect::PhysicalEffect;
use host_sim::io::measurement_csv::format_measurements;
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{PlantConfig, PlantModel};
use host_sim::synth::judge::{judge, Judgement};
use host_sim::synth::other_laws::{LawKind, OtherStretch, StretchLaw};
use host_sim::synth::{generate, Cyclic, Poses, Truth};
use kinematics_core::Calibration;
use kinematics_core::FiveBar;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const NOISE_UM: f64 = 2.0;

fn truth_with(effects: &[&str], noise_um: f64, rng: &mut ChaCha8Rng) -> Truth {
    let mut t = Truth {
        noise_um,
        ..Default::default()
    };
    for e in effects {
        t.add_random(PhysicalEffect::from_name(e).expect("an effect name"), rng)
            .expect("a library effect");
    }
    t
}

fn main() {
    // `cargo bench` passes `--bench` to a harness-less target: ignore flags.
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    match args.first().map(String::as_str) {
        None => {
            sweep();
            shape_sweep();
            table1_power();
        }
        Some("sweep") => sweep(),
        Some("shape") => shape_sweep(),
        Some("table1_power") => table1_power(),
        Some("plant") => plant_outputs(),
        Some("example") => write_example(
            args.get(1)
                .map(String::as_str)
                .unwrap_or("diagnose_example.csv"),
        ),
        Some(other) => {
            eprintln!(
                "unknown study '{other}' (known: sweep, shape, table1_power, plant, example FILE)"
            );
            std::process::exit(2);
        }
    }
}

/// The false-positive sweep (docs/design/diagnosis.md, "Figures"): every library
/// effect the generator has, every pair, every fourth triple, and no effect, each over seeds
/// and magnitudes, without and with an out-of-library effect (a gear-tooth cyclic error, a slow
/// instrument drift). Prints per case class the number of diagnoses, the false-positive rate
/// (a diagnosis naming any effect that is not hidden, the documented exact twins aside: a
/// hidden `scale` named `link_lengths` with the pair reported confounded, the encoder offset a
/// gear ratio about a fixed angle leaves; a named effect the report declares `ambiguous` with a
/// hidden one or with that encoder offset, counted apart as "declared ambiguous") and the miss rate (a hidden effect not named), and
/// lists every false positive. The drift runs on random poses only (on the grid's raster
/// order a drift in time is a smooth function of position). `parallelogram_mismatch` has no synthetic form (its truth is
/// the six-bar plant's part errors: tests/diagnose_plant.rs).
///
/// Env (defaults in parentheses; all defaults together are the full sweep):
/// * SWEEP_N: seeds per case and magnitude (2);
/// * SWEEP_SCALES: magnitude factors (`0.5,1.5`);
/// * SWEEP_ONLY: one case, e.g. `encoder_offset,frame` (all cases);
/// * SWEEP_POSES: a number of random poses, e.g. `120`: every diagnosis on `Poses::Random(n)`
///   (random targets, each from a random approach direction) (unset: 400 random poses and the
///   5 mm grid in turn, the drift on 400 random poses only);
/// * SWEEP_NOISE_UM: the instrument σ in µm, both the generated truth's noise and the noise
///   figure given to `DiagnoseOptions` (2);
/// * SWEEP_OOL: comma list of the out-of-library variants to run among `none,cyclic,drift`
///   (all three);
/// * SWEEP_MAX_HIDDEN: 1, 2 or 3, skip the cases with more hidden effects (3: all);
/// * SWEEP_VERBOSE: tables and selection logs of the misses.
///
/// Sparse data (120 random poses, random approach directions, a 1 µm
/// instrument, 5 seeds): `SWEEP_POSES=120 SWEEP_NOISE_UM=1 SWEEP_N=5 SWEEP_SCALES=1`.
fn sweep() {
    let env = SweepEnv::from_env();
    let (n, noise_um, max_hidden, verbose) = (env.n, env.noise_um, env.max_hidden, env.verbose);
    let (scales, ools) = (env.scales.clone(), env.ools.clone());
    let effects: Vec<&str> = LIBRARY
        .iter()
        .map(|e| e.name())
        .filter(|n| *n != "parallelogram_mismatch")
        .collect();
    let mut cases: Vec<Vec<&str>> = vec![vec![]];
    cases.extend(effects.iter().map(|e| vec![*e]));
    for i in 0..effects.len() {
        for j in i + 1..effects.len() {
            cases.push(vec![effects[i], effects[j]]);
        }
    }
    let mut k = 0;
    for i in 0..effects.len() {
        for j in i + 1..effects.len() {
            for l in j + 1..effects.len() {
                if k % 4 == 0 {
                    cases.push(vec![effects[i], effects[j], effects[l]]);
                }
                k += 1;
            }
        }
    }
    if let Ok(only) = std::env::var("SWEEP_ONLY") {
        cases.retain(|c| c.join(",") == only);
    }
    cases.retain(|c| c.len() <= max_hidden);
    // (class, out-of-library) → (runs, false positives, misses, unexplained flag wrong, declared
    // ambiguous with a hidden effect, a hidden effect named but declared open beside a shape
    // misfit)
    let mut tally: std::collections::BTreeMap<(usize, &str), [usize; 6]> = Default::default();
    let started = std::time::Instant::now();
    let mut run = 0u64;
    for case in &cases {
        for &ool in &ools {
            for (si, &f) in scales.iter().enumerate() {
                for seed in 0..n {
                    let id = 1000 * si as u64 + seed;
                    let mut rng = ChaCha8Rng::seed_from_u64(99_000 + id + 7919 * case.len() as u64);
                    let mut truth = truth_with(case, noise_um, &mut rng).scaled(f);
                    add_out_of_library(&mut truth, ool, seed);
                    // Grid and random poses in turn over the whole sweep.
                    run += 1;
                    let poses = env.poses(run, ool);
                    let data = generate(&truth, poses, 5000 + id);
                    let r = diagnose(
                        &data,
                        &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(noise_um)),
                    )
                    .unwrap();
                    let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
                    let Judgement {
                        false_positives: false_pos,
                        declared,
                        missed,
                    } = judge(case, &r);
                    let flag_wrong = r.unexplained != (ool != "none");
                    let hidden_open: Vec<&str> = case
                        .iter()
                        .copied()
                        .filter(|h| r.declares_open(h))
                        .collect();
                    let t = tally.entry((case.len(), ool)).or_default();
                    t[0] += 1;
                    t[1] += usize::from(!false_pos.is_empty());
                    t[2] += usize::from(!missed.is_empty());
                    t[3] += usize::from(flag_wrong);
                    t[4] += usize::from(!declared.is_empty());
                    t[5] += usize::from(!hidden_open.is_empty());
                    // One line per diagnosis, so that a partial run is readable.
                    println!(
                        "run {run}: {case:?} + {ool}, scale {f}, seed {seed}: named {named:?}; false {} missed {} unexplained {} ambiguous pairs {} two-for-two {}{}{}{}",
                        !false_pos.is_empty(),
                        !missed.is_empty(),
                        r.unexplained,
                        r.ambiguous.len(),
                        r.ambiguous_pairs.len(),
                        if declared.is_empty() { String::new() } else { format!(" declared ambiguous {declared:?}") },
                        if hidden_open.is_empty() { String::new() } else { format!(" hidden declared open {hidden_open:?}") },
                        final_checks(&r)
                    );
                    if !false_pos.is_empty() || (verbose && (!missed.is_empty() || flag_wrong)) {
                        println!(
                            "  {case:?} + {ool}, scale {f}, seed {seed}: named {named:?}; false {false_pos:?}, missed {missed:?}, unexplained {}",
                            r.unexplained
                        );
                        if verbose {
                            println!("{}", table(&r));
                            for line in &r.selection_log {
                                println!("    log: {line}");
                            }
                        }
                    }
                }
            }
        }
    }
    let poses_text = env.poses_text();
    println!(
        "\nfalse-positive sweep: {} cases (up to {max_hidden} hidden) x {} ({}) x {} magnitudes {scales:?} x {n} seeds, {poses_text}, σ = {noise_um} µm, {:.0} s",
        cases.len(),
        ools.len(),
        ools.join(", "),
        scales.len(),
        started.elapsed().as_secs_f64()
    );
    println!(
        "{:<8} {:<8} {:>6} {:>16} {:>12} {:>18} {:>18} {:>18}",
        "hidden",
        "extra",
        "runs",
        "false positives",
        "misses",
        "unexplained wrong",
        "declared ambiguous",
        "hidden open"
    );
    let mut total = [0usize; 6];
    for ((size, ool), t) in &tally {
        let pct = |k: usize| 100.0 * t[k] as f64 / t[0] as f64;
        println!(
            "{:<8} {:<8} {:>6} {:>9} ({:>4.1} %) {:>5} ({:>4.1} %) {:>9} ({:>4.1} %) {:>10} ({:>4.1} %) {:>10} ({:>4.1} %)",
            size, ool, t[0], t[1], pct(1), t[2], pct(2), t[3], pct(3), t[4], pct(4), t[5], pct(5)
        );
        for (sum, v) in total.iter_mut().zip(t) {
            *sum += v;
        }
    }
    println!(
        "all: {} diagnoses, false-positive rate {:.1} %, miss rate {:.1} %, unexplained flag wrong {:.1} %, declared ambiguous (a named effect not hidden, reported ambiguous with a hidden one) {:.1} %, a hidden effect named but declared open beside a shape misfit {:.1} %",
        total[0],
        100.0 * total[1] as f64 / total[0] as f64,
        100.0 * total[2] as f64 / total[0] as f64,
        100.0 * total[3] as f64 / total[0] as f64,
        100.0 * total[4] as f64 / total[0] as f64,
        100.0 * total[5] as f64 / total[0] as f64
    );
}

/// The shape-mismatch sweep: a distal stretch that follows another configuration law than the
/// library's `link_stretch` (`synth::other_laws`: the levers' opening angle, an external force
/// on the platform, a temperature gradient, a stiffening compliance of the loops' self-stress),
/// alone and beside each library effect the generator has, without and with an out-of-library
/// effect, over magnitudes and seeds. The truth in the library's terms is `link_stretch` plus
/// the companion: a false positive is any other effect named (the twins and declared
/// ambiguities of [`judge`] aside); a miss a companion not named. Also counted: the stretch not
/// named, and the diagnoses that report the stretch's shape misfit (`shape_misfits`).
///
/// Env: the sweep's (`SWEEP_N`, `SWEEP_SCALES`, `SWEEP_POSES`, `SWEEP_NOISE_UM`, `SWEEP_OOL`,
/// `SWEEP_VERBOSE`), `SHAPE_LAWS`, a comma list among the laws of `synth::other_laws` (`StretchLaw::name`;
/// all nine), and `SHAPE_COMPANIONS`, a comma list of companions (`none` or library effect names; all).
fn shape_sweep() {
    let env = SweepEnv::from_env();
    let laws: Vec<&str> = match std::env::var("SHAPE_LAWS") {
        Ok(v) => v
            .split(',')
            .map(str::trim)
            .filter(|x| !x.is_empty())
            .map(|w| {
                StretchLaw::all(0)
                    .iter()
                    .map(StretchLaw::name)
                    .find(|n| *n == w)
                    .unwrap_or_else(|| panic!("SHAPE_LAWS: '{w}' is not a law"))
            })
            .collect(),
        Err(_) => StretchLaw::all(0).iter().map(StretchLaw::name).collect(),
    };
    let companions: Vec<&str> = std::iter::once("")
        .chain(
            LIBRARY
                .iter()
                .map(|e| e.name())
                .filter(|n| *n != "parallelogram_mismatch"),
        )
        .collect();
    // The companions to run (their index in `companions` seeds the truth, so a subset draws the
    // same truths as the whole sweep).
    let wanted = |c: &str| match std::env::var("SHAPE_COMPANIONS") {
        Ok(v) => v
            .split(',')
            .map(str::trim)
            .any(|w| w == c || (w == "none" && c.is_empty())),
        Err(_) => true,
    };
    // (covered by the generalised shape, law, companion or none, out-of-library) → [runs, false
    // positives, misses, stretch not named, misfit reported, declared ambiguous]
    let mut tally: std::collections::BTreeMap<(LawKind, &str, bool, &str), [usize; 6]> =
        Default::default();
    let started = std::time::Instant::now();
    for &law_name in &laws {
        // The law's index among all the laws seeds the truth, so a subset of laws draws the same
        // truths as the whole sweep.
        let li = StretchLaw::all(0)
            .iter()
            .position(|l| l.name() == law_name)
            .expect("a law");
        for (ci, &companion) in companions.iter().enumerate() {
            if !wanted(companion) {
                continue;
            }
            for (oi, &ool) in env.ools.iter().enumerate() {
                for (si, &f) in env.scales.iter().enumerate() {
                    for seed in 0..env.n {
                        let id = 1000 * si as u64 + 100 * ci as u64 + seed;
                        // The diagnosis' number in the whole sweep (which picks its poses), so
                        // that a subset runs the same diagnoses as the whole.
                        let run = (((li * companions.len() + ci) * env.ools.len() + oi)
                            * env.scales.len()
                            + si) as u64
                            * env.n
                            + seed
                            + 1;
                        let mut rng = ChaCha8Rng::seed_from_u64(77_000 + id + 7919 * li as u64);
                        let hidden: Vec<&str> = if companion.is_empty() {
                            vec![]
                        } else {
                            vec![companion]
                        };
                        let mut truth = truth_with(&hidden, env.noise_um, &mut rng);
                        let law = StretchLaw::all(seed)
                            .into_iter()
                            .find(|l| l.name() == law_name)
                            .expect("a law");
                        truth.other_stretch = Some(OtherStretch {
                            law,
                            rms_um: rng.random_range(8.0..30.0),
                            c_ratio: rng.random_range(0.8..1.25),
                        });
                        let mut truth = truth.scaled(f);
                        add_out_of_library(&mut truth, ool, seed);
                        let data = generate(&truth, env.poses(run, ool), 6000 + id);
                        let r = diagnose(
                            &data,
                            &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(env.noise_um)),
                        )
                        .unwrap();
                        let mut truth_set = hidden.clone();
                        truth_set.push("link_stretch");
                        let j = judge(&truth_set, &r);
                        let stretch_missed = j.missed.iter().any(|m| m == "link_stretch");
                        let missed: Vec<&String> =
                            j.missed.iter().filter(|m| *m != "link_stretch").collect();
                        let misfit = !r.shape_misfits.is_empty();
                        let t = tally
                            .entry((law.kind(), law_name, !companion.is_empty(), ool))
                            .or_default();
                        t[0] += 1;
                        t[1] += usize::from(!j.false_positives.is_empty());
                        t[2] += usize::from(!missed.is_empty());
                        t[3] += usize::from(stretch_missed);
                        t[4] += usize::from(misfit);
                        t[5] += usize::from(!j.declared.is_empty());
                        let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
                        println!(
                            "run {run}: {law_name} stretch {:.1} µm + {hidden:?} + {ool}, scale {f}, seed {seed}: named {named:?}; false {:?} missed {:?} misfit {misfit} unexplained {}{}",
                            truth.other_stretch.map_or(0.0, |s| s.rms_um),
                            j.false_positives,
                            j.missed,
                            r.unexplained,
                            final_checks(&r)
                        );
                        if env.verbose && (!j.false_positives.is_empty() || !j.missed.is_empty()) {
                            println!("{}", table(&r));
                            for line in &r.selection_log {
                                println!("    log: {line}");
                            }
                        }
                    }
                }
            }
        }
    }
    println!(
        "\nshape-mismatch sweep: {} laws x {} companions (none and each library effect) x {} ({}) x {} magnitudes {:?} x {} seeds, {}, σ = {} µm, {:.0} s",
        laws.len(),
        companions.len(),
        env.ools.len(),
        env.ools.join(", "),
        env.scales.len(),
        env.scales,
        env.n,
        env.poses_text(),
        env.noise_um,
        started.elapsed().as_secs_f64()
    );
    println!(
        "{:<18} {:<10} {:<8} {:>6} {:>16} {:>12} {:>18} {:>16} {:>18}",
        "law",
        "companion",
        "extra",
        "runs",
        "false positives",
        "misses",
        "stretch not named",
        "misfit reported",
        "declared ambiguous"
    );
    let mut totals: std::collections::BTreeMap<LawKind, [usize; 6]> = Default::default();
    for ((kind, law, with, ool), t) in &tally {
        let pct = |k: usize| 100.0 * t[k] as f64 / t[0] as f64;
        println!(
            "{:<18} {:<10} {:<8} {:>6} {:>9} ({:>4.1} %) {:>5} ({:>4.1} %) {:>11} ({:>4.1} %) {:>9} ({:>4.1} %) {:>11} ({:>4.1} %)",
            law, if *with { "one" } else { "none" }, ool, t[0], t[1], pct(1), t[2], pct(2), t[3], pct(3), t[4], pct(4), t[5], pct(5)
        );
        for (sum, v) in totals.entry(*kind).or_default().iter_mut().zip(t) {
            *sum += v;
        }
    }
    for (kind, total) in &totals {
        let pct = |k: usize| 100.0 * total[k] as f64 / total[0].max(1) as f64;
        println!(
            "{}: {} diagnoses, false-positive rate {:.1} %, miss rate {:.1} %, stretch not named {:.1} %, shape misfit reported {:.1} %, declared ambiguous {:.1} %",
            match kind {
                LawKind::SelfStress => "self-stress laws (the generalised shape's)",
                LawKind::Beyond => "beyond the generalised shape",
            },
            total[0], pct(1), pct(2), pct(3), pct(4), pct(5)
        );
    }
}

/// What the selection's final checks did in a report, for the run lines: the effects the final
/// add test dropped (`selection::prune_weak`, log lines `drop …`) and those not named beside a
/// stretch's generalised shape (`shape_misfits`).
fn final_checks(r: &host_sim::diagnose::report::Report) -> String {
    let dropped: Vec<&str> = r
        .selection_log
        .iter()
        .filter_map(|l| l.strip_prefix("drop "))
        .filter_map(|l| l.split(':').next())
        .collect();
    let mut out = String::new();
    if !dropped.is_empty() {
        out.push_str(&format!(" final add test dropped {dropped:?}"));
    }
    for m in &r.shape_misfits {
        out.push_str(&format!(
            " {}{} shape misfit{} not named {:?} open {:?}",
            m.effect,
            if m.effect_named { "" } else { " (not named)" },
            if m.significant { " kept" } else { "" },
            m.not_named,
            m.open
        ));
    }
    out
}

/// Adds the sweep's out-of-library effect `ool` (`none`, `cyclic`, `drift`) for `seed`.
fn add_out_of_library(truth: &mut Truth, ool: &str, seed: u64) {
    match ool {
        "cyclic" => {
            truth.cyclic = Some(Cyclic {
                motor: (seed % 2) as usize,
                cycles: [36.0, 50.0, 72.0][(seed % 3) as usize],
                amplitude_urad: 35.0,
                phase_rad: 0.4 * seed as f64,
            })
        }
        "drift" => truth.drift_um_per_s = [0.012, -0.008],
        _ => {}
    }
}

/// The sweeps' conditions from the environment (the env list of [`sweep`]).
struct SweepEnv {
    n: u64,
    scales: Vec<f64>,
    fixed_poses: Option<usize>,
    noise_um: f64,
    ools: Vec<&'static str>,
    max_hidden: usize,
    verbose: bool,
}

impl SweepEnv {
    fn from_env() -> SweepEnv {
        let n: u64 = std::env::var("SWEEP_N")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(2);
        let scales: Vec<f64> = std::env::var("SWEEP_SCALES")
            .ok()
            .map(|v| v.split(',').filter_map(|x| x.parse().ok()).collect())
            .unwrap_or_else(|| vec![0.5, 1.5]);
        let fixed_poses: Option<usize> = std::env::var("SWEEP_POSES").ok().map(|v| {
            v.trim()
                .parse()
                .ok()
                .filter(|&p: &usize| p > 0)
                .unwrap_or_else(|| panic!("SWEEP_POSES={v}: a positive number of random poses"))
        });
        let noise_um: f64 = std::env::var("SWEEP_NOISE_UM").ok().map_or(NOISE_UM, |v| {
            v.trim()
                .parse()
                .ok()
                .filter(|&s: &f64| s > 0.0 && s.is_finite())
                .unwrap_or_else(|| panic!("SWEEP_NOISE_UM={v}: a positive σ in µm"))
        });
        let ools: Vec<&str> = match std::env::var("SWEEP_OOL") {
            Ok(v) => {
                let want: Vec<String> = v
                    .split(',')
                    .map(|x| x.trim().to_string())
                    .filter(|x| !x.is_empty())
                    .collect();
                for w in &want {
                    assert!(
                        ["none", "cyclic", "drift"].contains(&w.as_str()),
                        "SWEEP_OOL: '{w}' is not one of none, cyclic, drift"
                    );
                }
                ["none", "cyclic", "drift"]
                    .into_iter()
                    .filter(|o| want.iter().any(|w| w == o))
                    .collect()
            }
            Err(_) => vec!["none", "cyclic", "drift"],
        };
        let max_hidden: usize = std::env::var("SWEEP_MAX_HIDDEN").ok().map_or(3, |v| {
            v.trim()
                .parse()
                .ok()
                .filter(|m: &usize| (1..=3).contains(m))
                .unwrap_or_else(|| panic!("SWEEP_MAX_HIDDEN={v}: 1, 2 or 3"))
        });
        SweepEnv {
            n,
            scales,
            fixed_poses,
            noise_um,
            ools,
            max_hidden,
            verbose: std::env::var("SWEEP_VERBOSE").is_ok(),
        }
    }

    /// The pose set of the `run`-th diagnosis (1-based): the fixed random set, else 400 random
    /// poses and the 5 mm grid in turn (a drift only on random poses: on the grid's raster order
    /// time is a function of position, and a drift is then a geometry no test can tell).
    fn poses(&self, run: u64, ool: &str) -> Poses {
        match self.fixed_poses {
            Some(p) => Poses::Random(p),
            None if run % 2 == 1 || ool == "drift" => Poses::Random(400),
            None => Poses::Grid5mm,
        }
    }

    /// The pose sets, for the summary line.
    fn poses_text(&self) -> String {
        match self.fixed_poses {
            Some(p) => format!("{p} random poses (random approach directions)"),
            None => "400 random poses and the 5 mm grid in turn (drift: random)".to_string(),
        }
    }
}

/// Writes the synthetic example measurement file (hidden link lengths, backlash
/// and a 50-tooth cyclic error on motor 1, σ = 2 µm) to `path`.
fn write_example(path: &str) {
    let truth = Truth {
        noise_um: NOISE_UM,
        link_delta_um: [40.0, -25.0, 30.0, -60.0],
        backlash_urad: [120.0, 80.0],
        cyclic: Some(Cyclic {
            motor: 0,
            cycles: 50.0,
            amplitude_urad: 40.0,
            phase_rad: 0.3,
        }),
        ..Default::default()
    };
    std::fs::write(
        path,
        format_measurements(&generate(&truth, Poses::Grid5mm, 42)),
    )
    .unwrap();
    println!("{truth:?}");
}

/// What 9 points at 20 µm can tell: each effect hidden at the Table I poses,
/// without dir/time columns (the paper has none), at 1× and 5× the magnitudes of the tests.
fn table1_power() {
    let n = 20u64;
    for f in [1.0, 5.0] {
        for effect in LIBRARY.iter().map(|e| e.name()).chain(["none"]) {
            let mut exact = 0;
            let mut other: std::collections::BTreeMap<String, usize> = Default::default();
            for seed in 0..n {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                let mut truth = Truth {
                    noise_um: 20.0,
                    ..Default::default()
                };
                if effect != "none" {
                    truth
                        .add_random(
                            PhysicalEffect::from_name(effect).expect("an effect name"),
                            &mut rng,
                        )
                        .expect("a library effect");
                }
                let mut truth = truth.scaled(f);
                truth.noise_um = 20.0;
                let mut data = generate(&truth, Poses::Table1, seed);
                for m in data.iter_mut() {
                    m.dir = None;
                    m.t_s = None;
                }
                let r = diagnose(
                    &data,
                    &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(20.0)),
                )
                .unwrap();
                let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
                let want: Vec<&str> = if effect == "none" {
                    vec![]
                } else {
                    vec![effect]
                };
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
fn measured(
    p: &PlantConfig,
    cal: &Calibration<'_>,
    protocol: Protocol,
    seed: u64,
    noise_um: Option<f64>,
) -> Vec<host_sim::io::measurement_csv::Measurement> {
    measure(
        p,
        cal,
        &MeasureOptions {
            protocol,
            seed,
            noise_um,
            spec: MachineSpec::paper(),
        },
    )
    .unwrap()
}

/// The plant outputs: the six-bar plant measured by `host-sim measure` at 1 µm
/// noise (the noise, `paper` and link-error cases are the plants and seeds of
/// `tests/diagnose_plant.rs`), one line per case, the full
/// report for the six-bar's link errors and, for comparison, the same plant solved as its
/// effective five-bar.
fn plant_outputs() {
    let cal = Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    };
    let run = |p: &PlantConfig, protocol: Protocol, seed: u64| {
        let data = measured(p, &cal, protocol, seed, Some(1.0));
        diagnose(
            &data,
            &DiagnoseOptions::paper(FiveBar::paper_nominal(), Some(1.0)),
        )
        .unwrap()
    };
    let mut cyclic = PlantConfig::ideal();
    cyclic.drive_1.cyclic_error_urad = 40.0;
    cyclic.drive_1.cyclic_error_cycles_per_motor_rev = 5.0;
    let mut both = PlantConfig::paper()
        .with_only(PhysicalEffect::EncoderOffset)
        .unwrap();
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
    let paper_links = PlantConfig::paper()
        .with_only(PhysicalEffect::LinkGeometry)
        .unwrap();
    let mut links_backlash = paper_links.clone();
    links_backlash.drive_1.backlash_urad = 120.0;
    links_backlash.drive_2.backlash_urad = 80.0;
    let mut paper_links_five = paper_links.clone();
    paper_links_five.sixbar.model = PlantModel::Fivebar;
    let cases: Vec<(&str, PlantConfig, Protocol, u64)> = vec![
        (
            "noise only",
            PlantConfig::ideal(),
            Protocol::Random(150),
            40,
        ),
        (
            "paper clearances",
            PlantConfig::paper()
                .with_only(PhysicalEffect::Clearance)
                .unwrap(),
            Protocol::Random(150),
            43,
        ),
        (
            "paper quantization",
            PlantConfig::paper()
                .with_only(PhysicalEffect::EncoderQuantization)
                .unwrap(),
            Protocol::Random(150),
            44,
        ),
        (
            "paper encoder offsets",
            PlantConfig::paper()
                .with_only(PhysicalEffect::EncoderOffset)
                .unwrap(),
            Protocol::Random(150),
            2,
        ),
        ("backlash 150/90 µrad", backlash, Protocol::Random(150), 2),
        ("frame 72 µm, 262 µrad", frame, Protocol::Random(150), 3),
        (
            "paper instrument frame",
            PlantConfig::paper()
                .with_only(PhysicalEffect::Frame)
                .unwrap(),
            Protocol::Random(150),
            3,
        ),
        ("scale 300 ppm", scale, Protocol::Random(150), 4),
        (
            "paper offsets + backlash 120/80",
            both,
            Protocol::Random(150),
            7,
        ),
        (
            "cyclic 40 µrad, 5/motor rev, motor 1",
            cyclic,
            Protocol::Grid,
            70,
        ),
        (
            "paper link errors (six-bar)",
            paper_links.clone(),
            Protocol::Random(200),
            60,
        ),
        (
            "paper link errors (effective five-bar)",
            paper_links_five.clone(),
            Protocol::Random(200),
            60,
        ),
        (
            "random link errors σ 50 µm, seed 11",
            PlantConfig::ideal().with_random_errors(11, 0.05, 0.0),
            Protocol::Random(200),
            61,
        ),
        (
            "random link errors σ 50 µm, seed 12",
            PlantConfig::ideal().with_random_errors(12, 0.05, 0.0),
            Protocol::Random(200),
            62,
        ),
        (
            "paper link errors + backlash 120/80 µrad",
            links_backlash,
            Protocol::Random(400),
            63,
        ),
        (
            "the paper plant (every effect it has)",
            PlantConfig::paper(),
            Protocol::Random(400),
            1,
        ),
    ];
    println!("| plant (1 µm noise) | protocol | named | confounded | start RMS µm | final RMS µm | χ²/dof | unexplained |");
    println!("|---|---|---|---|---|---|---|---|");
    for (what, p, protocol, seed) in &cases {
        let r = run(p, *protocol, *seed);
        let named: Vec<&str> = r.steps.iter().map(|s| s.effect.as_str()).collect();
        let conf: Vec<String> = r.confounded.iter().map(|c| c.join("~")).collect();
        println!(
            "| {what} | {protocol:?} | {} | {} | {:.1} | {:.2} | {:.2} | {} |",
            if named.is_empty() {
                "—".to_string()
            } else {
                named.join(", ")
            },
            if conf.is_empty() {
                "—".to_string()
            } else {
                conf.join(", ")
            },
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
        .map(|(a, b)| {
            (a.measured_mm[0] - b.measured_mm[0]).hypot(a.measured_mm[1] - b.measured_mm[1]) * 1e3
        })
        .collect();
    let m = host_sim::numeric::max_rms(&d);
    println!(
        "\nparallelogram mismatch of the paper's link errors (six-bar − effective five-bar, 5 mm grid): min {:.1}, RMS {:.1}, max {:.1} µm",
        d.iter().cloned().fold(f64::INFINITY, f64::min),
        m.rms,
        m.max
    );
    for (what, p) in [
        ("six-bar", &paper_links),
        ("effective five-bar", &paper_links_five),
    ] {
        println!(
            "\n== paper link errors, {what}, random:200 seed 60\n{}",
            table(&run(p, Protocol::Random(200), 60))
        );
    }
}
