//! Property tests: no input, however hostile, makes the core panic or return a NaN.

use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
use kinematics_core::{Branch, Calibration, FiveBar, Servo, ServoConfig, WorkingMode};
use proptest::prelude::*;

/// Any f64, with the special values well represented.
fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -400.0..400.0f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(0.0),
        1 => Just(-0.0),
        1 => Just(f64::MAX),
        1 => Just(f64::MIN_POSITIVE),
        1 => Just(1e-300),
        1 => any::<f64>(),
    ]
}

fn branch() -> impl Strategy<Value = Branch> {
    prop_oneof![Just(Branch::Positive), Just(Branch::Negative)]
}

/// Machines from plausible to absurd.
fn machine() -> impl Strategy<Value = FiveBar<f64>> {
    let link = || prop_oneof![3 => 50.0..300.0f64, 1 => any_f64()];
    machine_with(link(), link(), link(), link())
}

/// Valid machines of any proportions.
fn valid_machine() -> impl Strategy<Value = FiveBar<f64>> {
    machine_with(50.0..300.0f64, 50.0..300.0f64, 50.0..300.0f64, 50.0..300.0f64)
}

fn machine_with(
    a: impl Strategy<Value = f64>,
    b: impl Strategy<Value = f64>,
    c: impl Strategy<Value = f64>,
    d: impl Strategy<Value = f64>,
) -> impl Strategy<Value = FiveBar<f64>> {
    (
        a,
        b,
        c,
        d,
        (-20.0..20.0f64, -20.0..20.0f64, -5.0..5.0f64, -5.0..5.0f64),
        (-0.5..0.5f64, -0.5..0.5f64),
        (branch(), branch(), branch()),
    )
        .prop_map(|(a, b, c, d, base, off, (e1, e2, asm))| FiveBar {
            a_mm: a,
            b_mm: b,
            c_mm: c,
            d_mm: d,
            base_a0_mm: [base.2, base.3],
            base_b0_mm: [base.0, base.1],
            encoder_offset_rad: [off.0, off.1],
            mode: WorkingMode { elbow_1: e1, elbow_2: e2, assembly: asm },
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]

    #[test]
    fn inverse_never_panics_nor_returns_nan(m in machine(), x in any_f64(), y in any_f64(), margin in any_f64()) {
        for mm in [m, m.cast::<f32>().cast::<f64>()] {
            if let Ok(pose) = mm.inverse_pose([x, y], margin) {
                prop_assert!(pose.theta_rad.iter().chain(pose.tool_mm.iter()).all(|v| v.is_finite()));
                if let Ok(j) = pose.inverse_jacobian() { prop_assert!(j.iter().flatten().all(|v| v.is_finite())); }
                if let Ok(j) = pose.jacobian() { prop_assert!(j.iter().flatten().all(|v| v.is_finite())); }
            }
        }
        let m32 = m.cast::<f32>();
        if let Ok(t) = m32.inverse([x as f32, y as f32], margin as f32) {
            prop_assert!(t.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn forward_never_panics_nor_returns_nan(m in machine(), t1 in any_f64(), t2 in any_f64(), margin in any_f64()) {
        if let Ok(p) = m.forward([t1, t2], margin) {
            prop_assert!(p.iter().all(|v| v.is_finite()));
        }
        if let Ok(p) = m.cast::<f32>().forward([t1 as f32, t2 as f32], margin as f32) {
            prop_assert!(p.iter().all(|v| v.is_finite()));
        }
    }

    /// Reachable targets of valid machines round-trip (random machines, not just the paper's).
    #[test]
    fn valid_machines_round_trip(m in valid_machine(), x in 100.0..300.0f64, y in -100.0..100.0f64) {
        if let Ok(theta) = m.inverse([x, y], 0.05) {
            let back = m.forward(theta, 0.0);
            prop_assert!(back.is_ok(), "{:?}", back);
            let back = back.unwrap();
            prop_assert!((back[0] - x).abs() < 1e-8 && (back[1] - y).abs() < 1e-8, "{:?} vs {:?}", back, [x, y]);
        }
    }

    #[test]
    fn grid_parse_never_panics_on_garbage(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = CorrectionGrid::parse(&bytes);
    }

    #[test]
    fn servo_never_panics_nor_commands_nan(
        steps in proptest::collection::vec((any_f64(), any_f64(), any_f64(), any_f64()), 1..40),
        start in (-3.0..3.0f64, -3.0..3.0f64),
    ) {
        let g = GridGeometry { nx: 3, ny: 3, x0_mm: 160.0, y0_mm: -80.0, step_x_mm: 50.0, step_y_mm: 80.0 };
        let mut img = vec![0u8; g.image_len()];
        encode(&mut img, &g, &FiveBar::paper_nominal(), &[[1e-4, -1e-4]; 9]).unwrap();
        let grid = CorrectionGrid::parse(&img).unwrap();
        for cal in [Calibration { model: FiveBar::paper_nominal(), grid: None }, Calibration::from_grid(grid)] {
            let mut servo = Servo::new(ServoConfig::default());
            let _ = servo.engage(&cal, [start.0 as f32, start.1 as f32]);
            for &(x, y, e1, e2) in &steps {
                match servo.step(&cal, [x as f32, y as f32], [e1 as f32, e2 as f32]) {
                    Ok(out) => {
                        for k in 0..2 {
                            let t = out.torque_nm[k];
                            prop_assert!(t.is_finite() && t.abs() <= servo.config().axes[k].torque_limit_nm);
                        }
                    }
                    // Every refusal is latched and reported as the latched fault.
                    Err(e) => prop_assert_eq!(servo.fault(), Some(e)),
                }
            }
        }
    }
}
