//! Property tests: no input, however hostile, makes the core panic or return a NaN, and the
//! paths each property claims to cover are really taken: every test counts the cases that
//! reached its assertions (`Ok` results, images past the magic bytes, servo steps that
//! commanded a torque) and requires a minimum number of them.

use std::cell::Cell;

use kinematics_core::grid::{
    encode, CorrectionGrid, GridError, GridGeometry, HEADER_LEN, MAGIC, MAX_NODES_PER_AXIS,
};
use kinematics_core::{
    AxisController, AxisGains, AxisReference, Branch, Calibration, FiveBar, Servo, ServoConfig,
    ServoOutput, StepError, WorkingMode,
};
use proptest::prelude::*;
use proptest::test_runner::{Config, FileFailurePersistence, TestCaseError, TestRunner};

/// Runs `property` on `cases` inputs drawn from `strategy` (a failing case is shrunk and the
/// test fails with it) and returns the sum of what the cases returned: how many times they
/// reached the path under test.
fn counted<S: Strategy>(
    cases: u32,
    strategy: S,
    property: impl Fn(S::Value) -> Result<u64, TestCaseError>,
) -> u64
where
    S::Value: std::fmt::Debug,
{
    let reached = Cell::new(0u64);
    // Failing seeds are saved next to this file and replayed first (cargo runs integration
    // tests in the package directory).
    let persistence = FileFailurePersistence::Direct("tests/hostile_inputs.proptest-regressions");
    let config = Config {
        cases,
        failure_persistence: Some(Box::new(persistence)),
        ..Config::default()
    };
    let mut runner = TestRunner::new(config);
    let result = runner.run(&strategy, |input| {
        let n = property(input)?;
        reached.set(reached.get() + n);
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
    reached.get()
}

/// Any f64, with the special values well represented.
fn any_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -400.0..400.0f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(0.0),
        1 => Just(-0.0),
        1 => Just(f64::MAX),
        1 => Just(f64::MIN_POSITIVE),
        1 => Just(1e-300),
        1 => any::<f64>(),
    ]
}

/// A coordinate (mm) or margin: half the time anything, half the time in the workspace of the
/// machines below, so that a good share of the cases gets solved.
fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![any_f64(), 100.0..300.0f64, -100.0..100.0f64]
}

/// An angle (rad): anything, or within a turn.
fn angle() -> impl Strategy<Value = f64> {
    prop_oneof![any_f64(), -3.2..3.2f64]
}

/// A singularity margin: anything, or a sensible one.
fn margin() -> impl Strategy<Value = f64> {
    prop_oneof![any_f64(), 0.0..0.2f64]
}

fn branch() -> impl Strategy<Value = Branch> {
    prop_oneof![Just(Branch::Positive), Just(Branch::Negative)]
}

/// Machines from plausible to absurd.
fn machine() -> impl Strategy<Value = FiveBar<f64>> {
    let link = || prop_oneof![3 => 50.0..300.0f64, 1 => any_f64()];
    machine_with(link(), link(), link(), link())
}

/// Valid machines of any proportions.
fn valid_machine() -> impl Strategy<Value = FiveBar<f64>> {
    machine_with(
        50.0..300.0f64,
        50.0..300.0f64,
        50.0..300.0f64,
        50.0..300.0f64,
    )
}

fn machine_with(
    a: impl Strategy<Value = f64>,
    b: impl Strategy<Value = f64>,
    c: impl Strategy<Value = f64>,
    d: impl Strategy<Value = f64>,
) -> impl Strategy<Value = FiveBar<f64>> {
    (
        a,
        b,
        c,
        d,
        (-20.0..20.0f64, -20.0..20.0f64, -5.0..5.0f64, -5.0..5.0f64),
        (-0.5..0.5f64, -0.5..0.5f64),
        (branch(), branch(), branch()),
    )
        .prop_map(|(a, b, c, d, base, off, (e1, e2, asm))| FiveBar {
            a_mm: a,
            b_mm: b,
            c_mm: c,
            d_mm: d,
            base_a0_mm: [base.2, base.3],
            base_b0_mm: [base.0, base.1],
            encoder_offset_rad: [off.0, off.1],
            mode: WorkingMode {
                elbow_1: e1,
                elbow_2: e2,
                assembly: asm,
            },
        })
}

/// Cases per property: 3000 in CI; `HOSTILE_CASES=N` for a longer fuzz run, e.g.
/// `HOSTILE_CASES=300000 cargo test -p kinematics-core --release --test hostile_inputs -- --nocapture`
/// (each test prints how many cases reached the path it checks).
fn hostile_cases() -> u32 {
    std::env::var("HOSTILE_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(3000)
}

#[test]
fn inverse_never_panics_nor_returns_nan() {
    let cases = hostile_cases();
    let solved = counted(
        cases,
        (machine(), coordinate(), coordinate(), margin()),
        |(m, x, y, margin)| {
            let mut solved = 0;
            for mm in [m, m.cast::<f32>().cast::<f64>()] {
                if let Ok(pose) = mm.inverse_pose([x, y], margin) {
                    solved += 1;
                    prop_assert!(pose
                        .theta_rad
                        .iter()
                        .chain(pose.tool_mm.iter())
                        .all(|v| v.is_finite()));
                    if let Ok(j) = pose.inverse_jacobian() {
                        prop_assert!(j.iter().flatten().all(|v| v.is_finite()));
                    }
                    if let Ok(j) = pose.jacobian() {
                        prop_assert!(j.iter().flatten().all(|v| v.is_finite()));
                    }
                }
            }
            let m32 = m.cast::<f32>();
            if let Ok(t) = m32.inverse([x as f32, y as f32], margin as f32) {
                solved += 1;
                prop_assert!(t.iter().all(|v| v.is_finite()));
            }
            Ok(solved)
        },
    );
    println!("inverse: {solved} solutions checked in {cases} cases");
    assert!(
        solved >= u64::from(cases) / 8,
        "only {solved} inputs were solved: the finite-output check barely ran"
    );
}

#[test]
fn forward_never_panics_nor_returns_nan() {
    let cases = hostile_cases();
    let solved = counted(
        cases,
        (machine(), angle(), angle(), margin()),
        |(m, t1, t2, margin)| {
            let mut solved = 0;
            if let Ok(p) = m.forward([t1, t2], margin) {
                solved += 1;
                prop_assert!(p.iter().all(|v| v.is_finite()));
            }
            if let Ok(p) = m
                .cast::<f32>()
                .forward([t1 as f32, t2 as f32], margin as f32)
            {
                solved += 1;
                prop_assert!(p.iter().all(|v| v.is_finite()));
            }
            Ok(solved)
        },
    );
    println!("forward: {solved} solutions checked in {cases} cases");
    assert!(
        solved >= u64::from(cases) / 5,
        "only {solved} inputs were solved"
    );
}

/// Reachable targets of valid machines round-trip (random machines, not just the paper's).
#[test]
fn valid_machines_round_trip() {
    let cases = hostile_cases();
    let checked = counted(
        cases,
        (valid_machine(), 100.0..300.0f64, -100.0..100.0f64),
        |(m, x, y)| {
            let Ok(theta) = m.inverse([x, y], 0.05) else {
                return Ok(0);
            };
            let back = m.forward(theta, 0.0);
            prop_assert!(back.is_ok(), "{:?}", back);
            let back = back.unwrap();
            prop_assert!(
                (back[0] - x).abs() < 1e-8 && (back[1] - y).abs() < 1e-8,
                "{:?} vs {:?}",
                back,
                [x, y]
            );
            Ok(1)
        },
    );
    println!("round trip: {checked} of {cases} targets reachable and checked");
    assert!(
        checked >= u64::from(cases) / 10,
        "only {checked} round trips checked"
    );
}

// ---------------------------------------------------------------------------------------------
// Grid images.

/// A valid image over the paper's workspace with a smooth correction field.
fn valid_image() -> (GridGeometry, Vec<u8>) {
    let g = GridGeometry {
        nx: 21,
        ny: 31,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    };
    let nodes: Vec<[f32; 2]> = (0..g.len())
        .map(|k| [1e-4 * (k as f32).sin(), -2e-4 * (k as f32 * 0.3).cos()])
        .collect();
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &nodes).unwrap();
    (g, img)
}

/// Writes the CRC over `img[..total - 4]` at `total - 4`, as a tool writing a consistent but
/// wrong image would.
fn fix_crc(img: &mut [u8], total: usize) {
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(&img[..total - 4]);
    img[total - 4..total].copy_from_slice(&crc.to_le_bytes());
}

/// Random bytes are refused, also when they start like an image: then the parser must get
/// past the magic bytes and still refuse.
#[test]
fn grid_parse_refuses_garbage() {
    let cases = hostile_cases();
    let (_, img) = valid_image();
    let header = img[..12].to_vec();
    // Magic, version, header length and node counts of a real image, then `n` bytes of garbage.
    let after_header = move |n: std::ops::Range<usize>| {
        let header = header.clone();
        proptest::collection::vec(any::<u8>(), n)
            .prop_map(move |tail| [header.clone(), tail].concat())
    };
    let garbage = prop_oneof![
        1 => proptest::collection::vec(any::<u8>(), 0..400),
        1 => after_header(0..6000),
        // At least as long as the image those counts make (5284 bytes): only the CRC can refuse.
        2 => after_header(5272..5600),
    ];
    let past_magic = counted(cases, garbage, |bytes| {
        let result = CorrectionGrid::parse(&bytes);
        prop_assert!(result.is_err(), "garbage of {} bytes accepted", bytes.len());
        Ok(u64::from(!matches!(
            result,
            Err(GridError::BadMagic) | Err(GridError::Truncated)
        )))
    });
    println!(
        "garbage: {past_magic} of {cases} inputs got past the magic bytes and the length check"
    );
    assert!(
        past_magic >= u64::from(cases) / 4,
        "only {past_magic} inputs got past the magic bytes"
    );
}

/// One field of the image: where it is and what it holds.
#[derive(Clone, Copy, Debug)]
enum Field {
    Magic,
    Version,
    HeaderLen,
    Nx,
    Ny,
    Flags,
    /// The k-th f32 of the header (offset 16 + 4k): x0, y0, step_x, step_y, a, b, c, d,
    /// b0_x, b0_y, offset_1, offset_2, a0_x, a0_y.
    HeaderF32(usize),
    /// One f32 of the node table.
    Node(usize),
}

const FIELD_KINDS: usize = 8;

fn field_kind(f: Field) -> usize {
    match f {
        Field::Magic => 0,
        Field::Version => 1,
        Field::HeaderLen => 2,
        Field::Nx => 3,
        Field::Ny => 4,
        Field::Flags => 5,
        Field::HeaderF32(_) => 6,
        Field::Node(_) => 7,
    }
}

fn field() -> impl Strategy<Value = Field> {
    prop_oneof![
        Just(Field::Magic),
        Just(Field::Version),
        Just(Field::HeaderLen),
        Just(Field::Nx),
        Just(Field::Ny),
        Just(Field::Flags),
        (0..14usize).prop_map(Field::HeaderF32),
        (0..2 * 21 * 31usize).prop_map(Field::Node),
    ]
}

/// Raw 32 bits for the field: any value, small integers, the valid value's neighbourhood, and
/// f32 specials.
fn raw_value() -> impl Strategy<Value = u32> {
    prop_oneof![
        2 => any::<u32>(),
        2 => 0..2048u32,
        1 => Just(u32::from_le_bytes(MAGIC)),
        1 => Just(1u32),
        1 => Just(HEADER_LEN as u32),
        1 => 0..8u32,
        // Node counts a 21x31 image has room for.
        1 => 2..32u32,
        1 => Just(f32::NAN.to_bits()),
        1 => Just(f32::INFINITY.to_bits()),
        1 => Just(f32::NEG_INFINITY.to_bits()),
        1 => Just((-0.0f32).to_bits()),
        1 => Just(0.0f32.to_bits()),
        1 => Just((-150.0f32).to_bits()),
        3 => (-400.0..400.0f32).prop_map(f32::to_bits),
        1 => Just(1e-30f32.to_bits()),
    ]
}

/// What the format (grid.rs, "Layout") says parsing must give for one tampered field with the
/// CRC fixed, derived from the layout table, not from the parser: `Ok(())` or the error.
fn expected(field: Field, raw: u32, g: &GridGeometry, len: usize) -> Result<(), GridError> {
    let f = f32::from_bits(raw);
    let u16v = raw as u16;
    let total = |nx: u16, ny: u16| HEADER_LEN + 8 * nx as usize * ny as usize + 4;
    let counts = |n: u16| (2..=MAX_NODES_PER_AXIS).contains(&n);
    match field {
        Field::Magic if raw.to_le_bytes() == MAGIC => Ok(()),
        Field::Magic => Err(GridError::BadMagic),
        Field::Version if u16v == 1 => Ok(()),
        Field::Version => Err(GridError::UnsupportedVersion(u16v)),
        Field::HeaderLen if u16v as usize == HEADER_LEN => Ok(()),
        Field::HeaderLen => Err(GridError::BadHeader),
        Field::Nx | Field::Ny => {
            let (nx, ny) = if matches!(field, Field::Nx) {
                (u16v, g.ny)
            } else {
                (g.nx, u16v)
            };
            if !counts(u16v) {
                Err(GridError::BadHeader)
            } else if total(nx, ny) > len {
                Err(GridError::Truncated)
            } else {
                // A smaller grid: its nodes are the first ones of the original, all finite.
                Ok(())
            }
        }
        Field::Flags if raw & !0b111 != 0 => Err(GridError::BadHeader),
        Field::Flags => Ok(()),
        // x0, y0: any finite number.
        Field::HeaderF32(0 | 1) if !f.is_finite() => Err(GridError::NonFinite),
        // Steps: finite and positive.
        Field::HeaderF32(2 | 3) if !(f.is_finite() && f > 0.0) => Err(GridError::NonFinite),
        // Links: finite and positive.
        Field::HeaderF32(4..=7) if !(f.is_finite() && f > 0.0) => Err(GridError::BadModel),
        // Base positions and encoder offsets: finite.
        Field::HeaderF32(8..=13) if !f.is_finite() => Err(GridError::BadModel),
        Field::HeaderF32(_) => Ok(()),
        Field::Node(_) if !f.is_finite() => Err(GridError::NonFinite),
        Field::Node(_) => Ok(()),
    }
}

/// Images tampered field by field, the CRC recomputed: every field must be refused exactly when
/// the format says so, with the error it names, and an accepted image must read back what was
/// written. Every field is tampered, and both outcomes occur for each kind of field.
#[test]
fn grid_images_tampered_field_by_field_with_the_crc_fixed() {
    let cases = hostile_cases();
    let (g, img) = valid_image();
    let outcomes: Vec<Cell<[u64; 2]>> = (0..FIELD_KINDS).map(|_| Cell::new([0; 2])).collect();
    counted(cases, (field(), raw_value()), |(field, raw)| {
        let mut v = img.clone();
        let bytes = raw.to_le_bytes();
        let (at, width) = match field {
            Field::Magic => (0, 4),
            Field::Version => (4, 2),
            Field::HeaderLen => (6, 2),
            Field::Nx => (8, 2),
            Field::Ny => (10, 2),
            Field::Flags => (12, 4),
            Field::HeaderF32(k) => (16 + 4 * k, 4),
            Field::Node(k) => (HEADER_LEN + 4 * k, 4),
        };
        v[at..at + width].copy_from_slice(&bytes[..width]);
        // The CRC goes where the tampered header says the image ends, if that is inside.
        let (nx, ny) = (
            u16::from_le_bytes([v[8], v[9]]),
            u16::from_le_bytes([v[10], v[11]]),
        );
        let total = HEADER_LEN + 8 * nx as usize * ny as usize + 4;
        if (2..=MAX_NODES_PER_AXIS).contains(&nx)
            && (2..=MAX_NODES_PER_AXIS).contains(&ny)
            && total <= v.len()
        {
            fix_crc(&mut v, total);
        }
        let want = expected(field, raw, &g, v.len());
        let got = CorrectionGrid::parse(&v);
        prop_assert_eq!(
            got.as_ref().map(|_| ()).map_err(|e| *e),
            want,
            "{:?} = {:#x}",
            field,
            raw
        );
        let kind = field_kind(field);
        let mut o = outcomes[kind].get();
        o[usize::from(got.is_ok())] += 1;
        outcomes[kind].set(o);
        if let Ok(grid) = got {
            // Whatever a consistent image holds, judging it refuses or accepts, never panics.
            let _ = kinematics_core::judge_image(&grid, &kinematics_core::MachineRecord::paper());
            let f = f32::from_bits(raw);
            let geo = grid.geometry();
            let m = grid.model();
            let read_back = match field {
                Field::Nx => geo.nx == raw as u16,
                Field::Ny => geo.ny == raw as u16,
                Field::Flags => {
                    let bit = |b: Branch, n: u32| u32::from(b == Branch::Positive) << n;
                    bit(m.mode.elbow_1, 0) | bit(m.mode.elbow_2, 1) | bit(m.mode.assembly, 2) == raw
                }
                Field::HeaderF32(k) => {
                    let stored = [
                        geo.x0_mm,
                        geo.y0_mm,
                        geo.step_x_mm,
                        geo.step_y_mm,
                        m.a_mm,
                        m.b_mm,
                        m.c_mm,
                        m.d_mm,
                        m.base_b0_mm[0],
                        m.base_b0_mm[1],
                        m.encoder_offset_rad[0],
                        m.encoder_offset_rad[1],
                        m.base_a0_mm[0],
                        m.base_a0_mm[1],
                    ];
                    stored[k].to_bits() == f.to_bits()
                }
                Field::Node(k) => {
                    let node = (k / 2) as u16;
                    grid.node_rad(node % g.nx, node / g.nx)[k % 2].to_bits() == f.to_bits()
                }
                Field::Magic | Field::Version | Field::HeaderLen => true,
            };
            prop_assert!(
                read_back,
                "{:?} = {:#x} accepted but not read back",
                field,
                raw
            );
        }
        Ok(1)
    });
    for (kind, o) in outcomes.iter().enumerate() {
        let [refused, accepted] = o.get();
        println!("field kind {kind}: {refused} refused, {accepted} accepted");
        assert!(
            refused >= 20 && accepted >= 5,
            "field kind {kind}: {refused} refused, {accepted} accepted"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// The servo.

const HOME_MM: [f32; 2] = [212.132, 0.0];

fn calibrations(img: &[u8]) -> [Calibration<'_>; 2] {
    [
        Calibration {
            model: FiveBar::paper_nominal(),
            grid: None,
        },
        Calibration::from_grid(CorrectionGrid::parse(img).unwrap()),
    ]
}

fn small_grid() -> Vec<u8> {
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let mut img = vec![0u8; g.image_len()];
    encode(&mut img, &g, &FiveBar::paper_nominal(), &[[1e-4, -1e-4]; 9]).unwrap();
    img
}

/// What one case feeds the servo.
#[derive(Clone, Debug)]
enum Sequence {
    /// Arbitrary setpoints and encoder readings from an arbitrary engage.
    Hostile {
        steps: Vec<(f64, f64, f64, f64)>,
        start: (f64, f64),
    },
    /// From the engaged home pose: setpoint accelerations within ±1 g per axis (fractions), the
    /// encoders one sample behind the reference plus noise (rad); at `spike`, one hostile step.
    Smooth {
        steps: Vec<(f32, f32, f32, f32)>,
        spike: Option<(usize, (f64, f64, f64, f64))>,
    },
}

fn sequence() -> impl Strategy<Value = Sequence> {
    let hostile_step = || (any_f64(), any_f64(), any_f64(), any_f64());
    let noise = || prop_oneof![3 => -2e-3..2e-3f32, 1 => -1.5e-2..1.5e-2f32];
    prop_oneof![
        (
            proptest::collection::vec(hostile_step(), 1..40),
            (-3.0..3.0f64, -3.0..3.0f64)
        )
            .prop_map(|(steps, start)| Sequence::Hostile { steps, start }),
        (
            proptest::collection::vec((-1.0..1.0f32, -1.0..1.0f32, noise(), noise()), 1..100),
            proptest::option::of((0..100usize, hostile_step())),
        )
            .prop_map(|(steps, spike)| Sequence::Smooth { steps, spike }),
    ]
}

/// Whatever the servo is fed, it never panics, never commands a non-finite torque or one beyond
/// its limit, every feedback fault is latched and no setpoint refusal is. Half the cases are smooth sequences from the engaged
/// pose, so the torque checks run on a large share of the steps, at the limit too.
#[test]
fn servo_never_panics_nor_commands_nan() {
    let cases = hostile_cases();
    let img = small_grid();
    let dt = ServoConfig::default().sample_period_s;
    let g_mm_s2 = kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
    let steps = Cell::new(0u64);
    let at_limit = Cell::new(0u64);
    let smooth_refused = Cell::new(0u64);
    let ok = counted(cases, sequence(), |seq| {
        let mut ok = 0;
        for cal in calibrations(&img) {
            let mut servo = Servo::new(ServoConfig::default()).unwrap();
            let mut check = |servo: &Servo,
                             before: (Option<kinematics_core::ServoFault>, bool),
                             result: Result<ServoOutput, StepError>| {
                steps.set(steps.get() + 1);
                match result {
                    Ok(out) => {
                        ok += 1;
                        for k in 0..2 {
                            let (t, limit) =
                                (out.torque_nm[k], servo.config().axes[k].torque_limit_nm);
                            prop_assert!(
                                t.is_finite() && t.abs() <= limit,
                                "torque {} (limit {})",
                                t,
                                limit
                            );
                            if t.abs() == limit {
                                at_limit.set(at_limit.get() + 1);
                            }
                        }
                        Ok(true)
                    }
                    // A feedback fault is latched and reported as the latched fault.
                    Err(StepError::Fault(e)) => {
                        prop_assert_eq!(servo.fault(), Some(e));
                        prop_assert!(!servo.is_engaged());
                        Ok(false)
                    }
                    // A refused setpoint latches nothing.
                    Err(StepError::Refused(_)) => {
                        prop_assert_eq!((servo.fault(), servo.is_engaged()), before);
                        Ok(false)
                    }
                }
            };
            match &seq {
                Sequence::Hostile { steps, start } => {
                    let _ = servo.engage(&cal, [start.0 as f32, start.1 as f32]);
                    for &(x, y, e1, e2) in steps {
                        let before = (servo.fault(), servo.is_engaged());
                        let r = servo.step(&cal, [x as f32, y as f32], [e1 as f32, e2 as f32]);
                        check(&servo, before, r)?;
                    }
                }
                Sequence::Smooth { steps, spike } => {
                    let mut encoder = cal.command_rad(HOME_MM, 0.05).unwrap();
                    let mut p = servo.engage(&cal, encoder).unwrap();
                    let mut v = [0.0f32; 2];
                    let mut reference = encoder;
                    let mut refused = false;
                    for (k, &(ax, ay, n1, n2)) in steps.iter().enumerate() {
                        let before = (servo.fault(), servo.is_engaged());
                        let r = match spike {
                            Some((at, (x, y, e1, e2))) if *at == k => {
                                servo.step(&cal, [*x as f32, *y as f32], [*e1 as f32, *e2 as f32])
                            }
                            _ => {
                                v = [v[0] + ax * g_mm_s2 * dt, v[1] + ay * g_mm_s2 * dt];
                                p = [p[0] + v[0] * dt, p[1] + v[1] * dt];
                                servo.step(&cal, p, encoder)
                            }
                        };
                        if let Ok(out) = &r {
                            reference = out.reference_rad;
                        }
                        refused |= !check(&servo, before, r)?;
                        // An ideal plant one sample behind, plus encoder noise.
                        encoder = [reference[0] + n1, reference[1] + n2];
                    }
                    if refused && spike.is_none() {
                        smooth_refused.set(smooth_refused.get() + 1);
                    }
                }
            }
        }
        Ok(ok)
    });
    let (steps, at_limit) = (steps.get(), at_limit.get());
    println!("servo: {ok} of {steps} steps returned Ok, {at_limit} torques at the limit");
    assert_eq!(
        smooth_refused.get(),
        0,
        "smooth sequences within the limits were refused"
    );
    assert!(
        ok * 3 >= steps,
        "only {ok} of {steps} steps returned Ok: the torque checks barely ran"
    );
    assert!(
        at_limit >= 100,
        "only {at_limit} torques at the limit: the limit check barely ran"
    );
}

// ---------------------------------------------------------------------------------------------
// Hostile settings: they are meant to come over a link.

/// The 28 numbers of a `ServoConfig`, in a fixed order (axis gains field by field, then the
/// servo's own).
const SETTINGS_FIELDS: usize = 28;
/// The numbers of one axis' `AxisGains`.
const GAINS: usize = 11;

fn gains_to_array(g: &AxisGains) -> [f32; GAINS] {
    [
        g.kp_nm_per_rad,
        g.ki_nm_per_rad_s,
        g.kd_nm_s_per_rad,
        g.inertia_ff_kg_m2,
        g.viscous_ff_nm_s_per_rad,
        g.coulomb_ff_nm,
        g.coulomb_ff_speed_rad_s,
        g.torque_limit_nm,
        g.integral_limit_nm,
        g.observer_bandwidth_rad_s,
        g.observer_inertia_kg_m2,
    ]
}

fn gains_from(v: &[f32]) -> AxisGains {
    AxisGains {
        kp_nm_per_rad: v[0],
        ki_nm_per_rad_s: v[1],
        kd_nm_s_per_rad: v[2],
        inertia_ff_kg_m2: v[3],
        viscous_ff_nm_s_per_rad: v[4],
        coulomb_ff_nm: v[5],
        coulomb_ff_speed_rad_s: v[6],
        torque_limit_nm: v[7],
        integral_limit_nm: v[8],
        observer_bandwidth_rad_s: v[9],
        observer_inertia_kg_m2: v[10],
    }
}

fn settings_to_array(c: &ServoConfig) -> [f32; SETTINGS_FIELDS] {
    let mut v = [0.0f32; SETTINGS_FIELDS];
    v[..GAINS].copy_from_slice(&gains_to_array(&c.axes[0]));
    v[GAINS..2 * GAINS].copy_from_slice(&gains_to_array(&c.axes[1]));
    v[2 * GAINS..].copy_from_slice(&[
        c.sample_period_s,
        c.min_transmission,
        c.max_speed_mm_s,
        c.max_accel_mm_s2,
        c.max_following_error_rad,
        0.0,
    ]);
    v
}

fn settings_from(v: &[f32; SETTINGS_FIELDS]) -> ServoConfig {
    ServoConfig {
        axes: [gains_from(&v[..GAINS]), gains_from(&v[GAINS..2 * GAINS])],
        sample_period_s: v[22],
        min_transmission: v[23],
        max_speed_mm_s: v[24],
        max_accel_mm_s2: v[25],
        max_following_error_rad: v[26],
    }
}

/// The documented rules (`ServoConfig::validate`, `AxisGains::validate`), written out here from
/// the doc comments rather than by calling them.
fn settings_valid(v: &[f32; SETTINGS_FIELDS]) -> bool {
    let finite_non_negative = |x: f32| x.is_finite() && x >= 0.0;
    let gains_ok = |g: &[f32]| {
        [g[0], g[1], g[2], g[7], g[8], g[9], g[10]]
            .into_iter()
            .all(finite_non_negative)
            && [g[3], g[4], g[5]].into_iter().all(f32::is_finite)
            && g[6].is_finite()
            && g[6] > 0.0
    };
    gains_ok(&v[..GAINS])
        && gains_ok(&v[GAINS..2 * GAINS])
        && v[22].is_finite()
        && v[22] > 0.0
        && (0.0..1.0).contains(&v[23])
        && v[24..27].iter().copied().all(finite_non_negative)
}

fn hostile_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(0.0f32),
        Just(-0.0f32),
        Just(f32::MAX),
        Just(-f32::MAX),
        Just(f32::MIN_POSITIVE),
        Just(-1.0f32),
        -1e6..1e6f32,
        any::<f32>(),
    ]
}

/// The default settings with every field scaled by 0.1..10 (valid but unusual), then up to three
/// fields replaced by hostile values.
fn hostile_settings() -> impl Strategy<Value = [f32; SETTINGS_FIELDS]> {
    (
        proptest::collection::vec(0.1..10.0f32, SETTINGS_FIELDS),
        proptest::collection::vec((0..SETTINGS_FIELDS - 1, hostile_f32()), 0..4),
    )
        .prop_map(|(scale, replaced)| {
            let mut v = settings_to_array(&ServoConfig::default());
            for (x, s) in v.iter_mut().zip(scale) {
                *x *= s;
            }
            // A margin scaled past 1 would refuse every pose: keep the scaled one sensible.
            v[23] = v[23].min(0.3);
            for (k, x) in replaced {
                v[k] = x;
            }
            v
        })
}

/// No settings value panics: `Servo::new` refuses exactly what the documented rules refuse; a
/// servo built from unusual but valid settings commands finite torques within its limit; the
/// PID given the raw (possibly refused) gains never panics and returns a finite torque within
/// the limit (zero for a limit that is not a finite non-negative number).
#[test]
fn hostile_settings_never_panic() {
    let cases = hostile_cases();
    let (refused, tracked, direct) = (Cell::new(0u64), Cell::new(0u64), Cell::new(0u64));
    let cal = Calibration {
        model: FiveBar::paper_nominal(),
        grid: None,
    };
    let strategy = (
        hostile_settings(),
        proptest::collection::vec((-1.0..1.0f32, -1.0..1.0f32, -1e-3..1e-3f32), 1..60),
    );
    counted(cases, strategy, |(v, motion)| {
        let config = settings_from(&v);
        let valid = settings_valid(&v);
        let servo = Servo::new(config);
        prop_assert_eq!(
            servo.is_ok(),
            valid,
            "{:?}: {:?}",
            config,
            servo.as_ref().err()
        );
        // The PID on its own, with whatever gains, at a reference far off and near.
        for gains in &config.axes {
            for (reference, angle, velocity) in [
                (1.0f32, 0.0f32, 0.0f32),
                (1e-3, 0.0, 50.0),
                (-2.0, 1.0, -3.0),
            ] {
                let r = AxisReference {
                    angle_rad: reference,
                    velocity_rad_s: velocity,
                    acceleration_rad_s2: 1e4,
                };
                let mut c = AxisController::default();
                for _ in 0..3 {
                    let t = c.update(gains, &r, angle, 0.0, config.sample_period_s);
                    let limit = gains.torque_limit_nm;
                    let bound = if limit.is_finite() && limit >= 0.0 {
                        limit
                    } else {
                        0.0
                    };
                    prop_assert!(
                        t.is_finite() && t.abs() <= bound,
                        "torque {} with {:?}",
                        t,
                        gains
                    );
                    prop_assert!(c.integral_nm().is_finite());
                    direct.set(direct.get() + 1);
                }
            }
        }
        let Ok(mut servo) = servo else {
            refused.set(refused.get() + 1);
            return Ok(0);
        };
        let Ok(mut encoder) = cal.command_rad(HOME_MM, config.min_transmission) else {
            return Ok(0);
        };
        let Ok(mut p) = servo.engage(&cal, encoder) else {
            return Ok(0);
        };
        let dt = config.sample_period_s;
        let mut vel = [0.0f32; 2];
        let mut reached = 0;
        for (ax, ay, noise) in motion {
            let a = 0.5 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2;
            vel = [vel[0] + ax * a * dt, vel[1] + ay * a * dt];
            p = [p[0] + vel[0] * dt, p[1] + vel[1] * dt];
            match servo.step(&cal, p, encoder) {
                Ok(out) => {
                    for k in 0..2 {
                        let limit = config.axes[k].torque_limit_nm;
                        prop_assert!(
                            out.torque_nm[k].is_finite() && out.torque_nm[k].abs() <= limit
                        );
                    }
                    encoder = [out.reference_rad[0] + noise, out.reference_rad[1] - noise];
                    reached += 1;
                }
                Err(StepError::Fault(_)) => break,
                Err(StepError::Refused(_)) => {}
            }
        }
        tracked.set(tracked.get() + reached);
        Ok(reached)
    });
    let (refused, tracked, direct) = (refused.get(), tracked.get(), direct.get());
    println!("hostile settings: {refused} of {cases} refused by Servo::new, {tracked} servo steps tracked with the others, {direct} PID updates with raw gains");
    assert!(
        refused >= u64::from(cases) / 4,
        "only {refused} settings refused: the hostile values barely ran"
    );
    assert!(
        tracked >= u64::from(cases) * 5,
        "only {tracked} steps tracked with unusual valid settings"
    );
}
