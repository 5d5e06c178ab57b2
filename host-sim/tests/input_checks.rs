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

/// A commanded list of `n` rows on the paper machine (what `command` writes), with or without
/// its targets, and the tool positions the export reports (mm).
fn session(dir: &Path, n: usize, with_targets: bool) -> (PathBuf, Vec<[f64; 2]>) {
    let m = kinematics_core::FiveBar::<f64>::paper_nominal();
    let mut text = String::from(if with_targets {
        "x_mm,y_mm,theta1_deg,theta2_deg\n"
    } else {
        "theta1_deg,theta2_deg\n"
    });
    let mut xy = Vec::new();
    for k in 0..n {
        let t = [
            170.0 + 80.0 * (k % 7) as f64 / 6.0,
            -60.0 + 120.0 * (k / 7 % 7) as f64 / 6.0,
        ];
        let th = m.inverse(t, 0.05).unwrap();
        if with_targets {
            text.push_str(&format!("{},{},", t[0], t[1]));
        }
        text.push_str(&format!("{},{}\n", th[0].to_degrees(), th[1].to_degrees()));
        xy.push([t[0] + 0.01, t[1] - 0.02]);
    }
    let p = dir.join(if with_targets {
        "angles.csv"
    } else {
        "angles_only.csv"
    });
    std::fs::write(&p, text).unwrap();
    (p, xy)
}

/// An export of `xy` (mm) scaled by `per_mm` units per mm, ids `{prefix}{k}` from `first`.
fn export(
    dir: &Path,
    name: &str,
    header: &str,
    xy: &[[f64; 2]],
    per_mm: f64,
    prefix: &str,
    first: u64,
) -> PathBuf {
    let mut text = format!("{header}\n");
    for (k, p) in xy.iter().enumerate() {
        text.push_str(&format!(
            "{prefix}{};{};{}\n",
            first + k as u64,
            p[0] * per_mm,
            p[1] * per_mm
        ));
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn import(args: &[&str]) -> (bool, String, String) {
    let mut a = vec!["import"];
    a.extend(args);
    run(&a)
}

#[test]
fn point_numbers_do_not_wrap_and_ids_may_start_with_a_hash() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.csv");
    let (cmd, xy) = session(d, 2, true);
    let e = export(d, "e.csv", "Point;X [mm];Y [mm]", &xy, 1.0, "P", 1);
    refused(
        &[
            "import",
            "--export",
            s(&e),
            "--map",
            "id=Point,x=X [mm],y=Y [mm]",
            "--commanded",
            s(&cmd),
            "--first-id",
            "18446744073709551615",
            "--out",
            s(&out),
        ],
        &[
            "--first-id 18446744073709551615",
            "numbered past 18446744073709551615",
        ],
        &out,
    );
    // The largest number is a point number like any other.
    let (one, xy1) = session(d, 1, true);
    let e1 = export(d, "e1.csv", "Point;X [mm];Y [mm]", &xy1, 1.0, "P", u64::MAX);
    let (ok, stdout, stderr) = import(&[
        "--export",
        s(&e1),
        "--map",
        "id=Point,x=X [mm],y=Y [mm]",
        "--commanded",
        s(&one),
        "--first-id",
        "18446744073709551615",
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("\"imported\": 1"), "{stdout}");
    // Ids such as #1, #2 are points, not comments.
    let (cmd, xy) = session(d, 6, true);
    let hash = export(d, "hash.csv", "Point;X [mm];Y [mm]", &xy, 1.0, "#", 1);
    let (ok, stdout, stderr) = import(&[
        "--export",
        s(&hash),
        "--map",
        "id=Point,x=X [mm],y=Y [mm]",
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("\"imported\": 6"), "{stdout}");
}

#[test]
fn units_are_read_from_headers_and_a_flag_and_an_ambiguous_scale_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.csv");
    let (cmd, xy) = session(d, 12, true);
    let map = "id=Point,x=X,y=Y";
    let mm = import(&[
        "--export",
        s(&export(d, "mm.csv", "Point;X;Y", &xy, 1.0, "P", 1)),
        "--map",
        map,
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(
        mm.0 && mm.2.contains("mm, as the points' spread says"),
        "{}",
        mm.2
    );
    let want = std::fs::read_to_string(&out).unwrap();
    // µm in the header, and µm by the flag: the same measurements.
    let um = export(d, "um.csv", "Point;X [um];Y [um]", &xy, 1000.0, "P", 1);
    let (ok, _, stderr) = import(&[
        "--export",
        s(&um),
        "--map",
        "id=Point,x=X [um],y=Y [um]",
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(
        ok && stderr.contains("unit um, from the header"),
        "{stderr}"
    );
    assert_eq!(std::fs::read_to_string(&out).unwrap(), want);
    let um_bare = export(d, "um_bare.csv", "Point;X;Y", &xy, 1000.0, "P", 1);
    let (ok, _, stderr) = import(&[
        "--export",
        s(&um_bare),
        "--map",
        map,
        "--units",
        "um",
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), want);
    std::fs::remove_file(&out).unwrap();
    // No unit anywhere and only angles in the list (no targets to compare): the spread
    // against the workspace decides, and µm or metres are refused with the evidence.
    let (angles, _) = session(d, 12, false);
    refused(
        &[
            "import",
            "--export",
            s(&um_bare),
            "--map",
            map,
            "--commanded",
            s(&angles),
            "--out",
            s(&out),
        ],
        &[
            "as mm the points spread",
            "the machine's workspace is 180.3 mm across",
            "looks like um: give --units um",
        ],
        &out,
    );
    let metres = export(d, "m_bare.csv", "Point;X;Y", &xy, 1e-3, "P", 1);
    refused(
        &[
            "import",
            "--export",
            s(&metres),
            "--map",
            map,
            "--commanded",
            s(&angles),
            "--out",
            s(&out),
        ],
        &["looks like m: give --units m"],
        &out,
    );
}

#[test]
fn latin1_and_utf16_exports_are_decoded_and_other_files_refused_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.csv");
    let (cmd, xy) = session(d, 8, true);
    let mut text = String::from("Job;Messung\nPoint;X [mm];Y [mm];H\n");
    for (k, p) in xy.iter().enumerate() {
        text.push_str(&format!("P{};{};{};0\n", k + 1, p[0], p[1]));
    }
    // Latin-1: a 'ö' as the one byte 0xF6 in the metadata and a µ (0xB5) in a column.
    let latin1: Vec<u8> = text
        .replace("Messung", "Höhe")
        .replace(";H\n", ";H [µm]\n")
        .chars()
        .map(|c| c as u32 as u8)
        .collect();
    let e = d.join("latin1.csv");
    std::fs::write(&e, &latin1).unwrap();
    let map = "id=Point,x=X [mm],y=Y [mm]";
    let (ok, stdout, stderr) = import(&[
        "--export",
        s(&e),
        "--map",
        map,
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("not UTF-8 from line 1 on: read as Latin-1"),
        "{stderr}"
    );
    assert!(stdout.contains("H [µm]"), "{stdout}");
    let utf16: Vec<u8> = [0xFF, 0xFE]
        .into_iter()
        .chain(text.encode_utf16().flat_map(u16::to_le_bytes))
        .collect();
    let e16 = d.join("utf16.csv");
    std::fs::write(&e16, utf16).unwrap();
    let (ok, _, stderr) = import(&[
        "--export",
        s(&e16),
        "--map",
        map,
        "--commanded",
        s(&cmd),
        "--out",
        s(&out),
    ]);
    assert!(ok && stderr.contains("UTF-16 LE file, decoded"), "{stderr}");
    // A measurement CSV is the tools' own format, UTF-8: refused naming the line.
    let bad = d.join("fm.csv");
    let mut bytes = b"theta1_deg,theta2_deg,x_mm,y_mm\n45,-45,212.1,0\n".to_vec();
    bytes.extend(b"45,-45,212.1,0 \xB5\n");
    std::fs::write(&bad, bytes).unwrap();
    let model = d.join("fit.json");
    refused(
        &[
            "fit",
            "--data",
            s(&bad),
            "--method",
            "ls",
            "--out",
            s(&model),
        ],
        &["line 3: not UTF-8 text (byte 0xB5); the file looks like Latin-1"],
        &model,
    );
}

#[test]
fn an_export_is_read_within_stated_limits() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("m.csv");
    let (cmd, _) = session(d, 2, true);
    let map = "id=Point,x=X [mm],y=Y [mm]";
    // 200 MB (sparse: no disk used): refused before a byte is read.
    let big = d.join("big.csv");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(200_000_000)
        .unwrap();
    refused(
        &[
            "import",
            "--export",
            s(&big),
            "--map",
            map,
            "--commanded",
            s(&cmd),
            "--out",
            s(&out),
        ],
        &["the file is 200000000 bytes; at most 67108864 are read"],
        &out,
    );
    // One line of 100 kB: refused naming the line.
    let long = d.join("long.csv");
    std::fs::write(
        &long,
        format!("Point;X [mm];Y [mm]\nP1;1;{}\n", "2".repeat(100_000)),
    )
    .unwrap();
    refused(
        &[
            "import",
            "--export",
            s(&long),
            "--map",
            map,
            "--commanded",
            s(&cmd),
            "--out",
            s(&out),
        ],
        &["line 2: longer than 65536 bytes"],
        &out,
    );
    // More points than any session: refused at the first one too many.
    let mut many = String::from("Point;X [mm];Y [mm]\n");
    for k in 0..200_001 {
        many.push_str(&format!("P{};200;0\n", k % 2 + 1));
    }
    let many_path = d.join("many.csv");
    std::fs::write(&many_path, many).unwrap();
    refused(
        &[
            "import",
            "--export",
            s(&many_path),
            "--map",
            map,
            "--commanded",
            s(&cmd),
            "--out",
            s(&out),
        ],
        &["line 200002: more than 200000 points"],
        &out,
    );
}

fn ok(args: &[&str]) -> (String, String) {
    let (success, stdout, stderr) = run(args);
    assert!(success, "{args:?} failed: {stderr}");
    (stdout, stderr)
}

fn second() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/second.toml")
}

fn second_plant() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("plants/second.toml")
}

/// A model, grid nodes and a grid image of `machine` (with its `plant`), made by the binary.
fn calibrated(dir: &Path, machine: &Path, plant: &str, tag: &str) -> [PathBuf; 4] {
    let f = |n: &str| dir.join(format!("{tag}_{n}"));
    let m = ["--machine", s(machine)];
    let plan = f("plan");
    ok(&[&["plan", "--out", s(&plan)][..], &m].concat());
    let measure = |list: &str, extra: &[&str], out: &Path| {
        let l = plan.join(list);
        ok(&[
            &[
                "measure",
                "--plant",
                plant,
                "--noise-um",
                "1",
                "--targets",
                s(&l),
                "--out",
                s(out),
            ][..],
            &m,
            extra,
        ]
        .concat());
    };
    let (fit, model, nodes, grid) = (f("fit.csv"), f("model.json"), f("nodes.csv"), f("grid.bin"));
    measure("identify.csv", &[], &fit);
    ok(&[
        &[
            "fit",
            "--data",
            s(&fit),
            "--method",
            "full",
            "--no-loo",
            "--out",
            s(&model),
        ][..],
        &m,
    ]
    .concat());
    measure("grid.csv", &["--model", s(&model)], &nodes);
    ok(&[
        &[
            "grid",
            "--model",
            s(&model),
            "--data",
            s(&nodes),
            "--out",
            s(&grid),
        ][..],
        &m,
    ]
    .concat());
    [fit, model, nodes, grid]
}

#[test]
fn every_file_knows_its_machine_and_another_machines_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let paper = Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/paper.toml");
    let [p_fit, p_model, _, p_grid] = calibrated(d, &paper, "paper", "p");
    let [s_fit, s_model, s_nodes, _] = calibrated(d, &second(), s(&second_plant()), "s");
    // What the tools write names the machine.
    let text = std::fs::read_to_string(&p_fit).unwrap();
    assert!(
        text.starts_with("# machine=paper digest="),
        "{}",
        &text[..60]
    );
    let model: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&s_model).unwrap()).unwrap();
    assert_eq!(model["machine"]["name"], "second");
    assert_eq!(model["machine"]["digest"].as_str().unwrap().len(), 8);
    let out = d.join("out.csv");
    let targets = d.join("s_plan/verify.csv");
    // command on the second machine with the paper's grid; the second's model on the paper.
    refused(
        &[
            "command",
            "--machine",
            s(&second()),
            "--grid",
            s(&p_grid),
            "--targets",
            s(&targets),
            "--out",
            s(&out),
        ],
        &[
            "p_grid.bin",
            "built for machine 'paper'",
            "this is machine 'second'",
        ],
        &out,
    );
    let p_targets = d.join("p_plan/verify.csv");
    refused(
        &[
            "command",
            "--model",
            s(&s_model),
            "--targets",
            s(&p_targets),
            "--out",
            s(&out),
        ],
        &[
            "--model",
            "is of machine 'second'",
            "the default machine (no --machine given) is machine 'paper'",
        ],
        &out,
    );
    // measure on the second machine and plant through the paper's grid.
    refused(
        &[
            "measure",
            "--machine",
            s(&second()),
            "--plant",
            s(&second_plant()),
            "--targets",
            s(&targets),
            "--grid",
            s(&p_grid),
            "--out",
            s(&out),
        ],
        &[
            "p_grid.bin",
            "built for machine 'paper'",
            "this is machine 'second'",
        ],
        &out,
    );
    // grid on the second machine with the paper's model and the second's data.
    let image = d.join("g.bin");
    refused(
        &[
            "grid",
            "--machine",
            s(&second()),
            "--model",
            s(&p_model),
            "--data",
            s(&s_nodes),
            "--out",
            s(&image),
        ],
        &[
            "--model",
            "is of machine 'paper'",
            &format!("--machine {} is machine 'second'", s(&second())),
        ],
        &image,
    );
    // fit, verify and accuracy on the second machine with the paper's measurements.
    let m = d.join("m.json");
    refused(
        &[
            "fit",
            "--machine",
            s(&second()),
            "--data",
            s(&p_fit),
            "--method",
            "full",
            "--out",
            s(&m),
        ],
        &["--data", "is of machine 'paper'"],
        &m,
    );
    let html = d.join("r.html");
    refused(
        &[
            "verify",
            "--machine",
            s(&second()),
            "--after-verify",
            s(&p_fit),
            "--after-repeat",
            s(&p_fit),
            "--out",
            s(&html),
        ],
        &["--after-verify", "is of machine 'paper'"],
        &html,
    );
    // The right machine's files are taken; a file from before machines were named gets a note.
    ok(&[
        "fit",
        "--machine",
        s(&second()),
        "--data",
        s(&s_fit),
        "--method",
        "full",
        "--no-loo",
        "--out",
        s(&m),
    ]);
    let table1 = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/table1.csv");
    let (_, stderr) = ok(&[
        "fit",
        "--data",
        s(&table1),
        "--method",
        "ls",
        "--out",
        s(&m),
    ]);
    assert!(
        stderr.contains(
            "names no machine (written before files carried one): taken as machine 'paper'"
        ),
        "{stderr}"
    );
    // A model without its machine (an older file) of another geometry is still refused.
    let mut old: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&s_model).unwrap()).unwrap();
    old.as_object_mut().unwrap().remove("machine");
    let old_model = d.join("old.json");
    std::fs::write(&old_model, old.to_string()).unwrap();
    refused(
        &[
            "command",
            "--model",
            s(&old_model),
            "--targets",
            s(&p_targets),
            "--out",
            s(&out),
        ],
        &[
            "names no machine",
            "a_mm = 120.",
            "it is a model of another machine",
        ],
        &out,
    );
}

#[test]
fn errors_say_what_the_file_is_and_what_to_do_next() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let paper = Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/paper.toml");
    let [fit, model, _, grid] = calibrated(d, &paper, "paper", "p");
    let m = d.join("m.json");
    // A plan's list given to fit: it is a plan, measure it first.
    let plan = d.join("p_plan/identify.csv");
    refused(
        &[
            "fit",
            "--data",
            s(&plan),
            "--method",
            "full",
            "--out",
            s(&m),
        ],
        &["this is a plan's target list", "measure it first"],
        &m,
    );
    // A CSV given as --model: not a model file.
    let out = d.join("angles.csv");
    let targets = d.join("p_plan/verify.csv");
    refused(
        &[
            "command",
            "--model",
            s(&fit),
            "--targets",
            s(&targets),
            "--out",
            s(&out),
        ],
        &[
            "is not a valid model file: it is not JSON",
            "a CSV table?",
            "the model.json that `host-sim fit` writes",
        ],
        &out,
    );
    // One target outside the grid image's workspace: which one, the polygon to the µm, what to do.
    let t = d.join("t.csv");
    std::fs::write(&t, "x_mm,y_mm\n200,0\n300,0\n210,5\n").unwrap();
    let (success, _, stderr) = run(&[
        "command",
        "--model",
        s(&model),
        "--grid",
        s(&grid),
        "--targets",
        s(&t),
        "--out",
        s(&out),
    ]);
    assert!(!success);
    assert!(
        stderr.contains("line 3: target (300, 0) is outside the workspace")
            && stderr.contains("(162.132, -75.000)")
            && stderr.contains("move or remove that target"),
        "{stderr}"
    );
    assert!(!stderr.contains("162.1320037841797"), "{stderr}");
    assert!(!out.exists());
    // diagnose --out-model refuses what fit refuses: the same data in metres.
    let text = std::fs::read_to_string(&fit).unwrap();
    let mut metres = String::new();
    for (k, line) in text.lines().enumerate() {
        if k < 2 {
            metres.push_str(line);
        } else {
            let f: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
            let row: Vec<String> = f
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    if i == 2 || i == 3 {
                        format!("{}", v / 1000.0)
                    } else {
                        format!("{v}")
                    }
                })
                .collect();
            metres.push_str(&row.join(","));
        }
        metres.push('\n');
    }
    let mdata = d.join("metres.csv");
    std::fs::write(&mdata, metres).unwrap();
    let (report, extended) = (d.join("d.json"), d.join("dm.json"));
    let (success, _, stderr) = run(&[
        "diagnose",
        "--data",
        s(&mdata),
        "--out",
        s(&report),
        "--out-model",
        s(&extended),
    ]);
    assert!(!success && stderr.contains("metres"), "{stderr}");
    assert!(!report.exists() && !extended.exists());
    // accuracy: a table for a person on stderr, the JSON on stdout.
    let rep = d.join("rep.csv");
    let list = d.join("p_plan/repeat.csv");
    ok(&[
        "measure",
        "--plant",
        "paper",
        "--noise-um",
        "1",
        "--targets",
        s(&list),
        "--out",
        s(&rep),
    ]);
    let (stdout, stderr) = ok(&["accuracy", "--data", s(&rep)]);
    assert!(
        stderr.contains("accuracy: 2 axis line(s) of machine 'paper'"),
        "{stderr}"
    );
    assert!(
        stderr.contains("| ") && stderr.lines().count() <= 8,
        "{stderr}"
    );
    serde_json::from_str::<serde_json::Value>(&stdout).unwrap();
}
