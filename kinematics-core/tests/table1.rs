//! The paper's Table I: its desired positions through our IK give its printed motor angles.

use kinematics_core::{wrap_angle_rad, FiveBar};

/// (θ1°, θ2°, x desired, y desired) of Table I; the printed angles have 3 decimals.
const TABLE_I: [(f64, f64, f64, f64); 9] = [
    (45.0, -45.0, 212.132, 0.0),
    (60.881, -21.938, 212.132, 75.0),
    (40.622, -8.689, 262.132, 75.0),
    (29.100, -29.100, 262.132, 0.0),
    (368.689, 319.378, 262.132, -75.0),
    (381.938, 299.119, 212.132, -75.0),
    (388.630, 281.721, 162.132, -75.0),
    (57.286, -57.286, 162.132, 0.0),
    (78.279, -28.630, 162.132, 75.0),
];

#[test]
fn table_i_desired_positions_give_the_printed_angles() {
    let m = FiveBar::<f64>::paper_nominal();
    for (i, &(t1, t2, x, y)) in TABLE_I.iter().enumerate() {
        let th = m.inverse([x, y], 0.0).unwrap();
        for (got, want) in th.iter().zip([t1, t2]) {
            let diff = wrap_angle_rad(got - want.to_radians()).to_degrees();
            // Printed to 0.001°: agree within half the last digit.
            assert!(
                diff.abs() <= 0.0005 + 1e-9,
                "point {}: got {} want {}",
                i + 1,
                got.to_degrees(),
                want
            );
        }
    }
}
