use super::*;
use crate::fault::StopCategory;
use crate::homing::HomingPhase;
use crate::stop::MotionState;
use crate::watchdog::WatchdogFault;
use heapless::spsc::Queue;
use kinematics_core::grid::{encode, CorrectionGrid, GridGeometry};
use kinematics_core::{EngageError, FiveBar, GridError, SetpointRefusal};

use crate::calibration::ImageError;
use crate::encoder_check::{EncoderFault, EncoderFaultKind};
use crate::setpoints::QUEUE_SLOTS;
use crate::stop::stopping_distance_bound_mm;
use crate::waypoint_moves::{Trajectory, WORKSPACE_TOUR_MM};

const HOME_MM: [f32; 2] = [212.132, 0.0];

/// The default settings with absolute encoders: the servo engages at boot (the QEMU
/// plant's encoders in every scenario but homing's).
fn absolute() -> Settings {
    let mut s = Settings::default();
    s.homing.absolute_encoders = true;
    s
}

fn image() -> Vec<u8> {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[3e-4, -2e-4]; 9]).unwrap();
    img
}

/// Boots on a valid image with the machine at the home pose.
fn running<'a>(settings: &'a Settings, img: &'a [u8]) -> (ServoLoop<'a>, [f32; 2]) {
    let cal = Calibration::from_grid(CorrectionGrid::parse(img).unwrap());
    let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
    let l = ServoLoop::boot(settings, cal, CalibrationState::Valid, encoder);
    assert_eq!(l.mode(), Mode::Running);
    (l, encoder)
}

#[test]
fn boot_engages_where_the_machine_is() {
    let (settings, img) = (absolute(), image());
    let (l, encoder) = running(&settings, &img);
    assert!(l.drives_enabled());
    let p = l.setpoint_mm();
    assert!(
        (p[0] - HOME_MM[0]).abs() < 1e-3 && (p[1] - HOME_MM[1]).abs() < 1e-3,
        "{p:?}"
    );
    assert_eq!(l.reference_rad(), encoder);
}

#[test]
fn a_refused_image_keeps_the_loop_safe_and_leaves_the_queue_alone() {
    let settings = absolute();
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
    let mut l = ServoLoop::boot(
        &settings,
        cal,
        CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
        encoder,
    );
    assert_eq!(
        l.mode(),
        Mode::SafeState(Fault::Calibration(ImageError::Grid(GridError::BadCrc)))
    );
    assert!(!l.drives_enabled());
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    for _ in 0..3 {
        let s = l.step(&mut rx, encoder);
        assert_eq!(s.torque_nm, [0.0; 2]);
        assert_eq!((s.fault, s.underrun, s.refill), (None, false, false));
    }
    assert_eq!(
        rx.len(),
        1,
        "nothing taken from the queue in the safe state"
    );
    // Uncorrected running allowed: engages with the nominal model.
    let l = ServoLoop::boot(
        &settings,
        cal,
        CalibrationState::Uncorrected(ImageError::Grid(GridError::BadCrc)),
        encoder,
    );
    assert_eq!(l.mode(), Mode::Running);
}

#[test]
fn boot_refuses_an_encoder_reading_the_kinematics_refuse() {
    // Encoder zero: both arms stretched along x, the distal links cannot meet.
    let (settings, img) = (absolute(), image());
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
    assert!(
        matches!(
            l.mode(),
            Mode::SafeState(Fault::Engage(EngageError::Kinematics(_)))
        ),
        "{:?}",
        l.mode()
    );
}

#[test]
fn boot_refuses_an_encoder_configuration_the_scale_refuses() {
    use crate::encoder::EncoderConfigError;
    let img = image();
    let mut settings = absolute();
    settings.encoders[1].counts_per_rev = 0;
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
    let l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, encoder);
    let want = Fault::Settings(SettingsError::Encoder {
        axis: 1,
        error: EncoderConfigError::ZeroCountsPerRev,
    });
    assert_eq!(l.mode(), Mode::SafeState(want));
}

/// A refused setpoint must not remove torque at once whatever the speed. At rest,
/// a NaN (category 1) stops at once (an empty stop) and removes torque at standstill, in the
/// same sample; the stop from rest holds the last accepted setpoint.
#[test]
fn a_nan_setpoint_at_rest_removes_torque_at_standstill() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    tx.enqueue(MotionSetpoint::at_rest([f32::NAN, 0.0]))
        .unwrap();
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    let s = l.step(&mut rx, encoder);
    assert!(s.fault.is_none() && !s.torque_off);
    let s = l.step(&mut rx, encoder);
    let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
    assert_eq!(
        (s.fault, s.torque_off, s.torque_nm),
        (Some(nan), true, [0.0; 2])
    );
    assert_eq!(
        s.setpoint_mm, HOME_MM,
        "the last accepted setpoint, not the NaN"
    );
    assert_eq!(l.mode(), Mode::SafeState(nan));
    assert_eq!(l.stop_profile().map(|p| p.distance_mm()), Some(0.0));
    let s = l.step(&mut rx, encoder);
    assert_eq!(
        (s.fault, s.torque_nm, s.torque_off),
        (None, [0.0; 2], false),
        "latched once, zero ever after"
    );
    assert_eq!(rx.len(), 1);
}

#[test]
fn an_empty_queue_holds_the_last_setpoint_and_asks_for_a_refill() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    let s = l.step(&mut rx, encoder);
    assert!(s.underrun && s.refill && s.fault.is_none());
    assert_eq!(s.setpoint_mm, l.setpoint_mm());
    while tx.ready() {
        tx.enqueue(MotionSetpoint::at_rest(l.setpoint_mm()))
            .unwrap();
    }
    let s = l.step(&mut rx, encoder);
    assert!(!s.underrun && !s.refill, "{} left", rx.len());
    while rx.len() >= REFILL_BELOW {
        rx.dequeue();
    }
    assert!(l.step(&mut rx, encoder).refill);
}

#[test]
fn a_streak_of_overruns_latches_deadline_missed_once() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (_, mut rx) = q.split();
    for k in 0..settings.overrun_streak_limit {
        let mut s = l.step(&mut rx, encoder);
        l.record_deadline(700.0, true, &mut s);
        let last = k + 1 == settings.overrun_streak_limit;
        assert_eq!(
            s.fault,
            last.then_some(Fault::DeadlineMissed),
            "overrun {k}"
        );
    }
    assert_eq!(l.mode(), Mode::SafeState(Fault::DeadlineMissed));
    let mut s = l.step(&mut rx, encoder);
    l.record_deadline(700.0, true, &mut s);
    assert_eq!(s.fault, None, "already safe: nothing new latched");
    assert_eq!(l.deadline().overruns, settings.overrun_streak_limit + 1);
}

#[test]
fn only_an_on_time_step_feeds_the_watchdog_and_the_safe_state_still_does() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (_, mut rx) = q.split();
    let s = l.step(&mut rx, encoder);
    assert!(!s.feed_watchdog, "no deadline recorded, no feed");
    let mut s = l.step(&mut rx, encoder);
    l.record_deadline(15.0, false, &mut s);
    assert!(s.feed_watchdog);
    let mut s = l.step(&mut rx, encoder);
    l.record_deadline(700.0, true, &mut s);
    assert!(!s.feed_watchdog, "late");
    let mut s = l.step(&mut rx, encoder);
    l.record_deadline(f32::NAN, false, &mut s);
    assert!(!s.feed_watchdog, "step time unreadable");
    // In the safe state the drives are off and the task still runs on time: it feeds.
    l.latch(Fault::Drive, &mut s);
    let mut s = l.step(&mut rx, encoder);
    l.record_deadline(10.0, false, &mut s);
    assert!(s.feed_watchdog && !l.drives_enabled());
}

#[test]
fn a_fault_at_boot_keeps_the_drives_off_and_the_first_reason_is_kept() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    l.latch_at_boot(Fault::Watchdog(WatchdogFault::Reset));
    assert_eq!(
        l.mode(),
        Mode::SafeState(Fault::Watchdog(WatchdogFault::Reset))
    );
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    let s = l.step(&mut rx, [encoder[0] + 1e-3, encoder[1]]);
    assert_eq!((s.torque_nm, s.fault), ([0.0; 2], None));
    // A refused image at boot stays the reason reported.
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let mut l = ServoLoop::boot(
        &settings,
        cal,
        CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
        encoder,
    );
    l.latch_at_boot(Fault::Watchdog(WatchdogFault::NotStarted));
    assert_eq!(
        l.mode(),
        Mode::SafeState(Fault::Calibration(ImageError::Grid(GridError::BadCrc)))
    );
}

#[test]
fn a_failed_pwm_write_latches_a_drive_fault() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (_, mut rx) = q.split();
    let mut s = l.step(&mut rx, [encoder[0] + 1e-5, encoder[1]]);
    assert!(s.torque_nm[0] != 0.0);
    l.latch(Fault::Drive, &mut s);
    assert_eq!(
        (s.fault, s.torque_nm, s.torque_off),
        (Some(Fault::Drive), [0.0; 2], true)
    );
    assert!(!l.drives_enabled());
}

#[test]
fn the_reference_is_model_ik_plus_the_grid_correction() {
    let (settings, img) = (absolute(), image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    let s = l.step(&mut rx, encoder);
    assert!(s.fault.is_none());
    let ik = FiveBar::<f32>::paper_nominal()
        .inverse(HOME_MM, 0.05)
        .unwrap();
    assert!(
        (s.reference_rad[0] - ik[0] - 3e-4).abs() < 1e-6,
        "{:?} vs {ik:?}",
        s.reference_rad
    );
    assert!((s.reference_rad[1] - ik[1] + 2e-4).abs() < 1e-6);
}

// -----------------------------------------------------------------------------------------
// Closed loop: the servo loop against two joint inertias with friction (the QEMU plant's
// parameters: its rotors plus the diagonal of its linkage's inertia matrix, 5.4e-3 kg·m²,
// without the coupling), the encoders quantised to 2^22 counts/rev.

const DT_S: f32 = crate::SAMPLE_PERIOD_S;

use crate::host_link::doubles::JointPlant as Plant;

/// What a closed run saw.
struct Run {
    samples: Vec<Sample>,
    modes: Vec<Mode>,
    /// The plant's joint angles after each sample's torque acted (rad).
    angles: Vec<[f32; 2]>,
    enabled: Vec<bool>,
}

/// Runs `n` samples from HOME: `setpoint(k)` is queued before sample k (`None`: nothing),
/// `reading(k, encoder)` is what the loop reads.
fn closed(
    settings: &Settings,
    cal: Calibration<'_>,
    n: usize,
    setpoint: impl FnMut(usize) -> Option<[f32; 2]>,
    reading: impl FnMut(usize, [f32; 2]) -> [f32; 2],
) -> Run {
    closed_with_requests(settings, cal, n, setpoint, reading, |_| None)
}

/// [`closed`], with `request(k)` applied before sample k (as the servo task does).
fn closed_with_requests(
    settings: &Settings,
    cal: Calibration<'_>,
    n: usize,
    mut setpoint: impl FnMut(usize) -> Option<[f32; 2]>,
    mut reading: impl FnMut(usize, [f32; 2]) -> [f32; 2],
    mut request: impl FnMut(usize) -> Option<ServoRequest>,
) -> Run {
    let start = cal.command_rad(HOME_MM, 0.05).unwrap();
    let mut plant = Plant {
        angle_rad: start,
        velocity_rad_s: [0.0; 2],
        torque_nm: [0.0; 2],
        enabled: true,
    };
    let mut l = ServoLoop::boot(settings, cal, CalibrationState::Valid, plant.encoder_rad());
    assert_eq!(l.mode(), Mode::Running);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    let mut run = Run {
        samples: vec![],
        modes: vec![],
        angles: vec![],
        enabled: vec![],
    };
    for k in 0..n {
        if let Some(p) = setpoint(k) {
            // Full once the loop stops taking setpoints (stopping, holding, safe state).
            // Positions only (a source without derivatives): no inertia fed forward.
            let _ = tx.enqueue(MotionSetpoint::at_rest(p));
        }
        if let Some(r) = request(k) {
            if let Ok(true) = l.request(r, &mut rx, reading(k, plant.encoder_rad())) {
                plant.enabled = true;
            }
        }
        let s = l.step(&mut rx, reading(k, plant.encoder_rad()));
        if s.torque_off {
            plant.enabled = false;
        }
        plant.torque_nm = s.torque_nm;
        plant.advance();
        run.samples.push(s);
        run.modes.push(l.mode());
        run.angles.push(plant.angle_rad);
        run.enabled.push(plant.enabled);
    }
    run
}

fn tour() -> Trajectory {
    let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
    Trajectory::new(HOME_MM, &WORKSPACE_TOUR_MM, 2.0 * g, 1500.0, 0.1, DT_S)
}

/// The sample of the tour's top speed, and that speed (mm/s).
fn top_speed() -> (usize, f32) {
    let mut t = tour();
    let mut last = t.next_mm();
    let mut best = (0, 0.0f32);
    for k in 1..t.total_samples() as usize {
        let p = t.next_mm();
        let v = libm::hypotf(p[0] - last[0], p[1] - last[1]) / DT_S;
        if v > best.1 {
            best = (k, v);
        }
        last = p;
    }
    best
}

fn tool_mm(cal: &Calibration<'_>, theta: [f32; 2]) -> [f32; 2] {
    let p = cal.model.forward(theta, 0.0).unwrap();
    let d = cal
        .grid
        .as_ref()
        .map_or([0.0; 2], |g| g.correction_rad(p).unwrap_or([0.0; 2]));
    cal.model
        .forward([theta[0] - d[0], theta[1] - d[1]], 0.0)
        .unwrap()
}

fn grid_cal(img: &[u8]) -> Calibration<'_> {
    Calibration::from_grid(CorrectionGrid::parse(img).unwrap())
}

/// The whole built-in tour at 2 g / 1.5 m/s, closed around the plant: the encoder check,
/// the workspace check and the underrun logic never trip.
#[test]
fn the_tour_runs_without_a_false_trip() {
    let (settings, img) = (absolute(), image());
    let mut t = tour();
    let n = t.total_samples() as usize + 200;
    let run = closed(
        &settings,
        grid_cal(&img),
        n,
        |_| Some(t.next_mm()),
        |_, e| e,
    );
    let faults: Vec<_> = run.samples.iter().filter_map(|s| s.fault).collect();
    assert!(faults.is_empty(), "{faults:?}");
    assert!(run.modes.iter().all(|m| *m == Mode::Running));
    let worst = run
        .samples
        .iter()
        .map(|s| s.following_error_rad)
        .fold(0.0, f32::max);
    assert!(worst < 2e-4, "following error {worst}");
}

/// Injects a fault through `inject` at the tour's top speed and returns the run, the
/// sample, and the stated stopping distance from the last accepted setpoint (its speed and
/// acceleration along the path from the setpoints).
fn stop_at_top_speed(
    settings: &Settings,
    img: &[u8],
    n: usize,
    inject: impl Fn(usize, [f32; 2]) -> Option<[f32; 2]>,
) -> (Run, usize, f32) {
    let (at, _) = top_speed();
    let mut t = tour();
    let run = closed(
        settings,
        grid_cal(img),
        at + n,
        |k| inject(k.wrapping_sub(at), t.next_mm()),
        |_, e| e,
    );
    let [p1, p2, p3] = [1, 2, 3].map(|j| run.samples[at - j].setpoint_mm);
    let v = [0, 1].map(|k| (p1[k] - p2[k]) / DT_S);
    let a = [0, 1].map(|k| (p1[k] - 2.0 * p2[k] + p3[k]) / (DT_S * DT_S));
    let m = MotionState::from_differences(p1, v, a, DT_S);
    let along = (m.accel_mm_s2[0] * m.velocity_mm_s[0] + m.accel_mm_s2[1] * m.velocity_mm_s[1])
        / m.speed_mm_s();
    (
        run,
        at,
        stopping_distance_bound_mm(m.speed_mm_s(), along, &settings.stop.limits),
    )
}

/// Checks a controlled stop from sample `at`: the stop's setpoints end at the stated
/// distance `bound_mm` from its origin (the last accepted setpoint) within 0.1 %; the tool
/// gets no further from the origin than that plus 0.1 mm (tracking) and stays inside the
/// calibrated rectangle. Returns (planned, travelled) in mm.
fn check_controlled_stop(cal: &Calibration<'_>, run: &Run, at: usize, bound_mm: f32) -> (f32, f32) {
    let from = run.samples[at - 1].setpoint_mm;
    let end = run.samples[run.samples.len() - 1].setpoint_mm;
    let planned = libm::hypotf(end[0] - from[0], end[1] - from[1]);
    assert!(
        (planned - bound_mm).abs() <= 1e-3 * bound_mm,
        "planned {planned} mm, stated {bound_mm}"
    );
    let mut furthest = 0.0f32;
    for k in at..run.angles.len() {
        let p = tool_mm(cal, run.angles[k]);
        furthest = furthest.max(libm::hypotf(p[0] - from[0], p[1] - from[1]));
        assert!(
            (160.0..=260.0).contains(&p[0]) && (-80.0..=80.0).contains(&p[1]),
            "left the rectangle: {p:?}"
        );
    }
    assert!(
        furthest <= planned + 0.1 && furthest >= planned - 0.1,
        "stopped in {furthest} mm, planned {planned}"
    );
    (planned, furthest)
}

/// A NaN at 1.4 m/s must not remove torque at once (the machine would coast 20-130 mm).
/// Now: category 1, braked along the path within the stated distance, torque off at
/// standstill, never before.
#[test]
fn a_nan_at_top_speed_brakes_along_the_path_then_removes_torque() {
    let (settings, img) = (absolute(), image());
    let (run, at, bound) = stop_at_top_speed(&settings, &img, 300, |k, p| {
        Some(if k == 0 { [p[0], f32::NAN] } else { p })
    });
    let nan = Fault::Setpoint(SetpointRefusal::NonFinite);
    assert_eq!(run.samples[at].fault, Some(nan));
    assert!(
        run.samples[at].torque_nm != [0.0; 2],
        "the fault's sample already brakes"
    );
    let off = run
        .samples
        .iter()
        .position(|s| s.torque_off)
        .expect("torque never removed");
    let stop = (settings.stop.limits.decel_mm_s2, bound);
    let duration = ((off - at) as f32) * DT_S;
    assert!(
        duration < 0.05 + 0.005,
        "torque removed {duration} s after the fault ({stop:?})"
    );
    assert!(run.enabled[..off].iter().all(|&e| e) && run.enabled[off..].iter().all(|&e| !e));
    assert!(run.samples[off..].iter().all(|s| s.torque_nm == [0.0; 2]));
    assert_eq!(run.modes[off], Mode::SafeState(nan));
    let (planned, travelled) = check_controlled_stop(&grid_cal(&img), &run, at, bound);
    println!("NaN at {at}: planned {planned:.3} mm (stated {bound:.3} mm), tool {travelled:.3} mm, torque off after {duration} s");
}

/// A setpoint jump at top speed: category 2, braked, then held with the drives on.
#[test]
fn a_jump_at_top_speed_brakes_then_holds() {
    let (settings, img) = (absolute(), image());
    let (run, at, bound) = stop_at_top_speed(&settings, &img, 300, |k, p| {
        Some(if k < 1000 { [p[0] + 1.0, p[1]] } else { p })
    });
    let jump = Fault::Setpoint(SetpointRefusal::Jump);
    assert_eq!(run.samples[at].fault, Some(jump));
    assert_eq!(run.modes[run.modes.len() - 1], Mode::Holding(jump));
    assert!(run.enabled.iter().all(|&e| e) && !run.samples.iter().any(|s| s.torque_off));
    check_controlled_stop(&grid_cal(&img), &run, at, bound);
    // Holding: from 50 ms after the stop within 20 µm of its end point (the integrator
    // gives back what it took on during the 5 g stop: ~10 µm for ~100 ms), the last 50
    // samples within a micrometre.
    let cal = grid_cal(&img);
    let end = run.samples[run.samples.len() - 1].setpoint_mm;
    let stop_end = at
        + run.modes[at..]
            .iter()
            .position(|m| matches!(m, Mode::Holding(_)))
            .unwrap();
    let error = |a: &[f32; 2]| {
        let p = tool_mm(&cal, *a);
        libm::hypotf(p[0] - end[0], p[1] - end[1])
    };
    let worst = run.angles[stop_end + 100..]
        .iter()
        .map(error)
        .fold(0.0, f32::max);
    assert!(worst < 0.02, "holding {worst} mm off the stop's end");
    let last = tool_mm(&cal, run.angles[run.angles.len() - 1]);
    for a in &run.angles[run.angles.len() - 50..] {
        let p = tool_mm(&cal, *a);
        assert!(
            libm::hypotf(p[0] - last[0], p[1] - last[1]) < 1e-3,
            "still moving: {p:?} vs {last:?}"
        );
    }
}

/// An empty queue for one sample at speed read as an infinite deceleration. Now:
/// category 2 from the last setpoint; at rest it just holds.
#[test]
fn an_underrun_while_moving_brakes_then_holds() {
    let (settings, img) = (absolute(), image());
    let (run, at, bound) =
        stop_at_top_speed(&settings, &img, 300, |k, p| (k >= 1 << 30).then_some(p));
    assert_eq!(run.samples[at].fault, Some(Fault::Underrun));
    assert!(run.samples[at].underrun);
    assert_eq!(
        run.modes[run.modes.len() - 1],
        Mode::Holding(Fault::Underrun)
    );
    check_controlled_stop(&grid_cal(&img), &run, at, bound);
}

/// The host's Stop at top speed is the same controlled stop (category 2, then hold); a
/// reset re-engages where it held, dropping what was queued; Disable brakes and
/// removes torque, and a reset turns the drives back on.
#[test]
fn a_commanded_stop_brakes_then_holds_and_a_reset_resumes() {
    let (settings, img) = (absolute(), image());
    let (at, _) = top_speed();
    let mut t = tour();
    let n = at + 401;
    let run = closed_with_requests(
        &settings,
        grid_cal(&img),
        n,
        |_| Some(t.next_mm()),
        |_, e| e,
        |k| match k {
            _ if k == at => Some(ServoRequest::Stop),
            _ if k == at + 1 => Some(ServoRequest::Reset), // refused: stopping
            _ if k == at + 400 => Some(ServoRequest::Reset),
            _ => None,
        },
    );
    assert_eq!(
        run.samples[at].fault, None,
        "a request takes effect from the next sample's stop"
    );
    assert_eq!(run.modes[at], Mode::Stopping(Fault::StopCommanded));
    assert_eq!(
        run.modes[at + 1],
        Mode::Stopping(Fault::StopCommanded),
        "reset refused during the stop"
    );
    assert_eq!(run.modes[at + 399], Mode::Holding(Fault::StopCommanded));
    assert_eq!(
        run.modes[at + 400],
        Mode::Running,
        "the reset dropped the tour's queued setpoints"
    );
    // The stop braked along the path, within its bound from the last accepted setpoint.
    let from = run.samples[at - 1].setpoint_mm;
    let end = run.samples[at + 399].setpoint_mm;
    let v = libm::hypotf(
        from[0] - run.samples[at - 2].setpoint_mm[0],
        from[1] - run.samples[at - 2].setpoint_mm[1],
    ) / DT_S;
    let travelled = libm::hypotf(end[0] - from[0], end[1] - from[1]);
    let bound = stopping_distance_bound_mm(v, 2.0 * 9806.65, &settings.stop.limits);
    assert!(
        travelled > 0.0 && travelled <= bound,
        "{travelled} mm, bound {bound} mm"
    );

    // Direct: disable at rest, reset turns the drives back on, a boot fault is permanent.
    let (mut l, enc) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, enc),
        Ok(false),
        "running: nothing to reset"
    );
    assert_eq!(l.request(ServoRequest::Disable, &mut rx, enc), Ok(false));
    let mut torque_off = false;
    for _ in 0..200 {
        torque_off |= l.step(&mut rx, enc).torque_off;
    }
    assert!(torque_off);
    assert_eq!(l.mode(), Mode::SafeState(Fault::DisableCommanded));
    let _ = tx.enqueue(MotionSetpoint::at_rest([200.0, 10.0]));
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, enc),
        Ok(true),
        "drives back on"
    );
    assert_eq!(l.mode(), Mode::Running);
    assert_eq!(rx.len(), 0, "the stale setpoint was dropped");
    let boot_fault = Fault::Calibration(ImageError::Grid(GridError::BadCrc));
    let nominal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let mut l = ServoLoop::boot(
        &settings,
        nominal,
        CalibrationState::Refused(ImageError::Grid(GridError::BadCrc)),
        enc,
    );
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, enc),
        Err(ResetRefusal::Permanent(boot_fault))
    );
}

/// A stream that heads for the edge of the calibrated rectangle too fast to stop before it
/// is refused early enough: the stop ends inside (the setpoint that would not is never
/// tracked), whereas the servo alone would accept setpoints up to the grid's edge.
#[test]
fn a_stream_too_fast_for_the_edge_is_stopped_inside() {
    let (settings, img) = (absolute(), image());
    let cal = grid_cal(&img);
    let (run, at) = towards_x_320(&settings, cal);
    assert_eq!(run.samples[at].fault, Some(Fault::StopOutsideWorkspace));
    assert!(run
        .samples
        .iter()
        .all(|s| s.setpoint_mm[0] <= 260.0 - settings.stop.workspace_margin_mm));
    assert!(matches!(
        run.modes[run.modes.len() - 1],
        Mode::Holding(Fault::StopOutsideWorkspace)
    ));
    let end = tool_mm(&cal, run.angles[run.angles.len() - 1]);
    assert!(
        end[0] <= 260.0 - 0.09 && end[0] > 230.0,
        "stopped at {end:?}"
    );
    // The speed when refused: well above what could stop in the last millimetre.
    let v = (run.samples[at - 1].setpoint_mm[0] - run.samples[at - 2].setpoint_mm[0]) / DT_S;
    assert!(v > 1000.0, "{v} mm/s");
}

/// From home towards x = 320 mm (beyond the grid's 260 mm edge) at 2 g / 1.5 m/s: the run and
/// the sample of its first fault.
fn towards_x_320<'a>(settings: &Settings, cal: Calibration<'a>) -> (Run, usize) {
    let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
    let mut t = Trajectory::new(HOME_MM, &[[320.0, 0.0]], 2.0 * g, 1500.0, 0.1, DT_S);
    let run = closed(settings, cal, 800, |_| Some(t.next_mm()), |_, e| e);
    let at = run.samples.iter().position(|s| s.fault.is_some()).unwrap();
    (run, at)
}

/// With the machine's workspace in the image, the edge is the polygon's, not the
/// grid's: the same stream towards x = 320 mm is stopped inside the polygon's right edge
/// at x = 240 mm (20 mm before the grid's), by the image's stop margin of 0.5 mm.
#[test]
fn the_edge_is_the_images_workspace_when_it_has_one() {
    use kinematics_core::grid::{append_workspace, WorkspaceLimits, WORKSPACE_LEN};
    use kinematics_core::ConvexWorkspace;
    let settings = absolute();
    let mut img = image();
    let n = img.len();
    img.resize(n + WORKSPACE_LEN, 0);
    let region =
        ConvexWorkspace::new(&[[170.0, -70.0], [240.0, -70.0], [240.0, 70.0], [170.0, 70.0]])
            .unwrap();
    append_workspace(
        &mut img,
        n,
        n,
        &WorkspaceLimits {
            region,
            stop_margin_mm: 0.5,
        },
    )
    .unwrap();
    let cal = grid_cal(&img);
    let (run, at) = towards_x_320(&settings, cal);
    assert_eq!(run.samples[at].fault, Some(Fault::StopOutsideWorkspace));
    assert!(
        run.samples.iter().all(|s| s.setpoint_mm[0] <= 240.0 - 0.5),
        "a setpoint beyond the polygon's edge"
    );
    let end = tool_mm(&cal, run.angles[run.angles.len() - 1]);
    assert!(
        end[0] <= 240.0 - 0.45 && end[0] > 215.0,
        "stopped at {end:?}"
    );
}

/// An encoder frozen during a stop, and a glitch while moving: category 0 at once, even
/// mid-stop (the stop never hides a feedback fault).
#[test]
fn encoder_faults_remove_torque_at_once_even_during_a_stop() {
    let (settings, img) = (absolute(), image());
    let (at, _) = top_speed();
    // A jump at top speed starts a category-2 stop; 10 samples into it the encoder of axis
    // 1 freezes (mid-stop, decelerating at 5 g).
    let mut t = tour();
    let mut frozen = None;
    let run = closed(
        &settings,
        grid_cal(&img),
        at + 100,
        |k| {
            Some(if k >= at {
                [t.next_mm()[0] + 1.0, 0.0]
            } else {
                t.next_mm()
            })
        },
        |k, e| {
            if k >= at + 10 {
                [e[0], *frozen.get_or_insert(e[1])]
            } else {
                e
            }
        },
    );
    let bad = run
        .samples
        .iter()
        .position(|s| {
            s.fault
                .is_some_and(|f| f.stop_category() == StopCategory::Zero)
        })
        .unwrap();
    // Joint 2 turns slower than 3 rad/s there: the stuck check, not the acceleration check,
    // finds it, within a few samples.
    assert!(
        (at + 10..=at + 20).contains(&bad),
        "found at {bad}, frozen at {}",
        at + 10
    );
    assert!(matches!(
        run.samples[bad].fault,
        Some(Fault::Encoder(EncoderFault { axis: 1, .. }))
    ));
    assert!(run.samples[bad].torque_off && run.samples[bad].torque_nm == [0.0; 2]);
    assert!(matches!(
        run.modes[run.modes.len() - 1],
        Mode::SafeState(Fault::Encoder(_))
    ));
    // A 5 mrad glitch at top speed: caught in its sample.
    let mut t = tour();
    let run = closed(
        &settings,
        grid_cal(&img),
        at + 10,
        |_| Some(t.next_mm()),
        |k, e| if k == at { [e[0] + 5e-3, e[1]] } else { e },
    );
    assert_eq!(
        run.samples[at].fault,
        Some(Fault::Encoder(EncoderFault {
            axis: 0,
            kind: EncoderFaultKind::Acceleration
        }))
    );
    assert!(run.samples[at].torque_off);
}

/// An encoder frozen at rest went unnoticed until the machine moved, then 8 N·m
/// drove the tool 43 mm off. Now the move's torque finds joint 1's reading stuck a few
/// samples after the move starts, the tool a fraction of a millimetre off; then it coasts
/// (category 0) from the low speed it had.
#[test]
fn an_encoder_frozen_at_rest_is_stuck_as_soon_as_the_machine_is_asked_to_move() {
    let (settings, img) = (absolute(), image());
    let cal = grid_cal(&img);
    let mut t = tour();
    // Rest 50 samples at home (the tour starts with a move), joint 1 frozen from sample 20.
    let mut frozen = None;
    let run = closed(
        &settings,
        cal,
        1000,
        |k| Some(if k < 50 { HOME_MM } else { t.next_mm() }),
        |k, e| {
            if k >= 20 {
                [*frozen.get_or_insert(e[0]), e[1]]
            } else {
                e
            }
        },
    );
    let bad = run
        .samples
        .iter()
        .position(|s| s.fault.is_some())
        .expect("not detected");
    assert_eq!(
        run.samples[bad].fault,
        Some(Fault::Encoder(EncoderFault {
            axis: 0,
            kind: EncoderFaultKind::Stuck
        }))
    );
    assert!(run.samples[bad].torque_off);
    let p0 = tool_mm(&cal, run.angles[19]);
    let off = |k: usize| {
        let p = tool_mm(&cal, run.angles[k]);
        libm::hypotf(p[0] - p0[0], p[1] - p0[1])
    };
    let at_detection = off(bad);
    let coasted = (bad..run.angles.len()).map(off).fold(0.0, f32::max);
    println!(
        "frozen at rest: stuck {} samples after the move started, tool {at_detection:.3} mm off, {coasted:.3} mm after the coast",
        bad - 50
    );
    assert!(bad > 50 && bad <= 50 + 30, "detected at sample {bad}");
    assert!(
        at_detection < 0.5,
        "tool {at_detection} mm off at detection"
    );
    assert!(coasted < 3.0, "coasted to {coasted} mm");
}

/// Without a grid (running uncorrected) there is no rectangle to check a stop against: a
/// stop the kinematics refuse on the way ends in category 0.
#[test]
fn a_stop_the_servo_refuses_is_category_zero() {
    let settings = absolute();
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let g = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
    // A stream along +x: 2 g up to 0.5 m/s, then cruising towards the 300 mm reach (a host
    // stream could do that, meaning to brake late); a NaN once past 297 mm, where the
    // 3.8 mm stop would end beyond the reach.
    let (mut x, mut v, mut nan_sent) = (HOME_MM[0], 0.0f32, false);
    let run = closed(
        &settings,
        cal,
        600,
        |_| {
            if x >= 297.0 && !nan_sent {
                nan_sent = true;
                return Some([f32::NAN, 0.0]);
            }
            v = (v + 2.0 * g * DT_S).min(500.0);
            x += v * DT_S;
            Some([x, 0.0])
        },
        |_, e| e,
    );
    let faults: Vec<Fault> = run.samples.iter().filter_map(|s| s.fault).collect();
    assert_eq!(
        faults.first(),
        Some(&Fault::Setpoint(SetpointRefusal::NonFinite)),
        "{faults:?}"
    );
    assert!(
        matches!(
            faults.get(1),
            Some(Fault::StopRefused(SetpointRefusal::Kinematics(_)))
        ),
        "{faults:?}"
    );
    assert!(matches!(
        run.modes[run.modes.len() - 1],
        Mode::SafeState(Fault::StopRefused(_))
    ));
}

/// The homing plan is checked at boot: settings whose search runs into a singularity keep
/// the drives off.
#[test]
fn a_homing_plan_near_a_singularity_is_refused_at_boot() {
    use crate::homing::{Direction, HomingFault};
    let img = image();
    let mut settings = Settings::default();
    settings.homing.search_direction = [Direction::Negative, Direction::Positive];
    settings.homing.index_rad = [0.10, -0.10];
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
    assert_eq!(l.mode(), Mode::SafeState(Fault::Homing(HomingFault::Plan)));
    assert!(l.start_homing([0.0; 2]).is_err() && !l.drives_enabled());
}

/// The host link's Home request: starts homing from `Unhomed` (drives on), nothing twice, and
/// nothing on a machine that is already running (a homed machine is not re-homed).
#[test]
fn a_home_request_starts_homing_only_from_unhomed() {
    let (settings, img) = (Settings::default(), image());
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (_, mut rx) = q.split();
    assert_eq!(l.mode(), Mode::Unhomed);
    assert_eq!(l.homing_phase(), None);
    assert_eq!(
        l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
        Ok(true),
        "drives on"
    );
    assert_eq!(
        (l.mode(), l.homing_phase()),
        (Mode::Homing, Some(HomingPhase::Search(0)))
    );
    assert_eq!(
        l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
        Ok(false),
        "not twice"
    );
    assert_eq!(l.mode(), Mode::Homing);
    // A fault while homing: the safe state; no reset engages the unhomed machine, it goes
    // back to Unhomed with the drives off, and Home runs again (no reboot).
    let mut sample = l.step_homing([0.0; 2], [None; 2]);
    l.latch(Fault::DeadlineMissed, &mut sample);
    assert_eq!(l.mode(), Mode::SafeState(Fault::DeadlineMissed));
    assert_eq!(
        l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
        Ok(false),
        "not before the fault is reset"
    );
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, [0.0; 2]),
        Ok(false),
        "nothing to enable"
    );
    assert_eq!(
        (l.mode(), l.homing_phase(), l.drives_enabled()),
        (Mode::Unhomed, None, false)
    );
    let s = l.step(&mut rx, [0.0; 2]);
    assert_eq!(
        (s.torque_nm, s.fault),
        ([0.0; 2], None),
        "Unhomed: zero torque"
    );
    assert_eq!(
        l.request(ServoRequest::Home, &mut rx, [0.0; 2]),
        Ok(true),
        "homing again, drives on"
    );
    assert_eq!(
        (l.mode(), l.homing_phase()),
        (Mode::Homing, Some(HomingPhase::Search(0)))
    );
    // The same after a fault latched at boot (a watchdog reset) before homing.
    let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
    l.latch_at_boot(Fault::DeadlineMissed);
    assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(false));
    assert!(!l.drives_enabled());
    assert_eq!(l.request(ServoRequest::Reset, &mut rx, [0.0; 2]), Ok(false));
    assert_eq!((l.mode(), l.drives_enabled()), (Mode::Unhomed, false));
    assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(true));
    // A watchdog that did not start is permanent: no reset, no homing, drives off.
    let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
    let nowd = Fault::Watchdog(WatchdogFault::NotStarted);
    l.latch_at_boot(nowd);
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, [0.0; 2]),
        Err(ResetRefusal::Permanent(nowd))
    );
    assert_eq!(l.request(ServoRequest::Home, &mut rx, [0.0; 2]), Ok(false));
    assert_eq!(
        (l.mode(), l.drives_enabled()),
        (Mode::SafeState(nowd), false)
    );
    let absolute = Settings {
        homing: crate::homing::HomingSettings {
            absolute_encoders: true,
            ..settings.homing
        },
        ..settings
    };
    let at = cal.command_rad(HOME_MM, 0.05).unwrap();
    let mut l = ServoLoop::boot(&absolute, cal, CalibrationState::Valid, at);
    assert_eq!(l.mode(), Mode::Running);
    assert_eq!(l.request(ServoRequest::Home, &mut rx, at), Ok(false));
    assert_eq!((l.mode(), l.homing_phase()), (Mode::Running, None));
    // Absolute encoders and a watchdog that did not start: no reset engages the drives
    // (before, a reset cleared it like any fault and the machine ran without a watchdog).
    let mut l = ServoLoop::boot(&absolute, cal, CalibrationState::Valid, at);
    l.latch_at_boot(nowd);
    assert_eq!(
        l.request(ServoRequest::Reset, &mut rx, at),
        Err(ResetRefusal::Permanent(nowd))
    );
    assert!(!l.drives_enabled());
}

/// Incremental encoders (the default): the loop boots `Unhomed`, drives off, refusing the
/// queue; homing against the joint plant (indexes at the settings' angles, counters reading
/// 0 at power-on) references the encoders and engages at home; the tour's first setpoint is
/// then accepted. An index that never comes ends in the safe state at rest.
#[test]
fn an_unhomed_machine_refuses_setpoints_until_homing_engages_it_at_home() {
    use crate::homing::HomingFault;
    let (settings, img) = (Settings::default(), image());
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let power_on = cal.command_rad([230.0, -30.0], 0.05).unwrap();
    for index_on_axis_2 in [true, false] {
        let mut plant = Plant {
            angle_rad: power_on,
            velocity_rad_s: [0.0; 2],
            torque_nm: [0.0; 2],
            enabled: false,
        };
        let relative = |p: &Plant, offset: [f32; 2]| {
            [0, 1].map(|k| p.encoder_rad()[k] - power_on[k] + offset[k])
        };
        let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, [0.0; 2]);
        assert_eq!(l.mode(), Mode::Unhomed);
        assert!(!l.drives_enabled());
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
        let s = l.step(&mut rx, [0.0; 2]);
        assert_eq!((s.torque_nm, s.fault), ([0.0; 2], None));
        assert_eq!(rx.len(), 1, "an unhomed machine takes no setpoint");
        l.start_homing([0.0; 2]).unwrap();
        assert_eq!(l.start_homing([0.0; 2]), Err(Mode::Homing), "not twice");
        plant.enabled = true;
        let index_rad = settings.homing.index_rad;
        let (mut offset, mut latched) = ([0.0; 2], [false; 2]);
        let (mut end, mut before) = (None, plant.angle_rad);
        for k in 0..20_000 {
            let reading = relative(&plant, offset);
            let index = [0, 1].map(|a| {
                let crossed =
                    (before[a] - index_rad[a]) * (plant.angle_rad[a] - index_rad[a]) <= 0.0;
                (crossed && !latched[a] && (a == 0 || index_on_axis_2)).then(|| {
                    latched[a] = true;
                    index_rad[a] - power_on[a]
                })
            });
            before = plant.angle_rad;
            let mut s = l.step_homing(reading, index);
            if s.set_reference {
                l.referenced(true, &mut s);
                offset = power_on;
            }
            assert!(s
                .torque_nm
                .iter()
                .all(|t| t.abs() <= settings.homing.torque_limit_nm));
            if s.torque_off {
                plant.enabled = false;
            }
            plant.torque_nm = s.torque_nm;
            plant.advance();
            if l.mode() != Mode::Homing {
                end = Some((k, s));
                break;
            }
        }
        let (k, s) = end.expect("homing did not end");
        if index_on_axis_2 {
            assert_eq!(l.mode(), Mode::Running, "after {k} samples");
            let p = l.setpoint_mm();
            assert!(
                (p[0] - HOME_MM[0]).abs() < 0.01 && (p[1] - HOME_MM[1]).abs() < 0.01,
                "engaged at {p:?}"
            );
            // The readings are absolute: the task-space servo takes the queued setpoint.
            let s = l.step(&mut rx, relative(&plant, offset));
            assert!(
                s.fault.is_none() && s.torque_nm != [0.0; 2] && rx.is_empty(),
                "{s:?}"
            );
            assert!(plant.enabled);
        } else {
            assert_eq!(
                l.mode(),
                Mode::SafeState(Fault::Homing(HomingFault::IndexNotFound(1)))
            );
            assert!(s.torque_off && !plant.enabled);
            assert!(
                plant.velocity_rad_s.iter().all(|w| w.abs() < 0.05),
                "{:?}",
                plant.velocity_rad_s
            );
            assert_eq!(rx.len(), 1);
        }
    }
}

/// A calibration committed while the tour runs: the loop switches in the next dwell (not
/// while moving), without a torque step; after the blend the reference carries the new
/// grid's correction and the tour goes on without a fault.
#[test]
fn a_new_calibration_is_switched_to_at_rest_without_a_jump() {
    let settings = absolute();
    let img = image();
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut new_img = vec![0u8; g.image_len()];
    encode(
        &mut new_img,
        &g,
        &FiveBar::paper_nominal(),
        &[[-3e-4, 2e-4]; 9],
    )
    .unwrap();
    let (old, new) = (grid_cal(&img), grid_cal(&new_img));
    let start = old.command_rad(HOME_MM, 0.05).unwrap();
    let mut plant = Plant {
        angle_rad: start,
        velocity_rad_s: [0.0; 2],
        torque_nm: [0.0; 2],
        enabled: true,
    };
    let mut l = ServoLoop::boot(&settings, old, CalibrationState::Valid, plant.encoder_rad());
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    let mut t = tour();
    let (mut pending, mut switched_at, mut last_torque, mut worst_step) =
        (false, None, [0.0f32; 2], 0.0f32);
    for k in 0..6000 {
        while tx.ready() && !t.finished() {
            tx.enqueue(t.next_setpoint()).unwrap();
        }
        if k == 700 {
            pending = true;
        }
        if pending {
            match l.switch_calibration(new, plant.encoder_rad()) {
                Ok(()) => {
                    pending = false;
                    switched_at = Some(k);
                }
                Err(e) => assert_eq!(e, SwitchRefused::NotAtRest),
            }
        }
        let s = l.step(&mut rx, plant.encoder_rad());
        assert!(s.fault.is_none(), "sample {k}: {:?}", s.fault);
        if switched_at.is_some_and(|at| k >= at && k < at + 50) {
            worst_step = worst_step
                .max((s.torque_nm[0] - last_torque[0]).abs())
                .max((s.torque_nm[1] - last_torque[1]).abs());
        }
        last_torque = s.torque_nm;
        plant.torque_nm = s.torque_nm;
        plant.advance();
    }
    let at = switched_at.expect("never switched");
    assert!(at > 700, "switched at {at}");
    // The reference now carries the new correction: commanded minus IK is the new grid's.
    let p = l.setpoint_mm();
    let ik = FiveBar::<f32>::paper_nominal().inverse(p, 0.05).unwrap();
    let d = [l.reference_rad()[0] - ik[0], l.reference_rad()[1] - ik[1]];
    assert!(
        (d[0] + 3e-4).abs() < 2e-6 && (d[1] - 2e-4).abs() < 2e-6,
        "{d:?}"
    );
    println!("switched at sample {at}, largest torque change per sample in the next 50: {worst_step:.3} N·m");
    assert!(worst_step < 1.0, "{worst_step}");
}

mod reset_and_switch;
