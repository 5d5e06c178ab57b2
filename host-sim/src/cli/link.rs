//! `host-sim link`: talk to a controller over its host link (`host_sim::link`): identify,
//! status, enable, disable, home, move, stream a trajectory (a knot file or the built-in
//! figure) with telemetry to CSV, stop, reset, upload a calibration image, record telemetry,
//! send garbage. JSON report on stdout, progress on stderr.
//!
//! Transport: `--tcp HOST:PORT` (QEMU's UART on a socket: `firmware/qemu/run-one.sh` with
//! `QEMU_SERIAL`) or `--serial PATH [--baud N]` (the real board: the NUCLEO-G474RE's ST-LINK
//! virtual COM port, e.g. `/dev/ttyACM0`, 115 200 Bd 8N1; see docs/guides/g474-bring-up.md). The
//! commands are the same over both: the client takes any `Read + Write`.
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::link_args::MAX_TIMEOUT_S;
use anyhow::{bail, Context, Result};
use host_sim::calib::image::{read_image, read_image_for};
use host_sim::dynamics::telemetry::{from_link, meta_for};
use host_sim::io::atomic::Outputs;
use host_sim::io::machine_file::read_machine;
use host_sim::io::policy::CommandFiles;
use host_sim::io::read_bytes;
use host_sim::io::telemetry_csv::telemetry_text;
use host_sim::io::KeyOrder;
use host_sim::link::link_protocol::{Command, ModeCode, Response, StatusReport, TelemetrySample};
use host_sim::link::{figure_knots, parse_knots_csv, stream_knots, upload_calibration, LinkClient};
use kinematics_core::{CorrectionGrid, MachineRecord};
use serde::Serialize;

/// Talk to a controller over its host link.
#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("transport").required(true).args(["tcp", "serial"])))]
pub struct Args {
    #[command(flatten)]
    pub link: super::link_args::LinkArgs,
    /// Seconds to wait for each reply (and for the connection).
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
    #[command(subcommand)]
    pub action: Action,
}

/// What to do.
#[derive(clap::Subcommand, Debug)]
pub enum Action {
    /// Firmware version, board, protocol version, calibration id.
    Identify,
    /// The controller's state.
    Status,
    /// Engage and enable the drives (after a disable or a commanded stop).
    Enable,
    /// Controlled stop, then drives off.
    Disable,
    /// Start homing and wait until it ends; reports the (mode, homing) states the status went
    /// through, the time taken and the status at the end.
    Home,
    /// Controlled stop, then hold.
    Stop,
    /// Clear a latched fault and re-engage.
    Reset,
    /// Move to a point (the controller plans the jerk-limited move); waits until it is there.
    Move {
        /// Target x (mm).
        #[arg(long)]
        x_mm: f32,
        /// Target y (mm).
        #[arg(long)]
        y_mm: f32,
    },
    /// Stream a trajectory (a knot file, or the built-in figure), wait until it has played,
    /// report the tracking from the telemetry.
    Stream(StreamArgs),
    /// Upload a calibration image (grid.bin) and read back its id: the controller must report
    /// the file's own (CRC-32C of its bytes), or the command fails.
    Upload {
        /// The image. It is judged first, as the controller will judge it: another machine's
        /// image, or one no calibration of the machine needs, is refused before a byte is sent.
        #[arg(long)]
        grid: PathBuf,
        /// The machine file of the controller's machine: the image must be that machine's
        /// (its digest). Without it the image is judged against its own machine record, or,
        /// if it carries none, against the firmware's built-in machine (the paper's).
        #[arg(long, value_name = "FILE")]
        machine: Option<PathBuf>,
    },
    /// Record telemetry for a while.
    Telemetry {
        /// Servo samples per telemetry sample (at least 20: 100 Hz).
        #[arg(long, default_value_t = 20)]
        decimation: u16,
        /// How long (s, wall clock).
        #[arg(long, default_value_t = 1.0)]
        seconds: f64,
        /// CSV output (the telemetry CSV: its first line names the machine).
        #[arg(long)]
        csv: PathBuf,
        /// The machine file of the controller's machine, named in the CSV (default: the
        /// paper's).
        #[arg(long, value_name = "FILE")]
        machine: Option<PathBuf>,
    },
    /// Send random bytes (bursts of 300, each ending with a frame delimiter) and count the
    /// frames they make and the answers: the controller must answer every one and not move.
    Garbage {
        /// Bytes to send.
        #[arg(long, default_value_t = 10_000)]
        bytes: usize,
        /// Seed of the bytes.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

/// `host-sim link stream`.
#[derive(clap::Args, Debug)]
pub struct StreamArgs {
    /// Knots: CSV with a header, `t_s,x_mm,y_mm,vx_mm_s,vy_mm_s` (times from the start).
    #[arg(long, conflicts_with = "seconds")]
    pub file: Option<PathBuf>,
    /// The built-in figure's length (s) (default when no --file: 3 s).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// The built-in figure's amplitudes along x and y (mm).
    #[arg(long, num_args = 2, default_values_t = [30.0, 40.0])]
    pub amp_mm: Vec<f64>,
    /// The built-in figure's frequency along x (Hz; y runs at twice that).
    #[arg(long, default_value_t = 0.5)]
    pub freq_hz: f64,
    /// The built-in figure's knot spacing (ms). Under QEMU use 50: its UART takes a byte per
    /// main-loop turn, ~100 ms per 8-knot frame, slower than 10 ms knots play.
    #[arg(long, default_value_t = 20)]
    pub knot_ms: u32,
    /// Stop sending after this many knots (provokes an underrun when the trajectory still moves
    /// there).
    #[arg(long)]
    pub cut_after: Option<usize>,
    /// Telemetry to CSV while streaming.
    #[arg(long)]
    pub telemetry_csv: Option<PathBuf>,
    /// Telemetry decimation (servo samples per telemetry sample).
    #[arg(long, default_value_t = 20)]
    pub decimation: u16,
    /// The machine file of the controller's machine, named in the telemetry CSV (default: the
    /// paper's).
    #[arg(long, value_name = "FILE")]
    pub machine: Option<PathBuf>,
}

/// The telemetry CSV of `samples` (`io::telemetry_csv`), naming `machine`'s machine (the
/// paper's without it).
fn telemetry_file(
    samples: &[TelemetrySample],
    machine: Option<&Path>,
    decimation: u16,
) -> Result<String> {
    let spec = match machine {
        Some(p) => read_machine(p)?,
        None => host_sim::io::machine_file::paper(),
    };
    let log = from_link(samples, Some(meta_for(&spec, u32::from(decimation))));
    Ok(telemetry_text(&log))
}

#[derive(Serialize)]
struct Done {
    done: &'static str,
}

#[derive(Serialize)]
struct StreamReport {
    knots_sent: usize,
    knots_total: usize,
    telemetry_samples: usize,
    max_following_error_urad: f64,
    final_status: StatusReport,
    telemetry_csv: Option<String>,
}

fn request<S: Read + Write>(client: &mut LinkClient<S>, command: Command) -> Result<Response> {
    Ok(client.request(command)?)
}

/// Waits until the controller has finished the move or stream (or stopped); returns its status.
fn wait_idle<S: Read + Write>(client: &mut LinkClient<S>, limit: Duration) -> Result<StatusReport> {
    let start = Instant::now();
    loop {
        let s = client.status()?;
        if !s.moving || s.mode != ModeCode::Running {
            // A stop under way: wait for it to end too.
            if s.mode != ModeCode::Stopping {
                return Ok(s);
            }
        }
        if start.elapsed() > limit {
            bail!("the controller is still moving after {limit:?}: {s:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The image `link upload` sends, judged as the controller will judge it (module doc of
/// `host_sim::calib::image`): for `machine`'s machine when given, else for the machine its own
/// record names, else for the firmware's built-in machine (the paper's).
fn upload_image(grid: &Path, machine: Option<&Path>) -> Result<Vec<u8>> {
    Ok(match machine {
        Some(path) => read_image(grid, &read_machine(path)?)?.bytes,
        None => {
            let bytes = read_bytes(grid)?;
            let own = CorrectionGrid::parse(&bytes)
                .map_err(|e| anyhow::anyhow!("{}: {e}", grid.display()))?
                .machine();
            read_image_for(grid, &own.unwrap_or_else(MachineRecord::paper))?.bytes
        }
    })
}

/// `identify`'s JSON: the controller's answer, its machine as every file the tools write names
/// one (`{name, digest}`, the digest as 8 hex digits: `machine_identity::MachineIdentity`).
fn identity_json(id: &host_sim::link::link_protocol::Identity) -> Result<serde_json::Value> {
    let mut v = serde_json::to_value(id)?;
    v["machine"] = serde_json::to_value(host_sim::machine_identity::MachineIdentity {
        name: id.machine.name().to_owned(),
        digest: format!("{:08x}", id.machine.digest),
    })?;
    Ok(v)
}

/// `host-sim link`.
pub fn run(args: &Args) -> Result<()> {
    let timeout = super::link_args::reply_timeout(args.timeout_s)?;
    check_ranges(args)?;
    // The files an action reads and writes, checked before the link is opened.
    let files = match &args.action {
        Action::Upload { grid, machine } => CommandFiles::new()
            .input("--grid", grid)
            .input("--machine", machine),
        Action::Telemetry { csv, machine, .. } => CommandFiles::new()
            .input("--machine", machine)
            .output("--csv", csv),
        Action::Stream(a) => CommandFiles::new()
            .input("--file", &a.file)
            .input("--machine", &a.machine)
            .output("--telemetry-csv", &a.telemetry_csv),
        _ => CommandFiles::new(),
    };
    let mut outputs = files.check()?;
    // An image the controller would refuse is refused before the link is opened.
    if let Action::Upload { grid, machine } = &args.action {
        upload_image(grid, machine.as_deref())?;
    }
    let (_, mut client) = args.link.open(timeout)?;
    act_then_quiet(&mut client, &args.action, timeout, &mut outputs)
}

/// Longest `telemetry --seconds` (s): a day.
const MAX_RECORD_S: f64 = 86_400.0;
/// Most bytes `garbage --bytes` sends.
const MAX_GARBAGE_BYTES: usize = 100_000_000;

/// Every numeric flag in its range, before the link is opened: a value out of range is an
/// error that names the flag, never a panic.
fn check_ranges(args: &Args) -> Result<()> {
    let within = |v: f64, lo: f64, hi: f64| v.is_finite() && v > lo && v <= hi;
    match &args.action {
        Action::Move { x_mm, y_mm } if !(x_mm.is_finite() && y_mm.is_finite()) => {
            bail!("--x-mm and --y-mm must be finite numbers, not {x_mm}, {y_mm}")
        }
        Action::Telemetry {
            seconds,
            decimation,
            ..
        } => {
            if !within(*seconds, 0.0, MAX_RECORD_S) {
                bail!(
                    "--seconds must be a number of seconds in (0, {MAX_RECORD_S}], not {seconds}"
                );
            }
            if *decimation == 0 {
                bail!("--decimation must be at least 1 (the controller raises it to its minimum)");
            }
        }
        Action::Garbage { bytes, .. } if !(1..=MAX_GARBAGE_BYTES).contains(bytes) => {
            bail!("--bytes must be between 1 and {MAX_GARBAGE_BYTES}, not {bytes}")
        }
        Action::Stream(a) => {
            if a.cut_after == Some(0) {
                bail!("--cut-after must be at least 1 knot (0 would send nothing)");
            }
            if a.decimation == 0 {
                bail!("--decimation must be at least 1 (the controller raises it to its minimum)");
            }
            if let Some(s) = a.seconds {
                if !(s > 1.0 && s < 600.0) {
                    bail!("--seconds must be between 1 and 600, not {s}");
                }
            }
            if !(1..=1000).contains(&a.knot_ms) {
                bail!("--knot-ms must be between 1 and 1000, not {}", a.knot_ms);
            }
            if !a
                .amp_mm
                .iter()
                .all(|v| v.is_finite() && (0.0..=500.0).contains(v))
            {
                bail!(
                    "--amp-mm must be two amplitudes in [0, 500] mm, not {:?}",
                    a.amp_mm
                );
            }
            if !within(a.freq_hz, 0.0, 100.0) {
                bail!("--freq-hz must be in (0, 100] Hz, not {}", a.freq_hz);
            }
        }
        _ => {}
    }
    Ok(())
}

/// A wait of `s` seconds (a controller's figure: NaN, negative or absurd ones become the
/// longest wait, a day, instead of a panic).
fn wait_s(s: f64) -> Duration {
    Duration::try_from_secs_f64(s)
        .unwrap_or(Duration::from_secs_f64(MAX_TIMEOUT_S))
        .min(Duration::from_secs_f64(MAX_TIMEOUT_S))
}

/// Runs `action`, then leaves the controller as it was found: whatever the outcome (done, an
/// error, Ctrl-C), an action that turned telemetry on turns it off again.
fn act_then_quiet<S: Read + Write>(
    client: &mut LinkClient<S>,
    action: &Action,
    timeout: Duration,
    outputs: &mut Outputs,
) -> Result<()> {
    host_sim::link::interrupt::install();
    let result = act(client, action, timeout, outputs);
    if matches!(action, Action::Telemetry { .. } | Action::Stream(_)) && result.is_err() {
        host_sim::link::interrupt::clear();
        if let Err(e) = client.request(Command::Telemetry { decimation: 0 }) {
            eprintln!("could not turn the controller's telemetry off: {e}");
        }
    }
    if host_sim::link::interrupt::requested() {
        bail!("interrupted (Ctrl-C)");
    }
    result
}

/// Runs `action` over an open link.
fn act<S: Read + Write>(
    client: &mut LinkClient<S>,
    action: &Action,
    timeout: Duration,
    outputs: &mut Outputs,
) -> Result<()> {
    let done = |what| super::print_json(&Done { done: what }, KeyOrder::Sorted);
    match action {
        Action::Identify => match request(client, Command::Identify)? {
            Response::Identity(id) => {
                eprintln!(
                    "controller: {:?} firmware {:?}, protocol {}, {}, calibration {}",
                    id.board,
                    id.firmware_version,
                    id.protocol_version,
                    id.machine,
                    id.calibration_id
                        .map_or_else(|| "none in force".to_owned(), |c| format!("{c:#010x}"))
                );
                super::print_json(&identity_json(&id)?, KeyOrder::Sorted)
            }
            other => bail!("unexpected reply: {other:?}"),
        },
        Action::Status => super::print_json(&client.status()?, KeyOrder::Sorted),
        Action::Enable => request(client, Command::Enable).and_then(|_| done("enable")),
        Action::Disable => request(client, Command::Disable).and_then(|_| done("disable")),
        Action::Stop => request(client, Command::Stop).and_then(|_| done("stop")),
        Action::Reset => request(client, Command::ResetFault).and_then(|_| done("reset")),
        Action::Home => {
            use host_sim::link::link_protocol::HomingState;
            let before = client.status()?;
            request(client, Command::Home)?;
            let start = Instant::now();
            // The (mode, homing state) pairs the status went through, in order, for the report.
            let mut states = vec![(before.mode, before.homing)];
            loop {
                let s = client.status()?;
                if states.last() != Some(&(s.mode, s.homing)) {
                    states.push((s.mode, s.homing));
                }
                match s.homing {
                    HomingState::Homed => break,
                    HomingState::Failed => bail!("homing failed: {s:?}"),
                    _ if start.elapsed() > 60 * timeout => bail!("homing did not finish: {s:?}"),
                    _ if host_sim::link::interrupt::requested() => bail!("interrupted (Ctrl-C)"),
                    _ => std::thread::sleep(Duration::from_millis(50)),
                }
            }
            #[derive(Serialize)]
            struct Homed {
                done: &'static str,
                seconds: f64,
                states: Vec<(ModeCode, HomingState)>,
                status: StatusReport,
            }
            let status = client.status()?;
            super::print_json(
                &Homed {
                    done: "home",
                    seconds: start.elapsed().as_secs_f64(),
                    states,
                    status,
                },
                KeyOrder::Sorted,
            )
        }
        Action::Move { x_mm, y_mm } => {
            let Response::MovePlanned { duration_s } = request(
                client,
                Command::MoveTo {
                    target_mm: [*x_mm, *y_mm],
                },
            )?
            else {
                bail!("unexpected reply to move");
            };
            eprintln!("move planned: {duration_s:.3} s");
            let s = wait_idle(client, timeout + wait_s(f64::from(duration_s) * 20.0))?;
            super::print_json(&s, KeyOrder::Sorted)
        }
        Action::Stream(a) => stream(client, a, timeout, outputs),
        Action::Upload { grid, machine } => {
            let image = upload_image(grid, machine.as_deref())?;
            let id = upload_calibration(client, &image, &mut |done, total| {
                eprint!("\rupload {done}/{total} bytes");
            });
            eprintln!();
            // The id the controller committed, equal to the file's (checked by upload_calibration).
            #[derive(Serialize)]
            struct Uploaded {
                calibration_id: u32,
                bytes: usize,
            }
            super::print_json(
                &Uploaded {
                    calibration_id: id?,
                    bytes: image.len(),
                },
                KeyOrder::Sorted,
            )
        }
        Action::Telemetry {
            decimation,
            seconds,
            csv,
            machine,
        } => {
            if !(*seconds > 0.0 && seconds.is_finite()) {
                bail!("--seconds must be a positive number, not {seconds}");
            }
            request(
                client,
                Command::Telemetry {
                    decimation: *decimation,
                },
            )?;
            client.listen(Duration::from_secs_f64(*seconds))?;
            request(client, Command::Telemetry { decimation: 0 })?;
            let samples = client.take_telemetry();
            let text = telemetry_file(&samples, machine.as_deref(), *decimation)?;
            outputs.bytes(csv, text.as_bytes())?;
            std::mem::take(outputs).commit()?;
            #[derive(Serialize)]
            struct Recorded {
                samples: usize,
                csv: String,
            }
            super::print_json(
                &Recorded {
                    samples: samples.len(),
                    csv: csv.display().to_string(),
                },
                KeyOrder::Sorted,
            )
        }
        Action::Garbage { bytes, seed } => {
            let before = client.status()?;
            let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
            let mut sent = 0usize;
            let (mut frames, mut answers) = (0usize, 0usize);
            while sent < *bytes {
                let n = (*bytes - sent).min(300);
                let mut burst: Vec<u8> = (0..n)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        x as u8
                    })
                    .collect();
                burst.push(0);
                let (f, a) = client.send_raw(&burst)?;
                frames += f;
                answers += a;
                sent += n;
            }
            let after = client.status()?;
            #[derive(Serialize)]
            struct Garbage {
                bytes: usize,
                frames: usize,
                answers: usize,
                setpoint_before_mm: [f32; 2],
                setpoint_after_mm: [f32; 2],
                overruns: u32,
                mode: ModeCode,
            }
            let report = Garbage {
                bytes: sent,
                frames,
                answers,
                setpoint_before_mm: before.setpoint_mm,
                setpoint_after_mm: after.setpoint_mm,
                overruns: after.overruns,
                mode: after.mode,
            };
            super::print_json(&report, KeyOrder::Sorted)
        }
    }
}

fn stream<S: Read + Write>(
    client: &mut LinkClient<S>,
    a: &StreamArgs,
    timeout: Duration,
    outputs: &mut Outputs,
) -> Result<()> {
    let knots = match (&a.file, a.seconds) {
        (Some(f), _) => parse_knots_csv(
            &std::fs::read_to_string(f).with_context(|| format!("cannot read {}", f.display()))?,
        )
        .with_context(|| format!("in {}", f.display()))?,
        (None, s) => {
            // Ranges checked before the link was opened (`check_ranges`).
            let seconds = s.unwrap_or(3.0);
            let start = client.status()?.setpoint_mm;
            figure_knots(
                [f64::from(start[0]), f64::from(start[1])],
                [a.amp_mm[0], a.amp_mm[1]],
                a.freq_hz,
                seconds,
                a.knot_ms,
            )
        }
    };
    let total = knots.len();
    // At least one knot (`check_ranges` refuses `--cut-after 0`; a file has one or more).
    let send = a.cut_after.map_or(total, |n| n.min(total)).max(1);
    request(
        client,
        Command::Telemetry {
            decimation: a.decimation,
        },
    )?;
    let streamed = stream_knots(
        client,
        &knots[..send],
        Duration::from_millis(20),
        &mut |done, total| {
            eprint!("\rstream {done}/{total} knots");
        },
    );
    eprintln!();
    streamed?;
    let duration_s = f64::from(knots[send - 1].t_us) * 1e-6;
    let status = wait_idle(client, timeout + wait_s(duration_s * 20.0))?;
    request(client, Command::Telemetry { decimation: 0 })?;
    client.listen(Duration::from_millis(100))?;
    let samples: Vec<TelemetrySample> = client.take_telemetry();
    let max_error = samples
        .iter()
        .map(|t| f64::from(t.following_error_rad))
        .fold(0.0, f64::max);
    if let Some(csv) = &a.telemetry_csv {
        let text = telemetry_file(&samples, a.machine.as_deref(), a.decimation)?;
        outputs.bytes(csv, text.as_bytes())?;
    }
    std::mem::take(outputs).commit()?;
    let report = StreamReport {
        knots_sent: send,
        knots_total: total,
        telemetry_samples: samples.len(),
        max_following_error_urad: max_error * 1e6,
        final_status: status,
        telemetry_csv: a.telemetry_csv.as_ref().map(|p| p.display().to_string()),
    };
    super::print_json(&report, KeyOrder::Sorted)
}
