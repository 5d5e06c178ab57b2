//! `host-sim verify` end to end on the simulated paper machine, through the binary as a
//! machine builder runs it: plan → measure the identification poses → fit → measure the
//! plan's verification targets and repeat runs with the nominal model (before) and with the
//! fitted model (after) → verify. The report must show the calibration: every headline figure
//! smaller after than before, the page self-contained (its plots embedded PNGs), and bad input
//! refused with a clear message, a non-zero exit and no output touched.
//!
//! (The grid is left out to keep the test cheap: `full` alone takes the paper machine from
//! ~3.5 mm to ~12 µm in the machine frame; the figures' arithmetic is tested on hand-computed tables in
//! `src/calib/verify/tests.rs`.)

use base64::Engine as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn fails(args: &[&str], want: &str) {
    let out = run(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    assert!(stderr.contains(want), "{args:?}: '{stderr}' lacks '{want}'");
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The measurements of the two states: (before verify, before repeat, after verify, after repeat).
fn measure_both(d: &Path) -> [PathBuf; 4] {
    let p = |n: &str| d.join(n);
    ok(&["plan", "--seed", "1", "--out", s(&p("plan"))]);
    let measure = |list: &str, model: Option<&Path>, seed: &str, out: &Path| {
        let t = p(list);
        let mut a = vec![
            "measure",
            "--plant",
            "paper",
            "--noise-um",
            "1",
            "--targets",
            s(&t),
            "--seed",
            seed,
            "--out",
            s(out),
        ];
        if let Some(m) = model {
            a.extend(["--model", s(m)]);
        }
        ok(&a);
    };
    measure("plan/identify.csv", None, "11", &p("fit.csv"));
    ok(&[
        "fit",
        "--data",
        s(&p("fit.csv")),
        "--method",
        "full",
        "--no-loo",
        "--out",
        s(&p("model.json")),
    ]);
    let files = [
        p("v_before.csv"),
        p("r_before.csv"),
        p("v_after.csv"),
        p("r_after.csv"),
    ];
    measure("plan/verify.csv", None, "12", &files[0]);
    measure("plan/repeat.csv", None, "13", &files[1]);
    measure("plan/verify.csv", Some(&p("model.json")), "14", &files[2]);
    measure("plan/repeat.csv", Some(&p("model.json")), "15", &files[3]);
    files
}

#[test]
fn the_report_shows_the_calibration_on_the_paper_machine() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let [vb, rb, va, ra] = measure_both(d);
    let (html, json) = (
        d.join("report/accuracy.html"),
        d.join("report/accuracy.json"),
    );
    let stdout = ok(&[
        "verify",
        "--before-verify",
        s(&vb),
        "--before-repeat",
        s(&rb),
        "--after-verify",
        s(&va),
        "--after-repeat",
        s(&ra),
        "--instrument-frame",
        s(&d.join("model.json")),
        "--out",
        s(&html),
        "--json",
        s(&json),
    ]);
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(
        r,
        serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(&json).unwrap())
            .unwrap()
    );
    assert_eq!(r["machine"], "paper");
    let stage = |k: usize| &r["stages"][k];
    assert_eq!(
        (stage(0)["stage"].as_str(), stage(1)["stage"].as_str()),
        (Some("before"), Some("after"))
    );
    let pos = |k: usize, f: &str| stage(k)["position"][f].as_f64().unwrap();
    eprintln!(
        "2-D position error before {} / {} µm, after {} / {} µm",
        pos(0, "max_um"),
        pos(0, "rms_um"),
        pos(1, "max_um"),
        pos(1, "rms_um")
    );
    // In the machine frame the fit registered (one instrument set-up for all four files):
    // before, the nominal five-bar, ~3.5 mm off; after the full fit: tens of µm at most.
    assert!(
        pos(0, "max_um") > 1000.0 && pos(0, "rms_um") > 400.0,
        "{}",
        stage(0)["position"]
    );
    assert!(
        pos(1, "max_um") < 30.0 && pos(1, "rms_um") < 10.0,
        "{}",
        stage(1)["position"]
    );
    assert_eq!(stage(1)["position"]["n_points"], 400);
    // Both axis lines of the plan's repeat runs, 5 runs each way at every target.
    for k in 0..2 {
        let lines = stage(k)["lines"].as_array().unwrap();
        let axes: Vec<&str> = lines.iter().map(|l| l["axis"].as_str().unwrap()).collect();
        assert_eq!(axes, ["x", "y"]);
        for l in lines {
            assert_eq!(l["targets"].as_array().unwrap().len(), 11);
            assert!(
                l["targets"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .all(|t| t["n_up"] == 5 && t["n_down"] == 5),
                "{l}"
            );
        }
    }
    // The y line (x = centre) carries the nominal model's error: A, E and P drop a lot; the
    // position error drops more than 20x.
    for ratio in r["improvement"]["ratios"].as_array().unwrap() {
        let (f, factor) = (
            ratio["figure"].as_str().unwrap(),
            ratio["factor"].as_f64().unwrap(),
        );
        eprintln!(
            "{f}: {} -> {} µm ({factor:.1}x)",
            ratio["before_um"], ratio["after_um"]
        );
        if f.starts_with("position") {
            assert!(factor > 20.0, "{ratio}");
        }
        if f.starts_with("y line") && (f.ends_with(" A") || f.ends_with(" E") || f.ends_with(" P"))
        {
            assert!(factor > 5.0, "{ratio}");
        }
    }
    assert!(r["notes"].as_array().unwrap().is_empty(), "{}", r["notes"]);

    // The page: self-contained, 2 maps + 2 ISO 230-2 charts, each a PNG.
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(page.starts_with("<!DOCTYPE html>") && page.trim_end().ends_with("</html>"));
    assert!(
        !page.contains("src=\"http") && !page.contains("<script"),
        "external content"
    );
    let pngs: Vec<Vec<u8>> = page
        .split("src=\"data:image/png;base64,")
        .skip(1)
        .map(|rest| {
            base64::engine::general_purpose::STANDARD
                .decode(&rest[..rest.find('"').unwrap()])
                .unwrap()
        })
        .collect();
    assert_eq!(pngs.len(), 4);
    assert!(pngs.iter().all(|b| b.starts_with(b"\x89PNG\r\n\x1a\n")));
    for text in [
        "Summary",
        "x line at y = 0 mm",
        "y line at x = 212.132 mm",
        "ISO 230-2 accuracy A",
        "VDI 3441 positioning uncertainty P",
        "before calibration",
        "after calibration",
    ] {
        assert!(page.contains(text), "the page lacks '{text}'");
    }
    // Only the after state: a report of the delivered machine.
    let only_after = d.join("after.html");
    let r: serde_json::Value = serde_json::from_str(&ok(&[
        "verify",
        "--after-verify",
        s(&va),
        "--after-repeat",
        s(&ra),
        "--out",
        s(&only_after),
    ]))
    .unwrap();
    assert_eq!(r["stages"].as_array().unwrap().len(), 1);
    assert!(r["improvement"].is_null());
    assert!(std::fs::read_to_string(&only_after)
        .unwrap()
        .contains("after calibration"));
}

#[test]
fn bad_input_is_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let w = |name: &str, text: &str| {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let head = "theta1_deg,theta2_deg,x_mm,y_mm,x_target_mm,y_target_mm,run\n";
    // Repeat runs along x at y = 0 and y at x = 212: 2 runs, each pass up then down.
    let mut repeat = String::from(head);
    let mut only_up = String::from(head);
    for run in 0..2 {
        for (axis, line) in [(0, [170.0, 200.0, 230.0]), (1, [-30.0, 0.5, 30.0])] {
            let at = |v: f64| if axis == 0 { (v, 0.0) } else { (212.0, v) };
            let pass: Vec<f64> = line.iter().chain(line.iter().rev()).cloned().collect();
            for (k, v) in pass.iter().enumerate() {
                let (x, y) = at(*v);
                let dev = 0.001 * (k as f64 + run as f64);
                let row = format!("0,0,{},{},{x},{y},{run}\n", x + dev, y + dev);
                repeat.push_str(&row);
                if k < 3 {
                    only_up.push_str(&row);
                }
            }
        }
    }
    let verify = w(
        "v.csv",
        &format!("{head}0,0,200.001,0.002,200,0,0\n0,0,210,10,210,10,0\n"),
    );
    let rep = w("r.csv", &repeat);
    let out = d.join("report.html");
    // The inputs work (2 runs: a note that ISO 230-2 asks for 5).
    let v: serde_json::Value = serde_json::from_str(&ok(&[
        "verify",
        "--after-verify",
        s(&verify),
        "--after-repeat",
        s(&rep),
        "--out",
        s(&out),
    ]))
    .unwrap();
    assert!(
        v["notes"][0]
            .as_str()
            .unwrap()
            .contains("ISO 230-2 asks for 5"),
        "{v}"
    );
    // From now on every run fails and the report already there stays as it is.
    std::fs::write(&out, "the previous report").unwrap();
    let json = d.join("r.json");
    let verify_with = |v: &Path, r: &Path, want: &str| {
        fails(
            &[
                "verify",
                "--after-verify",
                s(v),
                "--after-repeat",
                s(r),
                "--out",
                s(&out),
                "--json",
                s(&json),
            ],
            want,
        );
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            "the previous report"
        );
        assert!(!json.exists());
    };
    verify_with(&verify, &w("up.csv", &only_up), "after, repeat runs: no axis line has at least 2 targets with 2 approaches from each direction");
    let one_run: String = repeat
        .lines()
        .filter(|l| !l.ends_with(",1"))
        .map(|l| format!("{l}\n"))
        .collect();
    verify_with(
        &verify,
        &w("one.csv", &one_run),
        "has 1 approaches in + and 1 in − direction; each needs at least 2",
    );
    verify_with(
        &w("nan.csv", &format!("{head}0,0,NaN,0,200,0,0\n")),
        &rep,
        "line 2: 'x_mm' = 'NaN' is not finite",
    );
    verify_with(
        &w(
            "untargeted.csv",
            "theta1_deg,theta2_deg,x_mm,y_mm\n0,0,200,0\n",
        ),
        &rep,
        "line 2: every row needs its target",
    );
    let runless = w(
        "runless.csv",
        &repeat
            .lines()
            .map(|l| format!("{}\n", l.rsplit_once(',').unwrap().0))
            .collect::<String>(),
    );
    verify_with(
        &verify,
        &runless,
        "every row of the repeat runs needs its run",
    );
    verify_with(&w("empty.csv", head), &rep, "no data rows after the header");
    verify_with(&d.join("missing.csv"), &rep, "cannot read");
    // Flags: a before stage needs both files; an output must not overwrite an input.
    fails(
        &[
            "verify",
            "--after-verify",
            s(&verify),
            "--after-repeat",
            s(&rep),
            "--before-verify",
            s(&verify),
            "--out",
            s(&out),
        ],
        "--before-repeat",
    );
    fails(
        &[
            "verify",
            "--after-verify",
            s(&verify),
            "--after-repeat",
            s(&rep),
            "--out",
            s(&rep),
        ],
        "is the file of the input --after-repeat",
    );
    assert_eq!(
        std::fs::read_to_string(&out).unwrap(),
        "the previous report"
    );
}
