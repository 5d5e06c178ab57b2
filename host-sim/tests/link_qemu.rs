//! The controller in the loop: the real firmware binary under QEMU (scenario `link`: setpoints
//! from the host link; UART0 on a TCP socket), driven through `host-sim link`, every CI run:
//! identify, home, stream a 3 s figure through the workspace and check the tracking from the
//! telemetry, provoke an underrun (controlled stop, reported) and reset, a limit violation
//! (refused whole, nothing moved), a calibration upload the controller refuses (the image in
//! force stays), and garbage while the servo runs (every frame answered, no motion, no
//! deadline missed: the harness would end QEMU with FAIL).
//!
//! Needs the thumbv7em-none-eabihf target and qemu-system-arm (`bash tests/run-all.sh`
//! installs both). The firmware is built into `target/system-tests` (as the same-core test
//! does) so that this test does not wait on the lock of the `cargo test` that runs it.
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};

use serde_json::Value;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("host-sim is in the workspace").to_path_buf()
}

fn build_firmware() -> PathBuf {
    let root = workspace_root();
    let target_dir = root.join("target").join("system-tests");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(&root)
        .env("CARGO_TARGET_DIR", &target_dir)
        .args(["build", "--release", "-p", "firmware", "--bin", "firmware", "--target", "thumbv7em-none-eabihf"])
        .status()
        .expect("cargo runs");
    assert!(status.success(), "the firmware does not build");
    target_dir.join("thumbv7em-none-eabihf").join("release").join("firmware")
}

/// QEMU with the firmware; killed when dropped.
struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        // SIGTERM to run-one.sh's `timeout`, which passes it on to QEMU (SIGKILL would not be
        // passed on and would leave QEMU running).
        let _ = Command::new("kill").arg(self.0.id().to_string()).status();
        let _ = self.0.wait();
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").and_then(|l| l.local_addr()).expect("a free port").port()
}

fn host_sim(addr: &str, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["link", "--tcp", addr, "--timeout-s", "10"])
        .args(args)
        .output()
        .expect("host-sim runs")
}

/// Runs `host-sim link ARGS`, requires success, returns its JSON.
fn ok(addr: &str, args: &[&str]) -> Value {
    let out = host_sim(addr, args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "host-sim link {args:?} failed: {}\n{stdout}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{args:?}: not JSON ({e}): {stdout}"))
}

/// Runs `host-sim link ARGS`, requires failure, returns its stderr.
fn refused(addr: &str, args: &[&str]) -> String {
    let out = host_sim(addr, args);
    assert!(!out.status.success(), "host-sim link {args:?} should have been refused: {}", String::from_utf8_lossy(&out.stdout));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn xy(v: &Value) -> [f64; 2] {
    [v[0].as_f64().unwrap(), v[1].as_f64().unwrap()]
}

#[test]
fn the_host_tool_drives_the_firmware_under_qemu() {
    let elf = build_firmware();
    let port = free_port();
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
        .expect("bash and qemu-system-arm (bash tests/run-all.sh installs it)");
    let _qemu = Qemu(qemu);

    // Identify, home.
    let id = ok(&addr, &["identify"]);
    assert_eq!(id["board"], "Qemu");
    assert_eq!(id["protocol_version"], 1);
    let calibration_id = id["calibration_id"].as_u64().expect("the bundled image has an id");
    ok(&addr, &["home"]);
    let s = ok(&addr, &["status"]);
    assert_eq!((s["mode"].as_str(), s["homing"].as_str(), s["drives_enabled"].as_bool()), (Some("Running"), Some("Homed"), Some(true)));
    let home = xy(&s["setpoint_mm"]);

    // A 3 s figure (±30 mm × ±40 mm) through the workspace, tracked.
    let csv = work.path().join("telemetry.csv");
    let r = ok(&addr, &["stream", "--seconds", "3", "--knot-ms", "50", "--telemetry-csv", csv.to_str().unwrap()]);
    assert_eq!(r["knots_sent"], 60);
    assert_eq!(r["final_status"]["mode"], "Running", "{r}");
    assert!(r["final_status"]["fault"].is_null(), "{r}");
    let samples = r["telemetry_samples"].as_u64().unwrap();
    assert!(samples >= 250, "telemetry: {samples} samples for 3 s at 100 Hz");
    let max_error_urad = r["max_following_error_urad"].as_f64().unwrap();
    assert!(max_error_urad > 0.0 && max_error_urad < 50.0, "following error {max_error_urad} urad");
    let text = std::fs::read_to_string(&csv).unwrap();
    let xs: Vec<f64> = text.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    let span = xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min);
    assert!(span > 50.0, "the figure moved the setpoint over {span} mm along x (60 expected)");
    let end = xy(&r["final_status"]["setpoint_mm"]);
    assert!((end[0] - home[0]).hypot(end[1] - home[1]) < 0.01, "back at the start: {end:?} vs {home:?}");
    println!("LINK_QEMU stream: 60 knots, {samples} telemetry samples, max following error {max_error_urad:.2} urad");

    // Underrun: the stream stops coming mid-figure -> controlled stop, held, reported.
    let r = ok(&addr, &["stream", "--seconds", "3", "--knot-ms", "50", "--cut-after", "20"]);
    assert_eq!((r["final_status"]["mode"].as_str(), r["final_status"]["fault"].as_str()), (Some("Holding"), Some("Underrun")), "{r}");
    let refusal = refused(&addr, &["move", "--x-mm", "212", "--y-mm", "0"]);
    assert!(refusal.contains("Faulted(Underrun)"), "{refusal}");
    ok(&addr, &["reset"]);
    std::thread::sleep(std::time::Duration::from_millis(200));
    let s = ok(&addr, &["status"]);
    assert_eq!(s["mode"], "Running", "{s}");
    let held = xy(&s["setpoint_mm"]);

    // A limit violation: refused whole, nothing moved.
    let bad = work.path().join("bad.csv");
    std::fs::write(&bad, format!("t_s,x_mm,y_mm,vx_mm_s,vy_mm_s\n0.1,{},{},0,0\n0.2,300,0,0,0\n", held[0], held[1])).unwrap();
    let refusal = refused(&addr, &["stream", "--file", bad.to_str().unwrap()]);
    assert!(refusal.contains("Segment { index: 1"), "{refusal}");
    let s = ok(&addr, &["status"]);
    assert_eq!((s["stream_knots_queued"].as_u64(), s["moving"].as_bool()), (Some(0), Some(false)));
    assert_eq!(xy(&s["setpoint_mm"]), held, "nothing moved");

    // A calibration upload the controller refuses: the image in force stays.
    let image = work.path().join("bad-grid.bin");
    std::fs::write(&image, vec![0x5Au8; 3000]).unwrap();
    let refusal = refused(&addr, &["upload", "--grid", image.to_str().unwrap()]);
    assert!(refusal.contains("Calibration("), "{refusal}");
    assert_eq!(ok(&addr, &["identify"])["calibration_id"].as_u64(), Some(calibration_id));

    // Garbage while the servo runs: every frame answered with an error, no motion, deadline
    // held (a missed deadline would have ended QEMU, and the status says 0 overruns).
    let g = ok(&addr, &["garbage", "--bytes", "6000", "--seed", "7"]);
    assert!(g["frames"].as_u64().unwrap() > 10, "{g}");
    assert_eq!(g["answers"], g["frames"], "every frame answered: {g}");
    assert_eq!(g["setpoint_before_mm"], g["setpoint_after_mm"], "{g}");
    assert_eq!((g["mode"].as_str(), g["overruns"].as_u64()), (Some("Running"), Some(0)), "{g}");
    let s = ok(&addr, &["status"]);
    assert_eq!((s["mode"].as_str(), s["overruns"].as_u64()), (Some("Running"), Some(0)), "{s}");
    println!("LINK_QEMU garbage: {} bytes, {} frames, {} answers, no motion, 0 overruns", g["bytes"], g["frames"], g["answers"]);
}
