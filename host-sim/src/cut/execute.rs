//! Execution as the machine runs it: the gantry's drives follow their reference, the micro's
//! controller follows its own (the planned offset plus the gantry's measured following error),
//! both on one time base, and the tool is where the two plants really are.
//!
//! # The time base
//! Every sample `k` is the instant `k·Δt` of one clock (`Δt` the servo period, 0.5 ms). On a
//! real machine the gantry's CNC and the micro's controller share it: the CNC's interpolation
//! cycle (an EtherCAT distributed clock's SYNC0 or a hardware sync line) starts each sample of
//! the micro's 2 kHz timer, and both execute sample `k` of their trajectories, downloaded
//! beforehand with the same sample numbering; the gantry's linear scales are read by the
//! micro's controller in the same cycle (the scales' interface on the sync, or the drives'
//! position sent over the fieldbus, its latency compensated by the same prediction as here).
//! Here, sample `k`: both stages are read, the micro's setpoint is formed, both controllers
//! compute their command, both plants move for one period.
//!
//! # Dual-stage compensation
//! The micro's setpoint is `centre + tool(k) − gantry_measured(k)`: the planned offset
//! `tool − gantry_reference` plus the gantry's measured following error
//! `gantry_reference − gantry_measured`. Its look-ahead setpoint uses the measurement
//! extrapolated one sample. The feed-forward uses the plan's derivatives.
//!
//! # The micro's stage behind a trait
//! [`MicroStage`] is what the executor needs of the micro: engage at a point, then one servo
//! period per call. [`HostLoop`] is the host's closed loop (`kinematics-core`'s servo step on
//! host-sim's six-bar plant, as `sim::closed_loop` runs it); a co-simulation that streams the
//! setpoints to the firmware under QEMU implements the same trait.
//!
//! The gantry's acceleration also pushes on the micro: its moving masses feel `−m·a_gantry`.
//! [`HostLoop`] applies it to the lumped tool mass (`Jᵀ·F` at the joints), a disturbance the
//! micro's servo and observer have to reject.

use super::split::Plan;
use super::timeline::{Cursor, Layout, ToolSample};
use super::CutError;
use crate::gantry_spec::GantrySpec;
use crate::machine_spec::MachineSpec;
use crate::plant::gantry::{AxisReference, Gantry};
use crate::plant::{Plant, PlantConfig};
use crate::sim::closed_loop::{cast_setpoint, loop_config, SUBSTEPS};
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, FiveBarDynamics, Servo};

/// The micro's state after a servo period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MicroState {
    /// Where its tool point really is (micro frame, mm).
    pub tool_mm: [f64; 2],
    /// Its joints' speeds (rad/s).
    pub joint_speed_rad_s: [f64; 2],
    /// The torque commanded over the period (N·m).
    pub torque_nm: [f64; 2],
}

/// The micro's stage as the executor drives it (see the module doc).
pub trait MicroStage {
    /// A short description for reports.
    fn describe(&self) -> String;
    /// Brings the stage to rest at `at_mm` (micro frame) with its servo engaged.
    fn engage(&mut self, at_mm: [f64; 2]) -> Result<MicroState, CutError>;
    /// One servo period: follow `setpoint` (the one a period later in `next`, if known) while
    /// the base accelerates at `base_accel_mm_s2`; the state at the period's end.
    fn step(
        &mut self,
        setpoint: &MotionSetpoint<f64>,
        next: Option<&MotionSetpoint<f64>>,
        base_accel_mm_s2: [f64; 2],
    ) -> Result<MicroState, CutError>;
}

/// The host's closed loop: `kinematics-core`'s servo on host-sim's plant.
pub struct HostLoop<'a> {
    plant: Plant,
    servo: Servo,
    cal: Calibration<'a>,
    dt_s: f64,
    min_transmission: f32,
    tool_mass_kg: f64,
}

impl<'a> HostLoop<'a> {
    /// The loop on `plant` with the servo settings `sim::closed_loop` uses, feeding `dynamics`
    /// forward.
    pub fn new(
        plant: &PlantConfig,
        cal: Calibration<'a>,
        spec: &MachineSpec,
        dynamics: &FiveBarDynamics<f64>,
    ) -> Result<Self, CutError> {
        let plant = Plant::new(plant, 1);
        let config = loop_config(&plant, spec);
        let mut servo = Servo::new(config)
            .map_err(|e| CutError::Invalid(format!("servo settings refused: {e}")))?;
        servo
            .set_dynamics(Some(dynamics.cast()))
            .map_err(|e| CutError::Invalid(format!("dynamic parameters: {e}")))?;
        Ok(HostLoop {
            tool_mass_kg: plant.true_dynamics().tool_mass_kg,
            plant,
            servo,
            cal,
            dt_s: spec.sample_period_s,
            min_transmission: spec.min_transmission as f32,
        })
    }

    fn state(&mut self, torque_nm: [f64; 2]) -> Result<MicroState, CutError> {
        let sol = self.plant.solve().map_err(CutError::from)?;
        Ok(MicroState {
            tool_mm: self.plant.instrument.frame_mm(sol.tool_mm),
            joint_speed_rad_s: [
                self.plant.drives[0].velocity_rad_s,
                self.plant.drives[1].velocity_rad_s,
            ],
            torque_nm,
        })
    }
}

impl MicroStage for HostLoop<'_> {
    fn describe(&self) -> String {
        format!("host loop on the {} plant", self.plant.config.description)
    }

    fn engage(&mut self, at_mm: [f64; 2]) -> Result<MicroState, CutError> {
        let cmd = self
            .cal
            .command_rad([at_mm[0] as f32, at_mm[1] as f32], self.min_transmission)
            .map_err(|e| CutError::Execution(format!("the micro's start {at_mm:?} mm: {e}")))?;
        self.plant
            .settle([f64::from(cmd[0]), f64::from(cmd[1])], [1, 1])
            .map_err(CutError::from)?;
        let enc = self.plant.encoder_rad();
        self.servo
            .engage(&self.cal, [enc[0] as f32, enc[1] as f32])
            .map_err(|e| {
                CutError::Execution(format!("the micro's servo refused to engage: {e}"))
            })?;
        self.state([0.0; 2])
    }

    fn step(
        &mut self,
        setpoint: &MotionSetpoint<f64>,
        next: Option<&MotionSetpoint<f64>>,
        base_accel_mm_s2: [f64; 2],
    ) -> Result<MicroState, CutError> {
        let enc = self.plant.encoder_rad();
        let next32 = next.map(cast_setpoint);
        let out = self
            .servo
            .step_motion(
                &self.cal,
                &cast_setpoint(setpoint),
                next32.as_ref(),
                [enc[0] as f32, enc[1] as f32],
            )
            .map_err(|e| {
                CutError::Execution(format!(
                    "the micro's servo at setpoint ({:.3}, {:.3}) mm: {e}",
                    setpoint.position_mm[0], setpoint.position_mm[1]
                ))
            })?;
        let torque = [f64::from(out.torque_nm[0]), f64::from(out.torque_nm[1])];
        // The base's acceleration on the tool mass, at the joints: τ = Jᵀ·(−m·a) (SI units).
        let mut push = [0.0; 2];
        if let Ok(j) = self
            .cal
            .model
            .inverse_pose(
                [
                    setpoint.position_mm[0] as f32,
                    setpoint.position_mm[1] as f32,
                ],
                0.0,
            )
            .and_then(|p| p.jacobian())
        {
            let f = [
                -self.tool_mass_kg * base_accel_mm_s2[0] * 1e-3,
                -self.tool_mass_kg * base_accel_mm_s2[1] * 1e-3,
            ];
            for (i, p) in push.iter_mut().enumerate() {
                *p = (f64::from(j[0][i]) * f[0] + f64::from(j[1][i]) * f[1]) * 1e-3;
            }
        }
        self.plant
            .advance(
                [torque[0] + push[0], torque[1] + push[1]],
                self.dt_s,
                SUBSTEPS,
            )
            .map_err(CutError::from)?;
        self.state(torque)
    }
}

/// One executed sample (compact: the plan holds the references).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Executed {
    /// The gantry's real position (mm).
    pub gantry_mm: [f64; 2],
    /// The micro's real offset from its workspace centre (mm).
    pub micro_mm: [f64; 2],
    /// The micro's joint speeds (rad/s) and torques (N·m).
    pub joint_speed_rad_s: [f32; 2],
    pub torque_nm: [f32; 2],
    /// The beam is on.
    pub laser_on: bool,
    /// The move the tool is on (index into the layout's moves).
    pub move_index: u32,
}

impl Executed {
    /// Where the tool really is: gantry + micro offset (mm).
    pub fn tool_mm(&self) -> [f64; 2] {
        [
            self.gantry_mm[0] + self.micro_mm[0],
            self.gantry_mm[1] + self.micro_mm[1],
        ]
    }
}

/// The micro's setpoint for the tool at `tool_mm` (with the derivatives of `tool`) and the
/// gantry at `gantry_mm` (with the reference's derivatives `gd`).
fn micro_setpoint(
    centre_mm: [f64; 2],
    tool_mm: [f64; 2],
    gantry_mm: [f64; 2],
    tool: &ToolSample,
    gd: &[[f64; 2]; 3],
) -> MotionSetpoint<f64> {
    MotionSetpoint {
        position_mm: [
            centre_mm[0] + tool_mm[0] - gantry_mm[0],
            centre_mm[1] + tool_mm[1] - gantry_mm[1],
        ],
        velocity_mm_s: [
            tool.velocity_mm_s[0] - gd[0][0],
            tool.velocity_mm_s[1] - gd[0][1],
        ],
        acceleration_mm_s2: [
            tool.accel_mm_s2[0] - gd[1][0],
            tool.accel_mm_s2[1] - gd[1][1],
        ],
        jerk_mm_s3: [tool.jerk_mm_s3[0] - gd[2][0], tool.jerk_mm_s3[1] - gd[2][1]],
    }
}

/// Runs `plan` on the gantry of `gantry` and the micro `stage` (micro workspace centre
/// `centre_mm`); every sample of the plan, the executed state.
pub fn execute(
    layout: &Layout,
    plan: &Plan,
    gantry: &GantrySpec,
    stage: &mut dyn MicroStage,
    centre_mm: [f64; 2],
) -> Result<Vec<Executed>, CutError> {
    let dt = plan.dt_s;
    let n = plan.samples();
    let mut out = Vec::with_capacity(n);
    let mut g = Gantry::new(gantry, plan.gantry_mm[0], dt);
    let start_offset = [
        plan.tool_mm[0][0] - plan.gantry_mm[0][0],
        plan.tool_mm[0][1] - plan.gantry_mm[0][1],
    ];
    let mut micro = stage.engage([
        centre_mm[0] + start_offset[0],
        centre_mm[1] + start_offset[1],
    ])?;
    let mut cursor = Cursor::default();
    let mut last_move = 0u32;
    for k in 0..n {
        let t_tool = (k as f64 - plan.lead as f64) * dt;
        let tool = plan.timeline.at(layout, t_tool, &mut cursor);
        if let Some(i) = tool.move_index {
            last_move = i as u32;
        }
        let meas = g.measured_mm();
        out.push(Executed {
            gantry_mm: g.position_mm(),
            micro_mm: [
                micro.tool_mm[0] - centre_mm[0],
                micro.tool_mm[1] - centre_mm[1],
            ],
            joint_speed_rad_s: micro.joint_speed_rad_s.map(|v| v as f32),
            torque_nm: micro.torque_nm.map(|v| v as f32),
            laser_on: tool.laser_on,
            move_index: last_move,
        });
        let gd = plan.gantry_derivatives(k);
        // The micro's setpoint: the tool less the gantry as measured (module doc).
        let setpoint = micro_setpoint(centre_mm, plan.tool_mm[k], meas, &tool, &gd);
        let next = (k + 1 < n).then(|| {
            // The gantry a sample later: as measured, moved as its reference moves (its
            // following error changes slowly; a linear extrapolation of the measurement would
            // be off by a·Δt², 2.5 µm at 1 g).
            let (r0, r1) = (plan.gantry_mm[k], plan.gantry_mm[k + 1]);
            let pred = [meas[0] + r1[0] - r0[0], meas[1] + r1[1] - r0[1]];
            let mut c = cursor;
            let t1 = plan.timeline.at(layout, t_tool + dt, &mut c);
            micro_setpoint(
                centre_mm,
                plan.tool_mm[k + 1],
                pred,
                &t1,
                &plan.gantry_derivatives(k + 1),
            )
        });
        let reference = [0, 1].map(|i| AxisReference {
            position_mm: plan.gantry_mm[k][i],
            velocity_mm_s: gd[0][i],
            accel_mm_s2: gd[1][i],
        });
        let base = [gd[1][0], gd[1][1]];
        micro = stage
            .step(&setpoint, next.as_ref(), base)
            .map_err(|e| match e {
                CutError::Execution(m) => {
                    CutError::Execution(format!("at t = {:.4} s: {m}", k as f64 * dt))
                }
                other => other,
            })?;
        g.step(&reference);
    }
    Ok(out)
}
