//! The closed 2 kHz loop: `kinematics-core`'s servo step, exactly as the firmware runs it,
//! against the simulated plant.
//!
//! ```text
//!  trajectory(t_k) ─► Servo::step_motion (f32: IK + joint motion + grid + inverse dynamics
//!  + PID) ─► torque (held for 0.5 ms) ─► drives coupled through the linkage's inertia (10 RK4
//!  substeps of 50 µs: rotors, bars, platform, friction, torque limit, backlash) ─► link angles
//!  ─► six-bar equilibrium (or five-bar FK) ─► tool point;   encoders (quantized) ─► next step
//! ```
//! Simulated time advances by exactly 0.5 ms per servo step. The linkage's rigid-body dynamics
//! are in the drives' equations of motion (`plant::motion`); its elastic modes (~kHz, far above
//! the loop bandwidth) are not, so its equilibrium is solved once per sample, not per substep.
//!
//! What the servo feeds forward ([`FeedForward`]): the identified inverse dynamics on the
//! trajectory's exact derivatives (`Servo::step_motion`, the default of `host-sim simulate`), the
//! gains' constant inertia on the same derivatives, or (a trajectory file, which has positions
//! only, and [`run_loop`]) `Servo::step` on backward differences.
//!
//! Tracking error: |tool(t_k) - setpoint(t_k)| with the tool point seen in the instrument's frame
//! without noise (the frame the measurements, and hence the calibration, live in; on `ideal` it
//! is the machine frame), so on a plant with errors it includes what the calibration has not
//! removed.
//! Following error: what the loop itself lags, `|J·(reference - encoder)|` with the model's
//! Jacobian at the setpoint (µm at the tool), and the joint value (µrad). 5 g segments are the
//! samples whose setpoint acceleration (backward second difference, as the servo computes it) is
//! at least 95 % of the machine's rated acceleration (4.75 g on the paper machine).
//!
//! Cost per sample (release, `cargo bench -p host-sim`): ~0.4 µs with the five-bar plant
//! (1250-1600x real time), ~4-5 µs with the six-bar plant (115-175x real time): the six-bar
//! solve dominates.
//!
//! Overruns: simulation has no deadline, so nothing can overrun; `overruns` counts the steps
//! whose wall-clock time exceeded the 500 µs period (0 on any reasonable host).

use super::motions::Trajectory;
use super::SimError;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use crate::plant::Plant;
use kinematics_core::trajectory::MotionSetpoint;
use kinematics_core::{Calibration, FiveBarDynamics, Servo, ServoConfig};
use serde::Serialize;
use std::time::Instant;

/// Drive integration substeps per sample.
pub const SUBSTEPS: u32 = 10;
/// The settling window (µm at the tool).
pub const SETTLE_WINDOW_UM: f64 = 2.0;

/// What the servo feeds forward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FeedForward {
    /// `Servo::step` on the positions: velocity and acceleration feed-forward from backward
    /// differences with the gains' constant inertia (the simplest loop).
    Differences,
    /// `Servo::step_motion` on the exact derivatives with the gains' constant inertia.
    Constant,
    /// `Servo::step_motion` with these dynamic parameters (identified, `calib::dynamics`).
    Dynamics(FiveBarDynamics<f64>),
}

impl FeedForward {
    /// A short name for reports.
    pub fn name(&self) -> &'static str {
        match self {
            FeedForward::Differences => "differences",
            FeedForward::Constant => "constant",
            FeedForward::Dynamics(_) => "dynamics",
        }
    }
}

/// One logged sample.
#[derive(Clone, Copy, Debug)]
pub struct LogRow {
    pub t_s: f64,
    pub setpoint_mm: [f64; 2],
    /// Tool at t_k (instrument frame, noiseless).
    pub tool_mm: [f64; 2],
    pub encoder_rad: [f64; 2],
    pub reference_rad: [f64; 2],
    pub torque_nm: [f64; 2],
    /// |tool(t_k) - setpoint(t_k)|.
    pub tracking_err_um: f64,
    pub max_bar_tension_n: f64,
}

/// The figures of one run (the JSON summary of `simulate`).
#[derive(Clone, Debug, Serialize)]
pub struct LoopSummary {
    pub plant: String,
    pub trajectory: String,
    pub simulated_s: f64,
    pub samples: u64,
    pub max_tracking_err_um: f64,
    pub rms_tracking_err_um: f64,
    pub max_following_err_um: f64,
    pub max_following_err_5g_um: Option<f64>,
    pub max_joint_following_err_5g_urad: Option<f64>,
    pub samples_at_5g: u64,
    pub max_joint_following_err_urad: f64,
    pub max_torque_nm: f64,
    pub max_bar_tension_n: f64,
    pub realtime_factor: f64,
    pub overruns: u64,
    pub overruns_note: String,
    pub fault: Option<String>,
    /// What the servo fed forward (`differences`, `constant`, `dynamics`).
    pub feedforward: String,
    /// RMS of the following error at the tool (µm).
    pub rms_following_err_um: f64,
    /// From the end of the last motion, how long until the following error at the tool stays
    /// within ±2 µm for the rest of the run (s; `None`: never, or no motion end).
    pub settling_following_2um_s: Option<f64>,
    /// The same for the tracking error (tool against setpoint, instrument frame).
    pub settling_tracking_2um_s: Option<f64>,
}

/// When a signal has stayed within the settling window since: `end` is the motion's end.
#[derive(Clone, Copy, Debug)]
struct Settling {
    end_s: Option<f64>,
    last_outside_s: Option<f64>,
}

impl Settling {
    fn record(&mut self, t_s: f64, value_um: f64) {
        if matches!(self.end_s, Some(end) if t_s >= end) && !(value_um <= SETTLE_WINDOW_UM) {
            self.last_outside_s = Some(t_s);
        }
    }

    /// Settling time, if the run went on inside the window after the last excursion.
    fn time_s(&self, last_sample_s: f64, dt_s: f64) -> Option<f64> {
        let end = self.end_s?;
        match self.last_outside_s {
            None if last_sample_s >= end => Some(0.0),
            Some(t) if t < last_sample_s => Some(t + dt_s - end),
            _ => None,
        }
    }
}

/// Runs the loop for `seconds` of simulated time at `spec`'s sample period and singularity
/// margin, with the servo on backward differences ([`FeedForward::Differences`]). `log`
/// collects every sample.
pub fn run_loop(
    plant: &mut Plant,
    cal: &Calibration<'_>,
    trajectory: &Trajectory,
    seconds: f64,
    spec: &MachineSpec,
    log: Option<&mut Vec<LogRow>>,
) -> Result<LoopSummary, SimError> {
    run_loop_with(
        plant,
        cal,
        trajectory,
        seconds,
        spec,
        &FeedForward::Differences,
        log,
    )
}

/// [`run_loop`] with the servo feeding forward `feedforward` (a trajectory without derivatives
/// runs on differences whatever is asked), with the servo settings of [`loop_config`].
pub fn run_loop_with(
    plant: &mut Plant,
    cal: &Calibration<'_>,
    trajectory: &Trajectory,
    seconds: f64,
    spec: &MachineSpec,
    feedforward: &FeedForward,
    log: Option<&mut Vec<LogRow>>,
) -> Result<LoopSummary, SimError> {
    let config = loop_config(plant, spec);
    run_loop_configured(
        plant,
        cal,
        trajectory,
        seconds,
        spec,
        feedforward,
        config,
        log,
    )
}

/// The servo's default settings at `spec`'s sample period and singularity margin.
pub fn servo_config_at(spec: &MachineSpec) -> ServoConfig {
    ServoConfig {
        sample_period_s: spec.sample_period_s as f32,
        min_transmission: spec.min_transmission as f32,
        ..ServoConfig::default()
    }
}

/// The servo settings the loop runs with: the defaults at `spec`'s sample period and singularity
/// margin, with the Coulomb feed-forward set to 80 % of each drive's Coulomb friction, as a
/// commissioning run would identify it (on the paper plant this takes the slow-circle
/// following error from 22 to 16 µm).
pub fn loop_config(plant: &Plant, spec: &MachineSpec) -> ServoConfig {
    let mut config = servo_config_at(spec);
    let coulomb_nm = [
        plant.config.drive_1.coulomb_friction_nm,
        plant.config.drive_2.coulomb_friction_nm,
    ];
    for (axis, c) in config.axes.iter_mut().zip(coulomb_nm) {
        axis.coulomb_ff_nm = 0.8 * c as f32;
    }
    config
}

/// [`run_loop_with`] with the servo settings `config` (refused as [`SimError::Invalid`] if the
/// servo refuses them; its sample period should be `spec`'s, which sets the loop's time step).
#[allow(clippy::too_many_arguments)] // the loop's inputs, each a different kind
pub fn run_loop_configured(
    plant: &mut Plant,
    cal: &Calibration<'_>,
    trajectory: &Trajectory,
    seconds: f64,
    spec: &MachineSpec,
    feedforward: &FeedForward,
    config: ServoConfig,
    mut log: Option<&mut Vec<LogRow>>,
) -> Result<LoopSummary, SimError> {
    let dt = spec.sample_period_s;
    let n = (seconds / dt).round() as u64;
    let start = trajectory.at(0.0);
    // Start at rest on the first setpoint, as after a homing move.
    let cmd = cal
        .command_rad([start[0] as f32, start[1] as f32], config.min_transmission)
        .map_err(|e| SimError::Start {
            start_mm: start,
            reason: e.to_string(),
        })?;
    plant.settle([f64::from(cmd[0]), f64::from(cmd[1])], [1, 1])?;
    let feedforward = if trajectory.motion_at(0.0).is_some() {
        *feedforward
    } else {
        FeedForward::Differences
    };
    let mut servo = Servo::new(config)
        .map_err(|e| SimError::Invalid(format!("servo settings refused: {e}")))?;
    if let FeedForward::Dynamics(d) = &feedforward {
        servo
            .set_dynamics(Some(d.cast()))
            .map_err(|e| SimError::Invalid(format!("dynamic parameters: {e}")))?;
    }
    let enc0 = plant.encoder_rad();
    servo
        .engage(cal, [enc0[0] as f32, enc0[1] as f32])
        .map_err(|e| SimError::ServoRefused(e.to_string()))?;

    let first = plant.solve()?.tool_mm;
    let mut tool = plant.instrument.frame_mm(first);
    let (mut sum2, mut max_err, mut max_follow) = (0.0f64, 0.0f64, 0.0f64);
    let (mut max_5g, mut max_5g_joint, mut n_5g) = (0.0f64, 0.0f64, 0u64);
    let (mut max_joint, mut max_torque, mut max_tension) = (0.0f64, 0.0f64, 0.0f64);
    let mut history = [start, start];
    let mut overruns = 0u64;
    let mut fault = None;
    let mut done = 0u64;
    let mut sum2_follow = 0.0f64;
    let end_s = trajectory.motion_end_s();
    let mut settle_follow = Settling {
        end_s,
        last_outside_s: None,
    };
    let mut settle_track = Settling {
        end_s,
        last_outside_s: None,
    };
    let wall = Instant::now();
    let mut last_wall = wall;
    for k in 0..n {
        let t = k as f64 * dt;
        let sp = trajectory.at(t);
        let accel = ((sp[0] - 2.0 * history[0][0] + history[1][0])
            .hypot(sp[1] - 2.0 * history[0][1] + history[1][1]))
            / (dt * dt);
        history = [sp, history[0]];
        let enc = plant.encoder_rad();
        let err = (tool[0] - sp[0]).hypot(tool[1] - sp[1]) * 1e3;
        let enc32 = [enc[0] as f32, enc[1] as f32];
        let stepped = match (feedforward, trajectory.motion_at(t)) {
            (FeedForward::Differences, _) | (_, None) => {
                servo.step(cal, [sp[0] as f32, sp[1] as f32], enc32)
            }
            (_, Some(m)) => {
                let next = trajectory.motion_at(t + dt).map(|n| cast_setpoint(&n));
                servo.step_motion(cal, &cast_setpoint(&m), next.as_ref(), enc32)
            }
        };
        let out = match stepped {
            Ok(o) => o,
            Err(f) => {
                fault = Some(format!("t = {t:.4} s: {f}"));
                break;
            }
        };
        let torque = [f64::from(out.torque_nm[0]), f64::from(out.torque_nm[1])];
        plant.advance(torque, dt, SUBSTEPS)?;
        let sol = plant.solve()?;
        let follow_um = match cal
            .model
            .inverse_pose([sp[0] as f32, sp[1] as f32], 0.0)
            .and_then(|p| p.jacobian())
        {
            Ok(j) => {
                let e = out.following_error_rad;
                (j[0][0] * e[0] + j[0][1] * e[1]).hypot(j[1][0] * e[0] + j[1][1] * e[1]) as f64
                    * 1e3
            }
            Err(_) => f64::NAN,
        };
        let joint = f64::from(
            out.following_error_rad[0]
                .abs()
                .max(out.following_error_rad[1].abs()),
        ) * 1e6;
        sum2 += err * err;
        sum2_follow += follow_um * follow_um;
        settle_follow.record(t, follow_um);
        settle_track.record(t, err);
        max_err = max_err.max(err);
        max_follow = max_follow.max(follow_um);
        max_joint = max_joint.max(joint);
        max_torque = max_torque.max(torque[0].abs()).max(torque[1].abs());
        max_tension = max_tension.max(sol.max_abs_tension_n());
        if k >= 2 && accel >= 0.95 * spec.max_acceleration_g * STANDARD_GRAVITY_MM_S2 {
            n_5g += 1;
            max_5g = max_5g.max(follow_um);
            max_5g_joint = max_5g_joint.max(joint);
        }
        if let Some(l) = log.as_deref_mut() {
            l.push(LogRow {
                t_s: t,
                setpoint_mm: sp,
                tool_mm: tool,
                encoder_rad: enc,
                reference_rad: [
                    f64::from(out.reference_rad[0]),
                    f64::from(out.reference_rad[1]),
                ],
                torque_nm: torque,
                tracking_err_um: err,
                max_bar_tension_n: sol.max_abs_tension_n(),
            });
        }
        tool = plant.instrument.frame_mm(sol.tool_mm);
        done += 1;
        let now = Instant::now();
        if (now - last_wall).as_secs_f64() > dt {
            overruns += 1;
        }
        last_wall = now;
    }
    let wall_s = wall.elapsed().as_secs_f64();
    let simulated_s = done as f64 * dt;
    let last_s = done.saturating_sub(1) as f64 * dt;
    Ok(LoopSummary {
        plant: plant.config.description.clone(),
        trajectory: trajectory.name(),
        simulated_s,
        samples: done,
        max_tracking_err_um: max_err,
        rms_tracking_err_um: if done > 0 {
            (sum2 / done as f64).sqrt()
        } else {
            0.0
        },
        max_following_err_um: max_follow,
        max_following_err_5g_um: (n_5g > 0).then_some(max_5g),
        max_joint_following_err_5g_urad: (n_5g > 0).then_some(max_5g_joint),
        samples_at_5g: n_5g,
        max_joint_following_err_urad: max_joint,
        max_torque_nm: max_torque,
        max_bar_tension_n: max_tension,
        realtime_factor: if wall_s > 0.0 {
            simulated_s / wall_s
        } else {
            f64::INFINITY
        },
        overruns,
        overruns_note: format!(
            "simulation has no deadline; counts steps whose wall time exceeded {:.0} us",
            spec.sample_period_s * 1e6
        ),
        fault,
        feedforward: feedforward.name().into(),
        rms_following_err_um: if done > 0 {
            (sum2_follow / done as f64).sqrt()
        } else {
            0.0
        },
        settling_following_2um_s: settle_follow.time_s(last_s, dt),
        settling_tracking_2um_s: settle_track.time_s(last_s, dt),
    })
}

/// The servo's f32 setpoint.
pub fn cast_setpoint(m: &MotionSetpoint<f64>) -> MotionSetpoint<f32> {
    MotionSetpoint {
        position_mm: m.position_mm.map(|v| v as f32),
        velocity_mm_s: m.velocity_mm_s.map(|v| v as f32),
        acceleration_mm_s2: m.acceleration_mm_s2.map(|v| v as f32),
        jerk_mm_s3: m.jerk_mm_s3.map(|v| v as f32),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::plant::{PlantConfig, PlantModel};
    use kinematics_core::FiveBar;

    /// The paper's nominal hidden robot without a grid: what the loop and the calibration
    /// tests command with.
    pub(crate) fn nominal() -> Calibration<'static> {
        Calibration {
            model: FiveBar::<f32>::paper_nominal(),
            grid: None,
        }
    }

    fn run(plant: &mut Plant, name: &str, seconds: Option<f64>) -> LoopSummary {
        let spec = MachineSpec::paper();
        let tr = Trajectory::by_name(name, &spec).unwrap();
        let seconds = seconds.unwrap_or_else(|| tr.natural_duration_s());
        run_loop(plant, &nominal(), &tr, seconds, &spec, None).unwrap()
    }

    #[test]
    fn tracks_a_slow_circle_on_the_ideal_sixbar() {
        let mut plant = Plant::new(&PlantConfig::ideal(), 1);
        let s = run(&mut plant, "circle", Some(2.0));
        eprintln!("{s:?}");
        assert!(s.fault.is_none(), "{s:?}");
        assert_eq!(s.samples, 4000);
        // Stated bound: 2 µm on the ideal plant (f32 kinematics, PID lag during the ramp).
        assert!(s.max_tracking_err_um < 2.0, "{s:?}");
    }

    #[test]
    fn paper_plant_with_fivebar_model_runs_p2p_at_5g() {
        let mut cfg = PlantConfig::paper();
        cfg.sixbar.model = PlantModel::Fivebar;
        let mut plant = Plant::new(&cfg, 1);
        let s = run(&mut plant, "p2p", None);
        eprintln!("{s:?}");
        assert!(s.fault.is_none(), "{s:?}");
        assert!(s.samples_at_5g > 100, "{s:?}");
        // The loop's own lag at 5 g stays below 100 µm at the tool (about 50 µm measured with the
        // default gains and this plant's friction, which the servo does not feed forward).
        assert!(s.max_following_err_5g_um.unwrap() < 100.0, "{s:?}");
    }

    #[test]
    fn paper_sixbar_plant_closes_the_loop_on_a_figure_eight() {
        // Stress, clearances, backlash, friction, quantization all on.
        let mut plant = Plant::new(&PlantConfig::paper(), 1);
        let s = run(&mut plant, "figure8", Some(1.0));
        assert!(s.fault.is_none(), "{s:?}");
        assert!(s.max_bar_tension_n > 100.0, "{s:?}");
        // Friction without feed-forward: tens of µm of lag at the joints' reversals.
        assert!(s.max_following_err_um < 60.0, "{s:?}");
        // Uncalibrated: the paper plant's ~1.5 mm class error.
        assert!(
            s.max_tracking_err_um > 200.0 && s.max_tracking_err_um < 2000.0,
            "{s:?}"
        );
    }
}
