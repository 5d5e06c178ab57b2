//! The Jacobian and its inverse against central finite differences of FK and IK, on machines
//! with unequal links, a base offset and encoder offsets; and the paper's Eq. 8 (corrected).

use kinematics_core::jacobian::mat2_mul_vec;
use kinematics_core::{FiveBar, WorkingMode};

fn machines() -> Vec<FiveBar<f64>> {
    vec![
        FiveBar::paper_nominal(),
        FiveBar {
            a_mm: 120.0,
            b_mm: 170.0,
            c_mm: 160.0,
            d_mm: 135.0,
            base_a0_mm: [3.0, 4.0],
            base_b0_mm: [12.0, -30.0],
            encoder_offset_rad: [0.2, -0.3],
            mode: WorkingMode::PAPER,
        },
        FiveBar {
            a_mm: 149.9,
            b_mm: 150.2,
            c_mm: 149.7,
            d_mm: 150.05,
            base_a0_mm: [0.0; 2],
            base_b0_mm: [0.4, 0.9],
            encoder_offset_rad: [-0.01, 0.02],
            mode: WorkingMode::PAPER,
        },
    ]
}

const POINTS_MM: [[f64; 2]; 6] = [
    [212.132, 0.0],
    [170.0, 60.0],
    [250.0, -70.0],
    [190.0, -40.0],
    [230.0, 30.0],
    [175.0, 0.0],
];

#[test]
fn jacobian_matches_finite_differences_of_fk() {
    let h = 1e-6;
    let mut checked = 0;
    for m in machines() {
        for p in POINTS_MM {
            let Ok(pose) = m.inverse_pose(p, 0.05) else {
                continue;
            };
            checked += 1;
            let j = pose.jacobian().unwrap();
            for col in 0..2 {
                let mut tp = pose.theta_rad;
                let mut tm = pose.theta_rad;
                tp[col] += h;
                tm[col] -= h;
                let fp = m.forward(tp, 0.0).unwrap();
                let fm = m.forward(tm, 0.0).unwrap();
                for row in 0..2 {
                    let fd = (fp[row] - fm[row]) / (2.0 * h);
                    assert!(
                        (j[row][col] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                        "{m:?} {p:?} J[{row}][{col}] {} vs fd {fd}",
                        j[row][col]
                    );
                }
            }
        }
    }
    // Every machine and point above is reachable with margin: a pose refused here would skip
    // the check silently.
    assert_eq!(
        checked,
        machines().len() * POINTS_MM.len(),
        "only {checked} poses checked"
    );
}

#[test]
fn inverse_jacobian_matches_finite_differences_of_ik_and_inverts_j() {
    let h = 1e-6;
    let mut checked = 0;
    for m in machines() {
        for p in POINTS_MM {
            let Ok(pose) = m.inverse_pose(p, 0.05) else {
                continue;
            };
            checked += 1;
            let ji = pose.inverse_jacobian().unwrap();
            for col in 0..2 {
                let mut pp = p;
                let mut pm = p;
                pp[col] += h;
                pm[col] -= h;
                let tp = m.inverse(pp, 0.0).unwrap();
                let tm = m.inverse(pm, 0.0).unwrap();
                for row in 0..2 {
                    let fd = (tp[row] - tm[row]) / (2.0 * h);
                    assert!(
                        (ji[row][col] - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                        "J⁻¹[{row}][{col}] {} vs {fd}",
                        ji[row][col]
                    );
                }
            }
            let j = pose.jacobian().unwrap();
            let v = [0.3, -1.7];
            let back = mat2_mul_vec(&j, mat2_mul_vec(&ji, v));
            assert!((back[0] - v[0]).abs() < 1e-12 && (back[1] - v[1]).abs() < 1e-12);
        }
    }
    // Every machine and point above is reachable with margin: a pose refused here would skip
    // the check silently.
    assert_eq!(
        checked,
        machines().len() * POINTS_MM.len(),
        "only {checked} poses checked"
    );
}

/// Eq. 8 with the proximal links in the denominators:
/// δθ1 = -(cos θ3 δx + sin θ3 δy) / (a sin(θ1 - θ3)), δθ2 likewise with θ4 and d.
/// With the printed `b` and `e` it would fail on a machine with a ≠ b.
#[test]
fn corrected_eq8_equals_the_inverse_jacobian() {
    let mut checked = 0;
    for m in machines() {
        for p in POINTS_MM {
            let Ok(pose) = m.inverse_pose(p, 0.05) else {
                continue;
            };
            checked += 1;
            let ji = pose.inverse_jacobian().unwrap();
            let th1 = pose.theta_rad[0] + m.encoder_offset_rad[0];
            let th2 = pose.theta_rad[1] + m.encoder_offset_rad[1];
            let th3 =
                (pose.tool_mm[1] - pose.elbow_a_mm[1]).atan2(pose.tool_mm[0] - pose.elbow_a_mm[0]);
            let th4 =
                (pose.tool_mm[1] - pose.elbow_b_mm[1]).atan2(pose.tool_mm[0] - pose.elbow_b_mm[0]);
            let d = [0.013, -0.021];
            let eq8 = [
                -(th3.cos() * d[0] + th3.sin() * d[1]) / (m.a_mm * (th1 - th3).sin()),
                -(th4.cos() * d[0] + th4.sin() * d[1]) / (m.d_mm * (th2 - th4).sin()),
            ];
            let ours = mat2_mul_vec(&ji, d);
            for k in 0..2 {
                assert!((eq8[k] - ours[k]).abs() < 1e-13, "{eq8:?} vs {ours:?}");
            }
            if m.a_mm != m.b_mm {
                let printed = -(th3.cos() * d[0] + th3.sin() * d[1]) / (m.b_mm * (th1 - th3).sin());
                assert!(
                    (printed - ours[0]).abs() > 1e-9,
                    "the printed Eq. 8 should differ"
                );
            }
        }
    }
    // Every machine and point above is reachable with margin: a pose refused here would skip
    // the check silently.
    assert_eq!(
        checked,
        machines().len() * POINTS_MM.len(),
        "only {checked} poses checked"
    );
}
