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
        .args(["measure", "--plant", "paper", "--protocol", "repeat", "--seed", "4", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    let rows = host_sim::measurement_csv::read_measurements(&out).unwrap();
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
        (vec!["--plant".into(), "nosuch".into(), "--protocol".into(), "grid".into()], "unknown plant 'nosuch'"),
        (vec!["--plant".into(), "paper".into(), "--protocol".into(), "random:x".into()], "random:N"),
        (vec!["--plant".into(), "paper".into(), "--protocol".into(), "spiral".into()], "unknown protocol 'spiral'"),
        (vec!["--plant".into(), bad_plant.display().to_string(), "--protocol".into(), "grid".into()], "bad.toml"),
        (
            vec!["--plant".into(), "paper".into(), "--protocol".into(), "grid".into(), "--grid".into(), "/nonexistent/g.bin".into()],
            "g.bin",
        ),
    ];
    for (args, want) in cases {
        let o = host_sim().arg("measure").args(&args).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} left a file");
    }
    let o = host_sim().args(["simulate", "--plant", "ideal", "--trajectory", "spiral"]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("spiral"));
}

#[test]
fn simulate_prints_the_summary_and_writes_log_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let (log, plot) = (dir.path().join("l.csv"), dir.path().join("p.png"));
    let o = host_sim()
        .args(["simulate", "--plant", "ideal", "--trajectory", "circle", "--seconds", "0.5", "--log"])
        .arg(&log)
        .arg("--plot")
        .arg(&plot)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for key in ["max_tracking_err_um", "rms_tracking_err_um", "realtime_factor", "overruns"] {
        assert!(v.get(key).is_some(), "{key} missing in {v}");
    }
    assert_eq!(v["samples"], 1000);
    assert!(v["fault"].is_null());
    assert_eq!(std::fs::read_to_string(&log).unwrap().lines().count(), 1001);
    assert!(std::fs::metadata(&plot).unwrap().len() > 1000);
}
