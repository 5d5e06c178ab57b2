//! Co-simulation: the production firmware under QEMU drives host-sim's six-bar plant in lockstep
//! (`host_sim::cosim`), every CI run.
//!
//! * One journey, run twice: boot unhomed, home through the link (index marks), a move and a
//!   streamed figure through the link with telemetry on, the plant's true tool point where the
//!   controller put it; the two runs exchange the same bytes (digest of every frame both ways,
//!   the link's bytes and telemetry, the plant's final state bit for bit) although the second
//!   one's host pauses between steps (virtual time stands still while the firmware waits), no
//!   sample lost, repeated or late, and the firmware's worst servo step is reported.
//! * The firmware's own check of the lockstep: a host that answers the wrong sample ends the
//!   run with the firmware's failure line.
//! * QEMU never outlives the co-simulation: killed when dropped (also on a panic), and it ends
//!   by itself when the host's pipes close.
//! * Bad input: a firmware file that is not there (named, or by `HOST_SIM_FIRMWARE`), no QEMU,
//!   an ELF without co-simulation, a region without an image (the drives never enable and
//!   homing is refused), a power-on pose outside the workspace, an image larger than the region.
//!
//! Needs qemu-system-arm and the thumbv7em-none-eabihf target (`bash tests/run-all.sh`
//! installs both). The firmware is built into `target/system-tests` as the other QEMU tests do.
use std::path::{Path, PathBuf};
use std::time::Duration;

use host_sim::cosim::qemu::Qemu;
use host_sim::cosim::{commissioning_image, CoSim, CoSimError, CoSimOptions, CoSimStats};
use host_sim::link::link_protocol::{
    calibration_image_id, Command, HomingState, ModeCode, Response, StatusReport, TelemetrySample,
};
use host_sim::link::{figure_knots, stream_knots, ClientError, LinkClient};
use host_sim::machine_spec::MachineSpec;
use host_sim::plant::PlantConfig;

include!("../../tests/support/firmware_build.rs");

fn firmware() -> PathBuf {
    build_firmware_bin(&workspace_root(), "firmware")
}

/// The paper plant as built to its drawing: no part errors, clearances or encoder offsets,
/// a noiseless instrument in the machine's frame; its dynamics, friction, backlash (20 µrad)
/// and encoders (2^20 counts per motor revolution, gear 10) are the paper plant's. The nominal
/// model is then the truth, so where the controller says the tool is, it must be (within the
/// backlash and the servo's rest).
fn plant_as_drawn() -> PlantConfig {
    let mut p = PlantConfig::paper();
    p.sixbar.errors = Default::default();
    p.sixbar.pin_clearance_mm = 0.0;
    p.sixbar.bar_end_clearance_mm = 0.0;
    p.drive_1.encoder_offset_deg = 0.0;
    p.drive_2.encoder_offset_deg = 0.0;
    p.instrument.frame_offset_mm = [0.0; 2];
    p.instrument.noise_sigma_um = 0.0;
    p
}

fn options(elf: &Path) -> CoSimOptions {
    let spec = MachineSpec::paper();
    let image = commissioning_image(&spec).unwrap();
    let mut opts = CoSimOptions::new(spec, plant_as_drawn(), image);
    opts.firmware = Some(elf.to_path_buf());
    opts.frame_timeout = Duration::from_secs(120);
    opts
}

const TIMEOUT: Duration = Duration::from_secs(120);

fn dist_um(a: [f64; 2], b: [f64; 2]) -> f64 {
    1e3 * (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Runs the simulation in steps of `step_s` until `done` says so (at most `limit_s`).
fn run_until(
    sim: &mut CoSim,
    link: &mut LinkClient<host_sim::cosim::CoSimLink>,
    limit_s: f64,
    done: impl Fn(&StatusReport) -> bool,
) -> StatusReport {
    let until = sim.simulated_s() + limit_s;
    loop {
        sim.run_for_s(0.05).unwrap();
        let s = link.status().unwrap();
        if done(&s) {
            return s;
        }
        assert!(
            sim.simulated_s() < until,
            "not reached in {limit_s} s: {s:?}"
        );
    }
}

/// What one run leaves to compare.
#[derive(Debug, PartialEq)]
struct Run {
    stats: CoSimStats,
    telemetry: Vec<TelemetrySample>,
    final_tool_mm: [f64; 2],
    report: String,
}

/// Boot, home, move, stream, each checked against the plant's truth. `pause`: the host stops
/// for this long (wall time) between the steps, with the firmware waiting in its exchange.
fn journey(elf: &Path, pause: Duration, exchange_log: &Path) -> Run {
    let mut opts = options(elf);
    opts.exchange_log = Some(exchange_log.to_path_buf());
    let image_id = calibration_image_id(&opts.image);
    let mut sim = CoSim::start(&opts).unwrap();
    let mut link = sim.link(TIMEOUT).unwrap();
    let mut report = String::new();

    // The production app: identifies itself with the image the region holds, boots unhomed.
    let Response::Identity(id) = link.request(Command::Identify).unwrap() else {
        panic!("identify")
    };
    assert_eq!(id.calibration_id, Some(image_id), "{id:?}");
    let s = link.status().unwrap();
    assert_eq!(
        (s.mode, s.drives_enabled),
        (ModeCode::Unhomed, false),
        "{s:?}"
    );
    assert!(!sim.plant_truth().unwrap().drive_enable);

    // Homing on the index marks, through the link.
    std::thread::sleep(pause);
    assert_eq!(link.request(Command::Home).unwrap(), Response::Done);
    let s = run_until(&mut sim, &mut link, 10.0, |s| s.mode == ModeCode::Running);
    assert_eq!(s.homing, HomingState::Homed);
    let truth = sim.plant_truth().unwrap();
    for k in 0..2 {
        // The firmware's angle is the plant's encoder reading (quantised, 0.6 µrad a count).
        assert!(
            (f64::from(s.encoder_rad[k]) - truth.encoder_rad[k]).abs() < 2e-6,
            "axis {k}: firmware {} rad, plant's encoder {} rad",
            s.encoder_rad[k],
            truth.encoder_rad[k]
        );
    }
    report += &format!("homed at {:.3} s; ", sim.simulated_s());

    // A move: the plant's tool point where the controller put it.
    std::thread::sleep(pause);
    let target = [240.0, 30.0];
    let Response::MovePlanned { duration_s } = link
        .request(Command::MoveTo {
            target_mm: [target[0] as f32, target[1] as f32],
        })
        .unwrap()
    else {
        panic!("move")
    };
    sim.run_for_s(f64::from(duration_s) + 0.3).unwrap();
    let s = link.status().unwrap();
    assert!(!s.moving && s.mode == ModeCode::Running, "{s:?}");
    let tool = sim.plant_truth().unwrap().tool_mm;
    let e = dist_um(tool, target);
    report += &format!("move: tool {e:.2} um from the target; ");
    assert!(
        e < 5.0,
        "after the move the tool is {e:.2} um from {target:?}: {tool:?}"
    );

    // A streamed figure with telemetry on: it ends at rest at its centre.
    std::thread::sleep(pause);
    let centre = [212.0, 0.0];
    let Response::MovePlanned { duration_s } = link
        .request(Command::MoveTo {
            target_mm: [centre[0] as f32, centre[1] as f32],
        })
        .unwrap()
    else {
        panic!("move")
    };
    sim.run_for_s(f64::from(duration_s) + 0.1).unwrap();
    assert_eq!(
        link.request(Command::Telemetry { decimation: 20 }).unwrap(),
        Response::TelemetryDecimation(20)
    );
    let knots = figure_knots(centre, [25.0, 20.0], 1.0, 2.0, 10);
    stream_knots(&mut link, &knots, Duration::ZERO, &mut |_, _| {}).unwrap();
    let s = run_until(&mut sim, &mut link, 5.0, |s| !s.moving);
    assert_eq!((s.mode, s.fault), (ModeCode::Running, None), "{s:?}");
    sim.run_for_s(0.3).unwrap();
    link.request(Command::Telemetry { decimation: 0 }).unwrap();
    let telemetry = link.take_telemetry();
    // 2 s of figure at 100 Hz telemetry, and every sample of it from a running servo.
    assert!(
        telemetry.len() >= 200,
        "{} telemetry samples",
        telemetry.len()
    );
    let max_fe = telemetry
        .iter()
        .map(|t| t.following_error_rad)
        .fold(0.0f32, f32::max);
    let tool = sim.plant_truth().unwrap().tool_mm;
    let e = dist_um(tool, centre);
    report +=
        &format!("stream: tool {e:.2} um from its end, max following error {max_fe:.2e} rad; ");
    assert!(
        e < 5.0,
        "after the stream the tool is {e:.2} um from {centre:?}"
    );
    assert!(max_fe < 2e-4, "following error {max_fe} rad");

    let stats = sim.shutdown().unwrap();
    Run {
        stats,
        telemetry,
        final_tool_mm: tool,
        report,
    }
}

#[test]
fn the_firmware_homes_moves_and_streams_on_the_plant_deterministically() {
    let elf = firmware();
    let dir = tempfile::tempdir().unwrap();
    let (log_a, log_b) = (dir.path().join("a.bin"), dir.path().join("b.bin"));
    let a = journey(&elf, Duration::ZERO, &log_a);
    // The second run pauses 50 ms between steps: far beyond the watchdog's 3 ms, which would
    // fire if virtual time ran on while the firmware waits for the host.
    let b = journey(&elf, Duration::from_millis(50), &log_b);
    let s = &a.stats;
    eprintln!(
        "co-simulation: {}{} samples ({:.2} s simulated) in {:.2} s wall ({:.2} simulated s per \
         wall s; QEMU {:?} s CPU, host {:?} s CPU); firmware's worst servo step {} us, {} \
         overruns; sample interval {:?} us; exchange {} bytes, digest {}",
        a.report,
        s.samples,
        s.simulated_s,
        s.wall_s,
        s.speed,
        s.qemu_cpu_s,
        s.host_cpu_s,
        s.worst_step_us,
        s.overruns,
        s.sample_interval_us,
        s.exchange_bytes,
        s.exchange_digest
    );
    // Deterministic, whatever the host's pace: the same bytes both ways, the same telemetry,
    // the same plant.
    let (bytes_a, bytes_b) = (
        std::fs::read(&log_a).unwrap(),
        std::fs::read(&log_b).unwrap(),
    );
    assert_eq!(bytes_a.len() as u64, a.stats.exchange_bytes);
    assert!(bytes_a == bytes_b, "the exchange logs differ");
    assert_eq!(a.stats.exchange_digest, b.stats.exchange_digest);
    assert_eq!(a.stats.exchange_bytes, b.stats.exchange_bytes);
    assert_eq!(a.stats.link_digest, b.stats.link_digest);
    assert_eq!(a.stats.samples, b.stats.samples);
    assert_eq!(a.telemetry, b.telemetry);
    assert_eq!(a.final_tool_mm, b.final_tool_mm);
    // Lockstep: every sample was the next one (the host refuses any other, the firmware too),
    // none late, each one period after the last on the firmware's clock (the servo's
    // interrupt latency varies by a few µs with what it preempts).
    assert_eq!(s.boots, 1);
    assert_eq!(s.late_samples, 0);
    let [lo, hi] = s.sample_interval_us.unwrap();
    assert!(lo > 480.0 && hi < 520.0, "sample interval {lo}..{hi} us");
    assert_eq!(s.overruns, 0);
    assert!(
        s.worst_step_us > 0.0 && s.worst_step_us < 500.0,
        "{}",
        s.worst_step_us
    );
    // The machine's encoders, as the plant has them.
    assert_eq!(s.encoder_counts_per_rev, [1 << 20; 2]);
    assert_eq!(s.encoder_gear_ratio, [10.0; 2]);
}

/// Sets up a co-simulation by hand (the firmware's side of the lockstep is under test).
fn handshake(elf: &Path) -> Qemu {
    use cosim_wire::{decode_up, Config, Down, Sign, Up, DOWN_LEN};
    let image = commissioning_image(&MachineSpec::paper()).unwrap();
    let mut q = Qemu::spawn(Path::new("qemu-system-arm"), elf, &image).unwrap();
    let mut up = Vec::new();
    q.read_up(&mut up, TIMEOUT).unwrap();
    assert!(matches!(decode_up(&up), Ok(Up::Hello(_))), "{up:?}");
    let mut down = vec![0u8; DOWN_LEN];
    Down::Config(Config {
        counts_per_rev: [1 << 22; 2],
        gear_ratio: [1.0; 2],
        sign: [Sign::Normal; 2],
        index_rad: [1.4, -1.4],
        max_travel_rad: [1.35, 1.35],
        home_at_boot: false,
    })
    .encode(&mut down)
    .unwrap();
    q.write_down(&down).unwrap();
    q
}

#[test]
fn the_firmware_ends_the_run_when_the_host_answers_another_sample_or_goes_away() {
    use cosim_wire::{decode_up, Down, DownSample, Up, DOWN_LEN};
    let elf = firmware();
    // A reply for sample 1 to the firmware's sample 0.
    let mut q = handshake(&elf);
    let mut up = Vec::new();
    q.read_up(&mut up, TIMEOUT).unwrap();
    let Ok(Up::Sample(s)) = decode_up(&up) else {
        panic!("{up:?}")
    };
    assert_eq!(s.sample, 0);
    let mut down = vec![0u8; DOWN_LEN];
    Down::Sample(DownSample {
        sample: 1,
        counts: [0; 2],
        index_counts: [None; 2],
        rx_len: 0,
    })
    .encode(&mut down)
    .unwrap();
    q.write_down(&down).unwrap();
    let status = q.wait_exit(TIMEOUT).unwrap();
    assert_eq!(status.code(), Some(1), "{}", q.console());
    assert!(
        q.console().contains("the host answered another sample"),
        "{}",
        q.console()
    );

    // The host's pipes close: the firmware reads the end of its pipe and ends QEMU.
    let mut q = handshake(&elf);
    q.close_pipes().unwrap();
    let status = q.wait_exit(TIMEOUT).unwrap();
    assert_eq!(status.code(), Some(1), "{}", q.console());
    assert!(q.console().contains("FAIL cosim"), "{}", q.console());
}

fn alive(pid: u32) -> bool {
    // A zombie is dead too (its parent has not reaped it yet).
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map(|s| !s.contains(") Z "))
        .unwrap_or(false)
}

#[test]
fn qemu_never_outlives_its_cosimulation() {
    let elf = firmware();
    let sim = CoSim::start(&options(&elf)).unwrap();
    let pid = sim.qemu_pid();
    assert!(alive(pid));
    drop(sim);
    assert!(!alive(pid), "QEMU {pid} still runs after the drop");

    // A panic while the co-simulation runs: the unwinding drops it.
    let opts = options(&elf);
    let pid = std::sync::Mutex::new(0);
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut sim = CoSim::start(&opts).unwrap();
        *pid.lock().unwrap() = sim.qemu_pid();
        sim.run_for_s(0.01).unwrap();
        panic!("a test failing mid-run");
    }));
    assert!(r.is_err());
    let pid = *pid.lock().unwrap();
    assert!(
        pid != 0 && !alive(pid),
        "QEMU {pid} still runs after the panic"
    );
}

#[test]
fn bad_firmware_or_image_is_a_clear_error_and_never_moves_the_machine() {
    let elf = firmware();
    // A firmware path that is not a file.
    let mut opts = options(&elf);
    opts.firmware = Some("/nonexistent/firmware.elf".into());
    let e = CoSim::start(&opts).err().expect("refused").to_string();
    assert!(
        e.contains("/nonexistent/firmware.elf") && e.contains("cargo build"),
        "{e}"
    );

    // Nor through the environment: `commission --qemu` without --firmware takes the firmware
    // `HOST_SIM_FIRMWARE` names. In a child process, so that no other test of this binary,
    // running beside this one, sees the variable.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["commission", "--qemu", "--plant", "paper", "--out"])
        .arg(&out)
        .env("HOST_SIM_FIRMWARE", "/nonexistent/env-firmware.elf")
        .output()
        .expect("host-sim runs");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{e}");
    assert!(
        e.contains("HOST_SIM_FIRMWARE") && e.contains("env-firmware.elf"),
        "{e}"
    );
    assert!(!out.exists(), "nothing written");

    // No QEMU.
    let mut opts = options(&elf);
    opts.qemu = "/nonexistent/qemu-system-arm".into();
    let e = CoSim::start(&opts).err().expect("refused").to_string();
    assert!(e.contains("apt-get install qemu-system-arm"), "{e}");

    // An ELF that never opens the exchange (the same-core test's golden binary): QEMU ends and
    // the error carries its console.
    let golden = build_firmware_bin(&workspace_root(), "golden");
    let mut opts = options(&elf);
    opts.firmware = Some(golden);
    opts.frame_timeout = Duration::from_secs(20);
    match CoSim::start(&opts) {
        Err(CoSimError::Exited { .. } | CoSimError::Timeout { .. }) => {}
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("a firmware without co-simulation was accepted"),
    }

    // An erased calibration region: the firmware refuses to engage, homing is refused, the
    // drives never enable and the plant does not move.
    let mut opts = options(&elf);
    opts.image = vec![0xff; 64 * 1024];
    let mut sim = CoSim::start(&opts).unwrap();
    let start = sim.plant_truth().unwrap();
    let mut link = sim.link(TIMEOUT).unwrap();
    let Response::Identity(id) = link.request(Command::Identify).unwrap() else {
        panic!("identify")
    };
    assert_eq!(id.calibration_id, None);
    let refused = link.request(Command::Home);
    assert!(
        matches!(refused, Err(ClientError::Refused { .. })),
        "{refused:?}"
    );
    sim.run_for_s(0.5).unwrap();
    let s = link.status().unwrap();
    assert!(!s.drives_enabled, "{s:?}");
    let end = sim.plant_truth().unwrap();
    assert!(!end.drive_enable);
    assert_eq!(start.link_rad, end.link_rad, "the machine moved");
    sim.shutdown().unwrap();

    // Options that make no co-simulation.
    let mut opts = options(&elf);
    opts.power_on_mm = Some([400.0, 0.0]);
    let e = CoSim::start(&opts).err().expect("refused").to_string();
    assert!(e.contains("power_on_mm") && e.contains("outside"), "{e}");
    let mut opts = options(&elf);
    opts.image = vec![0; 65 * 1024];
    let e = CoSim::start(&opts).err().expect("refused").to_string();
    assert!(e.contains("region"), "{e}");
}
