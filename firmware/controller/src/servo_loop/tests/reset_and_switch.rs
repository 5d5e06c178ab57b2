//! What a reset clears, cell by cell of the table in [`crate::servo_loop::requests`]; and the
//! calibration switch: deferred while moving, at rest a move of at most the two calibrations'
//! difference, ramped in, never a fault, and every trace of it gone after a fault and a reset.
use super::*;
use crate::calibration_slots::CalibrationId;
use crate::encoder_check::{EncoderFault, EncoderFaultKind};
use crate::homing::{HomingFault, HomingSettings};
use crate::servo_loop::stops::Stop;
use crate::servo_loop::SwitchOutcome;
use crate::settings::SettingsError;
use crate::stop::StopProfile;
use crate::watchdog::WatchdogFault;
use kinematics_core::{ConfigError, KinematicsError, ServoFault};

/// One fault of every kind the loop can latch.
fn every_fault() -> Vec<Fault> {
    vec![
        Fault::Setpoint(SetpointRefusal::NonFinite),
        Fault::Setpoint(SetpointRefusal::Jump),
        Fault::StopOutsideWorkspace,
        Fault::Underrun,
        Fault::Servo(ServoFault::FollowingError),
        Fault::Encoder(EncoderFault {
            axis: 0,
            kind: EncoderFaultKind::Stuck,
        }),
        Fault::StopRefused(SetpointRefusal::Kinematics(KinematicsError::Unreachable)),
        Fault::DeadlineMissed,
        Fault::Drive,
        Fault::StopCommanded,
        Fault::DisableCommanded,
        Fault::Homing(HomingFault::IndexNotFound(1)),
        Fault::Homing(HomingFault::FollowingError(0)),
        Fault::Calibration(ImageError::Grid(GridError::BadCrc)),
        Fault::Settings(SettingsError::Servo(ConfigError::SamplePeriod)),
        Fault::Engage(EngageError::NonFiniteFeedback),
        Fault::Watchdog(WatchdogFault::Reset),
        Fault::Watchdog(WatchdogFault::NotStarted),
    ]
}

/// The states a reset can meet (the table's rows), the fault latched where there is one.
fn every_mode(f: Fault) -> [Mode; 6] {
    [
        Mode::Running,
        Mode::Stopping(f),
        Mode::Holding(f),
        Mode::SafeState(f),
        Mode::Unhomed,
        Mode::Homing,
    ]
}

/// What the table says a reset does from `mode` (`homed`: the encoder zero is known).
fn table(mode: Mode, homed: bool) -> (Result<bool, ResetRefusal>, Mode) {
    match mode {
        Mode::Running | Mode::Unhomed | Mode::Homing => (Ok(false), mode),
        Mode::Stopping(_) => (Err(ResetRefusal::Stopping), mode),
        Mode::Holding(f) | Mode::SafeState(f) if f.needs_reboot() => {
            (Err(ResetRefusal::Permanent(f)), mode)
        }
        Mode::Holding(_) if homed => (Ok(false), Mode::Running),
        Mode::SafeState(_) if homed => (Ok(true), Mode::Running),
        Mode::SafeState(_) => (Ok(false), Mode::Unhomed),
        Mode::Holding(_) => (Err(ResetRefusal::NotHomed), mode),
    }
}

/// A second image: the first one's corrections negated (0.6 mrad apart at every node).
fn other_image() -> Vec<u8> {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[-3e-4, 2e-4]; 9]).unwrap();
    img
}

const ID: CalibrationId = CalibrationId {
    slot: 1,
    sequence: 1,
    crc32: 0x1234_5678,
    len: 100,
};

/// Every cell of the reset table: for every fault and every mode (absolute encoders, homed;
/// incremental, never homed), the outcome, the mode after, and what is cleared: the stop, the
/// blend of a calibration switch, the queue; a machine that re-engaged then holds still at the
/// tool's position (the next setpoint taken from the queue, no fault), and a committed
/// calibration still pending is switched to at that rest.
#[test]
fn reset_table() {
    let img = image();
    let other = other_image();
    let mut cells = 0;
    for homed in [true, false] {
        let mut settings = Settings::default();
        settings.homing = HomingSettings {
            absolute_encoders: homed,
            ..settings.homing
        };
        for fault in every_fault() {
            for mode in every_mode(fault) {
                let cal = grid_cal(&img);
                let encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
                let mut l = ServoLoop::boot(&settings, cal, CalibrationState::Valid, encoder);
                // Put the loop in the cell's state, with everything a reset must clear.
                l.mode = mode;
                l.stop = Some(Stop {
                    profile: StopProfile::plan(&l.motion, &settings.stop.limits),
                    samples: 3,
                });
                let blend = kinematics_core::PathMotion::line(
                    HOME_MM,
                    [HOME_MM[0] + 0.1, HOME_MM[1]],
                    &settings.stream_limits(),
                )
                .unwrap();
                l.blend = Some(Blend::for_test(blend));
                l.offer_calibration(grid_cal(&other), ID);
                let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
                let (mut tx, mut rx) = q.split();
                tx.enqueue(MotionSetpoint::at_rest([200.0, 10.0])).unwrap();
                let cell = format!("{mode:?} homed {homed}");
                let (want, want_mode) = table(mode, homed);
                let got = l.request(ServoRequest::Reset, &mut rx, encoder);
                assert_eq!(got, want, "{cell}");
                assert_eq!(l.mode(), want_mode, "{cell}");
                cells += 1;
                let cleared = got.is_ok() && mode != want_mode;
                if !cleared {
                    // Nothing cleared: a refusal or a mode a reset does not touch.
                    assert!(l.blending() && rx.len() == 1, "{cell}: changed");
                    continue;
                }
                assert!(!l.blending(), "{cell}: the blend survived the reset");
                assert_eq!(l.stop_profile(), None, "{cell}: the stop survived");
                assert_eq!(rx.len(), 0, "{cell}: queued setpoints survived");
                assert_eq!(l.pending_calibration(), Some(ID), "{cell}: still pending");
                if want_mode != Mode::Running {
                    continue;
                }
                // At rest where it re-engaged: the pending calibration is switched to, the blend
                // brings the tool back there, then the queue is read (setpoints held there are
                // taken, no fault).
                let held = l.setpoint_mm();
                assert_eq!(
                    l.switch_pending(encoder),
                    Some(SwitchOutcome::Switched(ID)),
                    "{cell}"
                );
                let mut plant = Plant {
                    angle_rad: encoder,
                    velocity_rad_s: [0.0; 2],
                    torque_nm: [0.0; 2],
                    enabled: true,
                };
                for _ in 0..400 {
                    if tx.ready() {
                        tx.enqueue(MotionSetpoint::at_rest(held)).unwrap();
                    }
                    let s = l.step(&mut rx, plant.encoder_rad());
                    assert_eq!(s.fault, None, "{cell}");
                    plant.torque_nm = s.torque_nm;
                    plant.advance();
                }
                assert!(!l.blending(), "{cell}: the switch's blend ended");
                assert!(
                    rx.len() < QUEUE_SLOTS - 1,
                    "{cell}: the queue is read again"
                );
            }
        }
    }
    assert_eq!(cells, 2 * every_fault().len() * 6);
}

/// The reproduction: a good image committed while the machine holds after a stop, then a
/// reset, six times. Each reset must re-engage (`Running`, the drives on), the switch happen at
/// that rest, and the setpoint stay where the machine is (before, a blend never cleared kept
/// being stepped after every reset: the setpoint crept by micrometres per reset and the loop
/// ended `Holding(Setpoint)` again).
#[test]
fn resets_after_a_switch_under_way_re_engage_and_the_setpoint_stays() {
    let settings = absolute();
    let (img, other) = (image(), other_image());
    let old = grid_cal(&img);
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
    let mut index = NoIndex;
    let mut run = |l: &mut ServoLoop<'_>,
                   plant: &mut Plant,
                   request: Option<ServoRequest>,
                   offered: Option<(Calibration<'static>, CalibrationId)>| {
        let t = l.tick(request, offered, &mut rx, plant.encoder_rad(), &mut index);
        if t.enable_drives {
            plant.enabled = true;
        }
        if t.sample.torque_off {
            plant.enabled = false;
        }
        plant.torque_nm = t.sample.torque_nm;
        plant.advance();
        t
    };
    let _ = &mut tx;
    for _ in 0..50 {
        run(&mut l, &mut plant, None, None);
    }
    // Committed while running at rest: switched at once, the blend under way.
    let t = run(&mut l, &mut plant, None, Some((leaked(&other), ID)));
    assert_eq!(t.switch, Some(SwitchOutcome::Switched(ID)));
    assert!(l.blending());
    // A stop in the middle of the blend: held where the stop ended.
    run(&mut l, &mut plant, Some(ServoRequest::Stop), None);
    for _ in 0..200 {
        run(&mut l, &mut plant, None, None);
    }
    assert_eq!(l.mode(), Mode::Holding(Fault::StopCommanded));
    for reset in 0..6 {
        let t = run(&mut l, &mut plant, Some(ServoRequest::Reset), None);
        assert_eq!(t.sample.fault, None, "reset {reset}");
        assert_eq!(l.mode(), Mode::Running, "reset {reset}");
        assert!(!l.blending(), "reset {reset}: the blend survived");
        let engaged = l.setpoint_mm();
        for k in 0..200 {
            let t = run(&mut l, &mut plant, None, None);
            assert_eq!(t.sample.fault, None, "reset {reset}, sample {k}");
        }
        let p = l.setpoint_mm();
        assert!(
            libm::hypotf(p[0] - engaged[0], p[1] - engaged[1]) < 1e-4,
            "reset {reset}: the setpoint crept from {engaged:?} to {p:?}"
        );
        // Stopped again for the next reset.
        run(&mut l, &mut plant, Some(ServoRequest::Stop), None);
        for _ in 0..100 {
            run(&mut l, &mut plant, None, None);
        }
    }
}

/// A switch at rest moves the tool by the two calibrations' difference at its pose and no
/// more, ramped in at the switch's speed and acceleration, without a fault or a torque step;
/// one whose difference exceeds `switch.max_move_mm` is refused and nothing moves; while the
/// machine moves the switch stays pending.
#[test]
fn a_switch_at_rest_moves_the_tool_by_at_most_the_calibrations_difference() {
    let settings = absolute();
    let (img, other) = (image(), other_image());
    let (old, new) = (grid_cal(&img), grid_cal(&other));
    let start = old.command_rad(HOME_MM, 0.05).unwrap();
    // The difference at this pose: where each calibration puts the tool at the same reading.
    let difference_mm = {
        let (a, b) = (
            old.tool_mm(start, 0.05).unwrap(),
            new.tool_mm(start, 0.05).unwrap(),
        );
        libm::hypotf(a[0] - b[0], a[1] - b[1])
    };
    assert!(difference_mm > 0.05, "{difference_mm}");
    let mut plant = Plant {
        angle_rad: start,
        velocity_rad_s: [0.0; 2],
        torque_nm: [0.0; 2],
        enabled: true,
    };
    let mut l = ServoLoop::boot(&settings, old, CalibrationState::Valid, plant.encoder_rad());
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (_tx, mut rx) = q.split();
    let tool0 = tool_mm(&old, plant.angle_rad);
    let (mut furthest, mut fastest, mut worst_step, mut last) = (0.0f32, 0.0f32, 0.0f32, None);
    let mut previous = l.setpoint_mm();
    for k in 0..2000 {
        let offered = (k == 100).then(|| (leaked(&other), ID));
        let t = l.tick(None, offered, &mut rx, plant.encoder_rad(), &mut NoIndex);
        assert_eq!(t.sample.fault, None, "sample {k}");
        if k == 100 {
            assert_eq!(t.switch, Some(SwitchOutcome::Switched(ID)));
        }
        // The switch's own sample re-engages: the setpoint is where the new calibration puts
        // the tool, the reference the reading (no motion); the blend's setpoints follow.
        let p = t.sample.setpoint_mm;
        if k > 100 {
            fastest = fastest.max(libm::hypotf(p[0] - previous[0], p[1] - previous[1]) / DT_S);
        }
        previous = p;
        if let Some(last) = last {
            let step: [f32; 2] = t.sample.torque_nm;
            let last: [f32; 2] = last;
            worst_step = worst_step.max((step[0] - last[0]).abs().max((step[1] - last[1]).abs()));
        }
        last = Some(t.sample.torque_nm);
        plant.torque_nm = t.sample.torque_nm;
        plant.advance();
        let tool = tool_mm(&old, plant.angle_rad);
        furthest = furthest.max(libm::hypotf(tool[0] - tool0[0], tool[1] - tool0[1]));
    }
    println!(
        "switch at rest: difference {difference_mm:.4} mm, tool moved {furthest:.4} mm, setpoint speed {fastest:.1} mm/s, largest torque change {worst_step:.4} N·m per sample"
    );
    assert!(
        furthest <= difference_mm + 2e-3,
        "moved {furthest} mm for a {difference_mm} mm difference"
    );
    assert!(furthest >= 0.9 * difference_mm, "{furthest}");
    assert!(
        fastest <= settings.switch.speed_mm_s * 1.01,
        "{fastest} mm/s"
    );
    // The servo's own chatter on encoder counts (one count moves the derivative term by
    // 0.03 N·m) is all there is: no step from the switch (an implausible image's took 7.6 N·m).
    assert!(worst_step < 0.25, "{worst_step} N·m");
    assert!(!l.blending());

    // Beyond the bound: refused, the old calibration stays, nothing moves.
    let tight = Settings {
        switch: crate::settings::SwitchSettings {
            max_move_mm: 0.5 * difference_mm,
            ..settings.switch
        },
        ..settings
    };
    let (mut l, encoder) = running(&tight, &img);
    let before = (l.setpoint_mm(), l.reference_rad());
    let t = l.tick(
        None,
        Some((leaked(&other), ID)),
        &mut rx,
        encoder,
        &mut NoIndex,
    );
    assert!(
        matches!(
            t.switch,
            Some(SwitchOutcome::Refused(ID, SwitchRefused::TooFar { .. }))
        ),
        "{:?}",
        t.switch
    );
    assert_eq!((l.setpoint_mm(), l.reference_rad()), before);
    assert_eq!(l.pending_calibration(), None);
    assert!(!l.blending());
}

/// A switch offered while moving waits for the rest (pending, `NotAtRest` internally), and one
/// that cannot engage at the pose is refused with the old calibration untouched.
#[test]
fn a_switch_while_moving_stays_pending() {
    let settings = absolute();
    let (img, other) = (image(), other_image());
    let (mut l, encoder) = running(&settings, &img);
    let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
    let (mut tx, mut rx) = q.split();
    // Moving: a setpoint a little away, taken with its speed.
    l.motion =
        MotionState::from_differences([HOME_MM[0] + 0.01, HOME_MM[1]], [20.0, 0.0], [0.0; 2], DT_S);
    tx.enqueue(MotionSetpoint::at_rest(HOME_MM)).unwrap();
    let t = l.tick(
        None,
        Some((leaked(&other), ID)),
        &mut rx,
        encoder,
        &mut NoIndex,
    );
    assert_eq!(t.switch, None);
    assert_eq!(l.pending_calibration(), Some(ID));
    // A calibration whose grid does not cover the pose: refused at rest, nothing changed.
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 240.0,
        y0_mm: -80.0,
        step_x_mm: 10.0,
        step_y_mm: 80.0,
    };
    let mut far = vec![0u8; g.image_len()];
    encode(&mut far, &g, &FiveBar::paper_nominal(), &[[0.0; 2]; 9]).unwrap();
    let (mut l, encoder) = running(&settings, &img);
    let before = (l.setpoint_mm(), l.reference_rad());
    let t = l.tick(
        None,
        Some((leaked(&far), ID)),
        &mut rx,
        encoder,
        &mut NoIndex,
    );
    assert!(
        matches!(
            t.switch,
            Some(SwitchOutcome::Refused(ID, SwitchRefused::Engage(_)))
        ),
        "{:?}",
        t.switch
    );
    assert_eq!((l.setpoint_mm(), l.reference_rad()), before);
    let s = l.step(&mut rx, encoder);
    assert_eq!(s.fault, None);
}

/// No index capture (the machines here have absolute encoders).
struct NoIndex;

impl crate::servo_loop::IndexCapture for NoIndex {
    fn index_rad(&mut self) -> [Option<f32>; 2] {
        [None; 2]
    }
    fn reference_at_index(&mut self, _: [f32; 2]) -> bool {
        false
    }
}

/// The calibration of `img`, for the whole test (the loop borrows the one it switches to).
fn leaked(img: &[u8]) -> Calibration<'static> {
    let bytes: &'static [u8] = Vec::leak(img.to_vec());
    Calibration::from_grid(CorrectionGrid::parse(bytes).unwrap())
}
