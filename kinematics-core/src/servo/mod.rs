//! The servo step: one 2 kHz sample from task-space setpoint to joint torque commands.
//!
//! ```text
//! setpoint (x, y) ──► jump check ──► hidden-robot IK ──► + grid correction      [accept]
//!      ──► encoder check ──► unwrap ──► + backlash (play of the reference, if the image has
//!      it) ──► feed-forward (finite differences)
//!      ──► following-error check ──► PID per axis ──► torque commands            [track]
//! ```
//! The firmware calls it from its timer interrupt and `host-sim` calls the very same functions
//! against the simulated plant; nothing else computes a motor command.
//!
//! # The two steps
//! * [`Servo::step`] ([`Servo::accept`] then [`AcceptedSetpoint::track`]) takes a bare position
//!   and feeds forward the gains' constant inertia and viscous terms on its backward
//!   differences: the controlled stop's and the blend's setpoints, a host loop's.
//! * [`Servo::step_motion`] ([`Servo::accept_motion`] then [`AcceptedSetpoint::track`]) takes a
//!   [`MotionSetpoint`] (position with its exact velocity, acceleration and jerk, from a
//!   [`crate::trajectory`]) and the next one, if queued: the same refusals (plus the stated speed
//!   and acceleration within the limits), the feed-forward from the identified inverse dynamics
//!   of the mean motion until the next sample ([`crate::feed_forward`]; [`Servo::set_dynamics`];
//!   without them the gains' constant feed-forward on the same motion) plus each joint's
//!   disturbance observer's estimate of what that feed-forward lacks
//!   ([`crate::disturbance_observer`]; `AxisGains::observer_bandwidth_rad_s`, 0 turns it off) and
//!   the PID on the remainder ([`AxisController::feedback`]). The next setpoint's joint state is
//!   kept for the next sample, so each sample solves one IK.
//!
//! Each takes either kind of calibration ([`ServoCalibration`]): a [`Calibration`], whose model
//! every IK checks, or a [`ValidCalibration`], whose model was checked once when it was built
//! (the firmware's: the IK then skips the model check, its margin floor and its test that the
//! target is finite, which the jump check has proven; the angles are bit-identical).
//!
//! # Backlash
//! With a backlash block in the image ([`Calibration::backlash`]; taken at [`Servo::engage`])
//! the reference the motors track is the link reference plus the play operator of its
//! increments ([`crate::backlash`]): within ±β/2, continuous, 0 (mid-gap) at engage and after
//! a fault. Both steps form their reference in [`AcceptedSetpoint::track`], so both compensate.
//!
//! # Two kinds of error, two phases
//! A sample is [`Servo::accept`] then [`AcceptedSetpoint::track`] ([`Servo::step`] does both):
//! * **Setpoint refusals** ([`SetpointRefusal`], from `accept`): a non-finite setpoint, one that
//!   is unreachable, too close to a singularity or outside the correction grid, or a setpoint
//!   sequence that asks for more speed or acceleration than the machine can follow (5 g).
//!   `accept` takes `&self` as far as the servo's state goes: a refusal changes nothing, the
//!   servo stays engaged, and the caller may bring another setpoint *in the same sample* (the
//!   firmware's controlled stop does: the servo, its feedback and the drives are still
//!   trustworthy, so the machine is braked along its path rather than left to coast).
//! * **Faults** ([`ServoFault`], from `track`): a non-finite encoder reading, a following error
//!   beyond the limit. The feedback (or the servo itself) cannot be trusted: the fault latches,
//!   both torques must be taken as zero and every later sample is refused until
//!   [`Servo::engage`] re-arms the servo at the machine's actual position.
//!
//! Between the two phases the caller can inspect what the setpoint implies (its velocity and
//! acceleration, [`AcceptedSetpoint::velocity_mm_s`]) and drop it without effect, which is how
//! the firmware refuses a setpoint whose stopping point would leave the workspace. The
//! [`AcceptedSetpoint`] holds the servo borrowed, so a setpoint accepted against one history
//! cannot be tracked after another.
//!
//! ```
//! use kinematics_core::{Calibration, FiveBar, Servo, ServoConfig};
//!
//! // The nominal model without a grid; an image gives `Calibration::from_grid(grid)`.
//! let cal = Calibration { model: FiveBar::paper_nominal(), grid: None };
//! let mut servo = Servo::new(ServoConfig::default()).unwrap();
//! // Engage where the machine stands: the encoders read the angles of (212.132, 0) mm.
//! let encoder_rad = cal.command_rad([212.132, 0.0], 0.05).unwrap();
//! let at_mm = servo.engage(&cal, encoder_rad).unwrap();
//! assert!((at_mm[0] - 212.132).abs() < 1e-3 && at_mm[1].abs() < 1e-3);
//! // One sample: a setpoint 1 µm along +x; the machine has not moved yet, so the PID pushes.
//! let out = servo.step(&cal, [at_mm[0] + 1e-3, at_mm[1]], encoder_rad).unwrap();
//! assert!(out.torque_nm.iter().any(|t| *t != 0.0));
//! assert!(out.following_error_rad.iter().all(|e| e.abs() < 1e-4));
//! // A setpoint 5 mm away in one sample (10 m/s) is a jump: refused, nothing changed.
//! assert!(servo.step(&cal, [at_mm[0] + 5.0, at_mm[1]], encoder_rad).is_err());
//! ```
//!
//! # Settings
//! [`Servo::new`] validates its [`ServoConfig`] ([`ServoConfig::validate`]): settings come over
//! a link, and no value of them may panic or command a NaN. (The PID itself never panics
//! either, see [`crate::pid`].)
//!
//! # Cost
//! `cargo qemu-bench` prints the instructions (QEMU) and estimated Cortex-M4 cycles
//! (`firmware/qemu/plugin/m4cycles.c`) per call: `servo_step` (a [`ValidCalibration`] with a
//! grid), `servo_step_checking` (a [`Calibration`]: the IK's model check, margin floor and
//! finiteness test on every call), `servo_step_backlash` (with the backlash block),
//! `servo_step_motion` (the motion step with the identified dynamics and both disturbance
//! observers) and their `_uncorrected` variants (today's figures:
//! docs/validation/benchmarks.md); what the step is made of, by instructions: the hidden-robot IK
//! about 45 %, the grid lookup and correction about a fifth, the two PIDs about 15 %, the jump
//! checks, unwrapping, following-error check and history the rest. The motion step adds the next
//! setpoint's IK with the joint rates, the inverse dynamics and the interval's means.
//!
//! What keeps it there: no division in the step (VDIV is 14 cycles): `1 / sample_period_s` and
//! the squared limits are computed once in [`Servo::new`], and the history keeps the previous
//! sample's backward differences, so a second difference is one subtraction; finiteness is
//! never tested on the way through: a NaN or infinite setpoint or encoder reading makes a
//! speed or a following error that no limit admits, and only then is it told apart
//! ([`SetpointRefusal::NonFinite`] from `Jump`, [`ServoFault::NonFiniteFeedback`] from
//! `FollowingError`); the PID saturates in two comparisons in the usual case
//! ([`crate::pid::saturate`]) and skips the Coulomb term's division when it is off;
//! [`AcceptedSetpoint::track`] and the PID are inlined. No allocation, no panic on any input or
//! setting (property-tested).

use crate::backlash::Backlash;
use crate::disturbance_observer::{DisturbanceObserver, ObserverCoefficients};
use crate::dynamics::{DynamicsError, FiveBarDynamics};
use crate::feed_forward::{feed_forward_nm, interval_motion, predict, JointSample};
use crate::grid::GridError;
use crate::pid::{AxisController, AxisGains, AxisReference};
use crate::real::Real;
use crate::trajectory::MotionSetpoint;
use crate::valid_model::IkMargin;

mod calibration;
mod config;
use crate::KinematicsError;
pub use calibration::{Calibration, ServoCalibration, ValidCalibration};
pub use config::{ConfigError, ServoConfig, STANDARD_GRAVITY_MM_S2};

/// Why the servo refused a setpoint. Nothing is latched: the servo is exactly as before the
/// call, still engaged, and takes another setpoint (in the same sample, too).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SetpointRefusal {
    /// The servo is not engaged (never, or a [`ServoFault`] latched since): nothing is accepted.
    NotEngaged,
    /// A setpoint coordinate is NaN or infinite.
    NonFinite,
    /// The setpoint is unreachable or too close to a singularity.
    Kinematics(KinematicsError),
    /// The setpoint is outside the correction grid.
    Grid(GridError),
    /// The setpoint sequence needs more speed or acceleration than the limits allow.
    Jump,
}

impl core::fmt::Display for SetpointRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SetpointRefusal::NotEngaged => f.write_str("setpoint refused: servo not engaged"),
            SetpointRefusal::NonFinite => f.write_str("non-finite setpoint"),
            SetpointRefusal::Kinematics(e) => write!(f, "setpoint refused: {e}"),
            SetpointRefusal::Grid(e) => write!(f, "setpoint refused: {e}"),
            SetpointRefusal::Jump => f.write_str("setpoint jump beyond speed/acceleration limits"),
        }
    }
}

/// The message already names the kinematic or grid error inside, so `source` stays `None`
/// (a reporter walking the chain would print it twice).
impl core::error::Error for SetpointRefusal {}

/// A fault of the feedback or of the servo itself: latched, both torques zero, every later
/// sample refused until [`Servo::engage`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoFault {
    /// `track` was called before `engage`, or after a fault without re-engaging.
    NotEngaged,
    /// An encoder reading is NaN or infinite.
    NonFiniteFeedback,
    /// The motor lags its reference by more than the limit.
    FollowingError,
}

impl core::fmt::Display for ServoFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ServoFault::NotEngaged => f.write_str("servo not engaged"),
            ServoFault::NonFiniteFeedback => f.write_str("non-finite encoder reading"),
            ServoFault::FollowingError => f.write_str("following error beyond limit"),
        }
    }
}

impl core::error::Error for ServoFault {}

/// Why [`Servo::step`] produced no torque: a refused setpoint (nothing latched) or a fault
/// (latched).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StepError {
    /// [`Servo::accept`] refused the setpoint; the servo is unchanged.
    Refused(SetpointRefusal),
    /// [`AcceptedSetpoint::track`] latched a fault.
    Fault(ServoFault),
}

impl core::fmt::Display for StepError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            StepError::Refused(r) => r.fmt(f),
            StepError::Fault(e) => e.fmt(f),
        }
    }
}

impl core::error::Error for StepError {}

/// Why [`Servo::engage`] refused: the encoder reading is no tool position the servo can start
/// from. Nothing is engaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EngageError {
    /// An encoder reading is NaN or infinite.
    NonFiniteFeedback,
    /// The forward kinematics refuse the encoder reading (the arms cannot meet there, or the
    /// pose is too close to a singularity).
    Kinematics(KinematicsError),
    /// The tool position the encoders give is outside the correction grid.
    Grid(GridError),
}

impl core::fmt::Display for EngageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EngageError::NonFiniteFeedback => {
                f.write_str("engage refused: non-finite encoder reading")
            }
            EngageError::Kinematics(e) => write!(f, "engage refused: {e}"),
            EngageError::Grid(e) => write!(f, "engage refused: {e}"),
        }
    }
}

impl core::error::Error for EngageError {}

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

/// History the step needs from earlier samples: the last tracked setpoint and reference with
/// the backward differences computed for them, so that a sample's second differences are one
/// subtraction from its first (no division by `dt²`, no recomputation).
#[derive(Clone, Copy, Debug, PartialEq)]
struct History {
    setpoint_mm: [f32; 2],
    velocity_mm_s: [f32; 2],
    reference_rad: [f32; 2],
    reference_velocity_rad_s: [f32; 2],
    encoder_rad: [f32; 2],
}

/// What the step needs of the settings in the form it uses them, computed once when the servo
/// is built (the settings do not change afterwards): no division by `dt` in the hot path
/// (VDIV is 14 cycles on the Cortex-M4), no squaring of the limits.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Derived {
    /// `1 / sample_period_s` (Hz).
    rate_hz: f32,
    /// `max_speed_mm_s²`, at most `f32::MAX`: a non-finite speed never compares below it.
    max_speed2: f32,
    /// `max_accel_mm_s2²`, at most `f32::MAX`.
    max_accel2: f32,
    /// `min_transmission` raised to the IK's floor.
    ik_margin: IkMargin<f32>,
    /// Each axis' disturbance observer, `α` and `J_n/dt`.
    observer: [ObserverCoefficients; 2],
}

impl Derived {
    fn of(config: &ServoConfig) -> Self {
        let square = |v: f32| (v * v).min(f32::MAX);
        Derived {
            rate_hz: 1.0 / config.sample_period_s,
            max_speed2: square(config.max_speed_mm_s),
            max_accel2: square(config.max_accel_mm_s2),
            ik_margin: IkMargin::new(config.min_transmission),
            observer: config.axes.map(|a| {
                ObserverCoefficients::new(
                    a.observer_bandwidth_rad_s,
                    a.observer_inertia_kg_m2,
                    config.sample_period_s,
                )
            }),
        }
    }
}

/// The servo of both motors.
#[derive(Clone, Debug)]
pub struct Servo {
    config: ServoConfig,
    derived: Derived,
    axes: [AxisController; 2],
    /// The motion step's disturbance observers, one per axis.
    observers: [DisturbanceObserver; 2],
    history: Option<History>,
    fault: Option<ServoFault>,
    /// The identified dynamics the motion step feeds forward.
    dynamics: Option<FiveBarDynamics<f32>>,
    /// Two joint states: a sample's setpoint's and its next's, solved in place (no copies).
    joint: [JointSample<f32>; 2],
    /// Which slot holds the last tracked sample's next setpoint's state.
    ahead: Option<usize>,
    /// The lost motion the reference compensates: the backlash of the calibration the servo
    /// was engaged with ([`Calibration::backlash`], the image's block). Taken at engage, not
    /// per sample: a calibration is engaged before it is stepped, and the correction's state
    /// below only means something for the gap it was built on.
    backlash: Option<Backlash<f32>>,
    /// The backlash correction included in the history's reference (rad, within ±β/2;
    /// [`crate::backlash`]). Set to 0, the mid-gap, at engage and on a fault (the direction
    /// the motors came from is unknown there); only a servo with backlash reads or writes it,
    /// so the step without one pays one branch.
    backlash_rad: [f32; 2],
}

/// A setpoint [`Servo::accept`] found acceptable, with what it implies; the servo stays
/// borrowed until it is tracked or dropped. Dropping it leaves the servo unchanged.
#[derive(Debug)]
pub struct AcceptedSetpoint<'s> {
    servo: &'s mut Servo,
    setpoint_mm: [f32; 2],
    velocity_mm_s: [f32; 2],
    accel_mm_s2: [f32; 2],
    command_rad: [f32; 2],
    /// The motion step's feed-forward (`None`: the gains' on differences, [`Servo::accept`]).
    feedforward_nm: Option<[f32; 2]>,
    /// The slot holding the next setpoint's joint state, kept once tracked.
    ahead: Option<usize>,
}

pub(super) fn finite2(v: [f32; 2]) -> bool {
    v[0].is_finite() && v[1].is_finite()
}

/// Every number of the setpoint finite: exactly when their sum is (a sum beyond 1e38 is no
/// setpoint either). Cheaper than testing each.
#[inline(always)]
fn finite_setpoint(s: &MotionSetpoint<f32>) -> bool {
    let sum = [
        s.position_mm,
        s.velocity_mm_s,
        s.acceleration_mm_s2,
        s.jerk_mm_s3,
    ]
    .iter()
    .flatten()
    .fold(0.0f32, |a, v| a + v);
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
    /// A servo with `config`, not engaged yet; refuses settings [`ServoConfig::validate`]
    /// refuses.
    pub fn new(config: ServoConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Servo {
            config,
            derived: Derived::of(&config),
            axes: [AxisController::default(); 2],
            observers: [DisturbanceObserver::default(); 2],
            history: None,
            fault: None,
            dynamics: None,
            joint: [JointSample::zero(); 2],
            ahead: None,
            backlash: None,
            backlash_rad: [0.0; 2],
        })
    }

    /// The identified dynamics the motion step feeds forward (`None`: the gains' constant
    /// feed-forward). Refused if out of range; the servo keeps what it had.
    pub fn set_dynamics(
        &mut self,
        dynamics: Option<FiveBarDynamics<f32>>,
    ) -> Result<(), DynamicsError> {
        if let Some(d) = &dynamics {
            d.validate()?;
        }
        self.dynamics = dynamics;
        Ok(())
    }

    /// Replaces both axes' gains (checked as [`ServoConfig::validate`] checks them; refused:
    /// the servo keeps what it had) and disengages: new gains take effect at the next
    /// [`Servo::engage`], from rest, never in the middle of a motion. The firmware sets the
    /// gains its calibration's dynamics call for ([`crate::gain_design`]) right before engaging.
    pub fn set_gains(&mut self, axes: [AxisGains; 2]) -> Result<(), ConfigError> {
        let config = ServoConfig {
            axes,
            ..self.config
        };
        config.validate()?;
        self.config = config;
        self.derived = Derived::of(&config);
        self.history = None;
        self.ahead = None;
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

    /// Whether the servo is engaged (and no fault latched since): it accepts setpoints.
    pub fn is_engaged(&self) -> bool {
        self.history.is_some()
    }

    /// Arms the servo at the machine's current position and returns that tool position: the
    /// first setpoints must start there (a setpoint far from it is a jump). Clears a latched
    /// fault; on `Err` the servo is not engaged.
    pub fn engage(
        &mut self,
        cal: &Calibration<'_>,
        encoder_rad: [f32; 2],
    ) -> Result<[f32; 2], EngageError> {
        self.history = None;
        self.fault = None;
        self.ahead = None;
        self.backlash = cal.backlash();
        self.backlash_rad = [0.0; 2];
        self.axes = [AxisController::default(); 2];
        self.observers = [DisturbanceObserver::default(); 2];
        let tool = cal.tool_mm(encoder_rad, self.config.min_transmission)?;
        self.history = Some(History {
            setpoint_mm: tool,
            velocity_mm_s: [0.0; 2],
            reference_rad: encoder_rad,
            reference_velocity_rad_s: [0.0; 2],
            encoder_rad,
        });
        Ok(tool)
    }

    fn latch(&mut self, fault: ServoFault) -> ServoFault {
        self.fault = Some(fault);
        self.history = None;
        self.ahead = None;
        self.backlash_rad = [0.0; 2];
        for a in &mut self.axes {
            a.reset();
        }
        self.observers = [DisturbanceObserver::default(); 2];
        fault
    }

    /// Checks `setpoint_mm` against the setpoint history (speed and acceleration limits), the
    /// kinematics (reach, singularity margin) and the grid, and returns it with the encoder
    /// angles it commands. A refusal changes nothing. With a [`ValidCalibration`] the IK skips
    /// its per-call model check, margin floor and finiteness test (the jump check proves the
    /// setpoint finite: the history's setpoint is, and a speed below a finite limit leaves the
    /// new one finite; a non-finite one is refused there as [`SetpointRefusal::NonFinite`]).
    #[inline(always)]
    pub fn accept(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint_mm: [f32; 2],
    ) -> Result<AcceptedSetpoint<'_>, SetpointRefusal> {
        cal.accept(self, setpoint_mm)
    }

    #[inline(always)]
    fn accept_with(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint_mm: [f32; 2],
    ) -> Result<AcceptedSetpoint<'_>, SetpointRefusal> {
        let (v, a) = self.check_sequence(setpoint_mm)?;
        let command_rad = cal.command_rad_of_finite(setpoint_mm, self.derived.ik_margin)?;
        Ok(AcceptedSetpoint {
            servo: self,
            setpoint_mm,
            velocity_mm_s: v,
            accel_mm_s2: a,
            command_rad,
            feedforward_nm: None,
            ahead: None,
        })
    }

    /// Engaged, a finite setpoint, and the speed and acceleration the setpoint sequence implies
    /// (backward differences, returned) within the limits. A NaN or infinite coordinate makes
    /// the speed NaN or infinite, which never passes the limit (at most `f32::MAX`): finiteness
    /// is told apart from a jump only on the way out. So a setpoint that passes is finite (the
    /// history's setpoint is: engage's FK result or a setpoint that passed), which the IK of
    /// [`Servo::accept`] with a [`ValidCalibration`] relies on instead of testing it again.
    #[inline]
    fn check_sequence(
        &self,
        setpoint_mm: [f32; 2],
    ) -> Result<([f32; 2], [f32; 2]), SetpointRefusal> {
        let Some(h) = &self.history else {
            return Err(SetpointRefusal::NotEngaged);
        };
        let d = &self.derived;
        let rate = d.rate_hz;
        let v = [
            (setpoint_mm[0] - h.setpoint_mm[0]) * rate,
            (setpoint_mm[1] - h.setpoint_mm[1]) * rate,
        ];
        let a = [
            (v[0] - h.velocity_mm_s[0]) * rate,
            (v[1] - h.velocity_mm_s[1]) * rate,
        ];
        let speed2 = v[0] * v[0] + v[1] * v[1];
        let accel2 = a[0] * a[0] + a[1] * a[1];
        if !(speed2 <= d.max_speed2 && accel2 <= d.max_accel2) {
            return Err(if finite2(setpoint_mm) {
                SetpointRefusal::Jump
            } else {
                SetpointRefusal::NonFinite
            });
        }
        Ok((v, a))
    }

    /// [`Servo::accept`] for a setpoint with its exact derivatives, `next` the setpoint one
    /// sample later if known (else it is predicted from `setpoint`'s acceleration and jerk; a
    /// next setpoint that is not finite or not reachable is refused in its own sample, not
    /// here). Refused also if the setpoint's derivatives are not finite or its stated speed or
    /// acceleration exceed the limits. The feed-forward is computed here
    /// ([`crate::feed_forward`]); [`AcceptedSetpoint::velocity_mm_s`] and
    /// [`AcceptedSetpoint::accel_mm_s2`] stay the backward differences. A refusal changes
    /// nothing but the servo's scratch joint states.
    #[inline(always)]
    pub fn accept_motion(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint: &MotionSetpoint<f32>,
        next: Option<&MotionSetpoint<f32>>,
    ) -> Result<AcceptedSetpoint<'_>, SetpointRefusal> {
        cal.accept_motion(self, setpoint, next)
    }

    #[inline(always)]
    fn accept_motion_with(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint: &MotionSetpoint<f32>,
        next: Option<&MotionSetpoint<f32>>,
    ) -> Result<AcceptedSetpoint<'_>, SetpointRefusal> {
        let (cfg, d) = (&self.config, &self.derived);
        if self.history.is_some() {
            if !finite_setpoint(setpoint) {
                return Err(SetpointRefusal::NonFinite);
            }
            let (v, a) = (setpoint.velocity_mm_s, setpoint.acceleration_mm_s2);
            if !(v[0] * v[0] + v[1] * v[1] <= d.max_speed2
                && a[0] * a[0] + a[1] * a[1] <= d.max_accel2)
            {
                return Err(SetpointRefusal::Jump);
            }
        }
        let p = setpoint.position_mm;
        let (velocity_mm_s, accel_mm_s2) = self.check_sequence(p)?;
        let m = d.ik_margin;
        // This setpoint's joint state: the last sample's look-ahead if it was this setpoint.
        let now = match self.ahead {
            Some(i) if self.joint[i].is_for(setpoint) => i,
            _ => {
                cal.solve_joint(&mut self.joint[0], setpoint, m)
                    .map_err(SetpointRefusal::Kinematics)?;
                0
            }
        };
        let (a, b) = self.joint.split_at_mut(1);
        let (now_state, next_state) = if now == 0 {
            (&a[0], &mut b[0])
        } else {
            (&b[0], &mut a[0])
        };
        // The look-ahead never refuses this setpoint: the prediction stands in for a next one
        // that cannot be used (and, if that is out of reach too, no motion).
        let solved = match next {
            Some(n) if finite_setpoint(n) => cal.solve_joint(next_state, n, m).is_ok(),
            _ => false,
        };
        if !solved
            && cal
                .solve_joint(next_state, &predict(setpoint, cfg.sample_period_s), m)
                .is_err()
        {
            *next_state = *now_state;
        }
        let motion = interval_motion(now_state, next_state, d.rate_hz);
        let command_rad = cal.corrected_rad(p, now_state.angle_rad)?;
        let ff = feed_forward_nm(&motion, self.dynamics.as_ref(), &cfg.axes)
            .map_err(SetpointRefusal::Kinematics)?;
        Ok(AcceptedSetpoint {
            servo: self,
            setpoint_mm: p,
            velocity_mm_s,
            accel_mm_s2,
            command_rad,
            feedforward_nm: Some(ff),
            ahead: Some(1 - now),
        })
    }

    /// One motion sample: [`Servo::accept_motion`] then [`AcceptedSetpoint::track`] (see
    /// [`Servo::step`] for what an `Err` means).
    #[inline(always)]
    pub fn step_motion(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint: &MotionSetpoint<f32>,
        next: Option<&MotionSetpoint<f32>>,
        encoder_rad: [f32; 2],
    ) -> Result<ServoOutput, StepError> {
        cal.step_motion(self, setpoint, next, encoder_rad)
    }

    /// One sample: [`Servo::accept`] then [`AcceptedSetpoint::track`]. On
    /// `Err(StepError::Refused(_))` nothing changed (the caller may step again with another
    /// setpoint); on `Err(StepError::Fault(_))` the fault is latched. Either way this sample
    /// produced no torque: take both as zero unless another setpoint is stepped.
    #[inline(always)]
    pub fn step(
        &mut self,
        cal: &impl ServoCalibration,
        setpoint_mm: [f32; 2],
        encoder_rad: [f32; 2],
    ) -> Result<ServoOutput, StepError> {
        cal.step(self, setpoint_mm, encoder_rad)
    }
}

impl AcceptedSetpoint<'_> {
    /// The setpoint (mm).
    pub fn setpoint_mm(&self) -> [f32; 2] {
        self.setpoint_mm
    }

    /// Its velocity (mm/s): the backward difference to the previous accepted setpoint.
    pub fn velocity_mm_s(&self) -> [f32; 2] {
        self.velocity_mm_s
    }

    /// Its acceleration (mm/s²): the second backward difference.
    pub fn accel_mm_s2(&self) -> [f32; 2] {
        self.accel_mm_s2
    }

    /// The encoder angles it commands (IK plus grid correction, before unwrapping and before
    /// the backlash compensation `track` adds; rad).
    pub fn command_rad(&self) -> [f32; 2] {
        self.command_rad
    }

    /// The feed-forward torques of a motion setpoint (N·m; `None` for [`Servo::accept`]'s).
    pub fn feedforward_nm(&self) -> Option<[f32; 2]> {
        self.feedforward_nm
    }

    /// Runs the two position controllers towards the setpoint with the encoders at
    /// `encoder_rad`, and makes the setpoint part of the history. A non-finite encoder reading
    /// or a following error beyond the limit latches a [`ServoFault`]. A motion setpoint
    /// ([`Servo::accept_motion`]) feeds its feed-forward and the PID acts on the remainder, the
    /// velocity error from backward differences of reference and encoder alike (the measured
    /// velocity is half a sample old, so is the reference's).
    #[inline(always)]
    pub fn track(self, encoder_rad: [f32; 2]) -> Result<ServoOutput, ServoFault> {
        let servo = self.servo;
        let Some(h) = servo.history else {
            return Err(servo.fault.unwrap_or(ServoFault::NotEngaged));
        };
        let cfg = &servo.config;
        let dt = cfg.sample_period_s;
        let rate = servo.derived.rate_hz;
        let mut reference = [
            unwrap_near(self.command_rad[0], h.reference_rad[0]),
            unwrap_near(self.command_rad[1], h.reference_rad[1]),
        ];
        // Backlash: the motor leads the link reference by the play operator of the
        // link reference's increments (`crate::backlash`: continuous, never a step of the gap).
        if let Some(b) = &servo.backlash {
            let last = servo.backlash_rad;
            let increment = [0, 1].map(|k| reference[k] - (h.reference_rad[k] - last[k]));
            let c = b.next_correction_rad(last, increment);
            servo.backlash_rad = c;
            reference = [reference[0] + c[0], reference[1] + c[1]];
        }
        let error = [reference[0] - encoder_rad[0], reference[1] - encoder_rad[1]];
        // A NaN or infinite reading makes its error NaN or infinite, beyond any (finite) limit:
        // one comparison per axis covers both faults, told apart on the way out.
        let max = cfg.max_following_error_rad;
        if !(error[0].abs() <= max && error[1].abs() <= max) {
            let fault = if finite2(encoder_rad) {
                ServoFault::FollowingError
            } else {
                ServoFault::NonFiniteFeedback
            };
            return Err(servo.latch(fault));
        }
        let mut out = ServoOutput {
            torque_nm: [0.0; 2],
            reference_rad: reference,
            following_error_rad: error,
        };
        let mut reference_velocity_rad_s = [0.0; 2];
        for k in 0..2 {
            let velocity = (reference[k] - h.reference_rad[k]) * rate;
            let moved = encoder_rad[k] - h.encoder_rad[k];
            let gains = &cfg.axes[k];
            out.torque_nm[k] = match self.feedforward_nm {
                None => {
                    // No model feed-forward to observe the remainder of: the observers restart
                    // when motion samples resume (`DisturbanceObserver::is_current`).
                    let axis_ref = AxisReference {
                        angle_rad: reference[k],
                        velocity_rad_s: velocity,
                        acceleration_rad_s2: (velocity - h.reference_velocity_rad_s[k]) * rate,
                    };
                    servo.axes[k].update(gains, &axis_ref, encoder_rad[k], moved * rate, dt)
                }
                Some(ff) => {
                    let velocity_error = velocity - moved * rate;
                    let observer = &mut servo.observers[k];
                    if !observer.is_current(h.encoder_rad[k]) {
                        observer.restart(velocity_error, 0.0);
                    }
                    let disturbance = observer.estimate_nm(
                        &servo.derived.observer[k],
                        velocity_error,
                        gains.torque_limit_nm,
                        velocity != 0.0,
                    );
                    let torque = servo.axes[k].feedback(
                        gains,
                        error[k],
                        velocity_error,
                        ff[k] + disturbance,
                        dt,
                    );
                    observer.applied(torque - ff[k]);
                    observer.ran_at(encoder_rad[k]);
                    torque
                }
            };
            reference_velocity_rad_s[k] = velocity;
        }
        servo.history = Some(History {
            setpoint_mm: self.setpoint_mm,
            velocity_mm_s: self.velocity_mm_s,
            reference_rad: reference,
            reference_velocity_rad_s,
            encoder_rad,
        });
        servo.ahead = self.ahead;
        Ok(out)
    }
}
