//! The servo step: one 2 kHz sample from task-space setpoint to joint torque commands.
//!
//! ```text
//! setpoint (x, y) ──► jump check ──► hidden-robot IK ──► + grid correction ──► unwrap
//!      ──► feed-forward (finite differences) ──► PID per axis ──► torque commands
//! ```
//! The firmware calls [`Servo::step`] from its timer interrupt and `host-sim` calls the very same
//! function against the simulated plant; nothing else computes a motor command.
//!
//! [`Servo::step_motion`] takes a [`MotionSetpoint`] (position with its exact velocity,
//! acceleration and jerk, from a [`crate::trajectory`]) and the next one, if queued, instead:
//! the same checks, the feed-forward from the identified inverse dynamics of the mean motion
//! until the next sample ([`crate::feed_forward`]; [`Servo::set_dynamics`]; without them the
//! gains' constant feed-forward on the same motion) and the PID on the remainder
//! ([`AxisController::feedback`]). No finite-difference lag. The next setpoint's joint state is
//! kept for the next step, so each step solves one IK.
//!
//! # Faults
//! Any of these latches a fault, sets both torques to zero (safe torque off: the drives are
//! disabled, the motors never jump to a new position) and keeps refusing until
//! [`Servo::engage`] re-arms the servo at the machine's actual position:
//! non-finite setpoint or encoder reading, a setpoint that is unreachable, too close to a
//! singularity or outside the correction grid, a setpoint sequence that asks for more speed or
//! acceleration than the machine can follow (5 g), and a following error beyond the limit.
//!
//! # Cost
//! One IK (two `atan2`, two `sqrt`), two bilinear lookups, two PIDs: see `cargo qemu-bench`
//! (`BENCH servo_step`); the motion step adds the joint motion and the inverse dynamics
//! (`BENCH servo_step_motion`, with the trajectory's evaluation). No allocation, no panic on
//! any input (property-tested).

use crate::dynamics::{DynamicsError, FiveBarDynamics};
use crate::feed_forward::{feed_forward_nm, interval_motion, predict, JointSample};
use crate::grid::{CorrectionGrid, GridError};
use crate::model::FiveBar;
use crate::real::Real;
use crate::pid::{AxisController, AxisGains, AxisReference};
use crate::trajectory::MotionSetpoint;
use crate::KinematicsError;

/// Standard gravity (mm/s²), for limits stated in g.
pub const STANDARD_GRAVITY_MM_S2: f32 = 9_806.65;

/// Run-time settings of the servo; [`ServoConfig::default`] suits the paper's machine as
/// simulated by `host-sim`'s default plant.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ServoConfig {
    /// Sample period (s): 0.5 ms for the 2 kHz loop.
    pub sample_period_s: f32,
    /// Position controller of motor 1 and motor 2.
    pub axes: [AxisGains; 2],
    /// Smallest `|sin|` of a transmission angle a setpoint may have (see `Pose`).
    pub min_transmission: f32,
    /// Largest setpoint speed (mm/s) accepted.
    pub max_speed_mm_s: f32,
    /// Largest setpoint acceleration (mm/s²) accepted: 5 g plus 5 % for rounding.
    pub max_accel_mm_s2: f32,
    /// Largest `|reference - encoder|` (rad) before the servo gives up.
    pub max_following_error_rad: f32,
}

impl Default for ServoConfig {
    /// Tuned for the paper machine with its linkage: the diagonal of its identified inertia
    /// matrix is 7.4e-3 kg·m² per joint (2e-3 rotor, 5.4e-3 bars, elbow pieces, platform and
    /// tool; nearly constant over the workspace, the coupling term within ±2.4e-3), and a
    /// position bandwidth ω = 1000 rad/s (160 Hz): kp = J·ω², kd = 2ζ·J·ω (ζ = 0.7),
    /// ki = kp·ω/4. At 2 kHz the loop goes unstable near ω = 1400 rad/s; ±20 % of inertia
    /// moves ω within 900..1120 rad/s. The stiffness is what holds the following error at 5 g
    /// to a few micrometres when the feed-forward's masses are 20 % off (issue 14).
    fn default() -> Self {
        const INERTIA_KG_M2: f32 = 7.4e-3;
        const OMEGA_RAD_S: f32 = 1000.0;
        let kp = INERTIA_KG_M2 * OMEGA_RAD_S * OMEGA_RAD_S;
        let axis = AxisGains {
            kp_nm_per_rad: kp,
            ki_nm_per_rad_s: kp * OMEGA_RAD_S / 4.0,
            kd_nm_s_per_rad: 2.0 * 0.7 * INERTIA_KG_M2 * OMEGA_RAD_S,
            inertia_ff_kg_m2: INERTIA_KG_M2,
            viscous_ff_nm_s_per_rad: 0.0,
            // Off: set it to (a little under) the friction identified at commissioning;
            // on a frictionless axis it only pushes the axis through each reversal.
            coulomb_ff_nm: 0.0,
            coulomb_ff_speed_rad_s: 0.01,
            torque_limit_nm: 8.0,
            integral_limit_nm: 2.0,
        };
        ServoConfig {
            sample_period_s: 5.0e-4,
            axes: [axis; 2],
            min_transmission: 0.05,
            max_speed_mm_s: 3_000.0,
            max_accel_mm_s2: 5.0 * STANDARD_GRAVITY_MM_S2 * 1.05,
            max_following_error_rad: 0.02,
        }
    }
}

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
        Calibration { model: *grid.model(), grid: Some(grid) }
    }

    /// Encoder angles that put the tool at `tool_mm`: model IK plus grid correction. This is the
    /// one function that turns a target into a motor command, on the MCU and in the host tools.
    /// ([`Servo::step_motion`] keeps the model's angle from the IK it solved for the setpoint a
    /// step earlier, and corrects it here.)
    pub fn command_rad(&self, tool_mm: [f32; 2], min_transmission: f32) -> Result<[f32; 2], ServoFault> {
        let theta = self.model.inverse(tool_mm, min_transmission).map_err(ServoFault::Kinematics)?;
        self.corrected_rad(tool_mm, theta)
    }

    /// The model's encoder angles `theta_rad` for `tool_mm` plus the grid correction there.
    pub fn corrected_rad(&self, tool_mm: [f32; 2], theta_rad: [f32; 2]) -> Result<[f32; 2], ServoFault> {
        match &self.grid {
            None => Ok(theta_rad),
            Some(grid) => {
                let d = grid.correction_rad(tool_mm).map_err(ServoFault::Grid)?;
                Ok([theta_rad[0] + d[0], theta_rad[1] + d[1]])
            }
        }
    }
}

/// Why the servo stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoFault {
    /// `step` was called before `engage`, or after a fault without re-engaging.
    NotEngaged,
    /// A setpoint coordinate is NaN or infinite.
    NonFiniteSetpoint,
    /// An encoder reading is NaN or infinite.
    NonFiniteFeedback,
    /// The setpoint is unreachable or too close to a singularity.
    Kinematics(KinematicsError),
    /// The setpoint is outside the correction grid.
    Grid(GridError),
    /// The setpoint sequence needs more speed or acceleration than the limits allow.
    SetpointJump,
    /// The motor lags its reference by more than the limit.
    FollowingError,
}

impl core::fmt::Display for ServoFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ServoFault::NotEngaged => f.write_str("servo not engaged"),
            ServoFault::NonFiniteSetpoint => f.write_str("non-finite setpoint"),
            ServoFault::NonFiniteFeedback => f.write_str("non-finite encoder reading"),
            ServoFault::Kinematics(e) => write!(f, "setpoint refused: {e}"),
            ServoFault::Grid(e) => write!(f, "setpoint refused: {e}"),
            ServoFault::SetpointJump => f.write_str("setpoint jump beyond speed/acceleration limits"),
            ServoFault::FollowingError => f.write_str("following error beyond limit"),
        }
    }
}

/// The message already names the kinematic or grid error inside, so `source` stays `None`
/// (a reporter walking the chain would print it twice).
impl core::error::Error for ServoFault {}

/// What one sample produced.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ServoOutput {
    /// Joint torque commands (N·m), within the configured limits.
    pub torque_nm: [f32; 2],
    /// The encoder angles the axes were asked to reach.
    pub reference_rad: [f32; 2],
    /// `reference - encoder` (rad).
    pub following_error_rad: [f32; 2],
}

/// History the step needs from earlier samples.
#[derive(Clone, Copy, Debug, PartialEq)]
struct History {
    setpoint_mm: [[f32; 2]; 2],
    reference_rad: [[f32; 2]; 2],
    encoder_rad: [f32; 2],
}

/// The servo of both motors.
#[derive(Clone, Debug)]
pub struct Servo {
    config: ServoConfig,
    axes: [AxisController; 2],
    history: Option<History>,
    fault: Option<ServoFault>,
    dynamics: Option<FiveBarDynamics<f32>>,
    /// Two joint states: this step's setpoint's and the next's. Solved in place (no copies).
    joint: [JointSample<f32>; 2],
    /// Which slot holds the last step's next setpoint's state, if still valid.
    ahead: Option<usize>,
}

fn finite2(v: [f32; 2]) -> bool {
    v[0].is_finite() && v[1].is_finite()
}

/// Every number of the setpoint finite: exactly when their sum is (a sum beyond 1e38 is no
/// setpoint either). Cheaper than testing each.
#[inline(always)]
fn finite_setpoint(s: &MotionSetpoint<f32>) -> bool {
    let sum = [s.position_mm, s.velocity_mm_s, s.acceleration_mm_s2, s.jerk_mm_s3].iter().flatten().fold(0.0f32, |a, v| a + v);
    #[allow(clippy::eq_op)] // `sum - sum` is the test
    let finite = sum - sum == 0.0;
    finite
}

/// `angle` plus the multiple of 2π that brings it nearest to `near`: `angle` itself, after one
/// comparison, when it is within π already (every sample of a continuous motion).
#[inline]
fn unwrap_near(angle: f32, near: f32) -> f32 {
    if (near - angle).abs() < core::f32::consts::PI {
        return angle;
    }
    let two_pi = 2.0 * core::f32::consts::PI;
    // The trait method: `f32::round` is std-only, this crate is no_std.
    angle + two_pi * Real::round((near - angle) / two_pi)
}

impl Servo {
    /// A servo with `config`, not engaged yet.
    pub fn new(config: ServoConfig) -> Self {
        Servo {
            config,
            axes: [AxisController::default(); 2],
            history: None,
            fault: None,
            dynamics: None,
            joint: [JointSample::zero(); 2],
            ahead: None,
        }
    }

    /// The identified dynamics [`Servo::step_motion`] feeds forward (`None`: the gains'
    /// constant feed-forward). Refused if out of range; the servo keeps what it had.
    pub fn set_dynamics(&mut self, dynamics: Option<FiveBarDynamics<f32>>) -> Result<(), DynamicsError> {
        if let Some(d) = &dynamics {
            d.validate()?;
        }
        self.dynamics = dynamics;
        Ok(())
    }

    /// The dynamics fed forward, if any.
    pub fn dynamics(&self) -> Option<&FiveBarDynamics<f32>> {
        self.dynamics.as_ref()
    }

    /// Its gains and limits.
    pub fn config(&self) -> &ServoConfig {
        &self.config
    }

    /// The latched fault, if any.
    pub fn fault(&self) -> Option<ServoFault> {
        self.fault
    }

    /// Arms the servo at the machine's current position and returns that tool position: the
    /// first setpoints must start there (a setpoint far from it is a jump).
    pub fn engage(&mut self, cal: &Calibration<'_>, encoder_rad: [f32; 2]) -> Result<[f32; 2], ServoFault> {
        self.history = None;
        self.fault = None;
        self.ahead = None;
        self.axes = [AxisController::default(); 2];
        if !finite2(encoder_rad) {
            return Err(self.latch(ServoFault::NonFiniteFeedback));
        }
        let m = self.config.min_transmission;
        // Undo the correction by one fixed-point step: p = FK(θ - δ(FK(θ))). The correction
        // varies over millimetres, so the second pass is exact to well below a micrometre.
        let mut tool = cal.model.forward(encoder_rad, 0.0).map_err(|e| self.latch(ServoFault::Kinematics(e)))?;
        if let Some(grid) = &cal.grid {
            let d = grid.correction_rad(tool).map_err(|e| self.latch(ServoFault::Grid(e)))?;
            tool = cal
                .model
                .forward([encoder_rad[0] - d[0], encoder_rad[1] - d[1]], m)
                .map_err(|e| self.latch(ServoFault::Kinematics(e)))?;
        }
        self.history = Some(History {
            setpoint_mm: [tool; 2],
            reference_rad: [encoder_rad; 2],
            encoder_rad,
        });
        Ok(tool)
    }

    fn latch(&mut self, fault: ServoFault) -> ServoFault {
        self.fault = Some(fault);
        self.history = None;
        self.ahead = None;
        for a in &mut self.axes {
            a.reset();
        }
        fault
    }

    /// One sample. On `Err` the fault is latched and both torques must be taken as zero.
    pub fn step(
        &mut self,
        cal: &Calibration<'_>,
        setpoint_mm: [f32; 2],
        encoder_rad: [f32; 2],
    ) -> Result<ServoOutput, ServoFault> {
        let h = self.accept(setpoint_mm, encoder_rad)?;
        let command = match cal.command_rad(setpoint_mm, self.config.min_transmission) {
            Ok(c) => c,
            Err(f) => return Err(self.latch(f)),
        };
        self.close_loop(h, setpoint_mm, command, encoder_rad, None)
    }

    /// One sample towards `setpoint` with its exact derivatives, `next` the setpoint one sample
    /// later if known (else it is predicted from `setpoint`'s acceleration and jerk): the checks
    /// of [`Servo::step`], plus the setpoint's derivatives finite and its stated speed and
    /// acceleration within the limits (`next` is checked when it is the setpoint). On `Err` the
    /// fault is latched and both torques must be taken as zero.
    pub fn step_motion(
        &mut self,
        cal: &Calibration<'_>,
        setpoint: &MotionSetpoint<f32>,
        next: Option<&MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<ServoOutput, ServoFault> {
        let cfg = self.config;
        if self.history.is_some() {
            if !finite_setpoint(setpoint) {
                return Err(self.latch(ServoFault::NonFiniteSetpoint));
            }
            let (v, a) = (setpoint.velocity_mm_s, setpoint.acceleration_mm_s2);
            if !(v[0] * v[0] + v[1] * v[1] <= cfg.max_speed_mm_s * cfg.max_speed_mm_s)
                || !(a[0] * a[0] + a[1] * a[1] <= cfg.max_accel_mm_s2 * cfg.max_accel_mm_s2)
            {
                return Err(self.latch(ServoFault::SetpointJump));
            }
        }
        let p = setpoint.position_mm;
        let h = self.accept(p, encoder_rad)?;
        let m = cfg.min_transmission;
        // This setpoint's joint state: the last step's look-ahead if it was this setpoint.
        let now = match self.ahead {
            Some(i) if self.joint[i].is_for(setpoint) => i,
            _ => {
                if let Err(e) = self.joint[0].solve(&cal.model, setpoint, m) {
                    return Err(self.latch(ServoFault::Kinematics(e)));
                }
                0
            }
        };
        let (a, b) = self.joint.split_at_mut(1);
        let (now_state, next_state) = if now == 0 { (&a[0], &mut b[0]) } else { (&b[0], &mut a[0]) };
        // The look-ahead never faults this sample: a next setpoint that is not finite or not
        // reachable is refused in its own sample; until then the prediction stands in for it
        // (and, if that is out of reach too, no motion).
        let solved = match next {
            Some(n) if finite_setpoint(n) => next_state.solve(&cal.model, n, m).is_ok(),
            _ => false,
        };
        if !solved && next_state.solve(&cal.model, &predict(setpoint, cfg.sample_period_s), m).is_err() {
            *next_state = *now_state;
        }
        let motion = interval_motion(now_state, next_state, cfg.sample_period_s);
        let command = match cal.corrected_rad(p, now_state.angle_rad) {
            Ok(c) => c,
            Err(f) => return Err(self.latch(f)),
        };
        let ff = match feed_forward_nm(&motion, self.dynamics.as_ref(), &cfg.axes) {
            Ok(t) => t,
            Err(e) => return Err(self.latch(ServoFault::Kinematics(e))),
        };
        let out = self.close_loop(h, p, command, encoder_rad, Some(ff))?;
        self.ahead = Some(1 - now);
        Ok(out)
    }

    /// The checks every sample starts with: engaged, finite setpoint and encoders, a setpoint
    /// sequence within the speed and acceleration limits (backward differences).
    fn accept(&mut self, setpoint_mm: [f32; 2], encoder_rad: [f32; 2]) -> Result<History, ServoFault> {
        let Some(h) = self.history else {
            return Err(self.fault.unwrap_or(ServoFault::NotEngaged));
        };
        let cfg = self.config;
        let dt = cfg.sample_period_s;
        if !finite2(setpoint_mm) {
            return Err(self.latch(ServoFault::NonFiniteSetpoint));
        }
        if !finite2(encoder_rad) {
            return Err(self.latch(ServoFault::NonFiniteFeedback));
        }
        // Speed and acceleration the setpoint sequence implies (backward differences), compared
        // as the steps they allow in one and two samples (no division).
        let [p1, p2] = h.setpoint_mm;
        let d1 = [setpoint_mm[0] - p1[0], setpoint_mm[1] - p1[1]];
        let d2 = [setpoint_mm[0] - 2.0 * p1[0] + p2[0], setpoint_mm[1] - 2.0 * p1[1] + p2[1]];
        let step = cfg.max_speed_mm_s * dt;
        let bend = cfg.max_accel_mm_s2 * dt * dt;
        if !(d1[0] * d1[0] + d1[1] * d1[1] <= step * step) || !(d2[0] * d2[0] + d2[1] * d2[1] <= bend * bend) {
            return Err(self.latch(ServoFault::SetpointJump));
        }
        Ok(h)
    }

    /// References, following-error check and the PIDs for the encoder angles `command`:
    /// with the gains' feed-forward on differences of the references (`feedforward_nm` `None`,
    /// [`Servo::step`]) or with the given feed-forward torques.
    #[inline(always)]
    fn close_loop(
        &mut self,
        h: History,
        setpoint_mm: [f32; 2],
        command: [f32; 2],
        encoder_rad: [f32; 2],
        feedforward_nm: Option<[f32; 2]>,
    ) -> Result<ServoOutput, ServoFault> {
        let cfg = self.config;
        let dt = cfg.sample_period_s;
        let rate = 1.0 / dt;
        let [r1, r2] = h.reference_rad;
        let mut out = ServoOutput { torque_nm: [0.0; 2], reference_rad: [0.0; 2], following_error_rad: [0.0; 2] };
        for k in 0..2 {
            let reference = unwrap_near(command[k], r1[k]);
            let error = reference - encoder_rad[k];
            if !(error.abs() <= cfg.max_following_error_rad) {
                return Err(self.latch(ServoFault::FollowingError));
            }
            let moved = encoder_rad[k] - h.encoder_rad[k];
            out.torque_nm[k] = match feedforward_nm {
                None => {
                    let axis_ref = AxisReference {
                        angle_rad: reference,
                        velocity_rad_s: (reference - r1[k]) / dt,
                        acceleration_rad_s2: (reference - 2.0 * r1[k] + r2[k]) / (dt * dt),
                    };
                    self.axes[k].update(&cfg.axes[k], &axis_ref, encoder_rad[k], moved / dt, dt)
                }
                // The velocity error from backward differences of both, so that a reference
                // followed exactly gives none (the measured velocity is half a sample old).
                Some(ff) => self.axes[k].feedback(&cfg.axes[k], error, ((reference - r1[k]) - moved) * rate, ff[k], dt),
            };
            out.reference_rad[k] = reference;
            out.following_error_rad[k] = error;
        }
        let [p1, _] = h.setpoint_mm;
        self.history = Some(History {
            setpoint_mm: [setpoint_mm, p1],
            reference_rad: [out.reference_rad, r1],
            encoder_rad,
        });
        Ok(out)
    }
}
