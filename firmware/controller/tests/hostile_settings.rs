//! No settings value makes the controller panic or move a machine it should not (
//! "no panic for any settings value"): the settings are meant to come over a host link, so
//! every float of them (servo gains and limits, drive scale, trajectory, stop, encoder
//! limits, encoder gear ratios) is drawn from hostile values (NaN, ±∞, negative, zero,
//! subnormal, 1e38, any bit pattern) a few at a time, and the counters and an encoder's
//! resolution from the whole `u32` range. For each draw the loop boots and runs 300 samples on
//! a crude plant, fed a short motion and now and then a hostile encoder reading. Whatever
//! happens:
//! * nothing panics;
//! * settings that `Settings::validate` refuses leave the loop in its safe state from boot,
//!   with the drives never enabled and zero torque in every sample;
//! * every torque is finite and, for valid settings, within the largest axis torque limit.

use controller::calibration::CalibrationState;
use controller::servo_loop::{Mode, ServoLoop};
use controller::setpoints::QUEUE_SLOTS;
use controller::settings::Settings;
use heapless::spsc::Queue;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, FiveBar};
use proptest::prelude::*;

/// Every float field of the settings, by a mutable reference: what a hostile link can set.
fn floats(s: &mut Settings) -> Vec<&mut f32> {
    let Settings {
        servo,
        drive_full_scale_nm,
        encoders,
        trajectory_accel_mm_s2,
        trajectory_speed_mm_s,
        trajectory_jerk_mm_s3,
        trajectory_dwell_s,
        stop,
        encoder_limits,
        ..
    } = s;
    let mut v: Vec<&mut f32> = vec![
        &mut servo.sample_period_s,
        &mut servo.min_transmission,
        &mut servo.max_speed_mm_s,
        &mut servo.max_accel_mm_s2,
        &mut servo.max_following_error_rad,
        drive_full_scale_nm,
        trajectory_accel_mm_s2,
        trajectory_speed_mm_s,
        trajectory_jerk_mm_s3,
        trajectory_dwell_s,
        &mut stop.limits.decel_mm_s2,
        &mut stop.limits.jerk_mm_s3,
        &mut stop.workspace_margin_mm,
        &mut stop.standstill_rad_s,
        &mut stop.settle_timeout_s,
        &mut encoder_limits.max_speed_rad_s,
        &mut encoder_limits.max_accel_rad_s2,
        &mut encoder_limits.hold_torque_nm,
        &mut encoder_limits.max_inertia_kg_m2,
        &mut encoder_limits.max_coupling_inertia_kg_m2,
        &mut encoder_limits.max_velocity_product_kg_m2,
        &mut encoder_limits.stuck_motion_rad,
    ];
    for axis in servo.axes.iter_mut() {
        v.extend([
            &mut axis.kp_nm_per_rad,
            &mut axis.ki_nm_per_rad_s,
            &mut axis.kd_nm_s_per_rad,
            &mut axis.inertia_ff_kg_m2,
            &mut axis.viscous_ff_nm_s_per_rad,
            &mut axis.coulomb_ff_nm,
            &mut axis.coulomb_ff_speed_rad_s,
            &mut axis.torque_limit_nm,
            &mut axis.integral_limit_nm,
            &mut axis.observer_bandwidth_rad_s,
            &mut axis.observer_inertia_kg_m2,
        ]);
    }
    for e in encoders.iter_mut() {
        v.push(&mut e.gear_ratio);
    }
    v
}

fn hostile_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(0.0f32),
        Just(-0.0f32),
        Just(f32::MIN_POSITIVE / 4.0),
        Just(1e38f32),
        Just(-1.0f32),
        -1e6f32..1e6,
        any::<f32>(),
    ]
}

/// Which float fields to replace and with what; the two counters and axis 0's encoder
/// resolution (or their defaults).
type Draw = (Vec<(usize, f32)>, Option<u32>, Option<u32>, Option<u32>);

fn hostile_settings() -> impl Strategy<Value = Draw> {
    (
        proptest::collection::vec((0usize..64, hostile_f32()), 0..5),
        proptest::option::of(any::<u32>()),
        proptest::option::of(any::<u32>()),
        proptest::option::of(any::<u32>()),
    )
}

fn build(draw: &Draw) -> Settings {
    let mut s = Settings {
        builtin_tour_mm: &[],
        ..Settings::default()
    };
    // Absolute encoders, so that valid settings engage at boot and the servo runs: with the
    // default incremental ones every draw would boot `Unhomed`, drives off, and the torque
    // checks below would hold trivially.
    s.homing.absolute_encoders = true;
    {
        let mut f = floats(&mut s);
        let n = f.len();
        for &(i, v) in &draw.0 {
            *f[i % n] = v;
        }
    }
    if let Some(v) = draw.1 {
        s.overrun_streak_limit = v;
    }
    if let Some(v) = draw.2 {
        s.telemetry_period_ticks = v;
    }
    if let Some(v) = draw.3 {
        s.encoders[0].counts_per_rev = v;
    }
    s
}

/// Draws per run: 3000, or `HOSTILE_CASES`.
fn hostile_cases() -> u32 {
    std::env::var("HOSTILE_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(3000)
}

proptest! {
    // 3000 draws in CI; `HOSTILE_CASES=N` for a longer fuzz run (release profile advised).
    #![proptest_config(ProptestConfig { cases: hostile_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn hostile_settings_never_panic_nor_drive_a_refused_configuration(
        draw in hostile_settings(),
        glitches in proptest::collection::vec((0usize..300, hostile_f32()), 0..3),
    ) {
        let settings = build(&draw);
        let valid = settings.validate().is_ok();
        let model = FiveBar::<f32>::paper_nominal();
        let cal = Calibration { model, grid: None };
        let start = model.inverse([212.132, 0.0], 0.05).unwrap();
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, start);
        if !valid {
            prop_assert!(matches!(l.mode(), Mode::SafeState(_)), "refused settings booted into {:?}", l.mode());
        }
        let limit = settings.servo.axes.iter().map(|g| g.torque_limit_nm).fold(0.0f32, f32::max);
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let (mut angle, mut speed) = (start, [0.0f32; 2]);
        let mut enabled_ever = l.drives_enabled();
        for k in 0..300 {
            // A slow 1 mm move along x, then rest.
            let x = 212.132 + (k.min(200) as f32) * 0.005;
            let _ = tx.enqueue(MotionSetpoint::at_rest([x, 0.0]));
            let mut reading = angle;
            for &(at, v) in &glitches {
                if at == k {
                    reading[k % 2] = v;
                }
            }
            let s = l.step(&mut rx, reading);
            enabled_ever |= l.drives_enabled();
            for (t, (a, w)) in s.torque_nm.iter().zip(angle.iter_mut().zip(speed.iter_mut())) {
                prop_assert!(t.is_finite(), "sample {}: torque {}", k, t);
                if valid {
                    prop_assert!(t.abs() <= limit * (1.0 + 1e-6), "sample {}: torque {} beyond {}", k, t, limit);
                } else {
                    prop_assert_eq!(*t, 0.0, "sample {}: torque from refused settings", k);
                }
                // A crude joint: 3e-3 kg m², 0.5 ms.
                *w += t / 3e-3 * 5e-4;
                *a += *w * 5e-4;
            }
        }
        if !valid {
            prop_assert!(!enabled_ever, "refused settings enabled the drives");
        }
    }
}

/// The draws reach both outcomes: a test whose every case were refused (or accepted) would
/// not test what it says.
#[test]
fn the_draws_reach_valid_and_refused_settings() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    let mut runner = TestRunner::deterministic();
    let (mut valid, mut refused, mut engaged) = (0, 0, 0);
    let model = FiveBar::<f32>::paper_nominal();
    let start = model.inverse([212.132, 0.0], 0.05).unwrap();
    for _ in 0..2000 {
        let draw = hostile_settings().new_tree(&mut runner).unwrap().current();
        let settings = build(&draw);
        if settings.validate().is_ok() {
            valid += 1;
            let l = ServoLoop::boot(
                &settings,
                Calibration { model, grid: None },
                CalibrationState::Valid,
                start,
            );
            engaged += usize::from(l.mode() == Mode::Running && l.drives_enabled());
        } else {
            refused += 1;
        }
    }
    assert!(
        valid >= 100 && refused >= 100,
        "{valid} valid, {refused} refused of 2000 draws"
    );
    println!("hostile settings: {valid} valid ({engaged} engaged at boot), {refused} refused of 2000 draws");
    // The property's torque-limit check runs on a servo that is on.
    assert!(
        engaged * 2 >= valid,
        "only {engaged} of {valid} valid draws engaged the drives at boot"
    );
}
