//! `host-sim commission --qemu`: the machine builder's journey through the co-simulated
//! controller (the production firmware under QEMU driving the simulated six-bar in lockstep):
//! identify, home, plan, measure, fit, grid (two rounds, each measured through the image
//! uploaded before it), upload, verify at fresh targets through the controller.
//!
//! * A six-bar of the paper's design with part errors of the paper plant's kind (half their
//!   size), its instrument 3.2 mm off the machine frame, a 1 µm instrument: the journey ends
//!   with the calibration it uploaded in force (the id the controller reports is the CRC-32C
//!   of `grid.bin`), ≤ 1 µm max / 0.3 µm RMS where the tool lands at fresh targets, the
//!   instrument's frame registered, every file written.
//! * Bad input: a missing firmware, another machine's plant, a controller that does not
//!   answer, flags of another mode: a clear error, a non-zero exit, no output directory.
//!
//! Needs qemu-system-arm and the thumbv7em-none-eabihf target (`bash tests/run-all.sh`
//! installs both); the firmware is built into `target/system-tests` as the other QEMU tests do.
//! Wall time: about 90 s for the journey (about 310 simulated s; 1400 points through the
//! controller).

use host_sim::link::link_protocol::calibration_image_id;
use host_sim::plant::PlantConfig;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host-sim is in the workspace")
        .to_path_buf()
}

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

/// The paper plant with its link-length errors halved (the others, its clearances, backlash,
/// compliance, encoder offsets and instrument frame, as they are), a 1 µm instrument.
fn plant_file(dir: &Path) -> PathBuf {
    let mut p = PlantConfig::paper();
    let e = &mut p.sixbar.errors;
    for v in [
        &mut e.lever_length_mm,
        &mut e.bar_f_length_mm,
        &mut e.bar_q_length_mm,
        &mut e.bar_g_length_mm,
    ] {
        *v = v.map(|x| 0.5 * x);
    }
    p.instrument.noise_sigma_um = 1.0;
    let path = dir.join("plant.toml");
    std::fs::write(&path, p.to_toml()).unwrap();
    path
}

#[test]
fn the_journey_through_the_cosimulated_controller_calibrates_the_machine() {
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let tmp = tempfile::tempdir().unwrap();
    let plant = plant_file(tmp.path());
    let out = tmp.path().join("out");
    let o = host_sim(&[
        "commission",
        "--qemu",
        "--firmware",
        elf.to_str().unwrap(),
        "--plant",
        plant.to_str().unwrap(),
        "--verify-targets",
        "60",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (stdout, stderr) = text(&o);
    eprintln!("{stderr}");
    assert!(o.status.success(), "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();

    // Every step ran, in order, through the controller.
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

    // The uploaded calibration is in force: the controller's id is the file's, and it replaced
    // the commissioning image the controller started with.
    let grid_bin = std::fs::read(out.join("grid.bin")).unwrap();
    let id = calibration_image_id(&grid_bin);
    assert_eq!(r["calibration_id_u32"].as_u64(), Some(u64::from(id)));
    assert_eq!(r["calibration_id"], format!("{id:#010x}"));
    assert_ne!(r["calibration_id_before"], r["calibration_id"]);

    // The accuracy at fresh targets, where the tool really landed.
    let f = &r["final"];
    let (max, rms) = (f["max_um"].as_f64().unwrap(), f["rms_um"].as_f64().unwrap());
    assert_eq!(f["n_targets"], 60);
    assert!(max <= 1.0 && rms <= 0.3, "{max} / {rms} µm");
    assert_eq!(f["met"], true);
    // The readings carry the 1 µm instrument's noise: more than the truth, not much more.
    let measured = f["measured_rms_um"].as_f64().unwrap();
    assert!(measured > rms && measured < 3.0, "{measured} µm");

    // The instrument's frame registered (the plant's: 3.194 mm off in y).
    let off = &r["fit"]["instrument_frame"]["offset_mm"];
    let y = off[1].as_f64().unwrap();
    assert!((y - 3.194).abs() < 0.15, "{off}");
    // Two grid rounds, the second's node error smaller than the first's.
    let g = r["grid"].as_array().unwrap();
    assert_eq!(g.len(), 2);
    assert!(g[1]["node_err_rms_um"].as_f64() < g[0]["node_err_rms_um"].as_f64());

    for name in host_sim::commission::FILES {
        assert!(out.join(name).is_file(), "{name}");
    }
    let model = std::fs::read_to_string(out.join("model.json")).unwrap();
    assert!(model.contains("instrument_frame"), "{model}");
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
