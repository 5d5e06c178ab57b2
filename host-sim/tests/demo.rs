//! `host-sim demo` through the binary, as a user runs it: the accuracy after each step (JSON on
//! stdout, table on stderr), the noise-floor target, and every file it promises, each one
//! readable by the tool that consumes it.

use host_sim::calib::pipeline::{FILES, TARGET_MAX_UM, TARGET_RMS_UM};
use host_sim::io::measurement_csv::read_measurements;
use host_sim::io::model_file::read_model;
use kinematics_core::CorrectionGrid;
use std::process::Command;

#[test]
fn demo_runs_the_whole_story_and_writes_every_file() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["demo", "--out", out_dir.to_str().unwrap(), "--seed", "3"])
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{stderr}");
    eprintln!("{stderr}");

    // stdout is exactly one JSON document; the table is on stderr.
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(
        stderr.contains("full fit + 5 mm grid (2 rounds)") && stderr.contains("met"),
        "{stderr}"
    );
    let stages = v["stages"].as_array().unwrap();
    let keys: Vec<&str> = stages.iter().map(|s| s["step"].as_str().unwrap()).collect();
    assert_eq!(keys, ["nominal", "ls", "full", "full+grid", "full+grid2"]);
    let max = |k: usize| stages[k]["max_um"].as_f64().unwrap();
    let rms = |k: usize| stages[k]["rms_um"].as_f64().unwrap();
    // The default machine is the paper plant (six-bar; its instrument stands 3.2 mm off,
    // zeroed at Table I's point 1 as in the paper). Every stage is judged in the machine frame
    // the `full` fit registers: there the nominal model is ~3.5 mm off at worst (the paper's
    // ~1.5 mm is with its instrument zeroed at a reference pose, which takes the common offset
    // out). The paper's `ls` fit (4 links) in its own registered frame is better than nominal;
    // the `full` fit much more, the grid improves on it, and the second grid round only
    // refines at the noise floor.
    assert!((3000.0..=4000.0).contains(&max(0)), "before: {} µm", max(0));
    assert!(max(1) < max(0), "ls: {stages:?}");
    assert!(
        max(2) < max(0) / 20.0 && rms(2) < rms(0) / 20.0,
        "full fit: {stages:?}"
    );
    assert!(max(3) < max(2) && rms(3) < rms(2), "grid: {stages:?}");
    for (k, key) in keys.iter().enumerate().skip(3) {
        assert!(
            max(k) <= TARGET_MAX_UM && rms(k) <= TARGET_RMS_UM,
            "{key}: {} / {} µm",
            max(k),
            rms(k)
        );
    }
    assert_eq!(v["final"]["met"], serde_json::json!(true));
    assert_eq!(v["final"]["max_um"], stages[4]["max_um"]);
    assert_eq!(stages[4]["n_targets"], serde_json::json!(400));

    // Every file exists and parses with its consumer.
    for name in FILES {
        let p = out_dir.join(name);
        assert!(p.is_file(), "missing {}", p.display());
        assert!(
            v["files"]
                .as_array()
                .unwrap()
                .iter()
                .any(|f| f.as_str().unwrap().ends_with(name)),
            "{name} not listed"
        );
    }
    let leftovers: Vec<_> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    let model = read_model(&out_dir.join("model.json")).unwrap();
    read_model(&out_dir.join("model_ls.json")).unwrap();
    let image = std::fs::read(out_dir.join("grid.bin")).unwrap();
    let grid = CorrectionGrid::parse(&image).unwrap();
    assert_eq!((grid.geometry().nx, grid.geometry().ny), (21, 31));
    assert_eq!(
        *grid.model(),
        model.cast::<f32>(),
        "the grid embeds the fitted model"
    );
    assert_eq!(
        read_measurements(&out_dir.join("fit_measurements.csv"))
            .unwrap()
            .len(),
        40
    );
    assert_eq!(
        read_measurements(&out_dir.join("grid_measurements.csv"))
            .unwrap()
            .len(),
        21 * 31
    );
    assert_eq!(
        read_measurements(&out_dir.join("grid_measurements_round2.csv"))
            .unwrap()
            .len(),
        21 * 31
    );
    for k in ["nominal", "ls", "full", "full_grid", "full_grid2"] {
        assert_eq!(
            read_measurements(&out_dir.join(format!("verify_{k}.csv")))
                .unwrap()
                .len(),
            400
        );
    }
    assert_eq!(
        std::fs::read_to_string(out_dir.join("grid.csv"))
            .unwrap()
            .lines()
            .count(),
        1 + 21 * 31
    );
    for png in [
        "errors_fit.png",
        "errors_grid.png",
        "errors_final.png",
        "grid_nodes.png",
    ] {
        assert_eq!(
            &std::fs::read(out_dir.join(png)).unwrap()[1..4],
            b"PNG",
            "{png}"
        );
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary, v, "summary.json is the stdout JSON");
}

#[test]
fn demo_is_reproducible_for_a_seed() {
    let dir = tempfile::tempdir().unwrap();
    let run = |sub: &str| {
        let p = dir.path().join(sub);
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(["demo", "--out", p.to_str().unwrap(), "--seed", "7"])
            .output()
            .unwrap();
        assert!(out.status.success());
        let mut v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        v["out_dir"] = serde_json::Value::Null;
        v["files"] = serde_json::Value::Null;
        (v, std::fs::read(p.join("grid.bin")).unwrap())
    };
    assert_eq!(run("a"), run("b"));
}

#[test]
fn demo_into_an_unwritable_place_fails_clearly() {
    let dir = tempfile::tempdir().unwrap();
    // A file where the output directory should be.
    let blocker = dir.path().join("taken");
    std::fs::write(&blocker, b"x").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["demo", "--out", blocker.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("error:") && stderr.contains("taken"),
        "{stderr}"
    );
    assert!(out.stdout.is_empty(), "no JSON on failure");
}

/// A tracker set up anywhere (plant TOML `[instrument]` keys): 12.5 mm off and turned 0.35°
/// (another build of the paper design), metres away at 137°, and on the second machine
/// metres away at −75°. The demo registers the frame (reported: near where the tracker
/// stood, the difference being the machine frame's convention), runs every step including the
/// paper's `ls` row, and reaches the paper plant's accuracy class through the grid.
#[test]
fn demo_calibrates_with_the_tracker_anywhere() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let place = |plant: &str, offset: [f64; 2], rotation_deg: f64, name: &str| {
        let text = std::fs::read_to_string(root.join(plant)).unwrap();
        let text: Vec<String> = text
            .lines()
            .map(|l| {
                if l.starts_with("frame_offset_mm") {
                    format!("frame_offset_mm = [{:?}, {:?}]", offset[0], offset[1])
                } else if l.starts_with("frame_rotation_deg") {
                    format!("frame_rotation_deg = {rotation_deg:?}")
                } else {
                    l.to_string()
                }
            })
            .collect();
        let p = dir.path().join(name);
        std::fs::write(&p, text.join("\n")).unwrap();
        p
    };
    let second = root.join("machines/second.toml");
    let cases = [
        (
            place("plants/paper.toml", [12.5, -4.0], 0.35, "near.toml"),
            None,
            [12.5, -4.0],
            0.35,
        ),
        (
            place("plants/paper.toml", [2500.0, -1800.0], 137.0, "far.toml"),
            None,
            [2500.0, -1800.0],
            137.0,
        ),
        (
            place(
                "plants/second.toml",
                [-1500.0, 3200.0],
                -75.0,
                "second_far.toml",
            ),
            Some(&second),
            [-1500.0, 3200.0],
            -75.0,
        ),
    ];
    for (plant, machine, offset, rotation_deg) in cases {
        let out_dir = dir.path().join(plant.file_stem().unwrap());
        let mut args = vec![
            "demo".to_string(),
            "--plant".into(),
            plant.display().to_string(),
            "--noise-um".into(),
            "1".into(),
            "--out".into(),
            out_dir.display().to_string(),
        ];
        if let Some(m) = machine {
            args.extend(["--machine".into(), m.display().to_string()]);
        }
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(&args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{}: {stderr}", plant.display());
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let keys: Vec<&str> = v["stages"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["step"].as_str().unwrap())
            .collect();
        assert_eq!(keys, ["nominal", "ls", "full", "full+grid", "full+grid2"]);
        let (max, rms) = (
            v["final"]["max_um"].as_f64().unwrap(),
            v["final"]["rms_um"].as_f64().unwrap(),
        );
        eprintln!(
            "{}: final {max} / {rms} µm; frame {}",
            plant.display(),
            v["instrument_frame"]
        );
        assert!(
            max <= 1.0 && rms <= 0.3,
            "{}: {max} / {rms}",
            plant.display()
        );
        let f = &v["instrument_frame"];
        let got = f["offset_mm"].as_array().unwrap();
        let d = (got[0].as_f64().unwrap() - offset[0]).hypot(got[1].as_f64().unwrap() - offset[1]);
        // The six-bar's hidden robot sits within a few tenths of a mm and a few hundredths of
        // a degree of its nominal pose: that is the machine frame's convention.
        assert!(d < 0.5, "offset {got:?} vs {offset:?}");
        assert!(
            (f["rotation_deg"].as_f64().unwrap() - rotation_deg).abs() < 0.05,
            "{f}"
        );
        let model = host_sim::io::model_file::read_model_file(&out_dir.join("model.json")).unwrap();
        let nominal = match machine {
            Some(m) => host_sim::io::machine_file::read_machine(m).unwrap().nominal,
            None => kinematics_core::FiveBar::paper_nominal(),
        };
        assert_eq!(model.model().unwrap().base_a0_mm, nominal.base_a0_mm);
        assert!(model.instrument_frame.is_some());
    }
}
