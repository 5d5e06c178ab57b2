//! The host link: every message the host and the motion controller exchange, and the frame
//! around each one. `no_std`, no heap; the firmware and the host tools link this one crate.
//!
//! # Frame
//! ```text
//!   COBS( postcard(message) ‖ CRC-32(postcard bytes), little-endian ) ‖ 0x00
//! ```
//! * the message is serialised with [`postcard`] (serde; varint integers, `f32` as 4 bytes
//!   little-endian, enums as a varint tag);
//! * a CRC-32 (ISO-HDLC, the grid image's CRC, [`crc`] crate) over the postcard bytes follows
//!   them, so a corrupted frame is refused before any field of it is believed;
//! * the whole is COBS-encoded ([`cobs`]) and ends with a zero byte, the only zero on the wire:
//!   a receiver that lost bytes or started mid-frame resynchronises at the next zero;
//! * every message starts with the protocol version ([`PROTOCOL_VERSION`]), read before the rest:
//!   a frame of another version is refused as [`FrameError::Version`], never misread;
//! * an encoded frame is at most [`MAX_FRAME_LEN`] bytes with its delimiter; a longer one is
//!   refused ([`FrameError::TooLong`]) and the receiver skips to the next zero.
//!
//! # Exchange
//! The host sends a [`Request`] (a sequence number and a [`Command`]); the controller answers
//! every frame with one [`DeviceMessage`]: a [`DeviceMessage::Reply`] with the same sequence
//! number and either a [`Response`] or a typed [`LinkError`], or, when the frame could not even
//! be decoded (so its sequence number is unknown), [`DeviceMessage::FrameRejected`] with the
//! [`FrameError`]. Never silence. Telemetry, once subscribed, arrives unsolicited as
//! [`DeviceMessage::Telemetry`].
//!
//! Units are in the names: `_mm`, `_mm_s`, `_rad`, `_nm` (torque, newton-metre), `_us`, `_s`.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

use serde::{Deserialize, Serialize};

mod calibration;
mod frame;
pub use calibration::{CalibrationRefusal, ImageParameter, MachineId, MACHINE_NAME_LEN};
pub use frame::{decode, encode, FrameReader, Received};

/// Protocol version carried first in every message. Bumped when any message changes.
pub const PROTOCOL_VERSION: u16 = 3;
/// Largest encoded frame, COBS overhead and delimiter included (bytes).
pub const MAX_FRAME_LEN: usize = 256;
/// Largest postcard payload of a frame, before the CRC and COBS (bytes): what fits in
/// [`MAX_FRAME_LEN`] after the 4-byte CRC, COBS's one byte per 254 and the delimiter.
pub const MAX_PAYLOAD_LEN: usize = MAX_FRAME_LEN - 4 - 2 - 1;
/// Knots in one [`Command::StreamKnots`] frame.
pub const MAX_KNOTS_PER_FRAME: usize = 8;
/// Knots the controller's motion stream buffer holds (its depth; 64 knots of 10 ms are 640 ms
/// of motion).
pub const STREAM_BUFFER_KNOTS: usize = 64;
/// Bytes of calibration image in one [`Command::CalibrationChunk`] frame.
pub const CALIBRATION_CHUNK_LEN: usize = 128;
/// Largest calibration image the controller accepts (bytes): a slot of the calibration region.
pub const MAX_CALIBRATION_IMAGE_LEN: u32 = 64 * 1024;

/// The id of a calibration image, as [`Identity::calibration_id`] and
/// [`Response::CalibrationId`] report it: the CRC-32C (Castagnoli, `crc::CRC_32_ISCSI`) of the
/// image's bytes, as uploaded (grid and extension blocks). The host computes it over its
/// `grid.bin` and compares; the controller's slot store records it with each commit.
///
/// Not the grid format's own CRC-32/ISO-HDLC: an image ends with that CRC of its bytes, and an
/// ISO-HDLC CRC over such bytes is the same constant (the CRC residue) for every image of a
/// length, so it would identify nothing.
pub fn calibration_image_id(image: &[u8]) -> u32 {
    const IMAGE_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
    IMAGE_CRC.checksum(image)
}

/// A request from the host.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Request {
    /// [`PROTOCOL_VERSION`] of the sender.
    pub version: u16,
    /// Chosen by the host; echoed in the reply.
    pub seq: u16,
    /// What to do.
    pub command: Command,
}

impl Request {
    /// A request of this protocol version.
    pub fn new(seq: u16, command: Command) -> Self {
        Request {
            version: PROTOCOL_VERSION,
            seq,
            command,
        }
    }
}

/// What the host asks the controller to do.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    /// Firmware version, board, protocol version, calibration id, machine: [`Response::Identity`].
    Identify,
    /// The controller's state: [`Response::Status`].
    Status,
    /// Engage the servo at the machine's position and enable the drives. Refused unless homed
    /// (or the settings say the encoders are absolute) and no fault is latched.
    Enable,
    /// Controlled stop if moving, then drives off (category 1, commanded).
    Disable,
    /// Start the homing procedure: [`Response::Done`] when started; progress in
    /// [`StatusReport::homing`].
    Home,
    /// Move to a point: the controller plans the jerk-limited move itself within its
    /// trajectory limits. Refused while a stream or move is under way.
    MoveTo {
        /// Target tool position (mm).
        target_mm: [f32; 2],
    },
    /// Append knots to the motion stream (see [`Knot`]). `first_index` is the running index of
    /// the first knot in the stream: 0 starts a new stream (at rest only), any other value must
    /// equal the number of knots already received, so a lost frame is detected, not skipped.
    /// The knots are validated whole (time, speed, acceleration, jerk, workspace) before any
    /// is queued: [`LinkError::Segment`] names the first bad one and nothing is queued.
    StreamKnots {
        /// Index of `knots[0]` in the stream.
        first_index: u32,
        /// Up to [`MAX_KNOTS_PER_FRAME`] knots, in time order.
        knots: heapless::Vec<Knot, MAX_KNOTS_PER_FRAME>,
    },
    /// Controlled deceleration along the path within the stop limits, then hold (category 2,
    /// commanded); the stream or move is dropped.
    Stop,
    /// Clear a latched fault and re-engage at the machine's position (drives on only if the
    /// cause is gone and the machine is homed).
    ResetFault,
    /// Telemetry: one [`TelemetrySample`] every `decimation` servo samples (2 kHz /
    /// decimation); 0 stops it. The controller may raise a too small decimation to
    /// [`MIN_TELEMETRY_DECIMATION`] (the link's bandwidth), and says so in the reply.
    Telemetry {
        /// Servo samples per telemetry sample; 0 = off.
        decimation: u16,
    },
    /// Start a calibration upload into the inactive slot: `len` bytes will follow.
    CalibrationBegin {
        /// Image length (bytes), at most [`MAX_CALIBRATION_IMAGE_LEN`].
        len: u32,
    },
    /// A piece of the image, in order.
    CalibrationChunk {
        /// Byte offset of `data` in the image: must equal the bytes received so far.
        offset: u32,
        /// Up to [`CALIBRATION_CHUNK_LEN`] bytes.
        data: heapless::Vec<u8, CALIBRATION_CHUNK_LEN>,
    },
    /// Validate the uploaded image (header, CRC, this machine's, plausible) and switch to it
    /// atomically: [`Response::CalibrationId`] of the new image. A refused image leaves the
    /// old one in force.
    CalibrationCommit,
    /// The id of the image in force: [`Response::CalibrationId`].
    CalibrationId,
}

/// The smallest telemetry decimation the controller honours: 20 (100 Hz), what a 115 200 baud
/// UART carries with room for replies (a sample is ~60 bytes framed).
pub const MIN_TELEMETRY_DECIMATION: u16 = 20;

/// A knot of a streamed trajectory: a timestamped position with its velocity, in task space.
/// Between two knots the controller interpolates a cubic Hermite (position and velocity match
/// at both ends; acceleration is linear and jerk constant inside the segment) and samples it
/// at 2 kHz with its exact derivatives.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Knot {
    /// Time of the knot from the stream's start (µs). The stream starts at the setpoint the
    /// machine rests at, at time 0; times strictly increase.
    pub t_us: u32,
    /// Tool position (mm).
    pub position_mm: [f32; 2],
    /// Tool velocity (mm/s).
    pub velocity_mm_s: [f32; 2],
}

/// Every message from the controller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceMessage {
    /// [`PROTOCOL_VERSION`] of the controller.
    pub version: u16,
    /// What it says.
    pub body: DeviceBody,
}

impl DeviceMessage {
    /// A message of this protocol version.
    pub fn new(body: DeviceBody) -> Self {
        DeviceMessage {
            version: PROTOCOL_VERSION,
            body,
        }
    }
}

/// What a controller message says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum DeviceBody {
    /// The answer to the request with this sequence number.
    Reply {
        /// The request's sequence number.
        seq: u16,
        /// Done, or why not.
        result: Result<Response, LinkError>,
    },
    /// A frame that could not be decoded (its sequence number is unknown): why.
    FrameRejected(FrameError),
    /// A telemetry sample (after [`Command::Telemetry`]).
    Telemetry(TelemetrySample),
}

/// A successful answer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Response {
    /// The command was carried out or started.
    Done,
    /// Answer to [`Command::Identify`].
    Identity(Identity),
    /// Answer to [`Command::Status`].
    Status(StatusReport),
    /// Answer to [`Command::MoveTo`]: the planned move's duration (s).
    MovePlanned {
        /// Duration of the planned move (s).
        duration_s: f32,
    },
    /// Answer to [`Command::StreamKnots`]: the knots were queued.
    StreamAccepted {
        /// Knots received in this stream so far (the next `first_index`).
        next_index: u32,
        /// Free knot slots in the buffer now.
        free: u16,
    },
    /// Answer to [`Command::Telemetry`]: the decimation in force.
    TelemetryDecimation(u16),
    /// Answer to [`Command::CalibrationChunk`]: bytes received so far.
    CalibrationReceived(u32),
    /// Answer to [`Command::CalibrationCommit`] and [`Command::CalibrationId`]: the id (the
    /// image's CRC-32) of the image in force, `None` if there is none.
    CalibrationId(Option<u32>),
}

/// Which board the firmware was built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Board {
    /// MPS2-AN386 under QEMU, with the simulated machine.
    Qemu,
    /// STM32G474RE.
    Stm32G474,
}

/// Answer to [`Command::Identify`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Identity {
    /// The controller's [`PROTOCOL_VERSION`].
    pub protocol_version: u16,
    /// Firmware version (the package's semver).
    pub firmware_version: [u16; 3],
    /// The board.
    pub board: Board,
    /// The id of the calibration image in force ([`calibration_image_id`]), `None` if none is.
    pub calibration_id: Option<u32>,
    /// The machine the controller drives: the machine record of the image in force (its
    /// `HRMC` block), or the firmware's built-in record when the image carries none or no image
    /// is in force. An upload must be an image of this machine.
    pub machine: MachineId,
}

/// The servo loop's mode, as the link reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModeCode {
    /// Drives on, following the setpoints.
    Running,
    /// Drives on, braking after a fault or a stop command.
    Stopping,
    /// Drives on, holding where a stop ended.
    Holding,
    /// Drives off.
    SafeState,
    /// Drives off, waiting for homing (incremental encoders).
    Unhomed,
    /// Homing under way.
    Homing,
}

/// Why the machine stopped (the controller's fault, flattened for the wire; the details are in
/// the controller's defmt log).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCode {
    /// A setpoint the servo refused.
    Setpoint,
    /// A stop would have ended outside the workspace.
    StopOutsideWorkspace,
    /// The setpoint stream ran dry while moving (controlled stop, category 2).
    Underrun,
    /// Following error or non-finite feedback.
    Servo,
    /// Encoder implausible, stuck or glitching.
    Encoder,
    /// The stop's own setpoint was refused.
    StopRefused,
    /// Deadline overrun streak.
    DeadlineMissed,
    /// PWM write failed or drive outputs off.
    Drive,
    /// Settings refused at boot.
    Settings,
    /// Calibration image refused.
    Calibration,
    /// Could not engage at the machine's position.
    Engage,
    /// Watchdog reset or watchdog not started.
    Watchdog,
    /// A commanded stop or disable (not a failure).
    Commanded,
    /// Not homed.
    NotHomed,
    /// Homing failed (index not found, reference refused, following error while homing).
    Homing,
}

/// Homing progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingState {
    /// Not homed (the drives will not engage unless the encoders are absolute).
    NotHomed,
    /// Homing under way.
    InProgress,
    /// Homed: the encoder zero the calibration refers to is set.
    Homed,
    /// Homing failed (index pulse not found, hard stop not reached...).
    Failed,
}

/// Answer to [`Command::Status`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    /// Servo samples since the timer started.
    pub ticks: u32,
    /// The servo loop's mode.
    pub mode: ModeCode,
    /// The latched fault, if any.
    pub fault: Option<FaultCode>,
    /// Drive enable.
    pub drives_enabled: bool,
    /// Homing.
    pub homing: HomingState,
    /// The setpoint in force (mm).
    pub setpoint_mm: [f32; 2],
    /// The encoder angles (rad).
    pub encoder_rad: [f32; 2],
    /// Largest following error so far (rad).
    pub max_following_error_rad: f32,
    /// Deadline overruns so far.
    pub overruns: u32,
    /// Longest servo step (µs).
    pub worst_step_us: f32,
    /// Samples the setpoint queue was empty.
    pub setpoint_underruns: u32,
    /// Knots waiting in the motion stream buffer.
    pub stream_knots_queued: u16,
    /// A move, stream or stop is under way: the machine's setpoint still changes (false only
    /// once the servo loop's setpoint has reached where the motion ends).
    pub moving: bool,
    /// Telemetry decimation in force (0: off; [`Command::Telemetry`]).
    pub telemetry_decimation: u16,
    /// A committed calibration waits for the servo to switch to it (at the next rest): its id.
    pub calibration_pending: Option<u32>,
}

/// One telemetry sample.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TelemetrySample {
    /// Servo sample index.
    pub tick: u32,
    /// Setpoint (mm).
    pub setpoint_mm: [f32; 2],
    /// Commanded encoder angles (rad).
    pub reference_rad: [f32; 2],
    /// Encoder angles (rad).
    pub encoder_rad: [f32; 2],
    /// Torques written (N·m).
    pub torque_nm: [f32; 2],
    /// Largest |following error| of the two axes this sample (rad).
    pub following_error_rad: f32,
    /// The servo loop's mode.
    pub mode: ModeCode,
    /// The latched fault.
    pub fault: Option<FaultCode>,
}

/// Why a frame was not decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Longer than [`MAX_FRAME_LEN`].
    TooLong,
    /// Not valid COBS, or empty.
    Cobs,
    /// Shorter than its CRC.
    Short,
    /// The CRC does not match.
    Crc,
    /// Another protocol version (the one found).
    Version(u16),
    /// CRC good but not a message of this version (postcard refused it), or bytes left over.
    Malformed,
    /// The message does not fit a frame (encoder side).
    Overflow,
}

/// Why a well-formed request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkError {
    /// The request's protocol version is not the controller's (the one found).
    Version(u16),
    /// A fault is latched: [`Command::ResetFault`] first.
    Faulted(FaultCode),
    /// The drives are off: [`Command::Enable`] first.
    NotEnabled,
    /// The machine is not homed.
    NotHomed,
    /// A move, stream, stop or homing is under way.
    Busy,
    /// A knot of a [`Command::StreamKnots`] was refused (nothing of the frame was queued).
    Segment {
        /// Index in the stream of the refused knot.
        index: u32,
        /// Why.
        reason: SegmentRefusal,
    },
    /// [`Command::StreamKnots`]'s `first_index` is not the next expected (the expected one).
    StreamIndex(u32),
    /// The stream buffer has fewer free slots than knots sent (free slots).
    StreamFull(u16),
    /// [`Command::MoveTo`]'s target is outside the workspace, not finite, or the move could
    /// not be planned.
    Target,
    /// Calibration upload refused.
    Calibration(CalibrationRefusal),
    /// Homing could not start.
    Homing,
    /// The command is not available on this board or build, or (moves and streams) the
    /// controller's motion comes from a built-in source, not the link (`Settings::link_motion`).
    Unsupported,
}

/// Why a streamed knot was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SegmentRefusal {
    /// A non-finite number.
    NotFinite,
    /// Its time is not after the previous knot's.
    Time,
    /// The segment ending at it is longer than [`MAX_SEGMENT_US`].
    TooLong,
    /// Speed beyond the controller's limit somewhere in the segment.
    Speed,
    /// Acceleration beyond the limit.
    Acceleration,
    /// Jerk beyond the limit.
    Jerk,
    /// The segment leaves the workspace, or a stop from the knot would.
    Workspace,
}

/// Longest segment between two knots (µs): 1 s. Longer would let a single knot pin the machine
/// to a path the host no longer watches.
pub const MAX_SEGMENT_US: u32 = 1_000_000;
