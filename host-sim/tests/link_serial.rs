//! `host-sim link --serial`: the real board's transport, without the board. A pseudo-terminal
//! pair (`serialport::TTYPort::pair`) stands in for the ST-LINK's virtual COM port: the tool
//! opens the pty's terminal side by path, configures it (115 200 Bd 8N1, raw) and talks the
//! link protocol; a fake controller on the other side decodes the request and answers it with
//! the protocol's own encoder. Also: a missing device, a file that is not a terminal, a
//! controller that never answers, and the flags that do not go together, each a clear error
//! and a non-zero exit, no panic.
#![cfg(unix)]

use std::io::{Read, Write};
use std::process::Command as Process;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use host_sim::link::link_protocol::{
    decode, encode, Board, Command, DeviceBody, DeviceMessage, FrameReader, Identity, MachineId,
    Received, Request, Response, MAX_FRAME_LEN, PROTOCOL_VERSION,
};
use serialport::{SerialPort, TTYPort};

fn host_sim(args: &[&str]) -> (i32, String, String) {
    let out = Process::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .expect("run host-sim");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

/// A pty pair: the controller's side (the master) and the path of the terminal side the tool
/// opens. The terminal side is closed here: `serialport` takes an exclusive lock on the port
/// it opens (a second program on the same port is refused), so the tool must be its only
/// user. Until the tool opens it, the master reads EIO.
fn pty() -> (TTYPort, String) {
    let (master, terminal) = TTYPort::pair().expect("pseudo-terminal pair");
    let path = terminal.name().expect("pty path");
    drop(terminal);
    (master, path)
}

/// Answers Identify requests on `port` until `stop`; returns the requests it decoded.
fn fake_controller(
    mut port: TTYPort,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<Vec<Command>> {
    std::thread::spawn(move || {
        port.set_timeout(Duration::from_millis(20)).unwrap();
        let mut reader = FrameReader::new();
        let mut seen = Vec::new();
        let mut buf = [0u8; 64];
        while !stop.load(Ordering::Relaxed) {
            let n = match port.read(&mut buf) {
                Ok(n) => n,
                Err(_) => {
                    // A timeout, or EIO while the tool has not opened its side yet.
                    std::thread::sleep(Duration::from_millis(5));
                    continue;
                }
            };
            for &b in &buf[..n] {
                let Some(Received::Frame(frame)) = reader.push(b) else {
                    continue;
                };
                let Ok(request) = decode::<Request>(frame) else {
                    continue;
                };
                let result = match request.command {
                    Command::Identify => Ok(Response::Identity(Identity {
                        protocol_version: PROTOCOL_VERSION,
                        firmware_version: [0, 1, 0],
                        board: Board::Stm32G474,
                        calibration_id: Some(0x1234_5678),
                        machine: MachineId::new("second", 0x0bad_cafe),
                    })),
                    _ => continue,
                };
                seen.push(request.command);
                let mut out = [0u8; MAX_FRAME_LEN];
                let len = encode(
                    &DeviceMessage::new(DeviceBody::Reply {
                        seq: request.seq,
                        result,
                    }),
                    &mut out,
                )
                .unwrap();
                port.write_all(&out[..len]).unwrap();
            }
        }
        seen
    })
}

#[test]
fn identify_over_a_serial_port() {
    let (master, path) = pty();
    let stop = Arc::new(AtomicBool::new(false));
    let controller = fake_controller(master, stop.clone());
    let (code, stdout, stderr) = host_sim(&[
        "link",
        "--serial",
        &path,
        "--baud",
        "115200",
        "--timeout-s",
        "5",
        "identify",
    ]);
    stop.store(true, Ordering::Relaxed);
    let seen = controller.join().unwrap();
    assert_eq!(code, 0, "{stderr}");
    let id: serde_json::Value = serde_json::from_str(&stdout).expect("JSON report");
    assert_eq!(id["board"], "Stm32G474", "{stdout}");
    assert_eq!(id["calibration_id"], 0x1234_5678, "{stdout}");
    assert_eq!(
        (
            id["machine"]["name"].as_str(),
            id["machine"]["digest"].as_str()
        ),
        (Some("second"), Some("0badcafe")),
        "{stdout}"
    );
    assert_eq!(id["protocol_version"], PROTOCOL_VERSION, "{stdout}");
    assert_eq!(seen, [Command::Identify]);
}

#[test]
fn a_controller_that_never_answers_times_out_with_an_error() {
    let (_master, path) = pty();
    let (code, stdout, stderr) =
        host_sim(&["link", "--serial", &path, "--timeout-s", "0.3", "status"]);
    assert_eq!(code, 1, "{stdout}{stderr}");
    assert!(stderr.contains("no reply from the controller"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_missing_device_or_a_file_that_is_not_a_terminal_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("ttyACM9");
    let (code, stdout, stderr) =
        host_sim(&["link", "--serial", missing.to_str().unwrap(), "identify"]);
    assert_eq!((code, stdout.as_str()), (1, ""), "{stderr}");
    assert!(
        stderr.contains("opening the serial port") && stderr.contains("ttyACM9"),
        "{stderr}"
    );
    assert!(stderr.contains("No such file or directory"), "{stderr}");
    let plain = dir.path().join("plain");
    std::fs::write(&plain, b"").unwrap();
    let (code, _, stderr) = host_sim(&["link", "--serial", plain.to_str().unwrap(), "identify"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("opening the serial port"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn the_transport_flags_are_checked() {
    // Neither transport, both, a baud rate for TCP, a zero baud rate: usage errors.
    let (code, _, stderr) = host_sim(&["link", "identify"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("--tcp") && stderr.contains("--serial"),
        "{stderr}"
    );
    let (code, _, stderr) = host_sim(&[
        "link",
        "--tcp",
        "127.0.0.1:1",
        "--serial",
        "/dev/null",
        "identify",
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("cannot be used with"), "{stderr}");
    let (code, _, stderr) =
        host_sim(&["link", "--tcp", "127.0.0.1:1", "--baud", "9600", "identify"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("--baud applies to --serial only"),
        "{stderr}"
    );
    let (code, _, stderr) = host_sim(&["link", "--serial", "/dev/null", "--baud", "0", "identify"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("--baud must be a positive"), "{stderr}");
}
