//! `host-sim commission --qemu`: the machine builder's journey through the co-simulated
//! controller (the production firmware under QEMU driving the simulated six-bar in lockstep):
//! identify, home, plan, measure, fit, diagnose, dynamics (the excitation's telemetry
//! identified), grid (two rounds, each measured through the image uploaded before it), upload,
//! verify at fresh targets through the controller, moving (a figure-eight's following error).
//!
//! * The paper machine with the paper plant (part errors, clearances, backlash, its instrument
//!   3.2 mm off the machine frame) and a 1 µm instrument: the journey ends with the calibration
//!   it uploaded in force (the id the controller reports is the CRC-32C of `grid.bin`),
//!   ≤ 1 µm max / 0.3 µm RMS where the tool lands at fresh targets, the instrument's frame
//!   registered, the tool mass identified, the dynamics block in `grid.bin` and the check
//!   motion following closer with it, every file written.
//! * The second machine (another design: its own machine file, plant and 2 µm instrument; an
//!   octagonal workspace inside its grid): the same journey, the goal scaled with σ, the
//!   grid's nodes outside the workspace estimated.
//! * The moving steps alone with a 0.1 kg cutting head against the 40 g tool.
//! * A plant file it has never seen: another build of the second machine's design
//!   (`builds::another_build`: other part errors and encoder zeros, the instrument 2 m away and
//!   turned by degrees), commissioned with a 1 µm instrument. The octagonal workspace leaves a
//!   sixth of the grid's nodes outside it, estimated from the others
//!   (`calib::grid::unmeasured`): the goal, ≤ 1.0 µm max / 0.3 µm RMS where the tool lands at
//!   fresh targets, must hold there too. A shorter journey than the full one (one grid round,
//!   60 fresh targets); `cargo bench -p host-sim --bench commission_builds` runs the full one
//!   over several builds of both designs.
//! * Bad input: a missing firmware, another machine's plant, a controller that does not
//!   answer, flags of another mode, an excitation too short: a clear error, a non-zero exit, no
//!   output directory.
//!
//! Needs qemu-system-arm and the thumbv7em-none-eabihf target (`bash tests/run-all.sh`
//! installs both); the firmware is built into `target/system-tests` as the other QEMU tests do.
//! Wall time: about 65 s per journey alone (about 330 simulated s, some 1400 points through the
//! controller), 30 s for the other build, 15 s for the heavier head. A journey alone keeps
//! one core busy (QEMU and the host take turns); the harness runs it beside the other tests.

use host_sim::link::link_protocol::calibration_image_id;
use host_sim::plant::{Plant, PlantConfig};
use std::path::Path;
use std::process::{Command, Output};

include!("../../tests/support/firmware_build.rs");
#[path = "builds/mod.rs"]
mod builds;

fn host_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .expect("host-sim runs")
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Runs the journey on `machine` (a file under host-sim/machines, or the default) with the
/// plant `plant`, 60 fresh targets; returns the report, the stderr and the output directory.
fn journey(machine: Option<&str>, plant: &str) -> (serde_json::Value, String, tempfile::TempDir) {
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let root = workspace_root().join("host-sim");
    let mut args: Vec<String> = vec![
        "commission".into(),
        "--qemu".into(),
        "--firmware".into(),
        elf.display().to_string(),
        "--plant".into(),
        plant.into(),
        "--verify-targets".into(),
        "60".into(),
        "--out".into(),
        out.display().to_string(),
    ];
    if let Some(m) = machine {
        args.extend(["--machine".into(), root.join(m).display().to_string()]);
    }
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = host_sim(&a);
    let (stdout, stderr) = text(&o);
    eprintln!("{stderr}");
    assert!(o.status.success(), "{stderr}");
    (serde_json::from_str(&stdout).unwrap(), stderr, tmp)
}

/// What every journey must show: each step in order, the uploaded calibration in force (the
/// controller's id is the file's CRC-32C, and it replaced the one the controller started
/// with), the goal met where the tool landed at the fresh targets, every file written.
fn check_journey(
    r: &serde_json::Value,
    stderr: &str,
    out: &Path,
    plant: &str,
    tool_mass_tolerance: f64,
) -> (f64, f64) {
    let steps: Vec<&str> = r["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["step"].as_str().unwrap())
        .collect();
    assert_eq!(
        steps,
        [
            "identify", "home", "plan", "measure", "fit", "diagnose", "dynamics", "grid 1",
            "grid 2", "upload", "verify", "moving"
        ]
    );
    for step in &steps {
        assert!(stderr.contains(&format!("commission: {step}")), "{step}");
    }
    let grid_bin = std::fs::read(out.join("grid.bin")).unwrap();
    let id = calibration_image_id(&grid_bin);
    assert_eq!(r["calibration_id_u32"].as_u64(), Some(u64::from(id)));
    assert_eq!(r["calibration_id"], format!("{id:#010x}"));
    assert_ne!(r["calibration_id_before"], r["calibration_id"]);
    let f = &r["final"];
    let (max, rms) = (f["max_um"].as_f64().unwrap(), f["rms_um"].as_f64().unwrap());
    assert_eq!(f["n_targets"], 60);
    assert!(
        max <= f["target_max_um"].as_f64().unwrap() && rms <= f["target_rms_um"].as_f64().unwrap(),
        "{max} / {rms} µm"
    );
    assert_eq!(f["met"], true);
    // The readings carry the instrument's noise: more than the truth.
    assert!(f["measured_rms_um"].as_f64().unwrap() > rms, "{f}");
    let g = r["grid"].as_array().unwrap();
    assert_eq!(g.len(), 2);
    assert!(g[1]["node_err_rms_um"].as_f64() < g[0]["node_err_rms_um"].as_f64());
    for name in host_sim::commission::FILES {
        assert!(out.join(name).is_file(), "{name}");
    }
    let model = std::fs::read_to_string(out.join("model.json")).unwrap();
    assert!(model.contains("instrument_frame"), "{model}");
    check_dynamics(r, out, &grid_bin, plant, tool_mass_tolerance);
    (max, rms)
}

/// The dynamics step's: the tool mass identified through the controller within
/// `tool_mass_tolerance` of the plant's (its bodies lumped at the tool point,
/// `Plant::true_dynamics`; what the hidden robot's effective tool mass is near), written to
/// dynamics.json and into grid.bin's dynamics block, and the check motion following closer
/// with it fed forward than with the image before it (which carries none: the gains' constant
/// inertia fed forward). Returns the check motion's max following error before and after (µm).
/// Deterministic (the co-simulation): the same figures in every run.
fn check_dynamics(
    r: &serde_json::Value,
    out: &Path,
    grid_bin: &[u8],
    plant: &str,
    tool_mass_tolerance: f64,
) -> (f64, f64) {
    let truth = Plant::new(&PlantConfig::by_name(plant).unwrap(), 1).true_dynamics();
    let d = &r["dynamics"];
    let m = d["tool_mass_kg"].as_f64().unwrap();
    assert!(
        (m - truth.tool_mass_kg).abs() < tool_mass_tolerance * truth.tool_mass_kg,
        "tool mass {m} kg, the plant's {} kg",
        truth.tool_mass_kg
    );
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dynamics.json")).unwrap()).unwrap();
    assert!(
        (file["tool_mass_kg"].as_f64().unwrap() - m).abs() < 1e-6,
        "{file}"
    );
    assert_eq!(file["machine"]["name"], r["machine"]);
    let image = kinematics_core::CorrectionGrid::parse(grid_bin).unwrap();
    let block = image
        .dynamics()
        .expect("grid.bin carries the dynamics block");
    assert!((f64::from(block.tool_mass_kg) - m).abs() < 1e-5 * m.max(1.0));
    let telemetry = std::fs::read_to_string(out.join("excitation_telemetry.csv")).unwrap();
    assert!(telemetry.starts_with("# machine="), "{telemetry:.100}");
    let mv = &r["moving"];
    let (before, after) = (
        mv["before"]["max_following_um"].as_f64().unwrap(),
        mv["max_following_um"].as_f64().unwrap(),
    );
    eprintln!(
        "COMMISSION_DYNAMICS {}: tool mass {m:.4} kg (plant {:.4}); check motion max following \
         error {before:.2} um before, {after:.2} um after the dynamics",
        r["machine"], truth.tool_mass_kg
    );
    // The figures: docs/guides/commission.md ("The moving machine"). The RMS over the motion is
    // the steadier figure (the max is one sample's).
    assert!(after < before, "{mv}");
    let rms = |v: &serde_json::Value| v["rms_following_um"].as_f64().unwrap();
    assert!(rms(mv) < 0.7 * rms(&mv["before"]), "{mv}");
    (before, after)
}

#[test]
fn the_paper_machine_is_calibrated_through_the_cosimulated_controller() {
    let (r, stderr, tmp) = journey(None, "paper");
    // The paper machine's tool mass: within 5 % of its plant's 0.1648 kg.
    let (max, rms) = check_journey(&r, &stderr, &tmp.path().join("out"), "paper", 0.05);
    // The paper machine's goal with its 1 µm instrument.
    assert!(max <= 1.0 && rms <= 0.3, "{max} / {rms} µm");
    // The instrument's frame registered (the paper plant's: 3.194 mm off in y).
    let off = &r["fit"]["instrument_frame"]["offset_mm"];
    assert!((off[1].as_f64().unwrap() - 3.194).abs() < 0.15, "{off}");
    // Every node of the paper's grid is inside its workspace: none estimated.
    assert_eq!(r["grid"][1]["nodes_estimated"], 0);
}

#[test]
fn the_second_machine_is_calibrated_through_the_cosimulated_controller() {
    let plant = workspace_root().join("host-sim/plants/second.toml");
    let plant = plant.to_str().unwrap();
    let (r, stderr, tmp) = journey(Some("machines/second.toml"), plant);
    // The second design is no rhombus: its effective tool mass is checked within 10 % of the
    // bodies lumped (0.1648 kg).
    let (max, rms) = check_journey(&r, &stderr, &tmp.path().join("out"), plant, 0.1);
    // Its 2 µm instrument: the goal scaled (2.0 / 0.6 µm).
    assert_eq!(r["final"]["target_max_um"], 2.0);
    assert!(max <= 2.0 && rms <= 0.6, "{max} / {rms} µm");
    assert_eq!(r["machine"], "second");
    // Its octagon inside the grid's rectangle: the corners' nodes estimated, not measured.
    let est = r["grid"][1]["nodes_estimated"].as_u64().unwrap();
    assert!(
        est > 0 && est < r["grid"][1]["nodes"].as_u64().unwrap() / 2,
        "{est}"
    );
}

#[test]
fn bad_input_is_a_clear_error_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let root = workspace_root().join("host-sim");
    let second = root.join("machines/second.toml");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "--qemu".into(),
                "--firmware".into(),
                tmp.path().join("no-such.elf").display().to_string(),
            ],
            "--firmware",
        ),
        (
            vec![
                "--qemu".into(),
                "--machine".into(),
                second.display().to_string(),
                "--plant".into(),
                "paper".into(),
            ],
            "machine",
        ),
        (
            vec![
                "--tcp".into(),
                "127.0.0.1:1".into(),
                "--timeout-s".into(),
                "1".into(),
            ],
            "127.0.0.1:1",
        ),
        (
            vec![
                "--tcp".into(),
                "127.0.0.1:1".into(),
                "--plant".into(),
                "paper".into(),
                "--noise-um".into(),
                "2".into(),
            ],
            "--qemu only",
        ),
        (
            vec!["--qemu".into(), "--grid-rounds".into(), "3".into()],
            "grid rounds",
        ),
        // An excitation too short to identify anything: refused before the controller starts.
        (
            vec!["--qemu".into(), "--excitation-section-s".into(), "1".into()],
            "dynamics: excitation section length",
        ),
    ];
    for (args, says) in cases {
        let mut all = vec!["commission".to_string()];
        all.extend(args.iter().cloned());
        all.extend(["--out".into(), out.display().to_string()]);
        let a: Vec<&str> = all.iter().map(String::as_str).collect();
        let o = host_sim(&a);
        let (_, stderr) = text(&o);
        assert!(!o.status.success(), "{a:?}: {stderr}");
        assert!(stderr.contains(says), "{a:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{a:?}: {stderr}");
        assert!(!out.exists(), "{a:?} left {}", out.display());
    }
}

/// The moving machine's steps of the journey (`commission::dynamics`) on the co-simulated
/// controller, with the paper plant's 40 g tool and with a 0.3 kg cutting head on the same
/// machine (host-sim/plants/paper-head-300g.toml; the axis inertia 1.8 times the one the
/// settings' gains are designed for), whose controller runs the commissioning image (no
/// dynamics block: the settings' gains with the disturbance observer off, the gains' constant
/// inertia fed forward): the excitation identified, the check motion run at the machine's rated
/// 5 g, the identified block uploaded (the controller designs its gains for it), the check
/// motion again.
///
/// What must come out: the heavier head's tool mass (its bodies lumped at the tool point,
/// 0.425 kg against the design's 0.165) within 5 %, and with its block fed forward the heavier
/// head's check motion following as closely as the 40 g machine's with its own (RMS within
/// 0.03 µm), within 1 µm at every sample, and better than without the block. Deterministic
/// (the co-simulation); `-- --nocapture` prints the figures (docs/guides/commission.md).
#[test]
fn a_heavier_head_is_identified_and_follows_as_the_design_with_its_dynamics() {
    use host_sim::commission::dynamics::{check_run, identify, MovingOptions};
    use host_sim::commission::images::{model_image, Extras};
    use host_sim::commission::motion::wait_still;
    use host_sim::cosim::{commissioning_image, CoSim, CoSimOptions};
    use host_sim::dynamics::excitation::ExcitationOptions;
    use host_sim::link::link_protocol::{Command, HomingState, Response};
    use host_sim::link::upload_calibration;
    use host_sim::machine_spec::MachineSpec;
    use std::time::Duration;

    let spec = MachineSpec::paper();
    let o = MovingOptions {
        excitation: ExcitationOptions {
            section_s: 4.0,
            ..ExcitationOptions::default()
        },
        // The machine's rated acceleration (the check motion reaches 4.4 g of it).
        check_accel_mm_s2: 5.0 * host_sim::machine_spec::STANDARD_GRAVITY_MM_S2,
        ..MovingOptions::default()
    };
    // (tool mass identified, its truth, check motion before and after: (max, rms) µm)
    let run = |plant: &str| {
        let plant = PlantConfig::by_name(plant).unwrap();
        let mut opts = CoSimOptions::new(
            spec.clone(),
            plant.clone(),
            commissioning_image(&spec).unwrap(),
        );
        opts.firmware = Some(build_firmware_bin(&workspace_root(), "firmware"));
        opts.frame_timeout = Duration::from_secs(120);
        let mut sim = CoSim::start(&opts).unwrap();
        let mut link = sim.link(Duration::from_secs(120)).unwrap();
        link.request(Command::Home).unwrap();
        while link.status().unwrap().homing != HomingState::Homed {
            assert!(sim.simulated_s() < 30.0, "not homed after 30 s");
            sim.run_for_s(0.05).unwrap();
        }
        let id = identify(&mut link, &spec, &spec.nominal, &o).unwrap();
        let (before, _, _) = check_run(&mut link, &spec, &spec.nominal, &o).unwrap();
        let image = model_image(
            &spec.nominal,
            &spec,
            Extras {
                dynamics: Some(&id.block),
                backlash: None,
            },
        )
        .unwrap();
        wait_still(&mut link, 60.0).unwrap();
        let image_id = upload_calibration(&mut link, &image, &mut |_, _| {}).unwrap();
        let start = sim.simulated_s();
        loop {
            match link.request(Command::Identify).unwrap() {
                Response::Identity(i) if i.calibration_id == Some(image_id) => break,
                _ => assert!(
                    sim.simulated_s() < start + 10.0,
                    "the image is not in force"
                ),
            }
        }
        let (after, _, _) = check_run(&mut link, &spec, &spec.nominal, &o).unwrap();
        let truth = Plant::new(&plant, 1).true_dynamics().tool_mass_kg;
        (
            id.report.tool_mass_kg,
            truth,
            [before.max_following_um, before.rms_following_um],
            [after.max_following_um, after.rms_following_um],
        )
    };
    let design = run("paper");
    let heavy = run(workspace_root()
        .join("host-sim/plants/paper-head-300g.toml")
        .to_str()
        .unwrap());
    for (name, r) in [("40 g tool", design), ("0.3 kg head", heavy)] {
        eprintln!(
            "COMMISSION_HEAD {name}: tool mass {:.4} kg identified (plant {:.4}); check motion \
             following error max / RMS {:.2} / {:.3} um without the dynamics, {:.2} / {:.3} um \
             with them",
            r.0, r.1, r.2[0], r.2[1], r.3[0], r.3[1]
        );
    }
    let (m, truth, before, after) = heavy;
    assert!((m - truth).abs() < 0.05 * truth, "{m} kg vs {truth} kg");
    assert!(after[1] < 0.7 * before[1], "{before:?} -> {after:?}");
    assert!(
        after[0] <= 1.0 && after[0] < before[0],
        "{before:?} -> {after:?}"
    );
    assert!(
        after[1] <= design.3[1] + 0.03,
        "{after:?} vs {:?}",
        design.3
    );
}

#[test]
fn another_build_of_the_second_machine_reaches_the_goal_through_the_controller() {
    let root = workspace_root().join("host-sim");
    let base =
        host_sim::plant::PlantConfig::by_name(root.join("plants/second.toml").to_str().unwrap())
            .unwrap();
    let plant = builds::another_build(&base, [5.0, -8.0], 2002);
    // The instrument stands far away and turned: the registration must find it.
    let frame = plant.instrument.frame_offset_mm;
    assert!(frame[0].hypot(frame[1]) > 500.0, "{frame:?}");
    let tmp = tempfile::tempdir().unwrap();
    let plant_file = tmp.path().join("another_build.toml");
    std::fs::write(&plant_file, plant.to_toml()).unwrap();
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let out = tmp.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["commission", "--qemu", "--firmware"])
        .arg(&elf)
        .arg("--machine")
        .arg(root.join("machines/second.toml"))
        .arg("--plant")
        .arg(&plant_file)
        .args([
            "--noise-um",
            "1",
            "--grid-rounds",
            "1",
            "--verify-targets",
            "60",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("host-sim runs");
    let stderr = String::from_utf8_lossy(&o.stderr);
    eprintln!("{stderr}");
    assert!(o.status.success(), "{stderr}");
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let f = &r["final"];
    let (max, rms) = (f["max_um"].as_f64().unwrap(), f["rms_um"].as_f64().unwrap());
    assert_eq!(f["n_targets"], 60);
    assert_eq!(f["target_max_um"], 1.0);
    assert!(max <= 1.0 && rms <= 0.3, "{max} / {rms} µm");
    assert_eq!(f["met"], true);
    // The instrument's frame registered where it stood: its offset to well under a millimetre;
    // its rotation to a few hundredths of a degree beside the build's mean encoder-zero error
    // (the machine frame's rotation is the encoder zeros' mean, the registration's convention).
    let reg = &r["fit"]["instrument_frame"];
    for i in 0..2 {
        let off = reg["offset_mm"][i].as_f64().unwrap();
        assert!((off - frame[i]).abs() < 0.5, "{reg} against {frame:?}");
    }
    let zero_error_deg =
        0.5 * (plant.drive_1.encoder_offset_deg - 5.0 + plant.drive_2.encoder_offset_deg + 8.0);
    let rot = reg["rotation_deg"].as_f64().unwrap();
    assert!(
        (rot - plant.instrument.frame_rotation_deg - zero_error_deg).abs() < 0.03,
        "{reg}"
    );
    // A sixth of the lattice outside the octagon, estimated; the grid's smoothing decided by
    // the measured nodes (a few tens of effective nodes, not one per node).
    let g = &r["grid"][0];
    let est = g["nodes_estimated"].as_u64().unwrap();
    assert!(est > 50, "{est}");
    let eff = g["noise"]["effective_nodes"].as_f64().unwrap();
    assert!(eff < 60.0, "{eff} effective nodes");
}
