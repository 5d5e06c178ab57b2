//! The controller in the loop: the real firmware binary under QEMU (scenario `link`: setpoints
//! from the host link, incremental encoders so the machine powers up unhomed; UART0 on a TCP
//! socket), driven through `host-sim link`, every CI run: identify, home (Unhomed -> Homing ->
//! Running through the link), upload a calibration image and see it take effect (the id read
//! back is the file's, and the joints move by the new correction at the same setpoint), a bad
//! image refused (the image in force stays), stream a 3 s figure through the workspace and
//! check the tracking from the telemetry, provoke an underrun (controlled stop, reported) and
//! reset, a limit violation (refused whole, nothing moved), and garbage while the servo runs
//! (every frame answered, no motion, no deadline missed: the harness would end QEMU with FAIL).
//!
//! Needs the thumbv7em-none-eabihf target and qemu-system-arm (`bash tests/run-all.sh`
//! installs both). The firmware is built into `target/system-tests` (as the same-core test
//! does) so that this test does not wait on the lock of the `cargo test` that runs it.
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};

use host_sim::link::link_protocol::calibration_image_id;
use serde_json::Value;

// The QEMU board's synthetic images, the same generator the firmware's build script uses: the
// bundled image (in force at boot) and the second one (its field negated), uploaded here.
#[allow(dead_code)]
mod machine {
    include!("../../firmware/src/board/qemu/machine.rs");
}
mod synthetic {
    include!("../../firmware/src/board/qemu/synthetic_image.rs");
}

fn build_firmware() -> PathBuf {
    build_firmware_bin(&workspace_root(), "firmware")
}

include!("../../tests/support/firmware_build.rs");

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
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
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
    assert!(
        out.status.success(),
        "host-sim link {args:?} failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{args:?}: not JSON ({e}): {stdout}"))
}

/// Runs `host-sim link ARGS`, requires failure, returns its stderr.
fn refused(addr: &str, args: &[&str]) -> String {
    let out = host_sim(addr, args);
    assert!(
        !out.status.success(),
        "host-sim link {args:?} should have been refused: {}",
        String::from_utf8_lossy(&out.stdout)
    );
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

    // Identify: the image in force is the bundled one, and the firmware's id for it is the one
    // the host computes from the same bytes.
    let id = ok(&addr, &["identify"]);
    assert_eq!(id["board"], "Qemu");
    assert_eq!(
        id["protocol_version"],
        host_sim::link::link_protocol::PROTOCOL_VERSION
    );
    // The machine it drives: the bundled image carries no machine record, so the firmware's
    // built-in one, the paper machine's (host-sim's machines/paper.toml).
    let paper = kinematics_core::MachineRecord::paper();
    assert_eq!(
        (
            id["machine"]["name"].as_str(),
            id["machine"]["digest"].as_str()
        ),
        (
            Some("paper"),
            Some(format!("{:08x}", paper.digest()).as_str())
        ),
        "{id}"
    );
    let bundled_id = calibration_image_id(&synthetic::synthetic_image(1.0));
    assert_eq!(
        id["calibration_id"].as_u64(),
        Some(u64::from(bundled_id)),
        "{id}"
    );

    // Unhomed at power-on: drives off, motion refused; Home runs the index search through the
    // link and ends Running at home.
    let s = ok(&addr, &["status"]);
    assert_eq!(
        (
            s["mode"].as_str(),
            s["homing"].as_str(),
            s["drives_enabled"].as_bool()
        ),
        (Some("Unhomed"), Some("NotHomed"), Some(false)),
        "{s}"
    );
    let refusal = refused(&addr, &["move", "--x-mm", "212", "--y-mm", "0"]);
    assert!(refusal.contains("NotHomed"), "{refusal}");
    let h = ok(&addr, &["home"]);
    let states: Vec<(String, String)> = h["states"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            (
                p[0].as_str().unwrap().to_owned(),
                p[1].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    let pair = |m: &str, h: &str| (m.to_owned(), h.to_owned());
    assert_eq!(
        states,
        [
            pair("Unhomed", "NotHomed"),
            pair("Homing", "InProgress"),
            pair("Running", "Homed")
        ],
        "{h}"
    );
    let s = &h["status"];
    assert_eq!(
        (
            s["mode"].as_str(),
            s["homing"].as_str(),
            s["drives_enabled"].as_bool()
        ),
        (Some("Running"), Some("Homed"), Some(true)),
        "{h}"
    );
    let home = xy(&s["setpoint_mm"]);
    assert!(
        (home[0] - 212.132).hypot(home[1]) < 0.01,
        "engaged at home: {home:?}"
    );
    println!(
        "LINK_QEMU home: {:.2} s through {states:?}",
        h["seconds"].as_f64().unwrap()
    );

    // A measurement session through the controller: six verification targets of the paper's
    // plan, each approached as the list says (both motors arriving forward), settled by the
    // telemetry's criterion, the angles held written for `import` (the readings come from a
    // tracker's export afterwards).
    let plan = work.path().join("plan");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["plan", "--seed", "1", "--out", plan.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success());
    let list: Vec<String> = std::fs::read_to_string(plan.join("verify.csv"))
        .unwrap()
        .lines()
        .take(7)
        .map(String::from)
        .collect();
    let few = work.path().join("few.csv");
    std::fs::write(&few, list.join("\n") + "\n").unwrap();
    let angles = work.path().join("angles.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["session", "--tcp", &addr, "--timeout-s", "10", "--targets"])
        .args([
            few.to_str().unwrap(),
            "--instrument",
            "export",
            "--angles-out",
        ])
        .arg(&angles)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "session: {stderr}");
    let r: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (r["points"].as_u64(), r["deferred"].as_bool()),
        (Some(6), Some(true)),
        "{r}"
    );
    assert!(r["settle_s_max"].as_f64().unwrap() < 1.0, "{r}");
    assert!(
        r["following_error_urad_max"].as_f64().unwrap() <= 2.0,
        "{r}"
    );
    let rows = host_sim::io::commanded_csv::read_commanded(&angles).unwrap();
    assert_eq!(rows.len(), 6);
    assert!(rows.iter().all(|row| row.dir == Some([1, 1])), "{rows:?}");
    println!(
        "LINK_QEMU session: 6 points, settled within {:.3} s, following error ≤ {:.2} µrad",
        r["settle_s_max"], r["following_error_urad_max"]
    );
    // Back home, where the upload below checks the correction's change.
    let (hx, hy) = (format!("--x-mm={}", home[0]), format!("--y-mm={}", home[1]));
    ok(&addr, &["move", &hx, &hy]);

    // Upload the second image: the id read back is the file's, the servo switches to it at rest
    // (identify reports it once it is in force), and the joints move by the correction's change
    // at the same setpoint: at home the bundled field is (+1e-4, 0) rad, the new one (-1e-4, 0).
    let image = synthetic::synthetic_image(-1.0);
    let image_id = calibration_image_id(&image);
    let grid = work.path().join("grid-2.bin");
    std::fs::write(&grid, &image).unwrap();
    let before = ok(&addr, &["status"]);
    let up = ok(&addr, &["upload", "--grid", grid.to_str().unwrap()]);
    assert_eq!(
        up["calibration_id"].as_u64(),
        Some(u64::from(image_id)),
        "{up}"
    );
    let mut in_force = None;
    for _ in 0..50 {
        in_force = ok(&addr, &["identify"])["calibration_id"].as_u64();
        if in_force == Some(u64::from(image_id)) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert_eq!(
        in_force,
        Some(u64::from(image_id)),
        "the servo switched to the uploaded image"
    );
    std::thread::sleep(std::time::Duration::from_millis(300));
    let after = ok(&addr, &["status"]);
    assert_eq!(
        (after["mode"].as_str(), after["fault"].as_str()),
        (Some("Running"), None),
        "{after}"
    );
    let (p0, p1) = (xy(&before["setpoint_mm"]), xy(&after["setpoint_mm"]));
    assert!(
        (p1[0] - p0[0]).hypot(p1[1] - p0[1]) < 0.001,
        "the same setpoint: {p0:?} -> {p1:?}"
    );
    let (e0, e1) = (xy(&before["encoder_rad"]), xy(&after["encoder_rad"]));
    let moved = [e1[0] - e0[0], e1[1] - e0[1]];
    println!("LINK_QEMU upload: {} bytes, id {image_id:#010x} in force; joints moved {moved:?} rad at the same setpoint", image.len());
    assert!(
        (moved[0].abs() - 2.0e-4).abs() < 0.3e-4 && moved[1].abs() < 0.3e-4,
        "the new correction took effect: {moved:?}"
    );

    // A damaged image (one bit flipped in its grid): the host tool refuses it before it
    // connects; sent anyway (the library's upload, as another client could), the controller
    // refuses it and the image in force stays.
    let mut damaged = image.clone();
    damaged[image.len() / 2] ^= 0x10;
    let bad = work.path().join("damaged-grid.bin");
    std::fs::write(&bad, &damaged).unwrap();
    let refusal = refused(&addr, &["upload", "--grid", bad.to_str().unwrap()]);
    assert!(refusal.contains("grid image CRC mismatch"), "{refusal}");
    let mut client =
        host_sim::link::LinkClient::connect_tcp(&addr, std::time::Duration::from_secs(10)).unwrap();
    let refusal = host_sim::link::upload_calibration(&mut client, &damaged, &mut |_, _| {})
        .unwrap_err()
        .to_string();
    drop(client);
    assert!(refusal.contains("Calibration(Invalid)"), "{refusal}");
    assert_eq!(
        ok(&addr, &["identify"])["calibration_id"].as_u64(),
        Some(u64::from(image_id))
    );
    let s = ok(&addr, &["status"]);
    assert_eq!(
        (s["mode"].as_str(), xy(&s["setpoint_mm"])),
        (Some("Running"), p1),
        "{s}"
    );

    // A 3 s figure (±30 mm × ±40 mm) through the workspace, tracked. Knots 100 ms apart: QEMU's
    // clock runs ahead of the wall clock its UART's bytes come by (`-icount`, no sleep), so a
    // closer spacing lets the stream run dry between two frames now and then.
    let csv = work.path().join("telemetry.csv");
    let r = ok(
        &addr,
        &[
            "stream",
            "--seconds",
            "3",
            "--knot-ms",
            "100",
            "--telemetry-csv",
            csv.to_str().unwrap(),
        ],
    );
    assert_eq!(r["knots_sent"], 30);
    assert_eq!(r["final_status"]["mode"], "Running", "{r}");
    assert!(r["final_status"]["fault"].is_null(), "{r}");
    let samples = r["telemetry_samples"].as_u64().unwrap();
    assert!(
        samples >= 250,
        "telemetry: {samples} samples for 3 s at 100 Hz"
    );
    let max_error_urad = r["max_following_error_urad"].as_f64().unwrap();
    assert!(
        max_error_urad > 0.0 && max_error_urad < 50.0,
        "following error {max_error_urad} urad"
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.starts_with("# machine=paper digest="), "{text}");
    let xs: Vec<f64> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    let span =
        xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min);
    assert!(
        span > 50.0,
        "the figure moved the setpoint over {span} mm along x (60 expected)"
    );
    let end = xy(&r["final_status"]["setpoint_mm"]);
    assert!(
        (end[0] - home[0]).hypot(end[1] - home[1]) < 0.01,
        "back at the start: {end:?} vs {home:?}"
    );
    println!("LINK_QEMU stream: 30 knots, {samples} telemetry samples, max following error {max_error_urad:.2} urad");

    // Underrun: the stream stops coming mid-figure -> controlled stop, held, reported.
    let r = ok(
        &addr,
        &[
            "stream",
            "--seconds",
            "3",
            "--knot-ms",
            "100",
            "--cut-after",
            "20",
        ],
    );
    assert_eq!(
        (
            r["final_status"]["mode"].as_str(),
            r["final_status"]["fault"].as_str()
        ),
        (Some("Holding"), Some("Underrun")),
        "{r}"
    );
    let refusal = refused(&addr, &["move", "--x-mm", "212", "--y-mm", "0"]);
    assert!(refusal.contains("Faulted(Underrun)"), "{refusal}");
    ok(&addr, &["reset"]);
    std::thread::sleep(std::time::Duration::from_millis(200));
    let s = ok(&addr, &["status"]);
    assert_eq!(s["mode"], "Running", "{s}");
    let held = xy(&s["setpoint_mm"]);

    // A limit violation: refused whole, nothing moved.
    let bad = work.path().join("bad.csv");
    std::fs::write(
        &bad,
        format!(
            "t_s,x_mm,y_mm,vx_mm_s,vy_mm_s\n0.1,{},{},0,0\n0.2,300,0,0,0\n",
            held[0], held[1]
        ),
    )
    .unwrap();
    let refusal = refused(&addr, &["stream", "--file", bad.to_str().unwrap()]);
    assert!(refusal.contains("Segment { index: 1"), "{refusal}");
    let s = ok(&addr, &["status"]);
    assert_eq!(
        (s["stream_knots_queued"].as_u64(), s["moving"].as_bool()),
        (Some(0), Some(false))
    );
    assert_eq!(xy(&s["setpoint_mm"]), held, "nothing moved");

    // Garbage while the servo runs: every frame answered with an error, no motion, deadline
    // held (a missed deadline would have ended QEMU, and the status says 0 overruns).
    let g = ok(&addr, &["garbage", "--bytes", "6000", "--seed", "7"]);
    assert!(g["frames"].as_u64().unwrap() > 10, "{g}");
    assert_eq!(g["answers"], g["frames"], "every frame answered: {g}");
    assert_eq!(g["setpoint_before_mm"], g["setpoint_after_mm"], "{g}");
    assert_eq!(
        (g["mode"].as_str(), g["overruns"].as_u64()),
        (Some("Running"), Some(0)),
        "{g}"
    );
    let s = ok(&addr, &["status"]);
    assert_eq!(
        (s["mode"].as_str(), s["overruns"].as_u64()),
        (Some("Running"), Some(0)),
        "{s}"
    );
    println!(
        "LINK_QEMU garbage: {} bytes, {} frames, {} answers, no motion, 0 overruns",
        g["bytes"], g["frames"], g["answers"]
    );

    calibration_and_reset_safety(&addr, work.path(), image_id);
}

/// A small image of the QEMU machine over its home (3 × 3 nodes, 50 × 80 mm cells): `nodes`
/// corrections, `model`, optional dynamics. Valid CRCs throughout: only the content is bad.
fn small_image(
    model: &kinematics_core::FiveBar<f32>,
    nodes: [[f32; 2]; 9],
    dynamics: Option<kinematics_core::FiveBarDynamics<f32>>,
) -> Vec<u8> {
    use kinematics_core::grid::{append_dynamics, encode, GridGeometry, DYNAMICS_LEN};
    let g = GridGeometry {
        nx: 3,
        ny: 3,
        x0_mm: 162.132,
        y0_mm: -75.0,
        step_x_mm: 50.0,
        step_y_mm: 75.0,
    };
    let mut img = vec![0u8; g.image_len() + DYNAMICS_LEN];
    let n = encode(&mut img, &g, model, &nodes).unwrap();
    let end = match dynamics {
        Some(d) => append_dynamics(&mut img, n, n, &d).unwrap(),
        None => n,
    };
    img.truncate(end);
    img
}

/// Attacks on the calibration door, through the real firmware: CRC-valid images with absurd
/// content refused at commit with the parameter and its values (the image in force stays,
/// nothing moves); another design's model named with the parameter and both values; another
/// machine's commissioning image (its own machine record) refused naming both machines, by the
/// controller and in `host-sim link`'s message; an upload begun while a committed
/// image waits for the switch refused (the slot in use is never erased: the machine keeps
/// holding, no fault); resets after a switch under way re-engage every time; a client's stale
/// bytes never turn a move that ran into a refusal; Ctrl-C turns the telemetry off.
fn calibration_and_reset_safety(addr: &str, work: &Path, in_force: u32) {
    let nominal = kinematics_core::FiveBar::<f32>::paper_nominal();
    let put = |name: &str, bytes: &[u8]| {
        let p = work.join(name);
        std::fs::write(&p, bytes).unwrap();
        p.to_str().unwrap().to_owned()
    };
    // The controller's own judgement: uploaded through the library (`host-sim link upload`
    // judges an image on the host first and would not send these).
    let raw_upload = |bytes: &[u8]| -> String {
        let mut client =
            host_sim::link::LinkClient::connect_tcp(addr, std::time::Duration::from_secs(10))
                .unwrap();
        match host_sim::link::upload_calibration(&mut client, bytes, &mut |_, _| {}) {
            Ok(id) => panic!("accepted: {id:#010x}"),
            // The code and the sentence (the parameter's name and both values).
            Err(e) => format!("{e:?} / {e}"),
        }
    };
    let before = ok(addr, &["status"]);
    // A ±0.05 rad checkerboard (a switch to it drove 7.6 N·m).
    let checker: [[f32; 2]; 9] = core::array::from_fn(|k| {
        if k % 2 == 0 {
            [0.05, -0.05]
        } else {
            [-0.05, 0.05]
        }
    });
    let refusal = raw_upload(&small_image(&nominal, checker, None));
    assert!(
        refusal.contains("Implausible") && refusal.contains("NodeCorrectionMm"),
        "{refusal}"
    );
    // Masses 1000× the machine's.
    let heavy = machine::IMAGE_DYNAMICS.scaled_masses([1000.0; 5]);
    let refusal = raw_upload(&small_image(&nominal, [[0.0; 2]; 9], Some(heavy)));
    assert!(refusal.contains("InertiaRatio"), "{refusal}");
    // Another design: link b 11 mm longer; the refusal names it with both values.
    let other = kinematics_core::FiveBar {
        b_mm: nominal.b_mm + 11.0,
        ..nominal
    };
    let refusal = raw_upload(&small_image(&other, [[0.0; 2]; 9], None));
    assert!(
        refusal.contains("OtherMachine")
            && refusal.contains("LinkBMm")
            && refusal.contains("b_mm is 161.0000 in the image, 150.0000 on this machine"),
        "{refusal}"
    );
    // The second machine's commissioning image: consistent with its own record, so the host
    // tool sends it; the controller, the paper machine, refuses it naming both machines, and
    // `host-sim link` says so.
    let second = work.join("second-commissioning.bin");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["grid", "--nominal", "--machine"])
        .arg(workspace_root().join("host-sim/machines/second.toml"))
        .arg("--out")
        .arg(&second)
        .output()
        .expect("host-sim runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let second_record = kinematics_core::CorrectionGrid::parse(&std::fs::read(&second).unwrap())
        .unwrap()
        .machine()
        .expect("a commissioning image carries its machine record");
    let refusal = refused(addr, &["upload", "--grid", second.to_str().unwrap()]);
    let paper = kinematics_core::MachineRecord::paper();
    for expected in [
        "OtherRecord".to_owned(),
        format!(
            "the image was built for machine 'second' (digest {:08x}); this controller is machine 'paper' (digest {:08x})",
            second_record.digest(),
            paper.digest()
        ),
    ] {
        assert!(refusal.contains(&expected), "{expected}: {refusal}");
    }
    assert_eq!(
        ok(addr, &["identify"])["calibration_id"].as_u64(),
        Some(u64::from(in_force)),
        "the image in force stays"
    );
    let after = ok(addr, &["status"]);
    assert_eq!(after["setpoint_mm"], before["setpoint_mm"], "nothing moved");
    assert_eq!(
        (after["mode"].as_str(), after["fault"].as_str()),
        (Some("Running"), None)
    );

    // A stale half frame from another client, then a move: it runs and is reported so.
    for _ in 0..2 {
        let mut raw = std::net::TcpStream::connect(addr).unwrap();
        std::io::Write::write_all(&mut raw, &[0x07, 0x41, 0x13, 0x99]).unwrap();
        drop(raw);
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let moved = ok(addr, &["move", "--x-mm", "222", "--y-mm", "5"]);
    let p = xy(&moved["setpoint_mm"]);
    assert!((p[0] - 222.0).hypot(p[1] - 5.0) < 0.01, "{moved}");

    // Holding after a stop, a good image committed: the switch waits for the rest. A second
    // upload now is refused (it would erase the slot the servo still reads); the machine keeps
    // holding, no fault.
    ok(addr, &["stop"]);
    std::thread::sleep(std::time::Duration::from_millis(200));
    let good = synthetic::synthetic_image(1.0);
    let good_id = calibration_image_id(&good);
    let good_path = put("good.bin", &good);
    let up = ok(addr, &["upload", "--grid", &good_path]);
    assert_eq!(up["calibration_id"].as_u64(), Some(u64::from(good_id)));
    let s = ok(addr, &["status"]);
    assert_eq!(
        (s["mode"].as_str(), s["calibration_pending"].as_u64()),
        (Some("Holding"), Some(u64::from(good_id))),
        "{s}"
    );
    let refusal = refused(addr, &["upload", "--grid", &good_path]);
    assert!(refusal.contains("SwitchPending"), "{refusal}");
    std::thread::sleep(std::time::Duration::from_millis(100));
    let s = ok(addr, &["status"]);
    assert_eq!(
        (s["mode"].as_str(), s["fault"].as_str()),
        (Some("Holding"), Some("Commanded")),
        "the slot in use was not touched: {s}"
    );
    // Reset: re-engaged, the switch made at that rest, and again after five more stops.
    for k in 0..6 {
        ok(addr, &["reset"]);
        std::thread::sleep(std::time::Duration::from_millis(300));
        let s = ok(addr, &["status"]);
        assert_eq!(
            (s["mode"].as_str(), s["fault"].as_str()),
            (Some("Running"), None),
            "reset {k}: {s}"
        );
        let p = xy(&s["setpoint_mm"]);
        assert!((p[0] - 222.0).hypot(p[1] - 5.0) < 0.01, "reset {k}: {s}");
        ok(addr, &["stop"]);
        std::thread::sleep(std::time::Duration::from_millis(150));
    }
    ok(addr, &["reset"]);
    assert_eq!(
        ok(addr, &["identify"])["calibration_id"].as_u64(),
        Some(u64::from(good_id)),
        "switched at the rest after the reset"
    );

    // Ctrl-C in the middle of a recording: telemetry is off afterwards.
    let csv = work.join("interrupted.csv");
    let child = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args([
            "link",
            "--tcp",
            addr,
            "--timeout-s",
            "10",
            "telemetry",
            "--seconds",
            "60",
        ])
        .arg("--csv")
        .arg(&csv)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // (QEMU's socket serves one client at a time: the status is read after the recorder left;
    // without the clean-up the controller would still send telemetry at decimation 20.)
    std::thread::sleep(std::time::Duration::from_millis(1500));
    Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        !out.status.success() && String::from_utf8_lossy(&out.stderr).contains("interrupted"),
        "interrupted, not done: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let off = ok(addr, &["status"]);
    assert_eq!(off["telemetry_decimation"].as_u64(), Some(0), "{off}");
    println!("LINK_QEMU safety: implausible and other-machine images refused with their numbers, begin refused while a switch is pending, six resets re-engaged, stale bytes harmless, Ctrl-C left telemetry off");
}
