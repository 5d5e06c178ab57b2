//! Prints the 5 g motion figures, not a pass/fail test: the following error at
//! the tool (the tool point against where the servo's own reference puts it, µm) of the closed
//! 2 kHz loop at 5 g, on the ideal and the `paper` six-bar plant, for
//! * the jerk-limited point-to-point tour (`p2p`) and the two contours at 5 g peak acceleration
//!   (`circle-5g`, `figure8-5g`);
//! * four feed-forwards: the identified inverse dynamics (as shipped), the same with every mass
//!   and inertia 20 % high, 20 % low and alternately ±20 % (a model error), the gains' constant
//!   inertia on the exact derivatives, and backward differences of the setpoints (the simplest
//!   loop);
//! * the settling time into a ±2 µm window (following error, and tracking error against the
//!   setpoint in the instrument frame) after a 10 mm move.
//!
//! The dynamic parameters are identified once per plant from an excitation run
//! (`host_sim::calib::dynamics::identify`), as `host-sim simulate` does without `--dynamics`.
//! Run: `cargo bench -p host-sim --bench following` (about a minute).

use host_sim::calib::dynamics::identify;
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{Plant, PlantConfig};
use host_sim::sim::closed_loop::{run_loop_with, FeedForward, LoopSummary};
use host_sim::sim::motions::Trajectory;
use kinematics_core::{Calibration, FiveBar};

fn run(
    cfg: &PlantConfig,
    cal: &Calibration<'_>,
    spec: &MachineSpec,
    trajectory: &str,
    ff: &FeedForward,
) -> LoopSummary {
    let tr = Trajectory::by_name(trajectory, spec).expect("built-in trajectory");
    let mut plant = Plant::new(cfg, 1);
    run_loop_with(
        &mut plant,
        cal,
        &tr,
        tr.natural_duration_s(),
        spec,
        ff,
        None,
    )
    .expect("closed loop")
}

fn main() {
    let spec = MachineSpec::paper();
    let cal = Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    };
    println!("following error at the tool, 5 g moves (max / RMS um; faults flagged)");
    println!(
        "{:<7} {:<11} {:<28} {:>9} {:>9} {:>12} {:>11}",
        "plant", "trajectory", "feed-forward", "max_um", "rms_um", "max_at_5g_um", "samples_5g"
    );
    for plant in ["ideal", "paper"] {
        let cfg = PlantConfig::by_name(plant).expect("built-in plant");
        let id = identify(&cfg, &cal, &spec, 1).expect("identification");
        let d = id.dynamics;
        let cases = [
            ("dynamics (identified)", FeedForward::Dynamics(d)),
            (
                "dynamics, masses +20 %",
                FeedForward::Dynamics(d.scaled_masses([1.2; 5])),
            ),
            (
                "dynamics, masses -20 %",
                FeedForward::Dynamics(d.scaled_masses([0.8; 5])),
            ),
            (
                "dynamics, masses +-20 % alt.",
                FeedForward::Dynamics(d.scaled_masses([1.2, 0.8, 1.2, 0.8, 1.2])),
            ),
            ("constant inertia", FeedForward::Constant),
            ("differences (before)", FeedForward::Differences),
        ];
        for trajectory in ["p2p", "circle-5g", "figure8-5g"] {
            for (name, ff) in &cases {
                let s = run(&cfg, &cal, &spec, trajectory, ff);
                let fault = s
                    .fault
                    .as_deref()
                    .map(|f| format!("  FAULT {f}"))
                    .unwrap_or_default();
                println!(
                    "{plant:<7} {trajectory:<11} {name:<28} {:>9.2} {:>9.2} {:>12} {:>11}{fault}",
                    s.max_following_err_um,
                    s.rms_following_err_um,
                    s.max_following_err_5g_um
                        .map_or("-".to_string(), |e| format!("{e:.2}")),
                    s.samples_at_5g,
                );
            }
        }
        let s = run(&cfg, &cal, &spec, "move-10mm", &FeedForward::Dynamics(d));
        let show = |v: Option<f64>| v.map_or("never".to_string(), |t| format!("{:.1} ms", t * 1e3));
        println!(
            "{plant:<7} move-10mm   settling into +-2 um after the move: following {}, tracking {}",
            show(s.settling_following_2um_s),
            show(s.settling_tracking_2um_s)
        );
    }
}
