//! Inverse then forward kinematics returns the target, over the paper's whole workspace, in
//! both precisions: f64 within 1 nm, f32 (the MCU's path) within 0.1 µm; and the f32 IK and
//! FK each on their own against f64, as a distance at the tool.

use kinematics_core::{Branch, FiveBar, Real, WorkingMode};

/// The paper's workspace: x in [162.132, 262.132] mm, y in [-75, 75] mm.
const X_RANGE_MM: (f64, f64) = (162.132, 262.132);
const Y_RANGE_MM: (f64, f64) = (-75.0, 75.0);

/// Dense grid over the workspace, 0.5 mm spacing (60 501 points).
fn workspace_points() -> impl Iterator<Item = [f64; 2]> {
    let nx = 201;
    let ny = 301;
    (0..ny).flat_map(move |j| {
        (0..nx).map(move |i| {
            [
                X_RANGE_MM.0 + (X_RANGE_MM.1 - X_RANGE_MM.0) * i as f64 / (nx - 1) as f64,
                Y_RANGE_MM.0 + (Y_RANGE_MM.1 - Y_RANGE_MM.0) * j as f64 / (ny - 1) as f64,
            ]
        })
    })
}

/// Worst `|FK(IK(p)) - p|` (mm) over the workspace for a model in precision `T`.
fn worst_round_trip<T: Real>(model: &FiveBar<T>) -> f64 {
    let mut worst: f64 = 0.0;
    for p in workspace_points() {
        let pt = [T::from_f64(p[0]), T::from_f64(p[1])];
        let theta = model
            .inverse(pt, T::ZERO)
            .unwrap_or_else(|e| panic!("IK failed at {p:?}: {e}"));
        let back = model
            .forward(theta, T::ZERO)
            .unwrap_or_else(|e| panic!("FK failed at {p:?}: {e}"));
        // Compare with the target as represented in T (the f32 input is already rounded).
        let err = (back[0].to_f64() - pt[0].to_f64()).hypot(back[1].to_f64() - pt[1].to_f64());
        worst = worst.max(err);
    }
    worst
}

#[test]
fn f64_round_trip_within_1_nm() {
    let worst_mm = worst_round_trip(&FiveBar::<f64>::paper_nominal());
    println!("f64 worst round trip: {:.3e} nm", worst_mm * 1e6);
    assert!(worst_mm < 1e-6, "worst {worst_mm} mm");
}

#[test]
fn f32_round_trip_within_100_nm() {
    let worst_mm = worst_round_trip(&FiveBar::<f32>::paper_nominal());
    println!("f32 worst round trip: {:.1} nm", worst_mm * 1e6);
    assert!(worst_mm < 1e-4, "worst {worst_mm} mm");
}

/// A calibrated-looking machine: unequal links, base offset, encoder offsets.
fn irregular() -> FiveBar<f64> {
    FiveBar {
        a_mm: 149.868,
        b_mm: 150.21,
        c_mm: 149.74,
        d_mm: 150.12,
        base_a0_mm: [-0.6, 0.25],
        base_b0_mm: [0.35, -0.8],
        encoder_offset_rad: [0.004, -0.007],
        mode: WorkingMode::PAPER,
    }
}

#[test]
fn round_trip_on_irregular_machine_both_precisions() {
    let m = irregular();
    assert!(worst_round_trip(&m) < 1e-6);
    assert!(worst_round_trip(&m.cast::<f32>()) < 1e-4);
}

#[test]
fn forward_then_inverse_returns_the_angles() {
    let m = irregular();
    for p in workspace_points().step_by(97) {
        let theta = m.inverse(p, 0.0).unwrap();
        let back = m.inverse(m.forward(theta, 0.0).unwrap(), 0.0).unwrap();
        for k in 0..2 {
            assert!(
                (back[k] - theta[k]).abs() < 1e-11,
                "{p:?}: {theta:?} vs {back:?}"
            );
        }
    }
}

#[test]
fn every_working_mode_round_trips_where_it_is_assembled() {
    // For each of the 8 modes, take motor angles, solve FK in that mode, and check that IK in
    // the same mode gives the angles back whenever the elbows of the FK solution match it.
    let branches = [Branch::Positive, Branch::Negative];
    let mut checked = 0;
    for e1 in branches {
        for e2 in branches {
            for asm in branches {
                let mut m = irregular();
                m.mode = WorkingMode {
                    elbow_1: e1,
                    elbow_2: e2,
                    assembly: asm,
                };
                for k in 0..400 {
                    let th = [-3.0 + 0.015 * k as f64, 2.5 - 0.011 * k as f64];
                    let Ok(pose) = m.forward_pose(th, 0.05) else {
                        continue;
                    };
                    let Ok(back) = m.inverse(pose.tool_mm, 0.0) else {
                        continue;
                    };
                    let same = (0..2)
                        .all(|i| kinematics_core::wrap_angle_rad(back[i] - th[i]).abs() < 1e-9);
                    // IK in this mode must either reproduce the angles or give the other elbow.
                    if same {
                        checked += 1;
                    }
                }
            }
        }
    }
    assert!(checked > 200, "only {checked} round trips found");
}

fn widen(v: [f32; 2]) -> [f64; 2] {
    [f64::from(v[0]), f64::from(v[1])]
}

/// Worst errors (µm at the tool) of the f32 IK and of the f32 FK on their own, against f64:
/// the f32 angles for each f32 target put through the f64 FK (how far from the target the
/// MCU's angles really put the tool), and the f32 FK of those angles against the f64 FK.
fn worst_f32_ik_and_fk_um(m: &FiveBar<f64>) -> (f64, f64) {
    let m32 = m.cast::<f32>();
    // The f64 model of exactly the f32 numbers, so that only the arithmetic differs.
    let m64 = m32.cast::<f64>();
    let (mut ik, mut fk) = (0.0f64, 0.0f64);
    for p in workspace_points() {
        let p = [p[0] as f32, p[1] as f32];
        let theta = m32
            .inverse(p, 0.0)
            .unwrap_or_else(|e| panic!("f32 IK at {p:?}: {e}"));
        let reached = m64.forward(widen(theta), 0.0).expect("f64 FK");
        ik = ik.max((reached[0] - f64::from(p[0])).hypot(reached[1] - f64::from(p[1])) * 1e3);
        let fk32 = widen(
            m32.forward(theta, 0.0)
                .unwrap_or_else(|e| panic!("f32 FK at {p:?}: {e}")),
        );
        fk = fk.max((fk32[0] - reached[0]).hypot(fk32[1] - reached[1]) * 1e3);
    }
    (ik, fk)
}

#[test]
fn f32_ik_and_fk_each_within_0_1_um() {
    for (name, m) in [
        ("paper nominal", FiveBar::<f64>::paper_nominal()),
        ("irregular", irregular()),
    ] {
        let (ik, fk) = worst_f32_ik_and_fk_um(&m);
        println!(
            "{name}: f32 IK worst {ik:.4} um, f32 FK worst {fk:.4} um (at the tool, against f64)"
        );
        assert!(ik < 0.1 && fk < 0.1, "{name}: IK {ik} um, FK {fk} um");
    }
}
