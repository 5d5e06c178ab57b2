//! Prints the plant's figures (not a pass/fail test):
//! * realtime factor of the closed 2 kHz loop with the five-bar plant and with the compliant
//!   six-bar plant (goals: ≥ 1000x and ≥ 50x on one core);
//! * cost per 2 kHz sample of the plant's dynamics (the linkage's inertia and 10 RK4 substeps of
//!   the coupled drives);
//! * cost per call of the six-bar equilibrium solve (warm-started along a path, as in the loop,
//!   and cold, as between far-apart measurement points) against the closed-form five-bar IK and
//!   FK, and the ratio: the paper's reason for controlling through the hidden robot.

use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{Plant, PlantConfig, PlantModel, SixBar};
use host_sim::sim::closed_loop::run_loop;
use host_sim::sim::motions::Trajectory;
use kinematics_core::{Calibration, FiveBar};
use std::hint::black_box;
use std::time::Instant;

fn loop_factor(model: PlantModel, trajectory: &str, seconds: f64) -> (f64, f64) {
    let mut cfg = PlantConfig::paper();
    cfg.sixbar.model = model;
    let cal = Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    };
    let spec = MachineSpec::paper();
    let tr = Trajectory::by_name(trajectory, &spec).unwrap();
    let mut best: f64 = 0.0;
    let mut err = 0.0;
    for _ in 0..3 {
        let mut plant = Plant::new(&cfg, 1);
        let s = run_loop(&mut plant, &cal, &tr, seconds, &spec, None).unwrap();
        assert!(s.fault.is_none(), "{s:?}");
        best = best.max(s.realtime_factor);
        err = s.max_following_err_um;
    }
    (best, err)
}

fn per_call_ns(n: usize, mut f: impl FnMut(usize)) -> f64 {
    for i in 0..n / 10 {
        f(i);
    }
    let t = Instant::now();
    for i in 0..n {
        f(i);
    }
    t.elapsed().as_secs_f64() * 1e9 / n as f64
}

fn main() {
    println!("closed loop, paper plant, one core (best of 3):");
    for (name, model) in [
        ("five-bar plant", PlantModel::Fivebar),
        ("six-bar plant (compliant, solved)", PlantModel::Sixbar),
    ] {
        for tr in ["circle", "p2p"] {
            let (f, e) = loop_factor(model, tr, 4.0);
            println!(
                "  {name:36} {tr:7} realtime factor {f:9.0}x   (max following error {e:.1} um)"
            );
        }
    }

    // Targets along a slow path (consecutive 2 kHz samples of the circle) and scattered ones.
    let spec = MachineSpec::paper();
    let five = spec.nominal;
    let tr = Trajectory::by_name("circle", &spec).unwrap();
    let path: Vec<[f64; 2]> = (0..8000).map(|k| tr.at(k as f64 * 5e-4)).collect();
    let path_theta: Vec<[f64; 2]> = path
        .iter()
        .map(|&p| five.inverse(p, 0.0).unwrap())
        .collect();
    let g = spec.grid;
    let scattered: Vec<[f64; 2]> = (0..2000)
        .map(|k| {
            five.inverse(g.node_mm(k % g.nx, (k * 7) % g.ny), 0.0)
                .unwrap()
        })
        .collect();
    let cfg = PlantConfig::paper();
    let mut sb = SixBar::new(&cfg.sixbar);
    let mut iters = 0u64;
    let warm = per_call_ns(path_theta.len(), |i| {
        let s = sb
            .solve(black_box(path_theta[i % path_theta.len()]))
            .unwrap();
        iters += u64::from(s.iterations);
    });
    let warm_iters = iters as f64 / (path_theta.len() as f64 * 1.1);
    let mut sb = SixBar::new(&cfg.sixbar);
    iters = 0;
    let cold = per_call_ns(scattered.len(), |i| {
        let s = sb.solve(black_box(scattered[i % scattered.len()])).unwrap();
        iters += u64::from(s.iterations);
    });
    let cold_iters = iters as f64 / (scattered.len() as f64 * 1.1);
    let mut acc = 0.0;
    let ik = per_call_ns(200_000, |i| {
        let t = five.inverse(black_box(path[i % path.len()]), 0.0).unwrap();
        acc += t[0];
    });
    let fk = per_call_ns(200_000, |i| {
        let c = five
            .forward(black_box(path_theta[i % path_theta.len()]), 0.0)
            .unwrap();
        acc += c[0];
    });
    let five32 = FiveBar::<f32>::paper_nominal();
    let ik32 = per_call_ns(200_000, |i| {
        let p = path[i % path.len()];
        let t = five32
            .inverse(black_box([p[0] as f32, p[1] as f32]), 0.0)
            .unwrap();
        acc += f64::from(t[0]);
    });
    // The plant's dynamics per 2 kHz sample: the linkage's inertia once, 10 RK4 substeps.
    let mut dyn_plant = Plant::new(&cfg, 1);
    let start = five.inverse(path[0], 0.0).unwrap();
    dyn_plant.settle(start, [1, 1]).unwrap();
    let dynamics = per_call_ns(20_000, |i| {
        let tau = if (i / 200) % 2 == 0 {
            [0.3, -0.2]
        } else {
            [-0.3, 0.2]
        };
        dyn_plant.advance(black_box(tau), 5e-4, 10).unwrap();
    });
    black_box(acc);
    println!("per call (paper plant, host):");
    println!("  plant dynamics per 2 kHz sample (linkage + drives)  {dynamics:9.0} ns");
    println!("  six-bar equilibrium, warm start along a 2 kHz path  {warm:9.0} ns  ({warm_iters:.1} iterations)");
    println!("  six-bar equilibrium, from scattered grid points      {cold:9.0} ns  ({cold_iters:.1} iterations)");
    println!("  five-bar closed-form IK f64                           {ik:9.1} ns");
    println!("  five-bar closed-form FK f64                           {fk:9.1} ns");
    println!("  five-bar closed-form IK f32 (as in the firmware)      {ik32:9.1} ns");
    println!(
        "  ratio six-bar (warm) / five-bar FK                    {:9.0}x",
        warm / fk
    );
    println!(
        "  ratio six-bar (warm) / five-bar IK                    {:9.0}x",
        warm / ik
    );
    println!("  (the six-bar has no closed-form IK at all: an IK would wrap this solve in a 2-D Newton loop)");
}
