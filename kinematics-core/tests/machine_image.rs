//! The judgements of a calibration image against its machine (`kinematics_core::machine`):
//! every limit at and just beyond its value, the images a calibration of the paper machine
//! produces accepted whatever the instrument's frame, another design and absurd content
//! refused with what differs and both values.

use kinematics_core::grid::{
    append_backlash, append_dynamics, append_machine, append_workspace, encode, CorrectionGrid,
    GridGeometry, WorkspaceLimits, BACKLASH_LEN, DYNAMICS_LEN, MACHINE_LEN, WORKSPACE_LEN,
};
use kinematics_core::machine::{
    judge_image, same_machine, ImageRefusal, Implausible, MachineMismatch, MachineName,
    MachineRecord, ModelParameter,
};
use kinematics_core::{paper, Backlash, Branch, ConvexWorkspace, FiveBar, FiveBarDynamics};

/// What an image carries besides its grid.
#[derive(Default)]
struct Blocks {
    workspace: Option<WorkspaceLimits>,
    dynamics: Option<FiveBarDynamics<f32>>,
    backlash: Option<[f32; 2]>,
    machine: Option<MachineRecord>,
}

/// The paper machine's lattice with `model` and the node corrections `field(i, j)`.
fn image(model: &FiveBar<f32>, field: impl Fn(u16, u16) -> [f32; 2], blocks: &Blocks) -> Vec<u8> {
    let g = paper::grid_geometry();
    image_on(&g, model, field, blocks)
}

fn image_on(
    g: &GridGeometry,
    model: &FiveBar<f32>,
    field: impl Fn(u16, u16) -> [f32; 2],
    blocks: &Blocks,
) -> Vec<u8> {
    let nodes: Vec<[f32; 2]> = (0..g.ny)
        .flat_map(|j| (0..g.nx).map(move |i| (i, j)))
        .map(|(i, j)| field(i, j))
        .collect();
    let room = WORKSPACE_LEN + DYNAMICS_LEN + BACKLASH_LEN + MACHINE_LEN;
    let mut buf = vec![0u8; g.image_len() + room];
    let n = encode(&mut buf, g, model, &nodes).unwrap();
    let mut end = n;
    if let Some(w) = &blocks.workspace {
        end = append_workspace(&mut buf, n, end, w).unwrap();
    }
    if let Some(d) = &blocks.dynamics {
        end = append_dynamics(&mut buf, n, end, d).unwrap();
    }
    if let Some(b) = blocks.backlash {
        end = append_backlash(&mut buf, n, end, &Backlash::new(b).unwrap()).unwrap();
    }
    if let Some(r) = &blocks.machine {
        end = append_machine(&mut buf, n, end, r).unwrap();
    }
    buf.truncate(end);
    buf
}

fn judge(img: &[u8], machine: &MachineRecord) -> Result<(), ImageRefusal> {
    judge_image(&CorrectionGrid::parse(img).unwrap(), machine).map(|_| ())
}

fn implausible(r: Result<(), ImageRefusal>) -> Implausible {
    match r {
        Err(ImageRefusal::Implausible(e)) => e,
        other => panic!("expected an implausible image, got {other:?}"),
    }
}

fn paper() -> MachineRecord {
    MachineRecord::paper()
}

fn zero(_: u16, _: u16) -> [f32; 2] {
    [0.0; 2]
}

/// The largest `|J·v(i, j)|` over the nodes of the paper lattice, `J` the nominal's Jacobian at
/// the node: the definition of the node limits, computed here from the public API.
fn worst_tool_mm(v: impl Fn(u16, u16) -> [f32; 2]) -> f32 {
    let g = paper::grid_geometry();
    let m = FiveBar::<f32>::paper_nominal();
    let mut worst = 0.0f32;
    for j in 0..g.ny {
        for i in 0..g.nx {
            let jac = m
                .inverse_pose(g.node_mm(i, j), 0.0)
                .unwrap()
                .jacobian()
                .unwrap();
            let d = v(i, j);
            let t = [
                jac[0][0] * d[0] + jac[0][1] * d[1],
                jac[1][0] * d[0] + jac[1][1] * d[1],
            ];
            worst = worst.max((t[0] * t[0] + t[1] * t[1]).sqrt());
        }
    }
    worst
}

#[test]
fn the_nominal_and_a_fitted_model_in_a_tracker_frame_are_this_machine() {
    let m = paper();
    assert!(judge(&image(&m.nominal, zero, &Blocks::default()), &m).is_ok());
    // A fitted model of the paper plant: its links off by up to 2.3 mm, the instrument's frame
    // offset (3.27 mm) in its base. The per-parameter identity (2 mm per parameter) refused it.
    let fitted = FiveBar {
        a_mm: 148.397,
        b_mm: 152.254,
        c_mm: 147.735,
        d_mm: 151.555,
        base_a0_mm: [-0.031, 3.270],
        base_b0_mm: [0.015, -0.135],
        encoder_offset_rad: [-0.000578, 0.000420],
        ..m.nominal
    };
    let v = judge_image(
        &CorrectionGrid::parse(&image(&fitted, zero, &Blocks::default())).unwrap(),
        &m,
    )
    .unwrap();
    println!(
        "the paper plant's fitted model: {:.2} mm from the nominal in the best rigid frame",
        v.same.worst_mm
    );
    assert!(
        v.same.worst_mm > 0.5 && v.same.worst_mm < 1.5,
        "{:?}",
        v.same
    );
    assert!(!v.carried);
    // The same machine measured from a tracker 2 m away and turned by 30°: accepted.
    let turn = 30f32.to_radians();
    let moved = FiveBar {
        base_a0_mm: [2000.0, -500.0],
        encoder_offset_rad: [turn; 2],
        base_b0_mm: [0.0; 2],
        ..m.nominal
    };
    assert!(same_machine(&m, &moved).unwrap().worst_mm < 0.01);
}

#[test]
fn the_same_machine_tolerance_at_and_just_beyond_names_the_parameter() {
    let mut m = paper();
    let other = FiveBar {
        b_mm: 152.0,
        ..m.nominal
    };
    let d = same_machine(&m, &other).unwrap().worst_mm;
    assert!(d > 0.5 && d < 1.0, "{d}");
    m.limits.same_machine_tolerance_mm = d;
    assert!(judge(&image(&other, zero, &Blocks::default()), &m).is_ok());
    m.limits.same_machine_tolerance_mm = d * (1.0 - 1e-4);
    let e = judge(&image(&other, zero, &Blocks::default()), &m).unwrap_err();
    let ImageRefusal::OtherMachine(MachineMismatch::Geometry {
        worst_mm,
        parameter: Some(p),
        ..
    }) = e
    else {
        panic!("{e:?}");
    };
    assert_eq!(worst_mm, d);
    assert_eq!(
        (p.parameter, p.image, p.controller),
        (ModelParameter::B, 152.0, 150.0)
    );
    assert!(e
        .to_string()
        .contains("b_mm explains it: image 152.0000, controller 150.0000"));
}

#[test]
fn another_design_and_another_working_mode_are_refused_with_both_values() {
    let m = paper();
    // The second machine's five-bar: centimetres off wherever it is put.
    let second = FiveBar {
        a_mm: 120.0,
        b_mm: 170.0,
        c_mm: 160.0,
        d_mm: 130.0,
        base_a0_mm: [10.0, 20.0],
        base_b0_mm: [15.0, -65.0],
        encoder_offset_rad: [5f32.to_radians(), -8f32.to_radians()],
        ..m.nominal
    };
    match same_machine(&m, &second) {
        Err(MachineMismatch::Geometry {
            worst_mm,
            parameter: None,
            ..
        }) => {
            println!("the second machine's five-bar judged as the paper machine: {worst_mm:.1} mm");
            assert!(worst_mm > 10.0, "{worst_mm}")
        }
        Err(MachineMismatch::Unreachable {
            parameter: None, ..
        }) => {}
        other => panic!("{other:?}"),
    }
    let mut mirrored = m.nominal;
    mirrored.mode.elbow_2 = Branch::Positive;
    let e = same_machine(&m, &mirrored).unwrap_err();
    assert!(matches!(e, MachineMismatch::WorkingMode { .. }));
    assert!(
        e.to_string()
            .contains("(+, +, +), this machine's (+, -, +)"),
        "{e}"
    );
}

#[test]
fn an_image_with_another_machines_record_is_refused_naming_both() {
    let m = paper();
    let mut other = m;
    other.name = MachineName::new("wider").unwrap();
    other.workspace.region = ConvexWorkspace::rectangle([162.132, 262.132], [-75.0, 74.0]).unwrap();
    let img = image(
        &m.nominal,
        zero,
        &Blocks {
            machine: Some(other),
            ..Blocks::default()
        },
    );
    let e = judge(&img, &m).unwrap_err();
    assert!(
        matches!(
            e,
            ImageRefusal::OtherMachine(MachineMismatch::OtherRecord { .. })
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("'wider' (digest {:08x})", other.digest()))
            && msg.contains(&format!("'paper' (digest {:08x})", m.digest())),
        "{msg}"
    );
    // The same geometry under another name, with tighter limits: its own record judges it.
    let mut renamed = m;
    renamed.name = MachineName::new("paper-cell-3").unwrap();
    renamed.limits.max_node_correction_mm = 0.001;
    let img = image(
        &m.nominal,
        |_, _| [1e-4, 1e-4],
        &Blocks {
            machine: Some(renamed),
            ..Blocks::default()
        },
    );
    assert!(matches!(
        implausible(judge(&img, &m)),
        Implausible::NodeCorrection { .. }
    ));
    renamed.limits.max_node_correction_mm = 1.0;
    let img = image(
        &m.nominal,
        |_, _| [1e-4, 1e-4],
        &Blocks {
            machine: Some(renamed),
            ..Blocks::default()
        },
    );
    let grid = CorrectionGrid::parse(&img).unwrap();
    let v = judge_image(&grid, &m).unwrap();
    assert!(v.carried && v.record == renamed);
}

#[test]
fn node_correction_at_and_just_beyond_the_limit() {
    let mut m = paper();
    let field = |_: u16, _: u16| [4e-3f32, -2e-3];
    let worst = worst_tool_mm(field);
    assert!(worst > 0.3 && worst < 3.0, "{worst}");
    m.limits.max_node_correction_mm = worst;
    assert!(judge(&image(&m.nominal, field, &Blocks::default()), &m).is_ok());
    m.limits.max_node_correction_mm = worst * (1.0 - 1e-5);
    let e = implausible(judge(&image(&m.nominal, field, &Blocks::default()), &m));
    let Implausible::NodeCorrection { correction_mm, .. } = e else {
        panic!("{e:?}");
    };
    assert_eq!(correction_mm, worst);
}

#[test]
fn correction_slope_at_and_just_beyond_the_limit() {
    let mut m = paper();
    m.limits.max_node_correction_mm = 20.0;
    // A ramp along x: the change between x-neighbours is [s, 0] everywhere, none along y.
    let s = 2e-4f32;
    let field = move |i: u16, _: u16| [s * i as f32, 0.0];
    let worst = worst_tool_mm(|_, _| [s, 0.0]) / 5.0;
    m.limits.max_correction_slope = worst * (1.0 + 1e-5);
    assert!(judge(&image(&m.nominal, field, &Blocks::default()), &m).is_ok());
    m.limits.max_correction_slope = worst * (1.0 - 1e-4);
    let e = implausible(judge(&image(&m.nominal, field, &Blocks::default()), &m));
    let Implausible::CorrectionSlope {
        node, neighbour, ..
    } = e
    else {
        panic!("{e:?}");
    };
    assert_eq!(neighbour, [node[0] + 1, node[1]]);
}

#[test]
fn the_absurd_images_an_adversary_uploaded_are_refused() {
    let m = paper();
    // A ±0.05 rad checkerboard: each node's correction is itself beyond what a calibration
    // needs, and neighbours differ by 0.1 rad.
    let checker = |i: u16, j: u16| [if (i + j) % 2 == 0 { 0.05 } else { -0.05 }; 2];
    let e = implausible(judge(&image(&m.nominal, checker, &Blocks::default()), &m));
    assert!(matches!(e, Implausible::NodeCorrection { .. }), "{e:?}");
    // The same checkerboard small enough in magnitude: the slope refuses it.
    let fine = |i: u16, j: u16| [if (i + j) % 2 == 0 { 2e-3 } else { -2e-3 }; 2];
    let e = implausible(judge(&image(&m.nominal, fine, &Blocks::default()), &m));
    assert!(matches!(e, Implausible::CorrectionSlope { .. }), "{e:?}");
    // +0.5 rad everywhere.
    let e = implausible(judge(
        &image(&m.nominal, |_, _| [0.5; 2], &Blocks::default()),
        &m,
    ));
    let Implausible::NodeCorrection { correction_mm, .. } = e else {
        panic!("{e:?}");
    };
    assert!(correction_mm > 50.0, "{correction_mm}");
    // Dynamics 1000 times the machine's, and 1e30.
    for k in [1000.0f32, 1e30] {
        let d = paper::nominal_dynamics::<f32>().scaled_masses([k; 5]);
        let img = image(
            &m.nominal,
            zero,
            &Blocks {
                dynamics: Some(d),
                ..Blocks::default()
            },
        );
        let e = implausible(judge(&img, &m));
        assert!(
            matches!(
                e,
                Implausible::Inertia { .. } | Implausible::MassMatrix { .. }
            ),
            "{k}: {e:?}"
        );
    }
}

fn with_dynamics(m: &MachineRecord, d: FiveBarDynamics<f32>) -> Result<(), ImageRefusal> {
    let img = image(
        &m.nominal,
        zero,
        &Blocks {
            dynamics: Some(d),
            ..Blocks::default()
        },
    );
    judge(&img, m)
}

#[test]
fn dynamics_within_the_factor_and_just_beyond() {
    let m = paper();
    let f = m.limits.dynamics_factor;
    let nominal = m.limits.nominal_dynamics;
    // Every mass and inertia scaled by k: the kinetic energy of every motion scales by k.
    for (k, ok) in [
        (f * (1.0 - 1e-3), true),
        (f * (1.0 + 1e-3), false),
        (1.0 / f * (1.0 + 1e-3), true),
        (1.0 / f * (1.0 - 1e-3), false),
    ] {
        let r = with_dynamics(&m, nominal.scaled_masses([k; 5]));
        assert_eq!(r.is_ok(), ok, "{k}: {r:?}");
        if let Err(e) = r {
            let Implausible::Inertia { ratio, .. } = implausible(Err(e)) else {
                panic!();
            };
            assert!((ratio / k - 1.0).abs() < 1e-4, "{ratio} vs {k}");
        }
    }
    // Masses 20 % off with alternating signs (the QEMU image's), a 0.3 kg cutting head.
    assert!(with_dynamics(&m, nominal.scaled_masses([1.2, 0.8, 1.2, 0.8, 1.2])).is_ok());
    let head = FiveBarDynamics {
        tool_mass_kg: nominal.tool_mass_kg + 0.26,
        ..nominal
    };
    let img = image(
        &m.nominal,
        zero,
        &Blocks {
            dynamics: Some(head),
            ..Blocks::default()
        },
    );
    let v = judge_image(&CorrectionGrid::parse(&img).unwrap(), &m).unwrap();
    let [lo, hi] = v.margins.inertia_ratio.unwrap();
    println!("a 0.3 kg cutting head: kinetic-energy ratio {lo:.2} to {hi:.2} of the nominal");
    assert!(lo >= 1.0 && hi > 1.5 && hi < f, "{lo} {hi}");
    // Distal inertias so negative the mass matrix loses its definiteness.
    let e = implausible(with_dynamics(
        &m,
        FiveBarDynamics {
            distal_inertia_kg_m2: [-0.05; 2],
            ..nominal
        },
    ));
    assert!(matches!(e, Implausible::MassMatrix { .. }), "{e:?}");
    // Friction: at most the factor times the nominal's; the Coulomb speed within the factor.
    let viscous = |v: f32| FiveBarDynamics {
        viscous_nm_s_per_rad: [0.02, v],
        ..nominal
    };
    assert!(with_dynamics(&m, viscous(0.02 * f)).is_ok());
    let e = implausible(with_dynamics(&m, viscous(0.02 * f * 1.001)));
    assert!(
        matches!(
            e,
            Implausible::Friction {
                parameter: "viscous_2_nm_s_per_rad",
                ..
            }
        ),
        "{e:?}"
    );
    let coulomb = |c: f32| FiveBarDynamics {
        coulomb_nm: [c, 0.05],
        ..nominal
    };
    assert!(with_dynamics(&m, coulomb(0.05 * f)).is_ok());
    assert!(with_dynamics(&m, coulomb(0.05 * f * 1.001)).is_err());
    assert!(
        with_dynamics(&m, coulomb(0.0)).is_ok(),
        "no friction is plausible"
    );
    let speed = |w: f32| FiveBarDynamics {
        coulomb_speed_rad_s: w,
        ..nominal
    };
    assert!(with_dynamics(&m, speed(0.01 * f)).is_ok());
    assert!(with_dynamics(&m, speed(0.01 / f)).is_ok());
    assert!(with_dynamics(&m, speed(0.01 * f * 1.001)).is_err());
    assert!(with_dynamics(&m, speed(0.01 / f / 1.001)).is_err());
}

#[test]
fn backlash_at_and_just_beyond_the_limit() {
    let m = paper();
    let limit = m.limits.max_backlash_rad;
    let with = |b: [f32; 2]| {
        judge(
            &image(
                &m.nominal,
                zero,
                &Blocks {
                    backlash: Some(b),
                    ..Blocks::default()
                },
            ),
            &m,
        )
    };
    assert!(with([20e-6, limit]).is_ok());
    let e = implausible(with([20e-6, limit * 1.001]));
    assert_eq!(
        e,
        Implausible::Backlash {
            axis: 1,
            image_rad: limit * 1.001,
            limit_rad: limit
        }
    );
}

#[test]
fn the_image_workspace_inside_the_machines_and_home_in_the_grid() {
    let mut m = paper();
    m.workspace.region = ConvexWorkspace::rectangle([170.0, 250.0], [-70.0, 70.0]).unwrap();
    let with = |x1: f32| {
        let region = ConvexWorkspace::rectangle([170.0, x1], [-70.0, 70.0]).unwrap();
        image(
            &m.nominal,
            zero,
            &Blocks {
                workspace: Some(WorkspaceLimits {
                    region,
                    stop_margin_mm: 0.1,
                }),
                ..Blocks::default()
            },
        )
    };
    assert!(judge(&with(250.0), &m).is_ok());
    assert!(
        judge(&with(250.0009), &m).is_ok(),
        "f32 rounding of a vertex"
    );
    let e = implausible(judge(&with(250.01), &m));
    let Implausible::Workspace { vertex_mm, .. } = e else {
        panic!("{e:?}");
    };
    assert_eq!(vertex_mm, [250.01, -70.0]);
    // A partial grid that does not hold the home position.
    let part = GridGeometry {
        nx: 6,
        ny: 7,
        x0_mm: 180.0,
        y0_mm: -15.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    };
    let img = image_on(&part, &m.nominal, zero, &Blocks::default());
    assert_eq!(
        implausible(judge(&img, &m)),
        Implausible::HomeOutsideGrid {
            home_mm: [212.132, 0.0]
        }
    );
}

#[test]
fn every_refusal_reads_with_its_numbers() {
    let m = paper();
    let msgs = [
        implausible(judge(
            &image(&m.nominal, |_, _| [0.5; 2], &Blocks::default()),
            &m,
        ))
        .to_string(),
        MachineMismatch::Unreachable {
            at_mm: [1.0, 2.0],
            parameter: None,
        }
        .to_string(),
    ];
    assert!(msgs[0].contains("moves the tool by") && msgs[0].contains("the limit is 3 mm"));
    assert!(msgs[1].contains("(1.0, 2.0) mm"));
}
