//! Each limit of the module's table, at and just beyond it; the images a CRC let through that
//! moved the machine (a ±0.05 rad checkerboard, +0.5 rad everywhere, masses 1000× and 1e30);
//! the QEMU board's images accepted.
use super::*;
use kinematics_core::grid::{
    append_backlash, append_dynamics, append_workspace, encode, GridGeometry, WorkspaceLimits,
    BACKLASH_LEN, DYNAMICS_LEN, WORKSPACE_LEN,
};
use kinematics_core::{Backlash, ConvexWorkspace};

#[allow(dead_code)]
mod machine {
    include!("../../../src/board/qemu/machine.rs");
}
mod synthetic {
    include!("../../../src/board/qemu/synthetic_image.rs");
}

fn limits() -> ImageLimits {
    ImageLimits::of(
        &FiveBar::paper_nominal(),
        2.0,
        &ServoConfig::default(),
        100.0,
    )
}

const GEOMETRY: GridGeometry = GridGeometry {
    nx: 21,
    ny: 31,
    x0_mm: 162.132,
    y0_mm: -75.0,
    step_x_mm: 5.0,
    step_y_mm: 5.0,
};

/// An image of the paper's nominal model over [`GEOMETRY`] with `field(i, j)` at each node,
/// and optional dynamics and backlash blocks.
fn image(
    field: impl Fn(u16, u16) -> [f32; 2],
    dynamics: Option<FiveBarDynamics<f32>>,
    backlash_rad: Option<[f32; 2]>,
) -> Vec<u8> {
    let g = GEOMETRY;
    let mut nodes = Vec::new();
    for j in 0..g.ny {
        for i in 0..g.nx {
            nodes.push(field(i, j));
        }
    }
    let mut img = vec![0u8; g.image_len() + DYNAMICS_LEN + BACKLASH_LEN];
    let n = encode(&mut img, &g, &FiveBar::paper_nominal(), &nodes).unwrap();
    let mut end = n;
    if let Some(d) = dynamics {
        end = append_dynamics(&mut img, n, end, &d).unwrap();
    }
    if let Some(b) = backlash_rad {
        end = append_backlash(&mut img, n, end, &Backlash::new(b).unwrap()).unwrap();
    }
    img.truncate(end);
    img
}

fn judge(img: &[u8]) -> Result<(), Implausible> {
    limits().check(&CorrectionGrid::parse(img).unwrap())
}

/// Refused for `parameter`, naming a value beyond the limit (below it for the low inertia).
fn refused(img: &[u8], parameter: ImageParameter) -> Implausible {
    let e = judge(img).expect_err("accepted");
    assert_eq!(e.parameter, parameter, "{e}");
    if parameter == ImageParameter::InertiaLowKgM2 {
        assert!(e.value < e.limit, "{e}");
    } else if parameter != ImageParameter::WorkspaceVertexXMm {
        assert!(!(e.value <= e.limit), "{e}");
    }
    e
}

#[test]
fn the_limits_follow_from_the_machine_and_the_servo() {
    let l = limits();
    assert!((l.max_correction_rad - 4.0 / 150.0).abs() < 1e-6, "{l:?}");
    assert!((l.max_neighbour_rad_per_mm - 4.0 / 150.0 / 10.0).abs() < 1e-7);
    assert!((l.max_slope_change_rad_per_mm - 0.1 / 3000.0).abs() < 1e-9);
    assert!((l.inertia_kg_m2[0] - 7.4e-3 / 4.0).abs() < 1e-7);
    assert!((l.inertia_kg_m2[1] - 7.4e-3 * 4.0).abs() < 1e-6);
    assert!((l.max_coulomb_nm - 2.0).abs() < 1e-6);
    assert!((l.max_viscous_nm_s_per_rad - 0.04).abs() < 1e-6);
    // A machine with looser tolerances may need larger corrections.
    let loose = ImageLimits::of(
        &FiveBar::paper_nominal(),
        4.0,
        &ServoConfig::default(),
        100.0,
    );
    assert!((loose.max_correction_rad - 2.0 * l.max_correction_rad).abs() < 1e-6);
}

#[test]
fn the_qemu_boards_images_are_plausible() {
    for sign in [1.0, -1.0] {
        assert_eq!(judge(&synthetic::synthetic_image(sign)), Ok(()));
    }
}

/// The images of the reproduction: a ±0.05 rad checkerboard (committed, then a switch at rest
/// drove 7.6 N·m) and +0.5 rad at every node (`StopRefused`).
#[test]
fn the_absurd_corrections_a_crc_let_through_are_refused() {
    let checker = |amplitude: f32| {
        image(
            move |i, j| {
                let s = if (i + j) % 2 == 0 {
                    amplitude
                } else {
                    -amplitude
                };
                [s, -s]
            },
            None,
            None,
        )
    };
    refused(&checker(0.05), ImageParameter::NodeCorrectionRad);
    let e = refused(
        &image(|_, _| [0.5, 0.5], None, None),
        ImageParameter::NodeCorrectionRad,
    );
    assert_eq!((e.value, e.limit), (0.5, limits().max_correction_rad));
    // Within the magnitude, still a checkerboard: its neighbours refuse it.
    refused(
        &checker(0.9 * limits().max_correction_rad),
        ImageParameter::NeighbourDifferenceRadPerMm,
    );
}

#[test]
fn each_correction_limit_holds_at_the_limit_and_refuses_just_beyond() {
    let l = limits();
    // Magnitude: a constant field.
    let at = 0.999 * l.max_correction_rad;
    assert_eq!(judge(&image(|_, _| [at, -at], None, None)), Ok(()));
    refused(
        &image(|_, _| [0.0, 1.01 * l.max_correction_rad], None, None),
        ImageParameter::NodeCorrectionRad,
    );
    // Neighbour difference: a plane along x (no slope change anywhere), its slope at and just
    // beyond the limit, centred so that its range stays within the magnitude when it can.
    let plane = |slope: f32| move |i: u16, _: u16| [slope * (f32::from(i) - 10.0) * 5.0, 0.0];
    // The magnitude limit allows a slope of max_correction / 50 mm over this grid: below the
    // neighbour limit (max_correction / 10 mm). A finer grid would reach it: the same plane
    // over 10 nodes of 1 mm.
    assert_eq!(
        judge(&image(
            plane(0.99 * l.max_correction_rad / 50.0),
            None,
            None
        )),
        Ok(())
    );
    let fine = GridGeometry {
        nx: 11,
        ny: 3,
        x0_mm: 207.0,
        y0_mm: -5.0,
        step_x_mm: 1.0,
        step_y_mm: 5.0,
    };
    let fine_plane = |slope: f32| {
        let mut img = vec![0u8; fine.image_len()];
        let mut nodes = Vec::new();
        for _ in 0..fine.ny {
            for i in 0..fine.nx {
                nodes.push([slope * (f32::from(i) - 5.0), 0.0]);
            }
        }
        encode(&mut img, &fine, &FiveBar::paper_nominal(), &nodes).unwrap();
        img
    };
    let fine_check = |img: &[u8]| {
        let home = ImageLimits { ..l };
        home.check(&CorrectionGrid::parse(img).unwrap())
    };
    assert_eq!(
        fine_check(&fine_plane(0.99 * l.max_neighbour_rad_per_mm)),
        Ok(())
    );
    let e = fine_check(&fine_plane(1.01 * l.max_neighbour_rad_per_mm)).expect_err("accepted");
    assert_eq!(
        e.parameter,
        ImageParameter::NeighbourDifferenceRadPerMm,
        "{e}"
    );
    // Slope change: a parabola along y, its slope changing by the same amount at every node.
    let parabola = |change: f32| {
        move |_: u16, j: u16| {
            let y = (f32::from(j) - 15.0) * 5.0;
            // Second difference = change·step: the slope changes by `change` per cell.
            [0.5 * change * y * y / 5.0, 0.0]
        }
    };
    assert_eq!(
        judge(&image(
            parabola(0.95 * l.max_slope_change_rad_per_mm),
            None,
            None
        )),
        Ok(())
    );
    refused(
        &image(parabola(1.05 * l.max_slope_change_rad_per_mm), None, None),
        ImageParameter::SlopeChangeRadPerMm,
    );
}

/// The QEMU machine's image dynamics, and what a CRC-valid image could carry instead.
#[test]
fn dynamics_within_a_factor_of_the_machine_and_positive_definite() {
    let zero = |_, _| [0.0; 2];
    let good = machine::IMAGE_DYNAMICS;
    assert_eq!(judge(&image(zero, Some(good), None)), Ok(()));
    // Every mass and inertia 1000× (the reproduction: 4.9 kg·m², 165 kg), or 1e30.
    for factor in [1000.0, 1e30] {
        let heavy = good.scaled_masses([factor; 5]);
        refused(
            &image(zero, Some(heavy), None),
            ImageParameter::InertiaHighKgM2,
        );
    }
    // Just inside and just beyond the factor: every mass scaled so that the largest diagonal
    // term over the grid is at the limit.
    let grid_img = image(zero, Some(good), None);
    let grid = CorrectionGrid::parse(&grid_img).unwrap();
    let mut largest = 0.0f32;
    for j in 0..GEOMETRY.ny {
        for i in 0..GEOMETRY.nx {
            let Ok(pose) = grid.model().inverse_pose(GEOMETRY.node_mm(i, j), 0.05) else {
                continue;
            };
            let (m, _) = good.mass_matrix_and_bias(&pose, [0.0; 2]).unwrap();
            largest = largest.max(m[0][0]).max(m[1][1]);
        }
    }
    let high = limits().inertia_kg_m2[1];
    let scaled = |target: f32| good.scaled_masses([target / largest; 5]);
    assert_eq!(judge(&image(zero, Some(scaled(0.98 * high)), None)), Ok(()));
    refused(
        &image(zero, Some(scaled(1.03 * high)), None),
        ImageParameter::InertiaHighKgM2,
    );
    // Too light: a hundredth.
    refused(
        &image(zero, Some(good.scaled_masses([0.01; 5])), None),
        ImageParameter::InertiaLowKgM2,
    );
    // Not positive definite: distal inertias far negative against the rotors.
    let odd = FiveBarDynamics {
        distal_inertia_kg_m2: [-0.2, -0.2],
        ..good
    };
    let e = judge(&image(zero, Some(odd), None)).expect_err("accepted");
    assert!(
        matches!(
            e.parameter,
            ImageParameter::MassMatrixDeterminant | ImageParameter::InertiaLowKgM2
        ),
        "{e}"
    );
    // Friction at and beyond its limits.
    let l = limits();
    let viscous = |v: f32| FiveBarDynamics {
        viscous_nm_s_per_rad: [0.0, v],
        ..good
    };
    assert_eq!(
        judge(&image(
            zero,
            Some(viscous(0.99 * l.max_viscous_nm_s_per_rad)),
            None
        )),
        Ok(())
    );
    refused(
        &image(zero, Some(viscous(1.01 * l.max_viscous_nm_s_per_rad)), None),
        ImageParameter::ViscousNmSPerRad,
    );
    let coulomb = |c: f32| FiveBarDynamics {
        coulomb_nm: [c, 0.0],
        ..good
    };
    assert_eq!(
        judge(&image(zero, Some(coulomb(0.99 * l.max_coulomb_nm)), None)),
        Ok(())
    );
    refused(
        &image(zero, Some(coulomb(1.01 * l.max_coulomb_nm)), None),
        ImageParameter::CoulombNm,
    );
}

#[test]
fn backlash_and_workspace() {
    let zero = |_, _| [0.0; 2];
    let l = limits();
    assert_eq!(
        judge(&image(zero, None, Some([2e-5, 0.99 * l.max_backlash_rad]))),
        Ok(())
    );
    refused(
        &image(zero, None, Some([1.01 * l.max_backlash_rad, 0.0])),
        ImageParameter::BacklashRad,
    );
    // A workspace whose corner the model cannot reach: a grid out to x = 310 mm (the reach
    // is 300 mm), the polygon's right edge at 305 mm.
    let g = GridGeometry {
        nx: 4,
        ny: 3,
        x0_mm: 160.0,
        y0_mm: -80.0,
        step_x_mm: 50.0,
        step_y_mm: 80.0,
    };
    let build = |x1: f32| {
        let mut img = vec![0u8; g.image_len() + WORKSPACE_LEN];
        let n = encode(&mut img, &g, &FiveBar::paper_nominal(), &[[0.0; 2]; 12]).unwrap();
        let region =
            ConvexWorkspace::new(&[[170.0, -60.0], [x1, -60.0], [x1, 60.0], [170.0, 60.0]])
                .unwrap();
        let limits = WorkspaceLimits {
            region,
            stop_margin_mm: 0.1,
        };
        let end = append_workspace(&mut img, n, n, &limits).unwrap();
        img.truncate(end);
        img
    };
    assert_eq!(judge(&build(260.0)), Ok(()));
    let e = refused(&build(305.0), ImageParameter::WorkspaceVertexXMm);
    assert_eq!(e.value, 305.0);
}
