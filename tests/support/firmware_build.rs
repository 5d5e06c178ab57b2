// Shared by the tests that run a firmware binary under QEMU (`tests/tests/same_core_on_mcu.rs`,
// `host-sim/tests/link_qemu.rs`, `cosim.rs`, `commission.rs`, `moving_machine.rs`, the cosim bench), included with
// `include!`: where the workspace is, and building it, one way.

/// The workspace's root: the including crate (`tests/`, `host-sim/`) sits one level below it.
fn workspace_root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the crate is in the workspace")
        .to_path_buf()
}

/// Builds the firmware binary `bin` for the Cortex-M4F (release) into `target/system-tests`
/// under `root` (its own target directory, so that the test does not wait on the lock of the
/// `cargo test` that runs it) and returns the ELF's path.
fn build_firmware_bin(root: &std::path::Path, bin: &str) -> std::path::PathBuf {
    let target_dir = root.join("target").join("system-tests");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = std::process::Command::new(cargo)
        .current_dir(root)
        .env("CARGO_TARGET_DIR", &target_dir)
        .args(["build", "--release", "-p", "firmware", "--bin", bin, "--target", "thumbv7em-none-eabihf"])
        .status()
        .expect("cargo runs");
    assert!(
        status.success(),
        "building the firmware's {bin} failed (is the thumbv7em-none-eabihf target installed? bash tests/run-all.sh installs it)"
    );
    target_dir.join("thumbv7em-none-eabihf").join("release").join(bin)
}
