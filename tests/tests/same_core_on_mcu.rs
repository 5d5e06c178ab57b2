//! The same core on host and target: `tests/golden/cases.rs` (IK, FK, Jacobian, grid lookups, a
//! closed servo sequence, the same through a model checked once, hostile inputs) runs on the Cortex-M4F under QEMU (the firmware's
//! `golden` binary) and here on x86; every f32 result and every error must be bit-identical.
//!
//! Why it can fail: the MCU takes `sqrt` from the FPU's VSQRT, `atan2` and `sin_cos` from the
//! core's own f32 routines and the rest from libm, the host from the same sources but another
//! compiler backend; any
//! contraction into fused multiply-adds, any std routine sneaking in on the host (std's
//! `f32::sin_cos` shadows the core's), or a target-dependent branch would show here.
//!
//! Needs the thumbv7em-none-eabihf target and qemu-system-arm (`bash tests/run-all.sh`
//! installs both). The firmware is built into its own target directory so this test does not
//! wait on the lock of the `cargo test` that runs it.

mod cases {
    include!("../golden/cases.rs");
}

use std::path::PathBuf;
use std::process::Command;

/// Builds the golden firmware and returns its ELF.
fn build_golden() -> PathBuf {
    build_firmware_bin(&workspace_root(), "golden")
}

include!("../support/firmware_build.rs");

/// Runs the ELF under QEMU (bounded) and returns its `GOLDEN` words.
fn run_on_mcu(elf: &PathBuf) -> Vec<u32> {
    let out = Command::new("timeout")
        .args([
            "--kill-after=5",
            "120",
            "qemu-system-arm",
            "-machine",
            "mps2-an386",
            "-cpu",
            "cortex-m4",
        ])
        .args([
            "-nographic",
            "-monitor",
            "none",
            "-serial",
            "none",
            "-semihosting-config",
            "enable=on,target=native",
        ])
        .arg("-kernel")
        .arg(elf)
        .output()
        .expect("qemu-system-arm (or timeout) is missing: bash tests/run-all.sh installs it");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the golden firmware failed under QEMU ({:?}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let mut words = Vec::new();
    let mut end = None;
    for line in stdout.lines() {
        if let Some(hex) = line.strip_prefix("GOLDEN ") {
            words.push(
                u32::from_str_radix(hex.trim(), 16).unwrap_or_else(|_| panic!("bad line '{line}'")),
            );
        } else if let Some(n) = line.strip_prefix("GOLDEN-END ") {
            end = Some(n.trim().parse::<usize>().expect("count"));
        }
    }
    assert_eq!(
        end,
        Some(words.len()),
        "the firmware's output is incomplete:\n{stdout}"
    );
    words
}

fn describe(w: u32) -> String {
    if w & 0xffff_ff00 == cases::ERROR {
        format!("error code {:#x}", w & 0xff)
    } else {
        format!("{:e} ({w:#010x})", f32::from_bits(w))
    }
}

#[test]
fn every_result_is_bit_identical_on_the_mcu_and_the_host() {
    let mut host = Vec::new();
    cases::run(&mut |w| host.push(w));
    let errors = host
        .iter()
        .filter(|&&w| w & 0xffff_ff00 == cases::ERROR)
        .count();
    // The cases must exercise both results and refusals, and the servo sequence must have run.
    assert!(
        errors >= 5 && host.len() > 1000,
        "{} words, {errors} errors",
        host.len()
    );
    // The servo through a model checked once steps exactly like the per-call path.
    assert!(
        !host.contains(&cases::VALID_PATH_DIFFERS),
        "host: the checked-once path differs from the per-call one"
    );
    // Every section ran to its end (a failed step emits its error and stops the cases): the
    // last, the servo with a backlash block, ends on a torque.
    assert!(
        host.last()
            .is_some_and(|&w| w & 0xffff_ff00 != cases::ERROR),
        "the cases stopped early: {:#x?}",
        host.last()
    );

    let mcu = run_on_mcu(&build_golden());
    let first_diff = host.iter().zip(&mcu).position(|(h, m)| h != m);
    if let Some(i) = first_diff {
        panic!(
            "word {i} differs: host {} vs MCU {}",
            describe(host[i]),
            describe(mcu[i])
        );
    }
    assert_eq!(host.len(), mcu.len(), "same words, different counts");
    assert!(
        !mcu.contains(&cases::VALID_PATH_DIFFERS),
        "MCU: the checked-once path differs from the per-call one"
    );
    println!(
        "{} results bit-identical on host and Cortex-M4F ({errors} refusals among them)",
        host.len()
    );
}
