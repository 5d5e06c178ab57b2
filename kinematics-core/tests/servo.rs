//! The servo step closed around a simple two-inertia plant: it tracks; a refused setpoint leaves
//! it engaged and unchanged, a feedback fault is latched with zero torque; settings are
//! validated.

use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
use kinematics_core::{
    AxisGains, Calibration, ConfigError, EngageError, FiveBar, InvalidGain, KinematicsError, Servo,
    ServoConfig, ServoFault, SetpointRefusal, StepError,
};

const DT_S: f32 = 5e-4;
/// Joint inertia of the test plant (kg·m²), what the default gains assume.
const INERTIA_KG_M2: f32 = 7.4e-3;

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
    let phase = if t_s < ramp_s {
        omega_rad_s * t_s * t_s / (2.0 * ramp_s)
    } else {
        omega_rad_s * (t_s - ramp_s / 2.0)
    };
    [192.132 + 20.0 * phase.cos(), 20.0 * phase.sin()]
}

fn run(cal: &Calibration<'_>, seconds: f32, load_nm: [f32; 2]) -> (f32, Plant) {
    let start = cal.command_rad(circle_mm(0.0), 0.05).unwrap();
    let mut plant = Plant {
        angle_rad: start,
        velocity_rad_s: [0.0; 2],
        load_nm,
    };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    let tool = servo.engage(cal, plant.angle_rad).unwrap();
    assert!(
        (tool[0] - 212.132).abs() < 1e-3 && tool[1].abs() < 1e-3,
        "engage at {tool:?}"
    );
    let mut worst_um: f32 = 0.0;
    let n = (seconds / DT_S) as usize;
    for k in 0..n {
        let t = k as f32 * DT_S;
        let sp = circle_mm(t);
        let out = servo
            .step(cal, sp, plant.angle_rad)
            .unwrap_or_else(|f| panic!("fault {f} at t={t}"));
        plant.advance(out.torque_nm);
        // Tracking after the first half second, where the load has been taken over.
        if t > 0.5 {
            let cmd = cal.command_rad(circle_mm(t + DT_S), 0.05).unwrap();
            let err_rad = [
                (plant.angle_rad[0] - cmd[0]).abs(),
                (plant.angle_rad[1] - cmd[1]).abs(),
            ];
            worst_um = worst_um.max(err_rad[0].max(err_rad[1]) * 150.0 * 1000.0);
        }
    }
    (worst_um, plant)
}

#[test]
fn tracks_a_circle_with_a_load_within_2_um_at_the_link_tip() {
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let (worst_um, _) = run(&cal, 2.0, [0.3, -0.2]);
    println!("worst joint tracking error: {worst_um:.2} µm at the link tip");
    assert!(worst_um < 2.0, "worst {worst_um} µm");
}

#[test]
fn grid_correction_is_added_to_the_command() {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[1e-3, -2e-3]; 9]).unwrap();
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let plain = FiveBar::<f32>::paper_nominal()
        .inverse([200.0, 10.0], 0.05)
        .unwrap();
    let corrected = cal.command_rad([200.0, 10.0], 0.05).unwrap();
    assert!((corrected[0] - plain[0] - 1e-3).abs() < 1e-6);
    assert!((corrected[1] - plain[1] + 2e-3).abs() < 1e-6);
    // Engage undoes the correction: the tool position found is the commanded one.
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    let tool = servo.engage(&cal, corrected).unwrap();
    assert!(
        (tool[0] - 200.0).abs() < 1e-3 && (tool[1] - 10.0).abs() < 1e-3,
        "{tool:?}"
    );
    let (worst_um, _) = run(&cal, 1.0, [0.0; 2]);
    assert!(worst_um < 20.0);
}

/// Engages at the paper's home pose and returns the servo and encoder angles.
fn engaged() -> (Servo, Calibration<'static>, [f32; 2]) {
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let theta = cal.model.inverse([212.132, 0.0], 0.05).unwrap();
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    servo.engage(&cal, theta).unwrap();
    (servo, cal, theta)
}

/// A refused setpoint must not latch: otherwise the servo could not brake the machine after
/// it. Now a refusal leaves the servo engaged and exactly as it was: the next setpoint of the
/// stream (or of a controlled stop) is tracked in the same sample, with the same torque as if
/// the refused one had never been offered.
/// New gains take effect only from rest: setting them disengages the servo (no step is taken
/// until it is engaged again), and gains the settings' checks refuse are refused with the old
/// ones kept.
#[test]
fn new_gains_disengage_and_invalid_ones_are_refused() {
    let (mut servo, cal, theta) = engaged();
    let settings = *servo.config();
    let mut heavier = settings.axes;
    for a in &mut heavier {
        a.kp_nm_per_rad *= 1.5;
    }
    servo.set_gains(heavier).unwrap();
    assert!(!servo.is_engaged());
    assert_eq!(servo.config().axes, heavier);
    assert!(
        servo.step(&cal, [210.0, 0.0], theta).is_err(),
        "not engaged"
    );
    let mut bad = heavier;
    bad[1].kd_nm_s_per_rad = f32::NAN;
    assert!(servo.set_gains(bad).is_err());
    assert_eq!(servo.config().axes, heavier, "the old gains kept");
    servo.engage(&cal, theta).unwrap();
    assert!(servo.is_engaged());
}

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
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 212.132,
        y0_mm: 0.0,
        step_x_mm: 1e-3,
        step_y_mm: 1e-3,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[0.0; 2]; 9]).unwrap();
    let tiny_grid = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    for (n, (setpoint, want)) in cases.into_iter().enumerate() {
        let (mut servo, cal, theta) = engaged();
        // A grid of 2 µm: 1 µm off its corner is outside, and no jump.
        let (cal, setpoint, want) = if n == 4 {
            (
                tiny_grid,
                [212.1312, -1e-3],
                SetpointRefusal::Grid(kinematics_core::GridError::OutsideGrid),
            )
        } else {
            (cal, setpoint, want)
        };
        let enc = [theta[0] + 1e-4, theta[1] - 1e-4];
        let mut twin = servo.clone();
        let before = format!("{servo:?}");
        assert_eq!(
            servo.step(&cal, setpoint, enc),
            Err(StepError::Refused(want)),
            "setpoint {setpoint:?}"
        );
        assert_eq!(
            format!("{servo:?}"),
            before,
            "a refusal must leave the servo untouched"
        );
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
        assert_eq!(
            servo.step(&cal, [212.132, 0.0], enc),
            Err(StepError::Fault(want))
        );
        assert_eq!(servo.fault(), Some(want));
        assert!(!servo.is_engaged());
        // Still refused with a perfectly good setpoint and encoders: latched.
        assert_eq!(
            servo.step(&cal, [212.132, 0.0], theta),
            Err(StepError::Refused(SetpointRefusal::NotEngaged))
        );
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
        assert!(
            (a.velocity_mm_s()[0] - 20.0).abs() < 0.1 && a.velocity_mm_s()[1] == 0.0,
            "{:?}",
            a.velocity_mm_s()
        );
        assert!(
            (a.accel_mm_s2()[0] - 40_000.0).abs() < 200.0,
            "{:?}",
            a.accel_mm_s2()
        );
        assert_eq!(
            a.command_rad(),
            cal.command_rad([212.142, 0.0], 0.05).unwrap()
        );
        // Not tracked: dropped here.
    }
    assert_eq!(format!("{servo:?}"), before);
    let out = servo
        .accept(&cal, [212.142, 0.0])
        .unwrap()
        .track(theta)
        .unwrap();
    assert_ne!(
        format!("{servo:?}"),
        before,
        "tracking commits the setpoint"
    );
    assert!(out.torque_nm[0].abs() > 0.0);
}

/// Settings come over a link; a negative or NaN limit used to panic in the PID's
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
        (
            ServoConfig {
                sample_period_s: 0.0,
                ..d
            },
            ConfigError::SamplePeriod,
        ),
        (
            ServoConfig {
                sample_period_s: f32::NAN,
                ..d
            },
            ConfigError::SamplePeriod,
        ),
        (
            ServoConfig {
                min_transmission: -0.1,
                ..d
            },
            ConfigError::MinTransmission,
        ),
        (
            ServoConfig {
                min_transmission: 1.0,
                ..d
            },
            ConfigError::MinTransmission,
        ),
        (
            ServoConfig {
                max_speed_mm_s: -1.0,
                ..d
            },
            ConfigError::Limit("max_speed_mm_s"),
        ),
        (
            ServoConfig {
                max_accel_mm_s2: f32::INFINITY,
                ..d
            },
            ConfigError::Limit("max_accel_mm_s2"),
        ),
        (
            ServoConfig {
                max_following_error_rad: f32::NAN,
                ..d
            },
            ConfigError::Limit("max_following_error_rad"),
        ),
        (
            axis(|a| a.torque_limit_nm = -8.0),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("torque_limit_nm"),
            },
        ),
        (
            axis(|a| a.integral_limit_nm = f32::NAN),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("integral_limit_nm"),
            },
        ),
        (
            axis(|a| a.ki_nm_per_rad_s = f32::NEG_INFINITY),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("ki_nm_per_rad_s"),
            },
        ),
        (
            axis(|a| a.observer_bandwidth_rad_s = -1.0),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("observer_bandwidth_rad_s"),
            },
        ),
        (
            axis(|a| a.observer_bandwidth_rad_s = f32::INFINITY),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("observer_bandwidth_rad_s"),
            },
        ),
        (
            axis(|a| a.observer_inertia_kg_m2 = f32::NAN),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("observer_inertia_kg_m2"),
            },
        ),
        (
            axis(|a| a.observer_inertia_kg_m2 = -7.4e-3),
            ConfigError::Gain {
                axis: 1,
                gain: InvalidGain("observer_inertia_kg_m2"),
            },
        ),
    ] {
        assert_eq!(Servo::new(config).err(), Some(want), "{config:?}");
        assert!(!want.to_string().is_empty());
    }
    assert!(Servo::new(d).is_ok());
}

#[test]
fn engage_refuses_a_reading_that_is_no_tool_position() {
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    assert_eq!(
        servo.engage(&cal, [f32::NAN, 0.0]),
        Err(EngageError::NonFiniteFeedback)
    );
    // Encoder zero: both arms stretched along x, the distal links cannot meet.
    assert!(matches!(
        servo.engage(&cal, [0.0, 0.0]),
        Err(EngageError::Kinematics(_))
    ));
    assert!(!servo.is_engaged());
    assert_eq!(
        servo.step(&cal, [212.132, 0.0], [0.0; 2]),
        Err(StepError::Refused(SetpointRefusal::NotEngaged))
    );
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
    assert!(
        matches!(
            result,
            Err(StepError::Refused(SetpointRefusal::Kinematics(
                KinematicsError::NearSingularity(_) | KinematicsError::Unreachable
            )))
        ),
        "{result:?}"
    );
}

#[test]
fn step_before_engage_is_refused() {
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let mut servo = Servo::new(ServoConfig::default()).unwrap();
    assert_eq!(
        servo.step(&cal, [212.132, 0.0], [0.0; 2]),
        Err(StepError::Refused(SetpointRefusal::NotEngaged))
    );
}

// ---------------------------------------------------------------------------------------------
// `Servo::step_motion`: setpoints with exact derivatives, inverse dynamics fed forward.

mod motion {
    use kinematics_core::dynamics::FiveBarDynamics;
    use kinematics_core::path::Line;
    use kinematics_core::trajectory::{MotionSetpoint, PathMotion, TaskLimits};
    use kinematics_core::{
        Calibration, FiveBar, Servo, ServoConfig, ServoFault, SetpointRefusal, StepError,
    };

    const DT: f64 = 5e-4;
    const G: f64 = 9_806.65;

    /// The paper machine's hidden-robot dynamics (rotors and bars, no friction).
    fn truth() -> FiveBarDynamics<f64> {
        FiveBarDynamics {
            motor_inertia_kg_m2: [3.89e-3, 3.89e-3],
            tool_mass_kg: 0.165,
            distal_inertia_kg_m2: [-2.43e-4, -2.43e-4],
            viscous_nm_s_per_rad: [0.0; 2],
            coulomb_nm: [0.0; 2],
            coulomb_speed_rad_s: 0.01,
        }
    }

    fn scaled(d: &FiveBarDynamics<f64>, k: [f64; 5]) -> FiveBarDynamics<f64> {
        d.scaled_masses(k)
    }

    /// 5 g moves through the workspace corners and back, 50 ms dwell after each.
    fn tour() -> Vec<PathMotion<f64, Line<f64>>> {
        let limits = TaskLimits {
            speed_mm_s: 1500.0,
            accel_mm_s2: 5.0 * G,
            jerk_mm_s3: 5e6,
        };
        let pts = [
            [212.132, 0.0],
            [172.132, -65.0],
            [252.132, -65.0],
            [252.132, 65.0],
            [172.132, 65.0],
            [212.132, 0.0],
        ];
        pts.windows(2)
            .map(|w| PathMotion::line(w[0], w[1], &limits).unwrap())
            .collect()
    }

    /// Runs the servo around the rigid five-bar with dynamics `plant` (RK4, 10 substeps per
    /// sample), feeding forward `model`; returns the worst following error at the tool (µm).
    fn worst_following_um(
        plant: &FiveBarDynamics<f64>,
        model: Option<FiveBarDynamics<f64>>,
    ) -> f64 {
        worst_following_um_with(plant, model, ServoConfig::default())
    }

    fn worst_following_um_with(
        plant: &FiveBarDynamics<f64>,
        model: Option<FiveBarDynamics<f64>>,
        config: ServoConfig,
    ) -> f64 {
        worst_following_um_ahead(plant, model, config, true)
    }

    /// `look_ahead`: the servo is given the next setpoint (else it predicts it).
    fn worst_following_um_ahead(
        plant: &FiveBarDynamics<f64>,
        model: Option<FiveBarDynamics<f64>>,
        config: ServoConfig,
        look_ahead: bool,
    ) -> f64 {
        let five = FiveBar::<f64>::paper_nominal();
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let moves = tour();
        let mut samples: Vec<MotionSetpoint<f64>> = Vec::new();
        for m in &moves {
            let n = (m.duration_s() / DT).ceil() as usize + 100;
            samples.extend((0..n).map(|k| m.at(k as f64 * DT)));
        }
        let mut th = five.inverse(samples[0].position_mm, 0.0).unwrap();
        let mut w = [0.0f64; 2];
        let mut servo = Servo::new(config).unwrap();
        servo.set_dynamics(model.map(|d| d.cast())).unwrap();
        servo.engage(&cal, [th[0] as f32, th[1] as f32]).unwrap();
        let mut worst = 0.0f64;
        let f32_setpoint = |s: &MotionSetpoint<f64>| MotionSetpoint {
            position_mm: s.position_mm.map(|v| v as f32),
            velocity_mm_s: s.velocity_mm_s.map(|v| v as f32),
            acceleration_mm_s2: s.acceleration_mm_s2.map(|v| v as f32),
            jerk_mm_s3: s.jerk_mm_s3.map(|v| v as f32),
        };
        for (k, s) in samples.iter().enumerate() {
            let sp = f32_setpoint(s);
            let next = samples.get(k + 1).filter(|_| look_ahead).map(f32_setpoint);
            let out = servo
                .step_motion(&cal, &sp, next.as_ref(), [th[0] as f32, th[1] as f32])
                .unwrap();
            let j = five
                .inverse_pose(s.position_mm, 0.0)
                .unwrap()
                .jacobian()
                .unwrap();
            let e = out.following_error_rad.map(f64::from);
            worst = worst.max(
                1e3 * (j[0][0] * e[0] + j[0][1] * e[1]).hypot(j[1][0] * e[0] + j[1][1] * e[1]),
            );
            let tau = out.torque_nm.map(f64::from);
            let f = |th: [f64; 2], w: [f64; 2]| {
                plant
                    .forward_acceleration(&five.forward_pose(th, 0.0).unwrap(), w, tau)
                    .unwrap()
            };
            let h = DT / 10.0;
            for _ in 0..10 {
                let add = |x: [f64; 2], d: [f64; 2], s: f64| [x[0] + d[0] * s, x[1] + d[1] * s];
                let a1 = f(th, w);
                let (t2, w2) = (add(th, w, h / 2.0), add(w, a1, h / 2.0));
                let a2 = f(t2, w2);
                let (t3, w3) = (add(th, w2, h / 2.0), add(w, a2, h / 2.0));
                let a3 = f(t3, w3);
                let (t4, w4) = (add(th, w3, h), add(w, a3, h));
                let a4 = f(t4, w4);
                for k in 0..2 {
                    th[k] += h / 6.0 * (w[k] + 2.0 * w2[k] + 2.0 * w3[k] + w4[k]);
                    w[k] += h / 6.0 * (a1[k] + 2.0 * a2[k] + 2.0 * a3[k] + a4[k]);
                }
            }
        }
        worst
    }

    /// The figures are `cargo bench -p host-sim --bench dynamics`'s on the six-bar plant; here
    /// the bounds on the five-bar: exact model within 2 µm, every mass and inertia 20 % off
    /// (alternating) within 10 µm; the constant-inertia feed-forward (no coupling, no velocity
    /// products) clearly worse, no feed-forward at all an order of magnitude worse.
    #[test]
    fn follows_5g_moves_with_the_dynamics_fed_forward_even_with_20_percent_mass_errors() {
        let t = truth();
        let exact = worst_following_um(&t, Some(t));
        let predicted = worst_following_um_ahead(&t, Some(t), ServoConfig::default(), false);
        let off = worst_following_um(&t, Some(scaled(&t, [1.2, 0.8, 1.2, 0.8, 1.2])));
        let off2 = worst_following_um(&t, Some(scaled(&t, [0.8, 1.2, 0.8, 1.2, 0.8])));
        let constant = worst_following_um(&t, None);
        let mut bare = ServoConfig::default();
        for a in &mut bare.axes {
            a.inertia_ff_kg_m2 = 0.0;
        }
        let none = worst_following_um_with(&t, None, bare);
        println!(
            "5 g tour, five-bar plant: {exact:.2} µm exact model ({predicted:.2} µm predicting the next setpoint), \
             {off:.2} / {off2:.2} µm with ±20 %, {constant:.2} µm with the constant inertia feed-forward, \
             {none:.1} µm without feed-forward"
        );
        assert!(exact < 1.0, "{exact}");
        assert!(predicted < 2.0 && predicted > exact, "{predicted}");
        assert!(off < 10.0 && off2 < 10.0, "{off} {off2}");
        assert!(constant > 2.0 * exact, "{constant}");
        assert!(none > 10.0 * exact, "{none}");
    }

    fn engaged() -> (Servo, Calibration<'static>, [f32; 2]) {
        let cal = Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        };
        let theta = cal.model.inverse([212.132, 0.0], 0.05).unwrap();
        let mut servo = Servo::new(ServoConfig::default()).unwrap();
        servo.engage(&cal, theta).unwrap();
        (servo, cal, theta)
    }

    #[test]
    fn at_rest_the_reference_is_the_command() {
        let (mut servo, cal, theta) = engaged();
        let out = servo
            .step_motion(&cal, &MotionSetpoint::at_rest([212.132, 0.0]), None, theta)
            .unwrap();
        assert_eq!(
            out.reference_rad,
            cal.command_rad([212.132, 0.0], 0.05).unwrap()
        );
    }

    #[test]
    fn bad_derivatives_and_jumps_are_refused_without_latching() {
        let rest = MotionSetpoint::at_rest([212.132f32, 0.0]);
        let cases = [
            (
                MotionSetpoint {
                    velocity_mm_s: [f32::NAN, 0.0],
                    ..rest
                },
                SetpointRefusal::NonFinite,
            ),
            (
                MotionSetpoint {
                    jerk_mm_s3: [0.0, f32::INFINITY],
                    ..rest
                },
                SetpointRefusal::NonFinite,
            ),
            // Stated speed and acceleration beyond the limits (3 m/s, 5.25 g).
            (
                MotionSetpoint {
                    velocity_mm_s: [3100.0, 0.0],
                    ..rest
                },
                SetpointRefusal::Jump,
            ),
            (
                MotionSetpoint {
                    acceleration_mm_s2: [0.0, 60_000.0],
                    ..rest
                },
                SetpointRefusal::Jump,
            ),
            // A 0.1 mm step that claims to be at rest: the positions tell.
            (
                MotionSetpoint::at_rest([212.232, 0.0]),
                SetpointRefusal::Jump,
            ),
            (MotionSetpoint::at_rest([400.0, 0.0]), SetpointRefusal::Jump),
        ];
        for (sp, want) in cases {
            let (mut servo, cal, theta) = engaged();
            assert_eq!(
                servo.step_motion(&cal, &sp, None, theta),
                Err(StepError::Refused(want)),
                "{sp:?}"
            );
            // Nothing latched: the servo takes a good setpoint in the same sample.
            assert!(servo.is_engaged() && servo.fault().is_none());
            assert!(servo.step_motion(&cal, &rest, None, theta).is_ok());
        }
        // A non-finite next setpoint is refused in its own sample, not in the one before.
        let (mut servo, cal, theta) = engaged();
        let bad_next = MotionSetpoint::at_rest([f32::NAN, 0.0]);
        assert!(servo
            .step_motion(&cal, &rest, Some(&bad_next), theta)
            .is_ok());
        assert_eq!(
            servo.step_motion(&cal, &bad_next, None, theta),
            Err(StepError::Refused(SetpointRefusal::NonFinite))
        );
        // The feedback's faults latch.
        let (mut servo, cal, theta) = engaged();
        assert_eq!(
            servo.step_motion(&cal, &rest, None, [theta[0] + 0.05, theta[1]]),
            Err(StepError::Fault(ServoFault::FollowingError))
        );
        assert_eq!(servo.fault(), Some(ServoFault::FollowingError));
        assert!(
            servo.step_motion(&cal, &rest, None, theta).is_err(),
            "latched"
        );
    }

    #[test]
    fn invalid_dynamics_are_refused_and_the_old_ones_kept() {
        let mut servo = Servo::new(ServoConfig::default()).unwrap();
        let good = truth().cast::<f32>();
        servo.set_dynamics(Some(good)).unwrap();
        let bad = FiveBarDynamics {
            tool_mass_kg: -1.0,
            ..good
        };
        assert!(servo.set_dynamics(Some(bad)).is_err());
        assert_eq!(servo.dynamics(), Some(&good));
        servo.set_dynamics(None).unwrap();
        assert_eq!(servo.dynamics(), None);
    }
}

/// With a backlash block in the image the servo's reference leads the link command
/// by the play operator of its increments: ±β/2 after a move in each direction (the sign of
/// each joint's motion), 0 (mid-gap) at engage, continuous on a reversal (never a step of β),
/// and exactly the link command without the block.
#[test]
fn the_reference_compensates_the_images_backlash_continuously() {
    use kinematics_core::grid::{append_backlash, BACKLASH_LEN};
    use kinematics_core::Backlash;
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let n = g.image_len();
    let mut img = vec![0u8; n + BACKLASH_LEN];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[0.0; 2]; 9]).unwrap();
    let beta = [20e-6f32, 40e-6];
    append_backlash(&mut img, n, n, &Backlash::new(beta).unwrap()).unwrap();
    let with = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let without = Calibration::from_grid(CorrectionGrid::parse(&img[..n]).unwrap());
    assert_eq!(with.backlash().map(|b| b.beta_rad()), Some(beta));
    assert_eq!(without.backlash(), None);
    // 2 mm in +x over 0.5 s from rest (smooth), then back: a reversal of both joints.
    let path = |k: usize| {
        let s = |u: f32| u * u * (3.0 - 2.0 * u);
        let u = (k as f32 / 1000.0).min(2.0);
        let x = if u <= 1.0 {
            2.0 * s(u)
        } else {
            2.0 * (1.0 - s(u - 1.0))
        };
        [200.0 + x, 10.0]
    };
    for (cal, has) in [(&with, true), (&without, false)] {
        let mut servo = Servo::new(ServoConfig::default()).unwrap();
        let mut encoder = cal.command_rad(path(0), 0.05).unwrap();
        servo.engage(cal, encoder).unwrap();
        let (mut last_ref, mut last_cmd) = (encoder, encoder);
        let mut worst_ratio: f32 = 0.0;
        for k in 0..=2100 {
            let sp = path(k);
            let cmd = cal.command_rad(sp, 0.05).unwrap();
            let out = servo.step(cal, sp, encoder).unwrap();
            let lead = [out.reference_rad[0] - cmd[0], out.reference_rad[1] - cmd[1]];
            for j in 0..2 {
                let half = if has { beta[j] / 2.0 } else { 0.0 };
                assert!(
                    lead[j].abs() <= half + 1e-6,
                    "sample {k} joint {j}: lead {} beyond β/2",
                    lead[j]
                );
                let (dr, dc) = (
                    (out.reference_rad[j] - last_ref[j]).abs(),
                    (cmd[j] - last_cmd[j]).abs(),
                );
                if dc > 1e-6 {
                    worst_ratio = worst_ratio.max(dr / dc);
                }
            }
            if k == 0 {
                assert_eq!(lead, [0.0; 2], "mid-gap at engage");
            }
            // At the ends of the out and back moves: each joint's lead is ±β/2 by the sign of
            // the joint motion that brought it there (0 without the block).
            if has && (k == 1000 || k == 2100) {
                let dir = |j: usize| {
                    (cmd[j]
                        - cal
                            .command_rad(path(if k == 1000 { 0 } else { 1000 }), 0.05)
                            .unwrap()[j])
                        .signum()
                };
                for j in 0..2 {
                    let want = dir(j) * beta[j] / 2.0;
                    assert!(
                        (lead[j] - want).abs() < 2e-7,
                        "sample {k} joint {j}: lead {} want {want}",
                        lead[j]
                    );
                }
            } else if !has {
                assert!(lead[0].abs() < 1e-7 && lead[1].abs() < 1e-7);
            }
            (last_ref, last_cmd, encoder) = (out.reference_rad, cmd, out.reference_rad);
        }
        // The motor reference moves at most twice the link command's rate (crossing the gap).
        assert!(
            worst_ratio <= 2.0 + 1e-2,
            "reference/command rate {worst_ratio}"
        );
        assert!(
            !has || worst_ratio > 1.5,
            "the gap is crossed at up to twice the rate: {worst_ratio}"
        );
        // Engage again: back to the mid-gap (the link taken where the encoder is).
        let tool = servo.engage(cal, encoder).unwrap();
        let out = servo.step(cal, tool, encoder).unwrap();
        let cmd = cal.command_rad(tool, 0.05).unwrap();
        assert!(
            (out.reference_rad[0] - cmd[0]).abs() < 1e-6
                && (out.reference_rad[1] - cmd[1]).abs() < 1e-6
        );
        assert!(
            (out.reference_rad[0] - encoder[0]).abs() < 1e-6
                && (out.reference_rad[1] - encoder[1]).abs() < 1e-6
        );
    }
}
