//! The host link on the board: the byte port (a UART), the handler's view of the app's
//! resources ([`AppDevice`]), and the stand-ins for homing and the calibration store until the
//! device side (`homing.rs`, `calibration_slots.rs`) is wired.
//!
//! The app's `link_rx` task (priority 1, the UART's receive interrupt) drains the port into a
//! [`FrameReader`], hands each frame to the [`LinkHandler`] and writes the one reply; the
//! `telemetry` task (priority 1) polls the handler for due telemetry samples. Neither runs in
//! the servo task: what the servo task does for the link is apply a posted
//! [`ServoRequest`] (one lock, one `take`).
use controller::calibration::image_id;
use controller::host_link::{encode_or_reject, CalibrationStore, Device, Homing, HomingRefused, LinkHandler};
use controller::motion_stream::MotionStream;
use controller::servo_loop::ServoRequest;
use controller::status::Status;
use link_protocol::{Board, CalibrationRefusal, DeviceMessage, FrameReader, HomingState, MAX_FRAME_LEN};
use rtic::Mutex;

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
    /// Homing (stand-in, see [`PowerOnHoming`]).
    pub homing: PowerOnHoming,
    /// The calibration store (stand-in, see [`ReadOnlyStore`]).
    pub store: ReadOnlyStore,
}

impl<P: LinkPort> LinkState<P> {
    /// Drains the port: every complete frame is handled and answered.
    pub fn serve(&mut self, device: &mut impl DeviceResources) {
        while let Some(byte) = self.port.read_byte() {
            if let Some(received) = self.reader.push(byte) {
                let mut out = [0u8; MAX_FRAME_LEN];
                let mut dev = AppDevice { res: device, homing: &mut self.homing, store: &mut self.store };
                let n = self.handler.on_received(received, &mut dev, &mut out);
                self.port.write(&out[..n]);
            }
        }
    }

    /// Resumes a paused source when the servo runs again, and sends a telemetry sample if due.
    pub fn poll(&mut self, device: &mut impl DeviceResources) {
        let mut dev = AppDevice { res: device, homing: &mut self.homing, store: &mut self.store };
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
}

/// [`DeviceResources`] over three RTIC mutexes.
pub struct Locks<S, Q, M> {
    /// The status.
    pub status: S,
    /// The posted request.
    pub request: Q,
    /// The motion stream.
    pub stream: M,
}

impl<S, Q, M> DeviceResources for Locks<S, Q, M>
where
    S: Mutex<T = Status>,
    Q: Mutex<T = Option<ServoRequest>>,
    M: Mutex<T = MotionStream>,
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
}

struct AppDevice<'a, D> {
    res: &'a mut D,
    homing: &'a mut PowerOnHoming,
    store: &'a mut ReadOnlyStore,
}

impl<D: DeviceResources> Device for AppDevice<'_, D> {
    type Homing = PowerOnHoming;
    type Calibration = ReadOnlyStore;
    fn board(&self) -> Board {
        crate::board::BOARD_ID
    }
    fn status(&mut self) -> Status {
        self.res.status()
    }
    fn post(&mut self, request: ServoRequest) {
        self.res.post(request)
    }
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R {
        self.res.with_stream(f)
    }
    fn homing(&mut self) -> &mut PowerOnHoming {
        self.homing
    }
    fn calibration(&mut self) -> &mut ReadOnlyStore {
        self.store
    }
}

/// Stand-in until `homing.rs` is wired: the encoder zero is the one the board has at power-on,
/// which is what the firmware has always engaged on (the QEMU plant's counters start at the
/// true joint angles; on the real board this is only right with absolute encoders). It reports
/// `Homed` and `Home` succeeds without moving.
#[derive(Clone, Copy, Debug, Default)]
pub struct PowerOnHoming;

impl Homing for PowerOnHoming {
    fn start(&mut self) -> Result<(), HomingRefused> {
        Ok(())
    }
    fn state(&self) -> HomingState {
        HomingState::Homed
    }
    fn absolute_encoders(&self) -> bool {
        true
    }
}

/// Stand-in until `calibration_slots.rs` is wired: reports the id of the image in the
/// calibration region and refuses uploads with [`CalibrationRefusal::Flash`] (no flash
/// writes on this branch), so the image in force always stays.
#[derive(Clone, Copy, Debug)]
pub struct ReadOnlyStore {
    active_id: Option<u32>,
}

impl ReadOnlyStore {
    /// The store over the calibration region.
    pub fn new(region: &[u8]) -> Self {
        ReadOnlyStore { active_id: image_id(region) }
    }
}

impl CalibrationStore for ReadOnlyStore {
    fn begin(&mut self, _len: u32) -> Result<(), CalibrationRefusal> {
        Err(CalibrationRefusal::Flash)
    }
    fn write(&mut self, _offset: u32, _data: &[u8]) -> Result<u32, CalibrationRefusal> {
        Err(CalibrationRefusal::NotBegun)
    }
    fn commit(&mut self) -> Result<u32, CalibrationRefusal> {
        Err(CalibrationRefusal::NotBegun)
    }
    fn active_id(&self) -> Option<u32> {
        self.active_id
    }
}
