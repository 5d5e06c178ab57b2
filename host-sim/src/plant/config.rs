//! The plant description: one TOML file per simulated machine, every effect a parameter.
//!
//! A plant is the "real machine" the tools are tested against, so its description must be
//! explicit and reproducible: every key carries its unit in its name, unknown keys are refused
//! (`deny_unknown_fields`: a misspelt key must not silently fall back to zero), and every effect
//! is switched off by setting its parameter to zero. Plants are named on the command line as
//! `ideal` (everything off), `paper` (the documented default, identical to
//! `host-sim/plants/paper.toml`, a test checks it) or a path to a TOML file.
//!
//! [`PlantConfig::with_random_errors`] draws a plant with random manufacturing errors from a
//! seed and [`PlantConfig::with_only`] keeps one effect of a plant (named in the crate's one
//! vocabulary, [`PhysicalEffect`]) and switches every other one off: what the calibration and
//! diagnosis tests need.

use super::PlantError;
use crate::effect::PhysicalEffect;
use crate::machine_spec::BranchKey;
use kinematics_core::sixbar::SixBarDesign;
use kinematics_core::{FiveBar, WorkingMode};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The paper plant as shipped (the built-in `paper` must equal it: see the tests).
pub const PAPER_TOML: &str = include_str!("../../plants/paper.toml");

/// How the tool point is computed from the link angles.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum PlantModel {
    /// The compliant overconstrained six-bar, solved for static equilibrium (see `sixbar`).
    Sixbar,
    /// Closed-form five-bar with the arms' effective geometry (lever and Q-bar lengths, motor
    /// pins, the Q pins on the elbows and D, E on the platform; the followers' errors and the
    /// clearances are ignored): fast, no internal stress, no platform rotation.
    Fivebar,
}

/// Manufacturing errors of the six-bar (mm): each bar length, each pin position on each body
/// (`[sixbar.errors]`; the core's type, which the firmware's benchmark of the solve shares).
pub type SixBarErrors = kinematics_core::sixbar::SixBarErrors<f64>;

/// The nominal five-bar a six-bar is built around, for any machine (`[sixbar.geometry]`;
/// absent: the paper's, every link `link_mm`, both axes at the origin, the paper's working
/// mode, arm 2's parallelogram offsets the mirror image of arm 1's). The motors' axes sit
/// `platform_half_width_mm` above A0 and below B0, as D and E sit above and below the tool
/// point, so the tool point moves like this five-bar's end point (see `sixbar`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SixBarGeometry {
    /// Lever P1 and its follower F1 (the five-bar's a).
    pub a_mm: f64,
    /// Distal bar Q1 and its follower G1 (b).
    pub b_mm: f64,
    /// Distal bar Q2 and its follower G2 (c).
    pub c_mm: f64,
    /// Lever P2 and its follower F2 (d).
    pub d_mm: f64,
    /// The equivalent five-bar's A0 and B0 (machine frame).
    pub a0_mm: [f64; 2],
    pub b0_mm: [f64; 2],
    pub elbow_1: BranchKey,
    pub elbow_2: BranchKey,
    pub assembly: BranchKey,
    /// Offsets of arm 2's first and second parallelograms (arm 1's are
    /// `parallelogram_1_offset_mm` and `parallelogram_2_offset_mm`).
    pub arm_2_parallelogram_1_offset_mm: [f64; 2],
    pub arm_2_parallelogram_2_offset_mm: [f64; 2],
}

/// The linkage: nominal geometry, elasticity, clearances, errors.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SixBarConfig {
    pub model: PlantModel,
    /// Nominal length of every lever, bar and follower of the equivalent five-bar (a = b = c = d)
    /// when `geometry` is absent (the paper's machine); not used with it.
    pub link_mm: f64,
    /// Any other five-bar (`[sixbar.geometry]`); absent: the paper's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<SixBarGeometry>,
    /// Half the platform's DE distance (D = C + (0, w/2), E = C - (0, w/2)).
    pub platform_half_width_mm: f64,
    /// Offset of the first parallelogram of arm 1 (A0→A0*, A→A*); arm 2 is mirrored in x.
    pub parallelogram_1_offset_mm: [f64; 2],
    /// Offset of the second parallelogram of arm 1 (A→A**, D→D**); arm 2 mirrored.
    pub parallelogram_2_offset_mm: [f64; 2],
    /// Young's modulus of the bars (aluminium: 70 000 N/mm²).
    pub youngs_modulus_n_per_mm2: f64,
    /// Cross-section of the levers' partners Q1, Q2 (the load-carrying distal bars).
    pub main_bar_section_mm2: f64,
    /// Cross-section of the followers F and G.
    pub follower_bar_section_mm2: f64,
    /// Radial stiffness of the elbow bearings A (P1–K1) and B (P2–K2).
    pub pin_stiffness_n_per_mm: f64,
    /// Radial clearance of the elbow bearings (0 = none).
    pub pin_clearance_mm: f64,
    /// Total axial clearance of the two end pins of every bar (0 = none).
    pub bar_end_clearance_mm: f64,
    /// Stiffness inside a clearance, as a fraction of the contact stiffness (makes the
    /// equilibrium unique; 1e-3 is 0.1 %).
    pub clearance_centring_ratio: f64,
    pub errors: SixBarErrors,
}

/// One motor, gearbox and encoder (joint-side units: angles of the link, torques at the link).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DriveConfig {
    /// Motor and gearbox inertia seen at the joint (the linkage's bodies are `[linkage]`).
    pub inertia_kg_m2: f64,
    pub viscous_friction_nm_s_per_rad: f64,
    pub coulomb_friction_nm: f64,
    /// The amplifier's torque limit (joint side).
    pub torque_limit_nm: f64,
    /// Motor revolutions per joint revolution.
    pub gear_ratio: f64,
    /// Encoder counts per motor revolution (0 = no quantization).
    pub encoder_counts_per_motor_rev: f64,
    /// True geometric link angle minus encoder angle (what the calibration has to find).
    pub encoder_offset_deg: f64,
    /// Gear backlash: total lost motion at the joint (0 = none).
    pub backlash_urad: f64,
    /// Gear-tooth cyclic error at the joint: amplitude (0 = none) ...
    pub cyclic_error_urad: f64,
    /// ... cycles per motor revolution ...
    pub cyclic_error_cycles_per_motor_rev: f64,
    /// ... and phase.
    pub cyclic_error_phase_deg: f64,
    /// The torque the motor delivers is the command times `1 + pct/100` (after the amplifier's
    /// limit): a torque constant (or current gain) off its data sheet (0 = exact; optional).
    #[serde(default)]
    pub torque_constant_error_pct: f64,
    /// Cogging: a torque ripple `amplitude·sin(cycles·gear_ratio·motor + phase)` periodic in the
    /// motor angle, acting against the drive (0 = none; optional) ...
    #[serde(default)]
    pub cogging_nm: f64,
    /// ... its cycles per motor revolution (the motor's slot count and poles) ...
    #[serde(default)]
    pub cogging_cycles_per_motor_rev: f64,
    /// ... and phase.
    #[serde(default)]
    pub cogging_phase_deg: f64,
}

/// The measuring instrument (interferometer / laser tracker).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InstrumentConfig {
    /// Instrument reading = offset + R(rotation)·(1 + scale)·tool + noise.
    pub frame_offset_mm: [f64; 2],
    pub frame_rotation_deg: f64,
    pub scale_error_ppm: f64,
    /// Standard deviation of the Gaussian noise, per axis (0 = none).
    pub noise_sigma_um: f64,
}

/// A whole plant.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    pub description: String,
    pub sixbar: SixBarConfig,
    /// Masses of the linkage's bodies (optional in a file: the paper machine's by default).
    #[serde(default)]
    pub linkage: LinkageConfig,
    pub drive_1: DriveConfig,
    pub drive_2: DriveConfig,
    pub instrument: InstrumentConfig,
}

impl SixBarConfig {
    /// The nominal five-bar the linkage is built around (errors not included): the paper's, or
    /// `geometry`'s.
    pub fn nominal_five_bar(&self) -> FiveBar<f64> {
        match &self.geometry {
            None => {
                let mut f = FiveBar::paper_nominal();
                (f.a_mm, f.b_mm, f.c_mm, f.d_mm) =
                    (self.link_mm, self.link_mm, self.link_mm, self.link_mm);
                f
            }
            Some(g) => FiveBar {
                a_mm: g.a_mm,
                b_mm: g.b_mm,
                c_mm: g.c_mm,
                d_mm: g.d_mm,
                base_a0_mm: g.a0_mm,
                base_b0_mm: [g.b0_mm[0] - g.a0_mm[0], g.b0_mm[1] - g.a0_mm[1]],
                encoder_offset_rad: [0.0; 2],
                mode: WorkingMode {
                    elbow_1: g.elbow_1.into(),
                    elbow_2: g.elbow_2.into(),
                    assembly: g.assembly.into(),
                },
            },
        }
    }

    /// What the six-bar is built from besides its errors (`kinematics_core::sixbar`).
    pub fn design(&self) -> SixBarDesign<f64> {
        SixBarDesign {
            nominal: self.nominal_five_bar(),
            platform_half_width_mm: self.platform_half_width_mm,
            parallelogram_offsets_mm: self.parallelogram_offsets_mm(),
            youngs_modulus_n_per_mm2: self.youngs_modulus_n_per_mm2,
            main_bar_section_mm2: self.main_bar_section_mm2,
            follower_bar_section_mm2: self.follower_bar_section_mm2,
        }
    }

    /// The two parallelogram offsets of each arm: `[[g1, h1], [g2, h2]]`.
    pub fn parallelogram_offsets_mm(&self) -> [[[f64; 2]; 2]; 2] {
        let (g1, h1) = (
            self.parallelogram_1_offset_mm,
            self.parallelogram_2_offset_mm,
        );
        match &self.geometry {
            None => [[g1, h1], [[g1[0], -g1[1]], [h1[0], -h1[1]]]],
            Some(g) => [
                [g1, h1],
                [
                    g.arm_2_parallelogram_1_offset_mm,
                    g.arm_2_parallelogram_2_offset_mm,
                ],
            ],
        }
    }
}

fn ideal_drive() -> DriveConfig {
    DriveConfig {
        inertia_kg_m2: 2.0e-3,
        viscous_friction_nm_s_per_rad: 0.0,
        coulomb_friction_nm: 0.0,
        torque_limit_nm: 8.0,
        gear_ratio: 10.0,
        encoder_counts_per_motor_rev: 0.0,
        encoder_offset_deg: 0.0,
        backlash_urad: 0.0,
        cyclic_error_urad: 0.0,
        cyclic_error_cycles_per_motor_rev: 0.0,
        cyclic_error_phase_deg: 0.0,
        torque_constant_error_pct: 0.0,
        cogging_nm: 0.0,
        cogging_cycles_per_motor_rev: 0.0,
        cogging_phase_deg: 0.0,
    }
}

impl PlantConfig {
    /// Every error off, no clearance, no quantization, no friction, a perfect instrument: the
    /// six-bar's tool point is then the nominal five-bar's FK. The masses are the paper
    /// machine's (`[linkage]` defaults): an ideal machine still has inertia.
    pub fn ideal() -> Self {
        let r = 30.0 * std::f64::consts::FRAC_1_SQRT_2;
        PlantConfig {
            description: "ideal: every error off, no noise".into(),
            sixbar: SixBarConfig {
                model: PlantModel::Sixbar,
                link_mm: 150.0,
                geometry: None,
                platform_half_width_mm: 20.0,
                parallelogram_1_offset_mm: [-r, r],
                parallelogram_2_offset_mm: [r, r],
                youngs_modulus_n_per_mm2: 70_000.0,
                main_bar_section_mm2: 120.0,
                follower_bar_section_mm2: 40.0,
                pin_stiffness_n_per_mm: 20_000.0,
                pin_clearance_mm: 0.0,
                bar_end_clearance_mm: 0.0,
                clearance_centring_ratio: 1e-3,
                errors: SixBarErrors::default(),
            },
            linkage: LinkageConfig::default(),
            drive_1: ideal_drive(),
            drive_2: ideal_drive(),
            instrument: InstrumentConfig {
                frame_offset_mm: [0.0; 2],
                frame_rotation_deg: 0.0,
                scale_error_ppm: 0.0,
                noise_sigma_um: 0.0,
            },
        }
    }

    /// The ideal plant (every error off) built around `nominal`'s five-bar, for any machine:
    /// links, bases and working mode from `nominal`, the drives' encoder offsets its zero
    /// offsets, and each parallelogram's offset 30 mm long and perpendicular to the middle of
    /// its bar's angle range over `targets` (arm 1 turned +90°, arm 2 −90°, as on the paper
    /// machine), so that none comes near its flat, singular shape. `None` if `nominal` cannot
    /// reach a target.
    pub fn ideal_for(nominal: &FiveBar<f64>, targets: &[[f64; 2]]) -> Option<Self> {
        let mut p = PlantConfig::ideal();
        let mut lo = [f64::INFINITY; 4];
        let mut hi = [f64::NEG_INFINITY; 4];
        let mut first: Option<[f64; 4]> = None;
        // Bar angles: the levers' (link angles) and the distal bars' (from the elbows to C),
        // unwrapped next to the first target's.
        for &t in targets {
            let pose = nominal.inverse_pose(t, 0.0).ok()?;
            let link = [0, 1].map(|i| pose.theta_rad[i] + nominal.encoder_offset_rad[i]);
            let (ea, eb) = (pose.elbow_a_mm, pose.elbow_b_mm);
            let raw = [
                link[0],
                (t[1] - ea[1]).atan2(t[0] - ea[0]),
                link[1],
                (t[1] - eb[1]).atan2(t[0] - eb[0]),
            ];
            let f = *first.get_or_insert(raw);
            for k in 0..4 {
                let a = f[k] + kinematics_core::wrap_angle_rad(raw[k] - f[k]);
                lo[k] = lo[k].min(a);
                hi[k] = hi[k].max(a);
            }
        }
        let offset = |k: usize, turn: f64| {
            let mid = 0.5 * (lo[k] + hi[k]) + turn;
            [30.0 * mid.cos(), 30.0 * mid.sin()]
        };
        let half_pi = std::f64::consts::FRAC_PI_2;
        let s = &mut p.sixbar;
        s.parallelogram_1_offset_mm = offset(0, half_pi);
        s.parallelogram_2_offset_mm = offset(1, half_pi);
        let m = nominal.mode;
        s.geometry = Some(SixBarGeometry {
            a_mm: nominal.a_mm,
            b_mm: nominal.b_mm,
            c_mm: nominal.c_mm,
            d_mm: nominal.d_mm,
            a0_mm: nominal.base_a0_mm,
            b0_mm: [
                nominal.base_a0_mm[0] + nominal.base_b0_mm[0],
                nominal.base_a0_mm[1] + nominal.base_b0_mm[1],
            ],
            elbow_1: m.elbow_1.into(),
            elbow_2: m.elbow_2.into(),
            assembly: m.assembly.into(),
            arm_2_parallelogram_1_offset_mm: offset(2, -half_pi),
            arm_2_parallelogram_2_offset_mm: offset(3, -half_pi),
        });
        p.drive_1.encoder_offset_deg = nominal.encoder_offset_rad[0].to_degrees();
        p.drive_2.encoder_offset_deg = nominal.encoder_offset_rad[1].to_degrees();
        p.description = "ideal plant around a machine's nominal five-bar".into();
        Some(p)
    }

    /// The documented default resembling the paper's machine (see `plants/paper.toml` for the
    /// reasoning behind each number).
    pub fn paper() -> Self {
        let mut p = PlantConfig::ideal();
        p.description = "paper: resembles Kiper et al. Table I (about 1.5 mm worst error with the nominal model)".into();
        let s = &mut p.sixbar;
        s.pin_clearance_mm = 0.003;
        s.bar_end_clearance_mm = 0.002;
        let e = &mut s.errors;
        e.lever_length_mm = [-1.58, 1.52];
        e.bar_q_length_mm = [2.26, -2.34];
        e.bar_f_length_mm = [-1.55, 1.58];
        e.bar_g_length_mm = [2.31, -2.30];
        e.ground_motor_1_mm = [0.02, -0.01];
        e.ground_motor_2_mm = [-0.01, 0.015];
        e.ground_follower_1_mm = [0.04, -0.03];
        e.ground_follower_2_mm = [-0.02, 0.05];
        e.elbow_1_pin_q_mm = [0.01, 0.02];
        e.elbow_1_pin_f_mm = [-0.05, 0.03];
        e.elbow_1_pin_g_mm = [0.04, 0.06];
        e.elbow_2_pin_q_mm = [-0.02, 0.01];
        e.elbow_2_pin_f_mm = [0.03, -0.04];
        e.elbow_2_pin_g_mm = [-0.06, 0.02];
        e.platform_pin_d_mm = [0.015, -0.01];
        e.platform_pin_dd_mm = [-0.03, 0.05];
        e.platform_pin_e_mm = [0.01, 0.02];
        e.platform_pin_ee_mm = [0.05, -0.04];
        for (d, offset_deg) in [(&mut p.drive_1, -0.013), (&mut p.drive_2, 0.027)] {
            d.viscous_friction_nm_s_per_rad = 0.02;
            d.coulomb_friction_nm = 0.05;
            d.encoder_counts_per_motor_rev = 1_048_576.0;
            d.encoder_offset_deg = offset_deg;
            d.backlash_urad = 20.0;
        }
        p.instrument.frame_offset_mm = [-0.008, 3.194];
        p.instrument.noise_sigma_um = 10.0;
        p
    }

    /// `ideal`, `paper` or a path to a TOML file.
    pub fn by_name(name: &str) -> Result<Self, PlantError> {
        match name {
            "ideal" => Ok(PlantConfig::ideal()),
            "paper" => Ok(PlantConfig::paper()),
            path => {
                let p = Path::new(path);
                if !p.exists() {
                    return Err(PlantError::UnknownPlant(path.to_string()));
                }
                let text = std::fs::read_to_string(p).map_err(|e| PlantError::Read {
                    path: path.to_string(),
                    message: e.to_string(),
                })?;
                PlantConfig::from_toml(&text).map_err(|e| PlantError::InFile {
                    path: path.to_string(),
                    message: e.to_string(),
                })
            }
        }
    }

    /// Parses and validates a plant description.
    pub fn from_toml(text: &str) -> Result<Self, PlantError> {
        let p: PlantConfig = toml::from_str(text).map_err(|e| PlantError::Toml(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a plant always serializes")
    }

    /// Refuses non-finite numbers and physically meaningless values.
    pub fn validate(&self) -> Result<(), PlantError> {
        let s = &self.sixbar;
        let json = serde_json::to_value(self).map_err(|e| PlantError::Invalid(e.to_string()))?;
        fn walk(v: &serde_json::Value, path: &str) -> Result<(), PlantError> {
            let invalid = |m: String| Err(PlantError::Invalid(m));
            match v {
                serde_json::Value::Number(n) if !n.as_f64().is_some_and(f64::is_finite) => {
                    invalid(format!("'{path}' is not finite"))
                }
                serde_json::Value::Null => invalid(format!("'{path}' is not a finite number")),
                serde_json::Value::Object(m) => m
                    .iter()
                    .try_for_each(|(k, v)| walk(v, &format!("{path}.{k}"))),
                serde_json::Value::Array(a) => a
                    .iter()
                    .enumerate()
                    .try_for_each(|(i, v)| walk(v, &format!("{path}[{i}]"))),
                _ => Ok(()),
            }
        }
        walk(&json, "plant")?;
        let positive = [
            ("sixbar.link_mm", s.link_mm),
            ("sixbar.platform_half_width_mm", s.platform_half_width_mm),
            (
                "sixbar.youngs_modulus_n_per_mm2",
                s.youngs_modulus_n_per_mm2,
            ),
            ("sixbar.main_bar_section_mm2", s.main_bar_section_mm2),
            (
                "sixbar.follower_bar_section_mm2",
                s.follower_bar_section_mm2,
            ),
            ("sixbar.pin_stiffness_n_per_mm", s.pin_stiffness_n_per_mm),
            (
                "sixbar.clearance_centring_ratio",
                s.clearance_centring_ratio,
            ),
            ("drive_1.inertia_kg_m2", self.drive_1.inertia_kg_m2),
            ("drive_2.inertia_kg_m2", self.drive_2.inertia_kg_m2),
            ("drive_1.gear_ratio", self.drive_1.gear_ratio),
            ("drive_2.gear_ratio", self.drive_2.gear_ratio),
            ("drive_1.torque_limit_nm", self.drive_1.torque_limit_nm),
            ("drive_2.torque_limit_nm", self.drive_2.torque_limit_nm),
        ];
        for (name, v) in positive {
            if !(v > 0.0) {
                return Err(PlantError::Invalid(format!(
                    "'{name}' must be positive, not {v}"
                )));
            }
        }
        let non_negative = [
            ("sixbar.pin_clearance_mm", s.pin_clearance_mm),
            ("sixbar.bar_end_clearance_mm", s.bar_end_clearance_mm),
            ("instrument.noise_sigma_um", self.instrument.noise_sigma_um),
            ("drive_1.backlash_urad", self.drive_1.backlash_urad),
            ("drive_2.backlash_urad", self.drive_2.backlash_urad),
            (
                "drive_1.encoder_counts_per_motor_rev",
                self.drive_1.encoder_counts_per_motor_rev,
            ),
            (
                "drive_2.encoder_counts_per_motor_rev",
                self.drive_2.encoder_counts_per_motor_rev,
            ),
            (
                "drive_1.viscous_friction_nm_s_per_rad",
                self.drive_1.viscous_friction_nm_s_per_rad,
            ),
            (
                "drive_2.viscous_friction_nm_s_per_rad",
                self.drive_2.viscous_friction_nm_s_per_rad,
            ),
            (
                "drive_1.coulomb_friction_nm",
                self.drive_1.coulomb_friction_nm,
            ),
            (
                "drive_2.coulomb_friction_nm",
                self.drive_2.coulomb_friction_nm,
            ),
        ];
        for (name, v) in non_negative.into_iter().chain(self.linkage.non_negative()) {
            if !(v >= 0.0) {
                return Err(PlantError::Invalid(format!(
                    "'{name}' must not be negative, not {v}"
                )));
            }
        }
        for (k, d) in [(1, &self.drive_1), (2, &self.drive_2)] {
            if !(d.torque_constant_error_pct > -50.0 && d.torque_constant_error_pct < 100.0) {
                return Err(PlantError::Invalid(format!(
                    "'drive_{k}.torque_constant_error_pct' must be in (-50, 100), not {}",
                    d.torque_constant_error_pct
                )));
            }
            if !(d.cogging_nm >= 0.0 && d.cogging_nm <= d.torque_limit_nm) {
                return Err(PlantError::Invalid(format!(
                    "'drive_{k}.cogging_nm' must be in [0, the torque limit], not {}",
                    d.cogging_nm
                )));
            }
            if !(d.cogging_cycles_per_motor_rev >= 0.0 && d.cogging_cycles_per_motor_rev <= 1000.0)
            {
                return Err(PlantError::Invalid(format!(
                    "'drive_{k}.cogging_cycles_per_motor_rev' must be in [0, 1000], not {}",
                    d.cogging_cycles_per_motor_rev
                )));
            }
        }
        if s.pin_clearance_mm > 1.0 || s.bar_end_clearance_mm > 1.0 {
            return Err(PlantError::Invalid(
                "clearances above 1 mm are not a machine".into(),
            ));
        }
        Ok(())
    }

    /// This plant with every six-bar pin and length error drawn from N(0, sigma_mm²) and the
    /// encoder offsets from N(0, sigma_offset_deg²), reproducibly from `seed`.
    pub fn with_random_errors(&self, seed: u64, sigma_mm: f64, sigma_offset_deg: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = Normal::new(0.0, sigma_mm.abs()).expect("finite sigma");
        let o = Normal::new(0.0, sigma_offset_deg.abs()).expect("finite sigma");
        let mut p = self.clone();
        let e = &mut p.sixbar.errors;
        let mut draw2 = |v: &mut [f64; 2]| {
            v[0] = n.sample(&mut rng);
            v[1] = n.sample(&mut rng);
        };
        // The lengths first, then the pins: the order the draws have always been made in.
        for v in [
            &mut e.lever_length_mm,
            &mut e.bar_f_length_mm,
            &mut e.bar_q_length_mm,
            &mut e.bar_g_length_mm,
        ] {
            draw2(v);
        }
        for v in e.pins_mut() {
            draw2(v);
        }
        p.drive_1.encoder_offset_deg = o.sample(&mut rng);
        p.drive_2.encoder_offset_deg = o.sample(&mut rng);
        p.description = format!(
            "{} + random errors (seed {seed}, {sigma_mm} mm, {sigma_offset_deg} deg)",
            self.description
        );
        p
    }

    /// The ideal plant with only `effect` taken over from `self`. Effects the plant has no
    /// setting of its own for (`link_lengths`, `base_offset`, `link_stretch`,
    /// `parallelogram_mismatch`: parts of `link_geometry`; `gear_ratio`) are refused.
    pub fn with_only(&self, effect: PhysicalEffect) -> Result<Self, PlantError> {
        let mut p = PlantConfig::ideal();
        p.sixbar.model = self.sixbar.model;
        p.description = format!("{} with only {effect}", self.description);
        let pairs = [
            (&mut p.drive_1, &self.drive_1),
            (&mut p.drive_2, &self.drive_2),
        ];
        match effect {
            PhysicalEffect::LinkGeometry => p.sixbar.errors = self.sixbar.errors.clone(),
            PhysicalEffect::Clearance => {
                p.sixbar.pin_clearance_mm = self.sixbar.pin_clearance_mm;
                p.sixbar.bar_end_clearance_mm = self.sixbar.bar_end_clearance_mm;
            }
            PhysicalEffect::EncoderOffset => pairs
                .into_iter()
                .for_each(|(d, s)| d.encoder_offset_deg = s.encoder_offset_deg),
            PhysicalEffect::EncoderQuantization => pairs.into_iter().for_each(|(d, s)| {
                d.encoder_counts_per_motor_rev = s.encoder_counts_per_motor_rev;
                d.gear_ratio = s.gear_ratio;
            }),
            PhysicalEffect::Backlash => pairs
                .into_iter()
                .for_each(|(d, s)| d.backlash_urad = s.backlash_urad),
            PhysicalEffect::CyclicError => pairs.into_iter().for_each(|(d, s)| {
                d.cyclic_error_urad = s.cyclic_error_urad;
                d.cyclic_error_cycles_per_motor_rev = s.cyclic_error_cycles_per_motor_rev;
                d.cyclic_error_phase_deg = s.cyclic_error_phase_deg;
                d.gear_ratio = s.gear_ratio;
            }),
            PhysicalEffect::Frame => {
                p.instrument.frame_offset_mm = self.instrument.frame_offset_mm;
                p.instrument.frame_rotation_deg = self.instrument.frame_rotation_deg;
            }
            PhysicalEffect::Scale => p.instrument.scale_error_ppm = self.instrument.scale_error_ppm,
            PhysicalEffect::InstrumentNoise => {
                p.instrument.noise_sigma_um = self.instrument.noise_sigma_um
            }
            PhysicalEffect::CoulombFriction => pairs
                .into_iter()
                .for_each(|(d, s)| d.coulomb_friction_nm = s.coulomb_friction_nm),
            PhysicalEffect::ViscousFriction => pairs.into_iter().for_each(|(d, s)| {
                d.viscous_friction_nm_s_per_rad = s.viscous_friction_nm_s_per_rad
            }),
            PhysicalEffect::MotorInertia => pairs
                .into_iter()
                .for_each(|(d, s)| d.inertia_kg_m2 = s.inertia_kg_m2),
            PhysicalEffect::TorqueConstant => pairs
                .into_iter()
                .for_each(|(d, s)| d.torque_constant_error_pct = s.torque_constant_error_pct),
            PhysicalEffect::Cogging => pairs.into_iter().for_each(|(d, s)| {
                d.cogging_nm = s.cogging_nm;
                d.cogging_cycles_per_motor_rev = s.cogging_cycles_per_motor_rev;
                d.cogging_phase_deg = s.cogging_phase_deg;
                d.gear_ratio = s.gear_ratio;
            }),
            PhysicalEffect::ToolMass => p.linkage.tool_mass_kg = self.linkage.tool_mass_kg,
            PhysicalEffect::LinkLengths
            | PhysicalEffect::BaseOffset
            | PhysicalEffect::LinkStretch
            | PhysicalEffect::ParallelogramMismatch
            | PhysicalEffect::GearRatio => {
                return Err(PlantError::NoSetting(effect));
            }
        }
        Ok(p)
    }
}

/// Masses of the six-bar's bodies (plant TOML section `[linkage]`; every value is optional in
/// the file, the defaults are the paper machine's). The bars' masses come from the density and
/// the `[sixbar]` sections and lengths; 0 everywhere switches the linkage's inertia off (the
/// drives' own inertia remains).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct LinkageConfig {
    /// Density of the bars (aluminium: 2700 kg/m³).
    pub bar_density_kg_per_m3: f64,
    /// Each elbow piece K1, K2 (translates with its elbow).
    pub elbow_piece_mass_kg: f64,
    /// The platform T without the tool.
    pub platform_mass_kg: f64,
    /// The tool on the platform.
    pub tool_mass_kg: f64,
}

impl Default for LinkageConfig {
    /// The paper machine: aluminium bars, 30 g elbow pieces, a 60 g platform with a 40 g tool.
    fn default() -> Self {
        LinkageConfig {
            bar_density_kg_per_m3: 2700.0,
            elbow_piece_mass_kg: 0.03,
            platform_mass_kg: 0.06,
            tool_mass_kg: 0.04,
        }
    }
}

impl LinkageConfig {
    /// No inertia in the linkage at all.
    pub fn massless() -> Self {
        LinkageConfig {
            bar_density_kg_per_m3: 0.0,
            elbow_piece_mass_kg: 0.0,
            platform_mass_kg: 0.0,
            tool_mass_kg: 0.0,
        }
    }

    /// The values that must not be negative, with their keys.
    pub fn non_negative(&self) -> [(&'static str, f64); 4] {
        [
            ("linkage.bar_density_kg_per_m3", self.bar_density_kg_per_m3),
            ("linkage.elbow_piece_mass_kg", self.elbow_piece_mass_kg),
            ("linkage.platform_mass_kg", self.platform_mass_kg),
            ("linkage.tool_mass_kg", self.tool_mass_kg),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_paper_toml_equals_builtin() {
        let file = PlantConfig::from_toml(PAPER_TOML).unwrap();
        assert_eq!(file, PlantConfig::paper());
    }

    #[test]
    fn toml_round_trip_and_unknown_keys_refused() {
        let p = PlantConfig::paper();
        assert_eq!(PlantConfig::from_toml(&p.to_toml()).unwrap(), p);
        let bad = PAPER_TOML.replace("backlash_urad", "backlash_urd");
        let err = PlantConfig::from_toml(&bad).unwrap_err().to_string();
        assert!(err.contains("backlash_urd"), "{err}");
        let neg = PAPER_TOML.replacen(
            "pin_stiffness_n_per_mm = 20000.0",
            "pin_stiffness_n_per_mm = -1.0",
            1,
        );
        assert!(PlantConfig::from_toml(&neg).is_err());
        assert!(PlantConfig::by_name("no-such-plant").is_err());
    }

    #[test]
    fn random_plants_are_reproducible_and_with_only_keeps_one_effect() {
        let a = PlantConfig::ideal().with_random_errors(7, 0.05, 0.1);
        let b = PlantConfig::ideal().with_random_errors(7, 0.05, 0.1);
        assert_eq!(a, b);
        assert_ne!(a, PlantConfig::ideal().with_random_errors(8, 0.05, 0.1));
        let only = PlantConfig::paper()
            .with_only(PhysicalEffect::Backlash)
            .unwrap();
        assert_eq!(only.drive_1.backlash_urad, 20.0);
        assert_eq!(only.sixbar.errors, SixBarErrors::default());
        assert_eq!(only.drive_1.encoder_offset_deg, 0.0);
        assert_eq!(
            PlantConfig::paper().with_only(PhysicalEffect::GearRatio),
            Err(PlantError::NoSetting(PhysicalEffect::GearRatio))
        );
    }
}
