//! The machine the calibration runs against, behind one small trait, so that `demo` and the
//! pipeline test do not care whether it is a stand-in or the real plant.
//!
//! Why a trait: calibration only ever does one thing to a machine: command encoder angles
//! (approached from a given side, for backlash), let the servo settle, and read the tool point
//! with the instrument. [`Machine::measure`] is exactly that. In simulation it also returns
//! where the tool *really* is (noiseless, instrument frame), so accuracy can be judged against
//! the truth and not against a noisy reading.
//!
//! [`StandInMachine`] is a **stand-in**, not the plant: a rigid five-bar whose parameters carry
//! errors of the paper's kind (link lengths, base offset B0, encoder zero offsets; scaled so the
//! nominal model is 1.5 mm off at worst over the grid nodes, as in Table I), plus a smooth
//! position-dependent distortion of ~40 µm that no five-bar can describe (standing in for the
//! six-bar's configuration-dependent link-length change), read by a 1 µm (σ per axis)
//! instrument whose frame is the machine frame. It has no backlash and no encoder
//! quantisation: `approach_dir` is ignored and the encoders read exactly what was commanded.
//! Everything is drawn from a seed, so a run is reproducible.
//!
//! [`PlantMachine`] is the real plant (`crate::plant`: the compliant overconstrained six-bar,
//! drives with encoder quantisation and backlash, the instrument with its own frame, scale and
//! noise) behind the same trait: settle the drives, solve the linkage, read the instrument.

use super::{invalid, CalibError};
use crate::machine_spec::MachineSpec;
use crate::plant::{Plant, PlantConfig};
use kinematics_core::FiveBar;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// What one measurement of a machine gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// Encoder readings where the servo holds the motors (rad): what the measurement CSV
    /// records as `theta1_deg,theta2_deg` (equal to the command unless encoders quantise).
    pub encoder_rad: [f64; 2],
    /// What the instrument reads (mm, instrument frame, with its noise).
    pub measured_mm: [f64; 2],
    /// Where the tool really is, as a noiseless instrument would read it (mm, instrument
    /// frame). Known only in simulation; accuracy is judged on it.
    pub true_mm: [f64; 2],
}

/// A machine that can be commanded and measured.
pub trait Machine {
    /// One-line description for the demo's report.
    fn describe(&self) -> String;

    /// Drives the motors to the encoder angles `command_rad` (continuous, not wrapped),
    /// approaching each from the side `approach_dir` (+1: from below, i.e. the motor last moved
    /// in the positive direction; -1: from above), lets it settle and reads the tool point.
    fn measure(
        &mut self,
        command_rad: [f64; 2],
        approach_dir: [i8; 2],
    ) -> Result<Reading, CalibError>;

    /// Restarts the instrument's noise stream as a machine built with `seed` starts it (each
    /// list a session of its own: `host-sim measure --seed`, and the demo's lists).
    fn reseed(&mut self, seed: u64);
}

/// The stand-in's noise stream for a seed.
fn stand_in_noise(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed ^ 0x0157_2a3e)
}

/// Worst error of the nominal model over the 5 mm grid that [`StandInMachine::paper_like`]
/// scales its parameter errors to (Table I: about 1.5 mm at point 7).
pub const PAPER_WORST_ERROR_MM: f64 = 1.5;

/// The stand-in machine (see the module doc).
#[derive(Clone, Debug)]
pub struct StandInMachine {
    /// The machine's true five-bar (what a perfect `full` fit would find, but for the distortion).
    pub five_bar: FiveBar<f64>,
    /// The machine description (workspace: the distortion's coordinates; nominal model and grid:
    /// the scaling of [`StandInMachine::paper_like`]).
    pub spec: MachineSpec,
    /// Amplitude factor of the smooth distortion (1.0 ≈ 40 µm peak).
    pub distortion_scale: f64,
    /// Instrument noise, σ per axis (mm).
    pub noise_sigma_mm: f64,
    rng: ChaCha8Rng,
}

impl StandInMachine {
    /// A stand-in with the given true five-bar, distortion amplitude factor and noise; `seed`
    /// seeds the instrument noise.
    pub fn new(
        spec: &MachineSpec,
        five_bar: FiveBar<f64>,
        distortion_scale: f64,
        noise_sigma_mm: f64,
        seed: u64,
    ) -> Result<Self, CalibError> {
        five_bar
            .validate()
            .map_err(|e| invalid!("stand-in machine: {e}"))?;
        if !(noise_sigma_mm >= 0.0 && noise_sigma_mm.is_finite() && distortion_scale.is_finite()) {
            return Err(invalid!(
                "stand-in machine: noise σ must be a non-negative number and the distortion finite"
            ));
        }
        Ok(StandInMachine {
            five_bar,
            spec: spec.clone(),
            distortion_scale,
            noise_sigma_mm,
            rng: stand_in_noise(seed),
        })
    }

    /// A machine with randomly drawn errors of the paper's kind: links (σ 0.1 mm, the paper's
    /// largest manufactured link error), base offset B0 (σ 0.1 mm per axis) and encoder zero
    /// offsets (σ 0.05°), all scaled together so the nominal model misses by
    /// [`PAPER_WORST_ERROR_MM`] at worst over the grid nodes of `spec`; a 0.7–1.3 × 40 µm
    /// distortion; an instrument of `spec`'s σ (1 µm on the paper machine).
    pub fn paper_like(spec: &MachineSpec, seed: u64) -> Result<Self, CalibError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut n = || -> f64 { StandardNormal.sample(&mut rng) };
        let dl = [0.1 * n(), 0.1 * n(), 0.1 * n(), 0.1 * n()];
        let db = [0.1 * n(), 0.1 * n()];
        let doff = [0.05f64.to_radians() * n(), 0.05f64.to_radians() * n()];
        let distortion_scale = rng.random_range(0.7..1.3);
        let nominal = spec.nominal;
        let with = |k: f64| FiveBar {
            a_mm: nominal.a_mm + k * dl[0],
            b_mm: nominal.b_mm + k * dl[1],
            c_mm: nominal.c_mm + k * dl[2],
            d_mm: nominal.d_mm + k * dl[3],
            base_b0_mm: [
                nominal.base_b0_mm[0] + k * db[0],
                nominal.base_b0_mm[1] + k * db[1],
            ],
            encoder_offset_rad: [
                nominal.encoder_offset_rad[0] + k * doff[0],
                nominal.encoder_offset_rad[1] + k * doff[1],
            ],
            ..nominal
        };
        // The error is nearly linear in k: a few secant steps hit the target to < 1 %.
        let mut k = 1.0;
        for _ in 0..4 {
            let m = StandInMachine::new(spec, with(k), distortion_scale, 0.0, seed)?;
            let worst = m.worst_nominal_error_mm()?;
            if !(worst > 0.0) {
                return Err(invalid!("stand-in machine: seed {seed} drew no error"));
            }
            k *= PAPER_WORST_ERROR_MM / worst;
        }
        StandInMachine::new(
            spec,
            with(k),
            distortion_scale,
            spec.instrument_sigma_um * 1e-3,
            seed,
        )
    }

    /// Where the tool really is for encoder angles `theta_rad` (mm): the true five-bar's FK
    /// plus the smooth distortion.
    pub fn tool_mm(&self, theta_rad: [f64; 2]) -> Result<[f64; 2], CalibError> {
        let c = self.five_bar.forward(theta_rad, 0.0).map_err(|e| {
            invalid!(
                "stand-in machine cannot reach encoder angles ({:.4}, {:.4}) rad: {e}",
                theta_rad[0],
                theta_rad[1]
            )
        })?;
        let (centre, half) = (
            self.spec.workspace.centre_mm(),
            self.spec.workspace.half_mm(),
        );
        let u = (c[0] - centre[0]) / half[0];
        let v = (c[1] - centre[1]) / half[1];
        let s = self.distortion_scale;
        Ok([
            c[0] + s * (0.03 * (1.3 * u).sin() * v + 0.01 * v * v),
            c[1] + s * (0.025 * (0.9 * v).sin() * u - 0.015 * u * u),
        ])
    }

    /// Worst distance (mm) between target and tool over the grid nodes when commanded with the
    /// nominal model's IK (no noise): the "before calibration" error.
    pub fn worst_nominal_error_mm(&self) -> Result<f64, CalibError> {
        let mut worst = 0.0f64;
        for t in self.spec.grid_nodes_mm() {
            let th = self
                .spec
                .nominal
                .inverse(t, 0.0)
                .map_err(|e| invalid!("nominal IK of ({}, {}): {e}", t[0], t[1]))?;
            let p = self.tool_mm(th)?;
            worst = worst.max((p[0] - t[0]).hypot(p[1] - t[1]));
        }
        Ok(worst)
    }
}

impl Machine for StandInMachine {
    fn describe(&self) -> String {
        let m = &self.five_bar;
        format!(
            "stand-in (rigid five-bar + smooth distortion, not the six-bar plant): a {:.4}, b {:.4}, c {:.4}, d {:.4} mm, \
             B0 ({:.4}, {:.4}) mm, encoder offsets ({:.4}, {:.4})°, distortion ×{:.2} (~40 µm), instrument σ {:.1} µm",
            m.a_mm,
            m.b_mm,
            m.c_mm,
            m.d_mm,
            m.base_b0_mm[0],
            m.base_b0_mm[1],
            m.encoder_offset_rad[0].to_degrees(),
            m.encoder_offset_rad[1].to_degrees(),
            self.distortion_scale,
            self.noise_sigma_mm * 1e3
        )
    }

    fn measure(
        &mut self,
        command_rad: [f64; 2],
        _approach_dir: [i8; 2],
    ) -> Result<Reading, CalibError> {
        let true_mm = self.tool_mm(command_rad)?;
        let mut measured_mm = true_mm;
        for v in &mut measured_mm {
            let n: f64 = StandardNormal.sample(&mut self.rng);
            *v += self.noise_sigma_mm * n;
        }
        Ok(Reading {
            encoder_rad: command_rad,
            measured_mm,
            true_mm,
        })
    }

    fn reseed(&mut self, seed: u64) {
        self.rng = stand_in_noise(seed);
    }
}

/// Largest relative difference of a link between a plant's nominal five-bar and the machine's.
pub const PLANT_LINK_TOLERANCE: f64 = 0.05;
/// Largest distance (mm) between a plant's nominal base axes and the machine's.
pub const PLANT_BASE_TOLERANCE_MM: f64 = 10.0;

/// Refuses a plant built around another five-bar than `spec`'s nominal one (the plant of
/// another machine: calibrating it would fail far from any target, or silently fit nonsense):
/// every link within [`PLANT_LINK_TOLERANCE`], A0 and B0 within [`PLANT_BASE_TOLERANCE_MM`],
/// the same working mode. Manufacturing errors are not counted: they are what a calibration
/// finds.
pub fn check_plant_fits(plant: &PlantConfig, spec: &MachineSpec) -> Result<(), CalibError> {
    let (p, m) = (plant.sixbar.nominal_five_bar(), &spec.nominal);
    let links = [
        ("a", p.a_mm, m.a_mm),
        ("b", p.b_mm, m.b_mm),
        ("c", p.c_mm, m.c_mm),
        ("d", p.d_mm, m.d_mm),
    ];
    let b0 = |f: &FiveBar<f64>| {
        [
            f.base_a0_mm[0] + f.base_b0_mm[0],
            f.base_a0_mm[1] + f.base_b0_mm[1],
        ]
    };
    let far = |u: [f64; 2], v: [f64; 2]| (u[0] - v[0]).hypot(u[1] - v[1]) > PLANT_BASE_TOLERANCE_MM;
    let what = if let Some((name, pl, ml)) = links
        .iter()
        .find(|(_, pl, ml)| !((pl - ml).abs() <= PLANT_LINK_TOLERANCE * ml))
    {
        format!("its link {name} is {pl} mm, the machine's {ml} mm")
    } else if far(p.base_a0_mm, m.base_a0_mm) || far(b0(&p), b0(m)) {
        format!(
            "its axes A0 {:?}, B0 {:?} mm are not the machine's {:?}, {:?}",
            p.base_a0_mm,
            b0(&p),
            m.base_a0_mm,
            b0(m)
        )
    } else if p.mode != m.mode {
        format!(
            "its working mode {:?} is not the machine's {:?}",
            p.mode, m.mode
        )
    } else {
        return Ok(());
    };
    Err(invalid!(
        "the plant is not a simulation of machine '{}': {what} (give the plant of this machine with --plant FILE)",
        spec.name
    ))
}

/// The six-bar plant as a [`Machine`].
#[derive(Clone, Debug)]
pub struct PlantMachine {
    pub plant: Plant,
    /// How the plant was named (`ideal`, `paper`, a TOML path).
    pub name: String,
}

impl PlantMachine {
    /// The plant `name` (`ideal`, `paper` or a TOML file); `noise_um` overrides its
    /// instrument's σ per axis; `seed` seeds the instrument noise.
    pub fn by_name(name: &str, noise_um: Option<f64>, seed: u64) -> Result<Self, CalibError> {
        Self::from_config(PlantConfig::by_name(name)?, name, noise_um, seed)
    }

    /// A plant from its configuration (e.g. one with randomly drawn errors), named `name`.
    pub fn from_config(
        mut config: PlantConfig,
        name: &str,
        noise_um: Option<f64>,
        seed: u64,
    ) -> Result<Self, CalibError> {
        if let Some(n) = noise_um {
            if !(n >= 0.0 && n.is_finite()) {
                return Err(invalid!(
                    "the instrument noise σ must be a non-negative number of µm, not {n}"
                ));
            }
            config.instrument.noise_sigma_um = n;
        }
        Ok(PlantMachine {
            plant: Plant::new(&config, seed),
            name: name.to_string(),
        })
    }
}

impl Machine for PlantMachine {
    fn describe(&self) -> String {
        format!(
            "plant '{}' (six-bar, drives, instrument σ {:.1} µm)",
            self.name,
            self.plant.instrument.noise_sigma_mm * 1e3
        )
    }

    fn measure(
        &mut self,
        command_rad: [f64; 2],
        approach_dir: [i8; 2],
    ) -> Result<Reading, CalibError> {
        let (encoder_rad, solution) = self.plant.settle(command_rad, approach_dir)?;
        let true_mm = self.plant.instrument.frame_mm(solution.tool_mm);
        let measured_mm = self.plant.instrument.read_mm(solution.tool_mm);
        Ok(Reading {
            encoder_rad,
            measured_mm,
            true_mm,
        })
    }

    /// Also starts the linkage's solver afresh (its warm start): a list measured after others
    /// reads exactly what `measure --seed` reads on a new plant, to the last bit.
    fn reseed(&mut self, seed: u64) {
        self.plant.instrument.reseed(seed);
        self.plant.sixbar = crate::plant::sixbar::SixBar::new(&self.plant.config.sixbar);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_like_is_1_5_mm_off_and_reproducible() {
        let spec = MachineSpec::paper();
        for seed in [1, 2, 3] {
            let m = StandInMachine::paper_like(&spec, seed).unwrap();
            let w = m.worst_nominal_error_mm().unwrap();
            assert!(
                (w - PAPER_WORST_ERROR_MM).abs() < 0.02,
                "seed {seed}: {w} mm"
            );
            assert_eq!(
                m.five_bar,
                StandInMachine::paper_like(&spec, seed).unwrap().five_bar
            );
        }
        assert_ne!(
            StandInMachine::paper_like(&spec, 1).unwrap().five_bar,
            StandInMachine::paper_like(&spec, 2).unwrap().five_bar
        );
    }

    #[test]
    fn a_plant_of_another_machine_is_refused() {
        let spec = MachineSpec::paper();
        assert!(check_plant_fits(&PlantConfig::paper(), &spec).is_ok());
        let mut other = spec.clone();
        other.nominal.c_mm = 170.0;
        let e = check_plant_fits(&PlantConfig::paper(), &other)
            .unwrap_err()
            .to_string();
        assert!(e.contains("link c is 150 mm, the machine's 170 mm"), "{e}");
        other.nominal.c_mm = 150.0;
        other.nominal.base_b0_mm = [0.0, -60.0];
        assert!(check_plant_fits(&PlantConfig::paper(), &other)
            .unwrap_err()
            .to_string()
            .contains("axes"));
        // A plant built around the other machine fits it.
        let plant = PlantConfig::ideal_for(&other.nominal, &other.grid_nodes_mm()).unwrap();
        assert!(check_plant_fits(&plant, &other).is_ok());
    }

    #[test]
    fn noise_is_seeded_and_about_1_um() {
        let th = [45f64.to_radians(), -45f64.to_radians()];
        let mut a = StandInMachine::paper_like(&MachineSpec::paper(), 5).unwrap();
        let mut b = StandInMachine::paper_like(&MachineSpec::paper(), 5).unwrap();
        let ra: Vec<Reading> = (0..200).map(|_| a.measure(th, [1, 1]).unwrap()).collect();
        let rb: Vec<Reading> = (0..200).map(|_| b.measure(th, [1, 1]).unwrap()).collect();
        assert_eq!(ra, rb);
        let var = ra
            .iter()
            .map(|r| (r.measured_mm[0] - r.true_mm[0]).powi(2))
            .sum::<f64>()
            / 200.0;
        let sigma_um = var.sqrt() * 1e3;
        assert!((0.8..1.2).contains(&sigma_um), "{sigma_um}");
    }
}
