//! Grid builder and command path: the sign of the correction (commanding through the grid puts
//! a synthetic machine's tool on the target), the second round, and the lattice checks.

use host_sim::calib::grid::{build_nodes, detect_lattice, encode_image};
use host_sim::io::measurement_csv::Measurement;
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A machine with the paper's kind of errors (tenths of a mm in the links, mrad offsets).
fn machine() -> FiveBar<f64> {
    let mut m = FiveBar::<f64>::paper_nominal();
    m.a_mm = 149.7;
    m.b_mm = 150.25;
    m.c_mm = 149.85;
    m.d_mm = 150.3;
    m.base_b0_mm = [0.15, -0.1];
    m.encoder_offset_rad = [0.002, -0.0015];
    m
}

fn nodes() -> Vec<[f64; 2]> {
    let mut v = Vec::new();
    for j in 0..31 {
        for i in 0..20 {
            v.push([165.0 + 5.0 * i as f64, -75.0 + 5.0 * j as f64]);
        }
    }
    v
}

/// Measures `truth` at `targets` commanded through `cal` (f32, the firmware path).
fn measure(truth: &FiveBar<f64>, cal: &Calibration<'_>, targets: &[[f64; 2]]) -> Vec<Measurement> {
    targets
        .iter()
        .enumerate()
        .map(|(k, &t)| {
            let th = cal.command_rad([t[0] as f32, t[1] as f32], 0.05).unwrap();
            let th = [th[0] as f64, th[1] as f64];
            Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: truth.forward(th, 0.0).unwrap(),
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: k + 2,
            }
        })
        .collect()
}

fn build(model: &FiveBar<f64>, data: &[Measurement]) -> Vec<u8> {
    let (lattice, rows) = detect_lattice(data, 5.0).unwrap();
    assert_eq!((lattice.nx, lattice.ny), (20, 31));
    let nodes = build_nodes(model, data, &lattice, &rows).unwrap();
    encode_image(model, &lattice, &nodes).unwrap()
}

/// Max error (µm) of the machine commanded through `cal` at random targets inside the grid.
fn max_error_um(truth: &FiveBar<f64>, cal: &Calibration<'_>) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    (0..300)
        .map(|_| {
            let t = [
                rng.random_range(165.0..260.0),
                rng.random_range(-75.0..75.0),
            ];
            let m = &measure(truth, cal, &[t])[0];
            (m.measured_mm[0] - t[0]).hypot(m.measured_mm[1] - t[1]) * 1e3
        })
        .fold(0.0, f64::max)
}

#[test]
fn commanding_through_the_grid_puts_the_tool_on_the_target() {
    let truth = machine();
    let model = FiveBar::<f64>::paper_nominal();
    let bare = Calibration {
        model: model.cast(),
        grid: None,
    };
    let before = max_error_um(&truth, &bare);
    assert!(before > 300.0, "{before}");
    let image = build(&model, &measure(&truth, &bare, &nodes()));
    let grid = CorrectionGrid::parse(&image).unwrap();
    let cal = Calibration {
        model: model.cast(),
        grid: Some(grid),
    };
    let after = max_error_um(&truth, &cal);
    // First order in a ~0.7 mm error: a wrong sign would double it instead.
    assert!(after < 5.0, "before {before} µm, after {after} µm");

    // Second round: re-measure the nodes through the grid and rebuild; the (θ_cmd − θ_ik) term
    // keeps the first round's correction, so at the nodes the residual drops to the second order.
    // Between the nodes what remains is the bilinear interpolation error of the correction field
    // (~1 µm in the corners for this 0.7 mm error field; it scales with the error, so a model fit
    // first makes it proportionally smaller).
    let image2 = build(&model, &measure(&truth, &cal, &nodes()));
    let cal2 = Calibration {
        model: model.cast(),
        grid: Some(CorrectionGrid::parse(&image2).unwrap()),
    };
    let at_nodes = |cal: &Calibration<'_>| {
        measure(&truth, cal, &nodes())
            .iter()
            .map(|m| {
                let t = m.target_mm.unwrap();
                (m.measured_mm[0] - t[0]).hypot(m.measured_mm[1] - t[1]) * 1e3
            })
            .fold(0.0, f64::max)
    };
    let (nodes1, nodes2) = (at_nodes(&cal), at_nodes(&cal2));
    assert!(
        nodes1 < 5.0 && nodes2 < 0.1,
        "at the nodes: round 1 {nodes1} µm, round 2 {nodes2} µm"
    );
    let after2 = max_error_um(&truth, &cal2);
    assert!(after2 < 1.5, "round 2 between nodes {after2} µm");
}

#[test]
fn lattice_errors_name_the_node_or_line() {
    let truth = machine();
    let model = FiveBar::<f64>::paper_nominal();
    let bare = Calibration {
        model: model.cast(),
        grid: None,
    };
    let data = measure(&truth, &bare, &nodes());
    let err = |d: &[Measurement], step: f64| format!("{:#}", detect_lattice(d, step).unwrap_err());

    let mut missing = data.clone();
    missing.remove(25);
    let e = err(&missing, 5.0);
    assert!(e.contains("node (5, 1) at (190, -70) is missing"), "{e}");

    let mut dup = data.clone();
    dup[30] = dup[29].clone();
    dup[30].line = 32;
    let e = err(&dup, 5.0);
    assert!(
        e.contains("line 32: node (9, 1)") && e.contains("measured twice (also line 31)"),
        "{e}"
    );

    let e = err(&data, 2.5);
    assert!(
        e.contains("step mismatch") && e.contains("5 mm apart along x"),
        "{e}"
    );

    let mut off = data.clone();
    off[3].target_mm = Some([180.5, -75.0]);
    let e = err(&off, 5.0);
    assert!(
        e.contains("line 5: target (180.5, -75) is not on the 5 mm lattice"),
        "{e}"
    );
}
