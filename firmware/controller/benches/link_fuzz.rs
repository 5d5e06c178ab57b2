//! The long fuzz run of the host link: random and mutated frames into the frame reader, the
//! decoder and the command handler, with the servo loop, the motion stream and the plant
//! running one sample per frame ([`Rig`]). Checks every frame: answered (a reply, never
//! silence), with an error, no request posted to the servo, no motion queued, the setpoint
//! where it was. Then valid frames with absurd payloads (`doubles::absurd_command`) while the
//! servo moves (a sane move started whenever it is idle), five samples each: every frame
//! answered with its sequence number, no fault, no torque step beyond 1 N·m. Prints the counts.
//!
//! `cargo bench -p controller --features host-doubles --bench link_fuzz` (default 1 000 000
//! frames; `LINK_FUZZ_FRAMES=N` for another count). The CI-sized run of the same checks is the
//! property test `host_link::tests::garbage_is_answered_and_never_moves_the_machine`.
use controller::calibration::image_id;
use controller::host_link::doubles::Rig;
use controller::host_link::LinkHandler;
use controller::servo_loop::Mode;
use controller::settings::Settings;
use kinematics_core::grid::{encode as encode_grid, GridGeometry};
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use link_protocol::{
    decode, encode, Command, DeviceBody, DeviceMessage, FrameReader, Knot, Request,
    CALIBRATION_CHUNK_LEN, MAX_FRAME_LEN,
};

/// xorshift64*: a fuzz driver needs speed and reproducibility, not statistical quality.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn f32(&mut self) -> f32 {
        (self.next() % 2_000_000) as f32 * 0.001 - 1000.0
    }
}

fn command(rng: &mut Rng) -> Command {
    let knot = |rng: &mut Rng| Knot {
        t_us: rng.next() as u32,
        position_mm: [rng.f32(), rng.f32()],
        velocity_mm_s: [rng.f32(), rng.f32()],
    };
    match rng.below(14) {
        0 => Command::Identify,
        1 => Command::Status,
        2 => Command::Enable,
        3 => Command::Disable,
        4 => Command::Home,
        5 => Command::MoveTo {
            target_mm: [rng.f32(), rng.f32()],
        },
        6 => {
            let n = rng.below(9);
            let mut knots = heapless::Vec::new();
            for _ in 0..n {
                let _ = knots.push(knot(rng));
            }
            Command::StreamKnots {
                first_index: rng.below(3) as u32,
                knots,
            }
        }
        7 => Command::Stop,
        8 => Command::ResetFault,
        9 => Command::Telemetry {
            decimation: rng.next() as u16,
        },
        10 => Command::CalibrationBegin {
            len: rng.next() as u32,
        },
        11 => {
            let n = rng.below(CALIBRATION_CHUNK_LEN + 1);
            let data = heapless::Vec::from_iter((0..n).map(|_| rng.next() as u8));
            Command::CalibrationChunk {
                offset: rng.below(1000) as u32,
                data,
            }
        }
        12 => Command::CalibrationCommit,
        _ => Command::CalibrationId,
    }
}

fn main() {
    let frames: u64 = std::env::var("LINK_FUZZ_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode_grid(&mut img, &g, &FiveBar::paper_nominal(), &[[3e-4, -2e-4]; 9]).expect("grid image");
    let mut settings = Settings::default();
    settings.homing.absolute_encoders = true;
    let cal = Calibration::from_grid(CorrectionGrid::parse(&img).expect("grid parses"));
    let joints = cal
        .command_rad([212.132, 0.0], 0.05)
        .expect("home is reachable");
    let mut rig = Rig::boot(&settings, cal, joints, image_id(&img));
    rig.step();
    let home = rig.status.setpoint_mm;
    let mut handler = LinkHandler::new();
    let mut reader = FrameReader::new();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut random, mut mutated, mut truncated) = (0u64, 0u64, 0u64);
    let (mut replies, mut rejected, mut refused, mut bytes) = (0u64, 0u64, 0u64, 0u64);
    let started = std::time::Instant::now();
    let mut wire = Vec::with_capacity(2 * MAX_FRAME_LEN);
    for i in 0..frames {
        wire.clear();
        match i % 3 {
            0 => {
                random += 1;
                let n = rng.below(2 * MAX_FRAME_LEN);
                wire.extend((0..n).map(|_| rng.next() as u8));
            }
            1 => {
                mutated += 1;
                let mut frame = [0u8; MAX_FRAME_LEN];
                let n = encode(
                    &Request::new(rng.next() as u16, command(&mut rng)),
                    &mut frame,
                )
                .expect("fits");
                wire.extend_from_slice(&frame[..n]);
                let flips = 1 + rng.below(4);
                let original = wire.clone();
                for _ in 0..flips {
                    let at = rng.below(n - 1);
                    wire[at] ^= 1 + rng.below(255) as u8;
                }
                if wire == original {
                    wire[0] ^= 0x80;
                }
            }
            _ => {
                truncated += 1;
                let mut frame = [0u8; MAX_FRAME_LEN];
                let n = encode(
                    &Request::new(rng.next() as u16, command(&mut rng)),
                    &mut frame,
                )
                .expect("fits");
                let cut = 1 + rng.below(n - 2);
                wire.extend_from_slice(&frame[..cut]);
            }
        }
        // Every piece of garbage ends with a delimiter, so each is answered.
        wire.push(0);
        bytes += wire.len() as u64;
        for &b in &wire {
            if let Some(received) = reader.push(b) {
                let mut out = [0u8; MAX_FRAME_LEN];
                let n = handler.on_received(received, &mut rig, &mut out);
                assert!(n > 0, "frame {i}: silence");
                let reply: DeviceMessage = decode(&mut out[..n - 1]).expect("the reply decodes");
                replies += 1;
                match reply.body {
                    DeviceBody::FrameRejected(_) => rejected += 1,
                    DeviceBody::Reply { result: Err(_), .. } => refused += 1,
                    other => panic!("frame {i}: garbage was accepted: {other:?}"),
                }
            }
        }
        rig.step();
        assert_eq!(rig.posted, 0, "frame {i}: a request reached the servo");
        assert!(!rig.stream.is_playing(), "frame {i}: motion queued");
        assert_eq!(
            rig.status.setpoint_mm, home,
            "frame {i}: the setpoint moved"
        );
        assert_eq!(rig.status.mode, Mode::Running, "frame {i}");
    }
    let s = started.elapsed().as_secs_f64();
    absurd_payloads(&settings, cal, joints, image_id(&img), frames / 4);
    println!(
        "LINK_FUZZ frames {frames} (random {random}, mutated {mutated}, truncated {truncated}), {bytes} bytes, \
         {replies} replies ({rejected} frame errors, {refused} refused requests), 0 accepted, 0 requests posted, \
         0 setpoint changes, {:.1} s ({:.0} frames/s)",
        s,
        frames as f64 / s
    );
}

/// Valid frames with absurd payloads while the servo moves (module doc); prints its counts.
fn absurd_payloads(
    settings: &Settings,
    cal: Calibration<'_>,
    joints: [f32; 2],
    active_id: Option<u32>,
    frames: u64,
) {
    use controller::host_link::doubles::{absurd_command, FuzzRng};
    let mut rig = Rig::boot(settings, cal, joints, active_id);
    rig.store.check = Some(settings.image_check());
    rig.step();
    let mut handler = LinkHandler::new();
    let mut rng = FuzzRng(0xD1B5_4A32_D192_ED03);
    let (mut refused, mut done, mut moves) = (0u64, 0u64, 0u64);
    let mut last = rig.status.torque_nm;
    let mut worst = 0.0f32;
    let request = |rig: &mut Rig<'_>, handler: &mut LinkHandler, seq: u16, command| {
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = encode(&Request::new(seq, command), &mut frame).expect("fits");
        let mut reader = FrameReader::new();
        let mut answer = None;
        for &b in &frame[..n] {
            if let Some(received) = reader.push(b) {
                let mut out = [0u8; MAX_FRAME_LEN];
                let m = handler.on_received(received, rig, &mut out);
                let reply: DeviceMessage = decode(&mut out[..m - 1]).expect("the reply decodes");
                answer = Some(reply.body);
            }
        }
        match answer {
            Some(DeviceBody::Reply { seq: s, result }) if s == seq => result.is_ok(),
            other => panic!("frame {seq}: not its reply: {other:?}"),
        }
    };
    let started = std::time::Instant::now();
    for i in 0..frames {
        let seq = (2 * i) as u16;
        if rig.status.mode == Mode::Running && !rig.stream.is_moving() && i % 3 == 0 {
            let target = [185.0 + rng.below(55) as f32, -50.0 + rng.below(100) as f32];
            assert!(request(
                &mut rig,
                &mut handler,
                seq.wrapping_add(1),
                Command::MoveTo { target_mm: target }
            ));
            moves += 1;
        }
        if request(&mut rig, &mut handler, seq, absurd_command(&mut rng)) {
            done += 1;
        } else {
            refused += 1;
        }
        for _ in 0..5 {
            rig.step();
            let _ = handler.poll(&mut rig);
            let s = rig.status;
            assert_eq!(s.fault, None, "frame {i}: a fault no payload deserved");
            let step = (s.torque_nm[0] - last[0])
                .abs()
                .max((s.torque_nm[1] - last[1]).abs());
            worst = worst.max(step);
            last = s.torque_nm;
        }
    }
    assert!(worst <= 1.0, "torque step {worst} N·m");
    println!(
        "LINK_FUZZ absurd payloads: {frames} valid frames ({done} done, {refused} refused), {moves} moves run meanwhile, 0 faults, largest torque step {worst:.3} N·m per sample, {:.1} s",
        started.elapsed().as_secs_f64()
    );
}
