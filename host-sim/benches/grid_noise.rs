//! The noise-aware grid on many simulated machines (figures, not a timed test):
//! `cargo bench -p host-sim --bench grid_noise [-- NOISE_UM [MACHINES [second]]]` (defaults
//! 10 µm, 24).
//!
//! Machine 1 is the `paper` plant, machines 2.. are six-bar plants with random errors (every
//! bar, pin and pivot N(0, 0.1 mm²), encoder offsets N(0, 0.1°²)), each calibrated by the demo's
//! pipeline (40 fit poses, two rounds over the 651 grid nodes, one reading per node per round)
//! with unidirectional approach; accuracy at 400 fresh targets (where the tool really lands).
//! Prints, per machine, the fit alone, fit + grid after one round and after two, then the mean
//! and the worst of each column. With `second`: the second machine (`machines/second.toml`, its
//! plant `plants/second.toml`; one machine, its own errors).
//!
//! The column "(1) generic" is round 1's grid from the same readings without the six-bar prior
//! (`GridOptions::six_bar_prior` off: the generic bases by GCV, the grid before the prior).
//!
//! Where the one-round error comes from: the last column is the round-1 grid's estimate (its
//! basis and λ, `Smoothing::Exactly`) applied to the nodes' noiseless errors (where the tool
//! really was at each node). The estimate is linear in the readings, so this is its bias alone:
//! the smoothing's, the first-order formula's and the interpolation between nodes; what the
//! noisy grid has beyond it is the instrument's noise the estimate kept.

use host_sim::calib::grid::{build_with, GridOptions, Smoothing};
use host_sim::calib::machine::PlantMachine;
use host_sim::calib::measure::{measure_visits, Landed};
use host_sim::calib::pipeline::{accuracy, calibrate, Approach, Calibrated, PipelineOptions};
use host_sim::io::measurement_csv::Measurement;
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::PlantConfig;
use kinematics_core::{Calibration, CorrectionGrid};

/// max/RMS (µm) at the verification targets of the grid `opts` builds from `rows` with the
/// fitted model.
fn grid_accuracy(
    machine: &mut PlantMachine,
    cal: &Calibrated,
    spec: &MachineSpec,
    rows: &[Measurement],
    opts: &GridOptions,
) -> Result<(f64, f64), String> {
    let g = build_with(&cal.full.model, rows, opts).map_err(|e| e.to_string())?;
    let grid = CorrectionGrid::parse(&g.image).map_err(|e| e.to_string())?;
    let landed: Vec<Landed> = measure_visits(
        machine,
        &Calibration::from_grid(grid),
        &cal.plan.verify,
        Approach::Positive,
        spec,
        &mut 0,
    )
    .map_err(|e| e.to_string())?;
    let a = accuracy(&cal.in_machine_frame(&landed));
    Ok((a.max_um, a.rms_um))
}

/// The round-1 grid's estimate (its basis and λs) applied to the nodes' noiseless errors.
fn bias_only(
    machine: &mut PlantMachine,
    cal: &Calibrated,
    spec: &MachineSpec,
) -> Result<(f64, f64), String> {
    let truth: Vec<Measurement> = cal
        .in_machine_frame(&cal.grid_data)
        .iter()
        .map(|l| Measurement {
            measured_mm: l.true_mm,
            ..l.row.clone()
        })
        .collect();
    let n = &cal.grid.noise;
    let opts = GridOptions {
        smoothing: Smoothing::Exactly(n.basis, n.lambda, n.six_bar_lambda),
        instrument_sigma_um: None,
        ..GridOptions::for_machine(spec)
    };
    grid_accuracy(machine, cal, spec, &truth, &opts)
}

/// Round 1's grid from the same readings with the generic bases only.
fn generic(
    machine: &mut PlantMachine,
    cal: &Calibrated,
    spec: &MachineSpec,
) -> Result<(f64, f64), String> {
    let rows: Vec<Measurement> = cal
        .in_machine_frame(&cal.grid_data)
        .iter()
        .map(|l| l.row.clone())
        .collect();
    grid_accuracy(
        machine,
        cal,
        spec,
        &rows,
        &GridOptions {
            six_bar_prior: false,
            ..GridOptions::for_machine(spec)
        },
    )
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let noise_um: f64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(10.0);
    let second = args.get(2).map(String::as_str) == Some("second");
    let count: u64 = if second {
        1
    } else {
        args.get(1).and_then(|s| s.parse().ok()).unwrap_or(24)
    };
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let (plant, machine_spec) = if second {
        let plant = PlantConfig::by_name(&root.join("plants/second.toml").display().to_string())
            .expect("shipped plant");
        (
            plant,
            host_sim::io::machine_file::read_machine(&root.join("machines/second.toml"))
                .expect("shipped machine file"),
        )
    } else {
        (
            PlantConfig::by_name("paper").expect("built in"),
            MachineSpec::paper(),
        )
    };
    let mut columns: [Vec<(f64, f64)>; 5] = Default::default();
    println!("noise-aware grid, instrument σ = {noise_um} µm, {count} machines; max/RMS µm at 400 fresh targets");
    println!(
        "{:>8} {:>14} {:>16} {:>16} {:>16} {:>16}  round 1's basis, effective nodes",
        "machine", "fit", "fit + grid (1)", "fit + grid (2)", "(1) bias only", "(1) generic"
    );
    for seed in 1..=count {
        let config = if seed == 1 {
            plant.clone()
        } else {
            plant.with_random_errors(seed, 0.1, 0.1)
        };
        let mut m =
            PlantMachine::from_config(config, "bench", Some(noise_um), seed).expect("valid plant");
        // The machine file states the instrument the plant has (the fit's plausibility and the
        // grid's noise report compare against it).
        let spec = MachineSpec {
            instrument_sigma_um: noise_um,
            ..machine_spec.clone()
        };
        let opts = PipelineOptions {
            seed,
            approach: Approach::Positive,
            spec: spec.clone(),
        };
        let cal = match calibrate(&mut m, &opts, &mut |_| {}) {
            Ok(c) => c,
            Err(e) => {
                println!("{seed:>8} failed: {e}");
                continue;
            }
        };
        let bias = match bias_only(&mut m, &cal, &spec) {
            Ok(b) => b,
            Err(e) => {
                println!("{seed:>8} bias column failed: {e}");
                continue;
            }
        };
        let generic = match generic(&mut m, &cal, &spec) {
            Ok(g) => g,
            Err(e) => {
                println!("{seed:>8} generic column failed: {e}");
                continue;
            }
        };
        let figures = cal
            .stages
            .iter()
            .skip(2)
            .map(|s| (s.accuracy.max_um, s.accuracy.rms_um))
            .chain([bias, generic]);
        let cells: Vec<String> = figures
            .enumerate()
            .map(|(k, (max, rms))| {
                columns[k].push((max, rms));
                format!("{max:.1}/{rms:.2}")
            })
            .collect();
        let n = &cal.grid.noise;
        println!(
            "{seed:>8} {:>14} {:>16} {:>16} {:>16} {:>16}  {:?}, {:.1}",
            cells[0], cells[1], cells[2], cells[3], cells[4], n.basis, n.effective_nodes
        );
    }
    let stat = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        let mean = v.iter().map(f).sum::<f64>() / v.len().max(1) as f64;
        (mean, v.iter().map(f).fold(0.0, f64::max))
    };
    for (label, pick) in [("mean", 0usize), ("worst", 1)] {
        let cells: Vec<String> = columns
            .iter()
            .map(|c| {
                let (m, r) = (stat(c, |x| x.0), stat(c, |x| x.1));
                if pick == 0 {
                    format!("{:.1}/{:.2}", m.0, r.0)
                } else {
                    format!("{:.1}/{:.2}", m.1, r.1)
                }
            })
            .collect();
        println!(
            "{label:>8} {:>14} {:>16} {:>16} {:>16} {:>16}",
            cells[0], cells[1], cells[2], cells[3], cells[4]
        );
    }
}
