//! `host-sim commission --qemu`: the machine builder's journey through the co-simulated
//! controller (the production firmware under QEMU driving the simulated six-bar in lockstep):
//! identify, home, plan, measure, fit, grid (two rounds, each measured through the image
//! uploaded before it), upload, verify at fresh targets through the controller.
//!
//! * The paper machine with the paper plant (part errors, clearances, backlash, its instrument
//!   3.2 mm off the machine frame) and a 1 µm instrument: the journey ends with the calibration
//!   it uploaded in force (the id the controller reports is the CRC-32C of `grid.bin`),
//!   ≤ 1 µm max / 0.3 µm RMS where the tool lands at fresh targets, the instrument's frame
//!   registered, every file written.
//! * The second machine (another design: its own machine file, plant and 2 µm instrument; an
//!   octagonal workspace inside its grid): the same journey, the goal scaled with σ, the
//!   grid's nodes outside the workspace estimated.
//! * Bad input: a missing firmware, another machine's plant, a controller that does not
//!   answer, flags of another mode: a clear error, a non-zero exit, no output directory.
//!
//! Needs qemu-system-arm and the thumbv7em-none-eabihf target (`bash tests/run-all.sh`
//! installs both); the firmware is built into `target/system-tests` as the other QEMU tests do.
//! Wall time: about 80 s per journey alone (about 310 simulated s, some 1400 points through the
//! controller); the two run side by side.

use host_sim::link::link_protocol::calibration_image_id;
use std::path::Path;
use std::process::{Command, Output};

include!("../../tests/support/firmware_build.rs");

fn host_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .expect("host-sim runs")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Runs the journey on `machine` (a file under host-sim/machines, or the default) with the
/// plant `plant`, 60 fresh targets; returns the report, the stderr and the output directory.
fn journey(machine: Option<&str>, plant: &str) -> (serde_json::Value, String, tempfile::TempDir) {
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let root = workspace_root().join("host-sim");
    let mut args: Vec<String> = vec![
        "commission".into(),
        "--qemu".into(),
        "--firmware".into(),
        elf.display().to_string(),
        "--plant".into(),
        plant.into(),
        "--verify-targets".into(),
        "60".into(),
        "--out".into(),
        out.display().to_string(),
    ];
    if let Some(m) = machine {
        args.extend(["--machine".into(), root.join(m).display().to_string()]);
    }
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = host_sim(&a);
    let (stdout, stderr) = text(&o);
    eprintln!("{stderr}");
    assert!(o.status.success(), "{stderr}");
    (serde_json::from_str(&stdout).unwrap(), stderr, tmp)
}

/// What every journey must show: each step in order, the uploaded calibration in force (the
/// controller's id is the file's CRC-32C, and it replaced the one the controller started
/// with), the goal met where the tool landed at the fresh targets, every file written.
fn check_journey(r: &serde_json::Value, stderr: &str, out: &Path) -> (f64, f64) {
    let steps: Vec<&str> = r["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["step"].as_str().unwrap())
        .collect();
    assert_eq!(
        steps,
        [
            "identify", "home", "plan", "measure", "fit", "diagnose", "grid 1", "grid 2", "upload",
            "verify"
        ]
    );
    for step in &steps {
        assert!(stderr.contains(&format!("commission: {step}")), "{step}");
    }
    let grid_bin = std::fs::read(out.join("grid.bin")).unwrap();
    let id = calibration_image_id(&grid_bin);
    assert_eq!(r["calibration_id_u32"].as_u64(), Some(u64::from(id)));
    assert_eq!(r["calibration_id"], format!("{id:#010x}"));
    assert_ne!(r["calibration_id_before"], r["calibration_id"]);
    let f = &r["final"];
    let (max, rms) = (f["max_um"].as_f64().unwrap(), f["rms_um"].as_f64().unwrap());
    assert_eq!(f["n_targets"], 60);
    assert!(
        max <= f["target_max_um"].as_f64().unwrap() && rms <= f["target_rms_um"].as_f64().unwrap(),
        "{max} / {rms} µm"
    );
    assert_eq!(f["met"], true);
    // The readings carry the instrument's noise: more than the truth.
    assert!(f["measured_rms_um"].as_f64().unwrap() > rms, "{f}");
    let g = r["grid"].as_array().unwrap();
    assert_eq!(g.len(), 2);
    assert!(g[1]["node_err_rms_um"].as_f64() < g[0]["node_err_rms_um"].as_f64());
    for name in host_sim::commission::FILES {
        assert!(out.join(name).is_file(), "{name}");
    }
    let model = std::fs::read_to_string(out.join("model.json")).unwrap();
    assert!(model.contains("instrument_frame"), "{model}");
    (max, rms)
}

#[test]
fn the_paper_machine_is_calibrated_through_the_cosimulated_controller() {
    let (r, stderr, tmp) = journey(None, "paper");
    let (max, rms) = check_journey(&r, &stderr, &tmp.path().join("out"));
    // The paper machine's goal with its 1 µm instrument.
    assert!(max <= 1.0 && rms <= 0.3, "{max} / {rms} µm");
    // The instrument's frame registered (the paper plant's: 3.194 mm off in y).
    let off = &r["fit"]["instrument_frame"]["offset_mm"];
    assert!((off[1].as_f64().unwrap() - 3.194).abs() < 0.15, "{off}");
    // Every node of the paper's grid is inside its workspace: none estimated.
    assert_eq!(r["grid"][1]["nodes_estimated"], 0);
}

#[test]
fn the_second_machine_is_calibrated_through_the_cosimulated_controller() {
    let (r, stderr, tmp) = journey(
        Some("machines/second.toml"),
        workspace_root()
            .join("host-sim/plants/second.toml")
            .to_str()
            .unwrap(),
    );
    let (max, rms) = check_journey(&r, &stderr, &tmp.path().join("out"));
    // Its 2 µm instrument: the goal scaled (2.0 / 0.6 µm).
    assert_eq!(r["final"]["target_max_um"], 2.0);
    assert!(max <= 2.0 && rms <= 0.6, "{max} / {rms} µm");
    assert_eq!(r["machine"], "second");
    // Its octagon inside the grid's rectangle: the corners' nodes estimated, not measured.
    let est = r["grid"][1]["nodes_estimated"].as_u64().unwrap();
    assert!(
        est > 0 && est < r["grid"][1]["nodes"].as_u64().unwrap() / 2,
        "{est}"
    );
}

#[test]
fn bad_input_is_a_clear_error_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let root = workspace_root().join("host-sim");
    let second = root.join("machines/second.toml");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "--qemu".into(),
                "--firmware".into(),
                tmp.path().join("no-such.elf").display().to_string(),
            ],
            "--firmware",
        ),
        (
            vec![
                "--qemu".into(),
                "--machine".into(),
                second.display().to_string(),
                "--plant".into(),
                "paper".into(),
            ],
            "machine",
        ),
        (
            vec![
                "--tcp".into(),
                "127.0.0.1:1".into(),
                "--timeout-s".into(),
                "1".into(),
            ],
            "127.0.0.1:1",
        ),
        (
            vec![
                "--tcp".into(),
                "127.0.0.1:1".into(),
                "--plant".into(),
                "paper".into(),
                "--noise-um".into(),
                "2".into(),
            ],
            "--qemu only",
        ),
        (
            vec!["--qemu".into(), "--grid-rounds".into(), "3".into()],
            "grid rounds",
        ),
    ];
    for (args, says) in cases {
        let mut all = vec!["commission".to_string()];
        all.extend(args.iter().cloned());
        all.extend(["--out".into(), out.display().to_string()]);
        let a: Vec<&str> = all.iter().map(String::as_str).collect();
        let o = host_sim(&a);
        let (_, stderr) = text(&o);
        assert!(!o.status.success(), "{a:?}: {stderr}");
        assert!(stderr.contains(says), "{a:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{a:?}: {stderr}");
        assert!(!out.exists(), "{a:?} left {}", out.display());
    }
}
