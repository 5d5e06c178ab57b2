//! Why an image was refused for a machine: the typed answers of the judgements, each naming
//! what differs with both values, so a refusal on the controller and in the host tools says the
//! same thing.

use super::record::{MachineName, RecordError};
use crate::model::{Branch, WorkingMode};

/// One parameter of the hidden robot, as the machine file and `model.json` name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModelParameter {
    /// Link a (mm).
    A,
    /// Link b (mm).
    B,
    /// Link c (mm).
    C,
    /// Link d (mm).
    D,
    /// A0's x (mm).
    A0X,
    /// A0's y (mm).
    A0Y,
    /// B0's x relative to A0 (mm).
    B0X,
    /// B0's y relative to A0 (mm).
    B0Y,
    /// Motor 1's encoder offset (rad).
    Offset1,
    /// Motor 2's encoder offset (rad).
    Offset2,
}

impl ModelParameter {
    /// Every parameter, in the order of [`crate::FiveBar`]'s fields.
    pub const ALL: [ModelParameter; 10] = [
        ModelParameter::A,
        ModelParameter::B,
        ModelParameter::C,
        ModelParameter::D,
        ModelParameter::A0X,
        ModelParameter::A0Y,
        ModelParameter::B0X,
        ModelParameter::B0Y,
        ModelParameter::Offset1,
        ModelParameter::Offset2,
    ];

    /// Its name with its unit.
    pub fn name(self) -> &'static str {
        match self {
            ModelParameter::A => "a_mm",
            ModelParameter::B => "b_mm",
            ModelParameter::C => "c_mm",
            ModelParameter::D => "d_mm",
            ModelParameter::A0X => "a0_x_mm",
            ModelParameter::A0Y => "a0_y_mm",
            ModelParameter::B0X => "b0_x_mm (relative to A0)",
            ModelParameter::B0Y => "b0_y_mm (relative to A0)",
            ModelParameter::Offset1 => "encoder_offset_1_rad",
            ModelParameter::Offset2 => "encoder_offset_2_rad",
        }
    }

    /// The parameter's value in `m`.
    pub fn of(self, m: &crate::FiveBar<f32>) -> f32 {
        let mut copy = *m;
        *self.field(&mut copy)
    }

    /// `m` with this parameter set to `value`.
    pub fn set(self, m: &crate::FiveBar<f32>, value: f32) -> crate::FiveBar<f32> {
        let mut out = *m;
        *self.field(&mut out) = value;
        out
    }

    fn field(self, m: &mut crate::FiveBar<f32>) -> &mut f32 {
        match self {
            ModelParameter::A => &mut m.a_mm,
            ModelParameter::B => &mut m.b_mm,
            ModelParameter::C => &mut m.c_mm,
            ModelParameter::D => &mut m.d_mm,
            ModelParameter::A0X => &mut m.base_a0_mm[0],
            ModelParameter::A0Y => &mut m.base_a0_mm[1],
            ModelParameter::B0X => &mut m.base_b0_mm[0],
            ModelParameter::B0Y => &mut m.base_b0_mm[1],
            ModelParameter::Offset1 => &mut m.encoder_offset_rad[0],
            ModelParameter::Offset2 => &mut m.encoder_offset_rad[1],
        }
    }
}

/// One parameter that alone explains a difference: its value in the image and on the controller.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParameterDifference {
    /// Which.
    pub parameter: ModelParameter,
    /// The image's model's value.
    pub image: f32,
    /// The controller's nominal value.
    pub controller: f32,
}

/// Why an image's model is not a model of this machine.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MachineMismatch {
    /// The image carries another machine's record (its geometry's digest differs).
    OtherRecord {
        /// The image's machine.
        image_name: MachineName,
        /// Its digest.
        image_digest: u32,
        /// The controller's machine.
        controller_name: MachineName,
        /// Its digest.
        controller_digest: u32,
    },
    /// Another working mode: the IK would choose another solution (a mirrored pose).
    WorkingMode {
        /// The image's model's.
        image: WorkingMode,
        /// The controller's.
        controller: WorkingMode,
    },
    /// The tool positions differ beyond the tolerance in the best-fitting rigid frame.
    Geometry {
        /// The largest distance (mm) between the image's and the nominal's tool positions.
        worst_mm: f32,
        /// Where (mm, a workspace point).
        at_mm: [f32; 2],
        /// The record's tolerance (mm).
        tolerance_mm: f32,
        /// The one parameter that, set to the controller's value, brings the model within the
        /// tolerance, if there is one.
        parameter: Option<ParameterDifference>,
    },
    /// At the nominal's joint angles for a workspace point the image's model has no pose.
    Unreachable {
        /// The workspace point (mm).
        at_mm: [f32; 2],
        /// As in [`MachineMismatch::Geometry`].
        parameter: Option<ParameterDifference>,
    },
}

/// Why an image of this machine is not a plausible calibration of it (limits:
/// [`super::PlausibilityLimits`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Implausible {
    /// The home position lies outside the image's grid.
    HomeOutsideGrid {
        /// The record's home (mm).
        home_mm: [f32; 2],
    },
    /// A vertex of the image's workspace lies outside the machine's.
    Workspace {
        /// The vertex (mm).
        vertex_mm: [f32; 2],
        /// How far outside (mm).
        outside_mm: f32,
    },
    /// A drive's lost motion beyond the limit.
    Backlash {
        /// Motor 0 or 1.
        axis: u8,
        /// The image's (rad).
        image_rad: f32,
        /// The limit (rad).
        limit_rad: f32,
    },
    /// The image's model has no pose (or a singular one) at a grid node or workspace point.
    Unreachable {
        /// The point (mm).
        at_mm: [f32; 2],
    },
    /// A node's correction moves the tool too far.
    NodeCorrection {
        /// The node `(i, j)`.
        node: [u16; 2],
        /// The tool displacement of its correction (mm).
        correction_mm: f32,
        /// The limit (mm).
        limit_mm: f32,
    },
    /// Two neighbouring nodes' corrections differ too much for their distance.
    CorrectionSlope {
        /// The node `(i, j)`.
        node: [u16; 2],
        /// Its neighbour.
        neighbour: [u16; 2],
        /// The difference's tool displacement per mm between them.
        slope: f32,
        /// The limit.
        limit: f32,
    },
    /// The record's own nominal dynamics have no positive-definite mass matrix at a workspace
    /// point (the record cannot judge dynamics there).
    NominalDynamics {
        /// The point (mm).
        at_mm: [f32; 2],
    },
    /// The image's mass matrix is not positive definite at a workspace point.
    MassMatrix {
        /// The point (mm).
        at_mm: [f32; 2],
    },
    /// The kinetic energy of some joint motion is beyond the factor of the nominal's.
    Inertia {
        /// The point (mm).
        at_mm: [f32; 2],
        /// The image's energy over the nominal's for the worst motion there.
        ratio: f32,
        /// The limit (either way).
        factor: f32,
    },
    /// A friction parameter beyond the factor times the nominal's, or a Coulomb speed beyond
    /// the factor of it.
    Friction {
        /// The parameter (`crate::dynamics::PARAMETER_NAMES`, or `coulomb_speed_rad_s`).
        parameter: &'static str,
        /// The image's value.
        image: f32,
        /// The nominal's value.
        nominal: f32,
        /// The factor.
        factor: f32,
    },
}

/// Why the controller refuses an image that parses.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageRefusal {
    /// Built for another machine.
    OtherMachine(MachineMismatch),
    /// For this machine, but not a plausible calibration of it.
    Implausible(Implausible),
    /// The machine record the image is judged against does not validate.
    Record(RecordError),
}

fn mode_name(m: WorkingMode) -> (&'static str, &'static str, &'static str) {
    let s = |b: Branch| if b == Branch::Positive { "+" } else { "-" };
    (s(m.elbow_1), s(m.elbow_2), s(m.assembly))
}

impl core::fmt::Display for ParameterDifference {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} explains it: image {:.4}, controller {:.4}",
            self.parameter.name(),
            self.image,
            self.controller
        )
    }
}

impl core::fmt::Display for MachineMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MachineMismatch::OtherRecord {
                image_name,
                image_digest,
                controller_name,
                controller_digest,
            } => write!(
                f,
                "the image was built for machine '{image_name}' (digest {image_digest:08x}); this is machine '{controller_name}' (digest {controller_digest:08x})"
            ),
            MachineMismatch::WorkingMode { image, controller } => {
                let (i, c) = (mode_name(*image), mode_name(*controller));
                write!(
                    f,
                    "the image's working mode (elbow 1, elbow 2, assembly) is ({}, {}, {}), this machine's ({}, {}, {})",
                    i.0, i.1, i.2, c.0, c.1, c.2
                )
            }
            MachineMismatch::Geometry {
                worst_mm,
                at_mm,
                tolerance_mm,
                parameter,
            } => {
                write!(
                    f,
                    "the image's model is another machine: its tool positions differ from this machine's nominal by up to {worst_mm:.3} mm (at ({:.1}, {:.1}) mm, in the best-fitting rigid frame; tolerance {tolerance_mm} mm)",
                    at_mm[0], at_mm[1]
                )?;
                match parameter {
                    Some(p) => write!(f, "; {p}"),
                    None => f.write_str("; no single parameter explains it"),
                }
            }
            MachineMismatch::Unreachable { at_mm, parameter } => {
                write!(
                    f,
                    "the image's model is another machine: at this machine's joint angles for ({:.1}, {:.1}) mm it has no pose",
                    at_mm[0], at_mm[1]
                )?;
                match parameter {
                    Some(p) => write!(f, "; {p}"),
                    None => Ok(()),
                }
            }
        }
    }
}

impl core::fmt::Display for Implausible {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Implausible::HomeOutsideGrid { home_mm } => write!(
                f,
                "the home position ({}, {}) mm lies outside the image's grid",
                home_mm[0], home_mm[1]
            ),
            Implausible::Workspace {
                vertex_mm,
                outside_mm,
            } => write!(
                f,
                "the image's workspace vertex ({}, {}) mm lies {outside_mm:.3} mm outside this machine's workspace",
                vertex_mm[0], vertex_mm[1]
            ),
            Implausible::Backlash {
                axis,
                image_rad,
                limit_rad,
            } => write!(
                f,
                "the image's backlash of motor {} is {:.1} µrad, the limit {:.1} µrad",
                axis + 1,
                image_rad * 1e6,
                limit_rad * 1e6
            ),
            Implausible::Unreachable { at_mm } => write!(
                f,
                "the image's model has no pose at ({:.3}, {:.3}) mm",
                at_mm[0], at_mm[1]
            ),
            Implausible::NodeCorrection {
                node,
                correction_mm,
                limit_mm,
            } => write!(
                f,
                "the correction of grid node ({}, {}) moves the tool by {correction_mm:.3} mm, the limit is {limit_mm} mm",
                node[0], node[1]
            ),
            Implausible::CorrectionSlope {
                node,
                neighbour,
                slope,
                limit,
            } => write!(
                f,
                "the corrections of grid nodes ({}, {}) and ({}, {}) differ by {slope:.4} mm per mm at the tool, the limit is {limit}: moving between them would command a step",
                node[0], node[1], neighbour[0], neighbour[1]
            ),
            Implausible::NominalDynamics { at_mm } => write!(
                f,
                "the machine record's nominal dynamics have no positive-definite mass matrix at ({:.1}, {:.1}) mm",
                at_mm[0], at_mm[1]
            ),
            Implausible::MassMatrix { at_mm } => write!(
                f,
                "the image's dynamics have no positive-definite mass matrix at ({:.1}, {:.1}) mm",
                at_mm[0], at_mm[1]
            ),
            Implausible::Inertia {
                at_mm,
                ratio,
                factor,
            } => {
                write!(
                    f,
                    "the image's dynamics give a joint motion at ({:.1}, {:.1}) mm ",
                    at_mm[0], at_mm[1]
                )?;
                if *ratio >= 1e4 || *ratio < 1e-3 {
                    write!(f, "{ratio:.3e}")?;
                } else {
                    write!(f, "{ratio:.4}")?;
                }
                write!(
                    f,
                    " times the nominal kinetic energy, the limit is a factor {factor} either way"
                )
            }
            Implausible::Friction {
                parameter,
                image,
                nominal,
                factor,
            } => write!(
                f,
                "the image's {parameter} is {image:e}, the nominal {nominal:e}: beyond the factor {factor}"
            ),
        }
    }
}

impl core::fmt::Display for ImageRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ImageRefusal::OtherMachine(e) => write!(f, "{e}"),
            ImageRefusal::Implausible(e) => write!(f, "implausible calibration image: {e}"),
            ImageRefusal::Record(e) => write!(f, "cannot judge the image: {e}"),
        }
    }
}

impl core::error::Error for MachineMismatch {}
impl core::error::Error for Implausible {}
impl core::error::Error for ImageRefusal {}
