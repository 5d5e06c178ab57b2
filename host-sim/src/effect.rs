//! The physical effects, named once: the plant's settings ([`crate::plant::PlantConfig::with_only`])
//! and the diagnosis' library ([`crate::diagnose::library::LIBRARY`]) speak this vocabulary, and
//! its names are the strings of `diagnose`'s JSON report (a contract: `steps[].effect`,
//! `confounded`, ...).
//!
//! | effect | name | in the plant (`plants/*.toml`) | in the diagnosis library |
//! |---|---|---|---|
//! | [`LinkLengths`](PhysicalEffect::LinkLengths) | `link_lengths` | part of `link_geometry` | a, b, c, d |
//! | [`EncoderOffset`](PhysicalEffect::EncoderOffset) | `encoder_offset` | `drive_*.encoder_offset_deg` | δθ1, δθ2 |
//! | [`BaseOffset`](PhysicalEffect::BaseOffset) | `base_offset` | part of `link_geometry` | B0 |
//! | [`Backlash`](PhysicalEffect::Backlash) | `backlash` | `drive_*.backlash_urad` | β1, β2 |
//! | [`LinkStretch`](PhysicalEffect::LinkStretch) | `link_stretch` | arises from `link_geometry` and the bars' compliance | b, c vs (θ1, θ2): the distal bars' elongation under the loops' self-stress |
//! | [`Frame`](PhysicalEffect::Frame) | `frame` | `instrument.frame_offset_mm`, `frame_rotation_deg` | tx, ty, rot |
//! | [`Scale`](PhysicalEffect::Scale) | `scale` | `instrument.scale_error_ppm` | scale |
//! | [`GearRatio`](PhysicalEffect::GearRatio) | `gear_ratio` | — | g1, g2 |
//! | [`ParallelogramMismatch`](PhysicalEffect::ParallelogramMismatch) | `parallelogram_mismatch` | arises from `link_geometry` (followers' and pins' errors) | the loops' misfit: platform and elbow rotations, bearing deflections vs (θ1, θ2) |
//! | [`LinkGeometry`](PhysicalEffect::LinkGeometry) | `link_geometry` | `sixbar.errors` (every bar length and pin) | shows up as the above: link lengths, base offset, stretch, mismatch |
//! | [`Clearance`](PhysicalEffect::Clearance) | `clearance` | `sixbar.*_clearance_mm` | — |
//! | [`EncoderQuantization`](PhysicalEffect::EncoderQuantization) | `encoder_quantization` | `drive_*.encoder_counts_per_motor_rev` | — |
//! | [`CyclicError`](PhysicalEffect::CyclicError) | `cyclic_error` | `drive_*.cyclic_error_*` | — (reported as unexplained, periodic) |
//! | [`InstrumentNoise`](PhysicalEffect::InstrumentNoise) | `instrument_noise` | `instrument.noise_sigma_um` | the noise σ |
//! | [`CoulombFriction`](PhysicalEffect::CoulombFriction) | `coulomb_friction` | `drive_*.coulomb_friction_nm` | the moving machine's (`dynamics::effects`): τc1, τc2 |
//! | [`ViscousFriction`](PhysicalEffect::ViscousFriction) | `viscous_friction` | `drive_*.viscous_friction_nm_s_per_rad` | moving: b1, b2 |
//! | [`ToolMass`](PhysicalEffect::ToolMass) | `tool_mass` | `linkage.tool_mass_kg` | moving: the mass at the tool point |
//! | [`MotorInertia`](PhysicalEffect::MotorInertia) | `motor_inertia` | `drive_*.inertia_kg_m2` | moving: I1, I2 |
//! | [`TorqueConstant`](PhysicalEffect::TorqueConstant) | `torque_constant` | `drive_*.torque_constant_error_pct` | moving: k1, k2 |
//! | [`Cogging`](PhysicalEffect::Cogging) | `cogging` | `drive_*.cogging_*` | moving: amplitude and phase per motor |
//!
//! Where a change goes: a new effect is a variant here (name, row above), its setting in
//! `plant/config.rs` if the plant has it, its entry in `diagnose/library.rs` if the diagnosis
//! can name it.

use serde::Serialize;

/// One physical effect (see the module doc's table).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PhysicalEffect {
    /// The hidden robot's link lengths a, b, c, d differ from the model's.
    LinkLengths,
    /// The motors' zero offsets (encoder index not at the model's zero).
    EncoderOffset,
    /// B0 is not where the model has it.
    BaseOffset,
    /// Lost motion in each drive: the link lags the motor by half of it.
    Backlash,
    /// Configuration-dependent distal link lengths (internal stress of the overconstrained loops).
    LinkStretch,
    /// The six-bar's parallelograms disagree: the platform and elbow pieces turn with the
    /// configuration (no five-bar has it).
    ParallelogramMismatch,
    /// The instrument's frame: offset and rotation.
    Frame,
    /// The instrument's scale error.
    Scale,
    /// A transmission-ratio error per motor.
    GearRatio,
    /// The six-bar's manufacturing errors: every bar length and every pin position.
    LinkGeometry,
    /// Radial clearance of the elbow bearings and axial play of the bars' end pins.
    Clearance,
    /// The encoders' finite resolution.
    EncoderQuantization,
    /// Gear-tooth (periodic) error of a motor's transmission.
    CyclicError,
    /// The instrument's Gaussian noise.
    InstrumentNoise,
    /// Coulomb friction at a motor the dynamics model lacks.
    CoulombFriction,
    /// Viscous friction at a motor the dynamics model lacks.
    ViscousFriction,
    /// A mass at the tool point the dynamics model lacks (a heavier tool or payload).
    ToolMass,
    /// An error of a motor's inertia (rotor and gearbox).
    MotorInertia,
    /// A motor delivering another torque per command than the controller assumes.
    TorqueConstant,
    /// A torque ripple periodic in a motor's angle.
    Cogging,
}

impl PhysicalEffect {
    /// Every effect, in the order of the module doc's table.
    pub const ALL: [PhysicalEffect; 20] = [
        PhysicalEffect::LinkLengths,
        PhysicalEffect::EncoderOffset,
        PhysicalEffect::BaseOffset,
        PhysicalEffect::Backlash,
        PhysicalEffect::LinkStretch,
        PhysicalEffect::ParallelogramMismatch,
        PhysicalEffect::Frame,
        PhysicalEffect::Scale,
        PhysicalEffect::GearRatio,
        PhysicalEffect::LinkGeometry,
        PhysicalEffect::Clearance,
        PhysicalEffect::EncoderQuantization,
        PhysicalEffect::CyclicError,
        PhysicalEffect::InstrumentNoise,
        PhysicalEffect::CoulombFriction,
        PhysicalEffect::ViscousFriction,
        PhysicalEffect::ToolMass,
        PhysicalEffect::MotorInertia,
        PhysicalEffect::TorqueConstant,
        PhysicalEffect::Cogging,
    ];

    /// The name (reports, files, the diagnosis' JSON).
    pub const fn name(self) -> &'static str {
        match self {
            PhysicalEffect::LinkLengths => "link_lengths",
            PhysicalEffect::EncoderOffset => "encoder_offset",
            PhysicalEffect::BaseOffset => "base_offset",
            PhysicalEffect::Backlash => "backlash",
            PhysicalEffect::LinkStretch => "link_stretch",
            PhysicalEffect::ParallelogramMismatch => "parallelogram_mismatch",
            PhysicalEffect::Frame => "frame",
            PhysicalEffect::Scale => "scale",
            PhysicalEffect::GearRatio => "gear_ratio",
            PhysicalEffect::LinkGeometry => "link_geometry",
            PhysicalEffect::Clearance => "clearance",
            PhysicalEffect::EncoderQuantization => "encoder_quantization",
            PhysicalEffect::CyclicError => "cyclic_error",
            PhysicalEffect::InstrumentNoise => "instrument_noise",
            PhysicalEffect::CoulombFriction => "coulomb_friction",
            PhysicalEffect::ViscousFriction => "viscous_friction",
            PhysicalEffect::ToolMass => "tool_mass",
            PhysicalEffect::MotorInertia => "motor_inertia",
            PhysicalEffect::TorqueConstant => "torque_constant",
            PhysicalEffect::Cogging => "cogging",
        }
    }

    /// The effect of a name.
    pub fn from_name(name: &str) -> Option<PhysicalEffect> {
        PhysicalEffect::ALL.into_iter().find(|e| e.name() == name)
    }
}

impl std::fmt::Display for PhysicalEffect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_serialize_as_named() {
        for e in PhysicalEffect::ALL {
            assert_eq!(PhysicalEffect::from_name(e.name()), Some(e));
            assert_eq!(
                serde_json::to_value(e).unwrap(),
                serde_json::json!(e.name())
            );
        }
        assert_eq!(PhysicalEffect::from_name("links"), None);
    }
}
