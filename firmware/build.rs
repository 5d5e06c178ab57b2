//! Selects the board's linker files and builds the bundled calibration image.
//!
//! * The selected board's MEMORY block (`firmware/memory-{qemu,g474}.x`) is copied into OUT_DIR
//!   as `board-memory.x`, which the workspace's `memory.x` includes, and `firmware/device.x`
//!   (the interrupt handler names, the same on both boards) as `device.x`; OUT_DIR goes on the
//!   linker search path.
//!   The linker runs in the workspace root and finds `memory.x` there first, so the top-level
//!   file holds what every board shares and each board contributes only its MEMORY block.
//! * `calibration.bin`: a valid correction grid image for the paper's nominal machine, encoded
//!   with `kinematics_core::grid::encode` (the same encoder the host calibration tools use).
//!   Its node values are a smooth synthetic field of a few hundred µrad (up to 3.9e-4 rad),
//!   the size of the paper's corrections; `qemu-test`'s `track` needs at least 2e-4 rad on its
//!   tour to tell an applied grid from a missing one. A real image comes from the
//!   calibration, not from here. The image carries two extension blocks
//!   (`kinematics_core::grid`, "Extension blocks"): the paper machine's workspace (`HRWS`: the
//!   grid's rectangle and the 0.1 mm stop margin of `host-sim/machines/paper.toml`, as
//!   `host-sim grid` writes it), so the firmware's workspace check runs on the image's polygon,
//!   and the dynamics (`HRDY`) with the QEMU machine's dynamic parameters 20 % off its
//!   plant's (`src/board/qemu/machine.rs`, shared with the plant), which the servo feeds
//!   forward. The QEMU
//!   firmware links it into the calibration region (feature `board-qemu`); the real board
//!   gets its image flashed separately (see README).
//! * `calibration-2.bin`: the same with the field negated, bundled into the QEMU firmware's
//!   program (not the region) for the run-time upload scenarios.
use std::{env, fs, path::PathBuf};

use kinematics_core::grid::{append_dynamics, append_workspace, encode, GridGeometry, WorkspaceLimits, DYNAMICS_LEN, WORKSPACE_LEN};
use kinematics_core::{paper, ConvexWorkspace, FiveBar};

// `TRUE_DYNAMICS` (the plant's) and `IMAGE_DYNAMICS`.
#[allow(dead_code)]
mod machine {
    include!("src/board/qemu/machine.rs");
}

fn main() {
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let qemu = env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some();
    let g474 = env::var_os("CARGO_FEATURE_BOARD_G474").is_some();
    let memory = match (qemu, g474) {
        (true, false) => manifest.join("memory-qemu.x"),
        (false, true) => manifest.join("memory-g474.x"),
        _ => panic!("enable exactly one of the features `board-qemu` and `board-g474`"),
    };
    let device = manifest.join("device.x");
    fs::copy(&memory, out.join("board-memory.x")).expect("copy board-memory.x");
    fs::copy(&device, out.join("device.x")).expect("copy device.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
    println!("cargo:rerun-if-changed={}", device.display());
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=../memory.x");
    println!("cargo:rerun-if-changed=src/board/qemu/machine.rs");

    fs::write(out.join("calibration.bin"), synthetic_image(1.0)).expect("write calibration.bin");
    // The second image the QEMU upload scenarios upload at run time: the field negated.
    fs::write(out.join("calibration-2.bin"), synthetic_image(-1.0)).expect("write calibration-2.bin");
}

/// Grid over the paper's workspace (x 162.132..262.132 mm, y -75..75 mm) in 5 mm cells, the
/// synthetic field times `sign`.
fn synthetic_image(sign: f32) -> Vec<u8> {
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
    let end = append_dynamics(&mut image, n, end, &machine::IMAGE_DYNAMICS).expect("the QEMU machine's dynamics are valid");
    image.truncate(end);
    image
}
