//! The hidden robot: a planar five-bar whose end point moves like the real six-bar's tool point.
//!
//! ```text
//!                 A ●─────── b ───────╮
//!                  ╱                   ● C = (x, y)   tool point
//!              a  ╱ θ1                ╱
//!                ╱                   c
//!   A0 ●────────── x          B ●───╯
//!      ╲ B0 (= A0 + base_b0_mm) ╱
//!       ╲ θ2               d ╱
//!        ╰──────────────────╯
//! ```
//! Proximal link `a` turns about A0 by motor 1, proximal link `d` about B0 by motor 2; distal
//! links `b` (A to C) and `c` (B to C) meet at the tool point C. In the paper's machine A0 and B0
//! coincide at the origin and a = b = c = d = 150 mm.
//!
//! The frame is the one targets and measurements are given in (the instrument's, after
//! calibration). A0 may sit anywhere in it (`base_a0_mm`), so the hidden robot absorbs every
//! rigid error of that frame: a translation moves A0 (and B0 with it), a rotation about A0 is a
//! common encoder offset. A common scale of the instrument is a common scale of all lengths.
//!
//! Angles: every motor angle here is an *encoder* angle, what the motor's encoder reads and what
//! the servo commands. The geometric angle of a proximal link from the x axis is
//! `encoder angle + encoder_offset_rad`, so a model with offsets maps encoder readings to
//! positions directly and the calibration can fit the offsets.

use crate::real::Real;

/// One of the two solutions of a two-circle problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Branch {
    /// The `+` solution (see [`WorkingMode`] for what it means for each choice).
    Positive,
    /// The `-` solution.
    Negative,
}

impl Branch {
    /// `+1` or `-1` in the scalar type.
    pub fn sign<T: Real>(self) -> T {
        match self {
            Branch::Positive => T::ONE,
            Branch::Negative => -T::ONE,
        }
    }
}

/// Which of the (up to) four inverse and two forward solutions the machine is assembled in.
///
/// * `elbow_1`: motor 1's angle is `φ1 + α1` (`Positive`) or `φ1 - α1` (`Negative`), where `φ1`
///   is the direction from A0 to C and `α1 ∈ [0, π]` the angle between A0C and link a.
/// * `elbow_2`: the same for motor 2, about B0.
/// * `assembly`: C lies to the left of the line A→B (`Positive`) or to its right.
///
/// The paper's machine (Table I: C at x > 0, θ1 > θ2) is `elbow_1 = Positive`,
/// `elbow_2 = Negative`, `assembly = Positive`: the arms open like a V towards +x with both elbows
/// pointing outwards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WorkingMode {
    /// Elbow of arm 1 (motor 1's angle `φ1 ± α1`).
    pub elbow_1: Branch,
    /// Elbow of arm 2 (motor 2's angle `φ2 ± α2`).
    pub elbow_2: Branch,
    /// Side of the line A→B the tool point lies on (`Positive`: left).
    pub assembly: Branch,
}

impl WorkingMode {
    /// The working mode of the paper's machine.
    pub const PAPER: WorkingMode = WorkingMode {
        elbow_1: Branch::Positive,
        elbow_2: Branch::Negative,
        assembly: Branch::Positive,
    };

    /// The mode as three flag bits (bit 0 elbow 1, bit 1 elbow 2, bit 2 assembly; set for
    /// `Positive`): how the calibration image and the machine record store it.
    pub(crate) fn to_flags(self) -> u32 {
        let bit = |b: Branch, n: u32| if b == Branch::Positive { 1 << n } else { 0 };
        bit(self.elbow_1, 0) | bit(self.elbow_2, 1) | bit(self.assembly, 2)
    }

    /// The mode from the low three bits of `flags` ([`Self::to_flags`]; other bits ignored).
    pub(crate) fn from_flags(flags: u32) -> Self {
        let branch = |bit: u32| {
            if flags & (1 << bit) != 0 {
                Branch::Positive
            } else {
                Branch::Negative
            }
        };
        WorkingMode {
            elbow_1: branch(0),
            elbow_2: branch(1),
            assembly: branch(2),
        }
    }
}

/// The five-bar's parameters: everything the calibration can identify.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FiveBar<T> {
    /// Proximal link of motor 1, A0 to A.
    pub a_mm: T,
    /// Distal link of arm 1, A to C.
    pub b_mm: T,
    /// Distal link of arm 2, B to C.
    pub c_mm: T,
    /// Proximal link of motor 2, B0 to B.
    pub d_mm: T,
    /// Position of A0 in the machine frame.
    pub base_a0_mm: [T; 2],
    /// Position of B0 relative to A0.
    pub base_b0_mm: [T; 2],
    /// Geometric angle minus encoder angle, per motor.
    pub encoder_offset_rad: [T; 2],
    /// Which inverse and forward solution the machine is assembled in.
    pub mode: WorkingMode,
}

/// Why a set of model parameters cannot describe a machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModelError {
    /// A parameter is NaN or infinite.
    NonFinite,
    /// A link length is zero or negative.
    NonPositiveLink,
}

impl core::fmt::Display for ModelError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ModelError::NonFinite => f.write_str("a model parameter is not finite"),
            ModelError::NonPositiveLink => f.write_str("a link length is not positive"),
        }
    }
}

impl core::error::Error for ModelError {}

impl<T: Real> FiveBar<T> {
    /// The paper's nominal machine: a = b = c = d = 150 mm, coincident bases, no offsets.
    pub fn paper_nominal() -> Self {
        let l = T::from_f64(150.0);
        FiveBar {
            a_mm: l,
            b_mm: l,
            c_mm: l,
            d_mm: l,
            base_a0_mm: [T::ZERO; 2],
            base_b0_mm: [T::ZERO; 2],
            encoder_offset_rad: [T::ZERO; 2],
            mode: WorkingMode::PAPER,
        }
    }

    /// Checks that every parameter is finite and every link positive.
    pub fn validate(&self) -> Result<(), ModelError> {
        let all = [
            self.a_mm,
            self.b_mm,
            self.c_mm,
            self.d_mm,
            self.base_a0_mm[0],
            self.base_a0_mm[1],
            self.base_b0_mm[0],
            self.base_b0_mm[1],
            self.encoder_offset_rad[0],
            self.encoder_offset_rad[1],
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        if [self.a_mm, self.b_mm, self.c_mm, self.d_mm]
            .iter()
            .any(|&l| l <= T::ZERO)
        {
            return Err(ModelError::NonPositiveLink);
        }
        Ok(())
    }

    /// Whether all four links are positive (false for a NaN link): the one model check IK and
    /// FK make on every call (four comparisons, 7 instructions of the IK on the Cortex-M4F;
    /// [`crate::ValidFiveBar`] makes it once, with the rest of [`Self::validate`]). A
    /// negative link is what it must catch: the law of cosines would square it into a wrong
    /// but finite answer.
    #[inline(always)]
    pub(crate) fn links_positive(&self) -> bool {
        self.a_mm > T::ZERO && self.b_mm > T::ZERO && self.c_mm > T::ZERO && self.d_mm > T::ZERO
    }

    /// The error for a model [`Self::links_positive`] refused: what [`Self::validate`] names.
    #[cold]
    pub(crate) fn invalid_model(&self) -> crate::KinematicsError {
        crate::KinematicsError::InvalidModel(
            self.validate().err().unwrap_or(ModelError::NonPositiveLink),
        )
    }

    /// The same model in another scalar type (rounding to nearest).
    pub fn cast<U: Real>(&self) -> FiveBar<U> {
        let c = |v: T| U::from_f64(v.to_f64());
        FiveBar {
            a_mm: c(self.a_mm),
            b_mm: c(self.b_mm),
            c_mm: c(self.c_mm),
            d_mm: c(self.d_mm),
            base_a0_mm: [c(self.base_a0_mm[0]), c(self.base_a0_mm[1])],
            base_b0_mm: [c(self.base_b0_mm[0]), c(self.base_b0_mm[1])],
            encoder_offset_rad: [c(self.encoder_offset_rad[0]), c(self.encoder_offset_rad[1])],
            mode: self.mode,
        }
    }
}
