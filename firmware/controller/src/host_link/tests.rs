//! The handler end to end on the host: frames in through the reader, replies out, with the real
//! servo loop and motion stream running in the [`Rig`].
use super::doubles::Rig;
use super::*;
use kinematics_core::grid::{encode as encode_grid, GridGeometry};
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use link_protocol::{CalibrationRefusal, FrameReader, Knot, MAX_FRAME_LEN};
use proptest::prelude::*;

use crate::calibration::image_id;
use crate::settings::Settings;

const HOME_MM: [f32; 2] = [212.132, 0.0];

fn image(offset_rad: f32) -> Vec<u8> {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode_grid(
        &mut img,
        &g,
        &FiveBar::paper_nominal(),
        &[[offset_rad, -2e-4]; 9],
    )
    .unwrap();
    img
}

/// The production settings with absolute encoders (the rig's machine needs no homing; the
/// handler's homing gate is tested with the homing double).
fn settings() -> Settings {
    let mut s = Settings::default();
    s.homing.absolute_encoders = true;
    s
}

fn rig<'a>(settings: &'a Settings, img: &'a [u8]) -> Rig<'a> {
    let cal = Calibration::from_grid(CorrectionGrid::parse(img).unwrap());
    let joints = cal.command_rad(HOME_MM, 0.05).unwrap();
    let mut r = Rig::boot(settings, cal, joints, image_id(img));
    r.step();
    r
}

/// Sends `command` as a frame through the reader and the handler; returns the reply.
fn send(
    h: &mut LinkHandler,
    rig: &mut Rig<'_>,
    seq: u16,
    command: Command,
) -> Result<Response, LinkError> {
    let mut frame = [0u8; MAX_FRAME_LEN];
    let n = encode(&Request::new(seq, command), &mut frame).unwrap();
    let replies = feed(h, rig, &frame[..n]);
    assert_eq!(replies.len(), 1, "one reply per frame");
    match replies.into_iter().next().unwrap().body {
        DeviceBody::Reply { seq: s, result } => {
            assert_eq!(s, seq);
            result
        }
        other => panic!("not a reply: {other:?}"),
    }
}

/// Feeds bytes through a fresh reader into the handler; returns every message it answered.
fn feed(h: &mut LinkHandler, rig: &mut Rig<'_>, bytes: &[u8]) -> Vec<DeviceMessage> {
    let mut reader = FrameReader::new();
    let mut out = Vec::new();
    for &b in bytes {
        if let Some(received) = reader.push(b) {
            let mut reply = [0u8; MAX_FRAME_LEN];
            let n = h.on_received(received, rig, &mut reply);
            assert!(n > 0, "never silence");
            out.push(decode::<DeviceMessage>(&mut reply[..n - 1]).unwrap());
        }
    }
    out
}

fn run(h: &mut LinkHandler, rig: &mut Rig<'_>, samples: usize) -> Vec<Status> {
    (0..samples)
        .map(|_| {
            rig.step();
            let _ = h.poll(rig);
            rig.status
        })
        .collect()
}

/// A several-second figure through the workspace: a Lissajous 30 × 40 mm around HOME, as
/// knots every 10 ms, starting and ending at rest (sin² envelope on the first and last 0.5 s).
fn figure_knots(seconds: f32) -> Vec<Knot> {
    let n = (seconds * 100.0) as u32;
    let ramp = 0.5f32;
    (1..=n)
        .map(|i| {
            let t = i as f32 * 0.01;
            let pos = |t: f32| {
                let env = if t < ramp {
                    libm::sinf(core::f32::consts::FRAC_PI_2 * t / ramp).powi(2)
                } else if t > seconds - ramp {
                    libm::sinf(core::f32::consts::FRAC_PI_2 * (seconds - t) / ramp).powi(2)
                } else {
                    1.0
                };
                let w = 2.0 * core::f32::consts::PI * 0.5;
                [
                    HOME_MM[0] + env * 30.0 * libm::sinf(w * t),
                    HOME_MM[1] + env * 40.0 * libm::sinf(2.0 * w * t),
                ]
            };
            let h = 1e-4;
            let (a, b) = (pos(t - h), pos((t + h).min(seconds)));
            let dt = (t + h).min(seconds) - (t - h);
            let v = if i == n {
                [0.0; 2]
            } else {
                [(b[0] - a[0]) / dt, (b[1] - a[1]) / dt]
            };
            Knot {
                t_us: i * 10_000,
                position_mm: if i == n { pos(seconds) } else { pos(t) },
                velocity_mm_s: v,
            }
        })
        .collect()
}

/// Streams `knots` keeping the buffer ahead, runs until done; returns the statuses.
fn stream(
    h: &mut LinkHandler,
    rig: &mut Rig<'_>,
    knots: &[Knot],
    extra_samples: usize,
) -> Vec<Status> {
    let mut sent = 0usize;
    let mut statuses = Vec::new();
    let mut seq = 100;
    while sent < knots.len() || rig.stream.is_moving() {
        while sent < knots.len() && rig.stream.free() >= 8 {
            let end = (sent + 8).min(knots.len());
            let frame = heapless::Vec::from_slice(&knots[sent..end]).unwrap();
            seq += 1;
            let r = send(
                h,
                rig,
                seq,
                Command::StreamKnots {
                    first_index: sent as u32,
                    knots: frame,
                },
            );
            assert!(matches!(r, Ok(Response::StreamAccepted { .. })), "{r:?}");
            sent = end;
        }
        statuses.extend(run(h, rig, 20));
        assert!(statuses.len() < 100_000);
    }
    statuses.extend(run(h, rig, extra_samples));
    statuses
}

#[test]
fn identify_and_status_answer() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let Ok(Response::Identity(id)) = send(&mut h, &mut r, 1, Command::Identify) else {
        panic!()
    };
    assert_eq!(
        (id.protocol_version, id.board, id.calibration_id),
        (PROTOCOL_VERSION, Board::Qemu, image_id(&img))
    );
    // The machine in force: the built-in one (this store judges nothing).
    let paper = kinematics_core::machine::MachineRecord::paper();
    assert_eq!(
        (id.machine.name(), id.machine.digest),
        ("paper", paper.digest())
    );
    assert!(id.calibration_id.is_some());
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 2, Command::Status) else {
        panic!()
    };
    assert_eq!(
        (s.mode, s.fault, s.drives_enabled, s.moving),
        (ModeCode::Running, None, true, false)
    );
    let other = Request {
        version: PROTOCOL_VERSION + 1,
        seq: 9,
        command: Command::Enable,
    };
    assert_eq!(
        h.handle(&other, &mut r),
        DeviceBody::Reply {
            seq: 9,
            result: Err(LinkError::Version(PROTOCOL_VERSION + 1))
        }
    );
}

#[test]
fn a_streamed_figure_is_tracked_and_ends_at_rest_where_it_should() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let knots = figure_knots(3.0);
    let statuses = stream(&mut h, &mut r, &knots, 100);
    assert!(statuses.iter().all(|s| s.mode == Mode::Running), "no fault");
    assert!(statuses.len() >= 6000, "{} samples", statuses.len());
    // The setpoints pass through every knot at its time: sample k is at (k + 1) · 500 µs from
    // the stream's start, the first status after the start is sample 0 of the stream.
    // Where the stream started (after the hold setpoints already queued, at most 63): the
    // offset that puts the setpoint on the knot at 0.5 s.
    let at = |start: usize, k: &Knot| {
        let p = statuses[start + (k.t_us / 500) as usize - 1].setpoint_mm;
        libm::hypotf(p[0] - k.position_mm[0], p[1] - k.position_mm[1])
    };
    let start = (0..100)
        .min_by(|&a, &b| at(a, &knots[49]).total_cmp(&at(b, &knots[49])))
        .unwrap();
    let mut worst = 0.0f32;
    for k in &knots {
        worst = worst.max(at(start, k));
    }
    assert!(worst < 1e-3, "setpoint off a knot by {worst} mm");
    // Tracked: the following error stays as small as on the built-in tour.
    let following = r.status.max_following_error_rad;
    assert!(
        following > 0.0 && following < 2e-4,
        "following error {following} rad"
    );
    let end = statuses.last().unwrap().setpoint_mm;
    let last = knots.last().unwrap().position_mm;
    assert!(
        libm::hypotf(end[0] - last[0], end[1] - last[1]) < 1e-3,
        "{end:?} vs {last:?}"
    );
    assert!(!r.stream.is_moving());
}

#[test]
fn an_underrun_is_a_controlled_stop_reported_and_a_reset_resumes() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let knots = figure_knots(3.0);
    // Two frames (160 ms) of a moving figure, then nothing.
    for i in 0..2 {
        let frame = heapless::Vec::from_slice(&knots[i * 8..i * 8 + 8]).unwrap();
        send(
            &mut h,
            &mut r,
            i as u16,
            Command::StreamKnots {
                first_index: i as u32 * 8,
                knots: frame,
            },
        )
        .unwrap();
    }
    let statuses = run(&mut h, &mut r, 1000);
    assert!(statuses
        .iter()
        .any(|s| s.mode == Mode::Stopping(Fault::Underrun)));
    assert_eq!(r.status.mode, Mode::Holding(Fault::Underrun));
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 5, Command::Status) else {
        panic!()
    };
    assert_eq!(
        (s.mode, s.fault),
        (ModeCode::Holding, Some(FaultCode::Underrun))
    );
    let more = heapless::Vec::from_slice(&knots[16..24]).unwrap();
    assert_eq!(
        send(
            &mut h,
            &mut r,
            6,
            Command::StreamKnots {
                first_index: 16,
                knots: more
            }
        ),
        Err(LinkError::Faulted(FaultCode::Underrun))
    );
    assert_eq!(
        send(&mut h, &mut r, 7, Command::ResetFault),
        Ok(Response::Done)
    );
    run(&mut h, &mut r, 10);
    assert_eq!(r.status.mode, Mode::Running);
    let held = r.status.setpoint_mm;
    // A new stream starts from where it held.
    let Ok(Response::MovePlanned { duration_s }) =
        send(&mut h, &mut r, 8, Command::MoveTo { target_mm: HOME_MM })
    else {
        panic!()
    };
    assert!(duration_s > 0.0);
    let statuses = run(&mut h, &mut r, (duration_s / 5e-4) as usize + 100);
    assert!(statuses.iter().all(|s| s.mode == Mode::Running));
    let first = statuses[0].setpoint_mm;
    assert!(
        libm::hypotf(first[0] - held[0], first[1] - held[1]) < 0.01,
        "no jump: {first:?} {held:?}"
    );
    let end = r.status.setpoint_mm;
    assert!(libm::hypotf(end[0] - HOME_MM[0], end[1] - HOME_MM[1]) < 1e-3);
}

/// The motion source runs ahead of the servo loop through the setpoint queue: when it has
/// handed over its last setpoint the machine's setpoint is still up to 31.5 ms short of the end.
/// The status says "moving" until the servo loop's setpoint is the hold point (a host that
/// waited for "not moving" read a setpoint 18 µm short of the end).
#[test]
fn the_status_says_moving_until_the_servo_reaches_the_end_not_the_source() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let target = [HOME_MM[0] + 20.0, HOME_MM[1] - 10.0];
    let Ok(Response::MovePlanned { duration_s }) =
        send(&mut h, &mut r, 1, Command::MoveTo { target_mm: target })
    else {
        panic!()
    };
    let mut samples = 0usize;
    while r.stream.is_playing() {
        run(&mut h, &mut r, 1);
        samples += 1;
        assert!(samples < (duration_s / 5e-4) as usize + 100);
    }
    let short = libm::hypotf(
        r.status.setpoint_mm[0] - target[0],
        r.status.setpoint_mm[1] - target[1],
    );
    assert!(
        short > 0.0,
        "the servo is behind the source when the source ends"
    );
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 2, Command::Status) else {
        panic!()
    };
    assert!(
        s.moving,
        "{short} mm short of the end and not moving: {s:?}"
    );
    let mut behind = 0usize;
    loop {
        run(&mut h, &mut r, 1);
        behind += 1;
        let Ok(Response::Status(s)) = send(&mut h, &mut r, 3, Command::Status) else {
            panic!()
        };
        if !s.moving {
            assert_eq!(
                s.setpoint_mm, target,
                "not moving means at the end, exactly"
            );
            break;
        }
        assert!(
            behind < crate::setpoints::QUEUE_SLOTS + 2,
            "still moving {behind} samples after the source ended"
        );
    }
}

/// With a built-in motion source (`Settings::link_motion` off: the QEMU tour) the link's stream
/// is not what the servo follows: moves and streams are refused (they would be accepted and
/// never run), and "moving" is the servo's setpoint changing, not the idle stream's hold point
/// (the boot point) against the setpoint: the old rule said "moving" forever once a tour had
/// ended anywhere else.
#[test]
fn with_a_built_in_source_the_link_refuses_moves_and_moving_follows_the_setpoint() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    r.link_motion = false;
    let mut h = LinkHandler::new();
    let target = [HOME_MM[0] + 15.0, HOME_MM[1] + 8.0];
    assert_eq!(
        send(&mut h, &mut r, 1, Command::MoveTo { target_mm: target }),
        Err(LinkError::Unsupported)
    );
    let knots = figure_knots(0.2);
    let frame = heapless::Vec::from_slice(&knots[..4]).unwrap();
    assert_eq!(
        send(
            &mut h,
            &mut r,
            2,
            Command::StreamKnots {
                first_index: 0,
                knots: frame
            }
        ),
        Err(LinkError::Unsupported)
    );
    assert!(!r.stream.is_playing(), "nothing reached the link's stream");
    // The built-in source: a stream of its own feeds the servo; the link's stays at the boot point.
    let link_stream = r.stream.clone();
    let duration_s = r.stream.move_to(target).expect("the tour's move plans");
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 3, Command::Status) else {
        panic!()
    };
    assert!(
        !s.moving,
        "not yet moving: the servo has not taken a sample of the tour"
    );
    // The queue holds up to QUEUE_SLOTS setpoints of the hold before the first of the move.
    run(&mut h, &mut r, crate::setpoints::QUEUE_SLOTS + 20);
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 4, Command::Status) else {
        panic!()
    };
    assert!(s.moving, "the tour runs: {s:?}");
    run(
        &mut h,
        &mut r,
        (duration_s / 5e-4) as usize + crate::setpoints::QUEUE_SLOTS + 10,
    );
    assert_eq!(r.status.setpoint_mm, target, "the tour ended at its target");
    r.stream = link_stream;
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 5, Command::Status) else {
        panic!()
    };
    assert!(
        !s.moving,
        "the tour ended away from the link stream's hold point: not moving ({s:?})"
    );
    // The same status with the link as the source reads "moving" (the hold point is elsewhere):
    // the rule depends on which source drives the servo.
    r.link_motion = true;
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 6, Command::Status) else {
        panic!()
    };
    assert!(s.moving);
}

#[test]
fn a_frame_with_one_bad_knot_is_refused_whole_and_nothing_moves() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let mut knots = figure_knots(3.0)[..8].to_vec();
    knots[6].position_mm[0] = 400.0; // far outside the workspace
    let frame = heapless::Vec::from_slice(&knots).unwrap();
    let refused = send(
        &mut h,
        &mut r,
        1,
        Command::StreamKnots {
            first_index: 0,
            knots: frame,
        },
    );
    assert!(
        matches!(refused, Err(LinkError::Segment { index: 6, .. })),
        "{refused:?}"
    );
    let before = r.status.setpoint_mm;
    let statuses = run(&mut h, &mut r, 400);
    assert!(statuses
        .iter()
        .all(|s| s.setpoint_mm == before && s.mode == Mode::Running));
    assert_eq!(r.stream.queued(), 0);
    assert_eq!(
        send(
            &mut h,
            &mut r,
            2,
            Command::MoveTo {
                target_mm: [400.0, 0.0]
            }
        ),
        Err(LinkError::Target)
    );
}

#[test]
fn stop_disable_enable_and_homing() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    send(
        &mut h,
        &mut r,
        1,
        Command::MoveTo {
            target_mm: [250.0, 60.0],
        },
    )
    .unwrap();
    run(&mut h, &mut r, 200);
    assert_eq!(send(&mut h, &mut r, 2, Command::Stop), Ok(Response::Done));
    let statuses = run(&mut h, &mut r, 400);
    assert_eq!(statuses[0].mode, Mode::Stopping(Fault::StopCommanded));
    assert_eq!(r.status.mode, Mode::Holding(Fault::StopCommanded));
    assert_eq!(
        send(&mut h, &mut r, 3, Command::MoveTo { target_mm: HOME_MM }),
        Err(LinkError::Faulted(FaultCode::Commanded))
    );
    assert_eq!(send(&mut h, &mut r, 4, Command::Enable), Ok(Response::Done));
    run(&mut h, &mut r, 5);
    assert_eq!(r.status.mode, Mode::Running);
    send(&mut h, &mut r, 5, Command::MoveTo { target_mm: HOME_MM }).unwrap();

    assert_eq!(
        send(&mut h, &mut r, 6, Command::Disable),
        Ok(Response::Done)
    );
    run(&mut h, &mut r, 800);
    assert_eq!(r.status.mode, Mode::SafeState(Fault::DisableCommanded));
    assert_eq!(
        send(&mut h, &mut r, 7, Command::MoveTo { target_mm: HOME_MM }),
        Err(LinkError::NotEnabled)
    );
    // Unhomed: the drives do not engage; homing, then they do.
    r.homing.state = HomingState::NotHomed;
    assert_eq!(
        send(&mut h, &mut r, 8, Command::Enable),
        Err(LinkError::NotHomed)
    );
    assert_eq!(send(&mut h, &mut r, 9, Command::Home), Ok(Response::Done));
    assert_eq!(
        send(&mut h, &mut r, 10, Command::Enable),
        Ok(Response::Done)
    );
    run(&mut h, &mut r, 5);
    assert_eq!(
        (r.status.mode, r.status.drives_enabled),
        (Mode::Running, true)
    );
    send(
        &mut h,
        &mut r,
        11,
        Command::MoveTo {
            target_mm: [220.0, 10.0],
        },
    )
    .unwrap();
    assert_eq!(
        send(&mut h, &mut r, 12, Command::Home),
        Err(LinkError::Busy),
        "not while moving"
    );
}

/// Between a re-engage and the link resuming its stream, the stream is paused and refuses
/// knots as busy: the status must say "moving" then, or a host that waits for "not moving"
/// before it streams is refused.
#[test]
fn not_moving_means_a_stream_may_start() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    assert_eq!(send(&mut h, &mut r, 1, Command::Stop), Ok(Response::Done));
    run(&mut h, &mut r, 400);
    assert_eq!(r.status.mode, Mode::Holding(Fault::StopCommanded));
    assert_eq!(send(&mut h, &mut r, 2, Command::Enable), Ok(Response::Done));
    let mut seen_paused_running = false;
    for k in 0..10u16 {
        r.step();
        let paused_running = r.status.mode == Mode::Running && r.stream.is_paused();
        seen_paused_running |= paused_running;
        let Ok(Response::Status(s)) = send(&mut h, &mut r, 10 + k, Command::Status) else {
            panic!()
        };
        if paused_running {
            assert!(s.moving, "paused in Running, about to resume: {s:?}");
        }
        if !s.moving {
            // The reply's own poll may have resumed the stream: what counts is that a stream
            // can start now.
            assert!(!r.stream.is_paused() && !r.stream.is_moving(), "{s:?}");
        }
        let _ = h.poll(&mut r);
    }
    assert!(
        seen_paused_running,
        "the window this test is about never opened"
    );
    let Ok(Response::Status(s)) = send(&mut h, &mut r, 30, Command::Status) else {
        panic!()
    };
    assert!(!s.moving, "resumed and at rest: {s:?}");
}

#[test]
fn a_bad_image_is_refused_and_the_old_one_stays() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    let old = image_id(&img);
    let upload = |h: &mut LinkHandler, r: &mut Rig<'_>, bytes: &[u8]| {
        send(
            h,
            r,
            1,
            Command::CalibrationBegin {
                len: bytes.len() as u32,
            },
        )?;
        for (i, c) in bytes
            .chunks(link_protocol::CALIBRATION_CHUNK_LEN)
            .enumerate()
        {
            let offset = (i * link_protocol::CALIBRATION_CHUNK_LEN) as u32;
            send(
                h,
                r,
                2,
                Command::CalibrationChunk {
                    offset,
                    data: heapless::Vec::from_slice(c).unwrap(),
                },
            )?;
        }
        send(h, r, 3, Command::CalibrationCommit)
    };
    let mut bad = image(5e-4);
    bad[100] ^= 0x40;
    assert_eq!(
        upload(&mut h, &mut r, &bad),
        Err(LinkError::Calibration(CalibrationRefusal::Invalid))
    );
    assert_eq!(
        send(&mut h, &mut r, 4, Command::CalibrationId),
        Ok(Response::CalibrationId(old))
    );
    let new = image(5e-4);
    assert_eq!(
        upload(&mut h, &mut r, &new),
        Ok(Response::CalibrationId(image_id(&new)))
    );
    assert_ne!(image_id(&new), old);
    assert_eq!(
        send(&mut h, &mut r, 5, Command::CalibrationId),
        Ok(Response::CalibrationId(image_id(&new)))
    );
    // Out of order chunk.
    send(&mut h, &mut r, 6, Command::CalibrationBegin { len: 300 }).unwrap();
    let chunk = heapless::Vec::from_slice(&[1u8; 10]).unwrap();
    assert_eq!(
        send(
            &mut h,
            &mut r,
            7,
            Command::CalibrationChunk {
                offset: 5,
                data: chunk
            }
        ),
        Err(LinkError::Calibration(CalibrationRefusal::Offset))
    );
}

#[test]
fn telemetry_is_decimated_and_bounded() {
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    let mut h = LinkHandler::new();
    assert_eq!(
        send(&mut h, &mut r, 1, Command::Telemetry { decimation: 1 }),
        Ok(Response::TelemetryDecimation(MIN_TELEMETRY_DECIMATION))
    );
    let mut n = 0;
    for _ in 0..400 {
        r.step();
        if let Some(m) = h.poll(&mut r) {
            assert!(matches!(m.body, DeviceBody::Telemetry(t) if t.mode == ModeCode::Running));
            n += 1;
        }
    }
    assert_eq!(n, 400 / MIN_TELEMETRY_DECIMATION as usize);
    assert_eq!(
        send(&mut h, &mut r, 2, Command::Telemetry { decimation: 0 }),
        Ok(Response::TelemetryDecimation(0))
    );
    r.step();
    assert_eq!(h.poll(&mut r), None);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, ..ProptestConfig::default() })]

    /// Random bytes, and valid frames with bytes flipped, dropped or inserted, into the reader
    /// and the handler while the servo runs: every frame answered, a clear error, no request
    /// posted, no motion queued, the setpoint unchanged.
    #[test]
    fn garbage_is_answered_and_never_moves_the_machine(
        noise in prop::collection::vec(any::<u8>(), 0..600),
        seq in any::<u16>(),
        target in [150.0f32..270.0, -90.0f32..90.0],
        flips in prop::collection::vec((any::<prop::sample::Index>(), 1u8..=255), 1..4),
    ) {
        let (settings, img) = (settings(), image(3e-4));
        let mut r = rig(&settings, &img);
        let mut h = LinkHandler::new();
        let before = r.status.setpoint_mm;
        let mut bytes = noise.clone();
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = encode(&Request::new(seq, Command::MoveTo { target_mm: target }), &mut frame).unwrap();
        let mut mutated = frame[..n].to_vec();
        for (at, x) in &flips {
            let i = at.index(n - 1);
            mutated[i] ^= x;
        }
        prop_assume!(mutated[..] != frame[..n]);
        bytes.push(0);
        bytes.extend_from_slice(&mutated);
        bytes.push(0);
        let replies = feed(&mut h, &mut r, &bytes);
        for m in &replies {
            let is_error = matches!(m.body, DeviceBody::FrameRejected(_) | DeviceBody::Reply { result: Err(_), .. });
            // A reply that is not an error can only come from a frame that decoded: a random
            // frame passing the CRC-32 is a 2^-32 event, so here it means the frame was intact.
            prop_assert!(is_error, "{m:?}");
        }
        prop_assert_eq!(r.posted, 0);
        prop_assert!(!r.stream.is_moving());
        for s in run(&mut h, &mut r, 20) {
            prop_assert_eq!(s.setpoint_mm, before);
            prop_assert_eq!(s.mode, Mode::Running);
        }
    }
}

/// A homing that failed (or a fault latched before homing) is recovered without a reboot:
/// ResetFault takes the servo loop back to Unhomed with the drives off (it never engages on an
/// unknown zero; Enable stays refused), and Home runs again.
#[test]
fn a_failed_homing_is_reset_to_unhomed_and_homed_again_without_a_reboot() {
    use crate::homing::{HomingFault, HomingPhase};
    let (incremental, img) = (Settings::default(), image(3e-4));
    assert!(!incremental.homing.absolute_encoders);
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).unwrap());
    let mut r = Rig::boot(
        &incremental,
        cal,
        cal.command_rad(HOME_MM, 0.05).unwrap(),
        image_id(&img),
    );
    r.homing.state = HomingState::NotHomed;
    let mut h = LinkHandler::new();
    run(&mut h, &mut r, 2);
    assert_eq!(r.servo.mode(), Mode::Unhomed);
    r.post(ServoRequest::Home);
    run(&mut h, &mut r, 1);
    assert_eq!(r.servo.mode(), Mode::Homing);
    // Homing fails (no index found): the safe state, drives off.
    let failed = Fault::Homing(HomingFault::IndexNotFound(0));
    let mut sample = r.servo.step_homing(r.plant.encoder_rad(), [None; 2]);
    r.servo.latch(failed, &mut sample);
    r.homing.state = HomingState::Failed;
    run(&mut h, &mut r, 2);
    assert_eq!(
        (r.status.mode, r.servo.drives_enabled()),
        (Mode::SafeState(failed), false)
    );
    assert_eq!(
        send(&mut h, &mut r, 1, Command::Enable),
        Err(LinkError::Faulted(FaultCode::Homing)),
        "no engaging on an unknown zero"
    );
    assert_eq!(
        send(&mut h, &mut r, 2, Command::ResetFault),
        Ok(Response::Done)
    );
    let statuses = run(&mut h, &mut r, 20);
    assert!(
        statuses
            .iter()
            .all(|s| s.torque_nm == [0.0; 2] && !s.drives_enabled),
        "the drives stay off"
    );
    assert_eq!(
        (r.servo.mode(), r.servo.homing_phase()),
        (Mode::Unhomed, None)
    );
    // Home runs again (the firmware's Homing::start posts this from Unhomed).
    r.post(ServoRequest::Home);
    run(&mut h, &mut r, 1);
    assert_eq!(
        (r.servo.mode(), r.servo.homing_phase()),
        (Mode::Homing, Some(HomingPhase::Search(0)))
    );
}

/// The link's homing state follows the servo loop's mode and homing phase.
#[test]
fn the_homing_state_follows_the_mode_and_the_phase() {
    use crate::homing::{HomingFault, HomingPhase};
    use HomingState::*;
    let enc = Fault::Encoder(crate::encoder_check::EncoderFault {
        axis: 0,
        kind: crate::encoder_check::EncoderFaultKind::Speed,
    });
    let cases = [
        (Mode::Unhomed, None, false, NotHomed),
        (
            Mode::Homing,
            Some(HomingPhase::Search(1)),
            false,
            InProgress,
        ),
        (Mode::Homing, Some(HomingPhase::ToHome), false, InProgress),
        (Mode::Running, Some(HomingPhase::Done), false, Homed),
        // A fault after homing: the zero stays set.
        (Mode::SafeState(enc), Some(HomingPhase::Done), false, Homed),
        (
            Mode::Holding(Fault::Underrun),
            Some(HomingPhase::Done),
            false,
            Homed,
        ),
        // A fault while homing, or homing's own.
        (
            Mode::SafeState(enc),
            Some(HomingPhase::Search(0)),
            false,
            Failed,
        ),
        (
            Mode::SafeState(Fault::Homing(HomingFault::IndexNotFound(0))),
            Some(HomingPhase::Failed(HomingFault::IndexNotFound(0))),
            false,
            Failed,
        ),
        (
            Mode::SafeState(Fault::Homing(HomingFault::Plan)),
            None,
            false,
            Failed,
        ),
        // Never homed, a fault at boot (a watchdog reset): not homed, so no reset engages it.
        (
            Mode::SafeState(Fault::DeadlineMissed),
            None,
            false,
            NotHomed,
        ),
        // Absolute encoders.
        (Mode::Running, None, true, Homed),
        (Mode::SafeState(Fault::DeadlineMissed), None, true, Homed),
    ];
    for (mode, phase, absolute, expected) in cases {
        assert_eq!(
            homing_state(mode, phase, absolute),
            expected,
            "{mode:?} {phase:?} absolute {absolute}"
        );
    }
}

/// Every refusal of the slot store has its name on the link; an image's with its parameter and
/// values.
#[test]
fn the_slot_stores_refusals_have_their_link_names() {
    use crate::calibration::ImageError;
    use crate::calibration_slots::{FlashError, SlotError};
    use crate::plausibility::SlopeChange;
    use kinematics_core::machine::{
        ImageRefusal, Implausible, MachineMismatch, MachineName, ModelParameter,
        ParameterDifference,
    };
    use kinematics_core::GridError;
    use link_protocol::{ImageParameter, MachineId};
    let refused = |r: ImageRefusal| SlotError::Image(ImageError::Refused(r));
    let cases = [
        (SlotError::NoUpload, CalibrationRefusal::NotBegun),
        (SlotError::BadLength { max: 10 }, CalibrationRefusal::Length),
        (
            SlotError::OutOfOrder { expected: 3 },
            CalibrationRefusal::Offset,
        ),
        (SlotError::TooMuchData, CalibrationRefusal::Incomplete),
        (
            SlotError::Incomplete { received: 3 },
            CalibrationRefusal::Incomplete,
        ),
        (
            SlotError::Flash(FlashError::Timeout),
            CalibrationRefusal::Flash,
        ),
        (
            SlotError::Image(ImageError::Grid(GridError::BadCrc)),
            CalibrationRefusal::Invalid,
        ),
        (
            refused(ImageRefusal::OtherMachine(MachineMismatch::Geometry {
                worst_mm: 9.1,
                at_mm: [212.0, 0.0],
                tolerance_mm: 3.0,
                parameter: Some(ParameterDifference {
                    parameter: ModelParameter::B,
                    image: 161.0,
                    controller: 150.0,
                }),
            })),
            CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::LinkBMm,
                image: 161.0,
                machine: 150.0,
                tolerance: 3.0,
            },
        ),
        (
            refused(ImageRefusal::OtherMachine(MachineMismatch::Geometry {
                worst_mm: 24.7,
                at_mm: [212.0, 0.0],
                tolerance_mm: 3.0,
                parameter: None,
            })),
            CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::ToolPositionMm,
                image: 24.7,
                machine: 0.0,
                tolerance: 3.0,
            },
        ),
        (
            refused(ImageRefusal::OtherMachine(MachineMismatch::OtherRecord {
                image_name: MachineName::new("second").unwrap(),
                image_digest: 0x1234_5678,
                controller_name: MachineName::new("paper").unwrap(),
                controller_digest: 0x9abc_def0,
            })),
            CalibrationRefusal::OtherRecord {
                image: MachineId::new("second", 0x1234_5678),
                controller: MachineId::new("paper", 0x9abc_def0),
            },
        ),
        (
            refused(ImageRefusal::Implausible(Implausible::NodeCorrection {
                node: [3, 4],
                correction_mm: 7.5,
                limit_mm: 3.0,
            })),
            CalibrationRefusal::Implausible {
                parameter: ImageParameter::NodeCorrectionMm,
                value: 7.5,
                limit: 3.0,
            },
        ),
        (
            refused(ImageRefusal::Implausible(Implausible::Inertia {
                at_mm: [212.0, 0.0],
                ratio: 1000.0,
                factor: 4.0,
            })),
            CalibrationRefusal::Implausible {
                parameter: ImageParameter::InertiaRatio,
                value: 1000.0,
                limit: 4.0,
            },
        ),
        (
            refused(ImageRefusal::Implausible(Implausible::Inertia {
                at_mm: [212.0, 0.0],
                ratio: 0.1,
                factor: 4.0,
            })),
            CalibrationRefusal::Implausible {
                parameter: ImageParameter::InertiaRatio,
                value: 0.1,
                limit: 0.25,
            },
        ),
        (
            refused(ImageRefusal::Implausible(Implausible::Friction {
                parameter: "viscous_2_nm_s_per_rad",
                image: 0.1,
                nominal: 0.02,
                factor: 4.0,
            })),
            CalibrationRefusal::Implausible {
                parameter: ImageParameter::ViscousNmSPerRad,
                value: 0.1,
                limit: 0.08,
            },
        ),
        (
            refused(ImageRefusal::Implausible(Implausible::HomeOutsideGrid {
                home_mm: [212.132, 0.0],
            })),
            CalibrationRefusal::ImplausibleAt {
                parameter: ImageParameter::HomePosition,
                at_mm: [212.132, 0.0],
            },
        ),
        (
            SlotError::Image(ImageError::SlopeChange(SlopeChange {
                node: [1, 2],
                axis: 0,
                value_rad_per_mm: 1e-4,
                limit_rad_per_mm: 3.3e-5,
            })),
            CalibrationRefusal::Implausible {
                parameter: ImageParameter::SlopeChangeRadPerMm,
                value: 1e-4,
                limit: 3.3e-5,
            },
        ),
        (SlotError::SwitchPending, CalibrationRefusal::SwitchPending),
    ];
    for (e, expected) in cases {
        assert_eq!(calibration_refusal(e), expected, "{e:?}");
    }
}

/// The largest change of a drive's torque from one sample to the next that a link frame may
/// cause (N·m): the servo's own 2 g moves and its encoder-count chatter stay well below it.
const MAX_TORQUE_STEP_NM: f32 = 1.0;

/// Valid frames (they decode, their CRCs are right) carrying absurd payloads, while the servo
/// moves (a sane move is started whenever the machine is idle): NaN, infinite and enormous
/// targets and knots, decimations, lengths, offsets and chunks anywhere in their ranges, and
/// CRC-valid images with a ±0.05 rad checkerboard or masses 1000×. Every frame answered with
/// its sequence number; no fault (none of these payloads deserves one: the commands that may
/// stop the machine are not in the mix); no torque step beyond [`MAX_TORQUE_STEP_NM`]; the
/// image in force never changes. The bench `link_fuzz` runs the same with its counts for a
/// million frames.
#[test]
fn valid_frames_with_absurd_payloads_never_fault_nor_step_the_torque() {
    use super::doubles::{absurd_command, FuzzRng};
    let (settings, img) = (settings(), image(3e-4));
    let mut r = rig(&settings, &img);
    r.store.check = Some(settings.image_check());
    let in_force = r.store.active_id();
    let mut h = LinkHandler::new();
    let mut rng = FuzzRng(0x5DEE_CE66_D1CE_4E5B);
    let checker: [[f32; 2]; 9] = core::array::from_fn(|k| {
        if k % 2 == 0 {
            [0.05, -0.05]
        } else {
            [-0.05, 0.05]
        }
    });
    let bad_images = [
        {
            let mut b = image(0.0);
            let g = CorrectionGrid::parse(&b).unwrap();
            let geometry = *g.geometry();
            encode_grid(&mut b, &geometry, &FiveBar::paper_nominal(), &checker).unwrap();
            b
        },
        image(0.5),
    ];
    let (mut frames, mut refused, mut moves, mut uploads) = (0u32, 0u32, 0u32, 0u32);
    let mut last_torque = r.status.torque_nm;
    let mut worst_step = 0.0f32;
    let mut seq = 0u16;
    for k in 0..3000u32 {
        seq = seq.wrapping_add(1);
        if r.status.mode == Mode::Running && !r.stream.is_moving() && k % 3 == 0 {
            let target = [185.0 + rng.below(55) as f32, -50.0 + rng.below(100) as f32];
            assert!(send(&mut h, &mut r, seq, Command::MoveTo { target_mm: target }).is_ok());
            moves += 1;
            seq = seq.wrapping_add(1);
        }
        if k % 500 == 250 {
            // A CRC-valid image with absurd content, begun, sent and committed (the machine
            // at rest: uploads wait for it): refused.
            loop {
                let Ok(Response::Status(s)) = send(&mut h, &mut r, seq, Command::Status) else {
                    panic!("status refused");
                };
                if !s.moving {
                    break;
                }
                for s in run(&mut h, &mut r, 10) {
                    assert_eq!(s.fault, None, "frame {k}");
                }
            }
            last_torque = r.status.torque_nm;
            let bad = &bad_images[(k / 500) as usize % bad_images.len()];
            send(
                &mut h,
                &mut r,
                seq,
                Command::CalibrationBegin {
                    len: bad.len() as u32,
                },
            )
            .unwrap();
            for (i, chunk) in bad.chunks(128).enumerate() {
                let data = heapless::Vec::from_slice(chunk).unwrap();
                let offset = (i * 128) as u32;
                send(
                    &mut h,
                    &mut r,
                    seq,
                    Command::CalibrationChunk { offset, data },
                )
                .unwrap();
            }
            let e = send(&mut h, &mut r, seq, Command::CalibrationCommit).unwrap_err();
            assert!(
                matches!(
                    e,
                    LinkError::Calibration(CalibrationRefusal::Implausible { .. })
                ),
                "{e:?}"
            );
            uploads += 1;
        }
        let command = absurd_command(&mut rng);
        let is_upload = matches!(
            command,
            Command::CalibrationBegin { .. }
                | Command::CalibrationChunk { .. }
                | Command::CalibrationCommit
        );
        if send(&mut h, &mut r, seq, command).is_err() {
            refused += 1;
        }
        frames += 1;
        for s in run(&mut h, &mut r, 5) {
            assert_eq!(s.fault, None, "frame {k}: a fault no payload deserved");
            assert_eq!(s.mode, Mode::Running, "frame {k}");
            let step = (s.torque_nm[0] - last_torque[0])
                .abs()
                .max((s.torque_nm[1] - last_torque[1]).abs());
            worst_step = worst_step.max(step);
            last_torque = s.torque_nm;
        }
        assert_eq!(r.store.active_id(), in_force, "frame {k}: {is_upload}");
    }
    println!(
        "absurd payloads: {frames} frames ({refused} refused), {moves} moves run meanwhile, {uploads} implausible images refused, largest torque step {worst_step:.3} N·m"
    );
    assert!(worst_step <= MAX_TORQUE_STEP_NM, "{worst_step} N·m");
    assert!(
        moves > 50 && refused > 500,
        "{moves} moves, {refused} refused"
    );
}
