//! Host-side stand-ins for what the handler drives, so that the handler, the motion stream and
//! the servo loop can be run together on the host (tests, and the `link_fuzz` bench).
//!
//! * [`Rig`]: the firmware's three tasks in one struct: the real [`ServoLoop`] with its setpoint
//!   queue, the real [`MotionStream`] as the intake's source, the posted [`ServoRequest`], the
//!   published [`Status`], and the machine ([`JointPlant`], the servo loop's own test plant).
//! * [`HomingDouble`]: homes at once (or refuses); the real procedure is `homing.rs`.
//! * [`StoreDouble`]: a RAM calibration store with the real image check
//!   ([`image_id`](crate::calibration::image_id), the CRC-32C id the real store reports); the real one is the two flash
//!   slots of `calibration_slots.rs`.
use heapless::spsc::Queue;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::Calibration;
use link_protocol::{Board, CalibrationRefusal, HomingState, MachineId, MAX_CALIBRATION_IMAGE_LEN};

use super::{CalibrationStore, Device, Homing, HomingRefused};
use crate::calibration::CalibrationState;
use crate::motion_stream::{MotionStream, StreamLimits};
use crate::servo_loop::{ServoLoop, ServoRequest};
use crate::setpoints::{self, QUEUE_SLOTS};
use crate::settings::Settings;
use crate::status::Status;

/// Two direct-drive joints with viscous and Coulomb friction (rotor plus reflected link
/// inertia of the five-bar at the home pose), integrated in 10 sub-steps per sample; the
/// encoders read whole counts of 2²² per revolution. Torque acts only while enabled.
#[derive(Clone, Copy, Debug)]
pub struct JointPlant {
    /// Joint angles (rad).
    pub angle_rad: [f32; 2],
    /// Joint speeds (rad/s).
    pub velocity_rad_s: [f32; 2],
    /// Torque acting (N·m).
    pub torque_nm: [f32; 2],
    /// Drives enabled.
    pub enabled: bool,
}

impl JointPlant {
    const DT_S: f32 = crate::SAMPLE_PERIOD_S;
    const COUNT_RAD: f32 = 2.0 * core::f32::consts::PI / (1u32 << 22) as f32;

    /// One sample under `torque_nm`.
    pub fn advance(&mut self) {
        let h = Self::DT_S / 10.0;
        for (k, inertia) in [2.2e-3f32 + 5.4e-3, 1.8e-3 + 5.4e-3]
            .into_iter()
            .enumerate()
        {
            let tau = if self.enabled { self.torque_nm[k] } else { 0.0 };
            for _ in 0..10 {
                let w = self.velocity_rad_s[k];
                let friction = 0.01 * w + 0.03 * w / (w.abs() + 1e-3);
                self.velocity_rad_s[k] += (tau - friction) / inertia * h;
                self.angle_rad[k] += self.velocity_rad_s[k] * h;
            }
        }
    }

    /// The encoder reading (whole counts).
    pub fn encoder_rad(&self) -> [f32; 2] {
        self.angle_rad
            .map(|a| libm::roundf(a / Self::COUNT_RAD) * Self::COUNT_RAD)
    }
}

/// Homing that completes at once (the double).
#[derive(Clone, Copy, Debug)]
pub struct HomingDouble {
    /// Current state.
    pub state: HomingState,
    /// Refuse to start.
    pub refuse: bool,
    /// Absolute encoders.
    pub absolute: bool,
}

impl Homing for HomingDouble {
    fn start(&mut self) -> Result<(), HomingRefused> {
        if self.refuse {
            self.state = HomingState::Failed;
            return Err(HomingRefused);
        }
        self.state = HomingState::Homed;
        Ok(())
    }
    fn state(&self) -> HomingState {
        self.state
    }
    fn absolute_encoders(&self) -> bool {
        self.absolute
    }
}

/// Bytes the RAM store holds.
pub const STORE_LEN: usize = 8192;

/// A calibration store in RAM: the inactive slot, and the id of the image in force.
#[derive(Clone, Debug)]
pub struct StoreDouble {
    /// What a committed image must be (`None`: parsing is enough); its machine is the one
    /// `Identify` reports (the paper's without a check).
    pub check: Option<crate::calibration::ImageCheck>,
    inactive: heapless::Vec<u8, STORE_LEN>,
    expected_len: Option<u32>,
    active_id: Option<u32>,
    /// Commits that switched the image.
    pub switches: u32,
}

impl StoreDouble {
    /// A store whose image in force has `active_id`.
    pub fn new(active_id: Option<u32>) -> Self {
        StoreDouble {
            check: None,
            inactive: heapless::Vec::new(),
            expected_len: None,
            active_id,
            switches: 0,
        }
    }
}

impl CalibrationStore for StoreDouble {
    fn begin(&mut self, len: u32) -> Result<(), CalibrationRefusal> {
        if len == 0 || len > MAX_CALIBRATION_IMAGE_LEN || len as usize > STORE_LEN {
            return Err(CalibrationRefusal::Length);
        }
        self.inactive.clear();
        self.expected_len = Some(len);
        Ok(())
    }
    fn write(&mut self, offset: u32, data: &[u8]) -> Result<u32, CalibrationRefusal> {
        let len = self.expected_len.ok_or(CalibrationRefusal::NotBegun)?;
        if offset as usize != self.inactive.len() {
            return Err(CalibrationRefusal::Offset);
        }
        if offset as usize + data.len() > len as usize {
            return Err(CalibrationRefusal::Incomplete);
        }
        self.inactive
            .extend_from_slice(data)
            .map_err(|_| CalibrationRefusal::Length)?;
        Ok(self.inactive.len() as u32)
    }
    fn commit(&mut self) -> Result<u32, CalibrationRefusal> {
        let len = self
            .expected_len
            .take()
            .ok_or(CalibrationRefusal::NotBegun)?;
        if self.inactive.len() != len as usize {
            return Err(CalibrationRefusal::Incomplete);
        }
        if let Some(check) = &self.check {
            crate::calibration::validate_image(
                &self.inactive,
                check,
                crate::calibration::Judged::AtCommit,
            )
            .map_err(|e| super::image_refusal(&e))?;
        }
        let id = crate::calibration::image_id(&self.inactive).ok_or(CalibrationRefusal::Invalid)?;
        self.active_id = Some(id);
        self.switches += 1;
        Ok(id)
    }
    fn active_id(&self) -> Option<u32> {
        self.active_id
    }
    fn machine(&self) -> MachineId {
        let record = self
            .check
            .map_or_else(kinematics_core::machine::MachineRecord::paper, |c| {
                c.machine
            });
        super::machine_id(&record)
    }
}

/// The firmware's tasks on the host (see the module doc).
pub struct Rig<'a> {
    /// The servo loop.
    pub servo: ServoLoop<'a>,
    queue: Queue<MotionSetpoint<f32>, QUEUE_SLOTS>,
    /// The link's motion source (the intake's).
    pub stream: MotionStream,
    /// The request posted and not yet applied.
    pub request: Option<ServoRequest>,
    /// Requests posted so far.
    pub posted: u32,
    /// The status published after the last sample.
    pub status: Status,
    /// The machine.
    pub plant: JointPlant,
    /// Homing.
    pub homing: HomingDouble,
    /// Calibration store.
    pub store: StoreDouble,
    /// The link's stream is the motion source (`Settings::link_motion`); true unless a test
    /// sets it.
    pub link_motion: bool,
}

impl<'a> Rig<'a> {
    /// Boots the servo loop with the machine at `joints_rad` and the stream holding where it
    /// engaged; `active_id` is the id of the image `calibration` came from.
    pub fn boot(
        settings: &'a Settings,
        calibration: Calibration<'a>,
        joints_rad: [f32; 2],
        active_id: Option<u32>,
    ) -> Self {
        let servo = ServoLoop::boot(settings, calibration, CalibrationState::Valid, joints_rad);
        let limits = StreamLimits {
            task: settings.stream_limits(),
            knots: settings.knot_limits(),
            stop: settings.stop.limits,
            workspace: servo.calibration().workspace(),
        };
        let stream = MotionStream::new(limits, servo.setpoint_mm());
        let status = Status::at_boot(CalibrationState::Valid, &servo, joints_rad);
        Rig {
            servo,
            queue: Queue::new(),
            stream,
            request: None,
            posted: 0,
            status,
            plant: JointPlant {
                angle_rad: joints_rad,
                velocity_rad_s: [0.0; 2],
                torque_nm: [0.0; 2],
                enabled: true,
            },
            homing: HomingDouble {
                state: HomingState::Homed,
                refuse: false,
                absolute: false,
            },
            store: StoreDouble::new(active_id),
            link_motion: true,
        }
    }

    /// One servo sample as the firmware runs it: the posted request, the step, the intake's
    /// refill, the machine, the status.
    pub fn step(&mut self) {
        let (mut tx, mut rx) = self.queue.split();
        let encoder_rad = self.plant.encoder_rad();
        if let Some(r) = self.request.take() {
            if let Ok(true) = self.servo.request(r, &mut rx, encoder_rad) {
                self.plant.enabled = true;
            }
        }
        let sample = self.servo.step(&mut rx, encoder_rad);
        if sample.refill {
            setpoints::refill(&mut tx, &mut self.stream);
        }
        if sample.torque_off {
            self.plant.enabled = false;
        }
        self.plant.torque_nm = sample.torque_nm;
        self.plant.advance();
        let stop_mm = self.servo.stop_profile().map_or(0.0, |p| p.distance_mm());
        self.status
            .record(&sample, self.servo.mode(), self.servo.deadline(), stop_mm);
    }
}

impl Device for Rig<'_> {
    type Homing = HomingDouble;
    type Calibration = StoreDouble;
    fn board(&self) -> Board {
        Board::Qemu
    }
    fn status(&mut self) -> Status {
        self.status
    }
    fn post(&mut self, request: ServoRequest) {
        self.request = Some(request);
        self.posted += 1;
    }
    fn with_stream<R>(&mut self, f: impl FnOnce(&mut MotionStream) -> R) -> R {
        f(&mut self.stream)
    }
    fn homing(&mut self) -> &mut HomingDouble {
        &mut self.homing
    }
    fn calibration(&mut self) -> &mut StoreDouble {
        &mut self.store
    }
    fn link_drives_motion(&self) -> bool {
        self.link_motion
    }
}

/// xorshift64*: a fuzz driver needs speed and reproducibility, not statistical quality.
#[derive(Clone, Copy, Debug)]
pub struct FuzzRng(pub u64);

impl FuzzRng {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Below `n` (`n` > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    /// An absurd number: NaN, ±infinity, ±f32::MAX, subnormals, -0, huge or tiny powers of ten,
    /// or an arbitrary bit pattern.
    pub fn absurd_f32(&mut self) -> f32 {
        const SPECIAL: [f32; 10] = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            -0.0,
            1e30,
            -1e19,
            1e-40,
        ];
        match self.below(3) {
            0 => SPECIAL[self.below(SPECIAL.len())],
            1 => f32::from_bits(self.next_u64() as u32),
            _ => (self.next_u64() % 2_000_000) as f32 * 0.001 - 1000.0,
        }
    }
}

/// A well-formed command (it decodes, its CRC is right) whose payload is absurd: targets,
/// knots, decimations, lengths, offsets and chunks anywhere in their types' ranges, NaN and
/// infinities included; and the commands without payload. What the link must refuse (or do,
/// for the commands that may be obeyed) without a fault the payload did not deserve.
pub fn absurd_command(rng: &mut FuzzRng) -> link_protocol::Command {
    use link_protocol::{Command, Knot, CALIBRATION_CHUNK_LEN, MAX_KNOTS_PER_FRAME};
    let knot = |rng: &mut FuzzRng| Knot {
        t_us: match rng.below(3) {
            0 => 0,
            1 => u32::MAX,
            _ => rng.next_u64() as u32,
        },
        position_mm: [rng.absurd_f32(), rng.absurd_f32()],
        velocity_mm_s: [rng.absurd_f32(), rng.absurd_f32()],
    };
    match rng.below(12) {
        0 => Command::MoveTo {
            target_mm: [rng.absurd_f32(), rng.absurd_f32()],
        },
        1 | 2 => {
            let mut knots = heapless::Vec::new();
            for _ in 0..1 + rng.below(MAX_KNOTS_PER_FRAME) {
                let _ = knots.push(knot(rng));
            }
            Command::StreamKnots {
                first_index: match rng.below(3) {
                    0 => 0,
                    1 => u32::MAX,
                    _ => rng.next_u64() as u32,
                },
                knots,
            }
        }
        3 => Command::Telemetry {
            decimation: [0, 1, u16::MAX, rng.next_u64() as u16][rng.below(4)],
        },
        4 => Command::CalibrationBegin {
            len: [
                0,
                1,
                u32::MAX,
                MAX_CALIBRATION_IMAGE_LEN + 1,
                rng.next_u64() as u32,
            ][rng.below(5)],
        },
        5 => Command::CalibrationChunk {
            offset: [0, u32::MAX, rng.next_u64() as u32][rng.below(3)],
            data: heapless::Vec::from_iter(
                (0..rng.below(CALIBRATION_CHUNK_LEN + 1)).map(|_| rng.next_u64() as u8),
            ),
        },
        6 => Command::CalibrationCommit,
        7 => Command::Identify,
        8 => Command::Status,
        9 => Command::CalibrationId,
        10 => Command::Enable,
        _ => Command::ResetFault,
    }
}
