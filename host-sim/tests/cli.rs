//! The calibration commands through the binary: outputs, and bad input (clear message naming
//! the line or point, non-zero exit, no output file).

use host_sim::io::measurement_csv::{write_measurements, Measurement};
use host_sim::io::model_file::{write_model_file, ModelFile};
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

fn table1() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/table1.csv")
}

/// Runs the binary; returns (success, stdout, stderr).
fn run(args: &[&str]) -> (bool, String, String) {
    let out = bin().args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Table I's readings are in the machine frame (the paper zeroed its instrument at point 1):
/// `--frame machine` reproduces the paper's subsets; `full` registers the frame as always.
#[test]
fn fit_table1_poly_and_ls_paper_criterion() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.json");
    let (ok, stdout, stderr) = run(&[
        "fit",
        "--data",
        s(&table1()),
        "--method",
        "poly",
        "--subset-search",
        "--criterion",
        "paper",
        "--frame",
        "machine",
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["subset"], serde_json::json!([1, 8]));
    assert!((v["a_mm"].as_f64().unwrap() - 149.8675).abs() < 1e-3);
    assert!(
        stderr.contains("subset search: 36 subsets tried"),
        "{stderr}"
    );
    let m = host_sim::io::model_file::read_model(&out).unwrap();
    assert!((m.d_mm - 149.908).abs() < 1e-3);
    let (ok, stdout, _) = run(&[
        "fit",
        "--data",
        s(&table1()),
        "--method",
        "ls",
        "--subset-search",
        "--criterion",
        "paper",
        "--frame",
        "machine",
        "--out",
        s(&out),
    ]);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["subset"], serde_json::json!([1, 3, 4, 8]));
    let (ok, stdout, stderr) = run(&[
        "fit",
        "--data",
        s(&table1()),
        "--method",
        "full",
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    for k in ["a_mm", "b_mm", "c_mm", "d_mm", "max_err_um", "rms_err_um"] {
        assert!(v[k].as_f64().unwrap().is_finite(), "{k}");
    }
    assert!(v["std_dev"]["a_mm"].as_f64().unwrap() > 0.0);
    assert_eq!(
        v["leave_one_out"]["per_point_um"].as_array().unwrap().len(),
        9
    );
    // The frame is registered and stored: the model's A0 is the nominal one.
    assert!(
        v["instrument_frame"]["rotation_deg"].as_f64().is_some(),
        "{v}"
    );
    let f = host_sim::io::model_file::read_model_file(&out).unwrap();
    assert!(f.instrument_frame.is_some());
    assert_eq!(f.model().unwrap().base_a0_mm, [0.0, 0.0]);
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Expects failure with `want` in the message and no file at `out`.
fn fails(args: &[&str], want: &str, out: &Path) {
    let (ok, _, stderr) = run(args);
    assert!(!ok, "{args:?} succeeded");
    assert!(
        stderr.contains(want),
        "{args:?}: stderr '{stderr}' lacks '{want}'"
    );
    assert!(!out.exists(), "{args:?} left {}", out.display());
}

#[test]
fn fit_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.json");
    let header = "theta1_deg,theta2_deg,x_mm,y_mm\n";
    let nan = write(
        d,
        "nan.csv",
        &format!("{header}45,-45,212.132,0\n60.881,-21.938,NaN,74.95\n"),
    );
    fails(
        &["fit", "--data", s(&nan), "--method", "ls", "--out", s(&out)],
        "line 3: 'x_mm' = 'NaN' is not finite",
        &out,
    );
    let short = write(d, "short.csv", &format!("{header}45,-45,212.132\n"));
    fails(
        &[
            "fit",
            "--data",
            s(&short),
            "--method",
            "ls",
            "--out",
            s(&out),
        ],
        "line 2: 3 fields",
        &out,
    );
    let empty = write(d, "empty.csv", header);
    fails(
        &[
            "fit",
            "--data",
            s(&empty),
            "--method",
            "ls",
            "--out",
            s(&out),
        ],
        "no data rows",
        &out,
    );
    let dup = write(
        d,
        "dup.csv",
        &format!("{header}45,-45,212.132,0\n57.286,-57.286,162.22,-0.01\n45,-45,212.13,0.01\n"),
    );
    fails(
        &["fit", "--data", s(&dup), "--method", "ls", "--out", s(&out)],
        "line 4: duplicate point, same motor angles as line 2",
        &out,
    );
    let three = write(
        d,
        "three.csv",
        &format!("{header}45,-45,212.132,0\n57.286,-57.286,162.22,-0.01\n29.1,-29.1,262.03,0.04\n"),
    );
    fails(
        &[
            "fit",
            "--data",
            s(&three),
            "--method",
            "full",
            "--out",
            s(&out),
        ],
        "3 points give 6 equations, not more than the 10 parameters",
        &out,
    );
    fails(
        &[
            "fit",
            "--data",
            s(&three),
            "--method",
            "poly",
            "--out",
            s(&out),
        ],
        "poly uses exactly 2 precision points",
        &out,
    );
    fails(
        &[
            "fit",
            "--data",
            s(&three),
            "--method",
            "ls",
            "--criterion",
            "paper",
            "--out",
            s(&out),
        ],
        "line 2: --criterion paper needs x_target_mm",
        &out,
    );
    fails(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "ls",
            "--points",
            "1,12",
            "--out",
            s(&out),
        ],
        "point 12 does not exist",
        &out,
    );
    fails(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "full",
            "--fix",
            "e_mm",
            "--out",
            s(&out),
        ],
        "unknown parameter 'e_mm'",
        &out,
    );
}

/// A machine with errors, measured at a 5 mm grid commanded with the nominal model (a partial
/// grid around the home position, which every image must hold).
fn grid_data(dir: &Path) -> (PathBuf, PathBuf) {
    let mut truth = FiveBar::<f64>::paper_nominal();
    truth.a_mm = 149.9;
    truth.c_mm = 150.08;
    let model = FiveBar::<f64>::paper_nominal();
    let mut rows = Vec::new();
    for j in 0..7 {
        for i in 0..6 {
            let t = [195.0 + 5.0 * i as f64, -15.0 + 5.0 * j as f64];
            let th = model.inverse(t, 0.05).unwrap();
            rows.push(Measurement {
                theta_deg: [th[0].to_degrees(), th[1].to_degrees()],
                measured_mm: truth.forward(th, 0.0).unwrap(),
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: 0,
            });
        }
    }
    let data = dir.join("g.csv");
    write_measurements(&data, &rows).unwrap();
    let model_path = dir.join("model.json");
    write_model_file(&model_path, &ModelFile::from_model(&model)).unwrap();
    (data, model_path)
}

#[test]
fn grid_then_command_match_the_firmware_path() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (data, model) = grid_data(d);
    let grid = d.join("grid.bin");
    let (ok, stdout, stderr) = run(&[
        "grid",
        "--model",
        s(&model),
        "--data",
        s(&data),
        "--step-mm",
        "5",
        "--out",
        s(&grid),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("\"nx\": 6") && stdout.contains("\"ny\": 7"),
        "{stdout}"
    );
    // The six-bar prior is the default; --no-six-bar-prior takes the generic bases.
    assert!(stdout.contains("\"basis\": \"six_bar\""), "{stdout}");
    let generic = d.join("generic.bin");
    let (ok, generic_out, stderr) = run(&[
        "grid",
        "--model",
        s(&model),
        "--data",
        s(&data),
        "--no-six-bar-prior",
        "--out",
        s(&generic),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        !generic_out.contains("\"basis\": \"six_bar\"")
            && generic_out.contains("\"six_bar_lambda\": 0.0"),
        "{generic_out}"
    );
    let table = std::fs::read_to_string(d.join("grid.csv")).unwrap();
    assert!(table.starts_with("i,j,x_mm,y_mm,dx_um,dy_um,dtheta1_urad,dtheta2_urad\n"));
    assert_eq!(table.lines().count(), 1 + 42);

    let targets = write(
        d,
        "t.csv",
        "x_mm,y_mm\n196.3,-12.7\n215,15\n# comment\n207.5,0.25\n",
    );
    let angles = d.join("a.csv");
    let (ok, _, stderr) = run(&[
        "command",
        "--model",
        s(&model),
        "--grid",
        s(&grid),
        "--targets",
        s(&targets),
        "--out",
        s(&angles),
    ]);
    assert!(ok, "{stderr}");
    let image = std::fs::read(&grid).unwrap();
    let cal = Calibration::from_grid(CorrectionGrid::parse(&image).unwrap());
    let text = std::fs::read_to_string(&angles).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x_mm,y_mm,theta1_deg,theta2_deg"));
    for (line, t) in lines.zip([[196.3f32, -12.7], [215.0, 15.0], [207.5, 0.25]]) {
        let th = cal.command_rad(t, 0.05).unwrap();
        let f: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
        // Degrees with 9 decimals round-trip the f32 radians exactly.
        assert_eq!(
            (f[2].to_radians() as f32, f[3].to_radians() as f32),
            (th[0], th[1]),
            "{line}"
        );
    }

    // Without --model: the grid's own model, else the machine's nominal (this model.json holds
    // the nominal): the same angles, byte for byte.
    let no_model = d.join("a_no_model.csv");
    let (ok, _, stderr) = run(&[
        "command",
        "--grid",
        s(&grid),
        "--targets",
        s(&targets),
        "--out",
        s(&no_model),
    ]);
    assert!(ok, "{stderr}");
    assert_eq!(std::fs::read_to_string(&no_model).unwrap(), text);
    let (nominal, with_model) = (d.join("a_nominal.csv"), d.join("a_model.csv"));
    assert!(run(&["command", "--targets", s(&targets), "--out", s(&nominal)]).0);
    assert!(
        run(&[
            "command",
            "--model",
            s(&model),
            "--targets",
            s(&targets),
            "--out",
            s(&with_model)
        ])
        .0
    );
    assert_eq!(
        std::fs::read_to_string(&nominal).unwrap(),
        std::fs::read_to_string(&with_model).unwrap()
    );
    assert_ne!(
        std::fs::read_to_string(&nominal).unwrap(),
        text,
        "the grid's correction is not in the nominal angles"
    );

    // Bad input: target outside the grid, unreachable target, grid for another model, NaN.
    let outside = write(d, "o.csv", "x_mm,y_mm\n196,-12\n240,0\n");
    fails(
        &[
            "command",
            "--model",
            s(&model),
            "--grid",
            s(&grid),
            "--targets",
            s(&outside),
            "--out",
            s(&d.join("o1.csv")),
        ],
        "line 3: target (240, 0): ",
        &d.join("o1.csv"),
    );
    let far = write(d, "far.csv", "x_mm,y_mm\n196,-12\n400,0\n");
    fails(
        &[
            "command",
            "--model",
            s(&model),
            "--targets",
            s(&far),
            "--out",
            s(&d.join("o2.csv")),
        ],
        "line 3: target (400, 0)",
        &d.join("o2.csv"),
    );
    let mut other = FiveBar::<f64>::paper_nominal();
    other.b_mm = 150.01;
    let other_path = d.join("other.json");
    write_model_file(&other_path, &ModelFile::from_model(&other)).unwrap();
    fails(
        &[
            "command",
            "--model",
            s(&other_path),
            "--grid",
            s(&grid),
            "--targets",
            s(&targets),
            "--out",
            s(&d.join("o3.csv")),
        ],
        "grid was built for another model: b_mm",
        &d.join("o3.csv"),
    );
    let nan = write(d, "nan.csv", "x_mm,y_mm\n196,nan\n");
    fails(
        &[
            "command",
            "--model",
            s(&model),
            "--targets",
            s(&nan),
            "--out",
            s(&d.join("o4.csv")),
        ],
        "line 2: 'y_mm' = 'nan' is not finite",
        &d.join("o4.csv"),
    );

    // Grid: a missing node names it, nothing written.
    let text = std::fs::read_to_string(&data).unwrap();
    let cut: String = text
        .lines()
        .enumerate()
        .filter(|(k, _)| *k != 8)
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    let cut_path = write(d, "cut.csv", &cut);
    let g2 = d.join("g2.bin");
    fails(
        &[
            "grid",
            "--model",
            s(&model),
            "--data",
            s(&cut_path),
            "--out",
            s(&g2),
        ],
        "node (1, 1) at (200, -10) is missing",
        &g2,
    );
    assert!(!d.join("g2.csv").exists());
}

#[test]
fn accuracy_through_the_binary() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // x line at y = 0, targets 200, 210, 220; two runs up then down; +2 µm going up, −2 down.
    let mut text = String::from("theta1_deg,theta2_deg,x_mm,y_mm,x_target_mm,y_target_mm,run\n");
    for run in 0..3 {
        let noise = [0.0, 0.001, -0.001][run];
        for x in [200.0, 210.0, 220.0] {
            text.push_str(&format!("0,0,{},0,{x},0,{run}\n", x + 0.002 + noise));
        }
        for x in [220.0, 210.0, 200.0] {
            text.push_str(&format!("0,0,{},0,{x},0,{run}\n", x - 0.002 + noise));
        }
    }
    let data = write(d, "r.csv", &text);
    let (ok, stdout, stderr) = run(&["accuracy", "--data", s(&data)]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let line = &v["lines"][0];
    assert_eq!(line["axis"], "x");
    assert!(
        (line["iso_230_2"]["b_um"].as_f64().unwrap() - 4.0).abs() < 1e-6,
        "{line}"
    );
    // s = 1 µm at every target and direction: R = 2 + 2 + 4 = 8, Ps = 6.
    assert!(
        (line["iso_230_2"]["r_um"].as_f64().unwrap() - 8.0).abs() < 1e-6,
        "{line}"
    );
    assert!(
        (line["vdi_3441"]["ps_um"].as_f64().unwrap() - 6.0).abs() < 1e-6,
        "{line}"
    );
    assert!(
        (line["per_m"]["ps_pm"].as_f64().unwrap() - 150.0).abs() < 1e-6,
        "{line}"
    );

    let no_run = write(
        d,
        "nr.csv",
        "theta1_deg,theta2_deg,x_mm,y_mm,x_target_mm,y_target_mm\n0,0,1,0,1,0\n0,0,2,0,2,0\n",
    );
    let (ok, _, stderr) = run(&["accuracy", "--data", s(&no_run)]);
    assert!(
        !ok && stderr.contains("line 2: accuracy needs x_target_mm,y_target_mm and run"),
        "{stderr}"
    );
}
