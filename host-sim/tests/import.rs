//! `host-sim import`, a laser tracker's export joined by point id with the
//! commanded list, through the binary: realistic exports (semicolon with a decimal point, tab,
//! metres, metadata lines, extra columns, a missing point, a repeated reading), every refusal
//! with a non-zero exit, its message and no output written, and the whole path end to end:
//! a simulated session of a plan's list (`measure --plant paper`), rewritten as a tracker
//! export, imported, fits the same model as the direct measurement CSV.

use host_sim::io::measurement_csv::{parse_measurements, Measurement};
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

/// Runs the binary expecting success; returns (stdout, stderr).
fn ok(args: &[&str]) -> (String, String) {
    let (success, stdout, stderr) = run(args);
    assert!(success, "{args:?} failed: {stderr}");
    (stdout, stderr)
}

/// Expects failure with `want` in stderr, no panic, and `out` unchanged (absent or as before).
fn refused(args: &[&str], want: &str, out: &Path) {
    let before = std::fs::read(out).ok();
    let (success, _, stderr) = run(args);
    assert!(!success, "{args:?} succeeded");
    assert!(
        stderr.contains(want),
        "{args:?}: stderr '{stderr}' lacks '{want}'"
    );
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    assert_eq!(
        std::fs::read(out).ok(),
        before,
        "{args:?} wrote {}",
        out.display()
    );
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text).unwrap()
}

fn read_rows(p: &Path) -> Vec<Measurement> {
    parse_measurements(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// A commanded list as `command` writes it: 5 targets on a 10 mm line, made-up angles.
const COMMANDED: &str = "x_mm,y_mm,theta1_deg,theta2_deg\n\
200,0,30.000000000,150.000000000\n\
210,0,31.000000000,151.000000000\n\
220,0,32.000000000,152.000000000\n\
220,10,33.000000000,153.000000000\n\
210,10,34.000000000,154.000000000\n";

/// A tracker's export of that session, as a European AT-style job file: metadata on top,
/// semicolons, a decimal point, an RMS column, point 4 lost, point 2 read twice, in an
/// instrument frame shifted by (0.5, −0.25) mm and 12.3 mm up.
const SEMICOLON_EXPORT: &str = "Job;cal-2026-11-23\n\
Instrument;AT960 SN 1234\n\
Operator;me\n\
\n\
Point;X [mm];Y [mm];Z [mm];RMS [mm]\n\
P001;200.5012;-0.2503;12.3001;0.004\n\
P002;210.4991;-0.2497;12.2999;0.005\n\
P003;220.5008;-0.2511;12.3002;0.004\n\
P005;210.5003;9.7496;12.2998;0.006\n\
P002;210.4995;-0.2502;12.3000;0.004\n";

/// What a row is compared by: angles, measured point, target, run.
type Key = ([f64; 2], [f64; 2], Option<[f64; 2]>, Option<u32>);

#[test]
fn a_semicolon_export_with_metadata_a_missing_point_and_a_repeat() {
    let dir = tempfile::tempdir().unwrap();
    let (export, commanded) = (
        write(dir.path(), "job.csv", SEMICOLON_EXPORT),
        write(dir.path(), "angles.csv", COMMANDED),
    );
    let (out, report) = (dir.path().join("meas.csv"), dir.path().join("import.json"));
    let (stdout, stderr) = ok(&[
        "import",
        "--export",
        s(&export),
        "--map",
        "id=Point,x=X [mm],y=Y [mm],z=Z [mm]",
        "--commanded",
        s(&commanded),
        "--out",
        s(&out),
        "--report",
        s(&report),
    ]);
    // Rows in the list's order, the repeat as run 1, point 4 not written.
    let rows = read_rows(&out);
    let got: Vec<Key> = rows
        .iter()
        .map(|m| (m.theta_deg, m.measured_mm, m.target_mm, m.run))
        .collect();
    assert_eq!(
        got,
        vec![
            (
                [30.0, 150.0],
                [200.5012, -0.2503],
                Some([200.0, 0.0]),
                Some(0)
            ),
            (
                [31.0, 151.0],
                [210.4991, -0.2497],
                Some([210.0, 0.0]),
                Some(0)
            ),
            (
                [31.0, 151.0],
                [210.4995, -0.2502],
                Some([210.0, 0.0]),
                Some(1)
            ),
            (
                [32.0, 152.0],
                [220.5008, -0.2511],
                Some([220.0, 0.0]),
                Some(0)
            ),
            (
                [34.0, 154.0],
                [210.5003, 9.7496],
                Some([210.0, 10.0]),
                Some(0)
            ),
        ]
    );
    for note in [
        "4 line(s) before the header skipped",
        "semicolon-separated",
        "columns ignored: RMS [mm]",
        "unit mm, from the header",
        "1 of the list's 5 rows have no reading (not written): points 4",
        "read more than once",
    ] {
        assert!(stderr.contains(note), "stderr lacks '{note}': {stderr}");
    }
    let r = json(&stdout);
    assert_eq!(r, json(&std::fs::read_to_string(&report).unwrap()));
    assert_eq!(
        (
            r["imported"].as_u64(),
            r["rows_measured"].as_u64(),
            r["list_rows"].as_u64()
        ),
        (Some(5), Some(4), Some(5))
    );
    assert_eq!(r["missing"], serde_json::json!([4]));
    assert_eq!(r["repeated"], serde_json::json!([2]));
    assert_eq!(r["id_prefix"], "P");
    // Z: 12.2998..12.3002 mm, within 0.3 µm of a plane; the frame: a shift only.
    let z = &r["z"];
    assert!(
        (z["range_mm"].as_f64().unwrap() - 0.0004).abs() < 1e-9,
        "{z}"
    );
    assert!(z["plane_residual_max_um"].as_f64().unwrap() < 0.3, "{z}");
    assert!(
        r["frame"]["rigid_residual_max_mm"].as_f64().unwrap() < 0.01,
        "{r}"
    );
    assert_eq!(r["warnings"], serde_json::json!([]));
    // The fit's duplicate check passes: the repeated pose is two rows of different runs.
    host_sim::calib::fit::check_duplicates(&rows).unwrap();
    // The same job exported in a German locale (decimal commas) reads the same with --decimal-comma.
    let german = write(dir.path(), "job_de.csv", &SEMICOLON_EXPORT.lines().map(|l| if l.starts_with('P') { l.replace('.', ",") } else { l.to_string() } + "\n").collect::<String>());
    let out_de = dir.path().join("meas_de.csv");
    ok(&[
        "import",
        "--export",
        s(&german),
        "--map",
        "id=Point,x=X [mm],y=Y [mm],z=Z [mm]",
        "--commanded",
        s(&commanded),
        "--decimal-comma",
        "--out",
        s(&out_de),
    ]);
    assert_eq!(
        std::fs::read(&out_de).unwrap(),
        std::fs::read(&out).unwrap()
    );
    // --require-all: the missing point is an error, nothing written.
    let fresh = dir.path().join("strict.csv");
    refused(
        &[
            "import",
            "--export",
            s(&export),
            "--map",
            "id=Point,x=X [mm],y=Y [mm]",
            "--commanded",
            s(&commanded),
            "--require-all",
            "--out",
            s(&fresh),
        ],
        "1 of the list's 5 rows have no reading: points 4",
        &fresh,
    );
}

#[test]
fn tab_separated_in_metres_with_another_vendors_names() {
    let dir = tempfile::tempdir().unwrap();
    let commanded = write(dir.path(), "angles.csv", COMMANDED);
    // Unit from the header.
    let export = write(dir.path(), "e.txt", "Name\tX [m]\tY [m]\tTime\n1\t0.2005\t-0.00025\t10:00:01\n2\t0.2105\t-0.00025\t10:00:05\n3\t0.2205\t-0.00025\t10:00:09\n4\t0.2205\t0.00975\t10:00:13\n5\t0.2105\t0.00975\t10:00:17\n");
    let out = dir.path().join("m.csv");
    let (_, stderr) = ok(&[
        "import",
        "--export",
        s(&export),
        "--map",
        "id=Name,x=X [m],y=Y [m]",
        "--commanded",
        s(&commanded),
        "--out",
        s(&out),
    ]);
    assert!(
        stderr.contains("tab-separated")
            && stderr.contains("unit m, from the header")
            && stderr.contains("columns ignored: Time"),
        "{stderr}"
    );
    let rows = read_rows(&out);
    assert_eq!(rows.len(), 5);
    for (m, want) in rows.iter().zip([
        [200.5, -0.25],
        [210.5, -0.25],
        [220.5, -0.25],
        [220.5, 9.75],
        [210.5, 9.75],
    ]) {
        assert!(
            (m.measured_mm[0] - want[0]).abs() < 1e-9 && (m.measured_mm[1] - want[1]).abs() < 1e-9,
            "{:?} vs {want:?}",
            m.measured_mm
        );
    }
    // No unit in the header: --units m says it; without it the scale check names the mistake.
    let bare = write(dir.path(), "bare.csv", "Name,X,Y\nA1,0.2005,-0.00025\nA2,0.2105,-0.00025\nA3,0.2205,-0.00025\nA4,0.2205,0.00975\nA5,0.2105,0.00975\n");
    let out2 = dir.path().join("m2.csv");
    ok(&[
        "import",
        "--export",
        s(&bare),
        "--map",
        "id=Name,x=X,y=Y",
        "--commanded",
        s(&commanded),
        "--units",
        "m",
        "--out",
        s(&out2),
    ]);
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&out2).unwrap());
    let out3 = dir.path().join("m3.csv");
    refused(
        &[
            "import",
            "--export",
            s(&bare),
            "--map",
            "id=Name,x=X,y=Y",
            "--commanded",
            s(&commanded),
            "--out",
            s(&out3),
        ],
        "the export looks like m: give --units m",
        &out3,
    );
    // A header that says m and --units mm contradict.
    refused(
        &[
            "import",
            "--export",
            s(&export),
            "--map",
            "id=Name,x=X [m],y=Y [m]",
            "--commanded",
            s(&commanded),
            "--units",
            "mm",
            "--out",
            s(&out3),
        ],
        "column 'X [m]' says m but the unit given is mm",
        &out3,
    );
}

#[test]
fn bad_exports_are_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let commanded = write(dir.path(), "angles.csv", COMMANDED);
    let good = write(dir.path(), "job.csv", SEMICOLON_EXPORT);
    let out = dir.path().join("meas.csv");
    // An earlier output is not clobbered by a failing run.
    std::fs::write(&out, "theta1_deg,theta2_deg,x_mm,y_mm\n1,2,3,4\n").unwrap();
    let map = "id=Point,x=X [mm],y=Y [mm]";
    let import = |export: &Path, map: &str, extra: &[&str], want: &str| {
        let mut args = vec![
            "import",
            "--export",
            s(export),
            "--map",
            map,
            "--commanded",
            s(&commanded),
            "--out",
            s(&out),
        ];
        args.extend_from_slice(extra);
        refused(&args, want, &out);
    };
    let edit = |name: &str, from: &str, to: &str| {
        write(dir.path(), name, &SEMICOLON_EXPORT.replacen(from, to, 1))
    };
    // The column map names a column the export does not have: the header it found is listed.
    import(&good, "id=Point,x=X,y=Y [mm]", &[], "the column map names 'X' but no line has it; the header looks like line 5: 'Point', 'X [mm]', 'Y [mm]', 'Z [mm]', 'RMS [mm]'");
    import(&good, "id=Point,x=X [mm]", &[], "'y=COLUMN' is missing");
    // Cells that are not numbers, NaN, a decimal comma: the line and column named.
    import(
        &edit("text.csv", "210.4991", "n/a"),
        map,
        &[],
        "line 7: 'X [mm]' = 'n/a' is not a number",
    );
    import(
        &edit("nan.csv", "-0.2511", "NaN"),
        map,
        &[],
        "line 8: 'Y [mm]' = 'NaN' is not finite",
    );
    import(
        &edit("comma.csv", "210.4991", "210,4991"),
        map,
        &[],
        "(a decimal comma? write a point)",
    );
    // A point that is no row of the list, and mixed prefixes.
    import(
        &edit("p9.csv", "P005", "P009"),
        map,
        &[],
        "line 9: point 'P009' is number 9, but the list's rows are numbers 1..=5",
    );
    import(
        &edit("ref.csv", "P003", "REF3"),
        map,
        &[],
        "point ids with different prefixes: 'P' (line 6) and 'REF' (line 8)",
    );
    // Z off the plane beyond a tolerance.
    let zmap = "id=Point,x=X [mm],y=Y [mm],z=Z [mm]";
    import(&edit("z.csv", "12.3000", "12.5000"), zmap, &["--z-tolerance-mm", "0.05"], "line 10: point 'P002' is 0.1500 mm off the best-fit plane of the points' Z, above the tolerance 0.05 mm");
    import(
        &good,
        map,
        &["--z-tolerance-mm", "0.05"],
        "--z-tolerance-mm needs a z column",
    );
    // A plan list that is not the commanded list's.
    let plan = write(dir.path(), "plan.csv", "x_mm,y_mm,run\n200,0,0\n210,0,0\n");
    import(
        &good,
        map,
        &["--plan", s(&plan)],
        "the plan list and the commanded list differ: 2 plan rows, 5 commanded",
    );
    // The output may not be an input.
    let args = [
        "import",
        "--export",
        s(&good),
        "--map",
        map,
        "--commanded",
        s(&commanded),
        "--out",
        s(&commanded),
    ];
    refused(&args, "is the file of the input --commanded", &commanded);
    // The same exports with the right options import.
    ok(&[
        "import",
        "--export",
        s(&edit("p9b.csv", "P005", "P009")),
        "--map",
        map,
        "--commanded",
        s(&commanded),
        "--skip-unlisted",
        "--out",
        s(&dir.path().join("ok1.csv")),
    ]);
    let (stdout, _) = ok(&[
        "import",
        "--export",
        s(&edit("refb.csv", "P003", "REF3")),
        "--map",
        map,
        "--commanded",
        s(&commanded),
        "--id-prefix",
        "P",
        "--out",
        s(&dir.path().join("ok2.csv")),
    ]);
    assert_eq!(json(&stdout)["skipped"], serde_json::json!(["REF3"]));
    assert_eq!(json(&stdout)["missing"], serde_json::json!([3, 4]));
}

/// One row of a measurement CSV as text fields, by column name.
fn columns(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    (
        header,
        lines
            .map(|l| l.split(',').map(String::from).collect())
            .collect(),
    )
}

#[test]
fn a_simulated_session_through_a_tracker_export_fits_the_same_model() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n);
    ok(&["plan", "--seed", "1", "--out", s(&d("plan"))]);
    let list = d("plan").join("identify.csv");
    ok(&[
        "measure",
        "--plant",
        "paper",
        "--noise-um",
        "1",
        "--targets",
        s(&list),
        "--seed",
        "11",
        "--out",
        s(&d("direct.csv")),
    ]);
    // The session as a tracker and the controller would have recorded it: the commanded list
    // (angles, target, directions, in list order) and the tracker's export (its own ids, its
    // own column names, semicolons, metadata, an RMS column, a Z column, the points in another
    // order; the coordinates as the instrument read them).
    let (header, rows) = columns(&std::fs::read_to_string(d("direct.csv")).unwrap());
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let mut commanded = String::from("x_mm,y_mm,theta1_deg,theta2_deg,dir1,dir2\n");
    for r in &rows {
        let f = |n: &str| r[col(n)].as_str();
        commanded.push_str(&format!(
            "{},{},{},{},{},{}\n",
            f("x_target_mm"),
            f("y_target_mm"),
            f("theta1_deg"),
            f("theta2_deg"),
            f("dir1"),
            f("dir2")
        ));
    }
    let mut export =
        String::from("Job;identify\nDate;2026-11-23\nPoint;RMS [mm];X [mm];Y [mm];Z [mm]\n");
    let n = rows.len();
    for k in (0..n).map(|i| (i * 7) % n) {
        let r = &rows[k];
        export.push_str(&format!(
            "P{:03};0.003;{};{};{}\n",
            k + 1,
            r[col("x_mm")],
            r[col("y_mm")],
            25.0 + 1e-4 * ((k % 3) as f64 - 1.0)
        ));
    }
    assert_eq!(n, 40, "identify.csv has 40 poses");
    write(dir.path(), "angles.csv", &commanded);
    write(dir.path(), "export.csv", &export);
    let (stdout, _) = ok(&[
        "import",
        "--export",
        s(&d("export.csv")),
        "--map",
        "id=Point,x=X [mm],y=Y [mm],z=Z [mm]",
        "--commanded",
        s(&d("angles.csv")),
        "--plan",
        s(&list),
        "--z-tolerance-mm",
        "0.01",
        "--out",
        s(&d("imported.csv")),
    ]);
    let r = json(&stdout);
    assert_eq!(
        (
            r["imported"].as_u64(),
            r["missing"].as_array().map(Vec::len)
        ),
        (Some(40), Some(0))
    );
    // The simulated machine's frame against the list's targets: the nominal model's error,
    // about a millimetre, and no warning.
    assert!(
        r["frame"]["rigid_residual_max_mm"].as_f64().unwrap() < 2.0,
        "{r}"
    );
    assert_eq!(r["warnings"], serde_json::json!([]));
    // The imported rows are the direct ones but for the time column.
    let direct = read_rows(&d("direct.csv"));
    let imported = read_rows(&d("imported.csv"));
    assert_eq!(imported.len(), direct.len());
    for (a, b) in imported.iter().zip(&direct) {
        assert_eq!(
            (a.theta_deg, a.measured_mm, a.target_mm, a.dir, a.run),
            (b.theta_deg, b.measured_mm, b.target_mm, b.dir, b.run)
        );
    }
    // And the fit: the same model, to the last digit.
    ok(&[
        "fit",
        "--data",
        s(&d("direct.csv")),
        "--method",
        "full",
        "--no-loo",
        "--out",
        s(&d("direct.json")),
    ]);
    ok(&[
        "fit",
        "--data",
        s(&d("imported.csv")),
        "--method",
        "full",
        "--no-loo",
        "--out",
        s(&d("imported.json")),
    ]);
    assert_eq!(
        std::fs::read_to_string(d("imported.json")).unwrap(),
        std::fs::read_to_string(d("direct.json")).unwrap()
    );
    // `command`'s own output is a commanded list the import reads (the verification list
    // commanded through the fitted model; an export of its first three points).
    ok(&[
        "command",
        "--model",
        s(&d("imported.json")),
        "--targets",
        s(&d("plan").join("verify.csv")),
        "--out",
        s(&d("verify_angles.csv")),
    ]);
    let (_, vrows) = columns(&std::fs::read_to_string(d("verify_angles.csv")).unwrap());
    let mut vexport = String::from("Name,X,Y\n");
    for (k, v) in vrows.iter().take(3).enumerate() {
        vexport.push_str(&format!("V{},{},{}\n", k + 1, v[0], v[1]));
    }
    write(dir.path(), "vexport.csv", &vexport);
    let (stdout, _) = ok(&[
        "import",
        "--export",
        s(&d("vexport.csv")),
        "--map",
        "id=Name,x=X,y=Y",
        "--commanded",
        s(&d("verify_angles.csv")),
        "--out",
        s(&d("v.csv")),
    ]);
    assert_eq!(
        (
            json(&stdout)["imported"].as_u64(),
            json(&stdout)["missing"].as_array().map(Vec::len)
        ),
        (Some(3), Some(397))
    );
}
