//! An image's refusal on the link: the machine's judgement (`kinematics_core::machine`) and the
//! servo's own check ([`crate::plausibility`]) mapped onto the link's [`CalibrationRefusal`],
//! each with the parameter and its values, so that the host tool can say what differs with
//! the numbers (`link_protocol`'s `Display` of the refusal). The controller's defmt log keeps
//! the whole refusal (the node, the point).
use kinematics_core::machine::{
    ImageRefusal, Implausible, MachineMismatch, MachineRecord, ModelParameter,
    WORKSPACE_TOLERANCE_MM,
};
use kinematics_core::{Branch, WorkingMode};
use link_protocol::{CalibrationRefusal, ImageParameter, MachineId};

use crate::calibration::ImageError;

/// A machine record as `Identify` and the refusals name it.
pub fn machine_id(record: &MachineRecord) -> MachineId {
    MachineId::new(record.name.as_str(), record.digest())
}

/// The link's parameter of a model parameter.
fn model_parameter(p: ModelParameter) -> ImageParameter {
    match p {
        ModelParameter::A => ImageParameter::LinkAMm,
        ModelParameter::B => ImageParameter::LinkBMm,
        ModelParameter::C => ImageParameter::LinkCMm,
        ModelParameter::D => ImageParameter::LinkDMm,
        ModelParameter::A0X => ImageParameter::BaseA0XMm,
        ModelParameter::A0Y => ImageParameter::BaseA0YMm,
        ModelParameter::B0X => ImageParameter::BaseB0XMm,
        ModelParameter::B0Y => ImageParameter::BaseB0YMm,
        ModelParameter::Offset1 => ImageParameter::EncoderOffset1Rad,
        ModelParameter::Offset2 => ImageParameter::EncoderOffset2Rad,
    }
}

/// A working mode as the link's flags (bit 0 elbow 1, bit 1 elbow 2, bit 2 assembly, set when
/// positive; the image header's convention).
fn mode_flags(m: WorkingMode) -> f32 {
    let bit = |b: Branch, k: u32| if b == Branch::Positive { 1u32 << k } else { 0 };
    (bit(m.elbow_1, 0) | bit(m.elbow_2, 1) | bit(m.assembly, 2)) as f32
}

/// The link's refusal of an image the controller refused (module doc).
pub fn image_refusal(e: &ImageError) -> CalibrationRefusal {
    match e {
        ImageError::Grid(_) => CalibrationRefusal::Invalid,
        ImageError::Refused(ImageRefusal::OtherMachine(m)) => other_machine(m),
        ImageError::Refused(ImageRefusal::Implausible(i)) => implausible(i),
        // The record judged against does not validate: the image's own, which its parse
        // would have refused, so not a case a committed upload meets.
        ImageError::Refused(ImageRefusal::Record(_)) => CalibrationRefusal::Invalid,
        ImageError::SlopeChange(s) => CalibrationRefusal::Implausible {
            parameter: ImageParameter::SlopeChangeRadPerMm,
            value: s.value_rad_per_mm,
            limit: s.limit_rad_per_mm,
        },
    }
}

fn other_machine(m: &MachineMismatch) -> CalibrationRefusal {
    let explained = |p: &kinematics_core::machine::ParameterDifference, tolerance: f32| {
        CalibrationRefusal::OtherMachine {
            parameter: model_parameter(p.parameter),
            image: p.image,
            machine: p.controller,
            tolerance,
        }
    };
    match *m {
        MachineMismatch::OtherRecord {
            image_name,
            image_digest,
            controller_name,
            controller_digest,
        } => CalibrationRefusal::OtherRecord {
            image: MachineId::new(image_name.as_str(), image_digest),
            controller: MachineId::new(controller_name.as_str(), controller_digest),
        },
        MachineMismatch::WorkingMode { image, controller } => CalibrationRefusal::OtherMachine {
            parameter: ImageParameter::WorkingMode,
            image: mode_flags(image),
            machine: mode_flags(controller),
            tolerance: 0.0,
        },
        MachineMismatch::Geometry {
            worst_mm,
            tolerance_mm,
            parameter,
            ..
        } => match parameter {
            Some(p) => explained(&p, tolerance_mm),
            None => CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::ToolPositionMm,
                image: worst_mm,
                machine: 0.0,
                tolerance: tolerance_mm,
            },
        },
        // No pose at this machine's joint angles: no deviation to give, and the judgement does
        // not carry its tolerance here (NaN: not printed).
        MachineMismatch::Unreachable { parameter, .. } => match parameter {
            Some(p) => explained(&p, f32::NAN),
            None => CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::ToolPositionMm,
                image: f32::INFINITY,
                machine: 0.0,
                tolerance: f32::NAN,
            },
        },
    }
}

fn implausible(i: &Implausible) -> CalibrationRefusal {
    let beyond = |parameter, value, limit| CalibrationRefusal::Implausible {
        parameter,
        value,
        limit,
    };
    let at = |parameter, at_mm| CalibrationRefusal::ImplausibleAt { parameter, at_mm };
    match *i {
        Implausible::HomeOutsideGrid { home_mm } => at(ImageParameter::HomePosition, home_mm),
        Implausible::Workspace { outside_mm, .. } => beyond(
            ImageParameter::WorkspaceOutsideMm,
            outside_mm,
            WORKSPACE_TOLERANCE_MM,
        ),
        Implausible::Backlash {
            image_rad,
            limit_rad,
            ..
        } => beyond(ImageParameter::BacklashRad, image_rad, limit_rad),
        Implausible::Unreachable { at_mm } => at(ImageParameter::ModelPose, at_mm),
        Implausible::NodeCorrection {
            correction_mm,
            limit_mm,
            ..
        } => beyond(ImageParameter::NodeCorrectionMm, correction_mm, limit_mm),
        Implausible::CorrectionSlope { slope, limit, .. } => {
            beyond(ImageParameter::CorrectionSlope, slope, limit)
        }
        Implausible::NominalDynamics { at_mm } => at(ImageParameter::NominalDynamics, at_mm),
        Implausible::MassMatrix { at_mm } => at(ImageParameter::MassMatrix, at_mm),
        Implausible::Inertia { ratio, factor, .. } => {
            // Below the range: the bound it falls short of is the factor's inverse.
            let limit = if ratio < 1.0 { 1.0 / factor } else { factor };
            beyond(ImageParameter::InertiaRatio, ratio, limit)
        }
        Implausible::Friction {
            parameter,
            image,
            nominal,
            factor,
        } => {
            if parameter.starts_with("coulomb_speed") {
                let limit = if image < nominal {
                    nominal / factor
                } else {
                    nominal * factor
                };
                beyond(ImageParameter::CoulombSpeedRadS, image, limit)
            } else if parameter.starts_with("viscous") {
                beyond(ImageParameter::ViscousNmSPerRad, image, nominal * factor)
            } else {
                beyond(ImageParameter::CoulombNm, image, nominal * factor)
            }
        }
    }
}
