//! The calibrations the servo samples with: [`Calibration`] (a model and its grid, the model
//! checked on every IK) and [`ValidCalibration`] (the model checked once), both
//! [`ServoCalibration`]s; each kind's entry points are functions of its own (see the sealed
//! trait).
use crate::backlash::Backlash;
use crate::feed_forward::JointSample;
use crate::grid::CorrectionGrid;
use crate::model::{FiveBar, ModelError};
use crate::trajectory::MotionSetpoint;
use crate::valid_model::{IkMargin, ValidFiveBar};
use crate::KinematicsError;

use super::{
    finite2, AcceptedSetpoint, EngageError, Servo, ServoOutput, SetpointRefusal, StepError,
};

/// The hidden robot and (optionally) its correction grid: what a calibration delivers.
#[derive(Clone, Copy, Debug)]
pub struct Calibration<'a> {
    /// The fitted hidden robot.
    pub model: FiveBar<f32>,
    /// Joint corrections over the workspace; `None` runs the model uncorrected.
    pub grid: Option<CorrectionGrid<'a>>,
}

impl<'a> Calibration<'a> {
    /// The model and grid of a validated image.
    pub fn from_grid(grid: CorrectionGrid<'a>) -> Self {
        Calibration {
            model: *grid.model(),
            grid: Some(grid),
        }
    }

    /// Encoder angles that put the tool at `tool_mm`: model IK plus grid correction. This is the
    /// one function that turns a target into a motor command, on the MCU and in the host tools.
    /// ([`Servo::accept_motion`] keeps the model's angle from the IK it solved for the setpoint a
    /// sample earlier, and corrects it with [`Calibration::corrected_rad`].)
    #[inline(always)]
    pub fn command_rad(
        &self,
        tool_mm: [f32; 2],
        min_transmission: f32,
    ) -> Result<[f32; 2], SetpointRefusal> {
        let theta = self
            .model
            .inverse(tool_mm, min_transmission)
            .map_err(SetpointRefusal::Kinematics)?;
        self.corrected_rad(tool_mm, theta)
    }

    /// Where the tool is at the encoder reading `encoder_rad` by this calibration (mm): the
    /// model's FK with the correction undone by one fixed-point step, `FK(θ - δ(FK(θ)))` (the
    /// correction varies over millimetres, so the second pass is exact to well below a
    /// micrometre), at least `min_transmission` from a singularity. What [`Servo::engage`]
    /// engages at, computed without touching a servo: a caller can see whether a calibration
    /// would engage, and where, before switching to it.
    pub fn tool_mm(
        &self,
        encoder_rad: [f32; 2],
        min_transmission: f32,
    ) -> Result<[f32; 2], EngageError> {
        if !finite2(encoder_rad) {
            return Err(EngageError::NonFiniteFeedback);
        }
        let mut tool = self
            .model
            .forward(encoder_rad, 0.0)
            .map_err(EngageError::Kinematics)?;
        if let Some(grid) = &self.grid {
            let d = grid.correction_rad(tool).map_err(EngageError::Grid)?;
            tool = self
                .model
                .forward(
                    [encoder_rad[0] - d[0], encoder_rad[1] - d[1]],
                    min_transmission,
                )
                .map_err(EngageError::Kinematics)?;
        }
        Ok(tool)
    }

    /// The drives' lost motion the servo compensates: the image's backlash block, if the grid
    /// carries one ([`CorrectionGrid::backlash`]).
    #[inline(always)]
    pub fn backlash(&self) -> Option<Backlash<f32>> {
        self.grid.as_ref().and_then(|g| g.backlash().copied())
    }

    /// The model's encoder angles `theta_rad` for `tool_mm` plus the grid correction there.
    pub fn corrected_rad(
        &self,
        tool_mm: [f32; 2],
        theta_rad: [f32; 2],
    ) -> Result<[f32; 2], SetpointRefusal> {
        corrected_rad(self.grid.as_ref(), tool_mm, theta_rad)
    }
}

/// `theta_rad` plus the grid's correction at `tool_mm` (none without a grid).
#[inline(always)]
fn corrected_rad(
    grid: Option<&CorrectionGrid<'_>>,
    tool_mm: [f32; 2],
    theta_rad: [f32; 2],
) -> Result<[f32; 2], SetpointRefusal> {
    match grid {
        None => Ok(theta_rad),
        Some(grid) => {
            let d = grid
                .correction_rad(tool_mm)
                .map_err(SetpointRefusal::Grid)?;
            Ok([theta_rad[0] + d[0], theta_rad[1] + d[1]])
        }
    }
}

/// A [`Calibration`] whose model passed [`FiveBar::validate`] when it was built: the servo's
/// IK per sample (every entry point, [`ServoCalibration`]) then skips the model check and the
/// margin floor the [`Calibration`] path repeats on every call (the angles
/// are bit-identical). Its fields are private: an invalid model cannot be put in one.
#[derive(Clone, Copy, Debug)]
pub struct ValidCalibration<'a> {
    model: ValidFiveBar<f32>,
    grid: Option<CorrectionGrid<'a>>,
}

impl<'a> ValidCalibration<'a> {
    /// `cal` if its model is valid ([`FiveBar::validate`]), else the reason.
    pub fn new(cal: Calibration<'a>) -> Result<Self, ModelError> {
        Ok(ValidCalibration {
            model: ValidFiveBar::new(cal.model)?,
            grid: cal.grid,
        })
    }

    /// The model and grid of a validated image (its parser validated the model).
    pub fn from_grid(grid: CorrectionGrid<'a>) -> Self {
        ValidCalibration {
            model: *grid.valid_model(),
            grid: Some(grid),
        }
    }

    /// The checked model.
    pub fn model(&self) -> &ValidFiveBar<f32> {
        &self.model
    }

    /// The correction grid, if any.
    pub fn grid(&self) -> Option<&CorrectionGrid<'a>> {
        self.grid.as_ref()
    }

    /// The lost motion the servo compensates (the grid's backlash block), if any.
    pub fn backlash(&self) -> Option<Backlash<f32>> {
        self.grid.as_ref().and_then(|g| g.backlash().copied())
    }

    /// The same calibration as a plain [`Calibration`] (for [`Servo::engage`] and the
    /// functions that take one).
    pub fn calibration(&self) -> Calibration<'a> {
        Calibration {
            model: *self.model.model(),
            grid: self.grid,
        }
    }

    /// [`Calibration::command_rad`] with the model and margin checked once.
    #[inline(always)]
    pub fn command_rad(
        &self,
        tool_mm: [f32; 2],
        margin: IkMargin<f32>,
    ) -> Result<[f32; 2], SetpointRefusal> {
        let theta = self
            .model
            .inverse(tool_mm, margin)
            .map_err(SetpointRefusal::Kinematics)?;
        corrected_rad(self.grid.as_ref(), tool_mm, theta)
    }
}

/// A calibration the servo samples with: [`Calibration`] (its model checked on every IK) or
/// [`ValidCalibration`] (checked once when it was built). Each servo entry point
/// ([`Servo::accept`], [`Servo::accept_motion`], [`Servo::step`], [`Servo::step_motion`]) takes
/// either; the step is one generic implementation, monomorphised for each kind. Sealed: what a
/// sample needs of it is the crate's business.
pub trait ServoCalibration: sealed::SampleModel {}

impl ServoCalibration for Calibration<'_> {}
impl ServoCalibration for ValidCalibration<'_> {}

mod sealed {
    use super::super::{AcceptedSetpoint, Servo, ServoOutput, SetpointRefusal, StepError};
    use super::{IkMargin, JointSample, KinematicsError, MotionSetpoint};

    /// What the servo's sample needs of a calibration.
    pub trait SampleModel {
        /// IK plus grid correction for a target [`super::Servo::check_sequence`] passed (so
        /// finite: the IK need not test it again).
        fn command_rad_of_finite(
            &self,
            tool_mm: [f32; 2],
            margin: IkMargin<f32>,
        ) -> Result<[f32; 2], SetpointRefusal>;
        /// The joint state at `setpoint`, in place.
        fn solve_joint(
            &self,
            slot: &mut JointSample<f32>,
            setpoint: &MotionSetpoint<f32>,
            margin: IkMargin<f32>,
        ) -> Result<(), KinematicsError>;
        /// The grid correction added to the model's angles.
        fn corrected_rad(
            &self,
            tool_mm: [f32; 2],
            theta_rad: [f32; 2],
        ) -> Result<[f32; 2], SetpointRefusal>;
        /// [`super::Servo::accept`] with this calibration: a function of each kind's own
        /// (compiled in this crate, as the step's cost figures are measured).
        fn accept<'s>(
            &self,
            servo: &'s mut Servo,
            setpoint_mm: [f32; 2],
        ) -> Result<AcceptedSetpoint<'s>, SetpointRefusal>;
        /// [`super::Servo::accept_motion`] with this calibration.
        fn accept_motion<'s>(
            &self,
            servo: &'s mut Servo,
            setpoint: &MotionSetpoint<f32>,
            next: Option<&MotionSetpoint<f32>>,
        ) -> Result<AcceptedSetpoint<'s>, SetpointRefusal>;
        /// [`super::Servo::step`] with this calibration.
        fn step(
            &self,
            servo: &mut Servo,
            setpoint_mm: [f32; 2],
            encoder_rad: [f32; 2],
        ) -> Result<ServoOutput, StepError>;
        /// [`super::Servo::step_motion`] with this calibration.
        fn step_motion(
            &self,
            servo: &mut Servo,
            setpoint: &MotionSetpoint<f32>,
            next: Option<&MotionSetpoint<f32>>,
            encoder_rad: [f32; 2],
        ) -> Result<ServoOutput, StepError>;
    }
}
pub(super) use sealed::SampleModel;

/// The four entry points of one calibration kind, as functions of its own, and its grid
/// correction (both kinds keep their grid in a field `grid`).
macro_rules! entry_points {
    () => {
        #[inline(always)]
        fn corrected_rad(
            &self,
            tool_mm: [f32; 2],
            theta_rad: [f32; 2],
        ) -> Result<[f32; 2], SetpointRefusal> {
            corrected_rad(self.grid.as_ref(), tool_mm, theta_rad)
        }
        fn accept<'s>(
            &self,
            servo: &'s mut Servo,
            setpoint_mm: [f32; 2],
        ) -> Result<AcceptedSetpoint<'s>, SetpointRefusal> {
            servo.accept_with(self, setpoint_mm)
        }
        fn accept_motion<'s>(
            &self,
            servo: &'s mut Servo,
            setpoint: &MotionSetpoint<f32>,
            next: Option<&MotionSetpoint<f32>>,
        ) -> Result<AcceptedSetpoint<'s>, SetpointRefusal> {
            servo.accept_motion_with(self, setpoint, next)
        }
        fn step(
            &self,
            servo: &mut Servo,
            setpoint_mm: [f32; 2],
            encoder_rad: [f32; 2],
        ) -> Result<ServoOutput, StepError> {
            SampleModel::accept(self, servo, setpoint_mm)
                .map_err(StepError::Refused)?
                .track(encoder_rad)
                .map_err(StepError::Fault)
        }
        fn step_motion(
            &self,
            servo: &mut Servo,
            setpoint: &MotionSetpoint<f32>,
            next: Option<&MotionSetpoint<f32>>,
            encoder_rad: [f32; 2],
        ) -> Result<ServoOutput, StepError> {
            SampleModel::accept_motion(self, servo, setpoint, next)
                .map_err(StepError::Refused)?
                .track(encoder_rad)
                .map_err(StepError::Fault)
        }
    };
}

impl SampleModel for Calibration<'_> {
    entry_points!();
    #[inline(always)]
    fn command_rad_of_finite(
        &self,
        tool_mm: [f32; 2],
        margin: IkMargin<f32>,
    ) -> Result<[f32; 2], SetpointRefusal> {
        // `FiveBar::inverse` raises the margin to its floor again (the same value) and checks
        // the model and the target, as it always did on this path.
        Calibration::command_rad(self, tool_mm, margin.get())
    }
    #[inline(always)]
    fn solve_joint(
        &self,
        slot: &mut JointSample<f32>,
        setpoint: &MotionSetpoint<f32>,
        margin: IkMargin<f32>,
    ) -> Result<(), KinematicsError> {
        slot.solve(&self.model, setpoint, margin.get())
    }
}

impl SampleModel for ValidCalibration<'_> {
    entry_points!();
    #[inline(always)]
    fn command_rad_of_finite(
        &self,
        tool_mm: [f32; 2],
        margin: IkMargin<f32>,
    ) -> Result<[f32; 2], SetpointRefusal> {
        let theta = self
            .model
            .inverse_of_finite(tool_mm, margin)
            .map_err(SetpointRefusal::Kinematics)?;
        corrected_rad(self.grid.as_ref(), tool_mm, theta)
    }
    #[inline(always)]
    fn solve_joint(
        &self,
        slot: &mut JointSample<f32>,
        setpoint: &MotionSetpoint<f32>,
        margin: IkMargin<f32>,
    ) -> Result<(), KinematicsError> {
        slot.solve_valid(&self.model, setpoint, margin)
    }
}
