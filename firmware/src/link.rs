//! The host link on the board: the byte port (a UART), and the handler's view of the app's
//! resources ([`AppDevice`]): the status, the servo task's requests (stop, disable, reset,
//! home), the motion stream, the calibration slots.
//!
//! The app's `link_rx` task (priority 1, the UART's receive interrupt) drains the port into a
//! [`FrameReader`], hands each frame to the [`LinkHandler`] and writes the one reply, and sends
//! due telemetry. It never runs in the servo task: what the servo task does for the link is
//! apply a posted [`ServoRequest`] (one lock, one `take`) and switch to a newly committed
//! calibration at rest.
//!
//! * **Homing** ([`Homing`] for [`AppDevice`]): `Home` posts [`ServoRequest::Home`]; the servo
//!   task calls `ServoLoop::start_homing` at its next sample and enables the drives if it
//!   started. The state reported is [`homing_state`] of the published mode and homing phase.
//! * **Calibration** ([`CalibrationStore`] for [`AppDevice`]): begin, chunks and commit go to the
//!   shared `SlotStore` (the inactive slot; flash writes here, at priority 1, never in the
//!   servo task); after a commit the new image is parsed ([`crate::calibration::committed`]) and
//!   handed to the servo task through `new_calibration`, as the QEMU upload task does. The id
//!   reported is that of the image the servo uses (the published `Status::calibration_id`), so
//!   it changes when the servo has switched, not before.
use controller::calibration_slots::{CalibrationId, SlotError, SlotStore};
use controller::host_link::{
    calibration_refusal, encode_or_reject, homing_state, CalibrationStore, Device, Homing,
    HomingRefused, LinkHandler,
};
use controller::motion_stream::MotionStream;
use controller::servo_loop::{Mode, ServoRequest, SwitchOutcome};
use controller::status::Status;
use kinematics_core::Calibration;
use link_protocol::{
    Board, CalibrationRefusal, DeviceMessage, FrameReader, HomingState, MachineId, MAX_FRAME_LEN,
};
use rtic::Mutex;

use crate::calibration::RegionFlash;

/// A byte port to the host: non-blocking read, bounded write.
pub trait LinkPort {
    /// The next received byte, if one is waiting.
    fn read_byte(&mut self) -> Option<u8>;
    /// Writes `bytes`; gives up (and counts) if the port stays full too long, so that a host
    /// that stops reading cannot stall the link task forever.
    fn write(&mut self, bytes: &[u8]);
}

/// What the link task owns.
pub struct LinkState<P: LinkPort> {
    /// The port.
    pub port: P,
    /// Bytes to frames.
    pub reader: FrameReader,
    /// The command handler.
    pub handler: LinkHandler,
    /// What the handler is told of the controller besides its status.
    pub facts: LinkFacts,
}

/// What the link reports of the controller besides its status, fixed at boot: every frame's
/// [`AppDevice`] is built with them.
#[derive(Clone, Copy, Debug)]
pub struct LinkFacts {
    /// The settings say the encoders are absolute (the drives may engage unhomed).
    pub absolute_encoders: bool,
    /// The settings make the link's stream the motion source (`Settings::link_motion`).
    pub link_motion: bool,
    /// The board the firmware was built for, as `Identify` reports it.
    pub board: Board,
    /// The machine in force (the record of the image in force at boot), as `Identify`
    /// reports it.
    pub machine: MachineId,
}

impl<P: LinkPort> LinkState<P> {
    /// Drains the port: every complete frame is handled and answered.
    pub fn serve(&mut self, device: &mut impl DeviceResources) {
        while let Some(byte) = self.port.read_byte() {
            if let Some(received) = self.reader.push(byte) {
                let mut out = [0u8; MAX_FRAME_LEN];
                let mut dev = AppDevice::new(device, self.facts);
                let n = self.handler.on_received(received, &mut dev, &mut out);
                self.port.write(&out[..n]);
            }
        }
    }

    /// Resumes a paused source when the servo runs again, sends a telemetry sample if due, and
    /// withdraws a committed image the servo refused to switch to (its slot erased: the image in
    /// use stays in force, at the next boot too, and the next upload may go there).
    pub fn poll(&mut self, device: &mut impl DeviceResources) {
        let status = device.status();
        if let Some(SwitchOutcome::Refused(refused, why)) = status.last_switch {
            let in_use = status.calibration_id;
            let withdrawn = device.with_slots(|s| {
                let was = s.active_id() == Some(refused);
                s.withdraw(refused, in_use).map(|()| was)
            });
            if let Ok(true) = withdrawn {
                defmt::warn!(
                    "calibration {} refused at the switch ({}): withdrawn, {} stays in force",
                    refused,
                    why,
                    in_use
                );
            }
        }
        let mut dev = AppDevice::new(device, self.facts);
        if let Some(message) = self.handler.poll(&mut dev) {
            self.send(&message);
        }
    }

    fn send(&mut self, message: &DeviceMessage) {
        let mut out = [0u8; MAX_FRAME_LEN];
        let n = encode_or_reject(message, &mut out);
        self.port.write(&out[..n]);
    }
}

/// The app's shared resources the handler reaches, behind RTIC's locks.
pub trait DeviceResources {
    /// The published status.
    fn status(&mut self) -> Status;
    /// Posts a request to the servo task.
    fn post(&mut self, request: ServoRequest);
    /// Runs `f` on the motion stream, locked against the intake task.
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R;
    /// Runs `f` on the calibration slots.
    fn with_slots<R>(&mut self, f: impl FnOnce(&mut SlotStore<RegionFlash>) -> R) -> R;
    /// Records an upload's outcome in the status and hands a committed calibration to the servo
    /// task (it switches at rest).
    fn uploaded(
        &mut self,
        result: Result<CalibrationId, SlotError>,
        new: Option<(Calibration<'static>, CalibrationId)>,
    );
}

/// [`DeviceResources`] over the app's RTIC mutexes.
pub struct Locks<S, Q, M, C, N> {
    /// The status.
    pub status: S,
    /// The posted request.
    pub request: Q,
    /// The motion stream.
    pub stream: M,
    /// The calibration slots.
    pub slots: C,
    /// The calibration for the servo task to switch to.
    pub new_calibration: N,
}

impl<S, Q, M, C, N> DeviceResources for Locks<S, Q, M, C, N>
where
    S: Mutex<T = Status>,
    Q: Mutex<T = Option<ServoRequest>>,
    M: Mutex<T = MotionStream>,
    C: Mutex<T = SlotStore<RegionFlash>>,
    N: Mutex<T = Option<(Calibration<'static>, CalibrationId)>>,
{
    fn status(&mut self) -> Status {
        self.status.lock(|s| *s)
    }
    fn post(&mut self, request: ServoRequest) {
        self.request.lock(|r| *r = Some(request));
    }
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R {
        self.stream.lock(f)
    }
    fn with_slots<R>(&mut self, f: impl FnOnce(&mut SlotStore<RegionFlash>) -> R) -> R {
        self.slots.lock(f)
    }
    fn uploaded(
        &mut self,
        result: Result<CalibrationId, SlotError>,
        new: Option<(Calibration<'static>, CalibrationId)>,
    ) {
        if new.is_some() {
            self.new_calibration.lock(|n| *n = new);
        }
        self.status.lock(|s| s.last_upload = Some(result));
    }
}

/// The controller as the handler sees it, for one frame: the app's resources, and the status
/// read last (what [`Homing::state`] reports from).
pub struct AppDevice<'a, D> {
    res: &'a mut D,
    facts: LinkFacts,
    status: Status,
}

impl<'a, D: DeviceResources> AppDevice<'a, D> {
    /// Reads the status once.
    pub fn new(res: &'a mut D, facts: LinkFacts) -> Self {
        let status = res.status();
        AppDevice { res, facts, status }
    }
}

impl<D: DeviceResources> Device for AppDevice<'_, D> {
    type Homing = Self;
    type Calibration = Self;
    fn board(&self) -> Board {
        self.facts.board
    }
    fn status(&mut self) -> Status {
        self.status = self.res.status();
        self.status
    }
    fn post(&mut self, request: ServoRequest) {
        self.res.post(request)
    }
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R {
        self.res.with_stream(f)
    }
    fn homing(&mut self) -> &mut Self {
        self
    }
    fn calibration(&mut self) -> &mut Self {
        self
    }
    fn link_drives_motion(&self) -> bool {
        self.facts.link_motion
    }
}

/// Homing is the servo task's (`controller::homing` through `ServoLoop::step_homing`); the link
/// asks it to start and reads where it is.
impl<D: DeviceResources> Homing for AppDevice<'_, D> {
    /// From `Unhomed`: posts the request (the servo task starts at its next sample; a plan the
    /// servo loop refuses shows as `Failed`). Under way or done: nothing to do. Failed, or a
    /// fault latched before homing: refused until ResetFault has taken the servo loop back to
    /// `Unhomed` (drives off); then Home starts again, no reboot needed.
    fn start(&mut self) -> Result<(), HomingRefused> {
        match (self.status.mode, self.state()) {
            (Mode::Unhomed, _) => {
                self.res.post(ServoRequest::Home);
                Ok(())
            }
            (_, HomingState::InProgress | HomingState::Homed) => Ok(()),
            _ => Err(HomingRefused),
        }
    }
    fn state(&self) -> HomingState {
        homing_state(
            self.status.mode,
            self.status.homing,
            self.facts.absolute_encoders,
        )
    }
    fn absolute_encoders(&self) -> bool {
        self.facts.absolute_encoders
    }
}

/// The two calibration slots (`controller::calibration_slots`) as the link drives them.
impl<D: DeviceResources> CalibrationStore for AppDevice<'_, D> {
    fn begin(&mut self, len: u32) -> Result<(), CalibrationRefusal> {
        self.res
            .with_slots(|s| s.begin(len as usize, self.status.calibration_id))
            .map_err(calibration_refusal)
    }
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<u32, CalibrationRefusal> {
        self.res
            .with_slots(|s| s.write(offset as usize, data))
            .map_err(calibration_refusal)
    }
    fn commit(&mut self) -> Result<u32, CalibrationRefusal> {
        let result = self.res.with_slots(SlotStore::commit);
        match result {
            Ok(id) => defmt::info!("calibration upload committed over the link: {}", id),
            Err(e) => defmt::error!(
                "calibration upload refused: {} (the image in force stays)",
                e
            ),
        }
        let new = result.ok().and_then(crate::calibration::committed);
        let parsed = new.is_some();
        self.res.uploaded(result, new);
        match result {
            Ok(id) if parsed => Ok(id.crc32),
            Ok(_) => Err(CalibrationRefusal::Invalid),
            Err(e) => Err(calibration_refusal(e)),
        }
    }
    /// The image the servo uses (it switches at rest after a commit).
    fn active_id(&self) -> Option<u32> {
        self.status.calibration_id.map(|id| id.crc32)
    }
    /// The machine in force: the record of the image in force at boot (the slot store's).
    fn machine(&self) -> MachineId {
        self.facts.machine
    }
}
