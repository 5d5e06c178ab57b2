//! Inputs the tools must not take at face value, through the binary: machine-file values out of
//! physical range, point ids and numbering in an import, units and encodings of an export.
//! Each refusal: non-zero exit, a message naming what is wrong (the key, the line, the
//! encoding), no output written.

use std::path::{Path, PathBuf};
use std::process::Command;

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Expects failure with every one of `want` in stderr, no panic, and `absent` not written.
fn refused(args: &[&str], want: &[&str], absent: &Path) {
    let (ok, _, stderr) = run(args);
    assert!(!ok, "{args:?} succeeded");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    for w in want {
        assert!(
            stderr.contains(w),
            "{args:?}: stderr '{stderr}' lacks '{w}'"
        );
    }
    assert!(!absent.exists(), "{args:?} wrote {}", absent.display());
}

fn paper_toml() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/paper.toml"))
        .unwrap()
}

/// The paper machine file with one edit, written to `dir`.
fn machine_with(dir: &Path, from: &str, to: &str) -> PathBuf {
    let text = paper_toml();
    assert!(text.contains(from), "{from}");
    let p = dir.join("machine.toml");
    std::fs::write(&p, text.replacen(from, to, 1)).unwrap();
    p
}

#[test]
fn machine_file_values_out_of_physical_range_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("plan");
    for (from, to, key, why) in [
        (
            "distance_mm = 5.0",
            "distance_mm = 1e300",
            "approach.distance_mm",
            "a quarter of the workspace's smaller side (100 mm)",
        ),
        (
            "stop_margin_mm = 0.1",
            "stop_margin_mm = 80",
            "workspace.stop_margin_mm",
            "no workspace is left",
        ),
        (
            "sigma_um = 1.0",
            "sigma_um = 1e300",
            "instrument.sigma_um",
            "no instrument that calibrates is worse than 1 mm",
        ),
    ] {
        let m = machine_with(dir.path(), from, to);
        refused(
            &["plan", "--machine", s(&m), "--out", s(&out)],
            &[&format!("'{key}'"), why],
            &out,
        );
        // The demo refuses at once too, not late inside a step.
        let demo = dir.path().join("demo");
        refused(
            &["demo", "--machine", s(&m), "--out", s(&demo)],
            &[&format!("'{key}'")],
            &demo,
        );
    }
}
