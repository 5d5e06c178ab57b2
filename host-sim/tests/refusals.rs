//! The host tools refuse rather than guess: every
//! reported reproduction for the host tools, through the binary, failing on the code
//! before this change and passing after. Each refusal: non-zero exit, a message saying why, and
//! no output written (or clobbered).

use host_sim::io::measurement_csv::{write_measurements, Measurement};
use kinematics_core::FiveBar;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
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

fn table1() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/table1.csv")
}

/// Expects failure with `want` in stderr and none of `absent` existing afterwards.
fn refused(args: &[&str], want: &str, absent: &[&Path]) {
    let (ok, _, stderr) = run(args);
    assert!(!ok, "{args:?} succeeded");
    assert!(
        stderr.contains(want),
        "{args:?}: stderr '{stderr}' lacks '{want}'"
    );
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    for p in absent {
        assert!(!p.exists(), "{args:?} wrote {}", p.display());
    }
}

/// Readings of the nominal machine at `targets` (measured = where it is, plus noise σ mm).
fn readings(targets: &[[f64; 2]], sigma_mm: f64, seed: u64) -> Vec<Measurement> {
    let m = FiveBar::<f64>::paper_nominal();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma_mm.max(1e-12)).unwrap();
    targets
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let th = m.inverse(t, 0.05).unwrap();
            let p = m.forward(th, 0.0).unwrap();
            Measurement {
                theta_deg: th.map(f64::to_degrees),
                measured_mm: [p[0] + noise.sample(&mut rng), p[1] + noise.sample(&mut rng)],
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: i + 2,
            }
        })
        .collect()
}

fn random_targets(n: usize, seed: u64) -> Vec<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(170.0..255.0),
                rng.random_range(-70.0..70.0),
            ]
        })
        .collect()
}

#[test]
fn fix_is_validated() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.json");
    let all = "a_mm,b_mm,c_mm,d_mm,base_b0_x_mm,base_b0_y_mm,encoder_offset_1_rad,encoder_offset_2_rad,base_a0_x_mm,base_a0_y_mm";
    // Was: a panic (SVD of an empty matrix).
    refused(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "full",
            "--fix",
            all,
            "--out",
            s(&out),
        ],
        "nothing is left to fit",
        &[&out],
    );
    // Was: "18446744073709551615 parameters" (an underflow).
    let eleven = ["a_mm"; 11].join(",");
    refused(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "full",
            "--fix",
            &eleven,
            "--out",
            s(&out),
        ],
        "'a_mm' is given twice",
        &[&out],
    );
}

#[cfg(unix)]
#[test]
fn outputs_only_onto_regular_files_or_new_paths() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fit = |out: &Path| {
        run(&[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "ls",
            "--out",
            s(out),
        ])
    };
    // A FIFO stays a FIFO (was: replaced by a regular file).
    let fifo = d.join("fifo");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let (ok, _, err) = fit(&fifo);
    assert!(!ok && err.contains("a FIFO"), "{err}");
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
    // A symbolic link stays a link and its target is untouched.
    let target = d.join("keep.json");
    std::fs::write(&target, "keep").unwrap();
    let link = d.join("link.json");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let (ok, _, err) = fit(&link);
    assert!(!ok && err.contains("symbolic link"), "{err}");
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
    // A device is refused, not replaced (was: /dev/full replaced as root). /dev/null is
    // checked, never written: the refusal comes before any write.
    let (ok, _, err) = fit(Path::new("/dev/null"));
    assert!(!ok && err.contains("a device"), "{err}");
    assert!(std::fs::metadata("/dev/null")
        .unwrap()
        .file_type()
        .is_char_device());
}

#[test]
fn every_output_is_written_only_once_all_are_ready() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bad = d.join("a-directory");
    std::fs::create_dir(&bad).unwrap();
    // fit --out BAD --plot p.png: was: p.png written, then the failure.
    let png = d.join("p.png");
    refused(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "ls",
            "--out",
            s(&bad),
            "--plot",
            s(&png),
        ],
        "a directory",
        &[&png],
    );
    let json = d.join("m.json");
    refused(
        &[
            "fit",
            "--data",
            s(&table1()),
            "--method",
            "ls",
            "--out",
            s(&json),
            "--plot",
            s(&bad),
        ],
        "a directory",
        &[&json],
    );
    // grid --out BAD --csv x.csv: was: x.csv written, then the failure.
    let model = d.join("model.json");
    let (ok, _, err) = run(&[
        "fit",
        "--data",
        s(&table1()),
        "--method",
        "ls",
        "--out",
        s(&model),
    ]);
    assert!(ok, "{err}");
    let nodes: Vec<[f64; 2]> = (0..3)
        .flat_map(|i| (0..3).map(move |j| [207.0 + 5.0 * i as f64, -5.0 + 5.0 * j as f64]))
        .collect();
    let data = d.join("nodes.csv");
    write_measurements(&data, &readings(&nodes, 0.0, 1)).unwrap();
    let csv = d.join("x.csv");
    refused(
        &[
            "grid",
            "--model",
            s(&model),
            "--data",
            s(&data),
            "--out",
            s(&bad),
            "--csv",
            s(&csv),
        ],
        "a directory",
        &[&csv],
    );
    let image = d.join("g.bin");
    refused(
        &[
            "grid",
            "--model",
            s(&model),
            "--data",
            s(&data),
            "--out",
            s(&image),
            "--csv",
            s(&bad),
        ],
        "a directory",
        &[&image],
    );
    // And with good paths both are written.
    let (ok, _, err) = run(&[
        "grid",
        "--model",
        s(&model),
        "--data",
        s(&data),
        "--out",
        s(&image),
        "--csv",
        s(&csv),
    ]);
    assert!(ok && image.exists() && csv.exists(), "{err}");
    // diagnose --out report.json --out-model BAD: the report is not written either; an extended
    // model named like the measurements is refused and the measurements are kept.
    let m = d.join("m.csv");
    write_measurements(&m, &readings(&random_targets(60, 3), 1e-3, 3)).unwrap();
    let report = d.join("report.json");
    refused(
        &[
            "diagnose",
            "--data",
            s(&m),
            "--out",
            s(&report),
            "--out-model",
            s(&bad),
        ],
        "a directory",
        &[&report],
    );
    let before = std::fs::read(&m).unwrap();
    refused(
        &[
            "diagnose",
            "--data",
            s(&m),
            "--out",
            s(&report),
            "--out-model",
            s(&m),
        ],
        "is the file of the input --data",
        &[&report],
    );
    assert_eq!(
        std::fs::read(&m).unwrap(),
        before,
        "diagnose overwrote its measurements"
    );
    let extended = d.join("extended.json");
    let (ok, _, err) = run(&[
        "diagnose",
        "--data",
        s(&m),
        "--out",
        s(&report),
        "--out-model",
        s(&extended),
    ]);
    assert!(ok && report.exists() && extended.exists(), "{err}");
}

#[test]
fn unidentifiable_fits_are_refused_with_the_evidence() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.json");
    // 21 points on one line (was: links 150/239/165/151 mm, B0 = (64, −96) mm, exit 0).
    let line: Vec<[f64; 2]> = (0..21).map(|k| [170.0 + 4.0 * k as f64, 10.0]).collect();
    let p = d.join("line.csv");
    write_measurements(&p, &readings(&line, 0.002, 2)).unwrap();
    let (ok, _, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(!ok && !out.exists(), "{err}");
    assert!(
        err.contains("do not determine the model") || err.contains("implausible"),
        "{err}"
    );
    assert!(
        err.contains("condition number") && err.contains("residual σ"),
        "{err}"
    );
    // 40 points with 10 mm noise (was: 339/408/563/161 mm, "not poorly conditioned").
    let p = d.join("noisy.csv");
    write_measurements(&p, &readings(&random_targets(40, 3), 10.0, 3)).unwrap();
    let (ok, _, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(!ok && !out.exists(), "{err}");
    assert!(
        err.contains("residual σ") && err.contains("against the instrument's"),
        "{err}"
    );
    // The same poses with a calibration instrument's noise fit.
    let p = d.join("good.csv");
    write_measurements(&p, &readings(&random_targets(40, 3), 0.005, 3)).unwrap();
    let (ok, _, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(ok, "{err}");
}

#[test]
fn absurd_values_and_mixed_up_units_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.json");
    let good = readings(&random_targets(30, 4), 0.002, 4);
    // One θ = 1e300° row (was: accepted, b moved to 572 mm).
    let mut rows = good.clone();
    rows[5].theta_deg[0] = 1e300;
    let p = d.join("huge.csv");
    write_measurements(&p, &rows).unwrap();
    refused(
        &["fit", "--data", s(&p), "--method", "full", "--out", s(&out)],
        "line 7: 'theta1_deg' = 1e300 is absurd",
        &[&out],
    );
    // diagnose on a row with x = 1e300 (was: RMS inf, exit 0).
    let mut rows = good.clone();
    rows[2].measured_mm[0] = 1e300;
    let p = d.join("x_huge.csv");
    write_measurements(&p, &rows).unwrap();
    let report = d.join("report.json");
    refused(
        &["diagnose", "--data", s(&p), "--out", s(&report)],
        "line 4: 'x_mm' = 1e300 is absurd",
        &[&report],
    );
    // Radians in the _deg columns (was: exit 0 with b = 66 mm and 119° offsets).
    let rad: Vec<Measurement> = good
        .iter()
        .map(|m| Measurement {
            theta_deg: m.theta_deg.map(f64::to_radians),
            ..m.clone()
        })
        .collect();
    let p = d.join("rad.csv");
    write_measurements(&p, &rad).unwrap();
    for method in ["full", "ls"] {
        refused(
            &["fit", "--data", s(&p), "--method", method, "--out", s(&out)],
            "radians in the _deg columns",
            &[&out],
        );
    }
    // Metres in the _mm columns.
    let m: Vec<Measurement> = good
        .iter()
        .map(|m| Measurement {
            measured_mm: m.measured_mm.map(|v| v / 1e3),
            ..m.clone()
        })
        .collect();
    let p = d.join("metres.csv");
    write_measurements(&p, &m).unwrap();
    refused(
        &["fit", "--data", s(&p), "--method", "full", "--out", s(&out)],
        "metres in the _mm columns",
        &[&out],
    );
}

#[test]
fn leave_one_out_never_reports_zero_for_failed_refits() {
    // Six points fit ten parameters (12 equations); five do not: every refit fails.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("six.csv");
    write_measurements(
        &p,
        &readings(
            &[
                [180.0, -50.0],
                [240.0, -40.0],
                [200.0, 0.0],
                [250.0, 30.0],
                [175.0, 55.0],
                [220.0, 60.0],
            ],
            0.0,
            5,
        ),
    )
    .unwrap();
    let out = dir.path().join("m.json");
    let (ok, stdout, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let loo = &v["leave_one_out"];
    // Was: max_um 0.0, rms_um 0.0.
    assert!(loo["max_um"].is_null() && loo["rms_um"].is_null(), "{loo}");
    assert_eq!(loo["failed"], 6);
    assert!(err.contains("leave-one-out: no point"), "{err}");
}

/// The blunder test through the binary: the rows it rejects are named on
/// stderr and in the JSON; too many refuse the fit and write nothing; its flag is validated.
#[test]
fn blunders_are_named_or_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.json");
    let mut rows = readings(&random_targets(50, 31), 0.001, 32);
    rows[4].measured_mm[1] -= 0.4;
    rows[30].measured_mm = [rows[30].measured_mm[1], rows[30].measured_mm[0]];
    let p = d.join("two.csv");
    write_measurements(&p, &rows).unwrap();
    let (ok, stdout, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(ok, "{err}");
    assert!(err.contains("blunder test rejected 2 row(s)"), "{err}");
    let json: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let rejected = json["blunders"]["rejected"].as_array().unwrap();
    let named: Vec<u64> = rejected
        .iter()
        .map(|r| r["row"].as_u64().unwrap())
        .collect();
    assert_eq!(named, [5, 31], "{json}");
    assert!(
        (rejected[0]["residual_um"].as_f64().unwrap() - 400.0).abs() < 10.0,
        "{json}"
    );
    assert_eq!(json["n_points"], 48);
    // Off, every row is fitted: the swapped row pulls the fit until a pose is unreachable.
    let off = d.join("off.json");
    refused(
        &[
            "fit",
            "--data",
            s(&p),
            "--method",
            "full",
            "--reject-sigma",
            "0",
            "--out",
            s(&off),
        ],
        "unreachable",
        &[&off],
    );
    // Off on clean rows: every row fitted, no `blunders` record.
    let clean = d.join("clean.csv");
    write_measurements(&clean, &readings(&random_targets(50, 31), 0.001, 32)).unwrap();
    let (ok, stdout, err) = run(&[
        "fit",
        "--data",
        s(&clean),
        "--method",
        "full",
        "--reject-sigma",
        "0",
        "--no-loo",
        "--out",
        s(&off),
    ]);
    let json: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(
        ok && json.get("blunders").is_none() && json["n_points"] == 50,
        "{err} {json}"
    );
    // Seven blunders in 50 rows (5 allowed): refused, nothing written.
    for i in [1, 8, 15, 22, 29, 36, 43] {
        rows[i].measured_mm[0] += 0.3;
    }
    let p = d.join("many.csv");
    write_measurements(&p, &rows).unwrap();
    let out = d.join("many.json");
    refused(
        &["fit", "--data", s(&p), "--method", "full", "--out", s(&out)],
        "a fit may reject: the data or the model are wrong",
        &[&out],
    );
    for (flag, want) in [
        ("-1", "not a threshold"),
        ("NaN", "not a threshold"),
        ("1", "would reject good rows"),
    ] {
        let flag = format!("--reject-sigma={flag}");
        refused(
            &[
                "fit",
                "--data",
                s(&p),
                "--method",
                "full",
                &flag,
                "--out",
                s(&out),
            ],
            want,
            &[&out],
        );
    }
    refused(
        &[
            "fit",
            "--data",
            s(&p),
            "--method",
            "ls",
            "--reject-sigma",
            "4",
            "--out",
            s(&out),
        ],
        "--reject-sigma applies to --method full",
        &[&out],
    );
}

/// A fit whose link lengths are beyond what a machine built to this drawing can have is refused
/// through the binary, whatever the method: well-determined data (40 poses spread over the
/// workspace, a 2 µm instrument) of a machine whose distal bar b is 8 % longer than the
/// drawing's (12 mm where the limit is 5 %, 7.5 mm) give the fit b = 162 mm exactly; `fit`
/// exits non-zero naming the parameter, its deviation and the limit, and writes nothing.
#[test]
fn implausible_link_lengths_are_refused_through_the_binary() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let nominal = FiveBar::<f64>::paper_nominal();
    let mut long = nominal;
    long.b_mm *= 1.08;
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let noise = Normal::new(0.0, 0.002).unwrap();
    let rows: Vec<Measurement> = random_targets(40, 8)
        .into_iter()
        .enumerate()
        .map(|(i, t)| {
            let th = long.inverse(t, 0.05).unwrap();
            let p = long.forward(th, 0.0).unwrap();
            Measurement {
                theta_deg: th.map(f64::to_degrees),
                measured_mm: [p[0] + noise.sample(&mut rng), p[1] + noise.sample(&mut rng)],
                target_mm: Some(t),
                dir: None,
                run: None,
                t_s: None,
                line: i + 2,
            }
        })
        .collect();
    let p = d.join("long_b.csv");
    write_measurements(&p, &rows).unwrap();
    for method in ["full", "ls"] {
        let out = d.join(format!("{method}.json"));
        let (ok, stdout, err) =
            run(&["fit", "--data", s(&p), "--method", method, "--out", s(&out)]);
        assert!(!ok, "{method}: a 162 mm link b was accepted: {stdout}");
        assert!(!out.exists(), "{method}: wrote {}", out.display());
        assert!(!err.contains("panicked"), "{method}: {err}");
        assert!(
            err.contains("the fitted model is implausible") && err.contains("b_mm = 16"),
            "{method}: {err}"
        );
        assert!(err.contains("limit 7.500 mm"), "{method}: {err}");
    }
    // The same machine within its drawing's tolerance (b 2 % long) is fitted.
    let mut close = nominal;
    close.b_mm *= 1.02;
    let rows: Vec<Measurement> = rows
        .iter()
        .map(|m| {
            let th = close.inverse(m.target_mm.unwrap(), 0.05).unwrap();
            Measurement {
                theta_deg: th.map(f64::to_degrees),
                measured_mm: close.forward(th, 0.0).unwrap(),
                ..m.clone()
            }
        })
        .collect();
    let p = d.join("close_b.csv");
    write_measurements(&p, &rows).unwrap();
    let out = d.join("close.json");
    let (ok, _, err) = run(&["fit", "--data", s(&p), "--method", "full", "--out", s(&out)]);
    assert!(ok && out.exists(), "{err}");
}
