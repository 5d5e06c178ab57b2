//! Homing: establishes the encoder zero the calibration refers to, from each joint's index
//! pulse, then moves to the home position. Pure logic; the servo loop runs it sample by sample
//! ([`crate::servo_loop::ServoLoop::step_homing`]) and the board latches the index and sets the
//! reference (`EncoderScale::set_reference`).
//!
//! # Why it is needed
//! An incremental encoder's counter reads 0 wherever the machine stands at power-on, so the
//! joint angle is only known relative to that position. The calibration's model and grid refer
//! to the zero its identification used; until the zero is re-established, a setpoint in
//! millimetres has no meaning and the servo refuses every setpoint (mode `Unhomed`, drives off).
//! With absolute encoders (`HomingSettings::absolute_encoders`) the zero is known at power-on
//! and homing is skipped.
//!
//! # The procedure (index pulses)
//! Precondition: the tool stands inside the calibrated rectangle (the machine is switched off
//! there; a category-0 coast ends there, see `scenario::stop_check`). Then, in joint space,
//! with torque limited to `torque_limit_nm` and the speed, acceleration and jerk to the homing
//! limits (a jerk-limited rest-to-rest profile, never a step):
//! 1. **Search, axis after axis** (`order`): the axis moves in its `search_direction` over at
//!    most `max_travel_rad`, the other holds. When the board reports the index, the move is
//!    cut short: its cruise ends there and the profile's own deceleration follows (position,
//!    velocity and acceleration continuous). The index angle (`index_rad`) and the travel are
//!    chosen so that, from any start in the rectangle, the index lies ahead within the travel.
//! 2. **Reference**: both axes' readings at their index are tied to `index_rad`; the board
//!    calls `EncoderScale::set_reference`, the readings become absolute.
//! 3. **To home**: a straight joint-space move (both axes, one jerk-limited profile) to the
//!    encoder angles of the home position (model IK plus grid correction), then the servo
//!    engages in task space there and the mode becomes `Running`.
//!
//! **Kinematics-aware.** Moving one joint while the other holds swings the tool on a circle;
//! towards one side the five-bar stretches (distal links aligned: the reach singularity),
//! towards the other it folds. [`check_plan`] walks every sweep of the procedure (from a
//! lattice of start points over the calibrated rectangle, every search, the overshoot past the
//! index and the move to home) through the nominal model and refuses the settings if any pose
//! on the way has a transmission `|sin|` below `min_transmission` or cannot be assembled in the
//! working mode in use. The defaults (the paper's machine: the arms open, joint 1 upwards and
//! joint 2 downwards, away from the stretched singularity) pass with the margin printed by the
//! test `the_default_plan_keeps_away_from_singularities`. The servo loop runs it once at boot.
//!
//! # Failures: stop and report
//! * the index not found within `max_travel_rad`: the search has come to rest at the end of its
//!   profile; [`HomingFault::IndexNotFound`], category 1 (torque off at standstill);
//! * following error beyond `following_error_rad` (a blocked axis, a wrong sign, a collision):
//!   [`HomingFault::FollowingError`], category 0;
//! * an encoder fault (`encoder_check`, run as in every sample): category 0;
//! * the home position's IK refused, or a reference the scale refuses: [`HomingFault::Reference`],
//!   category 1 (the machine is at rest then).
//!
//! Hard stops (a documented alternative, not implemented): the same search at a low torque
//! limit until the following error grows while the speed is zero; the stop's angle is the
//! reference. Hard stops wear and deflect; the index is preferred wherever the encoder has one.
//!
//! Cost: one profile evaluation and two PID updates per sample (less than the servo step).
use kinematics_core::jerk_profile::{JerkProfile, ProfileLimits};
use kinematics_core::{AxisController, AxisGains, AxisReference, FiveBar};

/// Which way an axis searches for its index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Direction {
    /// Joint angle increasing.
    Positive,
    /// Joint angle decreasing.
    Negative,
}

impl Direction {
    fn sign(self) -> f32 {
        match self {
            Direction::Positive => 1.0,
            Direction::Negative => -1.0,
        }
    }
}

/// How the machine is homed (`Settings::homing`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HomingSettings {
    /// The encoders are absolute: the zero is known at power-on, no homing, the servo engages
    /// at boot. Default `false`.
    pub absolute_encoders: bool,
    /// Home at boot. Default `false`: a real machine does not move by itself at power-on; the
    /// host's Home command starts it. The QEMU board's `homing` scenarios set it.
    pub at_boot: bool,
    /// Encoder angle of each axis's index mark (rad, the encoder angle the kinematics use).
    /// Default (1.40, −1.40): beyond the angles the paper machine's calibrated rectangle needs
    /// (joint 1 0.15..1.37 rad, joint 2 −1.37..−0.15 rad) in the search direction.
    pub index_rad: [f32; 2],
    /// Search direction per axis. Default: joint 1 positive, joint 2 negative (the arms open,
    /// away from the stretched singularity).
    pub search_direction: [Direction; 2],
    /// Which axis searches first (0 or 1), the other second. Default [0, 1].
    pub order: [u8; 2],
    /// Longest search per axis (rad). Default 1.35 rad: the whole range from the far side of
    /// the rectangle to the index, plus margin.
    pub max_travel_rad: [f32; 2],
    /// Speed, acceleration and jerk limits of every homing move (joint space, rad/s, rad/s²,
    /// rad/s³). Default 1 rad/s (150 mm/s at a 150 mm link, a tenth of the tour's speed),
    /// 10 rad/s², 400 rad/s³.
    pub speed_rad_s: f32,
    /// See `speed_rad_s`.
    pub accel_rad_s2: f32,
    /// See `speed_rad_s`.
    pub jerk_rad_s3: f32,
    /// Torque limit while homing (N·m). Default 2 N·m (the servo's is 8).
    pub torque_limit_nm: f32,
    /// Following error that ends homing (rad). Default 0.01 rad.
    pub following_error_rad: f32,
    /// Smallest transmission `|sin|` any pose of the procedure may have ([`check_plan`]).
    /// Default 0.2 (the servo's own margin is 0.05).
    pub min_transmission: f32,
}

impl Default for HomingSettings {
    fn default() -> Self {
        HomingSettings {
            absolute_encoders: false,
            at_boot: false,
            index_rad: [1.40, -1.40],
            search_direction: [Direction::Positive, Direction::Negative],
            order: [0, 1],
            max_travel_rad: [1.35, 1.35],
            speed_rad_s: 1.0,
            accel_rad_s2: 10.0,
            jerk_rad_s3: 400.0,
            torque_limit_nm: 2.0,
            following_error_rad: 0.01,
            min_transmission: 0.2,
        }
    }
}

impl HomingSettings {
    /// Every number finite and positive where it must be, `order` a permutation of the axes.
    pub fn validate(&self) -> Result<(), &'static str> {
        let positive = |v: f32| v.is_finite() && v > 0.0;
        for (ok, name) in [
            (
                self.index_rad.iter().all(|v| v.is_finite()),
                "homing.index_rad",
            ),
            (
                self.max_travel_rad.iter().all(|&v| positive(v)),
                "homing.max_travel_rad",
            ),
            (positive(self.speed_rad_s), "homing.speed_rad_s"),
            (positive(self.accel_rad_s2), "homing.accel_rad_s2"),
            (positive(self.jerk_rad_s3), "homing.jerk_rad_s3"),
            (positive(self.torque_limit_nm), "homing.torque_limit_nm"),
            (
                positive(self.following_error_rad),
                "homing.following_error_rad",
            ),
            (
                (0.0..1.0).contains(&self.min_transmission),
                "homing.min_transmission",
            ),
            (matches!(self.order, [0, 1] | [1, 0]), "homing.order"),
        ] {
            if !ok {
                return Err(name);
            }
        }
        Ok(())
    }

    fn limits(&self) -> ProfileLimits<f32> {
        ProfileLimits {
            velocity: self.speed_rad_s,
            acceleration: self.accel_rad_s2,
            jerk: self.jerk_rad_s3,
        }
    }
}

/// Why homing failed (latched as `Fault::Homing`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingFault {
    /// No index pulse on this axis (0 or 1) within `max_travel_rad`.
    IndexNotFound(u8),
    /// Following error beyond the homing limit on this axis.
    FollowingError(u8),
    /// The home position's IK was refused, or the scale refused the reference.
    Reference,
    /// The homing settings were refused, or the plan came too close to a singularity
    /// ([`check_plan`]); at boot.
    Plan,
}

impl core::fmt::Display for HomingFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            HomingFault::IndexNotFound(a) => write!(
                f,
                "axis {}: index not found within the homing travel",
                a + 1
            ),
            HomingFault::FollowingError(a) => {
                write!(f, "axis {}: following error while homing", a + 1)
            }
            HomingFault::Reference => f.write_str("home position or encoder reference refused"),
            HomingFault::Plan => {
                f.write_str("homing settings refused (limits, or a sweep near a singularity)")
            }
        }
    }
}

/// Where homing is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HomingPhase {
    /// Searching the index of the `n`-th axis of `order` (0 or 1).
    Search(u8),
    /// Both indexes found and the reference set: moving to the home position.
    ToHome,
    /// At home: the servo takes over.
    Done,
    /// Stopped: the fault is latched by the servo loop.
    Failed(HomingFault),
}

/// What a homing sample asks of the servo loop besides its torques.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HomingEvent {
    /// Both indexes found and the machine at rest: tie each axis's reading at its index to
    /// `index_rad` (the board sets the reference; readings shift by `offset_rad`, absolute =
    /// relative + offset), then call [`Homing::referenced`] with the home's encoder angles.
    Reference {
        /// Absolute minus relative angle per axis (rad).
        offset_rad: [f32; 2],
    },
    /// At home, at rest: engage the task-space servo.
    Done,
    /// Stop and report.
    Failed(HomingFault),
}

/// One homing sample's outcome.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingOutput {
    /// Torques (N·m), within the homing limit.
    pub torque_nm: [f32; 2],
    /// The joint reference (rad).
    pub reference_rad: [f32; 2],
    /// Largest |following error| (rad).
    pub following_error_rad: f32,
    /// What the servo loop must do now.
    pub event: Option<HomingEvent>,
}

/// One joint-space move: `from + direction·s(t)`, with the cruise cut short after an index.
#[derive(Clone, Copy, Debug)]
struct Move {
    from_rad: [f32; 2],
    direction: [f32; 2],
    profile: JerkProfile<f32>,
    /// Profile time (s).
    t_s: f32,
    /// Added to the profile's position after a cut (keeps the position continuous).
    s_offset: f32,
    /// Cut the cruise when the acceleration phase ends (the index came during it).
    cut_pending: bool,
}

impl Move {
    fn new(from_rad: [f32; 2], to_rad: [f32; 2], limits: &ProfileLimits<f32>) -> Option<Self> {
        let d = [to_rad[0] - from_rad[0], to_rad[1] - from_rad[1]];
        let len = libm::hypotf(d[0], d[1]);
        let direction = if len > 0.0 {
            [d[0] / len, d[1] / len]
        } else {
            [0.0; 2]
        };
        let profile = JerkProfile::plan(len, limits).ok()?;
        Some(Move {
            from_rad,
            direction,
            profile,
            t_s: 0.0,
            s_offset: 0.0,
            cut_pending: false,
        })
    }

    /// Reference angle, velocity, acceleration per axis at the current time.
    fn at(&self) -> [AxisReference; 2] {
        let s = self.profile.at(self.t_s);
        [0, 1].map(|k| AxisReference {
            angle_rad: self.from_rad[k] + self.direction[k] * (s.position + self.s_offset),
            velocity_rad_s: self.direction[k] * s.velocity,
            acceleration_rad_s2: self.direction[k] * s.acceleration,
        })
    }

    /// Ends the cruise now (or when the acceleration phase ends): jumps to the start of the
    /// deceleration, where velocity and acceleration are the cruise's.
    fn cut(&mut self) {
        let (_, t_a, t_v) = self.profile.phases_s();
        if self.t_s < t_a {
            self.cut_pending = true;
        } else if self.t_s < t_a + t_v {
            let before = self.profile.at(self.t_s).position;
            self.t_s = t_a + t_v;
            self.s_offset += before - self.profile.at(self.t_s).position;
        }
    }

    fn advance(&mut self, dt_s: f32) {
        self.t_s += dt_s;
        let (_, t_a, _) = self.profile.phases_s();
        if self.cut_pending && self.t_s >= t_a {
            self.cut_pending = false;
            self.cut();
        }
    }

    fn finished(&self) -> bool {
        self.t_s >= self.profile.duration_s()
    }

    fn shift(&mut self, offset_rad: [f32; 2]) {
        self.from_rad = [
            self.from_rad[0] + offset_rad[0],
            self.from_rad[1] + offset_rad[1],
        ];
    }
}

/// The homing procedure's state.
#[derive(Clone, Copy, Debug)]
pub struct Homing {
    settings: HomingSettings,
    phase: HomingPhase,
    mv: Move,
    /// Relative reading of each axis at its index.
    index_reading_rad: [Option<f32>; 2],
    pid: [AxisController; 2],
    last_encoder_rad: [f32; 2],
}

impl Homing {
    /// Starts homing at the machine's current reading: the first axis's search.
    pub fn start(settings: &HomingSettings, encoder_rad: [f32; 2]) -> Result<Self, HomingFault> {
        settings.validate().map_err(|_| HomingFault::Plan)?;
        let mut h = Homing {
            settings: *settings,
            phase: HomingPhase::Search(0),
            mv: Move::new(encoder_rad, encoder_rad, &settings.limits()).ok_or(HomingFault::Plan)?,
            index_reading_rad: [None; 2],
            pid: [AxisController::default(); 2],
            last_encoder_rad: encoder_rad,
        };
        h.mv = h.search_move(0, encoder_rad)?;
        Ok(h)
    }

    /// Where homing is.
    pub fn phase(&self) -> HomingPhase {
        self.phase
    }

    fn search_move(&self, n: u8, from_rad: [f32; 2]) -> Result<Move, HomingFault> {
        let axis = self.settings.order[n as usize] as usize;
        let mut to = from_rad;
        to[axis] +=
            self.settings.search_direction[axis].sign() * self.settings.max_travel_rad[axis];
        Move::new(from_rad, to, &self.settings.limits()).ok_or(HomingFault::Plan)
    }

    /// The reference is set: readings are absolute from the next sample; `home_rad` is the
    /// encoder angles of the home position (IK plus grid). Starts the move to home.
    pub fn referenced(
        &mut self,
        offset_rad: [f32; 2],
        home_rad: Result<[f32; 2], HomingFault>,
    ) -> Result<(), HomingFault> {
        self.mv.shift(offset_rad);
        self.last_encoder_rad = [
            self.last_encoder_rad[0] + offset_rad[0],
            self.last_encoder_rad[1] + offset_rad[1],
        ];
        let here = self.mv.at().map(|r| r.angle_rad);
        let result = home_rad.and_then(|home| {
            Move::new(here, home, &self.settings.limits()).ok_or(HomingFault::Reference)
        });
        match result {
            Ok(mv) => {
                self.mv = mv;
                self.phase = HomingPhase::ToHome;
                Ok(())
            }
            Err(f) => {
                self.phase = HomingPhase::Failed(f);
                Err(f)
            }
        }
    }

    /// One sample: `encoder_rad` the readings (relative until referenced), `index_rad` the
    /// reading at an index pulse latched since the last sample, per axis; `gains` the servo's
    /// (the torque limit is replaced by the homing one).
    pub fn step(
        &mut self,
        encoder_rad: [f32; 2],
        index_rad: [Option<f32>; 2],
        gains: &[AxisGains; 2],
        dt_s: f32,
    ) -> HomingOutput {
        let reference = self.mv.at();
        let mut out = HomingOutput {
            torque_nm: [0.0; 2],
            reference_rad: reference.map(|r| r.angle_rad),
            following_error_rad: 0.0,
            event: None,
        };
        if matches!(self.phase, HomingPhase::Done | HomingPhase::Failed(_)) {
            return out;
        }
        for k in 0..2 {
            let error = reference[k].angle_rad - encoder_rad[k];
            out.following_error_rad = out.following_error_rad.max(error.abs());
            if !(error.abs() <= self.settings.following_error_rad) {
                return self.fail(HomingFault::FollowingError(k as u8), out);
            }
        }
        // The PID on the profile, torque-limited.
        for k in 0..2 {
            let velocity = (encoder_rad[k] - self.last_encoder_rad[k]) / dt_s;
            let g = AxisGains {
                torque_limit_nm: self.settings.torque_limit_nm.min(gains[k].torque_limit_nm),
                ..gains[k]
            };
            out.torque_nm[k] =
                self.pid[k].update(&g, &reference[k], encoder_rad[k], velocity, dt_s);
        }
        self.last_encoder_rad = encoder_rad;
        match self.phase {
            HomingPhase::Search(n) => {
                let axis = self.settings.order[n as usize] as usize;
                if self.index_reading_rad[axis].is_none() {
                    if let Some(at) = index_rad[axis] {
                        self.index_reading_rad[axis] = Some(at);
                        self.mv.cut();
                    }
                }
                self.mv.advance(dt_s);
                if self.mv.finished() {
                    if self.index_reading_rad[axis].is_none() {
                        return self.fail(HomingFault::IndexNotFound(axis as u8), out);
                    }
                    let end = self.mv.at().map(|r| r.angle_rad);
                    if n == 0 {
                        match self.search_move(1, end) {
                            Ok(mv) => {
                                self.mv = mv;
                                self.phase = HomingPhase::Search(1);
                            }
                            Err(f) => return self.fail(f, out),
                        }
                    } else {
                        let offset = [0, 1].map(|k| {
                            self.settings.index_rad[k] - self.index_reading_rad[k].unwrap_or(0.0)
                        });
                        // Hold at the end until `referenced` plans the move to home.
                        self.mv = match Move::new(end, end, &self.settings.limits()) {
                            Some(m) => m,
                            None => return self.fail(HomingFault::Plan, out),
                        };
                        out.event = Some(HomingEvent::Reference { offset_rad: offset });
                    }
                }
            }
            HomingPhase::ToHome => {
                self.mv.advance(dt_s);
                if self.mv.finished() {
                    self.phase = HomingPhase::Done;
                    out.event = Some(HomingEvent::Done);
                }
            }
            HomingPhase::Done | HomingPhase::Failed(_) => {}
        }
        out
    }

    fn fail(&mut self, fault: HomingFault, mut out: HomingOutput) -> HomingOutput {
        self.phase = HomingPhase::Failed(fault);
        out.event = Some(HomingEvent::Failed(fault));
        if matches!(fault, HomingFault::FollowingError(_)) {
            out.torque_nm = [0.0; 2];
        }
        out
    }
}

/// The smallest transmission along the whole procedure, over a `lattice`×`lattice` set of start
/// points covering `rect_mm` (x from, x to, y from, y to): every search sweep (to the index plus
/// the overshoot of a profile cut at full speed), and the straight joint-space move to
/// `home_mm`. `Err(start)`: a start point from which a pose cannot be assembled in the working
/// mode, or from which the index is not within the travel.
pub fn plan_margin(
    settings: &HomingSettings,
    model: &FiveBar<f32>,
    rect_mm: [f32; 4],
    home_mm: [f32; 2],
    lattice: usize,
) -> Result<f32, [f32; 2]> {
    let l = settings.limits();
    // Overshoot past the index: the deceleration phase from full speed.
    let overshoot = {
        let p = JerkProfile::plan(10.0, &l).map_err(|_| home_mm)?;
        let (_, t_a, t_v) = p.phases_s();
        p.distance() - p.at(t_a + t_v).position
    };
    let transmission = |theta: [f32; 2]| -> Option<f32> {
        let pose = model.forward_pose(theta, 0.0).ok()?;
        let [s1, s2] = pose.serial_transmission(model);
        Some(s1.min(s2).min(pose.parallel_transmission(model)))
    };
    let home = model.inverse(home_mm, 0.0).map_err(|_| home_mm)?;
    let mut worst = f32::INFINITY;
    let n = lattice.max(2) - 1;
    let step_rad = 0.005;
    for i in 0..=n {
        for j in 0..=n {
            let start_mm = [
                rect_mm[0] + (rect_mm[1] - rect_mm[0]) * i as f32 / n as f32,
                rect_mm[2] + (rect_mm[3] - rect_mm[2]) * j as f32 / n as f32,
            ];
            let mut theta = model.inverse(start_mm, 0.0).map_err(|_| start_mm)?;
            let sweep = |from: [f32; 2], to: [f32; 2], worst: &mut f32| -> Result<(), [f32; 2]> {
                let d = [to[0] - from[0], to[1] - from[1]];
                let steps = (libm::hypotf(d[0], d[1]) / step_rad) as usize + 1;
                for s in 0..=steps {
                    let f = s as f32 / steps as f32;
                    let t =
                        transmission([from[0] + d[0] * f, from[1] + d[1] * f]).ok_or(start_mm)?;
                    *worst = worst.min(t);
                }
                Ok(())
            };
            for &axis in &settings.order {
                let axis = axis as usize;
                let sign = settings.search_direction[axis].sign();
                let to_index = (settings.index_rad[axis] - theta[axis]) * sign;
                if !(to_index >= 0.0 && to_index + overshoot <= settings.max_travel_rad[axis]) {
                    return Err(start_mm);
                }
                let mut end = theta;
                end[axis] = settings.index_rad[axis] + sign * overshoot;
                sweep(theta, end, &mut worst)?;
                theta = end;
            }
            sweep(theta, home, &mut worst)?;
        }
    }
    Ok(worst)
}

/// [`plan_margin`] against `settings.min_transmission`, on a 9×9 lattice.
pub fn check_plan(
    settings: &HomingSettings,
    model: &FiveBar<f32>,
    rect_mm: [f32; 4],
    home_mm: [f32; 2],
) -> Result<f32, HomingFault> {
    match plan_margin(settings, model, rect_mm, home_mm, 9) {
        Ok(m) if m >= settings.min_transmission => Ok(m),
        _ => Err(HomingFault::Plan),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT_S: f32 = crate::SAMPLE_PERIOD_S;
    /// The paper machine's calibrated rectangle (the QEMU image's grid).
    const RECT_MM: [f32; 4] = [162.132, 262.132, -75.0, 75.0];
    const HOME_MM: [f32; 2] = [212.132, 0.0];

    #[test]
    fn the_default_plan_keeps_away_from_singularities() {
        let s = HomingSettings::default();
        let model = FiveBar::paper_nominal();
        let margin = plan_margin(&s, &model, RECT_MM, HOME_MM, 17).unwrap();
        println!("default homing plan: smallest transmission |sin| {margin:.3} over 17x17 starts");
        assert!(margin >= s.min_transmission, "{margin}");
        assert!(check_plan(&s, &model, RECT_MM, HOME_MM).is_ok());
        // Searching the other way (the arms closing) drives joint 1 into the stretched
        // singularity from the rectangle's far edge: refused.
        let closing = HomingSettings {
            search_direction: [Direction::Negative, Direction::Positive],
            index_rad: [0.10, -0.10],
            ..s
        };
        assert_eq!(
            check_plan(&closing, &model, RECT_MM, HOME_MM),
            Err(HomingFault::Plan)
        );
        // An index inside the range (behind some start points): refused.
        let inside = HomingSettings {
            index_rad: [0.8, -1.40],
            ..s
        };
        assert!(plan_margin(&inside, &model, RECT_MM, HOME_MM, 9).is_err());
        // A travel too short for the far side of the rectangle: refused.
        let short = HomingSettings {
            max_travel_rad: [0.5, 0.5],
            ..s
        };
        assert!(plan_margin(&short, &model, RECT_MM, HOME_MM, 9).is_err());
    }

    /// A joint-space plant for the procedure: two inertias with friction, an index mark per
    /// joint, encoders reading relative to the power-on angle.
    struct Joints {
        angle_rad: [f32; 2],
        velocity_rad_s: [f32; 2],
        power_on_rad: [f32; 2],
        index_at_rad: [Option<f32>; 2],
    }

    impl Joints {
        fn reading(&self, offset: [f32; 2]) -> [f32; 2] {
            [0, 1].map(|k| self.angle_rad[k] - self.power_on_rad[k] + offset[k])
        }
        /// Advances one sample; returns the relative reading at an index crossed.
        fn advance(&mut self, torque: [f32; 2]) -> [Option<f32>; 2] {
            let mut crossed = [None; 2];
            for k in 0..2 {
                let before = self.angle_rad[k];
                let w = self.velocity_rad_s[k];
                let friction = 0.01 * w + 0.03 * w / (w.abs() + 1e-3);
                self.velocity_rad_s[k] += (torque[k] - friction) / 7.5e-3 * DT_S;
                self.angle_rad[k] += self.velocity_rad_s[k] * DT_S;
                if let Some(i) = self.index_at_rad[k] {
                    if (before - i) * (self.angle_rad[k] - i) <= 0.0 && before != self.angle_rad[k]
                    {
                        crossed[k] = Some(i - self.power_on_rad[k]);
                    }
                }
            }
            crossed
        }
    }

    struct Run {
        events: Vec<(usize, HomingEvent)>,
        max_torque_nm: f32,
        max_speed_rad_s: f32,
        max_error_rad: f32,
        joints: Joints,
        homing: Homing,
    }

    fn run(s: &HomingSettings, mut j: Joints, home_rad: [f32; 2], samples: usize) -> Run {
        let gains = kinematics_core::ServoConfig::default().axes;
        let mut h = Homing::start(s, j.reading([0.0; 2])).unwrap();
        let mut r = Run {
            events: vec![],
            max_torque_nm: 0.0,
            max_speed_rad_s: 0.0,
            max_error_rad: 0.0,
            joints: Joints { ..j },
            homing: h,
        };
        let (mut offset, mut index) = ([0.0; 2], [None; 2]);
        for k in 0..samples {
            let out = h.step(j.reading(offset), index, &gains, DT_S);
            r.max_torque_nm = r
                .max_torque_nm
                .max(out.torque_nm[0].abs())
                .max(out.torque_nm[1].abs());
            r.max_error_rad = r.max_error_rad.max(out.following_error_rad);
            if let Some(e) = out.event {
                r.events.push((k, e));
                match e {
                    HomingEvent::Reference { offset_rad } => {
                        offset = offset_rad;
                        h.referenced(offset_rad, Ok(home_rad)).unwrap();
                    }
                    HomingEvent::Done | HomingEvent::Failed(_) => break,
                }
            }
            index = j.advance(out.torque_nm);
            r.max_speed_rad_s = r
                .max_speed_rad_s
                .max(j.velocity_rad_s[0].abs())
                .max(j.velocity_rad_s[1].abs());
        }
        r.joints = j;
        r.homing = h;
        r
    }

    #[test]
    fn homing_finds_both_indexes_sets_the_zero_and_ends_at_home() {
        let s = HomingSettings::default();
        let model = FiveBar::<f32>::paper_nominal();
        let home_rad = model.inverse(HOME_MM, 0.0).unwrap();
        // Power-on somewhere in the rectangle; the counters read 0 there.
        for start_mm in [[214.0, 3.0], [165.0, -70.0], [258.0, 70.0]] {
            let start = model.inverse(start_mm, 0.0).unwrap();
            let j = Joints {
                angle_rad: start,
                velocity_rad_s: [0.0; 2],
                power_on_rad: start,
                index_at_rad: [Some(1.40), Some(-1.40)],
            };
            let r = run(&s, j, home_rad, 40_000);
            let kinds: Vec<_> = r.events.iter().map(|e| e.1).collect();
            assert!(
                matches!(
                    kinds[..],
                    [HomingEvent::Reference { .. }, HomingEvent::Done]
                ),
                "{kinds:?}"
            );
            let HomingEvent::Reference { offset_rad } = kinds[0] else {
                unreachable!()
            };
            // The offset is the power-on angle, to the joint's index resolution.
            for k in 0..2 {
                assert!(
                    (offset_rad[k] - start[k]).abs() < 1e-6,
                    "{start_mm:?} axis {k}: {offset_rad:?} vs {start:?}"
                );
            }
            // At home, within the servo's precision, at rest.
            for k in 0..2 {
                assert!(
                    (r.joints.angle_rad[k] - home_rad[k]).abs() < 2e-4,
                    "{:?} vs {home_rad:?}",
                    r.joints.angle_rad
                );
                assert!(r.joints.velocity_rad_s[k].abs() < 0.05);
            }
            assert_eq!(r.homing.phase(), HomingPhase::Done);
            assert!(
                r.max_torque_nm <= s.torque_limit_nm + 1e-6,
                "{}",
                r.max_torque_nm
            );
            assert!(
                r.max_speed_rad_s <= s.speed_rad_s * 1.05,
                "{}",
                r.max_speed_rad_s
            );
            assert!(
                r.max_error_rad < s.following_error_rad,
                "{}",
                r.max_error_rad
            );
            println!(
                "homed from {start_mm:?} in {} samples, worst following error {:.2e} rad",
                r.events[1].0, r.max_error_rad
            );
        }
    }

    #[test]
    fn an_index_that_never_comes_ends_at_rest_within_the_travel() {
        let s = HomingSettings::default();
        let start = [0.8, -0.75];
        let j = Joints {
            angle_rad: start,
            velocity_rad_s: [0.0; 2],
            power_on_rad: start,
            index_at_rad: [Some(1.40), None],
        };
        let r = run(&s, j, [0.0; 2], 40_000);
        let last = r.events.last().unwrap().1;
        assert_eq!(last, HomingEvent::Failed(HomingFault::IndexNotFound(1)));
        assert!(!r
            .events
            .iter()
            .any(|e| matches!(e.1, HomingEvent::Reference { .. })));
        // Axis 2 travelled its whole search and stands at its end, at rest.
        assert!(
            (r.joints.angle_rad[1] - (start[1] - s.max_travel_rad[1])).abs() < 1e-3,
            "{:?}",
            r.joints.angle_rad
        );
        assert!(
            r.joints.velocity_rad_s[1].abs() < 0.05,
            "{:?}",
            r.joints.velocity_rad_s
        );
        assert_eq!(
            r.homing.phase(),
            HomingPhase::Failed(HomingFault::IndexNotFound(1))
        );
    }

    #[test]
    fn a_blocked_axis_is_a_following_error_with_zero_torque() {
        let s = HomingSettings::default();
        let gains = kinematics_core::ServoConfig::default().axes;
        let mut h = Homing::start(&s, [0.0; 2]).unwrap();
        let mut failed = None;
        for k in 0..10_000 {
            // The encoder never moves: a blocked joint (or a dead encoder).
            let out = h.step([0.0; 2], [None; 2], &gains, DT_S);
            if let Some(HomingEvent::Failed(f)) = out.event {
                assert_eq!(out.torque_nm, [0.0; 2]);
                failed = Some((k, f));
                break;
            }
            assert!(out.torque_nm[0].abs() <= s.torque_limit_nm);
        }
        let (k, f) = failed.expect("not detected");
        assert_eq!(f, HomingFault::FollowingError(0));
        println!("blocked axis found after {k} samples");
        assert!(k < 400, "{k}");
    }

    #[test]
    fn bad_settings_are_refused() {
        let d = HomingSettings::default();
        for bad in [
            HomingSettings {
                speed_rad_s: 0.0,
                ..d
            },
            HomingSettings {
                torque_limit_nm: f32::NAN,
                ..d
            },
            HomingSettings { order: [0, 0], ..d },
            HomingSettings {
                index_rad: [f32::INFINITY, 0.0],
                ..d
            },
            HomingSettings {
                min_transmission: 1.0,
                ..d
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
            assert_eq!(Homing::start(&bad, [0.0; 2]).err(), Some(HomingFault::Plan));
        }
    }
}
