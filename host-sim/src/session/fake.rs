//! An in-process rig for tests: the simulated plant behind a controller that commands exactly
//! as the firmware does (`Calibration::command_rad`, f32, through the calibration in force),
//! settles the plant quasi-statically (each motor from the side its last move came from) and
//! emits servo samples of a settling axis (an exponential approach, the plant's encoder
//! quantisation), and the plant's instrument. Faults can be planted: a link that drops after
//! some moves, a servo that hunts, points the instrument does not see, a reading that is
//! absurd. What the session does with a real controller, without QEMU.

use super::{
    settled_at, Moved, PointRequest, Reading, Rig, ServoSample, SessionError, SettleCriterion,
    Settled,
};
use crate::calib::machine::PlantMachine;
use crate::link::ClientError;
use kinematics_core::{wrap_angle_rad, Calibration, CorrectionGrid, FiveBar};

/// Faults to plant in a [`FakeRig`].
#[derive(Clone, Debug, Default)]
pub struct FakeFaults {
    /// The link drops at this move (0-based count of moves).
    pub drop_at_move: Option<usize>,
    /// The servo hunts ±5 µrad and never settles.
    pub hunting: bool,
    /// Rows (0-based) the instrument does not see.
    pub missing: Vec<usize>,
    /// A row whose reading is this instead (mm).
    pub absurd: Option<(usize, [f64; 2])>,
    /// The controller reports itself not homed.
    pub unhomed: bool,
}

/// The fake rig (module doc).
pub struct FakeRig {
    pub machine: PlantMachine,
    /// The calibration in force: its model and, optionally, a grid image.
    pub model: FiveBar<f64>,
    pub image: Option<Vec<u8>>,
    pub min_transmission: f64,
    pub faults: FakeFaults,
    /// Moves made.
    pub moves: usize,
    t_s: f64,
    command: Option<[f64; 2]>,
    encoder: [f64; 2],
    tool_mm: [f64; 2],
}

impl FakeRig {
    /// A rig around `machine` commanding through `model` (and `image`, if any).
    pub fn new(
        machine: PlantMachine,
        model: FiveBar<f64>,
        image: Option<Vec<u8>>,
        min_transmission: f64,
    ) -> Self {
        FakeRig {
            machine,
            model,
            image,
            min_transmission,
            faults: FakeFaults::default(),
            moves: 0,
            t_s: 0.0,
            command: None,
            encoder: [0.0; 2],
            tool_mm: [0.0; 2],
        }
    }

    fn command_rad(&self, target_mm: [f64; 2]) -> Result<[f64; 2], String> {
        let grid = match &self.image {
            Some(b) => Some(CorrectionGrid::parse(b).map_err(|e| e.to_string())?),
            None => None,
        };
        let cal = match grid {
            Some(g) => Calibration::from_grid(g),
            None => Calibration {
                model: self.model.cast(),
                grid: None,
            },
        };
        let c = cal
            .command_rad(
                [target_mm[0] as f32, target_mm[1] as f32],
                self.min_transmission as f32,
            )
            .map_err(|e| e.to_string())?;
        let prev = self.command.unwrap_or([0.0; 2]);
        Ok([0, 1].map(|i| prev[i] + wrap_angle_rad(f64::from(c[i]) - prev[i])))
    }
}

impl Rig for FakeRig {
    fn describe(&self) -> String {
        format!(
            "in-process controller around {}",
            crate::calib::machine::Machine::describe(&self.machine)
        )
    }

    fn check_ready(&mut self) -> Result<(), SessionError> {
        if self.faults.unhomed {
            return Err(SessionError::NotReady(
                "not homed (NotHomed): home it first (host-sim link home)".into(),
            ));
        }
        Ok(())
    }

    fn move_to(&mut self, target_mm: [f64; 2]) -> Result<Moved, SessionError> {
        if self.faults.drop_at_move == Some(self.moves) {
            return Err(SessionError::Link(ClientError::Io(std::io::Error::from(
                std::io::ErrorKind::ConnectionReset,
            ))));
        }
        self.moves += 1;
        let cmd = self
            .command_rad(target_mm)
            .map_err(|e| SessionError::NotReady(format!("the move was refused: {e}")))?;
        let dir = match self.command {
            Some(p) => [0, 1].map(|i| if cmd[i] >= p[i] { 1 } else { -1 }),
            None => [1, 1],
        };
        let (encoder, solution) = self
            .machine
            .plant
            .settle(cmd, dir)
            .map_err(|e| SessionError::NotReady(format!("the plant: {e}")))?;
        self.command = Some(cmd);
        self.encoder = encoder;
        self.tool_mm = solution.tool_mm;
        self.t_s += 0.2;
        Ok(Moved {
            t_s: self.t_s,
            encoder_rad: encoder,
        })
    }

    fn settle(&mut self, from_s: f64, c: &SettleCriterion) -> Result<Settled, SessionError> {
        let reference = self.command.unwrap_or(self.encoder);
        let dt = 0.01;
        let mut samples = Vec::new();
        let mut k = 0usize;
        loop {
            let t = from_s + k as f64 * dt;
            let decay = 5e-5 * (-(t - from_s) / 0.02).exp();
            let hunt = if self.faults.hunting {
                5e-6 * (k as f64).sin()
            } else {
                0.0
            };
            let enc = self.encoder.map(|e| e - decay + hunt);
            samples.push(ServoSample {
                t_s: t,
                reference_rad: reference,
                encoder_rad: enc,
                following_error_rad: (0..2)
                    .map(|j| (reference[j] - enc[j]).abs())
                    .fold(0.0, f64::max),
            });
            if let Some(i) = settled_at(&samples, from_s, c) {
                let s = samples[i];
                self.t_s = s.t_s;
                return Ok(Settled {
                    t_s: s.t_s,
                    settle_s: s.t_s - from_s,
                    reference_rad: reference,
                    encoder_rad: self.encoder,
                    following_error_rad: samples
                        .iter()
                        .filter(|x| x.t_s >= s.t_s - c.dwell_s)
                        .map(|x| x.following_error_rad)
                        .fold(0.0, f64::max),
                });
            }
            if t - from_s > c.timeout_s {
                return Err(SessionError::NotSettled(*c));
            }
            k += 1;
        }
    }

    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError> {
        if self.faults.missing.contains(&point.index) {
            return Ok(Reading::Missing);
        }
        if let Some((row, p)) = self.faults.absurd {
            if row == point.index {
                return Ok(Reading::Point(p));
            }
        }
        Ok(Reading::Point(
            self.machine.plant.instrument.read_mm(self.tool_mm),
        ))
    }

    fn truth_mm(&self) -> Option<[f64; 2]> {
        Some(self.machine.plant.instrument.frame_mm(self.tool_mm))
    }
}
