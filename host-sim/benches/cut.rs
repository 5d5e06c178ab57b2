//! The redundant machine's figures: every shipped part and random programs cut on the
//! simulated machine (the ideal six-bar plant, the paper's gantry), executed, and the planner's
//! own time on a nest of 1000 contours.
//!
//! ```text
//! cargo bench -p host-sim --bench cut                  # the table (parts, random, planner)
//! cargo bench -p host-sim --bench cut -- random N      # N random programs (default 24)
//! cargo bench -p host-sim --bench cut -- write-parts DIR   # the example programs, written
//! ```
//! Columns: the split machine's time as executed, the gantry alone's, the ratio, the lower
//! bound and the split's ratio to it, the contour error at the tool while the beam is on (max,
//! RMS, µm), whether the micro stayed in its workspace less the margin and every stage within
//! its limits (on the executed motion), and the planner's wall time.

use host_sim::cut::report::CutReport;
use host_sim::cut::{parts, plan_program, run, CutOptions};
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::PlantConfig;
use kinematics_core::Calibration;
use std::time::Instant;

fn cut(name: &str, text: &str) -> CutReport {
    let spec = MachineSpec::paper();
    let opts = CutOptions {
        spec: spec.clone(),
        plant: PlantConfig::ideal(),
        calibration: Calibration {
            model: spec.nominal.cast(),
            grid: None,
        },
        dynamics: None,
        program_name: name.to_string(),
    };
    match run(text, &opts) {
        Ok(r) => r.report,
        Err(e) => panic!("{name}: {e}"),
    }
}

fn header() {
    println!(
        "| program | plan | split s | gantry alone s | speed-up | bound s | split / bound | contour max / RMS um | micro inside | within limits | planner s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
}

fn row(r: &CutReport) {
    println!(
        "| {} | {:?} | {:.3} | {:.3} | {:.2}x | {:.3} | {:.3} | {:.2} / {:.2} | {} | {} | {:.3} |",
        r.program,
        r.plan,
        r.completion_s,
        r.gantry_only_s,
        r.speedup,
        r.bound_s,
        r.bound_ratio,
        r.contour_max_um,
        r.contour_rms_um,
        r.micro_inside_workspace,
        r.within_limits,
        r.planner_s
    );
}

fn random(n: u64) {
    println!("\nRandom programs (seeds 0..{n}, 12 features each, anywhere on the sheet):\n");
    header();
    let (mut worst_ratio, mut worst_contour, mut min_speedup) = (0.0f64, 0.0f64, f64::INFINITY);
    let mut bad = 0;
    for seed in 0..n {
        let text = parts::random(seed, 12, [20.0, 20.0], [1480.0, 2980.0]);
        let r = cut(&format!("random {seed}"), &text);
        row(&r);
        worst_ratio = worst_ratio.max(r.bound_ratio);
        worst_contour = worst_contour.max(r.contour_max_um);
        min_speedup = min_speedup.min(r.speedup);
        if !(r.micro_inside_workspace && r.within_limits) {
            bad += 1;
        }
    }
    println!(
        "\nrandom: slowest speed-up {min_speedup:.2}x, worst split / bound {worst_ratio:.3}, worst contour {worst_contour:.2} um, {bad} of {n} outside a limit or the workspace"
    );
}

fn planner_time() {
    let text = parts::nest_1000();
    let spec = MachineSpec::paper();
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..3 {
        let t = Instant::now();
        let (p, _) = plan_program(&text, &spec, &PlantConfig::ideal()).expect("the nest plans");
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(p);
    }
    let p = last.expect("planned three times");
    println!(
        "\nPlanner on the nest of 1000 contours ({} moves, {:.1} s of cutting program): {best:.3} s (best of 3, read + plan + bound); split {:.1} s, gantry alone {:.1} s, bound {:.1} s",
        p.layout.moves.len(),
        p.plan.completion_s(),
        p.plan.completion_s(),
        p.gantry_only_s,
        p.bound.bound_s
    );
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    match args.first().map(String::as_str) {
        Some("write-parts") => {
            let dir = args.get(1).map_or("host-sim/parts", String::as_str);
            for (name, text) in parts::examples() {
                let path = std::path::Path::new(dir).join(name);
                std::fs::write(&path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                println!("wrote {}", path.display());
            }
        }
        Some("random") => random(args.get(1).and_then(|n| n.parse().ok()).unwrap_or(24)),
        _ => {
            println!("The shipped parts (host-sim/parts/), executed on the ideal six-bar plant:\n");
            header();
            for (name, text) in parts::examples() {
                row(&cut(name, &text));
            }
            random(24);
            planner_time();
        }
    }
}
