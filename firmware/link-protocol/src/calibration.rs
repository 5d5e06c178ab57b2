//! What the link says about calibration images: the machine a controller drives
//! ([`MachineId`], in `Identity`), and why an upload was refused ([`CalibrationRefusal`], with
//! the parameter and its values: [`ImageParameter`]). Each refusal prints as a sentence
//! (`Display`), so the host tool and a log say the same thing.
use serde::{Deserialize, Serialize};

/// Bytes of a machine name on the wire (the machine record's name field).
pub const MACHINE_NAME_LEN: usize = 16;

/// A machine as the controller knows it: the name and the digest of its machine record
/// (`kinematics_core::machine::MachineRecord`; the digest is the CRC-32C of its geometry, what
/// makes two machine files the same machine).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MachineId {
    /// The name: 1..=16 printable ASCII bytes, then zeros.
    pub name: [u8; MACHINE_NAME_LEN],
    /// `MachineRecord::digest` of its geometry.
    pub digest: u32,
}

impl MachineId {
    /// The machine named `name` (cut at [`MACHINE_NAME_LEN`] bytes) with `digest`.
    pub fn new(name: &str, digest: u32) -> Self {
        let mut bytes = [0u8; MACHINE_NAME_LEN];
        let n = name.len().min(MACHINE_NAME_LEN);
        bytes[..n].copy_from_slice(&name.as_bytes()[..n]);
        MachineId {
            name: bytes,
            digest,
        }
    }

    /// The name up to its first zero; `"?"` if those bytes are not UTF-8 (a controller never
    /// sends such a name: the record refuses anything but printable ASCII).
    pub fn name(&self) -> &str {
        let len = self
            .name
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(MACHINE_NAME_LEN);
        core::str::from_utf8(&self.name[..len]).unwrap_or("?")
    }
}

impl core::fmt::Display for MachineId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "machine '{}' (digest {:08x})", self.name(), self.digest)
    }
}

/// Why a calibration upload was refused. The image in force stays in force.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalibrationRefusal {
    /// No upload was begun.
    NotBegun,
    /// Longer than [`crate::MAX_CALIBRATION_IMAGE_LEN`] or empty.
    Length,
    /// A chunk's offset is not the bytes received so far.
    Offset,
    /// More bytes than announced, or commit before all arrived.
    Incomplete,
    /// The image's header, CRC or format is invalid.
    Invalid,
    /// The image's model is not a model of this machine, judged by the tool positions over
    /// the workspace in the best-fitting rigid frame (`kinematics_core::machine::same_machine`).
    /// `parameter` is, in this order of preference:
    /// * [`ImageParameter::WorkingMode`]: the working modes differ (`image`, `machine`: the
    ///   modes as flags, bit 0 elbow 1, bit 1 elbow 2, bit 2 assembly, set when positive;
    ///   `tolerance` 0);
    /// * a model parameter (a link, a base coordinate, an encoder offset): the one parameter
    ///   that, set to this machine's value, brings the image's model within the tolerance:
    ///   `image` is its value in the image, `machine` this machine's nominal; `tolerance` is
    ///   the same-machine tolerance (mm of tool position), not a bound on the parameter (NaN
    ///   when the image's model has no pose at this machine's joint angles);
    /// * [`ImageParameter::ToolPositionMm`]: no single parameter explains it: `image` is the
    ///   largest tool-position difference (mm; infinite where the image's model has no pose at
    ///   this machine's joint angles, the tolerance then NaN), `machine` 0, `tolerance` the
    ///   same-machine tolerance.
    OtherMachine {
        /// What differs.
        parameter: ImageParameter,
        /// The image's value (the parameter's unit).
        image: f32,
        /// This machine's.
        machine: f32,
        /// The same-machine tolerance (see the variant).
        tolerance: f32,
    },
    /// The image carries another machine's record (`HRMC`): its digest is not the one of the
    /// machine this controller drives. Flash that machine's commissioning image to make the
    /// controller that machine, or upload an image of this one.
    OtherRecord {
        /// The image's machine.
        image: MachineId,
        /// The controller's.
        controller: MachineId,
    },
    /// The image is this machine's but carries something no calibration of it can need:
    /// `parameter` is `value`, beyond `limit` (docs/reference/calibration-image.md).
    Implausible {
        /// What is out of bounds.
        parameter: ImageParameter,
        /// Its value (the parameter's unit).
        value: f32,
        /// The bound it exceeds (below it for the lower bounds: the inertia ratio, the Coulomb
        /// speed).
        limit: f32,
    },
    /// The image is this machine's but fails a check at a point: `parameter` (one of
    /// [`ImageParameter::HomePosition`], [`ImageParameter::ModelPose`],
    /// [`ImageParameter::MassMatrix`], [`ImageParameter::NominalDynamics`]) at `at_mm`.
    ImplausibleAt {
        /// What fails there.
        parameter: ImageParameter,
        /// The point (mm).
        at_mm: [f32; 2],
    },
    /// Writing the flash failed.
    Flash,
    /// Not while the drives are on and moving.
    Busy,
    /// A committed image is waiting for the servo to switch to it (at the next rest): a new
    /// upload would erase the slot the servo still uses. Bring the machine to rest (or reset a
    /// held fault) and begin again once [`Identify`](crate::Command::Identify) reports the new
    /// id.
    SwitchPending,
}

/// What of a calibration image a refusal names ([`CalibrationRefusal`]); units in the names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageParameter {
    /// The working mode (elbows and assembly branch as flags: bit 0 elbow 1, bit 1 elbow 2,
    /// bit 2 assembly, set when positive).
    WorkingMode,
    /// Link `a` (mm).
    LinkAMm,
    /// Link `b` (mm).
    LinkBMm,
    /// Link `c` (mm).
    LinkCMm,
    /// Link `d` (mm).
    LinkDMm,
    /// Base A0, x (mm).
    BaseA0XMm,
    /// Base A0, y (mm).
    BaseA0YMm,
    /// Base B0 relative to A0, x (mm).
    BaseB0XMm,
    /// Base B0 relative to A0, y (mm).
    BaseB0YMm,
    /// Encoder offset of joint 1 (rad).
    EncoderOffset1Rad,
    /// Encoder offset of joint 2 (rad).
    EncoderOffset2Rad,
    /// The largest distance between the image's model's tool positions and the nominal's over
    /// the workspace, in the best-fitting rigid frame (mm).
    ToolPositionMm,
    /// The home position, outside the image's grid.
    HomePosition,
    /// How far a vertex of the image's workspace lies outside the machine's (mm).
    WorkspaceOutsideMm,
    /// Backlash of a drive (rad).
    BacklashRad,
    /// Viscous friction of a drive (N·m·s/rad).
    ViscousNmSPerRad,
    /// Coulomb friction of a drive (N·m).
    CoulombNm,
    /// The speed below which Coulomb friction is smoothed (rad/s).
    CoulombSpeedRadS,
    /// The image's mass matrix, not positive definite there.
    MassMatrix,
    /// The machine record's own nominal dynamics, without a positive-definite mass matrix
    /// there (the record cannot judge the image's dynamics).
    NominalDynamics,
    /// The kinetic energy of the worst joint motion under the image's dynamics over the
    /// nominal's (a ratio; the limit is the dynamics factor, or its inverse from below).
    InertiaRatio,
    /// The image's model has no pose (or a singular one) there: a grid node or a workspace
    /// point.
    ModelPose,
    /// A node's correction, as the tool displacement it makes (mm).
    NodeCorrectionMm,
    /// The change of that displacement between neighbouring nodes per millimetre between them.
    CorrectionSlope,
    /// The largest change of the correction's slope from one cell to the next (rad/mm): what a
    /// move across the grid at the servo's top speed turns into a step of the reference speed.
    SlopeChangeRadPerMm,
}

impl ImageParameter {
    /// Its name in messages, with the unit.
    pub fn name(self) -> &'static str {
        match self {
            ImageParameter::WorkingMode => "the working mode",
            ImageParameter::LinkAMm => "a_mm",
            ImageParameter::LinkBMm => "b_mm",
            ImageParameter::LinkCMm => "c_mm",
            ImageParameter::LinkDMm => "d_mm",
            ImageParameter::BaseA0XMm => "a0_x_mm",
            ImageParameter::BaseA0YMm => "a0_y_mm",
            ImageParameter::BaseB0XMm => "b0_x_mm (relative to A0)",
            ImageParameter::BaseB0YMm => "b0_y_mm (relative to A0)",
            ImageParameter::EncoderOffset1Rad => "encoder_offset_1_rad",
            ImageParameter::EncoderOffset2Rad => "encoder_offset_2_rad",
            ImageParameter::ToolPositionMm => "the tool-position difference (mm)",
            ImageParameter::HomePosition => "the home position",
            ImageParameter::WorkspaceOutsideMm => {
                "a workspace vertex's distance outside the machine's workspace (mm)"
            }
            ImageParameter::BacklashRad => "a drive's backlash (rad)",
            ImageParameter::ViscousNmSPerRad => "a drive's viscous friction (N·m·s/rad)",
            ImageParameter::CoulombNm => "a drive's Coulomb friction (N·m)",
            ImageParameter::CoulombSpeedRadS => "the Coulomb speed (rad/s)",
            ImageParameter::MassMatrix => "the dynamics' mass matrix",
            ImageParameter::NominalDynamics => "the machine record's nominal dynamics",
            ImageParameter::InertiaRatio => {
                "the kinetic energy of a joint motion over the nominal's"
            }
            ImageParameter::ModelPose => "the image's model",
            ImageParameter::NodeCorrectionMm => "a node's correction at the tool (mm)",
            ImageParameter::CorrectionSlope => {
                "the correction's change between neighbouring nodes (mm per mm)"
            }
            ImageParameter::SlopeChangeRadPerMm => {
                "the correction's slope change from one cell to the next (rad/mm)"
            }
        }
    }
}

/// `(elbow 1, elbow 2, assembly)` of working-mode flags, as `+` / `-`.
fn mode(flags: f32) -> [char; 3] {
    let bits = flags as u32;
    [0, 1, 2].map(|k| if bits & (1 << k) != 0 { '+' } else { '-' })
}

impl core::fmt::Display for CalibrationRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            CalibrationRefusal::NotBegun => f.write_str("no upload was begun"),
            CalibrationRefusal::Length => f.write_str("the image's length is not one a slot holds"),
            CalibrationRefusal::Offset => {
                f.write_str("a chunk's offset is not the bytes received so far")
            }
            CalibrationRefusal::Incomplete => {
                f.write_str("more bytes than announced, or a commit before all arrived")
            }
            CalibrationRefusal::Invalid => {
                f.write_str("the image's header, CRC or format is invalid")
            }
            CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::WorkingMode,
                image,
                machine,
                ..
            } => {
                let (i, m) = (mode(image), mode(machine));
                write!(
                    f,
                    "another machine's image: its working mode (elbow 1, elbow 2, assembly) is ({}, {}, {}), this machine's ({}, {}, {})",
                    i[0], i[1], i[2], m[0], m[1], m[2]
                )
            }
            CalibrationRefusal::OtherMachine {
                parameter: ImageParameter::ToolPositionMm,
                image,
                tolerance,
                ..
            } => {
                if image.is_finite() {
                    write!(
                        f,
                        "another machine's image: its model's tool positions differ from this machine's nominal by up to {image:.3} mm in the best-fitting rigid frame (tolerance {tolerance} mm); no single parameter explains it"
                    )
                } else {
                    f.write_str(
                        "another machine's image: at this machine's joint angles its model has no pose",
                    )
                }
            }
            CalibrationRefusal::OtherMachine {
                parameter,
                image,
                machine,
                tolerance,
            } => {
                write!(
                    f,
                    "another machine's image: {} is {image:.4} in the image, {machine:.4} on this machine",
                    parameter.name()
                )?;
                if tolerance.is_finite() {
                    write!(
                        f,
                        " (set to this machine's value, the model would be within the same-machine tolerance of {tolerance} mm)"
                    )?;
                }
                Ok(())
            }
            CalibrationRefusal::OtherRecord { image, controller } => write!(
                f,
                "the image was built for {image}; this controller is {controller}"
            ),
            CalibrationRefusal::Implausible {
                parameter,
                value,
                limit,
            } => write!(
                f,
                "implausible image: {} is {value:e}, the limit {limit:e}",
                parameter.name()
            ),
            CalibrationRefusal::ImplausibleAt { parameter, at_mm } => {
                let what = match parameter {
                    ImageParameter::HomePosition => "lies outside the image's grid",
                    ImageParameter::ModelPose => "has no pose",
                    ImageParameter::MassMatrix => "is not positive definite",
                    ImageParameter::NominalDynamics => "has no positive-definite mass matrix",
                    _ => "fails",
                };
                write!(
                    f,
                    "implausible image: {} {what} at ({:.3}, {:.3}) mm",
                    parameter.name(),
                    at_mm[0],
                    at_mm[1]
                )
            }
            CalibrationRefusal::Flash => f.write_str("writing the flash failed"),
            CalibrationRefusal::Busy => f.write_str("the machine is moving"),
            CalibrationRefusal::SwitchPending => f.write_str(
                "a committed image waits for the servo to switch to it at the next rest",
            ),
        }
    }
}
