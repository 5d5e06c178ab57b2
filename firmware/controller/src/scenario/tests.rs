use super::stop_check::{self, CoastModel, PlantState, StopReport};
use super::*;
use crate::calibration::{CalibrationState, ImageError};
use crate::calibration_slots::SlotError;
use crate::encoder_check::{EncoderFault, EncoderFaultKind};
use crate::fault::StopCategory;
use crate::servo_loop::Mode;
use crate::settings::Settings;
use crate::status::Status;
use crate::stop::{MotionState, StopProfile};
use crate::watchdog::WatchdogFault;
use crate::watchdog::TIMEOUT_US;
use kinematics_core::grid::{
    append_dynamics, append_workspace, encode, GridGeometry, WorkspaceLimits, DYNAMICS_LEN,
    WORKSPACE_LEN,
};
use kinematics_core::{Calibration, CorrectionGrid, SetpointRefusal};
use kinematics_core::{ConvexWorkspace, FiveBar, FiveBarDynamics, KinematicsError};

/// The QEMU image's geometry with a constant correction, without extension blocks.
fn plain_image(correction_rad: [f32; 2]) -> Vec<u8> {
    let g = GridGeometry {
        nx: 21,
        ny: 31,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(
        &mut img,
        &g,
        &FiveBar::paper_nominal(),
        &vec![correction_rad; g.len()],
    )
    .unwrap();
    img
}

/// [`plain_image`] with the workspace and dynamics blocks, as the bundled image has them.
fn image(correction_rad: [f32; 2]) -> Vec<u8> {
    let mut img = plain_image(correction_rad);
    let n = img.len();
    img.resize(n + WORKSPACE_LEN + DYNAMICS_LEN, 0);
    let region = ConvexWorkspace::rectangle([162.132, 262.132], [-75.0, 75.0]).unwrap();
    let end = append_workspace(
        &mut img,
        n,
        n,
        &WorkspaceLimits {
            region,
            stop_margin_mm: 0.1,
        },
    )
    .unwrap();
    let d = FiveBarDynamics {
        motor_inertia_kg_m2: [3e-3; 2],
        tool_mass_kg: 0.1,
        distal_inertia_kg_m2: [0.0; 2],
        viscous_nm_s_per_rad: [0.01; 2],
        coulomb_nm: [0.0; 2],
        coulomb_speed_rad_s: 0.01,
    };
    append_dynamics(&mut img, n, end, &d).unwrap();
    img
}

const D_RAD: [f32; 2] = [3e-4, -2.5e-4];
const P_MM: [f32; 2] = [212.132, 0.0];
const DT_S: f32 = crate::SAMPLE_PERIOD_S;
/// Independent joints with the QEMU plant's rotors: dynamic braking 0.225 N·m·s/rad, coast
/// time constants 9.4 / 7.7 ms (the plant itself is coupled, `coupled_inertia_kg_m2`).
const COAST: CoastModel = CoastModel {
    inertia_kg_m2: [2.2e-3, 1.8e-3],
    viscous_nm_s_per_rad: 0.01,
    dynamic_brake_nm_s_per_rad: 0.225,
    coupled_inertia_kg_m2: 0.0,
};
/// Faults at sample 1000; the move reaching it starts at 900.
const INJECTION: Injection = Injection {
    top_speed_sample: 1000,
    top_speed_mm_s: 1000.0,
    move_start_sample: 900,
};

fn cal(img: &[u8]) -> Calibration<'_> {
    Calibration::from_grid(CorrectionGrid::parse(img).unwrap())
}

/// A running status at `ticks` with the reference IK + `d` at `P_MM`.
fn running(ticks: u32, d: [f32; 2]) -> Status {
    let ik = FiveBar::<f32>::paper_nominal().inverse(P_MM, 0.05).unwrap();
    let reference = [ik[0] + d[0], ik[1] + d[1]];
    Status {
        ticks,
        overruns: 0,
        worst_step_us: 12.0,
        calibration: CalibrationState::Valid,
        mode: Mode::Running,
        fault: None,
        fault_tick: 0,
        drives_enabled: true,
        stop_distance_mm: 0.0,
        setpoint_mm: P_MM,
        setpoint_moved: false,
        reference_rad: reference,
        encoder_rad: reference,
        torque_nm: [0.1, -0.1],
        max_following_error_rad: 1e-4,
        setpoint_underruns: 0,
        calibration_id: None,
        calibration_pending: None,
        blending: false,
        last_switch: None,
        last_upload: None,
        homing: None,
    }
}

/// The plant at the status' reference (a machine that follows exactly).
fn plant_of(status: &Status) -> PlantState {
    PlantState {
        joint_rad: status.reference_rad,
        joint_rad_s: [0.0; 2],
    }
}

fn on(status: &Status) -> Observation<'_> {
    Observation {
        status,
        drive_enable: true,
        drive_enable_ever: true,
        drive_torque_nm: status.torque_nm,
        plant: plant_of(status),
    }
}

fn off(status: &Status) -> Observation<'_> {
    Observation {
        status,
        drive_enable: false,
        drive_enable_ever: true,
        drive_torque_nm: [0.0; 2],
        plant: plant_of(status),
    }
}

fn checker(scenario: Scenario, img: &[u8]) -> Checker<'_> {
    Checker::new(
        scenario,
        CorrectionGrid::parse(img),
        &Settings::default(),
        3_000,
        INJECTION,
        COAST,
    )
}

/// `homing`: torque above the homing limit while homing fails; after homing, readings that
/// are not the plant's true angles (a wrong zero) fail; the right zero goes on to `track`.
#[test]
fn homing_fails_on_torque_above_its_limit_or_a_wrong_zero() {
    let img = image(D_RAD);
    let homing = |ticks, torque_nm| Status {
        mode: Mode::Homing,
        torque_nm,
        ..running(ticks, D_RAD)
    };
    let mut c = checker(sc("homing"), &img);
    assert_eq!(c.observe(&on(&homing(1, [1.9, -1.9]))), None);
    assert_eq!(
        c.observe(&on(&homing(2, [2.5, 0.0]))),
        Some(Err("torque above the homing limit"))
    );
    assert_eq!(
        c.observe(&off(&homing(3, [0.0, 0.0]))),
        Some(Err("drives not enabled while homing"))
    );
    let s = running(100, D_RAD);
    let mut wrong = on(&s);
    wrong.plant.joint_rad[0] += 1e-3;
    let mut c = checker(sc("homing"), &img);
    assert_eq!(
        c.observe(&wrong),
        Some(Err(
            "after homing the readings are not the joints' true angles"
        ))
    );
    let mut c = checker(sc("homing"), &img);
    assert_eq!(c.observe(&on(&s)), None);
    assert_eq!(c.homed_at(), Some(100));
}

/// The upload scenarios' verdict at the end of the tour: committed and switched (with grid
/// checks against the new image), or refused for its CRC with the old image kept.
#[test]
fn the_upload_outcome_is_checked() {
    use crate::calibration_slots::CalibrationId;
    let img = image(D_RAD);
    let id = |sequence| CalibrationId {
        slot: sequence as u8,
        sequence,
        crc32: 7,
        len: 100,
    };
    let c = checker(sc("calibration-upload"), &img);
    let not_switched = Status {
        calibration_id: Some(id(0)),
        last_upload: Some(Ok(id(1))),
        ..running(1, D_RAD)
    };
    assert_eq!(
        c.upload_outcome(&not_switched),
        Err("the servo did not switch to the new image")
    );
    let switched = Status {
        calibration_id: Some(id(1)),
        ..not_switched
    };
    assert_eq!(
        c.upload_outcome(&switched),
        Err("too few grid checks against the new image")
    );
    let c = checker(sc("calibration-upload-corrupt"), &img);
    let refused = Status {
        calibration_id: Some(id(0)),
        last_upload: Some(Err(SlotError::Image(ImageError::Grid(GridError::BadCrc)))),
        ..running(1, D_RAD)
    };
    assert_eq!(c.upload_outcome(&refused), Ok(()));
    assert!(c.upload_outcome(&switched).is_err());
}

/// The scenario a test names (the registry's entry).
fn sc(name: &str) -> Scenario {
    Scenario::named(name).unwrap_or_else(|_| panic!("no scenario {name}"))
}

#[test]
fn command_line_names() {
    for (line, want) in [
        ("firmware run", "run"),
        ("firmware link", "link"),
        ("firmware long-run", "long-run"),
        ("firmware track", "track"),
        ("firmware track-5g", "track-5g"),
        ("firmware nan-setpoint", "nan-setpoint"),
        ("firmware out-of-reach", "out-of-reach"),
        ("firmware jump", "jump"),
        ("firmware underrun", "underrun"),
        ("firmware overrun", "overrun"),
        ("firmware encoder-frozen-at-rest", "encoder-frozen-at-rest"),
        ("firmware encoder-frozen-moving", "encoder-frozen-moving"),
        ("firmware glitch-small", "glitch-small"),
        ("firmware glitch-large", "glitch-large"),
        ("firmware stalled-task", "stalled-task"),
        ("firmware bad-image-crc", "bad-image-crc"),
        ("firmware bad-image-magic", "bad-image-magic"),
        ("firmware panic", "panic"),
        ("firmware hard-fault", "hard-fault"),
    ] {
        let s = Scenario::from_command_line(line).unwrap();
        assert_eq!(s.name(), want, "{line:?}");
        assert_eq!(s, sc(want));
    }
    // An empty or unknown name is an error, never the production path.
    for line in [
        "firmware",
        "",
        "firmware bogus",
        "firmware Track",
        "firmware list",
    ] {
        assert_eq!(
            Scenario::from_command_line(line),
            Err(UnknownScenario),
            "{line:?}"
        );
    }
}

/// The registry: unique scenario names, unique run names, each scenario a check, the runs
/// `qemu/test.sh` makes, and the `list` lines it reads.
#[test]
fn the_registry_is_consistent_and_lists_every_run() {
    let names: Vec<&str> = registry::SCENARIOS.iter().map(|s| s.name).collect();
    let mut unique = names.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), names.len(), "{names:?}");
    let runs: Vec<&str> = registry::SCENARIOS
        .iter()
        .flat_map(|s| s.runs.iter().map(|r| r.test))
        .collect();
    let mut unique = runs.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), runs.len(), "{runs:?}");
    assert_eq!(runs.len(), 23);
    // A scenario the watchdog resets into is in the registry.
    for s in &registry::SCENARIOS {
        if let Some(next) = s.after_watchdog_reset {
            assert!(Scenario::named(next).is_ok(), "{next}");
        }
        // Every run of a test scenario checks something and has a time limit.
        if !s.runs.is_empty() {
            assert!(!matches!(s.check, Check::Nothing), "{}", s.name);
        }
    }
    let mut line = String::new();
    sc("panic").spec().runs[0]
        .list_line("panic", &mut line)
        .unwrap();
    assert_eq!(line, "SCENARIO panic-exits panic 1 panic valid");
    line.clear();
    sc("bad-image-magic").spec().runs[1]
        .list_line("bad-image-magic", &mut line)
        .unwrap();
    assert_eq!(line, "SCENARIO no-image bad-image-magic 0 pass none");
}

/// docs/dev/testing.md's scenario table lists exactly the registry's runs, in its order (each
/// row's first cell names one run or several joined by ` / `).
#[test]
fn the_readme_table_lists_every_run_in_order() {
    let readme = concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/dev/testing.md");
    let text = std::fs::read_to_string(readme).unwrap();
    let table: Vec<String> = text
        .lines()
        .skip_while(|l| !l.starts_with("| run | image | expected |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .flat_map(|l| {
            let cell = l.split('|').nth(1).unwrap_or("").trim().to_owned();
            cell.split(" / ")
                .map(|n| n.trim().trim_matches('`').to_owned())
                .collect::<Vec<_>>()
        })
        .collect();
    let runs: Vec<String> = registry::SCENARIOS
        .iter()
        .flat_map(|s| s.runs.iter().map(|r| r.test.to_owned()))
        .collect();
    assert_eq!(table, runs, "docs/dev/testing.md's scenario table");
}

#[test]
fn injection_happens_only_where_the_scenario_says() {
    let (i, at) = (&INJECTION, INJECTION.top_speed_sample);
    let p = [200.0, 10.0];
    assert!(sc("nan-setpoint").tamper(i, at, p).unwrap()[1].is_nan());
    assert_eq!(sc("nan-setpoint").tamper(i, at + 1, p), Some(p));
    assert_eq!(sc("jump").tamper(i, at - 1, p), Some(p));
    assert_eq!(sc("jump").tamper(i, at + 5, p), Some([201.0, 10.0]));
    assert_eq!(sc("underrun").tamper(i, at - 1, p), Some(p));
    assert_eq!(sc("underrun").tamper(i, at + 7, p), None);
    for s in [sc("run"), sc("long-run"), sc("track")] {
        assert_eq!(s.tamper(i, at, p), Some(p));
        assert!(!s.overrun_at(i, at));
        assert_eq!(s.encoder_at(i, at), EncoderInjection::None);
        assert_eq!(s.tour_mm(&[[1.0, 2.0]]), &[[1.0, 2.0]]);
    }
    let overruns: Vec<u32> = (0..5_000)
        .filter(|&k| sc("overrun").overrun_at(i, k))
        .collect();
    assert_eq!(overruns, [at, at + 1, at + 2]);
    assert_eq!(sc("out-of-reach").tour_mm(&[]), &OUT_OF_REACH_TOUR_MM);
    assert_eq!(
        sc("glitch-small").encoder_at(i, at),
        EncoderInjection::Offset(SMALL_GLITCH_RAD)
    );
    assert_eq!(
        sc("glitch-small").encoder_at(i, at + 1),
        EncoderInjection::None
    );
    assert_eq!(
        sc("glitch-large").encoder_at(i, at),
        EncoderInjection::Offset(LARGE_GLITCH_RAD)
    );
    assert_eq!(
        sc("encoder-frozen-moving").encoder_at(i, at - 1),
        EncoderInjection::None
    );
    assert_eq!(
        sc("encoder-frozen-moving").encoder_at(i, at + 300),
        EncoderInjection::Freeze
    );
    let rest = INJECTION.move_start_sample - FROZEN_AT_REST_LEAD;
    assert_eq!(
        sc("encoder-frozen-at-rest").encoder_at(i, rest - 1),
        EncoderInjection::None
    );
    assert_eq!(
        sc("encoder-frozen-at-rest").encoder_at(i, rest),
        EncoderInjection::Freeze
    );
}

/// On the built-in tour the top speed is 1.38 m/s, mid-way along the long diagonal, and
/// the move reaching it starts after a rest.
#[test]
fn injection_finds_the_tours_top_speed_and_the_rest_before_it() {
    let settings = Settings {
        builtin_tour_mm: &crate::waypoint_moves::WORKSPACE_TOUR_MM,
        ..Settings::default()
    };
    let t = settings.builtin_trajectory(P_MM);
    let i = Injection::find(&t, DT_S);
    // 15/8·D/T with D = 160.4 mm and T = 0.218 s (436 samples: the 2 g limit binds).
    assert!((i.top_speed_mm_s - 1379.4).abs() < 0.5, "{i:?}");
    let mut t2 = t.clone();
    let points: Vec<[f32; 2]> = (0..t.total_samples()).map(|_| t2.next_mm()).collect();
    let at = i.top_speed_sample as usize;
    // Mid-way between (255, -68) and (170, 68).
    assert!(
        (points[at][0] - 212.5).abs() < 1.0 && points[at][1].abs() < 1.5,
        "{:?}",
        points[at]
    );
    let start = i.move_start_sample as usize;
    assert_eq!(
        points[start - 1],
        [255.0, -68.0],
        "rests at the move's start point"
    );
    assert_ne!(points[start], points[start - 1]);
    assert!(points[start - 1 - FROZEN_AT_REST_LEAD as usize..start]
        .iter()
        .all(|p| *p == [255.0, -68.0]));
}

/// The production path must never be stopped by a time limit.
#[test]
fn the_production_path_has_no_time_limit() {
    let img = image(D_RAD);
    let mut c = checker(sc("run"), &img);
    for ticks in [
        1,
        MAX_TICKS - 1,
        MAX_TICKS,
        LONG_RUN_TICKS,
        10 * LONG_RUN_TICKS,
        u32::MAX,
    ] {
        let s = running(ticks, D_RAD);
        assert_eq!(c.observe(&on(&s)), None, "ticks {ticks}");
    }
    // A test scenario is limited.
    let mut c = checker(sc("nan-setpoint"), &img);
    assert_eq!(
        c.observe(&on(&running(MAX_TICKS, D_RAD))),
        Some(Err("scenario did not finish in time"))
    );
}

#[test]
fn long_run_passes_at_8_s_only_if_still_running_without_fault() {
    let img = image(D_RAD);
    let mut c = checker(sc("long-run"), &img);
    for ticks in [1, 5_000, MAX_TICKS, LONG_RUN_TICKS - 1] {
        assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
    }
    assert_eq!(
        c.observe(&on(&running(LONG_RUN_TICKS, D_RAD))),
        Some(Ok(()))
    );
    let s = running(9_000, D_RAD);
    assert!(
        matches!(
            checker(sc("long-run"), &img).observe(&off(&s)),
            Some(Err(_))
        ),
        "enable line low"
    );
    let s = Status {
        fault: Some(Fault::DeadlineMissed),
        ..running(9_000, D_RAD)
    };
    assert!(matches!(
        checker(sc("long-run"), &img).observe(&on(&s)),
        Some(Err(_))
    ));
}

// -----------------------------------------------------------------------------------------
// Fault scenarios against a synthetic machine: at rest at 190 mm, then along +x at 1 m/s
// for 20 samples; at the fault (sample `fault_at`) it follows the stop the checker
// plans (or coasts, category 0), with `tweak` changing what the hardware or plant shows.

/// One sample of the synthetic machine.
struct Frame {
    status: Status,
    enable: bool,
    torque_nm: [f32; 2],
    plant: PlantState,
}

/// What to break.
#[derive(Clone, Copy, PartialEq)]
enum Tweak {
    None,
    /// The stop goes this much further (mm).
    Overshoot(f32),
    /// Enable low during a category-2 stop.
    EnableLow,
    /// Category 0: enable left on / torque left on.
    EnableLeftOn,
    TorqueLeftOn,
    /// Category 0: the joints keep going at their speed (pushed, or a drive that does not
    /// brake).
    Pushed,
    /// Category 0: the joints never come to rest.
    NeverAtRest,
    /// Category 1: torque never removed.
    NeverOff,
    /// Category 2: the tool drifts 5 µm per sample while holding.
    Drift,
    /// Category 2: the status never says Holding.
    NotHolding,
}

/// The synthetic machine's setpoint before the fault at `fault_at`: at rest at 190 mm,
/// moving at 1 m/s along +x for the last 20 samples.
fn x_before(k: u32, fault_at: u32) -> f32 {
    190.0 + 1000.0 * DT_S * k.saturating_sub(fault_at - 20) as f32
}

fn synthetic<'i>(
    img: &'i [u8],
    fault: Fault,
    fault_at: u32,
    tweak: Tweak,
) -> impl Fn(u32) -> Frame + 'i {
    let c = cal(img);
    let dt = DT_S;
    let settings = Settings::default();
    let v = [1000.0f32, 0.0];
    let state =
        MotionState::from_differences([x_before(fault_at - 1, fault_at), 0.0], v, [0.0; 2], dt);
    let profile = StopProfile::plan(&state, &settings.stop.limits);
    let category = fault.stop_category();
    let theta = move |x: f32| c.command_rad([x, 0.0], 0.05).unwrap();
    // The setpoint of sample k; the plant lags one sample behind (it is where the previous
    // sample's setpoint asked it to be, as the QEMU plant is).
    let x_at = move |k: u32| {
        if k < fault_at {
            x_before(k, fault_at)
        } else {
            let t = (k - fault_at + 1) as f32 * dt;
            let extra = match tweak {
                Tweak::Overshoot(mm) => mm * (t / profile.duration_s()).min(1.0),
                // From the start of the hold check on.
                Tweak::Drift => {
                    5e-3 * ((t - profile.duration_s() - stop_check::HOLD_AFTER_S) / dt).max(0.0)
                }
                _ => 0.0,
            };
            profile.origin_mm()[0] + profile.distance_at(t) + extra
        }
    };
    move |k: u32| {
        let mut status = running(k + 1, D_RAD);
        let (x, mode, enable) = if k < fault_at {
            (x_before(k, fault_at), Mode::Running, true)
        } else {
            let t = (k - fault_at + 1) as f32 * dt;
            let x = x_at(k);
            let finished = profile.finished(t);
            let mode = match category {
                StopCategory::Zero => Mode::SafeState(fault),
                StopCategory::One if finished && tweak != Tweak::NeverOff => Mode::SafeState(fault),
                StopCategory::Two if finished && tweak != Tweak::NotHolding => Mode::Holding(fault),
                _ => Mode::Stopping(fault),
            };
            let enable = match category {
                StopCategory::Zero => tweak == Tweak::EnableLeftOn,
                StopCategory::One => !matches!(mode, Mode::SafeState(_)),
                StopCategory::Two => tweak != Tweak::EnableLow,
            };
            (x, mode, enable)
        };
        status.setpoint_mm = [x, 0.0];
        status.mode = mode;
        if k >= fault_at {
            status.fault = Some(fault);
            status.fault_tick = fault_at;
            status.overruns = 3;
        }
        let mut plant = PlantState {
            joint_rad: theta(x_at(k.saturating_sub(1))),
            joint_rad_s: [0.0; 2],
        };
        if category == StopCategory::Zero && k >= fault_at {
            // Coasts: the joints' speed at the fault, decelerating to rest in 10 ms (travel
            // w·5 ms, inside the dynamic-braking bound J·w/(c + b) = w·7.7 ms for joint 2).
            let (a, b) = (
                theta(x_before(fault_at - 2, fault_at)),
                theta(x_before(fault_at - 1, fault_at)),
            );
            let w = [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt];
            let t = (k - fault_at) as f32 * dt;
            let (travel, speed) = match tweak {
                Tweak::Pushed => (t, 1.0),
                Tweak::NeverAtRest => (t.min(0.005), if t < 0.005 { 1.0 } else { 0.01 }),
                _ => {
                    let t = t.min(0.01);
                    (t - t * t / 0.02, 1.0 - t / 0.01)
                }
            };
            plant = PlantState {
                joint_rad: [0, 1].map(|i| b[i] + w[i] * travel),
                joint_rad_s: [0, 1].map(|i| w[i] * speed),
            };
        }
        let torque_nm = if enable || tweak == Tweak::TorqueLeftOn {
            [0.3, -0.2]
        } else {
            [0.0; 2]
        };
        status.torque_nm = torque_nm;
        Frame {
            status,
            enable,
            torque_nm,
            plant,
        }
    }
}

/// Runs `scenario`'s checker over the synthetic machine; returns the verdict and the report.
fn run_fault(
    scenario: Scenario,
    fault: Fault,
    fault_at: u32,
    tweak: Tweak,
) -> (Verdict, Option<StopReport>) {
    run_fault_coasting(COAST, scenario, fault, fault_at, tweak)
}

/// [`run_fault`] with the checker bounding a coast by `coast`.
fn run_fault_coasting(
    coast: CoastModel,
    scenario: Scenario,
    fault: Fault,
    fault_at: u32,
    tweak: Tweak,
) -> (Verdict, Option<StopReport>) {
    let img = image(D_RAD);
    let frames = synthetic(&img, fault, fault_at, tweak);
    let mut c = Checker::new(
        scenario,
        CorrectionGrid::parse(&img),
        &Settings::default(),
        3_000,
        INJECTION,
        coast,
    );
    for k in 0..MAX_TICKS {
        let f = frames(k);
        let o = Observation {
            status: &f.status,
            drive_enable: f.enable,
            drive_enable_ever: true,
            drive_torque_nm: f.torque_nm,
            plant: f.plant,
        };
        if let Some(v) = c.observe(&o) {
            return (Some(v), c.stop_report());
        }
    }
    (None, c.stop_report())
}

#[test]
fn category_two_passes_only_braking_within_the_plan_and_holding() {
    let jump = Fault::Setpoint(SetpointRefusal::Jump);
    let (v, report) = run_fault(sc("jump"), jump, 1000, Tweak::None);
    assert_eq!(v, Some(Ok(())));
    let r = report.unwrap();
    // 1 m/s: 10.2 + 2.5 mm.
    assert!(
        (r.planned_mm - 12.70).abs() < 0.05 && (r.travelled_mm - r.planned_mm).abs() < 0.05,
        "{r:?}"
    );
    assert!((r.speed_mm_s - 1000.0).abs() < 5.0, "{r:?}");
    for (tweak, why) in [
        (Tweak::Overshoot(0.2), "the stop went further than planned"),
        (
            Tweak::EnableLow,
            "drive enable low during a category-2 stop",
        ),
        (Tweak::Drift, "the tool does not hold the stop's end point"),
        (Tweak::NotHolding, "the loop is not holding after the stop"),
    ] {
        assert_eq!(run_fault(sc("jump"), jump, 1000, tweak).0, Some(Err(why)));
    }
    assert_eq!(
        run_fault(sc("jump"), jump, 1001, Tweak::None).0,
        Some(Err("no fault in the sample the fault was injected in"))
    );
    assert_eq!(
        run_fault(sc("jump"), jump, 999, Tweak::None).0,
        Some(Err("fault not in the sample the fault was injected in"))
    );
    assert_eq!(
        run_fault(sc("jump"), Fault::Underrun, 1000, Tweak::None).0,
        Some(Err("wrong fault"))
    );
    assert_eq!(
        run_fault(sc("underrun"), Fault::Underrun, 1000, Tweak::None).0,
        Some(Ok(()))
    );
}

#[test]
fn category_one_passes_only_with_torque_removed_after_the_stop() {
    let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
    let (v, report) = run_fault(sc("nan-setpoint"), nan, 1000, Tweak::None);
    assert_eq!(v, Some(Ok(())));
    assert!(report.unwrap().torque_off_after > 20);
    assert_eq!(
        run_fault(sc("nan-setpoint"), nan, 1000, Tweak::NeverOff).0,
        Some(Err("torque not removed after the stop"))
    );
    assert_eq!(
        run_fault(sc("nan-setpoint"), nan, 1000, Tweak::Overshoot(0.2)).0,
        Some(Err("the stop went further than planned"))
    );
}

#[test]
fn category_zero_passes_only_with_the_hardware_off_a_braked_coast_and_the_tool_inside() {
    let at = INJECTION.top_speed_sample + 2;
    let (v, report) = run_fault(sc("overrun"), Fault::DeadlineMissed, at, Tweak::None);
    assert_eq!(v, Some(Ok(())));
    let r = report.unwrap();
    assert!(
        r.joint_travel_rad
            .iter()
            .zip(r.coast_bound_rad)
            .all(|(t, b)| *t <= b && b > 0.0),
        "{r:?}"
    );
    for (tweak, why) in [
        (Tweak::EnableLeftOn, "drive enable still on after the fault"),
        (Tweak::TorqueLeftOn, "torque commanded after the fault"),
        (
            Tweak::Pushed,
            "a joint coasted further than the dynamic-braking bound",
        ),
        (
            Tweak::NeverAtRest,
            "the joints are not at rest at the end of the coast",
        ),
    ] {
        assert_eq!(
            run_fault(sc("overrun"), Fault::DeadlineMissed, at, tweak).0,
            Some(Err(why)),
            "{why}"
        );
    }
    // Checked against a free-wheeling drive's bound (no dynamic braking), a coast that goes
    // on at speed leaves the calibrated rectangle first: the workspace bound holds on its own.
    let free = CoastModel {
        dynamic_brake_nm_s_per_rad: 0.0,
        ..COAST
    };
    let (v, report) = run_fault_coasting(
        free,
        sc("overrun"),
        Fault::DeadlineMissed,
        at,
        Tweak::Pushed,
    );
    assert_eq!(v, Some(Err("the tool left the calibrated rectangle")));
    assert!(report.unwrap().left_workspace);
    // An encoder fault at rest must also keep the tool inside and barely moving.
    let stuck = Fault::Encoder(EncoderFault {
        axis: 0,
        kind: EncoderFaultKind::Stuck,
    });
    assert_eq!(
        run_fault(sc("encoder-frozen-at-rest"), stuck, 910, Tweak::None).0,
        Some(Err("the tool travelled further than the scenario allows"))
    );
    let glitch = Fault::Encoder(EncoderFault {
        axis: 0,
        kind: EncoderFaultKind::Acceleration,
    });
    assert_eq!(
        run_fault(sc("glitch-small"), glitch, 1000, Tweak::None).0,
        Some(Ok(()))
    );
    assert_eq!(
        run_fault(sc("glitch-large"), glitch, 1000, Tweak::None).0,
        Some(Err("wrong fault"))
    );
    assert_eq!(
        run_fault(sc("encoder-frozen-moving"), glitch, 1005, Tweak::None).0,
        Some(Ok(()))
    );
}

#[test]
fn drives_off_before_the_fault_fail() {
    let img = image(D_RAD);
    let s = running(5, D_RAD);
    assert_eq!(
        checker(sc("nan-setpoint"), &img).observe(&off(&s)),
        Some(Err("drives not enabled before the fault"))
    );
}

#[test]
fn out_of_reach_fails_if_an_out_of_grid_setpoint_was_accepted() {
    let img = image(D_RAD);
    let mut c = checker(sc("out-of-reach"), &img);
    assert_eq!(
        c.observe(&on(&Status {
            setpoint_mm: [263.0, 0.0],
            ..running(2_999, D_RAD)
        })),
        None
    );
    let s = Status {
        fault: Some(Fault::StopOutsideWorkspace),
        ..running(3_000, D_RAD)
    };
    assert_eq!(
        c.observe(&on(&s)),
        Some(Err("an out-of-grid setpoint was accepted"))
    );
    let mut c = checker(sc("out-of-reach"), &img);
    assert_eq!(c.observe(&on(&running(2_999, D_RAD))), None);
    let s = Status {
        fault: Some(Fault::Setpoint(SetpointRefusal::Kinematics(
            KinematicsError::Unreachable,
        ))),
        ..running(3_000, D_RAD)
    };
    assert_eq!(c.observe(&on(&s)), Some(Err("wrong fault")));
}

#[test]
fn a_bad_image_passes_only_if_the_drives_were_never_enabled() {
    let refused = |ticks| Status {
        calibration: CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
        fault: Some(Fault::Calibration(ImageError::Grid(GridError::BadCrc))),
        torque_nm: [0.0; 2],
        ..running(ticks, D_RAD)
    };
    fn never(s: &Status) -> Observation<'_> {
        Observation {
            drive_enable_ever: false,
            ..off(s)
        }
    }
    let settings = Settings::default();
    let mut c = Checker::new(
        sc("bad-image-crc"),
        Err(GridError::BadCrc),
        &settings,
        0,
        INJECTION,
        COAST,
    );
    for ticks in 1..BAD_IMAGE_TICKS {
        assert_eq!(c.observe(&never(&refused(ticks))), None);
    }
    assert_eq!(c.observe(&never(&refused(BAD_IMAGE_TICKS))), Some(Ok(())));
    // Enabled once, even if off now.
    assert_eq!(
        c.observe(&off(&refused(5))),
        Some(Err("drives enabled at a boot that must keep them off"))
    );
    let wrong = Status {
        calibration: CalibrationState::Refused(ImageError::Grid(GridError::BadMagic)),
        ..refused(BAD_IMAGE_TICKS)
    };
    assert!(matches!(c.observe(&never(&wrong)), Some(Err(_))));
}

/// Runs `track` to its end with the reference carrying correction `applied` while the
/// image holds `D_RAD`.
fn run_track(applied: [f32; 2], img_d: [f32; 2]) -> Verdict {
    let img = image(img_d);
    let mut c = checker(sc("track"), &img);
    for ticks in 1..MAX_TICKS {
        if let Some(v) = c.observe(&on(&running(ticks, applied))) {
            return Some(v);
        }
    }
    None
}

#[test]
fn track_fails_on_an_image_without_its_extension_blocks() {
    let img = plain_image(D_RAD);
    let mut c = checker(sc("track"), &img);
    let verdict = (1..MAX_TICKS).find_map(|ticks| c.observe(&on(&running(ticks, D_RAD))));
    assert_eq!(
        verdict,
        Some(Err("the image lacks its workspace or dynamics block"))
    );
}

#[test]
fn track_passes_only_if_the_grid_is_applied_and_large_enough_to_tell() {
    assert_eq!(run_track(D_RAD, D_RAD), Some(Ok(())));
    // Grid validated but not applied: the reference is the bare IK.
    assert_eq!(
        run_track([0.0; 2], D_RAD),
        Some(Err(
            "commanded angle minus model IK is not the grid correction: grid not applied"
        ))
    );
    // An image whose corrections are too small to tell.
    assert_eq!(
        run_track([1e-5, 0.0], [1e-5, 0.0]),
        Some(Err(
            "grid corrections too small to tell an applied grid from a missing one"
        ))
    );
    let img = image(D_RAD);
    let mut c = checker(sc("track"), &img);
    for ticks in 1..5_000 {
        c.observe(&on(&running(ticks, D_RAD)));
    }
    let g = c.grid_check();
    assert!(
        g.checks >= 10 && g.worst_residual_rad <= MAX_GRID_RESIDUAL_RAD,
        "{g:?}"
    );
    assert_eq!(g.largest_correction_rad, 3e-4);
}

#[test]
fn track_fails_on_a_fault_a_low_enable_line_or_a_bound() {
    let img = image(D_RAD);
    let s = running(10, D_RAD);
    assert_eq!(
        checker(sc("track"), &img).observe(&off(&s)),
        Some(Err("drives not enabled"))
    );
    let s = Status {
        fault: Some(Fault::Drive),
        ..running(10, D_RAD)
    };
    assert_eq!(
        checker(sc("track"), &img).observe(&on(&s)),
        Some(Err("unexpected fault"))
    );
    let end = MIN_TRACK_TICKS.max(3_000 + SETTLE_TICKS);
    for (bad, why) in [
        (
            Status {
                overruns: 1,
                ..running(end, D_RAD)
            },
            "deadline overrun",
        ),
        (
            Status {
                worst_step_us: 501.0,
                ..running(end, D_RAD)
            },
            "step longer than the deadline",
        ),
        (
            Status {
                setpoint_underruns: 1,
                ..running(end, D_RAD)
            },
            "setpoint queue ran empty",
        ),
        (
            Status {
                max_following_error_rad: 3e-4,
                ..running(end, D_RAD)
            },
            "following error above bound",
        ),
        (
            Status {
                encoder_rad: [0.81, -0.75],
                ..running(end, D_RAD)
            },
            "settled tool error above bound",
        ),
    ] {
        let mut c = checker(sc("track"), &img);
        for ticks in 1..end {
            assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None);
        }
        assert_eq!(c.observe(&on(&bad)), Some(Err(why)));
    }
}

#[test]
fn stalled_task_stalls_at_top_speed_and_the_machine_must_run_until_then() {
    let (i, at) = (&INJECTION, INJECTION.top_speed_sample);
    let stalls: Vec<u32> = (0..5_000)
        .filter(|&k| sc("stalled-task").stall_at(i, k))
        .collect();
    assert_eq!(stalls, [at]);
    for s in [sc("run"), sc("overrun"), sc("watchdog-restart")] {
        assert!(!s.stall_at(i, at));
    }
    let img = image(D_RAD);
    let mut c = checker(sc("stalled-task"), &img);
    // Status ticks count the samples done: sample `at` (the stall) would be tick at + 1.
    for ticks in 1..=at {
        assert_eq!(c.observe(&on(&running(ticks, D_RAD))), None, "tick {ticks}");
    }
    assert_eq!(
        c.observe(&on(&running(at + 1, D_RAD))),
        Some(Err("the servo task completed a sample after the stall"))
    );
    // Before the stall the machine must run.
    let s = running(5, D_RAD);
    assert_eq!(
        checker(sc("stalled-task"), &img).observe(&off(&s)),
        Some(Err("drives not enabled before the stall"))
    );
    let s = Status {
        fault: Some(Fault::Drive),
        ..running(5, D_RAD)
    };
    assert_eq!(
        checker(sc("stalled-task"), &img).observe(&on(&s)),
        Some(Err("fault before the stall"))
    );
    let s = running(5, D_RAD);
    let mut outside = on(&s);
    outside.plant.joint_rad = FiveBar::<f32>::paper_nominal()
        .inverse([200.0, 100.0], 0.05)
        .unwrap();
    assert_eq!(
        checker(sc("stalled-task"), &img).observe(&outside),
        Some(Err(
            "the tool left the calibrated rectangle before the stall"
        ))
    );
}

fn fired(o: WatchdogObservation) -> WatchdogVerdict {
    sc("stalled-task").watchdog_fired(&o)
}

#[test]
fn a_watchdog_interrupt_passes_only_if_it_removed_torque_within_the_timeout_of_the_stall() {
    // Fed at t = 1000 µs, stalled 40 µs later, fired exactly the timeout after the feed.
    let good = WatchdogObservation {
        stalled_at_us: Some(1_040.0),
        last_feed_at_us: Some(1_000.0),
        fired_at_us: 1_000.0 + TIMEOUT_US,
        drive_enable_at_fire: true,
        drive_enable: false,
        drive_torque_nm: [0.0; 2],
    };
    assert_eq!(fired(good), WatchdogVerdict::AsExpected);
    for (bad, why) in [
        (
            WatchdogObservation {
                stalled_at_us: None,
                ..good
            },
            "watchdog fired before the servo task was stalled",
        ),
        (
            WatchdogObservation {
                last_feed_at_us: None,
                ..good
            },
            "the watchdog was never fed",
        ),
        (
            WatchdogObservation {
                drive_enable_at_fire: false,
                ..good
            },
            "drives already off when the watchdog fired: the test proves nothing",
        ),
        (
            WatchdogObservation {
                drive_enable: true,
                ..good
            },
            "drive enable still on after the watchdog fired",
        ),
        (
            WatchdogObservation {
                drive_torque_nm: [0.0, 0.1],
                ..good
            },
            "torque commanded after the watchdog fired",
        ),
        // Fed long before the stall: the watchdog's timeout is right but torque came off late.
        (
            WatchdogObservation {
                stalled_at_us: Some(900.0),
                last_feed_at_us: Some(0.0),
                fired_at_us: 4_000.0,
                ..good
            },
            "torque not removed within the watchdog timeout of the stall",
        ),
        (
            WatchdogObservation {
                fired_at_us: 1_000.0 + TIMEOUT_US + 200.0,
                stalled_at_us: Some(1_300.0),
                ..good
            },
            "the watchdog did not fire its stated timeout after the last feed",
        ),
        (
            WatchdogObservation {
                fired_at_us: 1_000.0 + 0.5 * TIMEOUT_US,
                ..good
            },
            "the watchdog did not fire its stated timeout after the last feed",
        ),
        (
            WatchdogObservation {
                fired_at_us: f32::NAN,
                ..good
            },
            "torque not removed within the watchdog timeout of the stall",
        ),
    ] {
        assert_eq!(fired(bad), WatchdogVerdict::Fail(why), "{bad:?}");
    }
    // The production path: torque off, wait for the reset. Any other test: a failure.
    assert_eq!(sc("run").watchdog_fired(&good), WatchdogVerdict::Production);
    for s in [
        sc("track"),
        sc("long-run"),
        sc("overrun"),
        sc("watchdog-restart"),
    ] {
        assert_eq!(
            s.watchdog_fired(&good),
            WatchdogVerdict::Fail("watchdog fired: the servo task did not complete on time")
        );
    }
}

#[test]
fn the_boot_after_the_stall_must_keep_the_drives_off_and_the_machine_coast_as_category_zero() {
    assert_eq!(
        sc("stalled-task").after_reset(ResetCause::Watchdog),
        sc("watchdog-restart")
    );
    assert_eq!(
        sc("stalled-task").after_reset(ResetCause::PowerOnOrBrownOut),
        sc("stalled-task")
    );
    assert_eq!(sc("track").after_reset(ResetCause::Watchdog), sc("track"));
    let restarted = |ticks, fault| Status {
        fault: Some(fault),
        torque_nm: [0.0; 2],
        drives_enabled: false,
        ..running(ticks, D_RAD)
    };
    fn never(s: &Status) -> Observation<'_> {
        Observation {
            drive_enable_ever: false,
            ..off(s)
        }
    }
    let img = image(D_RAD);
    let reset = Fault::Watchdog(WatchdogFault::Reset);
    // The machine at the watchdog's interrupt: where `running` has it, at rest.
    let kept = plant_of(&running(1, D_RAD));
    let restart = || {
        let mut c = checker(sc("watchdog-restart"), &img);
        c.coast_after_reset(kept);
        c
    };
    let mut c = restart();
    for ticks in 1..=BAD_IMAGE_TICKS {
        assert_eq!(
            c.observe(&never(&restarted(ticks, reset))),
            None,
            "tick {ticks}"
        );
    }
    // Passes once both the boot's 0.5 s and the coast's 1000 samples are over.
    assert_eq!(
        c.observe(&never(&restarted(BAD_IMAGE_TICKS + 1, reset))),
        Some(Ok(()))
    );
    assert_eq!(c.fault_sample(), Some(0));
    assert_eq!(
        restart().observe(&never(&restarted(
            BAD_IMAGE_TICKS + 1,
            Fault::DeadlineMissed
        ))),
        Some(Err("watchdog reset not reported as the fault"))
    );
    assert_eq!(
        restart().observe(&off(&restarted(3, reset))),
        Some(Err("drives enabled at a boot that must keep them off"))
    );
    // The machine's state did not survive the reset: nothing to check the coast against.
    assert_eq!(
        checker(sc("watchdog-restart"), &img).observe(&never(&restarted(3, reset))),
        Some(Err("the machine's state at the watchdog's interrupt did not reach the boot after the reset"))
    );
    // A coast from rest that moves 0.01 rad: beyond the bound (0 rad plus round-off).
    let s = restarted(3, reset);
    let mut moved = never(&s);
    moved.plant.joint_rad[0] += 0.01;
    assert_eq!(
        restart().observe(&moved),
        Some(Err(
            "a joint coasted further than the dynamic-braking bound"
        ))
    );
    // Kept at speed, the bound is the dynamic-braking one from that speed: 1 rad/s on joint 1
    // is 9.4 mrad; 5 mrad passes, 12 mrad fails.
    let fast = PlantState {
        joint_rad_s: [1.0, 0.0],
        ..kept
    };
    for (travel, verdict) in [
        (5e-3, None),
        (
            12e-3,
            Some(Err(
                "a joint coasted further than the dynamic-braking bound",
            )),
        ),
    ] {
        let mut c = checker(sc("watchdog-restart"), &img);
        c.coast_after_reset(fast);
        let mut o = never(&s);
        o.plant.joint_rad[0] += travel;
        assert_eq!(c.observe(&o), verdict, "{travel}");
        let r = c.stop_report().unwrap();
        assert!(
            (r.coast_bound_rad[0] - 2.2e-3 / 0.235).abs() < 1e-6,
            "{r:?}"
        );
    }
}

/// A running status for `track-5g`: the setpoint oscillates ±5 mm in x at 101 rad/s (5.2 g
/// at the turning points) until sample 3000, then rests at `P_MM`; while it moves the
/// encoders lag the reference by `lag_rad` on axis 1.
fn oscillating(ticks: u32, lag_rad: f32) -> Status {
    let t = ticks.saturating_sub(1) as f32 * crate::SAMPLE_PERIOD_S;
    let x = if ticks < 3_000 {
        P_MM[0] + 5.0 * libm::sinf(101.0 * t)
    } else {
        P_MM[0]
    };
    let p = [x, P_MM[1]];
    let ik = FiveBar::<f32>::paper_nominal().inverse(p, 0.05).unwrap();
    let reference = [ik[0] + D_RAD[0], ik[1] + D_RAD[1]];
    Status {
        setpoint_mm: p,
        reference_rad: reference,
        encoder_rad: [
            reference[0] - if ticks < 3_000 { lag_rad } else { 0.0 },
            reference[1],
        ],
        ..running(ticks, D_RAD)
    }
}

fn run_track_5g(lag_rad: f32, oscillate: bool) -> (Verdict, MotionCheck) {
    let img = image(D_RAD);
    let mut c = checker(sc("track-5g"), &img);
    for ticks in 1..MAX_TICKS {
        let s = if oscillate {
            oscillating(ticks, lag_rad)
        } else {
            running(ticks, D_RAD)
        };
        if let Some(v) = c.observe(&on(&s)) {
            return (Some(v), c.motion_check());
        }
    }
    (None, c.motion_check())
}

#[test]
fn track_5g_needs_5g_moves_and_a_small_following_error_at_the_tool() {
    let (v, m) = run_track_5g(0.0, true);
    assert_eq!(v, Some(Ok(())), "{m:?}");
    assert!(
        m.samples_at_5g >= MIN_SAMPLES_AT_5G && m.max_following_error_um < 1e-3,
        "{m:?}"
    );
    // 1e-4 rad on motor 1 is about 15 µm at the tool: above the bound.
    let (v, m) = run_track_5g(1.0e-4, true);
    assert_eq!(
        v,
        Some(Err("following error at the tool above the 5 g bound")),
        "{m:?}"
    );
    assert!(m.max_following_error_um > MAX_FOLLOWING_ERROR_5G_UM);
    // 2e-5 rad: a few µm, within.
    let (v, m) = run_track_5g(2.0e-5, true);
    assert_eq!(v, Some(Ok(())), "{m:?}");
    assert!(m.max_following_error_um > 1.0, "{m:?}");
    // Standing still: no 5 g at all.
    let (v, _) = run_track_5g(0.0, false);
    assert_eq!(v, Some(Err("too few samples at 5 g")));
    let g5 = 5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
    assert_eq!(
        sc("track-5g").trajectory((Profile::Quintic, 1.0)),
        (Profile::JerkLimited, g5)
    );
    assert_eq!(
        sc("track").trajectory((Profile::Quintic, 1.0)),
        (Profile::Quintic, 1.0)
    );
}

#[test]
fn self_tests_that_return_fail() {
    let img = image(D_RAD);
    for s in [sc("panic"), sc("hard-fault")] {
        assert!(matches!(
            checker(s, &img).observe(&on(&running(1, D_RAD))),
            Some(Err(_))
        ));
    }
}

#[test]
fn tool_error_undoes_the_correction() {
    let img = image(D_RAD);
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let theta = cal.command_rad(P_MM, 0.05).unwrap();
    assert!(tool_error_mm(&cal, theta, P_MM).unwrap() < 1e-4);
    let bare = FiveBar::<f32>::paper_nominal().inverse(P_MM, 0.05).unwrap();
    // Without the correction the tool is ~50 µm off (3e-4 rad at 150 mm).
    assert!(tool_error_mm(&cal, bare, P_MM).unwrap() > 0.02);
}
