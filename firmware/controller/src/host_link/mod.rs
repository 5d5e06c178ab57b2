//! The host link's command handler: a decoded [`Request`] in, one [`DeviceMessage`] out, and
//! the calls into the rest of the controller it stands for.
//!
//! It runs in the link's low-priority task (priority 1, below the intake and the servo task),
//! never in the 2 kHz task: it reads the [`Status`] the servo task publishes, queues motion in
//! the [`MotionStream`] (shared with the intake task), and *posts* a [`ServoRequest`] that the
//! servo task applies at the start of its next sample ([`ServoLoop::request`]); that is all the
//! servo task does for the link (one lock, one `Option::take`).
//!
//! What each request does and when it is refused (a typed [`LinkError`], never silence; a
//! frame that does not decode gets [`DeviceBody::FrameRejected`]):
//!
//! | request | refused when | effect |
//! |---|---|---|
//! | Identify, Status, CalibrationId | never | answer (Identify: firmware, board, protocol, the calibration in force and the machine it defines) |
//! | Enable | not homed (encoders not absolute), fault latched (not a commanded one), stopping | re-engage where the machine is, drives on |
//! | Disable | never | controlled stop, drives off (category 1) |
//! | Home | moving or stopping, homing refuses | starts homing ([`Homing`]) |
//! | MoveTo | not running, moving, target outside / unplannable | plans the jerk-limited move |
//! | StreamKnots | not running, index, full, a bad knot | queues the knots (validated whole) |
//! | Stop | never | controlled stop, then hold (category 2) |
//! | ResetFault | stopping, permanent fault (settings, calibration, watchdog not started) | clears the fault, re-engages, drives on; never homed (homing failed, a fault before homing): back to `Unhomed`, drives off, Home again |
//! | Telemetry | never | sets the decimation (at least [`MIN_TELEMETRY_DECIMATION`]) |
//! | CalibrationBegin/Chunk/Commit | moving (a calibration switch's move included); a committed image still waiting for the switch (`SwitchPending`); what the [`CalibrationStore`] refuses (another machine's or an implausible image, with the parameter and its values) | writes the slot the servo does not use, commits; the servo switches at rest |
//!
//! After a stop, disable or reset the motion source is paused (it must not feed setpoints
//! planned before the stop, nor from a point the servo no longer holds); [`LinkHandler::poll`]
//! resumes it at the servo's setpoint once the servo loop runs again.
//!
//! [`ServoLoop::request`]: crate::servo_loop::ServoLoop::request
use link_protocol::{
    decode, encode, Board, CalibrationRefusal, Command, DeviceBody, DeviceMessage, FaultCode,
    FrameError, HomingState, Identity, LinkError, MachineId, ModeCode, Received, Request, Response,
    StatusReport, TelemetrySample, MIN_TELEMETRY_DECIMATION, PROTOCOL_VERSION,
};

use crate::calibration_slots::SlotError;
use crate::fault::Fault;
use crate::homing::HomingPhase;
use crate::motion_stream::{MotionStream, MoveRefusal, PushRefusal};
use crate::servo_loop::{Mode, ServoRequest};
use crate::status::Status;

#[cfg(any(test, feature = "host-doubles"))]
pub mod doubles;
mod refusal;

pub use refusal::{image_refusal, machine_id};

/// Homing would not start (the procedure says why in its own state and log).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HomingRefused;

/// Homing, as the link drives it (the procedure itself is `homing.rs`, the device side).
pub trait Homing {
    /// Starts the homing procedure.
    fn start(&mut self) -> Result<(), HomingRefused>;
    /// Where homing is.
    fn state(&self) -> HomingState;
    /// The settings say the encoders are absolute: the drives may engage unhomed.
    fn absolute_encoders(&self) -> bool;
}

/// The two-slot calibration store, as the link drives it: the upload goes to the inactive slot,
/// [`CalibrationStore::commit`] validates it and switches atomically; any refusal leaves the
/// image in force.
pub trait CalibrationStore {
    /// Erases the inactive slot for an image of `len` bytes.
    fn begin(&mut self, len: u32) -> Result<(), CalibrationRefusal>;
    /// Writes `data` at `offset` (the bytes received so far); returns the bytes received.
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<u32, CalibrationRefusal>;
    /// Validates the uploaded image (header, CRC, this machine) and switches to it; returns
    /// its id.
    fn commit(&mut self) -> Result<u32, CalibrationRefusal>;
    /// The id (CRC-32) of the image in force.
    fn active_id(&self) -> Option<u32>;
    /// The machine in force (`crate::calibration`): uploads must be images of it.
    fn machine(&self) -> MachineId;
}

/// The rest of the controller, as the link task reaches it (the firmware implements it over
/// the RTIC resources; the host tests over [`doubles`]).
pub trait Device {
    /// The homing procedure.
    type Homing: Homing;
    /// The calibration store.
    type Calibration: CalibrationStore;
    /// The board the firmware was built for.
    fn board(&self) -> Board;
    /// The status the servo task published last.
    fn status(&mut self) -> Status;
    /// Posts a request to the servo task (applied at its next sample; a newer one replaces
    /// an older one not yet applied).
    fn post(&mut self, request: ServoRequest);
    /// Runs `f` on the motion source (under the lock shared with the intake task).
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R;
    /// The homing procedure.
    fn homing(&mut self) -> &mut Self::Homing;
    /// The calibration store.
    fn calibration(&mut self) -> &mut Self::Calibration;
    /// Whether the link's motion stream is what the servo follows (`Settings::link_motion`);
    /// otherwise a built-in source (the QEMU tour) moves the machine, and the link refuses
    /// moves and streams it could not carry out.
    fn link_drives_motion(&self) -> bool;
}

/// The firmware's version, as [`Identity`] reports it.
pub const FIRMWARE_VERSION: [u16; 3] = [0, 1, 0];

/// The handler's own state between requests.
#[derive(Clone, Debug, Default)]
pub struct LinkHandler {
    /// Telemetry decimation (0: off).
    decimation: u16,
    /// Tick of the last telemetry sample sent.
    last_telemetry_tick: u32,
    /// Tick (of the published status) at which the last request was posted: the motion source
    /// stays paused until the servo loop has run a sample after it.
    posted_at_tick: Option<u32>,
}

/// The link's name of a fault.
pub fn fault_code(fault: Fault) -> FaultCode {
    match fault {
        Fault::Setpoint(_) => FaultCode::Setpoint,
        Fault::StopOutsideWorkspace => FaultCode::StopOutsideWorkspace,
        Fault::Underrun => FaultCode::Underrun,
        Fault::Servo(_) => FaultCode::Servo,
        Fault::Encoder(_) => FaultCode::Encoder,
        Fault::StopRefused(_) => FaultCode::StopRefused,
        Fault::DeadlineMissed => FaultCode::DeadlineMissed,
        Fault::Drive => FaultCode::Drive,
        Fault::StopCommanded | Fault::DisableCommanded => FaultCode::Commanded,
        Fault::Calibration(_) => FaultCode::Calibration,
        Fault::Settings(_) => FaultCode::Settings,
        Fault::Engage(_) => FaultCode::Engage,
        Fault::Watchdog(_) => FaultCode::Watchdog,
        Fault::Homing(_) => FaultCode::Homing,
    }
}

/// The link's name of a mode.
pub fn mode_code(mode: Mode) -> ModeCode {
    match mode {
        Mode::Running => ModeCode::Running,
        Mode::Stopping(_) => ModeCode::Stopping,
        Mode::Holding(_) => ModeCode::Holding,
        Mode::SafeState(_) => ModeCode::SafeState,
        Mode::Unhomed => ModeCode::Unhomed,
        Mode::Homing => ModeCode::Homing,
    }
}

/// Where homing is, as the link reports it, from the servo loop's mode and homing phase
/// ([`crate::servo_loop::ServoLoop::homing_phase`], published in the [`Status`]): homed once the
/// procedure reached home (whatever faults come later: the encoder zero stays set) or with
/// absolute encoders; failed when the procedure stopped on a fault (its own, or any fault latched
/// while it ran); not homed before it started.
pub fn homing_state(
    mode: Mode,
    phase: Option<HomingPhase>,
    absolute_encoders: bool,
) -> HomingState {
    match (mode, phase) {
        (Mode::Unhomed, _) => HomingState::NotHomed,
        (Mode::Homing, _) => HomingState::InProgress,
        (_, Some(HomingPhase::Done)) => HomingState::Homed,
        _ if absolute_encoders => HomingState::Homed,
        (Mode::SafeState(Fault::Homing(_)), _) | (_, Some(_)) => HomingState::Failed,
        (_, None) => HomingState::NotHomed,
    }
}

/// The link's name of the slot store's refusal (`calibration_slots`; an image's refusal with
/// its parameter and values: [`image_refusal`]).
pub fn calibration_refusal(e: SlotError) -> CalibrationRefusal {
    match e {
        SlotError::NoUpload => CalibrationRefusal::NotBegun,
        SlotError::BadLength { .. } => CalibrationRefusal::Length,
        SlotError::OutOfOrder { .. } => CalibrationRefusal::Offset,
        SlotError::TooMuchData | SlotError::Incomplete { .. } => CalibrationRefusal::Incomplete,
        SlotError::Flash(_) => CalibrationRefusal::Flash,
        SlotError::Image(e) => image_refusal(&e),
        SlotError::SwitchPending => CalibrationRefusal::SwitchPending,
    }
}

impl LinkHandler {
    /// A handler with telemetry off.
    pub const fn new() -> Self {
        LinkHandler {
            decimation: 0,
            last_telemetry_tick: 0,
            posted_at_tick: None,
        }
    }

    /// Decodes the frame the reader delivered, handles it, and encodes the one answer into
    /// `out` (at least [`link_protocol::MAX_FRAME_LEN`] bytes); returns its length.
    pub fn on_received(
        &mut self,
        received: Received<'_>,
        device: &mut impl Device,
        out: &mut [u8],
    ) -> usize {
        let body = match received {
            Received::TooLong => DeviceBody::FrameRejected(FrameError::TooLong),
            Received::Frame(frame) => match decode::<Request>(frame) {
                Ok(request) => self.handle(&request, device),
                Err(e) => DeviceBody::FrameRejected(e),
            },
        };
        encode_or_reject(&DeviceMessage::new(body), out)
    }

    /// Handles one decoded request.
    pub fn handle(&mut self, request: &Request, device: &mut impl Device) -> DeviceBody {
        let result = if request.version != PROTOCOL_VERSION {
            Err(LinkError::Version(request.version))
        } else {
            self.execute(&request.command, device)
        };
        DeviceBody::Reply {
            seq: request.seq,
            result,
        }
    }

    /// Pauses the motion source and posts `request` to the servo task.
    fn post(&mut self, request: ServoRequest, tick: u32, device: &mut impl Device) -> Response {
        device.with_stream(MotionStream::pause);
        device.post(request);
        self.posted_at_tick = Some(tick);
        Response::Done
    }

    fn execute(
        &mut self,
        command: &Command,
        device: &mut impl Device,
    ) -> Result<Response, LinkError> {
        let status = device.status();
        let mode = status.mode;
        match command {
            Command::Identify => Ok(Response::Identity(Identity {
                protocol_version: PROTOCOL_VERSION,
                firmware_version: FIRMWARE_VERSION,
                board: device.board(),
                calibration_id: device.calibration().active_id(),
                machine: device.calibration().machine(),
            })),
            Command::Status => Ok(Response::Status(self.report(&status, device))),
            Command::Enable => match mode {
                Mode::Running => Ok(Response::Done),
                Mode::Unhomed => Err(LinkError::NotHomed),
                Mode::Homing => Err(LinkError::Busy),
                Mode::Stopping(_) => Err(LinkError::Busy),
                Mode::Holding(f) | Mode::SafeState(f) if !commanded(f) => {
                    Err(LinkError::Faulted(fault_code(f)))
                }
                Mode::Holding(_) | Mode::SafeState(_) => self.reset(status.ticks, device),
            },
            Command::ResetFault => match mode {
                Mode::Running => Ok(Response::Done),
                Mode::Unhomed => Err(LinkError::NotHomed),
                Mode::Homing => Err(LinkError::Busy),
                Mode::Stopping(_) => Err(LinkError::Busy),
                Mode::Holding(f) | Mode::SafeState(f) if permanent(f) => {
                    Err(LinkError::Faulted(fault_code(f)))
                }
                // Never homed (homing failed, or a fault before it): the servo loop clears the
                // fault back to Unhomed, drives off, and Home may run again without a reboot.
                Mode::SafeState(_) if !homed(device) => {
                    Ok(self.post(ServoRequest::Reset, status.ticks, device))
                }
                Mode::Holding(_) | Mode::SafeState(_) => self.reset(status.ticks, device),
            },
            Command::Stop => Ok(self.post(ServoRequest::Stop, status.ticks, device)),
            Command::Disable => Ok(self.post(ServoRequest::Disable, status.ticks, device)),
            Command::Home => {
                // Whether homing may start with the drives on or off is the procedure's decision.
                if device.with_stream(|s| s.is_playing()) || matches!(mode, Mode::Stopping(_)) {
                    return Err(LinkError::Busy);
                }
                device
                    .homing()
                    .start()
                    .map(|()| Response::Done)
                    .map_err(|HomingRefused| LinkError::Homing)
            }
            Command::MoveTo { target_mm } => {
                link_is_source(device)?;
                running(mode)?;
                match device.with_stream(|s| s.move_to(*target_mm)) {
                    Ok(duration_s) => Ok(Response::MovePlanned { duration_s }),
                    Err(MoveRefusal::Busy) => Err(LinkError::Busy),
                    Err(MoveRefusal::Target) => Err(LinkError::Target),
                }
            }
            Command::StreamKnots { first_index, knots } => {
                link_is_source(device)?;
                running(mode)?;
                device.with_stream(|s| match s.push(*first_index, knots) {
                    Ok(()) => Ok(Response::StreamAccepted {
                        next_index: s.next_index(),
                        free: s.free() as u16,
                    }),
                    Err(PushRefusal::Knot(index, reason)) => {
                        Err(LinkError::Segment { index, reason })
                    }
                    Err(PushRefusal::Index(expected)) => Err(LinkError::StreamIndex(expected)),
                    Err(PushRefusal::Full(free)) => Err(LinkError::StreamFull(free)),
                    Err(PushRefusal::Busy) => Err(LinkError::Busy),
                })
            }
            Command::Telemetry { decimation } => {
                self.decimation = match *decimation {
                    0 => 0,
                    d => d.max(MIN_TELEMETRY_DECIMATION),
                };
                self.last_telemetry_tick = status.ticks;
                Ok(Response::TelemetryDecimation(self.decimation))
            }
            Command::CalibrationBegin { len } => {
                idle(&status, device)?;
                device
                    .calibration()
                    .begin(*len)
                    .map(|()| Response::Done)
                    .map_err(LinkError::Calibration)
            }
            Command::CalibrationChunk { offset, data } => {
                idle(&status, device)?;
                device
                    .calibration()
                    .write(*offset, data)
                    .map(Response::CalibrationReceived)
                    .map_err(LinkError::Calibration)
            }
            Command::CalibrationCommit => {
                idle(&status, device)?;
                device
                    .calibration()
                    .commit()
                    .map(|id| Response::CalibrationId(Some(id)))
                    .map_err(LinkError::Calibration)
            }
            Command::CalibrationId => Ok(Response::CalibrationId(device.calibration().active_id())),
        }
    }

    /// Re-engage (Enable, ResetFault): only homed (or with absolute encoders).
    fn reset(&mut self, tick: u32, device: &mut impl Device) -> Result<Response, LinkError> {
        if !homed(device) {
            return Err(LinkError::NotHomed);
        }
        Ok(self.post(ServoRequest::Reset, tick, device))
    }

    fn report(&self, s: &Status, device: &mut impl Device) -> StatusReport {
        let queued = device.with_stream(|m| m.queued() as u16);
        let moving = motion_under_way(s, device);
        StatusReport {
            ticks: s.ticks,
            mode: mode_code(s.mode),
            fault: s.mode.fault().map(fault_code),
            drives_enabled: s.drives_enabled,
            homing: device.homing().state(),
            setpoint_mm: s.setpoint_mm,
            encoder_rad: s.encoder_rad,
            max_following_error_rad: s.max_following_error_rad,
            overruns: s.overruns,
            worst_step_us: s.worst_step_us,
            setpoint_underruns: s.setpoint_underruns,
            stream_knots_queued: queued,
            moving,
            telemetry_decimation: self.decimation,
            calibration_pending: s.calibration_pending.map(|id| id.crc32),
        }
    }

    /// Called by the link task whenever it runs (each received frame and each telemetry
    /// tick): resumes a paused motion source at the servo's setpoint once the servo loop runs
    /// again, and returns a telemetry sample when one is due.
    pub fn poll(&mut self, device: &mut impl Device) -> Option<DeviceMessage> {
        let s = device.status();
        if let Some(t) = self.posted_at_tick {
            // The servo applies a request at its next sample: wait for one more to be published.
            if s.ticks.wrapping_sub(t) >= 2 {
                self.posted_at_tick = None;
            }
        }
        // Not during a calibration switch's blend: the source must hold where the blend ends.
        if s.mode == Mode::Running && self.posted_at_tick.is_none() && !s.blending {
            device.with_stream(|m| {
                if m.is_paused() {
                    m.hold(s.setpoint_mm);
                }
            });
        }
        if self.decimation == 0
            || s.ticks.wrapping_sub(self.last_telemetry_tick) < u32::from(self.decimation)
        {
            return None;
        }
        self.last_telemetry_tick = s.ticks;
        Some(DeviceMessage::new(DeviceBody::Telemetry(telemetry_sample(
            &s,
        ))))
    }

    /// The telemetry decimation in force (0: off).
    pub fn decimation(&self) -> u16 {
        self.decimation
    }
}

/// A telemetry sample of the published status. The following error is the largest of the two
/// axes' `|reference - encoder|` of the last sample.
pub fn telemetry_sample(s: &Status) -> TelemetrySample {
    let error = [0, 1].map(|k| (s.reference_rad[k] - s.encoder_rad[k]).abs());
    TelemetrySample {
        tick: s.ticks,
        setpoint_mm: s.setpoint_mm,
        reference_rad: s.reference_rad,
        encoder_rad: s.encoder_rad,
        torque_nm: s.torque_nm,
        following_error_rad: error[0].max(error[1]),
        mode: mode_code(s.mode),
        fault: s.mode.fault().map(fault_code),
    }
}

/// Encodes `message`; a message too big for a frame (none is: the protocol's tests check the
/// largest) would be answered by [`FrameError::Overflow`] instead of silence.
pub fn encode_or_reject(message: &DeviceMessage, out: &mut [u8]) -> usize {
    encode(message, out)
        .or_else(|e| encode(&DeviceMessage::new(DeviceBody::FrameRejected(e)), out))
        .unwrap_or(0)
}

fn commanded(f: Fault) -> bool {
    matches!(f, Fault::StopCommanded | Fault::DisableCommanded)
}

/// The encoder zero is known: homing reached home, or the encoders are absolute.
fn homed(device: &mut impl Device) -> bool {
    let homing = device.homing();
    homing.state() == HomingState::Homed || homing.absolute_encoders()
}

/// Faults only a reboot clears (the servo loop refuses to reset them).
fn permanent(f: Fault) -> bool {
    f.needs_reboot()
}

fn running(mode: Mode) -> Result<(), LinkError> {
    match mode {
        Mode::Running => Ok(()),
        Mode::Unhomed => Err(LinkError::NotHomed),
        Mode::Homing => Err(LinkError::Busy),
        Mode::SafeState(Fault::DisableCommanded) => Err(LinkError::NotEnabled),
        Mode::Stopping(_) => Err(LinkError::Busy),
        Mode::Holding(f) | Mode::SafeState(f) => Err(LinkError::Faulted(fault_code(f))),
    }
}

/// Moves and streams need the link to be the motion source; with a built-in source they would
/// be accepted and never run.
fn link_is_source(device: &impl Device) -> Result<(), LinkError> {
    if device.link_drives_motion() {
        Ok(())
    } else {
        Err(LinkError::Unsupported)
    }
}

/// The machine's setpoint still changes: a stop is under way, or, with the link as the motion
/// source, a move or stream plays (or starved) or the source already holds but the servo loop
/// has not yet reached its hold point (the source runs up to
/// [`QUEUE_SLOTS`](crate::setpoints::QUEUE_SLOTS) samples, 31.5 ms, ahead of the servo through
/// the setpoint queue; "not moving" before then let a host read a setpoint short of the end).
/// In Running, a source still paused by the last stop or re-engage counts as moving too: it
/// refuses knots as busy until the link resumes it at the servo's setpoint (a sample or two
/// later, [`LinkHandler::poll`]), so "not moving" always means a stream may start.
/// With a built-in source the link cannot see its plan: the last sample's setpoint changed.
fn motion_under_way(s: &Status, device: &mut impl Device) -> bool {
    if matches!(s.mode, Mode::Stopping(_)) || s.blending {
        return true;
    }
    if !device.link_drives_motion() {
        return s.mode == Mode::Running && s.setpoint_moved;
    }
    let (playing, paused, hold) =
        device.with_stream(|m| (m.is_playing(), m.is_paused(), m.hold_point_mm()));
    playing || (s.mode == Mode::Running && (paused || hold.is_some_and(|p| p != s.setpoint_mm)))
}

/// The calibration store is written only while nothing moves.
fn idle(s: &Status, device: &mut impl Device) -> Result<(), LinkError> {
    if motion_under_way(s, device) {
        return Err(LinkError::Calibration(CalibrationRefusal::Busy));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
