//! Typed errors of the kinematics: every way a pose can be refused.

/// Which kind of singularity a pose is too close to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Singularity {
    /// A proximal and its distal link are (nearly) aligned: the arm is stretched or folded, the
    /// tool point cannot move along that arm and the inverse Jacobian blows up. The workspace
    /// boundary.
    Serial,
    /// The two distal links are (nearly) aligned: the motors cannot hold the tool point across
    /// that line, the forward Jacobian blows up and the assembly mode can flip.
    Parallel,
}

/// Why the kinematics refused a pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KinematicsError {
    /// An input (or the model) holds a NaN or an infinity.
    NonFinite,
    /// Inverse: the target is out of an arm's reach, or reachable only in another assembly
    /// mode. Forward: the distal links cannot meet.
    Unreachable,
    /// The pose is within the caller's margin of a singularity, or within the type's floor of
    /// one whatever the margin (`Real::IK_MIN_TRANSMISSION`, `Real::FK_MIN_TRANSMISSION`) (a singular pose is never a solution).
    NearSingularity(Singularity),
    /// The model cannot describe a machine (a link that is not positive, a parameter that is
    /// not finite): IK and FK refuse to compute with it rather than return angles whose FK is
    /// another point.
    InvalidModel(crate::model::ModelError),
}

impl core::fmt::Display for KinematicsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            KinematicsError::NonFinite => f.write_str("non-finite input"),
            KinematicsError::Unreachable => f.write_str("pose out of reach"),
            KinematicsError::NearSingularity(Singularity::Serial) => {
                f.write_str("too close to a serial singularity (an arm stretched or folded)")
            }
            KinematicsError::NearSingularity(Singularity::Parallel) => {
                f.write_str("too close to a parallel singularity (distal links aligned)")
            }
            KinematicsError::InvalidModel(e) => write!(f, "invalid model: {e}"),
        }
    }
}

impl core::error::Error for KinematicsError {}
