//! A `host-sim simulate` run: a plant, a calibration and a trajectory in, the loop's summary
//! and (if asked) every sample out, and the sample log's CSV format.
//!
//! See [`super::closed_loop`] for what is simulated and how errors are defined. Cost: the loop's
//! (≈ 0.4 µs per sample with the five-bar plant, 4–5 µs with the six-bar).

use super::closed_loop::{run_loop_with, FeedForward, LogRow, LoopSummary};
use super::motions::Trajectory;
use super::SimError;
use crate::machine_spec::MachineSpec;
use crate::plant::{Plant, PlantConfig};
use kinematics_core::Calibration;
use std::fmt::Write as _;

/// Longest run accepted (s of simulated time).
pub const MAX_SECONDS: f64 = 3600.0;

/// What to run.
#[derive(Clone, Debug)]
pub struct SimulateOptions {
    /// Simulated seconds; `None`: the trajectory's natural length.
    pub seconds: Option<f64>,
    /// Seeds the plant's instrument (unused by the loop itself; kept for reproducibility).
    pub seed: u64,
    /// Keep every sample ([`SimulateRun::log`]).
    pub keep_log: bool,
    pub spec: MachineSpec,
    /// What the servo feeds forward.
    pub feedforward: FeedForward,
}

/// The outcome of a run.
#[derive(Clone, Debug)]
pub struct SimulateRun {
    pub summary: LoopSummary,
    /// Every sample, if asked for.
    pub log: Vec<LogRow>,
}

/// Runs the closed loop on `plant` commanded through `cal` along `trajectory`.
pub fn simulate(
    plant: &PlantConfig,
    cal: &Calibration<'_>,
    trajectory: &Trajectory,
    opts: &SimulateOptions,
) -> Result<SimulateRun, SimError> {
    let seconds = opts
        .seconds
        .unwrap_or_else(|| trajectory.natural_duration_s());
    if !(seconds > 0.0 && seconds <= MAX_SECONDS) {
        return Err(SimError::Invalid(format!(
            "the simulated time must be in (0, {MAX_SECONDS}] s, not {seconds}"
        )));
    }
    let mut plant = Plant::new(plant, opts.seed);
    let mut log = Vec::new();
    let summary = run_loop_with(
        &mut plant,
        cal,
        trajectory,
        seconds,
        &opts.spec,
        &opts.feedforward,
        opts.keep_log.then_some(&mut log),
    )?;
    Ok(SimulateRun { summary, log })
}

/// The sample log as CSV (`--log`): one row per sample.
pub fn format_log(rows: &[LogRow]) -> String {
    let mut s = String::from(
        "t_s,x_set_mm,y_set_mm,x_mm,y_mm,theta1_enc_rad,theta2_enc_rad,theta1_ref_rad,theta2_ref_rad,torque1_nm,torque2_nm,tracking_err_um,max_bar_tension_n\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{:.4},{:.6},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.9},{:.5},{:.5},{:.4},{:.3}",
            r.t_s,
            r.setpoint_mm[0],
            r.setpoint_mm[1],
            r.tool_mm[0],
            r.tool_mm[1],
            r.encoder_rad[0],
            r.encoder_rad[1],
            r.reference_rad[0],
            r.reference_rad[1],
            r.torque_nm[0],
            r.torque_nm[1],
            r.tracking_err_um,
            r.max_bar_tension_n
        );
    }
    s
}
