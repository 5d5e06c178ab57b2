//! The moving machine through the command line: the dynamics identified through the controller
//! (the real firmware under QEMU, scenario `link`: the excitation streamed over its link, its
//! telemetry recorded and fitted), the same from the recorded files, the moving machine's
//! diagnosis of that telemetry against the image's dynamics block, and the refusals of logs
//! that cannot be used; and the identification through the co-simulated controller (the same
//! firmware under QEMU driving host-sim's six-bar plant in lockstep: deterministic, the tight
//! check of what comes out).
//!
//! The QEMU firmware's plant is the hidden robot's dynamics with rotors, friction and masses
//! that are not the image's (`firmware/src/board/qemu/machine.rs`: every inertia and the tool
//! mass 20 % off, friction under-estimated): the identification must find the plant's, the
//! diagnosis must name what the image gets wrong.
//!
//! Needs the thumbv7em-none-eabihf target and qemu-system-arm (`bash tests/run-all.sh`
//! installs both); the firmware is built into `target/system-tests`, as `link_qemu` does.
use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Output};

use serde_json::Value;

#[allow(dead_code)]
mod machine {
    include!("../../firmware/src/board/qemu/machine.rs");
}
mod synthetic {
    include!("../../firmware/src/board/qemu/synthetic_image.rs");
}

include!("../../tests/support/firmware_build.rs");

/// The tests one after the other: the plain QEMU run's virtual clock races the host's link, and
/// a second QEMU or the files test's fits beside it slow the host's side (the streamed
/// excitation then differs from run to run, and so does what is identified from it).
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static QEMU: std::sync::Mutex<()> = std::sync::Mutex::new(());
    QEMU.lock().unwrap_or_else(|e| e.into_inner())
}

/// QEMU with the firmware; stopped when dropped.
struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        // SIGTERM to run-one.sh's `timeout`, which passes it on to QEMU.
        let _ = Command::new("kill").arg(self.0.id().to_string()).status();
        let _ = self.0.wait();
    }
}

fn host_sim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .expect("host-sim runs")
}

/// Runs host-sim, requires success, returns its JSON (stdout) or its table when not JSON.
fn ok(args: &[&str]) -> String {
    let out = host_sim(args);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "host-sim {args:?} failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn json(text: &str) -> Value {
    serde_json::from_str(text).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
}

/// Runs host-sim, requires failure, returns its stderr.
fn refused(args: &[&str]) -> String {
    let out = host_sim(args);
    assert!(
        !out.status.success(),
        "host-sim {args:?} should have been refused: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn params(d: &Value) -> [f64; 9] {
    let f = |k: &str, i: usize| d[k][i].as_f64().unwrap();
    [
        f("motor_inertia_kg_m2", 0),
        f("motor_inertia_kg_m2", 1),
        d["tool_mass_kg"].as_f64().unwrap(),
        f("distal_inertia_kg_m2", 0),
        f("distal_inertia_kg_m2", 1),
        f("viscous_nm_s_per_rad", 0),
        f("viscous_nm_s_per_rad", 1),
        f("coulomb_nm", 0),
        f("coulomb_nm", 1),
    ]
}

/// The inertias and tool mass of `params` with each distal inertia in the other motor's, as
/// [`base`] lumps the plant's (on the paper's rhombus no motion tells them apart).
fn lumped(p: &[f64; 9]) -> [f64; 3] {
    [p[0] + p[4], p[1] + p[3], p[2]]
}

fn read_json(p: &Path) -> Value {
    json(&std::fs::read_to_string(p).unwrap())
}

/// The hidden robot's parameters of `d` with the distal inertias in the other motor's (what
/// the identification fits on the paper's rhombus).
fn base(d: &kinematics_core::FiveBarDynamics<f32>, rotor: [f32; 2]) -> [f64; 3] {
    [
        f64::from(rotor[0] + d.motor_inertia_kg_m2[0] + d.distal_inertia_kg_m2[1]),
        f64::from(rotor[1] + d.motor_inertia_kg_m2[1] + d.distal_inertia_kg_m2[0]),
        f64::from(d.tool_mass_kg),
    ]
}

#[test]
fn the_dynamics_are_identified_and_diagnosed_through_the_qemu_firmware() {
    let _alone = one_at_a_time();
    let elf = build_firmware_bin(&workspace_root(), "firmware");
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let addr = format!("127.0.0.1:{port}");
    let work = tempfile::tempdir().unwrap();
    let qemu = Command::new("bash")
        .arg(workspace_root().join("firmware/qemu/run-one.sh"))
        .arg(&elf)
        .arg("link")
        .arg(work.path().join("qemu"))
        .env("QEMU_SERIAL", format!("tcp:{addr},server=on,wait=off"))
        .env("QEMU_TIMEOUT_S", "120")
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("bash and qemu-system-arm (bash tests/run-all.sh installs them)");
    let _qemu = Qemu(qemu);
    let link = ["link", "--tcp", addr.as_str(), "--timeout-s", "10"];
    ok(&[&link[..], &["home"]].concat());
    let dir = work.path();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_owned();
    let image = synthetic::synthetic_image(1.0);
    std::fs::write(p("grid.bin"), &image).unwrap();
    std::fs::write(p("other.bin"), synthetic::synthetic_image(-1.0)).unwrap();
    let tcp = ["--tcp", addr.as_str(), "--timeout-s", "10"];
    // An image that is not the one in force: its model is not what reads the encoders.
    let e = refused(
        &[
            &["identify"],
            &tcp[..],
            &["--grid", &p("other.bin"), "--out", &p("x.json")],
        ]
        .concat(),
    );
    assert!(e.contains("the controller runs calibration"), "{e}");
    assert!(!dir.join("x.json").exists());

    // Through the controller: the excitation streamed, its telemetry fitted.
    let start = std::time::Instant::now();
    let out = json(&ok(&[
        &["identify"],
        &tcp[..],
        &[
            "--grid",
            &p("grid.bin"),
            // The default 8 s sections: the QEMU board's coarse encoders leave the tool mass a
            // standard deviation of 4 % with 4 s sections, 3 % with these.
            // QEMU's clock outruns its UART: knots 80 ms apart keep the buffer fed (at 50 ms
            // the stream starves now and then: an underrun, refused with the fault's name).
            "--knot-ms",
            "80",
            "--out",
            &p("dynamics.json"),
            "--telemetry-csv",
            &p("telemetry.csv"),
            "--knots-out",
            &p("knots.csv"),
        ],
    ]
    .concat()));
    let wall_s = start.elapsed().as_secs_f64();
    println!(
        "MOVING_QEMU fit: {} used, {} at rest, {} saturated, residual {} N·m RMS, knots matched \
         within {} mm",
        out["samples_used"],
        out["samples_at_rest"],
        out["samples_saturated"],
        out["residual_rms_nm"],
        out["match_error_mm"]
    );
    let all = params(&read_json(&dir.join("dynamics.json")));
    let got = {
        let l = lumped(&all);
        [
            l[0], l[1], l[2], all[3], all[4], all[5], all[6], all[7], all[8],
        ]
    };
    let truth = base(&machine::LINKAGE, machine::ROTOR_INERTIA_KG_M2);
    let image_block = base(&machine::IMAGE_DYNAMICS, [0.0; 2]);
    println!(
        "MOVING_QEMU identify: {} telemetry samples in {wall_s:.1} s; I1 {:.4e} I2 {:.4e} m {:.4} \
         (plant {:.4e} {:.4e} {:.4}; image {:.4e} {:.4e} {:.4}), viscous {:.4} {:.4} coulomb {:.4} {:.4} \
         (plant 0.01, 0.03)",
        out["telemetry_samples"],
        got[0],
        got[1],
        got[2],
        truth[0],
        truth[1],
        truth[2],
        image_block[0],
        image_block[1],
        image_block[2],
        got[5],
        got[6],
        got[7],
        got[8]
    );
    for k in 0..3 {
        assert!(
            (got[k] - truth[k]).abs() < 0.1 * truth[k],
            "parameter {k}: {} vs the plant's {}",
            got[k],
            truth[k]
        );
        assert!((got[k] - truth[k]).abs() < 0.5 * (image_block[k] - truth[k]).abs());
    }
    // QEMU's virtual clock runs ahead of the host's link by a margin that changes from run to
    // run, and with it which samples the telemetry carries: the estimates scatter by their
    // standard deviations from run to run (tool mass 3 %; 10 % above is half the image's 20 %
    // error), the viscous friction (the smallest torque in the excitation) by up to 35 %. The
    // co-simulated controller's run is deterministic: its check is the tight one.
    for (k, want, within) in [
        (5, 0.01, 0.45),
        (6, 0.01, 0.45),
        (7, 0.03, 0.3),
        (8, 0.03, 0.3),
    ] {
        assert!(
            (got[k] - want).abs() < within * want,
            "friction {k}: {}",
            got[k]
        );
    }
    let telemetry = std::fs::read_to_string(dir.join("telemetry.csv")).unwrap();
    assert!(
        telemetry.starts_with("# machine=paper digest="),
        "{telemetry:.200}"
    );

    // The same from the files.
    ok(&[
        "identify",
        "--telemetry",
        &p("telemetry.csv"),
        "--knots",
        &p("knots.csv"),
        "--grid",
        &p("grid.bin"),
        "--out",
        &p("again.json"),
    ]);
    assert_eq!(params(&read_json(&dir.join("again.json"))), all);

    // What the image gets wrong, named from the same telemetry.
    let table = ok(&[
        "diagnose",
        "--telemetry",
        &p("telemetry.csv"),
        "--knots",
        &p("knots.csv"),
        "--grid",
        &p("grid.bin"),
        "--out",
        &p("report.json"),
        "--out-dynamics",
        &p("updated.json"),
    ]);
    println!("MOVING_QEMU diagnose:\n{table}");
    let r = read_json(&dir.join("report.json"));
    let named: Vec<&str> = r["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["effect"].as_str().unwrap())
        .collect();
    // The inertias' errors (20 % each way) are named in every run. The tool mass's 20 % is
    // named when this run sees it beyond the diagnosis' tenth: with the run's scatter (its
    // standard deviation 3 %) not always, so it is not required here (the dynamics unit tests name a hidden tool
    // mass on plants whose runs are reproducible).
    assert!(named.contains(&"motor_inertia"), "{named:?}");
    let (initial, last) = (
        r["initial_rms_um"].as_f64().unwrap(),
        r["final_rms_um"].as_f64().unwrap(),
    );
    assert!(last <= 0.5 * initial, "{initial} -> {last} um");
    assert!(r["confounded"].is_array() && r["unexplained"].is_boolean());
    // The block keeps the image's distal inertias: lumped as the plant's are compared.
    // The updated block is the image's moved towards the plant: most of the inertias' error
    // gone; the tool mass closer than the image's (this run's scatter, above, bounds how much:
    // its tool-mass estimate has landed up to 16 % off between runs; the co-simulated test
    // below, which is deterministic, holds it within 5 %).
    let updated = lumped(&params(&read_json(&dir.join("updated.json"))));
    for k in 0..3 {
        let share = if k == 2 { 1.0 } else { 0.6 };
        assert!(
            (updated[k] - truth[k]).abs() < share * (image_block[k] - truth[k]).abs(),
            "updated {k}: {} vs the plant's {} (image {})",
            updated[k],
            truth[k],
            image_block[k]
        );
    }
}

/// The files' path without a controller, and the refusals.
#[test]
fn the_moving_machine_from_files_and_the_logs_refused() {
    let _alone = one_at_a_time();
    let work = tempfile::tempdir().unwrap();
    let dir = work.path();
    let p = |name: &str| dir.join(name).to_str().unwrap().to_owned();
    ok(&[
        "identify",
        "--plant",
        "paper",
        "--section-s",
        "4",
        "--out",
        &p("d0.json"),
        "--telemetry-csv",
        &p("t.csv"),
        "--knots-out",
        &p("k.csv"),
    ]);
    let d0 = params(&read_json(&dir.join("d0.json")));
    ok(&[
        "identify",
        "--telemetry",
        &p("t.csv"),
        "--knots",
        &p("k.csv"),
        "--out",
        &p("d1.json"),
    ]);
    let d1 = params(&read_json(&dir.join("d1.json")));
    for k in 0..9 {
        assert!(
            (d1[k] - d0[k]).abs() <= 1e-6 * (1e-6 + d0[k].abs()),
            "{d0:?} {d1:?}"
        );
    }
    // The dynamics file names its machine (the record's digest, as the log's first line does)
    // and is refused on another machine, naming both.
    let file = read_json(&dir.join("d0.json"));
    assert_eq!(file["machine"]["name"], "paper", "{file}");
    let digest = file["machine"]["digest"].as_str().unwrap();
    assert_eq!(digest.len(), 8, "{file}");
    let log = std::fs::read_to_string(dir.join("t.csv")).unwrap();
    assert!(
        log.starts_with(&format!("# machine=paper digest={digest} ")),
        "{log:.120}"
    );
    let second = workspace_root().join("host-sim/machines/second.toml");
    let second_plant = workspace_root().join("host-sim/plants/second.toml");
    let e = refused(&[
        "simulate",
        "--plant",
        second_plant.to_str().unwrap(),
        "--machine",
        second.to_str().unwrap(),
        "--dynamics",
        &p("d0.json"),
        "--seconds",
        "0.1",
    ]);
    assert!(
        e.contains("--dynamics") && e.contains("machine 'paper'") && e.contains("'second'"),
        "{e}"
    );
    // Flags out of range, named, before anything runs or is written.
    for (flag, value) in [
        ("--decimation", "5"),
        ("--section-s", "0"),
        ("--accel-g", "0"),
        ("--knot-ms", "1000"),
    ] {
        let e = refused(&[
            "identify",
            "--plant",
            "paper",
            flag,
            value,
            "--out",
            &p("x.json"),
        ]);
        assert!(e.contains(flag), "{flag}: {e}");
    }
    // No controller at the address: said so, with where to read how to start one.
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .unwrap()
        .port();
    let e = refused(&[
        "identify",
        "--tcp",
        &format!("127.0.0.1:{port}"),
        "--out",
        &p("x.json"),
    ]);
    assert!(e.contains("is a controller listening there"), "{e}");
    assert!(!dir.join("x.json").exists());
    // Another machine's log.
    let e = refused(&[
        "identify",
        "--telemetry",
        &p("t.csv"),
        "--machine",
        second.to_str().unwrap(),
        "--out",
        &p("x.json"),
    ]);
    assert!(
        e.contains("machine 'paper'") && e.contains("--machine"),
        "{e}"
    );
    // A diagnosis needs the dynamics the controller fed forward.
    let e = refused(&[
        "diagnose",
        "--telemetry",
        &p("t.csv"),
        "--out",
        &p("x.json"),
    ]);
    assert!(e.contains("--dynamics"), "{e}");
    // A log cut short.
    let text = std::fs::read_to_string(dir.join("t.csv")).unwrap();
    let short: String = text.lines().take(300).map(|l| format!("{l}\n")).collect();
    std::fs::write(dir.join("short.csv"), short).unwrap();
    let e = refused(&[
        "diagnose",
        "--telemetry",
        &p("short.csv"),
        "--knots",
        &p("k.csv"),
        "--dynamics",
        &p("d0.json"),
        "--out",
        &p("x.json"),
    ]);
    assert!(e.contains("record the whole motion"), "{e}");
    // Not a number: refused naming the line and column.
    let nan: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 9 {
                let mut f: Vec<&str> = l.split(',').collect();
                f[7] = "NaN";
                f.join(",")
            } else {
                l.to_owned()
            }
        })
        .collect();
    std::fs::write(dir.join("nan.csv"), nan.join("\n")).unwrap();
    let e = refused(&[
        "identify",
        "--telemetry",
        &p("nan.csv"),
        "--out",
        &p("x.json"),
    ]);
    assert!(e.contains("line 10") && e.contains("torque_1_nm"), "{e}");
    assert!(
        !dir.join("x.json").exists(),
        "nothing written by a refused run"
    );
    // The diagnosis of the log of its own model: nothing named; the contract's keys.
    ok(&[
        "diagnose",
        "--telemetry",
        &p("t.csv"),
        "--knots",
        &p("k.csv"),
        "--dynamics",
        &p("d0.json"),
        "--out",
        &p("r.json"),
    ]);
    let r = read_json(&dir.join("r.json"));
    for key in ["steps", "confounded", "unexplained", "final_rms_um"] {
        assert!(!r[key].is_null(), "{key}: {r}");
    }
    // The host loop writes the same format.
    ok(&[
        "simulate",
        "--plant",
        "paper",
        "--plant-model",
        "fivebar",
        "--trajectory",
        "excitation",
        "--seconds",
        "1",
        "--telemetry-csv",
        &p("s.csv"),
    ]);
    let s = std::fs::read_to_string(dir.join("s.csv")).unwrap();
    let mut lines = s.lines();
    assert!(lines.next().unwrap().starts_with("# machine=paper digest="));
    assert!(lines
        .next()
        .unwrap()
        .starts_with("tick,setpoint_x_mm,setpoint_y_mm,"));
    assert_eq!(s.lines().count(), 2 + 100, "1 s at 100 Hz");
}

/// The dynamics identified through the co-simulated controller: the production firmware under
/// QEMU driving the paper six-bar plant in lockstep (`host_sim::cosim`), homed through its
/// link, the excitation streamed over the link (two sections of `SECTION_S`), the telemetry
/// fitted. What comes out is the plant's: its inertias and tool mass (the distal inertias
/// lumped into the other motor's, as the fit carries them on this rhombus) within
/// `TOLERANCE`, its friction within 30 %.
///
/// The tolerance: the fit's own standard deviations on sections this short are 2 % of the
/// inertias and the tool mass (asserted below 3 %: the excitation still separates them); the
/// estimates are 1.7, 2.8 and 1.0 % off the plant's (the `MOVING_COSIM` line), so 5 % holds
/// them with room while a fit that lost a parameter's share (a 20 % error is what the QEMU
/// board's image carries) fails. The co-simulated run is deterministic (the same figures in
/// every run), so a failure is a change of the firmware, the plant or the fit, not luck.
/// 15 s simulated: 2 to 9 s of wall time (7.6 simulated s per wall s on an idle machine, 2.5
/// on a loaded one), after the firmware's build.
#[test]
fn the_dynamics_are_identified_through_the_cosimulated_controller() {
    let _alone = one_at_a_time();
    use host_sim::cosim::{commissioning_image, CoSim, CoSimOptions};
    use host_sim::dynamics::excitation::ExcitationOptions;
    use host_sim::dynamics::identify::identify_through_link;
    use host_sim::dynamics::samples::SampleOptions;
    use host_sim::dynamics::session::LinkRunOptions;
    use host_sim::link::link_protocol::{Command, HomingState};
    use host_sim::machine_spec::MachineSpec;
    use host_sim::plant::{Plant, PlantConfig};
    use kinematics_core::ServoConfig;
    use std::time::{Duration, Instant};

    const SECTION_S: f64 = 4.0;
    const TOLERANCE: f64 = 0.05;
    let spec = MachineSpec::paper();
    let plant = PlantConfig::paper();
    let mut opts = CoSimOptions::new(
        spec.clone(),
        plant.clone(),
        commissioning_image(&spec).unwrap(),
    );
    opts.firmware = Some(build_firmware_bin(&workspace_root(), "firmware"));
    opts.frame_timeout = Duration::from_secs(120);
    let start = Instant::now();
    let mut sim = CoSim::start(&opts).unwrap();
    let mut link = sim.link(Duration::from_secs(120)).unwrap();
    link.request(Command::Home).unwrap();
    while link.status().unwrap().homing != HomingState::Homed {
        assert!(sim.simulated_s() < 30.0, "not homed after 30 s");
        sim.run_for_s(0.05).unwrap();
    }
    let homed_s = sim.simulated_s();
    let homed_wall_s = start.elapsed().as_secs_f64();
    let run = LinkRunOptions {
        spec: spec.clone(),
        excitation: ExcitationOptions {
            section_s: SECTION_S,
            ..ExcitationOptions::default()
        },
        decimation: 20,
        slack: Duration::from_secs(120),
        // The co-simulated link's reads advance the simulation: no wall-clock wait.
        poll: Duration::ZERO,
    };
    let samples = SampleOptions {
        model: spec.nominal,
        min_transmission: spec.min_transmission,
        torque_limit_nm: ServoConfig::default()
            .axes
            .map(|a| f64::from(a.torque_limit_nm)),
    };
    let id = identify_through_link(&mut link, &run, &samples, &mut |_, _| {}).unwrap();
    let stats = sim.stats();
    let fit = &id.result.identified;
    let got = fit.dynamics.to_array();
    // One standard deviation of each parameter, in `to_array`'s order.
    let sd: Vec<f64> = kinematics_core::dynamics::PARAMETER_NAMES
        .iter()
        .map(|name| {
            let (_, s) = fit.std_dev.iter().find(|(n, _)| n == name).unwrap();
            *s
        })
        .collect();
    let mut truth = Plant::new(&plant, 1).true_dynamics();
    truth.motor_inertia_kg_m2[0] += truth.distal_inertia_kg_m2[1];
    truth.motor_inertia_kg_m2[1] += truth.distal_inertia_kg_m2[0];
    let want = [
        truth.motor_inertia_kg_m2[0],
        truth.motor_inertia_kg_m2[1],
        truth.tool_mass_kg,
    ];
    println!(
        "MOVING_COSIM identify: {} telemetry samples; homed at {homed_s:.1} s simulated \
         ({homed_wall_s:.1} s wall), {:.1} s simulated in {:.1} s wall ({:.2} simulated s per \
         wall s; CPU: QEMU {:?} s, host {:?} s); I1 {:.4e} ± {:.1e} I2 {:.4e} ± {:.1e} m {:.4} \
         ± {:.1e} (plant {:.4e} {:.4e} {:.4}), viscous {:.4} {:.4} coulomb {:.4} {:.4} (plant \
         {:.4} {:.4}, {:.4} {:.4}); worst servo step {:.1} us",
        id.result.telemetry_samples,
        stats.simulated_s,
        start.elapsed().as_secs_f64(),
        stats.speed,
        stats.qemu_cpu_s,
        stats.host_cpu_s,
        got[0],
        sd[0],
        got[1],
        sd[1],
        got[2],
        sd[2],
        want[0],
        want[1],
        want[2],
        got[5],
        got[6],
        got[7],
        got[8],
        truth.viscous_nm_s_per_rad[0],
        truth.viscous_nm_s_per_rad[1],
        truth.coulomb_nm[0],
        truth.coulomb_nm[1],
        stats.worst_step_us
    );
    assert!(id.result.machine_named, "the log names its machine");
    for k in 0..3 {
        assert!(
            (got[k] - want[k]).abs() < TOLERANCE * want[k],
            "parameter {k}: {} vs the plant's {}",
            got[k],
            want[k]
        );
        assert!(sd[k] < 0.03 * want[k], "parameter {k}: ± {}", sd[k]);
    }
    let friction = [
        (5, truth.viscous_nm_s_per_rad[0]),
        (6, truth.viscous_nm_s_per_rad[1]),
        (7, truth.coulomb_nm[0]),
        (8, truth.coulomb_nm[1]),
    ];
    for (k, want) in friction {
        assert!(
            (got[k] - want).abs() < 0.3 * want,
            "friction {k}: {} vs the plant's {want}",
            got[k]
        );
    }
    assert_eq!(stats.overruns, 0, "{stats:?}");
}
