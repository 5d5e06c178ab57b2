//! A telemetry log matched with the knots that moved the machine: for each sample, the joint
//! motion the torque it reports produced, and what the controller followed.
//!
//! **Time.** A controller's ticks count from its power-up, the knots from the stream's start.
//! The stream's start tick is found from the setpoints the log reports: the integer tick at
//! which the played knots (`sim::knots::KnotPath`) best reproduce every reported setpoint, the
//! worst difference at most [`MATCH_TOLERANCE_MM`] (the controller plays the same cubics in
//! f32). A log that no start tick matches is not a run of these knots: refused.
//!
//! **Motion.** The torque of tick `k` acts over `[t_k, t_k + dt]`: it is matched with the
//! reference's motion at the middle of that interval (task-space position, velocity and
//! acceleration from the knots, joint motion by the model's inverse kinematics). The machine
//! follows the reference within micro-radians (the log's following error says by how much);
//! the acceleration this neglects is what the feedback itself adds, a few per cent at the
//! jerk changes and nothing on average.
//!
//! **The machine.** The commanded encoder angles the log reports must be the model's inverse
//! kinematics of the reported setpoints, within [`REFERENCE_TOLERANCE_RAD`] (room for the
//! correction grid and the backlash compensation, a fraction of a milliradian): a log of
//! another design, or read with another model, is refused.
//!
//! Samples left out (counted): the machine at rest on both axes (static friction holds
//! whatever the integrator left), a torque at the amplifier's limit (the plant got less), a
//! pose the model cannot reach.

use super::telemetry::LogFacts;
use super::DynError;
use crate::io::telemetry_csv::TelemetryLog;
use crate::sim::knots::KnotPath;
use kinematics_core::joint_motion::JointMotion;
use kinematics_core::{wrap_angle_rad, FiveBar};

/// Largest difference between a reported setpoint and the played knots at the matched time (mm).
pub const MATCH_TOLERANCE_MM: f64 = 0.005;
/// Largest difference between a reported reference angle and the model's IK of the setpoint (rad).
pub const REFERENCE_TOLERANCE_RAD: f64 = 3e-3;
/// Below this speed on both joints a sample is at rest (rad/s).
pub const REST_RAD_S: f64 = 0.02;

/// How to read the samples.
#[derive(Clone, Copy, Debug)]
pub struct SampleOptions {
    /// The hidden robot the controller commands with (the image's model).
    pub model: FiveBar<f64>,
    /// The singularity margin of its inverse kinematics.
    pub min_transmission: f64,
    /// The amplifiers' limit (N·m): samples at 99 % of it are left out.
    pub torque_limit_nm: [f64; 2],
}

/// One usable sample.
#[derive(Clone, Copy, Debug)]
pub struct MotionSample {
    /// The controller's tick.
    pub tick: u64,
    /// Time from the stream's start (s).
    pub t_s: f64,
    /// The reference's motion at the middle of the sample's interval.
    pub motion: JointMotion<f64>,
    /// The torques written (N·m).
    pub torque_nm: [f64; 2],
    /// Reference minus encoder, per axis (rad).
    pub following_error_rad: [f64; 2],
    /// The setpoint (mm).
    pub setpoint_mm: [f64; 2],
}

/// What matching found.
#[derive(Clone, Debug)]
pub struct Matched {
    /// The tick at which the stream started (its time 0).
    pub start_tick: i64,
    /// The usable samples during the motion, in order.
    pub samples: Vec<MotionSample>,
    /// Samples during the motion left out: at rest, saturated, unreachable.
    pub at_rest: usize,
    pub saturated: usize,
    pub unreachable: usize,
    /// Worst setpoint difference at the matched start (mm).
    pub match_error_mm: f64,
}

/// Finds the stream's start tick (see the module doc).
fn start_tick(
    log: &TelemetryLog,
    path: &KnotPath,
    dt: f64,
    dec: u64,
) -> Result<(i64, f64), DynError> {
    let start = path.start_mm();
    let away = |p: [f64; 2]| (p[0] - start[0]).hypot(p[1] - start[1]);
    let Some(m) = log.rows.iter().position(|r| away(r.setpoint_mm) > 1e-3) else {
        return Err(DynError::Telemetry(format!(
            "the log's setpoints never leave the excitation's start ({:.3}, {:.3}) mm: no motion \
             of these knots was recorded (was the machine at the start when the stream began?)",
            start[0], start[1]
        )));
    };
    // When the played path first moves 1 µm: the start tick is about that much before row m.
    let mut first_s = 0.0;
    while away(path.motion_at(first_s).position_mm) <= 1e-3 && first_s < path.end_s() {
        first_s += dt;
    }
    let guess = log.rows[m].tick as i64 - (first_s / dt).round() as i64;
    let span = 2 * dec as i64 + 2;
    let score = |k0: i64| {
        log.rows
            .iter()
            .map(|r| {
                let t = (r.tick as i64 - k0) as f64 * dt;
                away_from(path, t, r.setpoint_mm)
            })
            .fold(0.0f64, f64::max)
    };
    let (best, err) = (guess - span..=guess + span)
        .map(|k0| (k0, score(k0)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("a non-empty range");
    if !(err <= MATCH_TOLERANCE_MM) {
        return Err(DynError::Telemetry(format!(
            "the log's setpoints do not follow these knots: {err:.4} mm apart at best (tolerance \
             {MATCH_TOLERANCE_MM} mm); give the knots that were streamed (--knots)"
        )));
    }
    Ok((best, err))
}

fn away_from(path: &KnotPath, t_s: f64, p: [f64; 2]) -> f64 {
    let q = path.motion_at(t_s).position_mm;
    (p[0] - q[0]).hypot(p[1] - q[1])
}

/// Matches `log` (checked: `facts`) with `path` (see the module doc).
pub fn match_log(
    log: &TelemetryLog,
    facts: &LogFacts,
    path: &KnotPath,
    opts: &SampleOptions,
) -> Result<Matched, DynError> {
    let dt = facts.sample_period_s;
    let (k0, match_error_mm) = start_tick(log, path, dt, facts.decimation)?;
    let end_s = path.end_s();
    let time = |tick: u64| (tick as i64 - k0) as f64 * dt;
    let (first, last) = (
        time(log.rows[0].tick),
        time(log.rows[log.rows.len() - 1].tick),
    );
    let spacing = facts.decimation as f64 * dt;
    if first > spacing || last < end_s - spacing {
        return Err(DynError::Telemetry(format!(
            "the log covers {first:.2} s to {last:.2} s of the {end_s:.2} s excitation: record \
             the whole motion (from before the stream starts until the machine is at rest)"
        )));
    }
    let mut out = Matched {
        start_tick: k0,
        samples: Vec::new(),
        at_rest: 0,
        saturated: 0,
        unreachable: 0,
        match_error_mm,
    };
    for r in &log.rows {
        let t = time(r.tick);
        if !(t >= 0.0 && t <= end_s) {
            continue;
        }
        if r.mode != "Running" || r.fault.is_some() {
            return Err(DynError::Telemetry(format!(
                "at tick {} ({t:.3} s into the excitation) the controller was {}{}: the motion \
                 did not run to its end; reset the fault and record again",
                r.tick,
                r.mode,
                r.fault
                    .as_deref()
                    .map_or(String::new(), |f| format!(" with fault {f}"))
            )));
        }
        let ik = opts.model.inverse(r.setpoint_mm, opts.min_transmission);
        match ik {
            Ok(th) => {
                let d = [0, 1].map(|i| wrap_angle_rad(r.reference_rad[i] - th[i]).abs());
                if d[0].max(d[1]) > REFERENCE_TOLERANCE_RAD {
                    return Err(DynError::Telemetry(format!(
                        "at tick {} the controller commanded ({:.5}, {:.5}) rad for the setpoint \
                         ({:.3}, {:.3}) mm, where this machine's model gives ({:.5}, {:.5}) rad: a \
                         log of another machine, or of another model (give the image in force, \
                         --grid)",
                        r.tick,
                        r.reference_rad[0],
                        r.reference_rad[1],
                        r.setpoint_mm[0],
                        r.setpoint_mm[1],
                        th[0],
                        th[1]
                    )));
                }
            }
            Err(e) => {
                return Err(DynError::Telemetry(format!(
                    "at tick {} the setpoint ({:.3}, {:.3}) mm is not reachable by this machine's \
                     model ({e}): a log of another machine",
                    r.tick, r.setpoint_mm[0], r.setpoint_mm[1]
                )))
            }
        }
        let s = path.motion_at(t + 0.5 * dt);
        let Ok(motion) = opts.model.inverse_motion(
            s.position_mm,
            s.velocity_mm_s,
            s.acceleration_mm_s2,
            opts.min_transmission,
        ) else {
            out.unreachable += 1;
            continue;
        };
        let w = motion.velocity_rad_s;
        if w[0].abs() < REST_RAD_S && w[1].abs() < REST_RAD_S {
            out.at_rest += 1;
            continue;
        }
        if (0..2).any(|i| r.torque_nm[i].abs() >= 0.99 * opts.torque_limit_nm[i]) {
            out.saturated += 1;
            continue;
        }
        out.samples.push(MotionSample {
            tick: r.tick,
            t_s: t,
            motion,
            torque_nm: r.torque_nm,
            following_error_rad: [0, 1]
                .map(|i| wrap_angle_rad(r.reference_rad[i] - r.encoder_rad[i])),
            setpoint_mm: r.setpoint_mm,
        });
    }
    Ok(out)
}
