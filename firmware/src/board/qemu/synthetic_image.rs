// The QEMU board's synthetic calibration images (the bundled `calibration.bin`, and with the
// field negated `calibration-2.bin`, the image the upload scenarios and the host link's
// in-the-loop test upload). Not a module of the firmware: `include!`d by `build.rs` and by
// `host-sim/tests/link_qemu.rs`, each next to a `machine` module including `machine.rs`, so
// the test uploads exactly the image the firmware's own upload scenario does.
use kinematics_core::grid::{append_dynamics, append_workspace, encode, GridGeometry, WorkspaceLimits, DYNAMICS_LEN, WORKSPACE_LEN};
use kinematics_core::{paper, ConvexWorkspace, FiveBar};

/// Grid over the paper's workspace (x 162.132..262.132 mm, y -75..75 mm) in 5 mm cells, the
/// synthetic field times `sign`.
pub fn synthetic_image(sign: f32) -> Vec<u8> {
    let geometry = GridGeometry { nx: 21, ny: 31, x0_mm: 162.132, y0_mm: -75.0, step_x_mm: 5.0, step_y_mm: 5.0 };
    let model = FiveBar::<f32>::paper_nominal();
    let mut nodes = Vec::with_capacity(geometry.len());
    for j in 0..geometry.ny {
        for i in 0..geometry.nx {
            let [x, y] = geometry.node_mm(i, j);
            let (u, v) = ((x - 212.132) / 50.0, y / 75.0);
            nodes.push([
                sign * (3.0e-4 * (1.3 * u).sin() + 1.0e-4 * (2.0 * v).cos()),
                sign * (-2.0e-4 * (1.1 * v).sin() + 1.5e-4 * u * v),
            ]);
        }
    }
    let mut image = vec![0u8; geometry.image_len() + WORKSPACE_LEN + DYNAMICS_LEN];
    let n = encode(&mut image, &geometry, &model, &nodes).expect("synthetic grid encodes");
    let (x, y) = (paper::WORKSPACE_X_MM.map(|v| v as f32), paper::WORKSPACE_Y_MM.map(|v| v as f32));
    let region = ConvexWorkspace::rectangle(x, y).expect("the paper workspace is a rectangle");
    let limits = WorkspaceLimits { region, stop_margin_mm: paper::STOP_MARGIN_MM as f32 };
    let end = append_workspace(&mut image, n, n, &limits).expect("the paper workspace lies on its grid");
    let end = append_dynamics(&mut image, n, end, &super::machine::IMAGE_DYNAMICS).expect("the QEMU machine's dynamics are valid");
    image.truncate(end);
    image
}
