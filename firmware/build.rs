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
//!   gets its image flashed separately (see docs/design/firmware-architecture.md).
//! * `calibration-2.bin`: the same with the field negated, bundled into the QEMU firmware's
//!   program (not the region) for the run-time upload scenarios. Both come from
//!   `src/board/qemu/synthetic_image.rs`, which host-sim's in-the-loop test (`link_qemu`)
//!   includes too: it checks the bundled image's id and uploads the second over the link.
use std::{env, fs, path::PathBuf};

// `TRUE_DYNAMICS` (the plant's) and `IMAGE_DYNAMICS`.
#[allow(dead_code)]
mod machine {
    include!("src/board/qemu/machine.rs");
}

// `synthetic_image`, also included by host-sim's in-the-loop test (it uploads the second one).
mod synthetic {
    include!("src/board/qemu/synthetic_image.rs");
}
use synthetic::synthetic_image;

fn main() {
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    let manifest =
        PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
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
    println!("cargo:rerun-if-changed=src/board/qemu/synthetic_image.rs");

    fs::write(out.join("calibration.bin"), synthetic_image(1.0)).expect("write calibration.bin");
    // The second image the QEMU upload scenarios upload at run time: the field negated.
    fs::write(out.join("calibration-2.bin"), synthetic_image(-1.0))
        .expect("write calibration-2.bin");
}
