//! "Close the loop": the firmware's servo compensates the drives' backlash when the
//! image carries the backlash block. The closed loop (`host-sim simulate`'s, the servo step the
//! firmware runs) on the `paper` plant's backlash (20 µrad per drive, alone: the other effects
//! are the calibration's business), point-to-point moves between random targets, so each joint
//! arrives from either direction: the static positioning error at rest at each target with and
//! without the block. Without it the link rests β/2 short in the direction of arrival.
//!
//! The figures (docs/design/servo-and-dynamics.md "Backlash", docs/design/diagnosis.md "Closing the
//! loop"):
//! `cargo test -p host-sim --release --test integration backlash_servo:: -- --nocapture`.

use host_sim::effect::PhysicalEffect;
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::{Plant, PlantConfig};
use host_sim::sim::closed_loop::{run_loop_with, FeedForward, LogRow};
use host_sim::sim::motions::{rated_limits, Piece, Trajectory};
use kinematics_core::grid::{append_backlash, encode, BACKLASH_LEN};
use kinematics_core::trajectory::PathMotion;
use kinematics_core::{Backlash, Calibration, CorrectionGrid, FiveBar};

/// Rest at each target before the next move (s): the PID's integral has settled by its end.
const DWELL_S: f64 = 0.25;
/// Targets.
const TARGETS: usize = 24;

/// Random targets over the workspace's middle (a fixed LCG: reproducible without a crate).
fn targets() -> Vec<[f64; 2]> {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut u = || {
        s = s
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..TARGETS)
        .map(|_| [185.0 + 50.0 * u(), -45.0 + 90.0 * u()])
        .collect()
}

/// Static errors at rest (µm, tool against target, the last sample of each dwell), the servo
/// feeding forward the plant's dynamics (`simulate`'s default, identified).
fn static_errors_um(with_block: bool) -> Vec<f64> {
    let spec = MachineSpec::paper();
    let config = PlantConfig::paper()
        .with_only(PhysicalEffect::Backlash)
        .unwrap();
    assert_eq!(
        [config.drive_1.backlash_urad, config.drive_2.backlash_urad],
        [20.0, 20.0]
    );
    let mut plant = Plant::new(&config, 1);
    // A zero grid over the machine's grid region (the model is the plant's nominal one), with
    // or without the backlash block.
    let g = spec.grid.geometry();
    let n = g.image_len();
    let mut img = vec![0u8; n + BACKLASH_LEN];
    encode(
        &mut img,
        &g,
        &FiveBar::paper_nominal(),
        &vec![[0.0; 2]; g.len()],
    )
    .unwrap();
    let end = if with_block {
        append_backlash(&mut img, n, n, &Backlash::new([20e-6, 20e-6]).unwrap()).unwrap()
    } else {
        n
    };
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img[..end]).unwrap());
    assert_eq!(cal.backlash().is_some(), with_block);

    let points = targets();
    let limits = rated_limits(&spec);
    let pieces: Vec<Piece> = points
        .windows(2)
        .map(|w| Piece::Line(PathMotion::line(w[0], w[1], &limits).unwrap()))
        .collect();
    // The end of each dwell: where the next move starts (the last one at the trajectory's end).
    let mut ends = Vec::new();
    let mut t = DWELL_S;
    for p in &pieces {
        ends.push(t);
        t += p.duration_s() + DWELL_S;
    }
    ends.push(t);
    let trajectory = Trajectory::sequence("random targets", pieces, DWELL_S);
    let mut log: Vec<LogRow> = Vec::new();
    let feedforward = FeedForward::Dynamics(plant.true_dynamics());
    let summary = run_loop_with(
        &mut plant,
        &cal,
        &trajectory,
        t,
        &spec,
        &feedforward,
        Some(&mut log),
    )
    .unwrap();
    assert_eq!(summary.fault, None);
    // The last sample before each dwell's end (skipping the first dwell: the start).
    ends[1..]
        .iter()
        .zip(&points[1..])
        .map(|(&end_s, target)| {
            let row = log.iter().rev().find(|r| r.t_s < end_s - 1e-9).unwrap();
            assert_eq!(
                row.setpoint_mm.map(|v| (v * 1e6).round()),
                target.map(|v| (v * 1e6).round()),
                "at rest on the target"
            );
            (row.tool_mm[0] - target[0]).hypot(row.tool_mm[1] - target[1]) * 1e3
        })
        .collect()
}

fn max_rms(v: &[f64]) -> (f64, f64) {
    (
        v.iter().cloned().fold(0.0, f64::max),
        (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt(),
    )
}

#[test]
fn the_servo_compensates_the_images_backlash_at_rest_from_random_directions() {
    let without = static_errors_um(false);
    let with = static_errors_um(true);
    let ((max0, rms0), (max1, rms1)) = (max_rms(&without), max_rms(&with));
    println!("paper plant's backlash (20 µrad per drive), {} point-to-point moves, static error at rest:", without.len());
    println!("  without the block: max {max0:.3} µm, RMS {rms0:.3} µm");
    let landed = with.iter().filter(|&&e| e < 0.1).count();
    println!(
        "  with the block:    max {max1:.3} µm, RMS {rms1:.3} µm ({landed} of {} within 0.1 µm)",
        with.len()
    );
    // Without: the link rests β/2 = 10 µrad short per joint, ~1-2 µm at the tool.
    assert!(
        rms0 > 0.8,
        "without the block the backlash shows: RMS {rms0} µm"
    );
    // With: the gap is crossed on every reversal and the link lands on the target, but for a
    // move whose motor overshoots its reference at the end (it then comes back inside the
    // gap, and the link stays where the overshoot left it: at most β, the limit of a
    // compensation on the reference alone).
    assert!(
        rms1 < 0.15 * rms0,
        "with the block: RMS {rms1} µm (without: {rms0})"
    );
    assert!(
        landed * 10 >= with.len() * 9,
        "{landed} of {} targets within 0.1 µm",
        with.len()
    );
    assert!(
        max1 < max0,
        "max {max1} µm with the block, {max0} µm without"
    );
}
