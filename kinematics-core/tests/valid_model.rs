//! The model checked once: `ValidFiveBar` cannot be built from an invalid model,
//! its IK gives exactly `FiveBar::inverse`'s answers (angles bit for bit, the same errors),
//! and the servo's checked-once path (`Servo::step` with a `ValidCalibration`, `step_motion_valid`) steps exactly
//! like the per-call one, while a plain `Calibration` with an invalid model is still refused
//! on every sample.

use kinematics_core::trajectory::{PathMotion, TaskLimits};
use kinematics_core::{
    Calibration, FiveBar, IkMargin, KinematicsError, ModelError, Real, Servo, ServoConfig,
    SetpointRefusal, StepError, ValidCalibration, ValidFiveBar, WorkingMode,
};
use proptest::prelude::*;

/// A calibrated-looking machine: unequal links, offset bases and encoders.
fn calibrated<T: Real>() -> FiveBar<T> {
    let c = T::from_f64;
    FiveBar {
        a_mm: c(149.868),
        b_mm: c(150.21),
        c_mm: c(149.74),
        d_mm: c(150.12),
        base_a0_mm: [c(-0.61), c(0.27)],
        base_b0_mm: [c(0.35), c(-0.8)],
        encoder_offset_rad: [c(0.004), c(-0.007)],
        mode: WorkingMode::PAPER,
    }
}

/// Every parameter made invalid in turn: the constructor refuses it with `validate`'s reason.
#[test]
fn an_invalid_model_cannot_be_checked() {
    let mut refused = 0;
    for field in 0..10 {
        for bad in [
            -150.0f32,
            0.0,
            -0.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ] {
            let mut m = calibrated::<f32>();
            match field {
                0 => m.a_mm = bad,
                1 => m.b_mm = bad,
                2 => m.c_mm = bad,
                3 => m.d_mm = bad,
                4..=5 => m.base_a0_mm[field - 4] = bad,
                6..=7 => m.base_b0_mm[field - 6] = bad,
                _ => m.encoder_offset_rad[field - 8] = bad,
            }
            let want = m.validate();
            if want.is_err() {
                assert_eq!(
                    ValidFiveBar::new(m).err(),
                    want.err(),
                    "field {field} = {bad}"
                );
                assert_eq!(
                    ValidCalibration::new(Calibration {
                        model: m,
                        grid: None
                    })
                    .err(),
                    want.err()
                );
                refused += 1;
            } else {
                assert_eq!(ValidFiveBar::new(m).map(|v| *v.model()), Ok(m));
            }
        }
    }
    // Links: six bad values each; bases and offsets: the three non-finite ones.
    assert_eq!(refused, 4 * 6 + 6 * 3);
    assert_eq!(
        ValidFiveBar::new(calibrated::<f64>()).map(|v| *v.model()),
        Ok(calibrated::<f64>())
    );
}

/// The margin's floor applied once: the IK's floor for 0, negative and tiny margins, the
/// margin itself above it, NaN kept (it refuses every pose).
#[test]
fn the_margin_is_raised_to_the_floor() {
    assert_eq!(IkMargin::new(0.0f32).get(), f32::IK_MIN_TRANSMISSION);
    assert_eq!(IkMargin::new(-1.0f64).get(), f64::IK_MIN_TRANSMISSION);
    assert_eq!(IkMargin::new(1e-9f32).get(), f32::IK_MIN_TRANSMISSION);
    assert_eq!(IkMargin::new(0.05f32).get(), 0.05);
    assert!(IkMargin::new(f32::NAN).get().is_nan());
    let v = ValidFiveBar::new(calibrated::<f32>()).unwrap();
    assert_eq!(
        v.inverse([212.0, 0.0], IkMargin::new(f32::NAN)),
        Err(KinematicsError::NearSingularity(
            kinematics_core::Singularity::Serial
        ))
    );
    assert_eq!(
        v.inverse([212.0, 0.0], IkMargin::new(f32::NAN)),
        calibrated::<f32>().inverse([212.0, 0.0], f32::NAN)
    );
}

fn bits<const N: usize>(v: [f32; N]) -> [u32; N] {
    v.map(f32::to_bits)
}

proptest! {
    /// The checked-once IK and rates agree with the per-call ones bit for bit, refusals
    /// included, over and beyond the workspace, at margins from below the floor to refusing.
    #[test]
    fn valid_ik_is_the_per_call_ik(
        x in -50.0f32..350.0,
        y in -200.0f32..200.0,
        vx in -3000.0f32..3000.0,
        vy in -3000.0f32..3000.0,
        margin in prop_oneof![Just(-1.0f32), Just(0.0), Just(0.05), Just(0.5), Just(f32::NAN), 0.0f32..0.99],
        paper in any::<bool>(),
    ) {
        let m = if paper { FiveBar::<f32>::paper_nominal() } else { calibrated::<f32>() };
        let v = ValidFiveBar::new(m).unwrap();
        let k = IkMargin::new(margin);
        prop_assert_eq!(v.inverse([x, y], k).map(bits), m.inverse([x, y], margin).map(bits));
        let rates = |r: Result<kinematics_core::JointMotion<f32>, KinematicsError>| r.map(|j| (bits(j.angle_rad), bits(j.velocity_rad_s)));
        prop_assert_eq!(rates(v.inverse_rates([x, y], [vx, vy], k)), rates(m.inverse_rates([x, y], [vx, vy], margin)));
        // f64 too (the host tools' type).
        let m64 = calibrated::<f64>();
        let v64 = ValidFiveBar::new(m64).unwrap();
        let p = [f64::from(x), f64::from(y)];
        prop_assert_eq!(
            v64.inverse(p, IkMargin::new(f64::from(margin))).map(|t| t.map(f64::to_bits)),
            m64.inverse(p, f64::from(margin)).map(|t| t.map(f64::to_bits))
        );
    }
}

/// Hostile targets: the same refusals as the per-call IK (the target's finiteness is still
/// tested on the public path).
#[test]
fn valid_ik_refuses_hostile_targets_like_the_per_call_ik() {
    let m = calibrated::<f32>();
    let v = ValidFiveBar::new(m).unwrap();
    for p in [
        [f32::NAN, 0.0],
        [0.0, f32::INFINITY],
        [f32::NEG_INFINITY, 1.0],
        [1e30, 1e30],
        [f32::MAX, 0.0],
        [0.0, 0.0],
        [-0.61, 0.27],
        [400.0, 0.0],
    ] {
        let got = v.inverse(p, IkMargin::new(0.05));
        assert!(got.is_err(), "{p:?}");
        assert_eq!(got, m.inverse(p, 0.05), "{p:?}");
    }
}

/// The servo through a `ValidCalibration` steps exactly like through the `Calibration` it
/// came from, along a 5 g move and back (position steps and motion steps), and refuses the
/// same hostile setpoints with the same reasons.
#[test]
fn the_servo_steps_the_same_through_a_valid_calibration() {
    let cal = Calibration {
        model: calibrated::<f32>(),
        grid: None,
    };
    let valid = ValidCalibration::new(cal).unwrap();
    let limits = TaskLimits {
        speed_mm_s: 1500.0,
        accel_mm_s2: 49_033.25,
        jerk_mm_s3: 5.0e6,
    };
    let line = PathMotion::line([180.0f32, -50.0], [250.0, 60.0], &limits).unwrap();
    for motion_step in [false, true] {
        let mut servo = Servo::new(ServoConfig::default()).unwrap();
        let start = line.at(0.0).position_mm;
        let mut angle = cal.command_rad(start, 0.05).unwrap();
        servo.engage(&cal, angle).unwrap();
        let mut twin = servo.clone();
        let samples = (line.duration_s() / 5e-4) as usize + 20;
        let mut compared = 0;
        for n in 0..samples {
            let s = line.at(n as f32 * 5e-4);
            let next = line.at((n + 1) as f32 * 5e-4);
            let (a, b) = if motion_step {
                (
                    servo.step_motion(&cal, &s, Some(&next), angle),
                    twin.step_motion(&valid, &s, Some(&next), angle),
                )
            } else {
                (
                    servo.step(&cal, s.position_mm, angle),
                    twin.step(&valid, s.position_mm, angle),
                )
            };
            let (a, b) = (a.unwrap(), b.unwrap());
            assert_eq!(bits(a.torque_nm), bits(b.torque_nm), "sample {n}");
            assert_eq!(bits(a.reference_rad), bits(b.reference_rad), "sample {n}");
            assert_eq!(
                bits(a.following_error_rad),
                bits(b.following_error_rad),
                "sample {n}"
            );
            // The encoders follow the reference (the servo is not the subject here).
            angle = a.reference_rad;
            compared += 1;
        }
        assert!(compared > 100);
        // Hostile setpoints: refused alike, and both servos stay engaged.
        let here = line.at(line.duration_s()).position_mm;
        for bad in [
            [f32::NAN, 0.0],
            [here[0], f32::INFINITY],
            [here[0] + 50.0, here[1]],
            [f32::MAX, f32::MAX],
        ] {
            let a = servo.step(&cal, bad, angle);
            let b = twin.step(&valid, bad, angle);
            assert!(matches!(a, Err(StepError::Refused(_))), "{bad:?}: {a:?}");
            assert_eq!(a, b, "{bad:?}");
        }
        assert_eq!(
            servo.step(&cal, [f32::NAN, 0.0], angle),
            Err(StepError::Refused(SetpointRefusal::NonFinite))
        );
        assert!(servo.is_engaged() && twin.is_engaged());
    }
}

/// A plain `Calibration` with an invalid model is still refused by the servo on every
/// sample (its IK checks the model), and cannot become a `ValidCalibration`.
#[test]
fn an_invalid_model_is_never_used_by_the_servo() {
    let good = Calibration {
        model: FiveBar::<f32>::paper_nominal(),
        grid: None,
    };
    let target = [212.132f32, 0.0];
    let angle = good.command_rad(target, 0.05).unwrap();
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    servo.engage(&good, angle).unwrap();
    let mut bad = good;
    bad.model.b_mm = -150.0;
    assert_eq!(
        ValidCalibration::new(bad).err(),
        Some(ModelError::NonPositiveLink)
    );
    assert_eq!(
        servo.step(&bad, target, angle),
        Err(StepError::Refused(SetpointRefusal::Kinematics(
            KinematicsError::InvalidModel(ModelError::NonPositiveLink)
        )))
    );
    assert!(servo.is_engaged());
}
