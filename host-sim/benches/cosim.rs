//! The co-simulation's speed: the production firmware under QEMU driving the paper plant, a
//! session a calibration would run (`cargo bench -p host-sim --bench cosim [-- MOVES] [spread]`).
//!
//! Boots unhomed, homes through the link, visits MOVES targets (default 40) each with a move
//! and 0.2 s of settling, then streams a 3 s figure with telemetry on. Prints per phase the
//! simulated time, the wall time and their ratio (simulated seconds per wall second), QEMU's and
//! this process's CPU time (what the wall time would be on an idle machine), and at the end the
//! firmware's worst servo step and overruns (its own measurement, from its tick), the late
//! samples, and the exchange's size. The wall time depends on the machine and its load; the
//! CPU times much less. `spread` runs QEMU and the host wherever the OS puts them instead of on
//! one core (`CoSimOptions::one_core`), for comparison.
use std::time::{Duration, Instant};

use host_sim::cosim::{commissioning_image, CoSim, CoSimOptions, CoSimStats};
use host_sim::link::link_protocol::{Command, ModeCode, Response};
use host_sim::link::{figure_knots, stream_knots};
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::PlantConfig;

include!("../../tests/support/firmware_build.rs");

/// A phase's figures: the difference of two snapshots.
fn phase(name: &str, a: &CoSimStats, b: &CoSimStats, wall_s: f64) {
    let sim = b.simulated_s - a.simulated_s;
    let cpu = |x: Option<f64>, y: Option<f64>| y.zip(x).map(|(y, x)| y - x);
    let (q, h) = (
        cpu(a.qemu_cpu_s, b.qemu_cpu_s),
        cpu(a.host_cpu_s, b.host_cpu_s),
    );
    let per_sample_us = |c: Option<f64>| {
        c.map_or("-".to_string(), |c| {
            format!("{:.1}", 1e6 * c / (b.samples - a.samples).max(1) as f64)
        })
    };
    println!(
        "{name:<22} {sim:>8.2} s simulated {wall_s:>7.2} s wall {:>6.2} sim-s/wall-s   CPU per \
         sample: QEMU {} us, host {} us ({:.2} sim-s per CPU-s)",
        sim / wall_s.max(1e-9),
        per_sample_us(q),
        per_sample_us(h),
        q.zip(h).map_or(f64::NAN, |(q, h)| sim / (q + h).max(1e-9)),
    );
}

fn main() {
    let moves: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(40);
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let spec = MachineSpec::paper();
    let image = commissioning_image(&spec).expect("the paper machine's image");
    let mut opts = CoSimOptions::new(spec.clone(), PlantConfig::paper(), image);
    opts.firmware = Some(elf);
    opts.one_core = !std::env::args().any(|a| a == "spread");
    let t0 = Instant::now();
    let mut sim = CoSim::start(&opts).expect("co-simulation starts");
    let boot = t0.elapsed().as_secs_f64();
    let mut link = sim.link(Duration::from_secs(60)).expect("link");
    println!(
        "co-simulation of the paper plant: QEMU and firmware boot {boot:.2} s wall; {}",
        sim.stats()
            .core
            .map_or("QEMU and the host spread over the cores".to_string(), |c| {
                format!("QEMU and the host on core {c}")
            })
    );

    let s0 = sim.stats();
    let t = Instant::now();
    link.request(Command::Home).expect("home");
    loop {
        sim.run_for_s(0.05).expect("runs");
        if link.status().expect("status").mode == ModeCode::Running {
            break;
        }
        assert!(sim.simulated_s() < 20.0, "homing did not end");
    }
    let s1 = sim.stats();
    phase("homing", &s0, &s1, t.elapsed().as_secs_f64());

    let t = Instant::now();
    let c = spec.workspace.centre_mm();
    let h = spec.workspace.half_mm();
    for k in 0..moves {
        // A spread of targets over the workspace (a fixed sequence).
        let u = (k as f64 * 0.618_034).fract() * 2.0 - 1.0;
        let v = (k as f64 * 0.414_214).fract() * 2.0 - 1.0;
        let target = [
            (c[0] + 0.9 * h[0] * u) as f32,
            (c[1] + 0.9 * h[1] * v) as f32,
        ];
        let Response::MovePlanned { duration_s } = link
            .request(Command::MoveTo { target_mm: target })
            .expect("move")
        else {
            panic!("move")
        };
        sim.run_for_s(f64::from(duration_s) + 0.2).expect("runs");
    }
    let s2 = sim.stats();
    phase(
        &format!("{moves} moves + 0.2 s settle"),
        &s1,
        &s2,
        t.elapsed().as_secs_f64(),
    );

    let t = Instant::now();
    let Response::MovePlanned { duration_s } = link
        .request(Command::MoveTo {
            target_mm: [c[0] as f32, c[1] as f32],
        })
        .expect("move")
    else {
        panic!("move")
    };
    sim.run_for_s(f64::from(duration_s) + 0.1).expect("runs");
    link.request(Command::Telemetry { decimation: 20 })
        .expect("telemetry");
    let knots = figure_knots(c, [0.5 * h[0], 0.5 * h[1]], 1.0, 3.0, 10);
    stream_knots(&mut link, &knots, Duration::ZERO, &mut |_, _| {}).expect("stream");
    loop {
        sim.run_for_s(0.05).expect("runs");
        if !link.status().expect("status").moving {
            break;
        }
    }
    link.request(Command::Telemetry { decimation: 0 })
        .expect("telemetry off");
    let telemetry = link.take_telemetry().len();
    let s3 = sim.stats();
    phase("stream 3 s, telemetry", &s2, &s3, t.elapsed().as_secs_f64());
    phase("whole session", &s0, &s3, s3.wall_s - boot);

    let end = sim.shutdown().expect("clean shutdown");
    println!(
        "firmware: worst servo step {:.2} us, {} overruns; {} samples, {} late, interval {:?} \
         us; {telemetry} telemetry samples; exchange {} bytes ({:.0} per sample)",
        end.worst_step_us,
        end.overruns,
        end.samples,
        end.late_samples,
        end.sample_interval_us,
        end.exchange_bytes,
        end.exchange_bytes as f64 / end.samples as f64
    );
    println!(
        "BENCH cosim speed {:.2} simulated s per wall s ({:.2} simulated s in {:.2} s wall, boot \
         included); worst servo step {:.2} us",
        end.speed, end.simulated_s, end.wall_s, end.worst_step_us
    );
}
