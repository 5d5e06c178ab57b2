//! The `measure` and `simulate` commands end to end: outputs parse, bad input fails cleanly
//! (non-zero exit, a message naming the input, no file left behind).

use std::process::Command;

fn host_sim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

#[test]
fn measure_writes_a_measurement_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.csv");
    let st = host_sim()
        .args([
            "measure",
            "--plant",
            "paper",
            "--protocol",
            "repeat",
            "--seed",
            "4",
            "--out",
        ])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let rows = host_sim::io::measurement_csv::read_measurements(&out).unwrap();
    assert_eq!(rows.len(), 220);
    assert_eq!(rows.iter().map(|m| m.run.unwrap()).max(), Some(4));
}

#[test]
fn bad_input_fails_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.csv");
    let bad_plant = dir.path().join("bad.toml");
    std::fs::write(&bad_plant, "description = \"x\"\n").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "--plant".into(),
                "nosuch".into(),
                "--protocol".into(),
                "grid".into(),
            ],
            "unknown plant 'nosuch'",
        ),
        (
            vec![
                "--plant".into(),
                "paper".into(),
                "--protocol".into(),
                "random:x".into(),
            ],
            "random:N",
        ),
        (
            vec![
                "--plant".into(),
                "paper".into(),
                "--protocol".into(),
                "spiral".into(),
            ],
            "unknown protocol 'spiral'",
        ),
        (
            vec![
                "--plant".into(),
                bad_plant.display().to_string(),
                "--protocol".into(),
                "grid".into(),
            ],
            "bad.toml",
        ),
        (
            vec![
                "--plant".into(),
                "paper".into(),
                "--protocol".into(),
                "grid".into(),
                "--grid".into(),
                "/nonexistent/g.bin".into(),
            ],
            "g.bin",
        ),
    ];
    for (args, want) in cases {
        let o = host_sim()
            .arg("measure")
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} left a file");
    }
    let o = host_sim()
        .args(["simulate", "--plant", "ideal", "--trajectory", "spiral"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("spiral"));
}

#[test]
fn simulate_prints_the_summary_and_writes_log_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let (log, plot) = (dir.path().join("l.csv"), dir.path().join("p.png"));
    let o = host_sim()
        .args([
            "simulate",
            "--plant",
            "ideal",
            "--trajectory",
            "circle",
            "--seconds",
            "0.5",
            "--log",
        ])
        .arg(&log)
        .arg("--plot")
        .arg(&plot)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for key in [
        "max_tracking_err_um",
        "rms_tracking_err_um",
        "realtime_factor",
        "overruns",
    ] {
        assert!(v.get(key).is_some(), "{key} missing in {v}");
    }
    assert_eq!(v["samples"], 1000);
    assert!(v["fault"].is_null());
    assert_eq!(std::fs::read_to_string(&log).unwrap().lines().count(), 1001);
    assert!(std::fs::metadata(&plot).unwrap().len() > 1000);
}

#[test]
fn measure_with_a_zero_grid_matches_without_and_model_mismatch_is_refused() {
    use kinematics_core::grid::{encode, GridGeometry};
    use kinematics_core::FiveBar;
    let dir = tempfile::tempdir().unwrap();
    let geometry = GridGeometry {
        nx: 21,
        ny: 31,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 5.0,
        step_y_mm: 5.0,
    };
    let mut image = vec![0u8; geometry.image_len()];
    let model = FiveBar::<f32>::paper_nominal();
    let n = encode(
        &mut image,
        &geometry,
        &model,
        &vec![[0.0f32; 2]; geometry.len()],
    )
    .unwrap();
    let grid = dir.path().join("g.bin");
    std::fs::write(&grid, &image[..n]).unwrap();
    let (a, b) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
    let base = [
        "measure",
        "--plant",
        "paper",
        "--protocol",
        "table1",
        "--seed",
        "2",
        "--out",
    ];
    assert!(host_sim().args(base).arg(&a).status().unwrap().success());
    assert!(host_sim()
        .args(base)
        .arg(&b)
        .arg("--grid")
        .arg(&grid)
        .status()
        .unwrap()
        .success());
    assert_eq!(
        std::fs::read_to_string(&a).unwrap(),
        std::fs::read_to_string(&b).unwrap()
    );
    // A model file that is not the grid's model.
    let mut other = FiveBar::<f64>::paper_nominal();
    other.a_mm = 150.5;
    let m = dir.path().join("m.json");
    host_sim::io::model_file::write_model_file(
        &m,
        &host_sim::io::model_file::ModelFile::from_model(&other),
    )
    .unwrap();
    let c = dir.path().join("c.csv");
    let o = host_sim()
        .args(base)
        .arg(&c)
        .arg("--grid")
        .arg(&grid)
        .arg("--model")
        .arg(&m)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("differs"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!c.exists());
    // The model alone is used.
    assert!(host_sim()
        .args(base)
        .arg(&c)
        .arg("--model")
        .arg(&m)
        .status()
        .unwrap()
        .success());
    assert_ne!(
        std::fs::read_to_string(&a).unwrap(),
        std::fs::read_to_string(&c).unwrap()
    );
}
