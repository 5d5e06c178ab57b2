//! The calibration in force, with everything the servo loop derives from it, built in one
//! place ([`ActiveCalibration::new`]) and engaged as one ([`ActiveCalibration::engage`]): the
//! model checked once for the servo's IK ([`ValidCalibration`]), the identified dynamics the
//! motion step feeds forward, the workspace a stop must end in, the backlash the reference
//! compensates. A switch replaces the whole value; nothing of it is kept in step by hand.
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{
    AcceptedSetpoint, Calibration, EngageError, FiveBarDynamics, Servo, ServoOutput,
    SetpointRefusal, StepError, ValidCalibration,
};

use crate::settings::Settings;
use crate::stop::{MotionState, StopLimits, StopProfile, Workspace};

/// The calibration in force and what the servo loop derives from it (module doc).
#[derive(Clone, Copy, Debug)]
pub struct ActiveCalibration<'a> {
    calibration: Calibration<'a>,
    /// `calibration` with its model checked once, what the servo's samples use (its IK then
    /// repeats no model check). `None` when the model is invalid: the samples then go through
    /// `calibration`, whose IK refuses it on every call.
    valid: Option<ValidCalibration<'a>>,
    /// The identified dynamics the image carries (validated when it was parsed).
    dynamics: Option<FiveBarDynamics<f32>>,
    /// Where a stop may end: the image's workspace polygon (or, without one, the machine's
    /// where the grid covers it, else the grid's rectangle) less the machine's stop margin (`None`: no grid, running uncorrected; then only the servo's
    /// reach and singularity checks bound a stop).
    workspace: Option<Workspace>,
    /// The grid's rectangle less the margin, where the machine may stand at power-on: the
    /// starts homing's plan is checked from (`[x0, x1, y0, y1]`, mm).
    homing_rectangle_mm: Option<[f32; 4]>,
    /// The servo's singularity margin (`ServoConfig::min_transmission`).
    min_transmission: f32,
}

impl<'a> ActiveCalibration<'a> {
    /// Everything `calibration` implies under `settings`.
    pub fn new(calibration: Calibration<'a>, settings: &Settings) -> Self {
        let margin_mm = settings.stop.workspace_margin_mm;
        let grid = calibration.grid.as_ref();
        let homing_rectangle_mm = grid
            .and_then(|g| Workspace::of_grid(g.geometry(), margin_mm))
            .map(|w| {
                let ([x0, x1], [y0, y1]) = w.region().bounds_mm();
                [
                    x0 + margin_mm,
                    x1 - margin_mm,
                    y0 + margin_mm,
                    y1 - margin_mm,
                ]
            });
        ActiveCalibration {
            calibration,
            valid: ValidCalibration::new(calibration).ok(),
            dynamics: grid.and_then(|g| g.dynamics().copied()),
            workspace: grid.and_then(|g| {
                Workspace::of_machine_image(g, &settings.machine.workspace.region, margin_mm)
            }),
            homing_rectangle_mm,
            min_transmission: settings.servo.min_transmission,
        }
    }

    /// The model and grid.
    pub fn calibration(&self) -> &Calibration<'a> {
        &self.calibration
    }

    /// Where a stop may end (`None`: uncorrected, no grid).
    pub fn workspace(&self) -> Option<Workspace> {
        self.workspace
    }

    /// The rectangle homing's plan is checked over (`None`: no grid).
    pub fn homing_rectangle_mm(&self) -> Option<[f32; 4]> {
        self.homing_rectangle_mm
    }

    /// Where the tool is at `encoder_rad` by this calibration: where [`Self::engage`] would
    /// engage, without touching a servo.
    pub fn tool_mm(&self, encoder_rad: [f32; 2]) -> Result<[f32; 2], EngageError> {
        self.calibration.tool_mm(encoder_rad, self.min_transmission)
    }

    /// Arms `servo` at `encoder_rad` with this calibration: its dynamics fed forward, its
    /// backlash compensated (taken by `Servo::engage`), its tool position returned.
    pub fn engage(
        &self,
        servo: &mut Servo,
        encoder_rad: [f32; 2],
    ) -> Result<[f32; 2], EngageError> {
        // Validated when the image was parsed; `set_dynamics` checks again and keeps none if
        // not (the gains' constant feed-forward then).
        let _ = servo.set_dynamics(self.dynamics);
        servo.engage(&self.calibration, encoder_rad)
    }

    /// [`Servo::accept_motion`] with this calibration (the checked model when there is one).
    #[inline]
    pub fn accept_motion<'s>(
        &self,
        servo: &'s mut Servo,
        setpoint: &MotionSetpoint<f32>,
        ahead: Option<&MotionSetpoint<f32>>,
    ) -> Result<AcceptedSetpoint<'s>, SetpointRefusal> {
        match &self.valid {
            Some(valid) => servo.accept_motion(valid, setpoint, ahead),
            None => servo.accept_motion(&self.calibration, setpoint, ahead),
        }
    }

    /// [`Servo::step`] with this calibration (the checked model when there is one).
    #[inline]
    pub fn step(
        &self,
        servo: &mut Servo,
        setpoint_mm: [f32; 2],
        encoder_rad: [f32; 2],
    ) -> Result<ServoOutput, StepError> {
        match &self.valid {
            Some(valid) => servo.step(valid, setpoint_mm, encoder_rad),
            None => servo.step(&self.calibration, setpoint_mm, encoder_rad),
        }
    }

    /// Whether the controlled stop from `state` ends inside the workspace (always, without one).
    #[inline]
    pub fn stop_ends_inside(&self, state: &MotionState, limits: &StopLimits) -> bool {
        match &self.workspace {
            Some(w) => w.contains(StopProfile::plan(state, limits).end_mm()),
            None => true,
        }
    }
}
