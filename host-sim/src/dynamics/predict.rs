//! The closed loop as the controller's dynamics model predicts it: the core's servo (the
//! controller's settings, feeding forward the model in force) around the model as a plant
//! (`model_plant`, with whatever effects are being tried), along the reference of a telemetry
//! log (the knots it played). What it gives: the following error at the log's samples, which
//! the diagnosis sets against the telemetry's.
//!
//! Sample `j` of the prediction is the log's tick `start_tick + j` (the stream's start, matched
//! by `samples`); the servo steps exactly as `sim::closed_loop` steps it (`Servo::step_motion`
//! with the next setpoint), starting at rest on the stream's first setpoint.
//!
//! The following error at the tool: `J·e` (µm), with the model's Jacobian at the setpoint, as
//! the host loop reports it.

use super::model_plant::{Extras, ModelPlant};
use super::DynError;
use crate::machine_spec::MachineSpec;
use crate::sim::closed_loop::cast_setpoint;
use crate::sim::knots::KnotPath;
use kinematics_core::gain_design;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, ConvexWorkspace, FiveBar, FiveBarDynamics, Servo, ServoConfig};

/// What the controller runs.
#[derive(Clone, Copy, Debug)]
pub struct Controller {
    /// The model it commands with (its encoders read through it).
    pub model: FiveBar<f64>,
    /// Its servo settings (sample period included): the gains the controller designs from
    /// them for `fed_forward` are what the loop runs (`gain_design`, as the firmware does when
    /// it engages an image with that dynamics block).
    pub servo: ServoConfig,
    /// The dynamics it feeds forward.
    pub fed_forward: FiveBarDynamics<f64>,
    /// Where it commands the tool (the machine's workspace): where the axis inertias the gains
    /// are designed for are averaged.
    pub workspace: ConvexWorkspace<f32>,
}

impl Controller {
    /// The controller of `spec` commanding with `model`, its settings `servo`, feeding forward
    /// `fed_forward`.
    pub fn new(
        spec: &MachineSpec,
        model: FiveBar<f64>,
        servo: ServoConfig,
        fed_forward: FiveBarDynamics<f64>,
    ) -> Result<Self, DynError> {
        let record = spec
            .record()
            .map_err(|e| DynError::Invalid(format!("machine '{}': {e}", spec.name)))?;
        Ok(Controller {
            model,
            servo,
            fed_forward,
            workspace: record.workspace.region,
        })
    }

    /// The servo settings the loop runs: `servo` with the gains designed for `fed_forward`.
    pub fn designed_servo(&self) -> ServoConfig {
        gain_design::servo_config_for_dynamics(
            &self.servo,
            Some(&self.fed_forward.cast()),
            &self.model.cast(),
            &self.workspace,
        )
    }
}

/// The following error (reference − encoder, rad) the loop has at each stream sample in
/// `samples` (sorted, from 0), with the machine being `plant` plus `extras`.
pub fn following_error_rad(
    path: &KnotPath,
    samples: &[u64],
    controller: &Controller,
    plant: &FiveBarDynamics<f64>,
    extras: &Extras,
) -> Result<Vec<[f64; 2]>, DynError> {
    closed_loop(&|t| path.motion_at(t), samples, controller, plant, extras)
        .map(|v| v.into_iter().map(|(e, _)| e).collect())
}

/// A sample of the predicted loop: the following error (rad) and the setpoint (mm).
pub type Sampled = ([f64; 2], [f64; 2]);

/// The loop along `setpoint(t)` (from rest at its start): at each sample in `samples` (sorted,
/// from 0) the following error (rad) and the setpoint (mm).
pub fn closed_loop(
    setpoint: &dyn Fn(f64) -> MotionSetpoint<f64>,
    samples: &[u64],
    controller: &Controller,
    plant: &FiveBarDynamics<f64>,
    extras: &Extras,
) -> Result<Vec<Sampled>, DynError> {
    let sim = |m: String| DynError::Invalid(format!("the prediction's closed loop: {m}"));
    let dt = f64::from(controller.servo.sample_period_s);
    let cal = Calibration {
        model: controller.model.cast::<f32>(),
        grid: None,
    };
    let mut servo =
        Servo::new(controller.designed_servo()).map_err(|e| sim(format!("settings: {e:?}")))?;
    servo
        .set_dynamics(Some(controller.fed_forward.cast()))
        .map_err(|e| sim(format!("the fed-forward dynamics: {e}")))?;
    let start = setpoint(0.0).position_mm;
    let th0 = controller
        .model
        .inverse(start, f64::from(controller.servo.min_transmission))
        .map_err(|e| sim(format!("the start {start:?}: {e}")))?;
    let mut plant = ModelPlant::new(controller.model, *plant, *extras, th0);
    let enc = |p: &ModelPlant| p.angle_rad.map(|v| v as f32);
    servo
        .engage(&cal, enc(&plant))
        .map_err(|e| sim(format!("engage: {e:?}")))?;
    let mut out = Vec::with_capacity(samples.len());
    let last = samples.last().copied().unwrap_or(0);
    let mut next = samples.iter().peekable();
    for j in 0..=last {
        let t = j as f64 * dt;
        let now_f64 = setpoint(t);
        let now = cast_setpoint(&now_f64);
        let ahead = cast_setpoint(&setpoint(t + dt));
        let step = servo
            .step_motion(&cal, &now, Some(&ahead), enc(&plant))
            .map_err(|f| sim(format!("the servo faulted at {t:.4} s: {f:?}")))?;
        if next.peek() == Some(&&j) {
            next.next();
            out.push((step.following_error_rad.map(f64::from), now_f64.position_mm));
        }
        let torque = step.torque_nm.map(f64::from);
        plant
            .advance(torque, dt)
            .map_err(|e| sim(format!("the plant at {t:.4} s: {e}")))?;
    }
    Ok(out)
}

/// The following error at the tool (µm, x and y) of the joint errors `e_rad` at the setpoint
/// `setpoint_mm`: `J·e` with `model`'s Jacobian (`None` where it has none).
pub fn at_tool_um(
    model: &FiveBar<f64>,
    setpoint_mm: [f64; 2],
    e_rad: [f64; 2],
    min_transmission: f64,
) -> Option<[f64; 2]> {
    let j = model
        .inverse_pose(setpoint_mm, min_transmission)
        .and_then(|p| p.jacobian())
        .ok()?;
    Some([
        (j[0][0] * e_rad[0] + j[0][1] * e_rad[1]) * 1e3,
        (j[1][0] * e_rad[0] + j[1][1] * e_rad[1]) * 1e3,
    ])
}
