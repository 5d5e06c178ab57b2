//! The frame and the messages: round trips, the limits, and hostile bytes (random, mutated,
//! truncated, oversized, other versions) that must give a typed error and never a panic.
//! The long run of the same checks is the `fuzz_frames` bench (prints its counts).
use link_protocol::*;
use proptest::prelude::*;

fn finite() -> impl Strategy<Value = f32> {
    -1.0e6f32..1.0e6
}
fn pair() -> impl Strategy<Value = [f32; 2]> {
    [finite(), finite()]
}
fn knot() -> impl Strategy<Value = Knot> {
    (any::<u32>(), pair(), pair()).prop_map(|(t_us, position_mm, velocity_mm_s)| Knot {
        t_us,
        position_mm,
        velocity_mm_s,
    })
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Identify),
        Just(Command::Status),
        Just(Command::Enable),
        Just(Command::Disable),
        Just(Command::Home),
        pair().prop_map(|target_mm| Command::MoveTo { target_mm }),
        (
            any::<u32>(),
            prop::collection::vec(knot(), 0..=MAX_KNOTS_PER_FRAME)
        )
            .prop_map(|(first_index, k)| {
                Command::StreamKnots {
                    first_index,
                    knots: heapless::Vec::from_slice(&k).unwrap(),
                }
            }),
        Just(Command::Stop),
        Just(Command::ResetFault),
        any::<u16>().prop_map(|decimation| Command::Telemetry { decimation }),
        any::<u32>().prop_map(|len| Command::CalibrationBegin { len }),
        (
            any::<u32>(),
            prop::collection::vec(any::<u8>(), 0..=CALIBRATION_CHUNK_LEN)
        )
            .prop_map(|(offset, d)| {
                Command::CalibrationChunk {
                    offset,
                    data: heapless::Vec::from_slice(&d).unwrap(),
                }
            }),
        Just(Command::CalibrationCommit),
        Just(Command::CalibrationId),
    ]
}

fn roundtrip<
    T: serde::Serialize + for<'de> serde::Deserialize<'de> + PartialEq + core::fmt::Debug,
>(
    m: &T,
) {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(m, &mut buf).expect("every message fits a frame");
    assert!(n <= MAX_FRAME_LEN);
    assert_eq!(buf[n - 1], 0, "ends with the delimiter");
    assert!(!buf[..n - 1].contains(&0), "the only zero is the delimiter");
    let back: T = decode(&mut buf[..n - 1]).unwrap();
    assert_eq!(&back, m);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn every_request_round_trips(seq in any::<u16>(), c in command()) {
        roundtrip(&Request::new(seq, c));
    }

    #[test]
    fn a_frame_read_byte_by_byte_is_the_frame(seq in any::<u16>(), c in command(), junk in prop::collection::vec(1u8..=255, 0..40)) {
        // Junk before (no zero in it), a zero, then the frame: the reader resynchronises.
        let mut buf = [0u8; MAX_FRAME_LEN];
        let req = Request::new(seq, c);
        let n = encode(&req, &mut buf).unwrap();
        let mut reader = FrameReader::new();
        let mut got = Vec::new();
        for &b in junk.iter().chain([0u8].iter()).chain(buf[..n].iter()) {
            if let Some(Received::Frame(f)) = reader.push(b) {
                got.push(decode::<Request>(f));
            }
        }
        prop_assert_eq!(got.len(), if junk.is_empty() { 1 } else { 2 });
        prop_assert_eq!(got.last().cloned(), Some(Ok(req)));
    }

    #[test]
    fn random_bytes_never_panic(mut bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode::<Request>(&mut bytes);
    }

    #[test]
    fn a_flipped_bit_is_refused(seq in any::<u16>(), c in command(), at in any::<prop::sample::Index>(), bit in 0u8..8) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&Request::new(seq, c), &mut buf).unwrap();
        let i = at.index(n - 1);
        buf[i] ^= 1 << bit;
        // CRC-32 detects every single-bit error; COBS may see the change first.
        prop_assert!(decode::<Request>(&mut buf[..n - 1]).is_err());
    }
}

#[test]
fn the_largest_messages_fit() {
    let knot = Knot {
        t_us: u32::MAX,
        position_mm: [f32::MAX; 2],
        velocity_mm_s: [f32::MIN; 2],
    };
    let knots = heapless::Vec::from_slice(&[knot; MAX_KNOTS_PER_FRAME]).unwrap();
    roundtrip(&Request::new(
        u16::MAX,
        Command::StreamKnots {
            first_index: u32::MAX,
            knots,
        },
    ));
    let data = heapless::Vec::from_slice(&[0xFFu8; CALIBRATION_CHUNK_LEN]).unwrap();
    roundtrip(&Request::new(
        u16::MAX,
        Command::CalibrationChunk {
            offset: u32::MAX,
            data,
        },
    ));
    let status = StatusReport {
        ticks: u32::MAX,
        mode: ModeCode::SafeState,
        fault: Some(FaultCode::NotHomed),
        drives_enabled: true,
        homing: HomingState::Failed,
        setpoint_mm: [f32::MAX; 2],
        encoder_rad: [f32::MAX; 2],
        max_following_error_rad: f32::MAX,
        overruns: u32::MAX,
        worst_step_us: f32::MAX,
        setpoint_underruns: u32::MAX,
        stream_knots_queued: u16::MAX,
        moving: true,
        telemetry_decimation: u16::MAX,
        calibration_pending: Some(u32::MAX),
    };
    roundtrip(&DeviceMessage::new(DeviceBody::Reply {
        seq: u16::MAX,
        result: Ok(Response::Status(status)),
    }));
    let t = TelemetrySample {
        tick: u32::MAX,
        setpoint_mm: [1.0; 2],
        reference_rad: [1.0; 2],
        encoder_rad: [1.0; 2],
        torque_nm: [1.0; 2],
        following_error_rad: 1.0,
        mode: ModeCode::Running,
        fault: Some(FaultCode::Underrun),
    };
    roundtrip(&DeviceMessage::new(DeviceBody::Telemetry(t)));
    let e = LinkError::Segment {
        index: u32::MAX,
        reason: SegmentRefusal::Workspace,
    };
    roundtrip(&DeviceMessage::new(DeviceBody::Reply {
        seq: 1,
        result: Err(e),
    }));
    // The refusals that carry numbers.
    for refusal in [
        CalibrationRefusal::OtherMachine {
            parameter: ImageParameter::BaseA0YMm,
            image: f32::MAX,
            machine: f32::MIN,
            tolerance: f32::MAX,
        },
        CalibrationRefusal::Implausible {
            parameter: ImageParameter::SlopeChangeRadPerMm,
            value: f32::MAX,
            limit: f32::MIN_POSITIVE,
        },
        CalibrationRefusal::ImplausibleAt {
            parameter: ImageParameter::ModelPose,
            at_mm: [f32::MAX, f32::MIN],
        },
        CalibrationRefusal::OtherRecord {
            image: MachineId {
                name: [0xFF; MACHINE_NAME_LEN],
                digest: u32::MAX,
            },
            controller: MachineId {
                name: [0x7E; MACHINE_NAME_LEN],
                digest: u32::MAX,
            },
        },
    ] {
        roundtrip(&DeviceMessage::new(DeviceBody::Reply {
            seq: u16::MAX,
            result: Err(LinkError::Calibration(refusal)),
        }));
    }
    roundtrip(&DeviceMessage::new(DeviceBody::FrameRejected(
        FrameError::Version(u16::MAX),
    )));
    let identity = Identity {
        protocol_version: u16::MAX,
        firmware_version: [u16::MAX; 3],
        board: Board::Stm32G474,
        calibration_id: Some(u32::MAX),
        machine: MachineId {
            name: [0xFF; MACHINE_NAME_LEN],
            digest: u32::MAX,
        },
    };
    roundtrip(&DeviceMessage::new(DeviceBody::Reply {
        seq: u16::MAX,
        result: Ok(Response::Identity(identity)),
    }));
}

/// Every refusal reads as a sentence naming what differs with its values.
#[test]
fn refusals_print_the_parameter_and_both_values() {
    let other = CalibrationRefusal::OtherMachine {
        parameter: ImageParameter::LinkBMm,
        image: 161.0,
        machine: 150.0,
        tolerance: 3.0,
    };
    let s = other.to_string();
    assert!(
        s.contains("b_mm is 161.0000 in the image, 150.0000 on this machine"),
        "{s}"
    );
    let record = CalibrationRefusal::OtherRecord {
        image: MachineId::new("second", 0x1234_abcd),
        controller: MachineId::new("paper", 0xdead_beef),
    };
    let s = record.to_string();
    assert!(
        s.contains("machine 'second' (digest 1234abcd)")
            && s.contains("machine 'paper' (digest deadbeef)"),
        "{s}"
    );
    let mode = CalibrationRefusal::OtherMachine {
        parameter: ImageParameter::WorkingMode,
        image: 3.0,
        machine: 7.0,
        tolerance: 0.0,
    };
    assert!(
        mode.to_string()
            .contains("is (+, +, -), this machine's (+, +, +)"),
        "{mode}"
    );
    let far = CalibrationRefusal::OtherMachine {
        parameter: ImageParameter::ToolPositionMm,
        image: 24.7,
        machine: 0.0,
        tolerance: 3.0,
    };
    assert!(far.to_string().contains("up to 24.700 mm"), "{far}");
    let big = CalibrationRefusal::Implausible {
        parameter: ImageParameter::NodeCorrectionMm,
        value: 7.5,
        limit: 3.0,
    };
    assert!(
        big.to_string().contains("(mm) is 7.5e0, the limit 3e0"),
        "{big}"
    );
    let at = CalibrationRefusal::ImplausibleAt {
        parameter: ImageParameter::HomePosition,
        at_mm: [300.0, 0.0],
    };
    assert!(
        at.to_string()
            .contains("outside the image's grid at (300.000, 0.000)"),
        "{at}"
    );
    assert_eq!(
        MachineId::new("a-name-longer-than-16", 1).name(),
        "a-name-longer-th"
    );
}

#[test]
fn another_version_is_refused_with_its_number() {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(
        &Request {
            version: 7,
            seq: 3,
            command: Command::Enable,
        },
        &mut buf,
    )
    .unwrap();
    assert_eq!(
        decode::<Request>(&mut buf[..n - 1]),
        Err(FrameError::Version(7))
    );
}

#[test]
fn a_good_crc_on_bytes_that_are_no_message_is_malformed() {
    // This version, then a command tag that does not exist.
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    let version = PROTOCOL_VERSION as u8;
    let payload = [version, 0, 99];
    let mut raw = payload.to_vec();
    raw.extend_from_slice(&crc.checksum(&payload).to_le_bytes());
    let mut frame = cobs::encode_vec(&raw);
    assert_eq!(decode::<Request>(&mut frame), Err(FrameError::Malformed));
    // Trailing bytes after a whole message are refused too.
    let payload = [version, 0, 0, 0];
    let mut raw = payload.to_vec();
    raw.extend_from_slice(&crc.checksum(&payload).to_le_bytes());
    let mut frame = cobs::encode_vec(&raw);
    assert_eq!(decode::<Request>(&mut frame), Err(FrameError::Malformed));
}

#[test]
fn short_empty_and_oversized_frames_are_refused() {
    assert_eq!(decode::<Request>(&mut []), Err(FrameError::Cobs));
    assert_eq!(decode::<Request>(&mut [2, 7]), Err(FrameError::Short));
    assert_eq!(
        decode::<Request>(&mut [0x11; MAX_FRAME_LEN + 1]),
        Err(FrameError::TooLong)
    );
    let mut reader = FrameReader::new();
    for _ in 0..1000 {
        assert_eq!(reader.push(0x55), None);
    }
    assert_eq!(reader.push(0), Some(Received::TooLong));
    assert_eq!(reader.push(0), None, "reported once, empty frames skipped");
    assert_eq!(reader.pending(), 0);
}

/// The calibration id is CRC-32C (check value of "123456789": 0xE3069283), not zlib's CRC-32
/// (0xCBF43926): the firmware's slot store and the host tool compute it with this one function.
#[test]
fn the_calibration_id_is_crc32c() {
    assert_eq!(
        link_protocol::calibration_image_id(b"123456789"),
        0xE306_9283
    );
    assert_ne!(
        link_protocol::calibration_image_id(b"123456789"),
        0xCBF4_3926
    );
}
