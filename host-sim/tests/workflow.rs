//! The calibration workflow as a machine builder runs it, command by command through
//! the binary (plan → measure → fit → grid → command → accuracy), on the paper machine and on a
//! second, different machine (`machines/second.toml`: unequal links, bases 67 mm apart, an
//! octagonal workspace, a 4 mm grid; its plant `plants/second.toml`), against the demo:
//!
//! * the separate commands reproduce the demo's figures bit for bit (one path: the demo calls
//!   the same library functions with the same lists and seeds; the step-by-step guide's workflow);
//! * the second machine runs the whole workflow and the demo, reaching its noise floor;
//! * docs/guides/calibrate-step-by-step.md's command blocks run as written and reach the figures
//!   stated for them (the verifications' comments; `verify`'s report figures in the guide and
//!   docs/reference/calibration-tools.md);
//! * bad input of the new parts fails cleanly: a target outside the workspace, a plant of
//!   another machine, a simulation that faults, a demo that misses its goal.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the binary; panics with its stderr on failure; returns stdout.
fn ok(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{args:?} failed: {stderr}");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs the binary expecting failure with `want` in the message; returns (stdout, stderr).
fn fails(args: &[&str], want: &str) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(stderr.contains(want), "{args:?}: '{stderr}' lacks '{want}'");
    (stdout, stderr)
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The machine and its plant: (`--machine` args, plant, noise).
struct Setup {
    machine: Vec<String>,
    plant: String,
    noise_um: String,
}

impl Setup {
    fn paper() -> Self {
        Setup {
            machine: vec![],
            plant: "paper".into(),
            noise_um: "1".into(),
        }
    }
    fn second() -> Self {
        let r = root();
        Setup {
            machine: vec![
                "--machine".into(),
                r.join("machines/second.toml").display().to_string(),
            ],
            plant: r.join("plants/second.toml").display().to_string(),
            noise_um: "2".into(),
        }
    }
    fn args<'a>(&'a self, head: &[&'a str]) -> Vec<&'a str> {
        let mut v = head.to_vec();
        v.extend(self.machine.iter().map(String::as_str));
        v
    }
}

/// Verification figures per stage: `(stage, [max, rms] µm)`.
type Figures = Vec<(String, [f64; 2])>;

/// The demo's measurement seeds for seed 1 (`calib::pipeline::noise_seed`): 10·1 + step.
const SEED: u64 = 1;
fn seed(step: u64) -> String {
    host_sim::calib::pipeline::noise_seed(SEED, step).to_string()
}

/// The command-by-command workflow of the step-by-step guide, in `dir`; returns the verification
/// figures of every stage (`[max, rms]` µm, rounded as the demo's summary rounds them) and the
/// final image.
fn workflow(setup: &Setup, dir: &Path) -> (Figures, Vec<u8>) {
    let p = |name: &str| dir.join(name).display().to_string();
    let plan = json(&ok(&setup.args(&[
        "plan",
        "--seed",
        &SEED.to_string(),
        "--out",
        &p("plan"),
    ])));
    eprintln!("plan: {}", plan["identification"]);
    let measure =
        |targets: &str, calibration: &[&str], step: u64, out: &str| -> serde_json::Value {
            let mut a = vec![
                "measure",
                "--plant",
                &setup.plant,
                "--noise-um",
                &setup.noise_um,
                "--targets",
            ];
            let t = p(targets);
            let (sd, o) = (seed(step), p(out));
            a.extend([t.as_str(), "--seed", sd.as_str(), "--out", o.as_str()]);
            a.extend_from_slice(calibration);
            json(&ok(&setup.args(&a)))
        };
    let round = |v: &serde_json::Value| {
        [v["max_um"].as_f64().unwrap(), v["rms_um"].as_f64().unwrap()]
            .map(|x| (x * 1e3).round() / 1e3)
    };
    let mut figures = Vec::new();
    measure("plan/identify.csv", &[], 1, "fit.csv");
    ok(&setup.args(&[
        "fit",
        "--data",
        &p("fit.csv"),
        "--method",
        "full",
        "--no-loo",
        "--out",
        &p("model.json"),
    ]));
    ok(&setup.args(&[
        "fit",
        "--data",
        &p("fit.csv"),
        "--method",
        "ls",
        "--out",
        &p("model_ls.json"),
    ]));
    figures.push((
        "nominal".into(),
        // Judged in the machine frame the fit registered (the demo's nominal stage).
        round(&measure(
            "plan/verify.csv",
            &["--instrument-frame", &p("model.json")],
            2,
            "v_nominal.csv",
        )),
    ));
    figures.push((
        "ls".into(),
        round(&measure(
            "plan/verify.csv",
            &["--model", &p("model_ls.json")],
            3,
            "v_ls.csv",
        )),
    ));
    figures.push((
        "full".into(),
        round(&measure(
            "plan/verify.csv",
            &["--model", &p("model.json")],
            4,
            "v_full.csv",
        )),
    ));
    measure(
        "plan/grid.csv",
        &["--model", &p("model.json")],
        5,
        "nodes1.csv",
    );
    let g1 = json(&ok(&setup.args(&[
        "grid",
        "--model",
        &p("model.json"),
        "--data",
        &p("nodes1.csv"),
        "--out",
        &p("grid1.bin"),
    ])));
    assert_eq!(g1["workspace_block"], "written", "{g1}");
    figures.push((
        "full+grid".into(),
        round(&measure(
            "plan/verify.csv",
            &["--model", &p("model.json"), "--grid", &p("grid1.bin")],
            6,
            "v_grid1.csv",
        )),
    ));
    measure(
        "plan/grid.csv",
        &["--model", &p("model.json"), "--grid", &p("grid1.bin")],
        7,
        "nodes2.csv",
    );
    // Round 2 pools both rounds' readings, as the demo does.
    ok(&setup.args(&[
        "grid",
        "--model",
        &p("model.json"),
        "--data",
        &p("nodes1.csv"),
        &p("nodes2.csv"),
        "--out",
        &p("grid.bin"),
    ]));
    figures.push((
        "full+grid2".into(),
        round(&measure(
            "plan/verify.csv",
            &["--model", &p("model.json"), "--grid", &p("grid.bin")],
            8,
            "v_grid2.csv",
        )),
    ));
    (figures, std::fs::read(dir.join("grid.bin")).unwrap())
}

/// The demo's figures and image for the same machine and seed.
fn demo(setup: &Setup, dir: &Path) -> (Figures, Vec<u8>, serde_json::Value) {
    let out = dir.join("demo");
    let mut a = vec![
        "demo",
        "--plant",
        &setup.plant,
        "--noise-um",
        &setup.noise_um,
        "--seed",
        "1",
        "--out",
        s(&out),
    ];
    a.extend(setup.machine.iter().map(String::as_str));
    let v = json(&ok(&a));
    let stages = v["stages"].as_array().unwrap();
    let figures = stages
        .iter()
        .map(|st| {
            (
                st["step"].as_str().unwrap().to_string(),
                [
                    st["max_um"].as_f64().unwrap(),
                    st["rms_um"].as_f64().unwrap(),
                ],
            )
        })
        .collect();
    (figures, std::fs::read(out.join("grid.bin")).unwrap(), v)
}

#[test]
fn the_separate_commands_reproduce_the_demo_on_the_paper_machine() {
    let dir = tempfile::tempdir().unwrap();
    let (steps, image) = workflow(&Setup::paper(), dir.path());
    let (demo_steps, demo_image, v) = demo(&Setup::paper(), dir.path());
    eprintln!("commands: {steps:?}\ndemo:     {demo_steps:?}");
    assert_eq!(steps, demo_steps, "the commands and the demo disagree");
    assert!(
        image == demo_image,
        "the commands' grid.bin differs from the demo's"
    );
    assert_eq!(v["final"]["met"], true);
    // The image carries the paper machine's workspace for the firmware.
    let grid = kinematics_core::CorrectionGrid::parse(&image).unwrap();
    let ws = grid.workspace().expect("a workspace block");
    assert_eq!(
        ws.region.vertices_mm(),
        [
            [162.132f32, -75.0],
            [262.132, -75.0],
            [262.132, 75.0],
            [162.132, 75.0]
        ]
    );
    assert_eq!(ws.stop_margin_mm, 0.1);
    assert!(
        grid.dynamics().is_none(),
        "no --dynamics, no dynamics block"
    );

    // grid --dynamics: the same image with the dynamics block at the end of its chain, which
    // simulate feeds forward; a dynamics file that does not validate writes nothing.
    let d = dir.path();
    let dynamics = d.join("dynamics.json");
    std::fs::write(&dynamics, DYNAMICS_JSON).unwrap();
    let (m, g1, g2, gd) = (
        d.join("model.json"),
        d.join("nodes1.csv"),
        d.join("nodes2.csv"),
        d.join("gd.bin"),
    );
    let v = json(&ok(&[
        "grid",
        "--model",
        s(&m),
        "--data",
        s(&g1),
        s(&g2),
        "--out",
        s(&gd),
        "--dynamics",
        s(&dynamics),
    ]));
    assert_eq!(
        (&v["workspace_block"], &v["dynamics_block"]),
        (&"written".into(), &true.into()),
        "{v}"
    );
    // The dynamics block goes after the workspace block and before the machine record, which
    // every image ends with.
    let with = std::fs::read(&gd).unwrap();
    let record = kinematics_core::grid::MACHINE_LEN;
    let before_record = image.len() - record;
    assert_eq!(&with[..before_record], &image[..before_record]);
    assert_eq!(&with[with.len() - record..], &image[before_record..]);
    assert_eq!(
        with.len(),
        image.len() + kinematics_core::grid::DYNAMICS_LEN
    );
    let parsed = kinematics_core::CorrectionGrid::parse(&with).unwrap();
    assert_eq!(parsed.workspace(), Some(ws));
    assert_eq!(parsed.dynamics().unwrap().tool_mass_kg, 0.165);
    let sim = json(&ok(&[
        "simulate",
        "--trajectory",
        "move-10mm",
        "--model",
        s(&m),
        "--grid",
        s(&gd),
    ]));
    assert_eq!(
        sim["dynamics_source"], "the --grid image's dynamics block",
        "{sim}"
    );
    // Dynamics 1000 times the machine's: a valid file, an image the controller would refuse;
    // nothing is written.
    std::fs::write(
        &dynamics,
        DYNAMICS_JSON
            .replace("[0.0037, 0.0037]", "[3.7, 3.7]")
            .replace("0.165", "165.0"),
    )
    .unwrap();
    let absurd = d.join("absurd.bin");
    fails(
        &[
            "grid",
            "--model",
            s(&m),
            "--data",
            s(&g1),
            s(&g2),
            "--out",
            s(&absurd),
            "--dynamics",
            s(&dynamics),
        ],
        "times the nominal kinetic energy",
    );
    assert!(!absurd.exists() && !absurd.with_extension("csv").exists());
    std::fs::write(&dynamics, DYNAMICS_JSON.replace("0.165", "-0.165")).unwrap();
    let bad = d.join("bad.bin");
    fails(
        &[
            "grid",
            "--model",
            s(&m),
            "--data",
            s(&g1),
            s(&g2),
            "--out",
            s(&bad),
            "--dynamics",
            s(&dynamics),
        ],
        "dynamics.json",
    );
    assert!(!bad.exists());
    // `--out nodes1.bin` would write its node table over the measurements it read.
    let before = std::fs::read(&g1).unwrap();
    fails(
        &[
            "grid",
            "--model",
            s(&m),
            "--data",
            s(&g1),
            "--out",
            s(&d.join("nodes1.bin")),
        ],
        "is the file of the input --data",
    );
    assert_eq!(std::fs::read(&g1).unwrap(), before);
    assert!(!d.join("nodes1.bin").exists());
    // The same file twice would pass its readings off as repeats.
    fails(
        &[
            "grid",
            "--model",
            s(&m),
            "--data",
            s(&g2),
            "--data",
            s(&g2),
            "--out",
            s(&bad),
        ],
        "names",
    );
    assert!(!bad.exists());
}

/// A dynamics file (`io::dynamics_file`) with the QEMU machine's kind of values.
const DYNAMICS_JSON: &str = r#"{"format": "hidden-robot-dynamics", "version": 1,
  "motor_inertia_kg_m2": [0.0037, 0.0037], "tool_mass_kg": 0.165, "distal_inertia_kg_m2": [0.0, 0.0],
  "viscous_nm_s_per_rad": [0.02, 0.02], "coulomb_nm": [0.05, 0.05], "coulomb_speed_rad_s": 0.01}"#;

#[test]
fn the_second_machine_runs_the_whole_workflow_and_the_demo() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let setup = Setup::second();
    let spec =
        host_sim::io::machine_file::read_machine(&root().join("machines/second.toml")).unwrap();
    let (steps, image) = workflow(&setup, d);
    let (demo_steps, demo_image, v) = demo(&setup, d);
    eprintln!("second machine, commands: {steps:?}\ndemo: {demo_steps:?}");
    assert_eq!(steps, demo_steps);
    assert!(image == demo_image);
    // Before calibration it is hundreds of µm off; fit + grid reach the 2 µm instrument's floor.
    let get = |k: &str| steps.iter().find(|(s, _)| s == k).unwrap().1;
    assert!(get("nominal")[0] > 300.0, "{steps:?}");
    assert!(get("full")[0] < get("nominal")[0] / 20.0, "{steps:?}");
    let [max, rms] = get("full+grid2");
    assert_eq!(v["final"]["target_max_um"], 10.0);
    assert_eq!(v["final"]["target_rms_um"], 4.0);
    assert!(
        max <= 10.0 && rms <= 4.0 && rms < get("full")[1],
        "fit + grid {max} / {rms} µm"
    );
    assert_eq!(v["final"]["met"], true);

    // The image: the machine's octagon and 0.2 mm soft limit, its 4 mm lattice.
    let grid = kinematics_core::CorrectionGrid::parse(&image).unwrap();
    let g = grid.geometry();
    assert_eq!(
        (g.nx, g.ny, g.x0_mm, g.y0_mm, g.step_x_mm),
        (22, 32, 168.0, -72.0, 4.0)
    );
    let ws = grid.workspace().unwrap();
    assert_eq!(ws.region.vertices_mm().len(), 8);
    assert_eq!(ws.stop_margin_mm, 0.2);
    assert_eq!(
        *grid.model(),
        host_sim::io::model_file::read_model(&d.join("model.json"))
            .unwrap()
            .cast::<f32>()
    );

    // command: the firmware's path with the machine's calibration; the octagon's cut corner
    // (inside the grid's rectangle) and a point off the grid are refused.
    let targets = d.join("t.csv");
    std::fs::write(&targets, "x_mm,y_mm\n210,-10\n245,30\n172,-50\n").unwrap();
    let angles = d.join("a.csv");
    let (m, gb) = (d.join("model.json"), d.join("grid.bin"));
    ok(&setup.args(&[
        "command",
        "--model",
        s(&m),
        "--grid",
        s(&gb),
        "--targets",
        s(&targets),
        "--out",
        s(&angles),
    ]));
    let cal = kinematics_core::Calibration::from_grid(grid);
    for (line, t) in std::fs::read_to_string(&angles)
        .unwrap()
        .lines()
        .skip(1)
        .zip([[210.0f32, -10.0], [245.0, 30.0], [172.0, -50.0]])
    {
        let th = cal.command_rad(t, spec.min_transmission as f32).unwrap();
        let f: Vec<f64> = line.split(',').map(|v| v.parse().unwrap()).collect();
        assert_eq!(
            (f[2].to_radians() as f32, f[3].to_radians() as f32),
            (th[0], th[1]),
            "{line}"
        );
    }
    let corner = d.join("corner.csv");
    std::fs::write(&corner, "x_mm,y_mm\n210,-10\n172,-69\n").unwrap();
    let o = d.join("o.csv");
    fails(
        &setup.args(&[
            "command",
            "--model",
            s(&m),
            "--grid",
            s(&gb),
            "--targets",
            s(&corner),
            "--out",
            s(&o),
        ]),
        "line 3: target (172, -69) is outside the workspace of machine 'second'",
    );
    fails(
        &setup.args(&[
            "command",
            "--model",
            s(&m),
            "--targets",
            s(&corner),
            "--out",
            s(&o),
        ]),
        "line 3: target (172, -69) is outside the workspace",
    );
    assert!(!o.exists());

    // accuracy: the plan's repeat runs measured through the calibration; both axis lines.
    let rep = d.join("repeat.csv");
    let plan_repeat = d.join("plan/repeat.csv");
    let mut a = vec![
        "measure",
        "--plant",
        &setup.plant,
        "--noise-um",
        &setup.noise_um,
        "--targets",
        s(&plan_repeat),
        "--grid",
        s(&gb),
        "--seed",
        "9",
        "--out",
        s(&rep),
    ];
    a.extend(setup.machine.iter().map(String::as_str));
    ok(&a);
    let r = json(&ok(&setup.args(&["accuracy", "--data", s(&rep)])));
    assert_eq!(r["skipped"], serde_json::json!([]), "{r}");
    let axes: Vec<&str> = r["lines"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["axis"].as_str().unwrap())
        .collect();
    assert_eq!(axes, ["x", "y"]);
    eprintln!(
        "second machine, ISO 230-2 / VDI 3441 after calibration: {}",
        r["summary"]
    );

    // The paper plant is not this machine's simulation.
    fails(
        &setup.args(&[
            "measure",
            "--plant",
            "paper",
            "--protocol",
            "table1",
            "--out",
            s(&o),
        ]),
        "the plant is not a simulation of machine 'second'",
    );
}

#[test]
fn command_without_a_grid_refuses_targets_outside_the_workspace() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let model = d.join("m.json");
    let nominal = host_sim::io::machine_file::paper().nominal;
    host_sim::io::model_file::write_model_file(
        &model,
        &host_sim::io::model_file::ModelFile::from_model(&nominal),
    )
    .unwrap();
    let out = d.join("a.csv");
    for (t, line) in [
        ("212,-200", "line 3: target (212, -200)"),
        ("50,0", "line 3: target (50, 0)"),
    ] {
        let targets = d.join("t.csv");
        std::fs::write(&targets, format!("x_mm,y_mm\n212.132,0\n{t}\n")).unwrap();
        let (_, e) = fails(
            &[
                "command",
                "--model",
                s(&model),
                "--targets",
                s(&targets),
                "--out",
                s(&out),
            ],
            line,
        );
        assert!(
            e.contains("outside the workspace of machine 'paper'"),
            "{e}"
        );
        assert!(!out.exists());
    }
    // The workspace's corner is a target (Table I's point 7).
    let targets = d.join("t.csv");
    std::fs::write(&targets, "x_mm,y_mm\n162.132,-75\n").unwrap();
    ok(&[
        "command",
        "--model",
        s(&model),
        "--targets",
        s(&targets),
        "--out",
        s(&out),
    ]);
}

#[test]
fn a_simulation_that_faults_and_a_demo_that_misses_its_goal_exit_non_zero() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A 20 mm jump in one millisecond: the servo refuses the setpoint.
    let jump = d.join("jump.csv");
    std::fs::write(
        &jump,
        "t_s,x_mm,y_mm\n0,212.132,0\n0.05,212.132,0\n0.051,232.132,0\n0.2,232.132,0\n",
    )
    .unwrap();
    let (stdout, _) = fails(
        &["simulate", "--plant", "ideal", "--trajectory", s(&jump)],
        "the simulation faulted",
    );
    assert!(
        json(&stdout)["fault"].is_string(),
        "the summary still says what happened: {stdout}"
    );
    // A gear cyclic error of 40 µrad at 50 cycles per motor revolution (a period of 2 mm at the
    // tool, under the 5 mm grid's step): neither the fit nor the grid can follow it (about
    // 15 µm max > 5). (Random approach on the paper plant no longer misses: its backlash is
    // measured and corrected by direction.)
    let plant = d.join("cyclic.toml");
    let text = std::fs::read_to_string(root().join("plants/paper.toml")).unwrap();
    let cyclic = text
        .replace("cyclic_error_urad = 0.0", "cyclic_error_urad = 40.0")
        .replace(
            "cyclic_error_cycles_per_motor_rev = 0.0",
            "cyclic_error_cycles_per_motor_rev = 50.0",
        );
    assert_ne!(cyclic, text);
    std::fs::write(&plant, cyclic).unwrap();
    let out = d.join("demo");
    let (stdout, stderr) = fails(
        &["demo", "--plant", s(&plant), "--out", s(&out)],
        "the accuracy target",
    );
    assert_eq!(json(&stdout)["final"]["met"], false);
    assert!(stderr.contains("NOT met"), "{stderr}");
    assert!(
        out.join("summary.json").is_file(),
        "the outputs are written"
    );
}

#[test]
fn machine_files_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = std::fs::read_to_string(root().join("machines/paper.toml")).unwrap();
    let bad = d.join("bad.toml");
    std::fs::write(
        &bad,
        text.replace("sigma_um = 1.0", "sigma_um = 1.0\nsigma_mm = 0.001"),
    )
    .unwrap();
    let (_, e) = fails(
        &["plan", "--machine", s(&bad), "--out", s(&d.join("p"))],
        "sigma_mm",
    );
    assert!(e.contains("bad.toml") && e.contains("machine file"), "{e}");
    assert!(!d.join("p").exists());
    fails(
        &[
            "fit",
            "--machine",
            "/nonexistent/m.toml",
            "--data",
            "x.csv",
            "--method",
            "full",
            "--out",
            s(&d.join("m.json")),
        ],
        "m.toml",
    );
    // The shipped paper file is the default: the same plan either way.
    let (a, b) = (d.join("a"), d.join("b"));
    ok(&["plan", "--out", s(&a)]);
    ok(&[
        "plan",
        "--machine",
        s(&root().join("machines/paper.toml")),
        "--out",
        s(&b),
    ]);
    for f in [
        "identify.csv",
        "grid.csv",
        "verify.csv",
        "repeat.csv",
        "plan.json",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
}

/// docs/guides/calibrate-step-by-step.md's "Command by command", run line by line as written (`$h`
/// is the binary, `$m` the measure prefix the block defines): every command succeeds and every
/// figure in a comment (`max / rms` µm) is what that command printed, to the digits shown.
#[test]
fn the_readme_workflow_reaches_the_figures_it_states() {
    let readme =
        std::fs::read_to_string(root().join("../docs/guides/calibrate-step-by-step.md")).unwrap();
    let section = readme
        .split("## Command by command")
        .nth(1)
        .expect("the guide's section");
    let block = section
        .split("```sh\n")
        .nth(1)
        .unwrap()
        .split("```")
        .next()
        .unwrap();
    let measure = block
        .lines()
        .find_map(|l| l.strip_prefix("m=\""))
        .unwrap()
        .trim_end_matches('"');
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("T.csv"), "x_mm,y_mm\n212.132,0\n240,30\n").unwrap();
    let mut checked = 0;
    for line in block.lines().filter(|l| l.starts_with("$h ")) {
        let (command, comment) = line
            .split_once('#')
            .map_or((line, ""), |(c, k)| (c, k.trim()));
        let command = command.replacen("$h ", "", 1).replace("$m", measure);
        let args: Vec<&str> = command.split_whitespace().collect();
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(&args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "guide: `{line}` failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let figures: Vec<&str> = comment.split(" / ").map(str::trim).collect();
        if figures.len() == 2 && figures.iter().all(|f| f.parse::<f64>().is_ok()) {
            let v = json(&String::from_utf8_lossy(&out.stdout));
            for (key, stated) in ["max_um", "rms_um"].into_iter().zip(&figures) {
                let decimals = stated.split('.').nth(1).map_or(0, str::len) as i32;
                let got = v[key].as_f64().unwrap();
                let shown = (got * 10f64.powi(decimals)).round() / 10f64.powi(decimals);
                assert_eq!(
                    shown,
                    stated.parse::<f64>().unwrap(),
                    "guide: `{line}`: {key} is {got}"
                );
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 4, "the four verifications carry their figures");
    assert!(dir.path().join("angles.csv").is_file());
}

/// docs/guides/calibrate-step-by-step.md's "The customer's accuracy report (`verify`)", run as
/// written (`$H` is the binary, `$M` the plant options the block defines, `\` continues a line):
/// every command succeeds, and the figures the guide's sentence and calibration-tools.md's table state for it are what
/// `verify` printed, to the digits shown (≥ 100: units, ≥ 10: one decimal, else two).
#[test]
fn the_readme_verify_block_reaches_the_figures_the_docs_state() {
    let readme =
        std::fs::read_to_string(root().join("../docs/guides/calibrate-step-by-step.md")).unwrap();
    let section = readme
        .split("## The customer's accuracy report (`verify`)")
        .nth(1)
        .expect("the guide's section");
    let block = section
        .split("```sh\n")
        .nth(1)
        .unwrap()
        .split("```")
        .next()
        .unwrap()
        .replace("\\\n", " ");
    let plant = block
        .lines()
        .find_map(|l| l.split("M=\"").nth(1))
        .unwrap()
        .split('"')
        .next()
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut report = None;
    for line in block.lines().filter(|l| l.starts_with("$H ")) {
        let command = line
            .split('#')
            .next()
            .unwrap()
            .replacen("$H ", "", 1)
            .replace("$M", plant);
        let args: Vec<&str> = command.split_whitespace().collect();
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(&args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "guide: `{line}` failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        if args[0] == "verify" {
            report = Some(json(&String::from_utf8_lossy(&out.stdout)));
        }
    }
    let v = report.expect("the block runs verify");
    let shown = |x: &serde_json::Value| {
        let x = x.as_f64().unwrap();
        if x >= 100.0 {
            format!("{x:.0}")
        } else if x >= 10.0 {
            format!("{x:.1}")
        } else {
            format!("{x:.2}")
        }
    };
    let (before, after) = (&v["stages"][0], &v["stages"][1]);
    assert_eq!(
        (before["stage"].as_str(), after["stage"].as_str()),
        (Some("before"), Some("after"))
    );
    let pos = |st: &serde_json::Value| {
        format!(
            "{} / {}",
            shown(&st["position"]["max_um"]),
            shown(&st["position"]["rms_um"])
        )
    };
    let line = |st: &serde_json::Value, k: usize, axis: &str| {
        let l = &st["lines"][k];
        assert_eq!(l["axis"].as_str(), Some(axis));
        l.clone()
    };
    let iso = |l: &serde_json::Value, key: &str| shown(&l["iso_230_2"][key]);
    let vdi = |l: &serde_json::Value, key: &str| shown(&l["vdi_3441"][key]);
    let (bx, by, ax, ay) = (
        line(before, 0, "x"),
        line(before, 1, "y"),
        line(after, 0, "x"),
        line(after, 1, "y"),
    );
    let sentence = format!(
        "error {} max / RMS before, {} after; ISO 230-2 accuracy A {} → {} (x line) and {} → {} (y line); VDI 3441 P {} → {} and {} → {}.",
        pos(before),
        pos(after),
        iso(&bx, "a_um"),
        iso(&ax, "a_um"),
        iso(&by, "a_um"),
        iso(&ay, "a_um"),
        vdi(&bx, "p_um"),
        vdi(&ax, "p_um"),
        vdi(&by, "p_um"),
        vdi(&ay, "p_um"),
    );
    let one_line = |t: &str| t.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(
        one_line(section).contains(&sentence),
        "the guide's verify figures are stale; verify printed: {sentence}"
    );
    let arbe = |l: &serde_json::Value| {
        ["a_um", "r_um", "e_um", "b_um"]
            .map(|k| iso(l, k))
            .join(" / ")
    };
    let p_ps = |l: &serde_json::Value| format!("{} / {}", vdi(l, "p_um"), vdi(l, "ps_um"));
    let calibration =
        std::fs::read_to_string(root().join("../docs/reference/calibration-tools.md")).unwrap();
    for row in [
        format!(
            "| 2-D position error max / RMS (400 targets) | {} | {} |",
            pos(before),
            pos(after)
        ),
        format!(
            "| x line (y = 0): ISO 230-2 A / R / E / B | {} | {} |",
            arbe(&bx),
            arbe(&ax)
        ),
        format!(
            "| y line (x = 212.132): ISO 230-2 A / R / E / B | {} | {} |",
            arbe(&by),
            arbe(&ay)
        ),
        format!(
            "| x line: VDI 3441 P / Ps | {} | {} |",
            p_ps(&bx),
            p_ps(&ax)
        ),
        format!(
            "| y line: VDI 3441 P / Ps | {} | {} |",
            p_ps(&by),
            p_ps(&ay)
        ),
    ] {
        assert!(
            calibration.contains(&row),
            "calibration-tools.md's verify table is stale; verify printed: {row}"
        );
    }
}

/// `plan`'s files, checked from the files alone on both machines: every target in the
/// workspace with the machine's approach, the verification targets disjoint from every other
/// list (brute force), the repeat runs as ISO 230-2 / VDI 3441 want them, the identification
/// design better than random poses of the same count.
#[test]
fn plan_files_hold_what_the_issue_asks_on_both_machines() {
    for setup in [Setup::paper(), Setup::second()] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("plan");
        let report = json(&ok(&setup.args(&["plan", "--seed", "3", "--out", s(&out)])));
        let spec = match setup.machine.get(1) {
            Some(f) => host_sim::io::machine_file::read_machine(Path::new(f)).unwrap(),
            None => host_sim::io::machine_file::paper(),
        };
        let read = |name: &str| {
            host_sim::io::targets_csv::read_target_list(&out.join(format!("{name}.csv"))).unwrap()
        };
        let (identify, grid, verify, repeat) = (
            read("identify"),
            read("grid"),
            read("verify"),
            read("repeat"),
        );
        assert_eq!(
            (identify.len(), grid.len(), verify.len()),
            (40, spec.grid.nx * spec.grid.ny, 400),
            "{}",
            spec.name
        );
        for t in identify.iter().chain(&verify).chain(&repeat) {
            assert!(
                spec.workspace.contains(t.target_mm, 1e-9),
                "{}: {:?} outside the workspace",
                spec.name,
                t.target_mm
            );
        }
        for t in identify.iter().chain(&grid).chain(&verify).chain(&repeat) {
            assert_eq!(
                t.dir,
                Some([1, 1]),
                "{}: positive approach on every row",
                spec.name
            );
            assert!(t.from_mm.is_some());
        }
        // Disjoint: no verification target within 1 µm of any target of the other lists.
        let others: Vec<[f64; 2]> = identify
            .iter()
            .chain(&grid)
            .chain(&repeat)
            .map(|t| t.target_mm)
            .collect();
        let nearest = verify
            .iter()
            .map(|v| {
                others
                    .iter()
                    .map(|o| (o[0] - v.target_mm[0]).hypot(o[1] - v.target_mm[1]))
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest > 1e-3,
            "{}: a verification target {nearest} mm from another list's",
            spec.name
        );
        assert_eq!(
            report["verify_min_distance_to_others_mm"].as_f64().unwrap(),
            nearest
        );
        // Repeat runs: 5 runs, each over both axis lines through the centre, both directions,
        // 11 targets per line (ISO 230-2: ≥ 5 targets, 5 bidirectional runs).
        let c = spec.workspace.centre_mm();
        let runs: std::collections::BTreeSet<u32> = repeat.iter().map(|t| t.run.unwrap()).collect();
        assert_eq!(
            runs.into_iter().collect::<Vec<_>>(),
            [0, 1, 2, 3, 4],
            "{}",
            spec.name
        );
        for run in 0..5 {
            let rows: Vec<[f64; 2]> = repeat
                .iter()
                .filter(|t| t.run == Some(run))
                .map(|t| t.target_mm)
                .collect();
            let x_line: Vec<f64> = rows.iter().filter(|p| p[1] == c[1]).map(|p| p[0]).collect();
            let y_line: Vec<f64> = rows
                .iter()
                .filter(|p| p[0] == c[0] && p[1] != c[1])
                .map(|p| p[1])
                .collect();
            let distinct = |v: &[f64]| {
                v.iter()
                    .map(|x| x.to_bits())
                    .collect::<std::collections::BTreeSet<_>>()
                    .len()
            };
            assert_eq!(
                distinct(&x_line),
                11,
                "{} run {run}: x line {x_line:?}",
                spec.name
            );
            assert!(
                distinct(&y_line) >= 10,
                "{} run {run}: y line {y_line:?}",
                spec.name
            );
            // Both directions: the line is walked up and down.
            assert!(
                x_line.windows(2).any(|w| w[1] > w[0]) && x_line.windows(2).any(|w| w[1] < w[0]),
                "{}",
                spec.name
            );
        }
        let id = &report["identification"];
        let f = |k: &str, w: &str| id[k][w].as_f64().unwrap();
        assert!(
            f("chosen", "condition_number") < f("random_same_count", "condition_number"),
            "{}: {id}",
            spec.name
        );
        assert!(
            f("chosen", "observability_o1") > f("random_same_count", "observability_o1"),
            "{}: {id}",
            spec.name
        );
        assert_eq!(id["random_same_count"]["poses"], 40);
    }
}
