//! The f32 IK and FK each on their own against f64, over the paper's workspace, as a distance
//! at the tool (the figures of the README's cycle-budget table; `round_trip.rs` measures the
//! two chained).
//!
//! * IK: the f32 angles for an f32 target, put through the f64 FK: how far from the target
//!   the MCU's angles really put the tool.
//! * FK: the f32 tool point for f32 angles against the f64 FK of the same angles.

use kinematics_core::{FiveBar, WorkingMode};

/// 0.5 mm grid over x in [162.132, 262.132] mm, y in [-75, 75] mm, as f32 targets.
fn workspace_f32() -> impl Iterator<Item = [f32; 2]> {
    (0..301).flat_map(|j| (0..201).map(move |i| [(162.132 + 0.5 * i as f64) as f32, (-75.0 + 0.5 * j as f64) as f32]))
}

fn dist_um(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1]) * 1e3
}

fn widen(v: [f32; 2]) -> [f64; 2] {
    [f64::from(v[0]), f64::from(v[1])]
}

/// Worst IK and FK errors (µm) of a machine.
fn worst_um(m64: &FiveBar<f64>) -> (f64, f64) {
    let m32 = m64.cast::<f32>();
    // The f64 model of exactly the f32 numbers, so that only the arithmetic differs.
    let m64 = m32.cast::<f64>();
    let (mut ik, mut fk) = (0.0f64, 0.0f64);
    for p in workspace_f32() {
        let theta32 = m32.inverse(p, 0.0).unwrap_or_else(|e| panic!("f32 IK at {p:?}: {e}"));
        let reached = m64.forward(widen(theta32), 0.0).expect("f64 FK");
        ik = ik.max(dist_um(reached, widen(p)));
        let fk32 = m32.forward(theta32, 0.0).unwrap_or_else(|e| panic!("f32 FK at {p:?}: {e}"));
        fk = fk.max(dist_um(widen(fk32), reached));
    }
    (ik, fk)
}

#[test]
fn f32_ik_and_fk_each_within_0_1_um() {
    let irregular = FiveBar {
        a_mm: 149.868,
        b_mm: 150.21,
        c_mm: 149.74,
        d_mm: 150.12,
        base_a0_mm: [-0.6, 0.25],
        base_b0_mm: [0.35, -0.8],
        encoder_offset_rad: [0.004, -0.007],
        mode: WorkingMode::PAPER,
    };
    for (name, m) in [("paper nominal", FiveBar::<f64>::paper_nominal()), ("irregular", irregular)] {
        let (ik, fk) = worst_um(&m);
        println!("{name}: f32 IK worst {ik:.4} um, f32 FK worst {fk:.4} um (at the tool, against f64)");
        assert!(ik < 0.1 && fk < 0.1, "{name}: IK {ik} um, FK {fk} um");
    }
}
