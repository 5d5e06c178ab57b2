//! The machine is the image's: the boot's judgement against the image's own record, an
//! upload's against the machine in force; a calibration measured in a tracker's frame accepted,
//! another design refused naming what differs; the images a CRC let through that moved the
//! machine refused; the servo's slope-change limit at and just beyond it.
use super::*;
use crate::host_link::image_refusal;
use crate::settings::Settings;
use kinematics_core::grid::{
    append_backlash, append_dynamics, append_machine, append_workspace, encode, GridGeometry,
    WorkspaceLimits, BACKLASH_LEN, DYNAMICS_LEN, MACHINE_LEN, WORKSPACE_LEN,
};
use kinematics_core::machine::{
    ImageRefusal, Implausible, MachineMismatch, MachineName, ModelParameter, ParameterDifference,
};
use kinematics_core::{paper, Backlash, ConvexWorkspace, FiveBar, FiveBarDynamics};
use link_protocol::{CalibrationRefusal, ImageParameter, MachineId};

#[allow(dead_code)]
mod machine {
    include!("../../../src/board/qemu/machine.rs");
}
mod synthetic {
    include!("../../../src/board/qemu/synthetic_image.rs");
}

/// The built-in machine (the paper's) with the default servo's slope-change limit.
fn check() -> ImageCheck {
    Settings::default().image_check()
}

/// The paper's grid lattice.
fn paper_grid() -> GridGeometry {
    paper::grid_geometry()
}

/// What an image carries besides its grid.
#[derive(Clone, Copy, Default)]
struct Blocks {
    workspace: Option<WorkspaceLimits>,
    dynamics: Option<FiveBarDynamics<f32>>,
    backlash_rad: Option<[f32; 2]>,
    record: Option<MachineRecord>,
}

/// An image of `model` over `g` with `field(i, j)` at each node and `blocks` (the record last).
fn build(
    g: &GridGeometry,
    model: &FiveBar<f32>,
    field: impl Fn(u16, u16) -> [f32; 2],
    blocks: Blocks,
) -> Vec<u8> {
    let mut nodes = Vec::new();
    for j in 0..g.ny {
        for i in 0..g.nx {
            nodes.push(field(i, j));
        }
    }
    let room = WORKSPACE_LEN + DYNAMICS_LEN + BACKLASH_LEN + MACHINE_LEN;
    let mut img = vec![0u8; g.image_len() + room];
    let n = encode(&mut img, g, model, &nodes).unwrap();
    let mut end = n;
    if let Some(w) = blocks.workspace {
        end = append_workspace(&mut img, n, end, &w).unwrap();
    }
    if let Some(d) = blocks.dynamics {
        end = append_dynamics(&mut img, n, end, &d).unwrap();
    }
    if let Some(b) = blocks.backlash_rad {
        end = append_backlash(&mut img, n, end, &Backlash::new(b).unwrap()).unwrap();
    }
    if let Some(r) = blocks.record {
        end = append_machine(&mut img, n, end, &r).unwrap();
    }
    img.truncate(end);
    img
}

/// A machine of another design, the shape of host-sim's `machines/second.toml`: unequal links,
/// the motor axes 67 mm apart away from the origin, encoder zeros off the geometric zero, an
/// octagonal workspace inside a 4 mm grid, its own home, stop margin and dynamics.
fn second() -> (MachineRecord, GridGeometry) {
    let deg = |d: f32| d.to_radians();
    let nominal = FiveBar {
        a_mm: 120.0,
        b_mm: 170.0,
        c_mm: 160.0,
        d_mm: 130.0,
        base_a0_mm: [10.0, 20.0],
        base_b0_mm: [15.0, -65.0],
        encoder_offset_rad: [deg(5.0), deg(-8.0)],
        mode: kinematics_core::WorkingMode::PAPER,
    };
    let octagon = [
        [185.0f32, -70.0],
        [240.0, -70.0],
        [250.0, -50.0],
        [250.0, 35.0],
        [235.0, 50.0],
        [175.0, 50.0],
        [170.0, 40.0],
        [170.0, -55.0],
    ];
    let dynamics = FiveBarDynamics {
        motor_inertia_kg_m2: [0.0034, 0.00352],
        tool_mass_kg: 0.165,
        distal_inertia_kg_m2: [-0.000339, -0.0003],
        viscous_nm_s_per_rad: [0.02, 0.02],
        coulomb_nm: [0.05, 0.05],
        coulomb_speed_rad_s: 0.01,
    };
    let record = MachineRecord {
        name: MachineName::new("second").unwrap(),
        nominal,
        encoder_sign: [1, 1],
        workspace: WorkspaceLimits {
            region: ConvexWorkspace::new(&octagon).unwrap(),
            stop_margin_mm: 0.2,
        },
        home_mm: [210.0, -10.0],
        limits: kinematics_core::machine::PlausibilityLimits::with_nominal_dynamics(dynamics),
    };
    record.validate().unwrap();
    let grid = GridGeometry {
        nx: 22,
        ny: 32,
        x0_mm: 168.0,
        y0_mm: -72.0,
        step_x_mm: 4.0,
        step_y_mm: 4.0,
    };
    (record, grid)
}

/// `machine`'s commissioning image: its nominal, zero corrections, its workspace and record.
fn commissioning(machine: &MachineRecord, g: &GridGeometry) -> Vec<u8> {
    let blocks = Blocks {
        workspace: Some(machine.workspace),
        record: Some(*machine),
        ..Blocks::default()
    };
    build(g, &machine.nominal, |_, _| [0.0; 2], blocks)
}

/// `nominal` as a calibration measured with a laser tracker standing elsewhere identifies it:
/// the instrument's frame (rotation `rot_rad` about its origin, then `offset_mm`) lands in the
/// base A0 and B0 and in both encoder offsets; with small link errors a real fit finds.
fn in_tracker_frame(nominal: &FiveBar<f32>, offset_mm: [f32; 2], rot_rad: f32) -> FiveBar<f32> {
    let (s, c) = rot_rad.sin_cos();
    let turn = |p: [f32; 2]| [c * p[0] - s * p[1], s * p[0] + c * p[1]];
    let a0 = turn(nominal.base_a0_mm);
    FiveBar {
        a_mm: nominal.a_mm + 0.12,
        b_mm: nominal.b_mm + 0.35,
        d_mm: nominal.d_mm - 0.2,
        base_a0_mm: [a0[0] + offset_mm[0], a0[1] + offset_mm[1]],
        base_b0_mm: turn(nominal.base_b0_mm),
        encoder_offset_rad: nominal.encoder_offset_rad.map(|o| o + rot_rad),
        ..*nominal
    }
}

/// A smooth correction field of a few hundred microradians (as a real grid's).
fn smooth(i: u16, j: u16) -> [f32; 2] {
    let (u, v) = (f32::from(i) / 20.0, f32::from(j) / 30.0);
    [
        3e-4 * (1.3 * u).sin(),
        -2e-4 * (1.1 * v).cos() + 1e-4 * u * v,
    ]
}

fn judged(img: &[u8], check: &ImageCheck, when: Judged) -> Result<MachineRecord, ImageError> {
    validate_image(img, check, when).map(|v| v.machine)
}

#[test]
fn a_valid_image_gives_its_model_and_grid_and_without_a_record_the_built_in_machine() {
    let mut region = synthetic::synthetic_image(1.0);
    region.extend([0xFF; 100]); // erased flash after the image
    let loaded = load(&region, &check(), false);
    assert_eq!(loaded.state, CalibrationState::Valid);
    assert_eq!(loaded.machine, MachineRecord::paper());
    let grid = loaded.calibration.grid.expect("grid in use");
    assert!(grid.correction_rad([200.0, 0.0]).is_ok());
}

/// The image's length (what an upload commits and a slot holds) ends with its chain of
/// blocks, whichever it has, not with the grid's CRC nor the region.
#[test]
fn the_image_length_includes_its_chain_of_blocks() {
    let g = paper_grid();
    let plain = build(&g, &FiveBar::paper_nominal(), smooth, Blocks::default());
    let full = build(
        &g,
        &FiveBar::paper_nominal(),
        smooth,
        Blocks {
            workspace: Some(MachineRecord::paper().workspace),
            dynamics: Some(machine::IMAGE_DYNAMICS),
            backlash_rad: Some([2e-5, 3e-5]),
            record: Some(MachineRecord::paper()),
        },
    );
    let mut region = full.clone();
    region.extend([0xFF; 64]);
    for when in [Judged::AtBoot, Judged::AtCommit] {
        let v = validate_image(&region, &check(), when).unwrap();
        assert_eq!(v.len, full.len());
        assert!(v.grid.workspace().is_some() && v.grid.dynamics().is_some());
        assert!(v.grid.backlash().is_some() && v.grid.machine().is_some());
        assert_eq!(
            validate_image(&plain, &check(), when).unwrap().len,
            plain.len()
        );
    }
}

#[test]
fn a_bad_image_is_refused_unless_uncorrected_running_is_allowed() {
    let mut region = synthetic::synthetic_image(1.0);
    region[100] ^= 1;
    let loaded = load(&region, &check(), false);
    assert_eq!(
        loaded.state,
        CalibrationState::Refused(ImageError::Grid(GridError::BadCrc))
    );
    assert!(loaded.calibration.grid.is_none());
    assert_eq!(
        loaded.machine,
        MachineRecord::paper(),
        "the built-in machine"
    );
    let loaded = load(&[0xFF; 4096], &check(), true);
    assert_eq!(
        loaded.state,
        CalibrationState::Uncorrected(ImageError::Grid(GridError::BadMagic))
    );
    assert!(loaded.calibration.grid.is_none());
    assert_eq!(loaded.calibration.model, FiveBar::paper_nominal());
}

/// The README's calibration: a fitted model whose base carries the tracker's offset (3.27 mm)
/// and whose offsets carry its rotation. The per-parameter judgement refused it (2 mm per
/// parameter); judged by what the machine does, it is this machine's, at boot and at commit,
/// with its record and without.
#[test]
fn a_calibration_measured_in_a_trackers_frame_is_this_machines() {
    let paper = MachineRecord::paper();
    let fitted = in_tracker_frame(&paper.nominal, [-0.03, 3.27], (-0.25f32).to_radians());
    for record in [Some(paper), None] {
        let img = build(
            &paper_grid(),
            &fitted,
            smooth,
            Blocks {
                workspace: Some(paper.workspace),
                dynamics: Some(machine::IMAGE_DYNAMICS),
                record,
                ..Blocks::default()
            },
        );
        for when in [Judged::AtBoot, Judged::AtCommit] {
            assert_eq!(judged(&img, &check(), when), Ok(paper), "{when:?}");
        }
    }
    // Moved by metres and turned by 20°: still this machine.
    let far = in_tracker_frame(&paper.nominal, [800.0, -300.0], 0.35);
    let img = build(&paper_grid(), &far, |_, _| [0.0; 2], Blocks::default());
    let grid = CorrectionGrid::parse(&img).unwrap();
    assert_eq!(
        same_machine(&paper, grid.model()).map(|s| s.worst_mm < 1.0),
        Ok(true)
    );
}

/// Another design is refused at commit naming what differs with both values, on the link too.
#[test]
fn another_design_is_refused_naming_what_differs() {
    let n = FiveBar::paper_nominal();
    let refusal = |model: &FiveBar<f32>| {
        let img = build(&paper_grid(), model, |_, _| [0.0; 2], Blocks::default());
        let e = judged(&img, &check(), Judged::AtCommit).expect_err("accepted");
        (e, image_refusal(&e))
    };
    // Link b 11 mm longer: b alone explains it.
    let (e, link) = refusal(&FiveBar { b_mm: 161.0, ..n });
    assert!(
        matches!(
            e,
            ImageError::Refused(ImageRefusal::OtherMachine(MachineMismatch::Geometry {
                parameter: Some(ParameterDifference {
                    parameter: ModelParameter::B,
                    ..
                }),
                ..
            }))
        ),
        "{e:?}"
    );
    assert_eq!(
        link,
        CalibrationRefusal::OtherMachine {
            parameter: ImageParameter::LinkBMm,
            image: 161.0,
            machine: 150.0,
            tolerance: 3.0
        }
    );
    // The mirrored assembly: the IK would pick another pose.
    let mut mirrored = n;
    mirrored.mode.assembly = kinematics_core::Branch::Negative;
    let (_, link) = refusal(&mirrored);
    assert_eq!(
        link,
        CalibrationRefusal::OtherMachine {
            parameter: ImageParameter::WorkingMode,
            image: 1.0,
            machine: 5.0,
            tolerance: 0.0
        }
    );
    // The second design's five-bar: centimetres off, no single parameter explains it.
    let (_, link) = refusal(&second().0.nominal);
    let CalibrationRefusal::OtherMachine {
        parameter: ImageParameter::ToolPositionMm,
        image,
        tolerance,
        ..
    } = link
    else {
        panic!("{link:?}")
    };
    assert!(image > 10.0 && tolerance == 3.0, "{link:?}");
}

/// At boot the image in force defines the machine by its own record; an upload is judged
/// against the machine in force and never changes it.
#[test]
fn the_image_in_force_defines_the_machine_and_uploads_never_change_it() {
    let (second, g) = second();
    let paper = MachineRecord::paper();
    let flashed = commissioning(&second, &g);
    // Booted with it, whatever the built-in machine: the controller is `second`.
    let loaded = load(&flashed, &check(), false);
    assert_eq!(
        (loaded.state, loaded.machine),
        (CalibrationState::Valid, second)
    );
    assert_eq!(loaded.calibration.model, second.nominal);
    // Uploaded to a paper controller: refused, naming both machines and digests.
    let e = judged(&flashed, &check(), Judged::AtCommit).expect_err("accepted");
    assert_eq!(
        image_refusal(&e),
        CalibrationRefusal::OtherRecord {
            image: MachineId::new("second", second.digest()),
            controller: MachineId::new("paper", paper.digest()),
        }
    );
    // On the second machine's controller: its calibration (a tracker's frame, a smooth
    // field) is accepted; the paper's images are refused, with their record or without.
    let on_second = Settings::default().for_machine(&second).image_check();
    let fitted = in_tracker_frame(&second.nominal, [1.5, -2.0], 0.004);
    let calibration = build(
        &g,
        &fitted,
        smooth,
        Blocks {
            workspace: Some(second.workspace),
            record: Some(second),
            ..Blocks::default()
        },
    );
    assert_eq!(
        judged(&calibration, &on_second, Judged::AtCommit),
        Ok(second)
    );
    let paper_image = build(
        &paper_grid(),
        &paper.nominal,
        |_, _| [0.0; 2],
        Blocks::default(),
    );
    assert!(matches!(
        judged(&paper_image, &on_second, Judged::AtCommit),
        Err(ImageError::Refused(ImageRefusal::OtherMachine(_)))
    ));
    let sealed = build(
        &paper_grid(),
        &paper.nominal,
        |_, _| [0.0; 2],
        Blocks {
            record: Some(paper),
            ..Blocks::default()
        },
    );
    assert!(matches!(
        judged(&sealed, &on_second, Judged::AtCommit),
        Err(ImageError::Refused(ImageRefusal::OtherMachine(
            MachineMismatch::OtherRecord { .. }
        )))
    ));
}

/// An image whose record has this machine's geometry but looser limits is judged by the limits
/// in force at a commit (an upload never loosens them); at boot it is the machine's own.
#[test]
fn an_upload_cannot_loosen_the_limits_in_force() {
    let paper = MachineRecord::paper();
    let mut loose = paper;
    loose.name = MachineName::new("paper-loose").unwrap();
    loose.limits.max_node_correction_mm = 20.0;
    loose.limits.max_correction_slope = 0.5;
    assert_eq!(loose.digest(), paper.digest());
    // 0.03 rad at every node: about 5 mm at the tool, within the loose record's 20 mm.
    let img = build(
        &paper_grid(),
        &paper.nominal,
        |_, _| [0.03, 0.0],
        Blocks {
            record: Some(loose),
            ..Blocks::default()
        },
    );
    let e = judged(&img, &check(), Judged::AtCommit).expect_err("accepted");
    assert!(
        matches!(
            e,
            ImageError::Refused(ImageRefusal::Implausible(Implausible::NodeCorrection {
                limit_mm: 3.0,
                ..
            }))
        ),
        "{e:?}"
    );
    assert_eq!(judged(&img, &check(), Judged::AtBoot), Ok(loose));
}

#[test]
fn the_qemu_boards_images_are_plausible() {
    for sign in [1.0, -1.0] {
        let img = synthetic::synthetic_image(sign);
        for when in [Judged::AtBoot, Judged::AtCommit] {
            assert_eq!(judged(&img, &check(), when), Ok(MachineRecord::paper()));
        }
    }
}

/// The images of the reproduction a CRC let through: a ±0.05 rad checkerboard (committed, then
/// a switch at rest drove 7.6 N·m), +0.5 rad at every node (`StopRefused`), masses 1000× and
/// 1e30. Refused at commit and at boot, with the parameter and its values on the link.
#[test]
fn the_absurd_images_a_crc_let_through_are_refused() {
    let paper = MachineRecord::paper();
    let with = |field: &dyn Fn(u16, u16) -> [f32; 2], dynamics| {
        build(
            &paper_grid(),
            &paper.nominal,
            field,
            Blocks {
                dynamics,
                ..Blocks::default()
            },
        )
    };
    let checker = |i: u16, j: u16| {
        let s = if (i + j) % 2 == 0 { 0.05 } else { -0.05 };
        [s, -s]
    };
    // What the link says: the parameter beyond its limit, or (masses of 1e30: the mass
    // matrix's determinant overflows) the point where the mass matrix is not positive definite.
    let beyond = |parameter| {
        move |r: CalibrationRefusal| match r {
            CalibrationRefusal::Implausible {
                parameter: p,
                value,
                limit,
            } => p == parameter && value > limit,
            _ => false,
        }
    };
    let not_positive_definite = |r: CalibrationRefusal| {
        matches!(
            r,
            CalibrationRefusal::ImplausibleAt {
                parameter: ImageParameter::MassMatrix,
                ..
            }
        )
    };
    type Expected = Box<dyn Fn(CalibrationRefusal) -> bool>;
    let cases: [(Vec<u8>, Expected); 4] = [
        (
            with(&checker, None),
            Box::new(beyond(ImageParameter::NodeCorrectionMm)),
        ),
        (
            with(&|_, _| [0.5, 0.5], None),
            Box::new(beyond(ImageParameter::NodeCorrectionMm)),
        ),
        (
            with(
                &|_, _| [0.0; 2],
                Some(machine::IMAGE_DYNAMICS.scaled_masses([1000.0; 5])),
            ),
            Box::new(beyond(ImageParameter::InertiaRatio)),
        ),
        (
            with(
                &|_, _| [0.0; 2],
                Some(machine::IMAGE_DYNAMICS.scaled_masses([1e30; 5])),
            ),
            Box::new(not_positive_definite),
        ),
    ];
    for (img, expected) in cases {
        for when in [Judged::AtBoot, Judged::AtCommit] {
            let e = judged(&img, &check(), when).expect_err("accepted");
            assert!(expected(image_refusal(&e)), "{e:?}");
        }
        let loaded = load(&img, &check(), false);
        assert!(matches!(loaded.state, CalibrationState::Refused(_)));
        assert!(loaded.calibration.grid.is_none());
    }
}

/// The servo's own check: a zigzag along y (alternate nodes ±a: the slope changes by 4a per
/// cell, while the correction and its first difference stay microscopic), at and just beyond
/// the limit; refused with the node, the axis and both values.
#[test]
fn the_slope_change_limit_holds_at_and_refuses_just_beyond() {
    let limit = crate::plausibility::max_slope_change_rad_per_mm(&Settings::default().servo);
    assert!((limit - 0.1 / 3000.0).abs() < 1e-9, "{limit}");
    let g = paper_grid();
    let zigzag = |fraction: f32| {
        let a = fraction * limit * g.step_y_mm / 4.0;
        move |_: u16, j: u16| [0.0, if j % 2 == 0 { a } else { -a }]
    };
    let ok = build(
        &g,
        &FiveBar::paper_nominal(),
        zigzag(0.98),
        Blocks::default(),
    );
    assert!(judged(&ok, &check(), Judged::AtCommit).is_ok());
    let bad = build(
        &g,
        &FiveBar::paper_nominal(),
        zigzag(1.02),
        Blocks::default(),
    );
    let e = judged(&bad, &check(), Judged::AtCommit).expect_err("accepted");
    let ImageError::SlopeChange(s) = e else {
        panic!("{e:?}")
    };
    assert_eq!((s.node, s.axis, s.limit_rad_per_mm), ([0, 1], 1, limit));
    assert!((s.value_rad_per_mm / limit - 1.02).abs() < 1e-3, "{s:?}");
    // The QEMU board's synthetic image: far inside.
    let grid_img = synthetic::synthetic_image(1.0);
    let largest =
        crate::plausibility::slope_change(&CorrectionGrid::parse(&grid_img).unwrap(), limit)
            .unwrap();
    assert!(largest < 0.05 * limit, "{largest}");
    // Identity only (the harness's reading): the content is not judged.
    let identity = ImageCheck {
        max_slope_change_rad_per_mm: None,
        ..check()
    };
    assert_eq!(
        judged(&bad, &identity, Judged::AtCommit),
        Ok(MachineRecord::paper())
    );
}
