//! IK and FK never answer for a model that cannot be a machine, nor at an exact singularity,
//! whatever the margin: what `FiveBar::inverse_pose` documents. The cases: with margin 0, a
//! target at an exact parallel singularity (its angles would have no FK), and a = -150 mm (the
//! law of cosines squares the sign away: angles whose FK is another point).

use kinematics_core::{FiveBar, KinematicsError, ModelError, Singularity};

fn paper() -> FiveBar<f64> {
    FiveBar::paper_nominal()
}

/// Every sign flip and zero of each link is refused by IK and FK, with the model's reason;
/// a NaN link too.
#[test]
fn ik_and_fk_refuse_a_model_whose_links_are_not_positive() {
    let target = [212.132, 0.0];
    let angles = paper().inverse(target, 0.05).unwrap();
    let mut refused = 0;
    for link in 0..4 {
        for bad in [-150.0, 0.0, -0.0, f64::NAN] {
            let mut m = paper();
            *[&mut m.a_mm, &mut m.b_mm, &mut m.c_mm, &mut m.d_mm][link] = bad;
            let want = if bad.is_nan() {
                ModelError::NonFinite
            } else {
                ModelError::NonPositiveLink
            };
            assert_eq!(
                m.inverse(target, 0.0),
                Err(KinematicsError::InvalidModel(want)),
                "link {link} = {bad}"
            );
            assert!(matches!(
                m.inverse_pose(target, 0.0),
                Err(KinematicsError::InvalidModel(_))
            ));
            assert_eq!(
                m.forward(angles, 0.0),
                Err(KinematicsError::InvalidModel(want)),
                "link {link} = {bad}"
            );
            assert!(matches!(
                m.forward_pose(angles, 0.0),
                Err(KinematicsError::InvalidModel(_))
            ));
            refused += 1;
        }
    }
    assert_eq!(refused, 16);
    // f32 too (the MCU's path).
    let mut m = FiveBar::<f32>::paper_nominal();
    m.a_mm = -150.0;
    assert_eq!(
        m.inverse([212.132, 0.0], 0.0),
        Err(KinematicsError::InvalidModel(ModelError::NonPositiveLink))
    );
}

/// With margin 0 every pose the IK accepts has an FK (margin 0 too) that returns the target:
/// scanned finely along lines through the parallel singularities of the paper machine (on
/// the x axis its distal links become collinear) and across full reach, where each arm is
/// stretched (serial). Before, near-singular poses were accepted whose FK failed.
#[test]
fn margin_zero_never_accepts_a_pose_fk_cannot_return() {
    for (name, m) in [("f64", paper())] {
        let mut accepted = 0;
        let mut refused_singular = 0;
        for i in 0..=60_000 {
            let x = 0.005 * i as f64;
            for y in [0.0, 1e-9, -1e-9, 1e-4, 37.5] {
                match m.inverse([x, y], 0.0) {
                    Ok(th) => {
                        let back = m.forward(th, 0.0).unwrap_or_else(|e| {
                            panic!("{name} ({x}, {y}): FK of an accepted IK: {e}")
                        });
                        let err = ((back[0] - x).powi(2) + (back[1] - y).powi(2)).sqrt();
                        assert!(err < 1e-6, "{name} ({x}, {y}): FK(IK) off by {err} mm");
                        accepted += 1;
                    }
                    Err(KinematicsError::NearSingularity(_)) => refused_singular += 1,
                    Err(_) => {}
                }
            }
        }
        assert!(accepted > 100_000, "{name}: {accepted} accepted");
        assert!(
            refused_singular >= 3,
            "{name}: the scan must meet singularities ({refused_singular})"
        );
    }
    // f32, the MCU's type: FK of every pose the IK accepts with margin 0 succeeds; near its
    // floor (a transmission of 4.9e-3) f32 rounding is amplified, so the round trip there is
    // good to the figure printed, not to 0.1 µm (the servo's margin keeps far away;
    // tests/round_trip.rs bounds the workspace to 0.1 µm).
    let m = FiveBar::<f32>::paper_nominal();
    let mut accepted = 0;
    let mut worst = 0.0f32;
    for i in 0..=60_000 {
        let x = 0.005 * i as f32;
        for y in [0.0f32, 1e-6, -1e-6, 0.01, 37.5] {
            if let Ok(th) = m.inverse([x, y], 0.0) {
                let back = m
                    .forward(th, 0.0)
                    .unwrap_or_else(|e| panic!("f32 ({x}, {y}): FK of an accepted IK: {e}"));
                let err = ((back[0] - x).powi(2) + (back[1] - y).powi(2)).sqrt();
                worst = worst.max(err);
                accepted += 1;
            }
        }
    }
    assert!(accepted > 100_000, "f32: {accepted} accepted");
    println!("f32 worst FK(IK) error at margin 0: {worst} mm");
    assert!(worst < 0.02, "f32 worst FK(IK) error {worst} mm");
}

/// A negative margin acts as 0, a NaN margin refuses every pose (it compares false), for IK
/// and FK alike.
#[test]
fn margin_semantics() {
    let m = paper();
    let target = [212.132, 0.0];
    assert_eq!(m.inverse(target, -1.0), m.inverse(target, 0.0));
    assert!(m.inverse(target, 0.0).is_ok());
    assert!(m.inverse(target, f64::NAN).is_err());
    let th = m.inverse(target, 0.0).unwrap();
    assert_eq!(m.forward(th, -1.0), m.forward(th, 0.0));
    assert!(m.forward(th, f64::NAN).is_err());
    // Exactly at full reach (|C| = a + b): both arms stretched, refused with margin 0.
    assert_eq!(
        m.inverse([300.0, 0.0], 0.0),
        Err(KinematicsError::NearSingularity(Singularity::Serial))
    );
}
