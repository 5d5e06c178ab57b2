//! The servo step closed around a simple two-inertia plant: it tracks; a refused setpoint leaves
//! it engaged and unchanged, a feedback fault is latched with zero torque; settings are
//! validated.

use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
use kinematics_core::{
    AxisGains, Calibration, ConfigError, EngageError, FiveBar, InvalidGain, KinematicsError, Servo, ServoConfig, ServoFault,
    SetpointRefusal, StepError,
};

const DT_S: f32 = 5e-4;
/// Joint inertia of the test plant (kg·m²), what the default gains assume.
const INERTIA_KG_M2: f32 = 2e-3;

/// Rigid joints with inertia and a constant load torque, integrated with 10 substeps.
struct Plant {
    angle_rad: [f32; 2],
    velocity_rad_s: [f32; 2],
    load_nm: [f32; 2],
}

impl Plant {
    fn advance(&mut self, torque_nm: [f32; 2]) {
        let h = DT_S / 10.0;
        for _ in 0..10 {
            for (k, torque_nm) in torque_nm.into_iter().enumerate() {
                let acc = (torque_nm - self.load_nm[k]) / INERTIA_KG_M2;
                self.velocity_rad_s[k] += acc * h;
                self.angle_rad[k] += self.velocity_rad_s[k] * h;
            }
        }
    }
}

/// A 20 mm circle through the home pose (212.132, 0), one turn per second after the angular
/// speed ramps up from zero over the first half second.
fn circle_mm(t_s: f32) -> [f32; 2] {
    let (omega_rad_s, ramp_s) = (2.0 * core::f32::consts::PI, 0.5);
    let phase = if t_s < ramp_s { omega_rad_s * t_s * t_s / (2.0 * ramp_s) } else { omega_rad_s * (t_s - ramp_s / 2.0) };
    [192.132 + 20.0 * phase.cos(), 20.0 * phase.sin()]
}

fn run(cal: &Calibration<'_>, seconds: f32, load_nm: [f32; 2]) -> (f32, Plant) {
    let start = cal.command_rad(circle_mm(0.0), 0.05).unwrap();
    let mut plant = Plant { angle_rad: start, velocity_rad_s: [0.0; 2], load_nm };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    let tool = servo.engage(cal, plant.angle_rad).unwrap();
    assert!((tool[0] - 212.132).abs() < 1e-3 && tool[1].abs() < 1e-3, "engage at {tool:?}");
    let mut worst_um: f32 = 0.0;
    let n = (seconds / DT_S) as usize;
    for k in 0..n {
        let t = k as f32 * DT_S;
        let sp = circle_mm(t);
        let out = servo.step(cal, sp, plant.angle_rad).unwrap_or_else(|f| panic!("fault {f} at t={t}"));
        plant.advance(out.torque_nm);
        // Tracking after the first half second, where the load has been taken over.
        if t > 0.5 {
            let cmd = cal.command_rad(circle_mm(t + DT_S), 0.05).unwrap();
            let err_rad = [(plant.angle_rad[0] - cmd[0]).abs(), (plant.angle_rad[1] - cmd[1]).abs()];
            worst_um = worst_um.max(err_rad[0].max(err_rad[1]) * 150.0 * 1000.0);
        }
    }
    (worst_um, plant)
}

#[test]
fn tracks_a_circle_with_a_load_within_2_um_at_the_link_tip() {
    let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
    let (worst_um, _) = run(&cal, 2.0, [0.3, -0.2]);
    println!("worst joint tracking error: {worst_um:.2} µm at the link tip");
    assert!(worst_um < 2.0, "worst {worst_um} µm");
}

#[test]
fn grid_correction_is_added_to_the_command() {
    let g = GridGeometry { nx: 3, ny: 3, x0_mm: 160.0, y0_mm: -80.0, step_x_mm: 50.0, step_y_mm: 80.0 };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[1e-3, -2e-3]; 9]).unwrap();
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let plain = FiveBar::<f32>::paper_nominal().inverse([200.0, 10.0], 0.05).unwrap();
    let corrected = cal.command_rad([200.0, 10.0], 0.05).unwrap();
    assert!((corrected[0] - plain[0] - 1e-3).abs() < 1e-6);
    assert!((corrected[1] - plain[1] + 2e-3).abs() < 1e-6);
    // Engage undoes the correction: the tool position found is the commanded one.
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    let tool = servo.engage(&cal, corrected).unwrap();
    assert!((tool[0] - 200.0).abs() < 1e-3 && (tool[1] - 10.0).abs() < 1e-3, "{tool:?}");
    let (worst_um, _) = run(&cal, 1.0, [0.0; 2]);
    assert!(worst_um < 20.0);
}

/// Engages at the paper's home pose and returns the servo and encoder angles.
fn engaged() -> (Servo, Calibration<'static>, [f32; 2]) {
    let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
    let theta = cal.model.inverse([212.132, 0.0], 0.05).unwrap();
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    servo.engage(&cal, theta).unwrap();
    (servo, cal, theta)
}

/// Issue 11: a refused setpoint used to latch, so the servo could not brake the machine after
/// it. Now a refusal leaves the servo engaged and exactly as it was: the next setpoint of the
/// stream (or of a controlled stop) is tracked in the same sample, with the same torque as if
/// the refused one had never been offered.
#[test]
fn a_refused_setpoint_changes_nothing_and_the_servo_steps_on() {
    let cases: [([f32; 2], SetpointRefusal); 5] = [
        ([f32::NAN, 0.0], SetpointRefusal::NonFinite),
        ([212.132, f32::INFINITY], SetpointRefusal::NonFinite),
        // 0.1 mm in one sample is 200 mm/s: fine for speed, but 400 m/s² of acceleration.
        ([212.232, 0.0], SetpointRefusal::Jump),
        ([400.0, 0.0], SetpointRefusal::Jump),
        ([212.132, 0.0], SetpointRefusal::NonFinite), // replaced below: a grid refusal
    ];
    let g = GridGeometry { nx: 3, ny: 3, x0_mm: 212.132, y0_mm: 0.0, step_x_mm: 1e-3, step_y_mm: 1e-3 };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[0.0; 2]; 9]).unwrap();
    let tiny_grid = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    for (n, (setpoint, want)) in cases.into_iter().enumerate() {
        let (mut servo, cal, theta) = engaged();
        // A grid of 2 µm: 1 µm off its corner is outside, and no jump.
        let (cal, setpoint, want) = if n == 4 {
            (tiny_grid, [212.1312, -1e-3], SetpointRefusal::Grid(kinematics_core::GridError::OutsideGrid))
        } else {
            (cal, setpoint, want)
        };
        let enc = [theta[0] + 1e-4, theta[1] - 1e-4];
        let mut twin = servo.clone();
        let before = format!("{servo:?}");
        assert_eq!(servo.step(&cal, setpoint, enc), Err(StepError::Refused(want)), "setpoint {setpoint:?}");
        assert_eq!(format!("{servo:?}"), before, "a refusal must leave the servo untouched");
        assert_eq!(servo.fault(), None);
        assert!(servo.is_engaged());
        // The next good setpoint is tracked, exactly as by a servo that never saw the refusal.
        let home = [212.132, 0.0];
        let out = servo.step(&cal, home, enc).unwrap();
        assert_eq!(Ok(out), twin.step(&cal, home, enc));
        assert!(out.torque_nm[0] != 0.0, "the offset encoders give torque");
    }
}

/// Feedback faults latch: both torques zero, every later setpoint refused until re-engaged.
#[test]
fn feedback_faults_latch_and_refuse_until_reengaged() {
    let cases: [([f32; 2], ServoFault); 3] = [
        ([f32::INFINITY, 0.0], ServoFault::NonFiniteFeedback),
        ([0.0, f32::NAN], ServoFault::NonFiniteFeedback),
        ([0.05, 0.0], ServoFault::FollowingError),
    ];
    for (encoder_offset, want) in cases {
        let (mut servo, cal, theta) = engaged();
        let enc = [theta[0] + encoder_offset[0], theta[1] + encoder_offset[1]];
        assert_eq!(servo.step(&cal, [212.132, 0.0], enc), Err(StepError::Fault(want)));
        assert_eq!(servo.fault(), Some(want));
        assert!(!servo.is_engaged());
        // Still refused with a perfectly good setpoint and encoders: latched.
        assert_eq!(servo.step(&cal, [212.132, 0.0], theta), Err(StepError::Refused(SetpointRefusal::NotEngaged)));
        assert_eq!(servo.fault(), Some(want));
        servo.engage(&cal, theta).unwrap();
        assert_eq!(servo.fault(), None);
        assert!(servo.step(&cal, [212.132, 0.0], theta).is_ok());
    }
}

/// `accept` shows what a setpoint implies and dropping it changes nothing; `track` commits it.
#[test]
fn accept_reports_velocity_and_acceleration_and_dropping_it_changes_nothing() {
    let (mut servo, cal, theta) = engaged();
    let before = format!("{servo:?}");
    {
        let a = servo.accept(&cal, [212.142, 0.0]).unwrap();
        // 10 µm in 0.5 ms from rest: 20 mm/s and 40 m/s² (second difference over dt²).
        assert!((a.velocity_mm_s()[0] - 20.0).abs() < 0.1 && a.velocity_mm_s()[1] == 0.0, "{:?}", a.velocity_mm_s());
        assert!((a.accel_mm_s2()[0] - 40_000.0).abs() < 200.0, "{:?}", a.accel_mm_s2());
        assert_eq!(a.command_rad(), cal.command_rad([212.142, 0.0], 0.05).unwrap());
        // Not tracked: dropped here.
    }
    assert_eq!(format!("{servo:?}"), before);
    let out = servo.accept(&cal, [212.142, 0.0]).unwrap().track(theta).unwrap();
    assert_ne!(format!("{servo:?}"), before, "tracking commits the setpoint");
    assert!(out.torque_nm[0].abs() > 0.0);
}

/// Issue 11: settings come over a link; a negative or NaN limit used to panic in the PID's
/// `f32::clamp`. Now `Servo::new` refuses them, naming the field.
#[test]
fn servo_new_refuses_invalid_settings() {
    let d = ServoConfig::default();
    let axis = |f: fn(&mut AxisGains)| {
        let mut c = d;
        f(&mut c.axes[1]);
        c
    };
    for (config, want) in [
        (ServoConfig { sample_period_s: 0.0, ..d }, ConfigError::SamplePeriod),
        (ServoConfig { sample_period_s: f32::NAN, ..d }, ConfigError::SamplePeriod),
        (ServoConfig { min_transmission: -0.1, ..d }, ConfigError::MinTransmission),
        (ServoConfig { min_transmission: 1.0, ..d }, ConfigError::MinTransmission),
        (ServoConfig { max_speed_mm_s: -1.0, ..d }, ConfigError::Limit("max_speed_mm_s")),
        (ServoConfig { max_accel_mm_s2: f32::INFINITY, ..d }, ConfigError::Limit("max_accel_mm_s2")),
        (ServoConfig { max_following_error_rad: f32::NAN, ..d }, ConfigError::Limit("max_following_error_rad")),
        (axis(|a| a.torque_limit_nm = -8.0), ConfigError::Gain { axis: 1, gain: InvalidGain("torque_limit_nm") }),
        (axis(|a| a.integral_limit_nm = f32::NAN), ConfigError::Gain { axis: 1, gain: InvalidGain("integral_limit_nm") }),
        (axis(|a| a.ki_nm_per_rad_s = f32::NEG_INFINITY), ConfigError::Gain { axis: 1, gain: InvalidGain("ki_nm_per_rad_s") }),
    ] {
        assert_eq!(Servo::new(config).err(), Some(want), "{config:?}");
        assert!(!want.to_string().is_empty());
    }
    assert!(Servo::new(d).is_ok());
}

#[test]
fn engage_refuses_a_reading_that_is_no_tool_position() {
    let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    assert_eq!(servo.engage(&cal, [f32::NAN, 0.0]), Err(EngageError::NonFiniteFeedback));
    // Encoder zero: both arms stretched along x, the distal links cannot meet.
    assert!(matches!(servo.engage(&cal, [0.0, 0.0]), Err(EngageError::Kinematics(_))));
    assert!(!servo.is_engaged());
    assert_eq!(servo.step(&cal, [212.132, 0.0], [0.0; 2]), Err(StepError::Refused(SetpointRefusal::NotEngaged)));
}

#[test]
fn unreachable_setpoint_approached_smoothly_is_refused_by_the_kinematics() {
    // Walk outward at constant speed (no jump) until the arm would have to stretch past reach.
    let (mut servo, cal, mut theta) = engaged();
    let mut x = 212.132f32;
    let mut result = Ok(());
    // Accelerate at 0.1 g to 100 mm/s, then cruise.
    let (mut v, dt) = (0.0f32, 5e-4f32);
    for _ in 0..40_000 {
        v = (v + 980.6 * dt).min(100.0);
        x += v * dt;
        match servo.step(&cal, [x, 0.0], theta) {
            Ok(out) => theta = out.reference_rad, // an ideal plant follows exactly
            Err(e) => {
                result = Err(e);
                break;
            }
        }
    }
    assert!(x < 300.0, "reached x = {x} before refusing");
    assert!(matches!(
        result,
        Err(StepError::Refused(SetpointRefusal::Kinematics(
            KinematicsError::NearSingularity(_) | KinematicsError::Unreachable
        )))
    ), "{result:?}");
}

#[test]
fn step_before_engage_is_refused() {
    let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    assert_eq!(servo.step(&cal, [212.132, 0.0], [0.0; 2]), Err(StepError::Refused(SetpointRefusal::NotEngaged)));
}
