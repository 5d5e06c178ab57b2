//! The noise-aware grid on many simulated machines (figures, not a timed test):
//! `cargo bench -p host-sim --bench grid_noise [-- NOISE_UM [MACHINES]]` (defaults 10 µm, 24).
//!
//! Machine 1 is the `paper` plant, machines 2.. are six-bar plants with random errors (every
//! bar, pin and pivot N(0, 0.1 mm²), encoder offsets N(0, 0.1°²)), each calibrated by the demo's
//! pipeline (40 fit poses, two rounds over the 651 grid nodes, one reading per node per round)
//! with unidirectional approach; accuracy at 400 fresh targets (where the tool really lands).
//! Prints, per machine, the fit alone, fit + grid after one round and after two, then the mean
//! and the worst of each column.

use host_sim::calib::machine::PlantMachine;
use host_sim::calib::pipeline::{calibrate, Approach, PipelineOptions};
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::PlantConfig;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let noise_um: f64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(10.0);
    let count: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(24);
    let paper = PlantConfig::by_name("paper").expect("built in");
    let mut columns: [Vec<(f64, f64)>; 3] = Default::default();
    println!("noise-aware grid, instrument σ = {noise_um} µm, {count} machines; max/RMS µm at 400 fresh targets");
    println!("{:>8} {:>14} {:>16} {:>16}", "machine", "fit", "fit + grid (1)", "fit + grid (2)");
    for seed in 1..=count {
        let config = if seed == 1 { paper.clone() } else { paper.with_random_errors(seed, 0.1, 0.1) };
        let mut m = PlantMachine::from_config(config, "bench", Some(noise_um), seed).expect("valid plant");
        // The machine file states the instrument the plant has (the fit's plausibility and the
        // grid's noise report compare against it).
        let spec = MachineSpec { instrument_sigma_um: noise_um, ..MachineSpec::paper() };
        let opts = PipelineOptions { seed, approach: Approach::Positive, spec };
        let cal = match calibrate(&mut m, &opts, &mut |_| {}) {
            Ok(c) => c,
            Err(e) => {
                println!("{seed:>8} failed: {e}");
                continue;
            }
        };
        let cells: Vec<String> = cal.stages.iter().skip(2).enumerate().map(|(k, s)| {
            columns[k].push((s.accuracy.max_um, s.accuracy.rms_um));
            format!("{:.1}/{:.2}", s.accuracy.max_um, s.accuracy.rms_um)
        }).collect();
        println!("{seed:>8} {:>14} {:>16} {:>16}", cells[0], cells[1], cells[2]);
    }
    let stat = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        let mean = v.iter().map(f).sum::<f64>() / v.len().max(1) as f64;
        (mean, v.iter().map(f).fold(0.0, f64::max))
    };
    for (label, pick) in [("mean", 0usize), ("worst", 1)] {
        let cells: Vec<String> = columns.iter().map(|c| {
            let (m, r) = (stat(c, |x| x.0), stat(c, |x| x.1));
            if pick == 0 { format!("{:.1}/{:.2}", m.0, r.0) } else { format!("{:.1}/{:.2}", m.1, r.1) }
        }).collect();
        println!("{label:>8} {:>14} {:>16} {:>16}", cells[0], cells[1], cells[2]);
    }
}
