//! `host-sim cut`: a part program through the binary (its files, its JSON, bad programs refused
//! with nothing written), the shipped parts' plans against the figures the planner promises,
//! and random programs (property tests: the claims hold for the class, not the examples),
//! some executed on the simulated machine.
//!
//! Kept small for CI (debug build): plans are checked on every part and 16 random programs;
//! three short programs are executed (the five-bar plant model, fast). The full figures on the
//! six-bar plant are `cargo bench -p host-sim --bench cut`.

use host_sim::cut::split::PlanMode;
use host_sim::cut::{parts, plan_program, MachineLimits, Planned};
use host_sim::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use host_sim::plant::{PlantConfig, PlantModel};
use std::path::Path;
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

/// A short program with small features: a hole, a square, a short rapid.
const SMALL: &str =
    "(hole and square)\nG21 G90\nG0 X100 Y100\nM3\nG4 P0.05\nG1 X104 F9000\nG3 I-4 J0\nM5\n\
G0 X120 Y96\nM3\nG1 X136 F9000\nY112\nX120\nY96\nM5\nM30\n";

#[test]
fn a_program_is_cut_with_its_files_and_figures() {
    let dir = tempfile::tempdir().unwrap();
    let prog = dir.path().join("small.nc");
    std::fs::write(&prog, SMALL).unwrap();
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = run(&[
        "cut",
        "--program",
        s(&prog),
        "--plant-model",
        "fivebar",
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let f = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("{k} in {stdout}"));
    assert_eq!(v["plan"], "split", "{stdout}");
    assert!(f("completion_s") < f("gantry_only_s"), "{stdout}");
    assert!(f("bound_s") <= f("completion_s"), "{stdout}");
    assert!(f("contour_max_um") <= 10.0 && f("contour_rms_um") <= f("contour_max_um"));
    assert_eq!(v["micro_inside_workspace"], true);
    assert_eq!(v["within_limits"], true, "{stdout}");
    assert!(
        stderr.contains("gantry alone") && stderr.contains("lower bound"),
        "{stderr}"
    );
    for name in ["part.png", "motion.png", "executed.csv", "report.json"] {
        let bytes = std::fs::read(out.join(name)).unwrap();
        assert!(bytes.len() > 100, "{name}");
    }
    let csv = std::fs::read_to_string(out.join("executed.csv")).unwrap();
    let digest = format!("{:08x}", MachineSpec::paper().record().unwrap().digest());
    assert!(csv.starts_with(&format!(
        "# machine=paper digest={digest} program=small.nc sample_period_s=0.0005"
    )));
    assert_eq!(v["machine"]["digest"], digest.as_str());
    let rows = csv.lines().count() - 2;
    assert_eq!(rows as u64, v["samples"].as_u64().unwrap());
    // The file report is the printed one.
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(file["completion_s"], v["completion_s"]);
}

/// Another machine's file: the micro's ideal plant is built around that machine's five-bar, the
/// part is cut inside its workspace and the files name it.
#[test]
fn a_program_is_cut_on_another_machine() {
    let dir = tempfile::tempdir().unwrap();
    let prog = dir.path().join("small.nc");
    std::fs::write(&prog, SMALL).unwrap();
    let out = dir.path().join("out");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let machine = root.join("machines/second.toml");
    let (ok, stdout, stderr) = run(&[
        "cut",
        "--program",
        s(&prog),
        "--machine",
        s(&machine),
        "--plant-model",
        "fivebar",
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["machine"]["name"], "second", "{stdout}");
    let spec = host_sim::io::machine_file::read_machine(&machine).unwrap();
    let digest = format!("{:08x}", spec.record().unwrap().digest());
    assert_eq!(v["machine"]["digest"], digest.as_str());
    assert_eq!(v["micro_inside_workspace"], true, "{stdout}");
    assert_eq!(v["within_limits"], true, "{stdout}");
    assert!(v["contour_max_um"].as_f64().unwrap() <= 10.0, "{stdout}");
}

#[test]
fn bad_programs_are_refused_naming_the_line_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, &[u8], &str); 6] = [
        (
            "travel.nc",
            b"G0 X100 Y100\nM3\nG1 X1600 F6000\nM5\n",
            "line 3: 'X1600'",
        ),
        (
            "arc.nc",
            b"G0 X100 Y100\nM3\nG1 F6000\nG2 X120 Y100 I5 J0\nM5\n",
            "line 4: 'I5': the arc's centre does not match its radius",
        ),
        ("feed.nc", b"G0 X100 Y100\nM3\nG1 X110 F0\n", "line 3: 'F0'"),
        (
            "words.nc",
            b"This is not a part program.\n",
            "line 1: 'This'",
        ),
        (
            "binary.nc",
            &[0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a, 0, 0, 0xff],
            "not text",
        ),
        ("empty.nc", b"(only a comment)\n", "no move"),
    ];
    for (name, bytes, want) in cases {
        let prog = dir.path().join(name);
        std::fs::write(&prog, bytes).unwrap();
        let out = dir.path().join(format!("out-{name}"));
        let (ok, stdout, stderr) = run(&["cut", "--program", s(&prog), "--out", s(&out)]);
        assert!(!ok, "{name}: {stdout}");
        assert!(stderr.contains(want), "{name}: '{stderr}' lacks '{want}'");
        assert!(stdout.is_empty(), "{name}");
        assert!(!out.exists(), "{name}: {} was written", out.display());
    }
}

fn planned(text: &str) -> (Planned, MachineLimits) {
    plan_program(text, &MachineSpec::paper(), &PlantConfig::ideal()).unwrap()
}

/// The plan's own checks, computed here from its samples: the gantry within its limits (the
/// planning share), the micro inside its workspace less the margin and within its
/// acceleration; the split no slower than the gantry alone and no faster than the bound.
fn check_plan(name: &str, p: &Planned, l: &MachineLimits) {
    let plan = &p.plan;
    let dt = plan.dt_s;
    let completion = plan.completion_s();
    assert!(
        completion <= p.gantry_only_s + 1e-9,
        "{name}: slower than the gantry alone"
    );
    assert!(
        p.bound.bound_s <= completion + 1e-9,
        "{name}: beats the bound"
    );
    assert!(p.bound.bound_s <= p.gantry_only_s + 1e-9, "{name}");
    let g = &plan.gantry_mm;
    let lim = &l.split.gantry;
    for (k, w) in g.windows(3).enumerate() {
        let (p0, p1, p2) = (w[0], w[1], w[2]);
        for ((x0, x1), x2) in p0.iter().zip(p1).zip(p2) {
            let v = (x2 - x1) / dt;
            let a = (x2 - 2.0 * x1 + x0) / (dt * dt);
            assert!(
                v.abs() <= lim.speed_mm_s * 1.0001,
                "{name}: gantry speed {v} at {k}"
            );
            if plan.mode == PlanMode::Split {
                assert!(
                    a.abs() <= lim.accel_mm_s2 * 1.0001,
                    "{name}: gantry accel {a} at {k}"
                );
            }
        }
    }
    let micro = &l.split.micro;
    for (k, (t, g)) in plan.tool_mm.iter().zip(g).enumerate() {
        let m = [t[0] - g[0], t[1] - g[1]];
        assert!(micro.holds(m, 0.0), "{name}: micro at {m:?} at sample {k}");
    }
}

#[test]
fn the_shipped_parts_are_planned_as_promised() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("parts");
    for (name, small_features) in [
        ("holes.nc", true),
        ("stars.nc", true),
        ("nest.nc", true),
        ("test-piece.nc", false),
        ("frame.nc", false),
    ] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        let (p, l) = planned(&text);
        check_plan(name, &p, &l);
        let (t, g, b) = (p.plan.completion_s(), p.gantry_only_s, p.bound.bound_s);
        eprintln!(
            "{name}: split {t:.3} s, gantry alone {g:.3} s ({:.2}x), bound {b:.3} s ({:.3})",
            g / t,
            t / b
        );
        if small_features {
            assert_eq!(p.plan.mode, PlanMode::Split, "{name}");
            assert!(g / t >= 1.5, "{name}: {:.2}x", g / t);
        }
        assert!(t / b <= 1.2, "{name}: {:.3} of the bound", t / b);
    }
}

#[test]
fn random_programs_keep_the_promises() {
    let mut worst_ratio = 0.0f64;
    for seed in 0..16 {
        let text = parts::random(seed, 6, [20.0, 20.0], [1480.0, 2980.0]);
        let (p, l) = planned(&text);
        check_plan(&format!("random {seed}"), &p, &l);
        let ratio = p.plan.completion_s() / p.bound.bound_s;
        worst_ratio = worst_ratio.max(ratio);
        assert!(
            ratio <= 1.2,
            "random {seed}: {ratio:.3} of the bound\n{text}"
        );
    }
    eprintln!("worst split / bound over 16 random programs: {worst_ratio:.3}");
}

/// Executed on the simulated machine: the contour error at the tool while the beam is on, the
/// micro inside its workspace and every stage within its limits, measured on the executed
/// motion (the five-bar plant model: the six-bar's figures are the bench's).
#[test]
fn random_programs_executed_keep_the_contour_and_the_limits() {
    let spec = MachineSpec::paper();
    let mut plant = PlantConfig::ideal();
    plant.sixbar.model = PlantModel::Fivebar;
    for seed in [3, 11] {
        let text = parts::random(100 + seed, 3, [20.0, 20.0], [1480.0, 2980.0]);
        let opts = host_sim::cut::CutOptions {
            spec: spec.clone(),
            plant: plant.clone(),
            calibration: kinematics_core::Calibration {
                model: spec.nominal.cast(),
                grid: None,
            },
            dynamics: None,
            program_name: format!("random {seed}"),
        };
        let r = host_sim::cut::run(&text, &opts).unwrap().report;
        eprintln!(
            "random {seed}: {:.3} s vs {:.3} s, contour {:.2} um, clearance {:.2} mm, micro {:.1} g",
            r.completion_s,
            r.gantry_only_s,
            r.contour_max_um,
            r.micro.min_clearance_mm,
            r.micro.peak_accel_mm_s2 / STANDARD_GRAVITY_MM_S2
        );
        assert!(r.contour_max_um <= 10.0, "random {seed}: {r:?}");
        assert!(
            r.micro_inside_workspace && r.within_limits,
            "random {seed}: {r:?}"
        );
        assert!(r.completion_s <= r.gantry_only_s, "random {seed}");
    }
}
