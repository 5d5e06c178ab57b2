//! The effect library: the effects the diagnosis can name, each a small parametric extension
//! of the five-bar forward model with a physical meaning, their parameters in one flat vector,
//! and the nuisances fitted alongside them (never named). The forward function that applies any
//! subset of them is [`super::forward_model`].
//!
//! Why one flat parameter vector: every effect owns a fixed slice of [`N_PARAMS`] numbers;
//! inactive effects keep theirs at zero, so "the model with effects E" is just "the forward
//! function with only E's entries free". Internal units are chosen so every parameter is O(1..100)
//! (µm, µrad, ppm): the LM and its finite differences then need no scaling.
//!
//! Nuisances (not in the library, never named): when the residual shows a periodic error in a
//! motor angle (> 10 cycles/rev: a gear tooth) or a drift in time, the selection fits it in every
//! model so that no library effect is chosen on its account (`selection.rs`); it stays
//! `unexplained` in the report.

use crate::effect::PhysicalEffect;

/// Number of entries of the full parameter vector (library effects, then nuisances).
pub const N_PARAMS: usize = 32 + N_SHAPE;

/// Modes of a named effect's shape misfit (a nuisance, `diagnose::shape`).
pub const N_SHAPE: usize = 20;

/// Parameter names with units (index = position in the full vector).
#[rustfmt::skip]
pub const PARAM_NAMES: [&str; N_PARAMS] = [
    "da_um", "db_um", "dc_um", "dd_um",            // 0..4 link_lengths
    "dtheta1_urad", "dtheta2_urad",                // 4..6 encoder_offset
    "b0x_um", "b0y_um",                            // 6..8 base_offset
    "beta1_urad", "beta2_urad",                    // 8..10 backlash
    "ks1_um", "ks2_um", "ks3_um", "ks4_um", "ks5_um", // 10..15 link_stretch: self-stress modes (RMS stretch)
    "kc_compliance_pct",                           // 15 link_stretch: c's compliance beyond the design's, %
    "tx_um", "ty_um", "rot_urad",                  // 16..19 frame
    "scale_ppm",                                   // 19 scale
    "gear1_ppm", "gear2_ppm",                      // 20..22 gear_ratio
    "pm1_um", "pm2_um", "pm3_um", "pm4_um",        // 22..26 parallelogram_mismatch (RMS over the data)
    "cyclic1_cos_urad", "cyclic1_sin_urad",        // 26..28 nuisance: periodic error, motor 1
    "cyclic2_cos_urad", "cyclic2_sin_urad",        // 28..30 nuisance: periodic error, motor 2
    "drift_x_um_per_ks", "drift_y_um_per_ks",      // 30..32 nuisance: instrument drift
    // 32..52 nuisance: a named effect's shape misfit (modes, RMS displacement over the data)
    "misfit1_um", "misfit2_um", "misfit3_um", "misfit4_um", "misfit5_um",
    "misfit6_um", "misfit7_um", "misfit8_um", "misfit9_um", "misfit10_um",
    "misfit11_um", "misfit12_um", "misfit13_um", "misfit14_um", "misfit15_um",
    "misfit16_um", "misfit17_um", "misfit18_um", "misfit19_um", "misfit20_um",
];

/// Index ranges of the parameters.
pub mod idx {
    pub const LINKS: usize = 0;
    pub const OFFSETS: usize = 4;
    pub const BASE: usize = 6;
    pub const BACKLASH: usize = 8;
    pub const STRETCH: usize = 10;
    /// c's relative compliance (the last link_stretch parameter).
    pub const STRETCH_RATIO: usize = 15;
    pub const FRAME: usize = 16;
    pub const SCALE: usize = 19;
    pub const GEAR: usize = 20;
    pub const MISMATCH: usize = 22;
    pub const CYCLIC: usize = 26;
    pub const DRIFT: usize = 30;
    pub const SHAPE: usize = 32;
}

/// One candidate effect: a [`PhysicalEffect`] with its parameters in the extended forward model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Effect {
    /// Which effect (its name is the report's: the tests and other tools rely on it).
    pub kind: PhysicalEffect,
    /// Indices into the full parameter vector.
    pub params: &'static [usize],
    /// Physical meaning, for the report.
    pub meaning: &'static str,
    /// The effect needs the dir1/dir2 columns.
    pub needs_dir: bool,
}

/// The library, in a fixed order (ties in the selection go to the earlier one).
pub const LIBRARY: [Effect; 9] = [
    Effect {
        kind: PhysicalEffect::LinkLengths,
        params: &[0, 1, 2, 3],
        meaning: "a, b, c, d differ from the model (manufacturing, assembly)",
        needs_dir: false,
    },
    Effect {
        kind: PhysicalEffect::EncoderOffset,
        params: &[4, 5],
        meaning: "motor zero offsets (encoder index not at the model's zero)",
        needs_dir: false,
    },
    Effect { kind: PhysicalEffect::BaseOffset, params: &[6, 7], meaning: "B0 is not where the model has it", needs_dir: false },
    Effect {
        kind: PhysicalEffect::Backlash,
        params: &[8, 9],
        meaning: "lost motion per motor: the link lags the encoder by beta/2 against the approach direction",
        needs_dir: true,
    },
    Effect {
        kind: PhysicalEffect::LinkStretch,
        params: &[10, 11, 12, 13, 14, 15],
        meaning: "the distal bars' elastic elongation under the overconstrained loops' self-stress, a function of the \
                  absolute link angles (theta1, theta2): the self-stress modes of the six-bar's linearised loop closure \
                  (ks: RMS stretch over the data, um), both bars by the one self-stress, c's compliance relative to b's \
                  free around the design's (kc_compliance_pct)",
        needs_dir: false,
    },
    Effect {
        kind: PhysicalEffect::Frame,
        params: &[16, 17, 18],
        meaning: "instrument frame offset (x, y) and rotation about A0",
        needs_dir: false,
    },
    Effect { kind: PhysicalEffect::Scale, params: &[19], meaning: "instrument scale error (about A0)", needs_dir: false },
    Effect {
        kind: PhysicalEffect::GearRatio,
        params: &[20, 21],
        meaning: "transmission ratio error per motor: link angle = encoder angle scaled by (1+g) about the data's mean angle \
                  (the constant part stays encoder_offset)",
        needs_dir: false,
    },
    Effect {
        kind: PhysicalEffect::ParallelogramMismatch,
        params: &[22, 23, 24, 25],
        meaning: "the six-bar's parallelograms disagree (follower and pin errors): the platform and elbow pieces turn and \
                  the bearings yield with the configuration; four dominant tool-displacement modes of the linearised loop \
                  closure that no constant five-bar parameter reproduces (pm: RMS displacement over the data, um)",
        needs_dir: false,
    },
];

impl Effect {
    /// The effect's name ([`PhysicalEffect::name`]).
    pub const fn name(&self) -> &'static str {
        self.kind.name()
    }
}

/// The parameters of `effects`, in order.
pub fn params_of(effects: &[&Effect]) -> Vec<usize> {
    effects
        .iter()
        .flat_map(|e| e.params.iter().copied())
        .collect()
}

/// The `candidates` not in `set`, in order.
pub fn outside(candidates: &[&'static Effect], set: &[&'static Effect]) -> Vec<&'static Effect> {
    candidates
        .iter()
        .copied()
        .filter(|c| !set.contains(c))
        .collect()
}

/// Looks an effect up by its exact name.
pub fn effect(name: &str) -> Option<&'static Effect> {
    LIBRARY.iter().find(|e| e.name() == name)
}

/// Structures outside the library fitted alongside it (see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Nuisance {
    /// Periodic error of each motor: cycles per revolution of the motor angle.
    pub cyclic_cycles: [Option<f64>; 2],
    /// A linear drift of the readings in time.
    pub drift: bool,
    /// The shape misfit of a named effect: which effect, and how many modes (`Point::shape_um`).
    pub shape: Option<(PhysicalEffect, usize)>,
}

impl Nuisance {
    /// The parameters the nuisances add to every fit.
    pub fn params(&self) -> Vec<usize> {
        let mut p = Vec::new();
        for j in 0..2 {
            if self.cyclic_cycles[j].is_some() {
                p.extend([idx::CYCLIC + 2 * j, idx::CYCLIC + 2 * j + 1]);
            }
        }
        if self.drift {
            p.extend([idx::DRIFT, idx::DRIFT + 1]);
        }
        if let Some((_, k)) = self.shape {
            p.extend(idx::SHAPE..idx::SHAPE + k.min(N_SHAPE));
        }
        p
    }

    pub fn is_empty(&self) -> bool {
        self.params().is_empty()
    }
}

/// The five-bar's constant parameters (the span the mismatch modes are made orthogonal to):
/// link lengths, encoder offsets, base offset, frame, scale.
pub const FIVE_BAR_SPAN: [usize; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19];
