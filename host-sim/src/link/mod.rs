//! The host side of the controller's link (`link-protocol`): a client over any byte stream (a
//! TCP socket to QEMU's UART, [`LinkClient::connect_tcp`]; the real board's serial port,
//! [`LinkClient::open_serial`]), typed requests and replies, streamed motion with flow control,
//! calibration upload, telemetry.
//!
//! * [`LinkClient`]: one request, one reply (matched by sequence number); telemetry samples
//!   that arrive meanwhile are kept ([`LinkClient::take_telemetry`]).
//! * [`stream_knots`]: sends a trajectory's knots in frames of 8, keeping the controller's
//!   buffer full and waiting (polling the status) when it is.
//! * [`upload_calibration`]: Begin, Chunks, Commit.
//! * [`figure_knots`]: the built-in test trajectory (a Lissajous figure through the workspace);
//!   [`read_knots_csv`]: knots from a file.
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};

use link_protocol::{
    decode, encode, Command, DeviceBody, DeviceMessage, FrameReader, Knot, LinkError, Received,
    Request, Response, StatusReport, TelemetrySample, CALIBRATION_CHUNK_LEN, MAX_FRAME_LEN,
    MAX_KNOTS_PER_FRAME,
};

pub use link_protocol;

pub mod interrupt;

/// What can go wrong talking to a controller.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The byte stream failed.
    #[error("link i/o: {0}")]
    Io(#[from] std::io::Error),
    /// The serial port could not be opened or configured (missing device, no permission,
    /// not a terminal, a baud rate the driver refuses).
    #[error("serial port: {0}")]
    SerialPort(serialport::Error),
    /// No reply in time.
    #[error("no reply from the controller within {0:?}")]
    Timeout(Duration),
    /// The controller could not decode our frame.
    #[error("the controller rejected the frame: {0:?}")]
    FrameRejected(link_protocol::FrameError),
    /// The controller refused the request (a calibration refusal also as its sentence, which
    /// names what differs with the values).
    #[error("the controller refused {command}: {error:?}{}", explained(.error))]
    Refused {
        /// The request's name.
        command: &'static str,
        /// Why.
        error: LinkError,
    },
    /// A reply of an unexpected kind.
    #[error("unexpected reply to {command}: {reply:?}")]
    Unexpected {
        /// The request's name.
        command: &'static str,
        /// What came back.
        reply: Box<Response>,
    },
    /// A frame from the controller that does not decode (a corrupted byte on the wire).
    #[error("undecodable frame from the controller: {0:?}")]
    BadFrame(link_protocol::FrameError),
    /// A knot file or trajectory is unusable.
    #[error("trajectory: {0}")]
    Trajectory(String),
    /// Interrupted (Ctrl-C) while waiting for the controller.
    #[error("interrupted")]
    Interrupted,
    /// The controller committed an image whose id is not the file's.
    #[error("the controller reports calibration id {controller:?} after the upload, the file's is {file:#010x}")]
    CalibrationId {
        /// The file's id ([`link_protocol::calibration_image_id`]).
        file: u32,
        /// What the controller reported.
        controller: Option<u32>,
    },
}

/// A refusal's sentence where the code alone does not say enough: a calibration refusal names
/// the parameter and both values, or both machines (`CalibrationRefusal`'s `Display`).
fn explained(error: &LinkError) -> String {
    match error {
        LinkError::Calibration(r) => format!(": {r}"),
        _ => String::new(),
    }
}

/// The name of a command, for messages.
pub fn command_name(c: &Command) -> &'static str {
    match c {
        Command::Identify => "identify",
        Command::Status => "status",
        Command::Enable => "enable",
        Command::Disable => "disable",
        Command::Home => "home",
        Command::MoveTo { .. } => "move",
        Command::StreamKnots { .. } => "stream",
        Command::Stop => "stop",
        Command::ResetFault => "reset",
        Command::Telemetry { .. } => "telemetry",
        Command::CalibrationBegin { .. } => "calibration begin",
        Command::CalibrationChunk { .. } => "calibration chunk",
        Command::CalibrationCommit => "calibration commit",
        Command::CalibrationId => "calibration id",
    }
}

/// The first sequence number of a client: from the process id, so that a late reply to another
/// process's client (its numbers started elsewhere) is unlikely to carry one of ours, while
/// the same process always sends the same bytes (co-simulation runs are compared byte for
/// byte).
fn first_seq() -> u16 {
    let pid = std::process::id();
    (pid ^ (pid >> 16)) as u16
}

/// A connection to a controller.
pub struct LinkClient<S: Read + Write> {
    io: S,
    reader: FrameReader,
    seq: u16,
    telemetry: Vec<TelemetrySample>,
    /// Messages read but not yet returned (several can arrive in one read).
    pending: std::collections::VecDeque<DeviceBody>,
    /// Frames from the controller that did not decode.
    pub bad_frames: u64,
    timeout: Duration,
}

impl LinkClient<TcpStream> {
    /// Connects to `addr` (QEMU's `-serial tcp:...` socket), retrying until `timeout`.
    pub fn connect_tcp(addr: &str, timeout: Duration) -> Result<Self, ClientError> {
        let start = Instant::now();
        loop {
            match TcpStream::connect(addr) {
                Ok(s) => {
                    s.set_nodelay(true)?;
                    s.set_read_timeout(Some(Duration::from_millis(20)))?;
                    return LinkClient::new(s, timeout);
                }
                Err(e) if start.elapsed() > timeout => return Err(e.into()),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        }
    }
}

/// How long one read of a serial port waits for a byte: short, so that the request deadline
/// is checked often (a silent controller is noticed within its timeout).
const SERIAL_READ_TIMEOUT: Duration = Duration::from_millis(20);

impl LinkClient<Box<dyn serialport::SerialPort>> {
    /// Opens the serial port at `path` (the real board's UART: the ST-LINK virtual COM port
    /// of a NUCLEO-G474RE is `/dev/ttyACM0` or similar), `baud` bits per second, 8 data bits,
    /// no parity, 1 stop bit, no flow control, raw mode (the `serialport` crate sets the
    /// termios); `timeout` bounds each request.
    pub fn open_serial(path: &Path, baud: u32, timeout: Duration) -> Result<Self, ClientError> {
        let port = serialport::new(path.to_string_lossy(), baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(SERIAL_READ_TIMEOUT)
            .open()
            .map_err(ClientError::SerialPort)?;
        // Bytes the port received before we opened it are not answers to us.
        port.clear(serialport::ClearBuffer::Input)
            .map_err(ClientError::SerialPort)?;
        LinkClient::new(port, timeout)
    }
}

/// Any byte stream a client runs on: a TCP socket, a serial port, a test's pipe.
pub trait Port: Read + Write {}
impl<T: Read + Write> Port for T {}

/// Where a controller's link is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Transport {
    /// QEMU's `-serial tcp:...` socket: HOST:PORT.
    Tcp(String),
    /// A serial port (the real board), 8N1 at `baud`.
    Serial { path: std::path::PathBuf, baud: u32 },
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transport::Tcp(addr) => write!(f, "controller at {addr}"),
            Transport::Serial { path, .. } => write!(f, "controller on {}", path.display()),
        }
    }
}

impl LinkClient<Box<dyn Port>> {
    /// Connects over `transport` ([`LinkClient::connect_tcp`], [`LinkClient::open_serial`]):
    /// one client type for either, so that a command is written once for both.
    pub fn open(transport: &Transport, timeout: Duration) -> Result<Self, ClientError> {
        Ok(match transport {
            Transport::Tcp(addr) => LinkClient::connect_tcp(addr, timeout)?.boxed(),
            Transport::Serial { path, baud } => {
                LinkClient::open_serial(path, *baud, timeout)?.boxed()
            }
        })
    }
}

impl<S: Read + Write> LinkClient<S> {
    /// A client over `io` (reads must time out, so that a silent controller is noticed);
    /// `timeout` bounds each request.
    pub fn new(mut io: S, timeout: Duration) -> Result<Self, ClientError> {
        // A zero ends whatever half frame an earlier client left in the controller's reader
        // (the controller answers those bytes with a rejection, which `request` tells apart).
        io.write_all(&[0])?;
        Ok(LinkClient {
            io,
            reader: FrameReader::new(),
            seq: first_seq(),
            telemetry: Vec::new(),
            pending: Default::default(),
            bad_frames: 0,
            timeout,
        })
    }

    /// The same client over its stream boxed (see [`LinkClient::open`]).
    pub fn boxed(self) -> LinkClient<Box<dyn Port>>
    where
        S: 'static,
    {
        LinkClient {
            io: Box::new(self.io),
            reader: self.reader,
            seq: self.seq,
            telemetry: self.telemetry,
            pending: self.pending,
            bad_frames: self.bad_frames,
            timeout: self.timeout,
        }
    }

    /// The client with its next request numbered `first` (then counting up): where the run must
    /// be reproducible to the byte (a co-simulation), the numbers must not depend on when or by
    /// which process the client was made.
    pub fn with_sequence(mut self, first: u16) -> Self {
        self.seq = first.wrapping_sub(1);
        self
    }

    /// Sends raw bytes (the garbage test) and waits for the answers they provoke: the
    /// controller answers every non-empty run of bytes between two zeros with exactly one
    /// message (a rejection, unless the run happens to be a valid frame). Returns (frames sent,
    /// answers received); waits at most the client's timeout for the answers.
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(usize, usize), ClientError> {
        let frames = bytes
            .split(|&b| b == 0)
            .filter(|run| !run.is_empty())
            .count()
            - usize::from(bytes.last().is_some_and(|&b| b != 0));
        self.io.write_all(bytes)?;
        let deadline = Instant::now() + self.timeout;
        let mut answers = 0;
        while answers < frames {
            match self.next_message(deadline) {
                Ok(_) => answers += 1,
                Err(ClientError::Timeout(_)) => break,
                Err(e) => return Err(e),
            }
        }
        Ok((frames, answers))
    }

    /// Sends `command` and waits for its reply: the [`DeviceBody::Reply`] that carries its
    /// sequence number. Anything else that arrives meanwhile is not the answer: telemetry is
    /// kept, replies to other sequence numbers (late answers to an earlier client or request)
    /// are dropped. A [`DeviceBody::FrameRejected`] carries no sequence number: it may be ours
    /// (the frame was damaged on the way, the command did not run) or the answer to stale bytes
    /// another client left in the controller's reader. The controller answers frames in order,
    /// so the client sends a `Status` probe and reads on: if the reply to the command comes
    /// before the probe's, the rejection was someone else's and the reply is returned; if the
    /// probe's comes first, the command's frame was the one rejected, and that is the error. So
    /// a command that ran is never reported refused, nor a refused one done.
    pub fn request(&mut self, command: Command) -> Result<Response, ClientError> {
        let name = command_name(&command);
        let seq = self.send(command)?;
        let deadline = Instant::now() + self.timeout;
        let (mut probe, mut rejected) = (None, None);
        loop {
            match self.next_message(deadline)? {
                DeviceBody::Reply { seq: s, result } if s == seq => {
                    return result.map_err(|error| ClientError::Refused {
                        command: name,
                        error,
                    })
                }
                DeviceBody::Reply { seq: s, .. } if Some(s) == probe => {
                    // The probe was answered and the command was not: its frame was rejected.
                    if let Some(e) = rejected {
                        return Err(ClientError::FrameRejected(e));
                    }
                }
                DeviceBody::FrameRejected(e) => {
                    rejected = Some(e);
                    probe = Some(self.send(Command::Status)?);
                }
                // A late reply to an earlier request (after a timeout), or telemetry: go on.
                _ => {}
            }
        }
    }

    /// Encodes and sends one request with the next sequence number; returns it.
    fn send(&mut self, command: Command) -> Result<u16, ClientError> {
        self.seq = self.seq.wrapping_add(1);
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = encode(&Request::new(self.seq, command), &mut frame)
            .map_err(ClientError::FrameRejected)?;
        self.io.write_all(&frame[..n])?;
        Ok(self.seq)
    }

    /// Reads until one message (telemetry is kept) or `deadline`.
    fn next_message(&mut self, deadline: Instant) -> Result<DeviceBody, ClientError> {
        let mut buf = [0u8; 256];
        loop {
            if let Some(body) = self.pending.pop_front() {
                return Ok(body);
            }
            if interrupt::requested() {
                return Err(ClientError::Interrupted);
            }
            if Instant::now() > deadline {
                return Err(ClientError::Timeout(self.timeout));
            }
            let n = match self.io.read(&mut buf) {
                Ok(0) => return Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof).into()),
                Ok(n) => n,
                // A signal during the read (Ctrl-C's handler) interrupts it: read again, after
                // the interrupt flag's check above, so that Ctrl-C reads as `Interrupted`.
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) =>
                {
                    continue
                }
                Err(e) => return Err(e.into()),
            };
            for &b in &buf[..n] {
                let body = match self.reader.push(b) {
                    None => continue,
                    Some(Received::TooLong) => Err(link_protocol::FrameError::TooLong),
                    Some(Received::Frame(f)) => decode::<DeviceMessage>(f).map(|m| m.body),
                };
                match body {
                    Ok(DeviceBody::Telemetry(t)) => self.telemetry.push(t),
                    Ok(other) => self.pending.push_back(other),
                    Err(_) => self.bad_frames += 1,
                }
            }
        }
    }

    /// Reads for `duration`, keeping telemetry.
    pub fn listen(&mut self, duration: Duration) -> Result<(), ClientError> {
        let deadline = Instant::now() + duration;
        loop {
            match self.next_message(deadline) {
                Err(ClientError::Timeout(_)) => return Ok(()),
                Err(e) => return Err(e),
                Ok(_) => {}
            }
        }
    }

    /// The telemetry samples received so far (and forgets them).
    pub fn take_telemetry(&mut self) -> Vec<TelemetrySample> {
        std::mem::take(&mut self.telemetry)
    }

    /// The controller's status.
    pub fn status(&mut self) -> Result<StatusReport, ClientError> {
        match self.request(Command::Status)? {
            Response::Status(s) => Ok(s),
            other => Err(ClientError::Unexpected {
                command: "status",
                reply: Box::new(other),
            }),
        }
    }
}

/// Progress of a long operation: (done, total).
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// How long a stream's first frame waits while the controller answers `Busy` (it finishes a
/// move or a calibration switch at rest) before the refusal is the answer.
pub const BUSY_WAIT: Duration = Duration::from_secs(3);

/// Streams `knots` (times from the stream's start), keeping the controller's buffer as full as
/// it takes; returns when every knot is queued. A first frame refused as `Busy` is sent again
/// for up to [`BUSY_WAIT`]. `poll` is how long to wait before asking again
/// when the buffer is full.
pub fn stream_knots<S: Read + Write>(
    client: &mut LinkClient<S>,
    knots: &[Knot],
    poll: Duration,
    progress: Progress<'_>,
) -> Result<(), ClientError> {
    let mut sent = 0usize;
    let mut free = link_protocol::MAX_KNOTS_PER_FRAME;
    let mut busy_since: Option<Instant> = None;
    while sent < knots.len() {
        let end = (sent + MAX_KNOTS_PER_FRAME).min(knots.len());
        if free < end - sent {
            std::thread::sleep(poll);
            let s = client.status()?;
            // A controller that faulted or left Running plays no more knots: its buffer would
            // never free (the stream waits for a reset), so the stream ends here, named.
            if s.fault.is_some() || s.mode != link_protocol::ModeCode::Running {
                return Err(ClientError::Trajectory(format!(
                    "the controller stopped playing the stream after {sent} of {} knots: mode {:?}, \
                     fault {:?} (`host-sim link status` tells more; `link reset` clears it)",
                    knots.len(),
                    s.mode,
                    s.fault
                )));
            }
            free = controller_free(&s);
            continue;
        }
        let frame = heapless::Vec::from_slice(&knots[sent..end])
            .map_err(|_| ClientError::Trajectory("frame".into()))?;
        match client.request(Command::StreamKnots {
            first_index: sent as u32,
            knots: frame,
        }) {
            Ok(Response::StreamAccepted { free: f, .. }) => {
                free = usize::from(f);
                sent = end;
                progress(sent, knots.len());
            }
            Err(ClientError::Refused {
                error: LinkError::StreamFull(f),
                ..
            }) => free = usize::from(f),
            // The first frame while the controller still finishes what came before (a move's
            // last samples, a calibration switch's ramp at rest): wait for it, a bounded time.
            Err(ClientError::Refused {
                error: LinkError::Busy,
                ..
            }) if sent == 0
                && busy_since.get_or_insert_with(Instant::now).elapsed() < BUSY_WAIT =>
            {
                std::thread::sleep(poll.max(Duration::from_millis(5)));
                client.status()?;
            }
            // Later frames: the controller's stream ran dry before this one came (it stops
            // the machine, an underrun) or another client took the motion over.
            Err(ClientError::Refused {
                error: LinkError::Busy,
                ..
            }) if sent > 0 => {
                return Err(ClientError::Trajectory(format!(
                    "the controller took no more knots after {sent} of {}: its stream ran dry \
                     before the next frame came (an underrun stops the machine; `status` tells) \
                     or another client moved it; knots further apart give the link more time",
                    knots.len()
                )))
            }
            Ok(other) => {
                return Err(ClientError::Unexpected {
                    command: "stream",
                    reply: Box::new(other),
                })
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

fn controller_free(s: &StatusReport) -> usize {
    link_protocol::STREAM_BUFFER_KNOTS.saturating_sub(usize::from(s.stream_knots_queued))
}

/// Uploads a calibration image; returns its id, which the controller's commit reported and which
/// is the file's own ([`link_protocol::calibration_image_id`], CRC-32C of its bytes; anything
/// else is [`ClientError::CalibrationId`]).
pub fn upload_calibration<S: Read + Write>(
    client: &mut LinkClient<S>,
    image: &[u8],
    progress: Progress<'_>,
) -> Result<u32, ClientError> {
    client.request(Command::CalibrationBegin {
        len: image.len() as u32,
    })?;
    for (i, chunk) in image.chunks(CALIBRATION_CHUNK_LEN).enumerate() {
        let offset = (i * CALIBRATION_CHUNK_LEN) as u32;
        let data = heapless::Vec::from_slice(chunk)
            .map_err(|_| ClientError::Trajectory("chunk".into()))?;
        client.request(Command::CalibrationChunk { offset, data })?;
        progress(offset as usize + chunk.len(), image.len());
    }
    let file = link_protocol::calibration_image_id(image);
    match client.request(Command::CalibrationCommit)? {
        Response::CalibrationId(Some(id)) if id == file => Ok(id),
        Response::CalibrationId(controller) => Err(ClientError::CalibrationId { file, controller }),
        other => Err(ClientError::Unexpected {
            command: "calibration commit",
            reply: Box::new(other),
        }),
    }
}

/// The built-in test trajectory: a Lissajous figure (±`amp_mm[0]` along x at `freq_hz`,
/// ±`amp_mm[1]` along y at twice that) around `centre_mm`, as knots every `knot_ms` for
/// `seconds`, with a sin² envelope over the first and last 0.5 s so that it starts and ends
/// at rest at the centre.
pub fn figure_knots(
    centre_mm: [f64; 2],
    amp_mm: [f64; 2],
    freq_hz: f64,
    seconds: f64,
    knot_ms: u32,
) -> Vec<Knot> {
    let ramp = 0.5f64.min(seconds / 2.0);
    let w = 2.0 * std::f64::consts::PI * freq_hz;
    // Position and velocity of the enveloped figure (exact derivative).
    let at = |t: f64| {
        let (env, denv) = if t < ramp {
            let a = std::f64::consts::FRAC_PI_2 * t / ramp;
            (
                a.sin().powi(2),
                2.0 * a.sin() * a.cos() * std::f64::consts::FRAC_PI_2 / ramp,
            )
        } else if t > seconds - ramp {
            let a = std::f64::consts::FRAC_PI_2 * (seconds - t) / ramp;
            (
                a.sin().powi(2),
                -2.0 * a.sin() * a.cos() * std::f64::consts::FRAC_PI_2 / ramp,
            )
        } else {
            (1.0, 0.0)
        };
        let (sx, cx) = (w * t).sin_cos();
        let (sy, cy) = (2.0 * w * t).sin_cos();
        let p = [
            centre_mm[0] + env * amp_mm[0] * sx,
            centre_mm[1] + env * amp_mm[1] * sy,
        ];
        let v = [
            denv * amp_mm[0] * sx + env * amp_mm[0] * w * cx,
            denv * amp_mm[1] * sy + env * amp_mm[1] * 2.0 * w * cy,
        ];
        (p, v)
    };
    let knot_ms = knot_ms.max(1);
    let n = (seconds * 1000.0 / f64::from(knot_ms)).round() as u32;
    (1..=n)
        .map(|i| {
            let (p, v) = at(f64::from(i * knot_ms) * 1e-3);
            Knot {
                t_us: i * knot_ms * 1000,
                position_mm: [p[0] as f32, p[1] as f32],
                velocity_mm_s: [v[0] as f32, v[1] as f32],
            }
        })
        .collect()
}

/// Knots from CSV text: `t_s,x_mm,y_mm,vx_mm_s,vy_mm_s` per line (times from the stream's
/// start, strictly increasing; the controller checks the limits), after an optional header: a
/// first line that is five numbers is the first knot, not a header to skip.
pub fn parse_knots_csv(text: &str) -> Result<Vec<Knot>, ClientError> {
    let mut knots = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let parsed: Result<Vec<f64>, _> =
            line.split(',').map(|v| v.trim().parse::<f64>()).collect();
        let f = match parsed {
            Ok(f) => f,
            // The header: the first line, not numbers.
            Err(_) if i == 0 => continue,
            Err(e) => return Err(ClientError::Trajectory(format!("line {}: {e}", i + 1))),
        };
        let [t, x, y, vx, vy] = f[..] else {
            return Err(ClientError::Trajectory(format!(
                "line {}: expected 5 numbers, got {}",
                i + 1,
                f.len()
            )));
        };
        if !(t > 0.0 && t < 4000.0 && [x, y, vx, vy].iter().all(|v| v.is_finite())) {
            return Err(ClientError::Trajectory(format!(
                "line {}: time must be in (0, 4000) s and every number finite",
                i + 1
            )));
        }
        knots.push(Knot {
            t_us: (t * 1e6).round() as u32,
            position_mm: [x as f32, y as f32],
            velocity_mm_s: [vx as f32, vy as f32],
        });
    }
    if knots.is_empty() {
        return Err(ClientError::Trajectory("no knots".into()));
    }
    Ok(knots)
}

/// Telemetry as CSV text (header and one line per sample).
pub fn telemetry_csv(samples: &[TelemetrySample]) -> String {
    let mut s = String::from(
        "tick,setpoint_x_mm,setpoint_y_mm,reference_1_rad,reference_2_rad,encoder_1_rad,encoder_2_rad,torque_1_nm,torque_2_nm,following_error_rad,mode,fault\n",
    );
    for t in samples {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{:?},{}\n",
            t.tick,
            t.setpoint_mm[0],
            t.setpoint_mm[1],
            t.reference_rad[0],
            t.reference_rad[1],
            t.encoder_rad[0],
            t.encoder_rad[1],
            t.torque_nm[0],
            t.torque_nm[1],
            t.following_error_rad,
            t.mode,
            t.fault.map_or(String::new(), |f| format!("{f:?}")),
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_figure_starts_and_ends_at_rest_at_its_centre_and_its_velocities_are_derivatives() {
        let k = figure_knots([212.0, 0.0], [30.0, 40.0], 0.5, 3.0, 10);
        assert_eq!(k.len(), 300);
        let last = k.last().unwrap();
        assert!((last.position_mm[0] - 212.0).abs() < 1e-4 && last.position_mm[1].abs() < 1e-4);
        assert!(last.velocity_mm_s[0].abs() < 1e-3 && last.velocity_mm_s[1].abs() < 1e-3);
        for w in k.windows(3).skip(10).step_by(17) {
            // The envelope is C¹ but not C² where the ramps meet the plateau (0.5 s, 2.5 s): a
            // central difference across those knots is off by h·Δp''/4 there.
            let t_mid = f64::from(w[1].t_us) * 1e-6;
            if (t_mid - 0.5).abs() < 0.011 || (t_mid - 2.5).abs() < 0.011 {
                continue;
            }
            for a in 0..2 {
                let v = (w[2].position_mm[a] - w[0].position_mm[a]) / 0.02;
                assert!(
                    (v - w[1].velocity_mm_s[a]).abs()
                        < 0.02 * w[1].velocity_mm_s[a].abs().max(10.0),
                    "{v} {:?}",
                    w[1]
                );
            }
        }
    }

    #[test]
    fn a_knot_file_is_read_and_bad_lines_are_named() {
        let k =
            parse_knots_csv("t_s,x_mm,y_mm,vx_mm_s,vy_mm_s\n0.01,212,0,1,0\n0.02,212.01,0,0,0\n")
                .unwrap();
        assert_eq!(k.len(), 2);
        assert_eq!(k[1].t_us, 20_000);
        let e = parse_knots_csv("h\n0.01,212,0,1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("5 numbers"), "{e}");
        assert!(parse_knots_csv("h\n0.01,NaN,0,1,0\n").is_err());
        assert!(parse_knots_csv("h\n").is_err());
    }

    /// A knot file without a header: its first line is the first knot, not skipped.
    #[test]
    fn a_knot_file_without_a_header_keeps_its_first_knot() {
        let k = parse_knots_csv("0.01,212,0,1,0\n0.02,212.01,0,0,0\n").unwrap();
        assert_eq!(k.len(), 2);
        assert_eq!((k[0].t_us, k[1].t_us), (10_000, 20_000));
        let e = parse_knots_csv("0.01,212,0,1,0\nx,1,2,3,4\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
    }

    /// A controller in memory: it decodes each request frame the client writes and answers as
    /// the firmware would, in order; `stale` bytes are waiting in its reader when the client
    /// connects (another client sent them without a delimiter), and `damage` lists the
    /// sequence numbers of the frames the wire damages (answered with a rejection, not run).
    struct Controller {
        reader: FrameReader,
        to_host: std::collections::VecDeque<u8>,
        damage: Vec<u16>,
        /// The commands that ran.
        ran: Vec<Command>,
    }

    impl Controller {
        fn new(stale: &[u8], damage: &[u16]) -> Self {
            let mut c = Controller {
                reader: FrameReader::new(),
                to_host: Default::default(),
                damage: damage.to_vec(),
                ran: vec![],
            };
            for &b in stale {
                c.reader.push(b);
            }
            c
        }

        fn answer(&mut self, body: DeviceBody) {
            let mut out = [0u8; MAX_FRAME_LEN];
            let n = encode(&DeviceMessage::new(body), &mut out).unwrap();
            self.to_host.extend(&out[..n]);
        }
    }

    impl Write for Controller {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            for &b in bytes {
                let body = match self.reader.push(b) {
                    None => continue,
                    Some(Received::TooLong) => {
                        DeviceBody::FrameRejected(link_protocol::FrameError::TooLong)
                    }
                    Some(Received::Frame(f)) => match decode::<Request>(f) {
                        Err(e) => DeviceBody::FrameRejected(e),
                        Ok(r) if self.damage.contains(&r.seq) => {
                            DeviceBody::FrameRejected(link_protocol::FrameError::Crc)
                        }
                        Ok(r) => {
                            self.ran.push(r.command.clone());
                            let result = match r.command {
                                Command::MoveTo { .. } => {
                                    Ok(Response::MovePlanned { duration_s: 0.5 })
                                }
                                Command::Stop => Err(LinkError::Busy),
                                _ => Ok(Response::Done),
                            };
                            DeviceBody::Reply { seq: r.seq, result }
                        }
                    },
                };
                self.answer(body);
            }
            Ok(bytes.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Read for Controller {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            if self.to_host.is_empty() {
                return Err(std::io::ErrorKind::WouldBlock.into());
            }
            let n = buf.len().min(self.to_host.len());
            for (b, v) in buf.iter_mut().zip(self.to_host.drain(..n)) {
                *b = v;
            }
            Ok(n)
        }
    }

    /// The reproduction: another client sent 4 bytes without a delimiter and went away; the
    /// next client's leading zero makes the controller reject them (a `FrameRejected` with no
    /// sequence number). The move that follows ran and is reported planned, not "rejected:
    /// Cobs"; a refused command is reported refused; the rejection is told apart from one of
    /// the client's own frames, which did not run and is reported as such.
    #[test]
    fn answers_are_matched_by_sequence_number_and_stale_rejections_dropped() {
        let mut client = LinkClient::new(
            Controller::new(&[0x07, 0x41, 0x13, 0x99], &[]),
            Duration::from_secs(2),
        )
        .unwrap();
        let r = client.request(Command::MoveTo {
            target_mm: [222.0, 5.0],
        });
        assert!(
            matches!(r, Ok(Response::MovePlanned { .. })),
            "a move that ran reported as {r:?}"
        );
        assert_eq!(
            client.io.ran.len(),
            2,
            "the move and the client's probe ran"
        );
        assert!(matches!(
            client.request(Command::Stop),
            Err(ClientError::Refused {
                error: LinkError::Busy,
                ..
            })
        ));
        assert!(matches!(
            client.request(Command::Status),
            Ok(Response::Done)
        ));
        // Our own frame damaged on the way: not run, reported rejected.
        let next = client.seq.wrapping_add(1);
        client.io.damage.push(next);
        let before = client.io.ran.len();
        let r = client.request(Command::MoveTo {
            target_mm: [200.0, 0.0],
        });
        assert!(matches!(r, Err(ClientError::FrameRejected(_))), "{r:?}");
        assert!(
            !client.io.ran[before..]
                .iter()
                .any(|c| matches!(c, Command::MoveTo { .. })),
            "the damaged move did not run"
        );
        // A late reply to another sequence number is not an answer.
        client.io.answer(DeviceBody::Reply {
            seq: client.seq.wrapping_add(7),
            result: Err(LinkError::Busy),
        });
        assert!(matches!(
            client.request(Command::Enable),
            Ok(Response::Done)
        ));
    }
}
