//! The calibration in force, with everything the servo loop derives from it, built in one
//! place ([`ActiveCalibration::new`]) and engaged as one ([`ActiveCalibration::engage`]): the
//! model checked once for the servo's IK ([`ValidCalibration`]), the identified dynamics the
//! motion step feeds forward and the servo gains designed for them
//! ([`kinematics_core::gain_design`]), the workspace a stop must end in, the backlash the
//! reference compensates. A switch replaces the whole value; nothing of it is kept in step by
//! hand.
use kinematics_core::gain_design::servo_config_for_dynamics;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{
    AcceptedSetpoint, AxisGains, Calibration, EngageError, FiveBarDynamics, Servo, ServoOutput,
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
    /// The servo gains for them: the settings' designed for the axis inertias the dynamics
    /// give over the workspace, or the settings' with the observer off without dynamics
    /// (`kinematics_core::gain_design`). Computed here, once per calibration, so that an
    /// engage costs none of it.
    gains: [AxisGains; 2],
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
        let dynamics = grid.and_then(|g| g.dynamics().copied());
        let workspace = grid.and_then(|g| {
            Workspace::of_machine_image(g, &settings.machine.workspace.region, margin_mm)
        });
        // The inertia is averaged where this calibration commands the tool: its workspace, in
        // its model's frame (the machine's without one).
        let region = workspace.map_or(settings.machine.workspace.region, |w| *w.region());
        let gains = servo_config_for_dynamics(
            &settings.servo,
            dynamics.as_ref(),
            &calibration.model,
            &region,
        )
        .axes;
        ActiveCalibration {
            calibration,
            valid: ValidCalibration::new(calibration).ok(),
            dynamics,
            gains,
            workspace,
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

    /// The servo gains this calibration runs with.
    pub fn gains(&self) -> &[AxisGains; 2] {
        &self.gains
    }

    /// Arms `servo` at `encoder_rad` with this calibration: its gains, its dynamics fed
    /// forward, its backlash compensated (taken by `Servo::engage`), its tool position
    /// returned.
    pub fn engage(
        &self,
        servo: &mut Servo,
        encoder_rad: [f32; 2],
    ) -> Result<[f32; 2], EngageError> {
        // The settings' gains, scaled within `gain_design::MAX_INERTIA_RATIO` or with the
        // observer off, pass the checks the settings passed at boot; were they refused, the
        // servo would keep the gains it has. The dynamics were validated when the image was
        // parsed; `set_dynamics` checks again and keeps none if not (the gains' constant
        // feed-forward then).
        let _ = servo.set_gains(self.gains);
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

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::grid::{append_dynamics, encode, DYNAMICS_LEN};
    use kinematics_core::{paper, CorrectionGrid};

    /// The paper's grid with zero corrections, with or without a dynamics block.
    fn image(dynamics: Option<FiveBarDynamics<f32>>) -> Vec<u8> {
        let g = paper::grid_geometry();
        let nodes = vec![[0.0f32; 2]; usize::from(g.nx) * usize::from(g.ny)];
        let mut img = vec![0u8; g.image_len() + DYNAMICS_LEN];
        let n = encode(&mut img, &g, &paper::nominal::<f32>(), &nodes).unwrap();
        let mut end = n;
        if let Some(d) = dynamics {
            end = append_dynamics(&mut img, n, end, &d).unwrap();
        }
        img.truncate(end);
        img
    }

    /// Without dynamics the settings' gains run with the observer off; with a heavier tool's
    /// dynamics every gain grows with the axis inertia, and engaging puts them in the servo.
    #[test]
    fn the_gains_follow_the_images_dynamics() {
        let settings = Settings::default();
        let base = settings.servo.axes;
        let plain = image(None);
        let active = ActiveCalibration::new(
            Calibration::from_grid(CorrectionGrid::parse(&plain).unwrap()),
            &settings,
        );
        for (g, b) in active.gains().iter().zip(base) {
            assert_eq!(g.observer_bandwidth_rad_s, 0.0);
            assert_eq!(g.kp_nm_per_rad, b.kp_nm_per_rad);
        }
        let heavy_dynamics = FiveBarDynamics {
            tool_mass_kg: 0.425,
            ..paper::nominal_dynamics()
        };
        let heavy = image(Some(heavy_dynamics));
        let active = ActiveCalibration::new(
            Calibration::from_grid(CorrectionGrid::parse(&heavy).unwrap()),
            &settings,
        );
        for (g, b) in active.gains().iter().zip(base) {
            let r = g.kp_nm_per_rad / b.kp_nm_per_rad;
            assert!(r > 1.5 && r < 2.2, "{r}");
            assert!((g.observer_inertia_kg_m2 / b.observer_inertia_kg_m2 - r).abs() < 1e-4);
            assert_eq!(g.observer_bandwidth_rad_s, b.observer_bandwidth_rad_s);
        }
        let mut servo = Servo::new(settings.servo).unwrap();
        let theta = paper::nominal::<f32>()
            .inverse(settings.machine.home_mm, 0.05)
            .unwrap();
        active.engage(&mut servo, theta).unwrap();
        assert_eq!(&servo.config().axes, active.gains());
        assert_eq!(servo.dynamics(), Some(&heavy_dynamics));
    }
}
