//! Run-time settings of the firmware, in one place.
//!
//! Two sources: the board's (drive-level: gains, encoder resolution, limits of the servo, the
//! stop's dynamics; compiled in, [`Settings::default`] and each board's `settings()`) and the
//! machine's ([`Settings::machine`], the machine record of the calibration image in force,
//! `crate::calibration`): nominal model and working mode, workspace and stop margin, home
//! position, the limits a calibration image is judged against. At boot the app takes the
//! board's settings, judges the image in force and adopts its record
//! ([`Settings::for_machine`]); the app then keeps one `&'static Settings` (set up in `init`)
//! that every task borrows. [`Settings::validate`] checks every field (settings are
//! meant to come over a link): the servo loop refuses to enable the drives with settings it
//! refuses (`Fault::Settings`), and no value of them can make the firmware panic.
use kinematics_core::{ConfigError, ServoConfig};

use crate::calibration::ImageCheck;
use crate::encoder::{EncoderConfig, EncoderConfigError, EncoderScale};
use crate::encoder_check::EncoderLimits;
use crate::homing::HomingSettings;
use crate::plausibility::max_slope_change_rad_per_mm;
use crate::stop::StopSettings;
use crate::waypoint_moves::{Profile, Trajectory};
use kinematics_core::machine::MachineRecord;
use kinematics_core::TaskLimits;

/// Every run-time setting, with the defaults documented on each field.
#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Servo gains and limits: the gains are the design for the inertia in their
    /// `inertia_ff_kg_m2`, scaled to each axis' inertia by the dynamics of the image in force,
    /// or run with the observer off without a dynamics block
    /// (`kinematics_core::gain_design`). Default: `ServoConfig::default()` (7.4e-3 kg·m² per joint,
    /// torque limit 8 N·m, setpoint acceleration limit 5 g·1.05, following error limit
    /// 0.02 rad) with the sample period pinned to the timer's, [`crate::SAMPLE_PERIOD_S`]
    /// (the servo timer runs at [`crate::SAMPLE_RATE_HZ`]; the two must agree).
    pub servo: ServoConfig,
    /// Run without correction grid when the image is bad or missing. Default `false`: the
    /// machine exists for micrometre work and the uncorrected model is off by tens of
    /// micrometres, so a bad image keeps the drives disabled
    /// (docs/design/firmware-architecture.md).
    pub allow_uncorrected: bool,
    /// Consecutive deadline overruns that latch `Fault::DeadlineMissed`. Default 3
    /// (1.5 ms without a fresh torque command).
    pub overrun_streak_limit: u32,
    /// Torque at 0 % / 100 % PWM duty (N·m): the drive's full scale. Default 10 N·m, above the
    /// servo's 8 N·m limit so that the limit, not the PWM, saturates.
    pub drive_full_scale_nm: f32,
    /// Telemetry period in servo samples. Default 500 (4 Hz).
    pub telemetry_period_ticks: u32,
    /// Waypoints of the built-in tour run after engaging; empty: hold the engaged position
    /// until a host link fills the setpoint queue. Default empty: a real machine must not start
    /// moving by itself at power-on. The QEMU board runs
    /// [`WORKSPACE_TOUR_MM`](crate::waypoint_moves::WORKSPACE_TOUR_MM).
    pub builtin_tour_mm: &'static [[f32; 2]],
    /// Each axis's encoder as fitted: counts per motor revolution, counting direction, gear
    /// ratio from motor to joint ([`EncoderConfig`]; the zero comes from homing, not from
    /// here). Default: [`EncoderConfig::DIRECT_DRIVE_2_22`] on both axes, the QEMU board's
    /// simulated encoders; set them for the motors fitted before the first power-up (see the
    /// bring-up guide, docs/guides/g474-bring-up.md). [`Settings::validate`] refuses a
    /// configuration `EncoderScale::new` refuses (`SettingsError::Encoder`), and the board reads
    /// such an axis as NaN, so the drives stay off either way. The encoder check takes each axis's
    /// resolution from here.
    pub encoders: [EncoderConfig; 2],
    /// Peak tool acceleration of the built-in trajectory (mm/s²). Default 2 g.
    pub trajectory_accel_mm_s2: f32,
    /// Peak tool speed of the built-in trajectory (mm/s). Default 1500 mm/s.
    pub trajectory_speed_mm_s: f32,
    /// Peak tool acceleration the host link's streamed knots may have (mm/s²). Default 5 g,
    /// the machine's rated acceleration (the servo accepts 5 g·1.05): what the machine is
    /// built for is run, and its following error checked, over the link. The knots' speed and
    /// jerk, and everything of a planned move (`MoveTo`), keep the built-in trajectory's
    /// limits ([`Settings::stream_limits`]). At most `servo.max_accel_mm_s2`.
    pub stream_accel_mm_s2: f32,
    /// The built-in trajectory's time law. Default
    /// [`Profile::Quintic`](crate::waypoint_moves::Profile::Quintic); the QEMU board's `track-5g`
    /// runs `JerkLimited`.
    pub trajectory_profile: crate::waypoint_moves::Profile,
    /// Peak tool jerk of the built-in trajectory's jerk-limited profile (mm/s³). Default
    /// [`DEFAULT_JERK_MM_S3`](crate::waypoint_moves::DEFAULT_JERK_MM_S3), 5e6 mm/s³ (5 g reached in
    /// 10 ms).
    pub trajectory_jerk_mm_s3: f32,
    /// Rest at every waypoint (s). Default 0.1 s.
    pub trajectory_dwell_s: f32,
    /// Where the setpoints come from: `false`, the built-in tour (`builtin_tour_mm`); `true`,
    /// the host link's motion (moves and streams, `motion_stream`), holding still until the
    /// host commands one. Default `false` (the boards' behaviour before the link); the QEMU
    /// board's `link` scenario sets it.
    pub link_motion: bool,
    /// The controlled stop (stop categories 1 and 2): deceleration 5 g built up in 5 ms, and
    /// when a category-1 stop removes torque. See [`StopSettings`].
    pub stop: StopSettings,
    /// Encoder plausibility: the mechanism's speed and acceleration, the stuck-encoder check.
    /// See [`EncoderLimits`].
    pub encoder_limits: EncoderLimits,
    /// The machine the controller drives (`crate::calibration`, "The machine is the image's"):
    /// name, nominal model and working mode, workspace and stop margin, home position (where
    /// homing ends), the limits a calibration image is judged against. At boot the app sets it
    /// to the record of the image in force ([`Settings::for_machine`]); what the board gives is
    /// the built-in machine, the one an image without a record is judged against. Default:
    /// the paper's machine, `MachineRecord::paper()` (equal to host-sim's
    /// `machines/paper.toml`).
    pub machine: MachineRecord,
    /// Homing: absolute encoders (no homing) or the index procedure, its limits and whether it
    /// runs at boot. See [`HomingSettings`]. Where homing ends is the machine's
    /// (`machine.home_mm`).
    pub homing: HomingSettings,
    /// Switching to a newly committed calibration at rest: how far it may move the tool and
    /// how fast (`servo_loop::switch`). See [`SwitchSettings`].
    pub switch: SwitchSettings,
}

/// How a calibration switch at rest moves the tool: from where the new calibration puts it to
/// where the old one held it, in a straight jerk-limited move (the stop's jerk), at most
/// `max_move_mm` long.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SwitchSettings {
    /// The largest move a switch may make (mm); a calibration that disagrees more with the one
    /// in force at the machine's pose is refused (the old one stays). Default 5 mm: a
    /// calibration of this machine and the nominal model disagree by up to about 1.4 mm on the
    /// paper's machine (docs/getting-started.md: the nominal model's 1.34 mm error), two
    /// calibrations of it by micrometres.
    pub max_move_mm: f32,
    /// The move's peak speed (mm/s). Default 20 mm/s.
    pub speed_mm_s: f32,
    /// The move's peak acceleration (mm/s²). Default 500 mm/s² (0.05 g: a few hundredths of a
    /// newton-metre at the motors).
    pub accel_mm_s2: f32,
}

impl Default for SwitchSettings {
    fn default() -> Self {
        SwitchSettings {
            max_move_mm: 5.0,
            speed_mm_s: 20.0,
            accel_mm_s2: 500.0,
        }
    }
}

/// Settings [`Settings::validate`] refuses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsError {
    /// The servo's settings (`servo`).
    Servo(ConfigError),
    /// An axis's encoder configuration (`encoders[axis]`).
    Encoder {
        /// 0 or 1.
        axis: u8,
        /// Why `EncoderScale::new` refused it.
        error: EncoderConfigError,
    },
    /// Another field, by name: not a finite number in its range.
    Field(&'static str),
}

impl core::fmt::Display for SettingsError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SettingsError::Servo(e) => write!(f, "servo: {e}"),
            SettingsError::Encoder { axis, error } => write!(f, "encoders[{axis}]: {error}"),
            SettingsError::Field(name) => write!(f, "{name} out of range"),
        }
    }
}

impl Settings {
    /// The built-in tour from `start_mm` at the servo rate, in its profile.
    pub fn builtin_trajectory(&self, start_mm: [f32; 2]) -> Trajectory {
        let settings = self;
        match settings.trajectory_profile {
            Profile::Quintic => Trajectory::new(
                start_mm,
                settings.builtin_tour_mm,
                settings.trajectory_accel_mm_s2,
                settings.trajectory_speed_mm_s,
                settings.trajectory_dwell_s,
                crate::SAMPLE_PERIOD_S,
            ),
            Profile::JerkLimited => {
                let limits = TaskLimits {
                    speed_mm_s: settings.trajectory_speed_mm_s,
                    accel_mm_s2: settings.trajectory_accel_mm_s2,
                    jerk_mm_s3: settings.trajectory_jerk_mm_s3,
                };
                Trajectory::jerk_limited(
                    start_mm,
                    settings.builtin_tour_mm,
                    &limits,
                    settings.trajectory_dwell_s,
                    crate::SAMPLE_PERIOD_S,
                )
            }
        }
    }

    /// These settings with the machine `record` adopted (module doc): the machine, and the
    /// stop margin from its workspace. Everything else stays the board's.
    pub fn for_machine(&self, record: &MachineRecord) -> Settings {
        let mut stop = self.stop;
        stop.workspace_margin_mm = record.workspace.stop_margin_mm;
        Settings {
            machine: *record,
            stop,
            ..*self
        }
    }

    /// How calibration images are judged with these settings (`crate::calibration`): against
    /// [`Settings::machine`], plus the servo's slope-change limit from its top speed.
    pub fn image_check(&self) -> ImageCheck {
        ImageCheck {
            machine: self.machine,
            max_slope_change_rad_per_mm: Some(max_slope_change_rad_per_mm(&self.servo)),
        }
    }

    /// Where homing ends and the servo engages after it (mm): the machine's home.
    pub fn home_mm(&self) -> [f32; 2] {
        self.machine.home_mm
    }

    /// The limits the host link's planned moves (`MoveTo`) keep: the same speed, acceleration
    /// and jerk as the built-in trajectory's.
    pub fn stream_limits(&self) -> kinematics_core::trajectory::TaskLimits<f32> {
        kinematics_core::trajectory::TaskLimits {
            speed_mm_s: self.trajectory_speed_mm_s,
            accel_mm_s2: self.trajectory_accel_mm_s2,
            jerk_mm_s3: self.trajectory_jerk_mm_s3,
        }
    }

    /// The limits the host link's streamed knots keep: the planned moves' speed and jerk, and
    /// [`Settings::stream_accel_mm_s2`].
    pub fn knot_limits(&self) -> kinematics_core::trajectory::TaskLimits<f32> {
        kinematics_core::trajectory::TaskLimits {
            accel_mm_s2: self.stream_accel_mm_s2,
            ..self.stream_limits()
        }
    }

    /// Checks every field: the servo's ([`ServoConfig::validate`]), its sample period equal to
    /// the timer's, the stop's, each axis's encoder configuration ([`EncoderScale::new`]) and
    /// the encoder check's; a positive finite drive full scale,
    /// trajectory acceleration and speed; a positive stream acceleration the servo accepts; a finite non-negative dwell; at least one overrun in
    /// a streak and one sample per telemetry period.
    pub fn validate(&self) -> Result<(), SettingsError> {
        self.servo.validate().map_err(SettingsError::Servo)?;
        if self.servo.sample_period_s != crate::SAMPLE_PERIOD_S {
            return Err(SettingsError::Field(
                "servo.sample_period_s (must be the timer's)",
            ));
        }
        self.stop
            .validate(self.servo.max_accel_mm_s2)
            .map_err(SettingsError::Field)?;
        for (axis, config) in self.encoders.iter().enumerate() {
            EncoderScale::new(config).map_err(|error| SettingsError::Encoder {
                axis: axis as u8,
                error,
            })?;
        }
        self.encoder_limits
            .validate()
            .map_err(SettingsError::Field)?;
        self.homing.validate().map_err(SettingsError::Field)?;
        let positive = |v: f32| v.is_finite() && v > 0.0;
        for (ok, name) in [
            (positive(self.drive_full_scale_nm), "drive_full_scale_nm"),
            (
                positive(self.trajectory_accel_mm_s2),
                "trajectory_accel_mm_s2",
            ),
            (
                positive(self.trajectory_speed_mm_s),
                "trajectory_speed_mm_s",
            ),
            (
                positive(self.stream_accel_mm_s2)
                    && self.stream_accel_mm_s2 <= self.servo.max_accel_mm_s2,
                "stream_accel_mm_s2 (at most servo.max_accel_mm_s2)",
            ),
            (
                positive(self.trajectory_jerk_mm_s3),
                "trajectory_jerk_mm_s3",
            ),
            (
                self.trajectory_dwell_s.is_finite() && self.trajectory_dwell_s >= 0.0,
                "trajectory_dwell_s",
            ),
            (self.overrun_streak_limit >= 1, "overrun_streak_limit"),
            (self.telemetry_period_ticks >= 1, "telemetry_period_ticks"),
            (positive(self.switch.max_move_mm), "switch.max_move_mm"),
            (positive(self.switch.speed_mm_s), "switch.speed_mm_s"),
            (positive(self.switch.accel_mm_s2), "switch.accel_mm_s2"),
            (self.machine.validate().is_ok(), "machine (its record)"),
            (
                self.machine.encoder_sign == [1, 1],
                "machine.encoder_sign (the counting direction is Settings::encoders' sign)",
            ),
        ] {
            if !ok {
                return Err(SettingsError::Field(name));
            }
        }
        Ok(())
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            servo: ServoConfig {
                sample_period_s: crate::SAMPLE_PERIOD_S,
                ..ServoConfig::default()
            },
            allow_uncorrected: false,
            overrun_streak_limit: 3,
            drive_full_scale_nm: 10.0,
            telemetry_period_ticks: 500,
            builtin_tour_mm: &[],
            encoders: [EncoderConfig::DIRECT_DRIVE_2_22; 2],
            trajectory_accel_mm_s2: 2.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2,
            trajectory_speed_mm_s: 1_500.0,
            stream_accel_mm_s2: 5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2,
            trajectory_profile: crate::waypoint_moves::Profile::Quintic,
            trajectory_jerk_mm_s3: crate::waypoint_moves::DEFAULT_JERK_MM_S3,
            trajectory_dwell_s: 0.1,
            link_motion: false,
            stop: StopSettings::default(),
            encoder_limits: EncoderLimits::default(),
            machine: MachineRecord::paper(),
            homing: HomingSettings::default(),
            switch: SwitchSettings::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_servo_runs_at_the_timer_rate_and_a_real_machine_does_not_move_by_itself() {
        let s = Settings::default();
        assert_eq!(s.servo.sample_period_s * crate::SAMPLE_RATE_HZ as f32, 1.0);
        assert!(s.builtin_tour_mm.is_empty());
        assert!(!s.allow_uncorrected);
        // The servo's torque limit, not the PWM range, must saturate first.
        assert!(s
            .servo
            .axes
            .iter()
            .all(|a| a.torque_limit_nm < s.drive_full_scale_nm));
        assert_eq!(s.validate(), Ok(()));
        // The default encoders are valid (a refused one would keep the drives off).
        for e in &s.encoders {
            assert!(crate::encoder::EncoderScale::new(e).is_ok(), "{e:?}");
        }
    }

    #[test]
    fn validate_names_the_bad_field() {
        let d = Settings::default();
        let mut servo = d.servo;
        servo.axes[0].torque_limit_nm = -1.0;
        assert!(matches!(
            Settings { servo, ..d }.validate(),
            Err(SettingsError::Servo(_))
        ));
        let servo = ServoConfig {
            sample_period_s: 1e-3,
            ..d.servo
        };
        assert!(matches!(
            Settings { servo, ..d }.validate(),
            Err(SettingsError::Field(_))
        ));
        for (bad, name) in [
            (
                Settings {
                    drive_full_scale_nm: 0.0,
                    ..d
                },
                "drive_full_scale_nm",
            ),
            (
                Settings {
                    trajectory_accel_mm_s2: f32::NAN,
                    ..d
                },
                "trajectory_accel_mm_s2",
            ),
            (
                Settings {
                    trajectory_dwell_s: -1.0,
                    ..d
                },
                "trajectory_dwell_s",
            ),
            (
                Settings {
                    trajectory_jerk_mm_s3: 0.0,
                    ..d
                },
                "trajectory_jerk_mm_s3",
            ),
            (
                Settings {
                    overrun_streak_limit: 0,
                    ..d
                },
                "overrun_streak_limit",
            ),
            (
                Settings {
                    telemetry_period_ticks: 0,
                    ..d
                },
                "telemetry_period_ticks",
            ),
        ] {
            assert_eq!(bad.validate(), Err(SettingsError::Field(name)));
        }
        let mut stop = d.stop;
        stop.limits.jerk_mm_s3 = f32::INFINITY;
        assert_eq!(
            Settings { stop, ..d }.validate(),
            Err(SettingsError::Field("stop.limits.jerk_mm_s3"))
        );
        let encoder_limits = EncoderLimits {
            stuck_motion_rad: 0.0,
            ..d.encoder_limits
        };
        assert_eq!(
            Settings {
                encoder_limits,
                ..d
            }
            .validate(),
            Err(SettingsError::Field("encoder_limits.stuck_motion_rad"))
        );
        let mut encoders = d.encoders;
        encoders[1].gear_ratio = -50.0;
        assert_eq!(
            Settings { encoders, ..d }.validate(),
            Err(SettingsError::Encoder {
                axis: 1,
                error: EncoderConfigError::GearRatio
            })
        );
        encoders[1].gear_ratio = 1.0;
        encoders[0].counts_per_rev = 0;
        assert_eq!(
            Settings { encoders, ..d }.validate(),
            Err(SettingsError::Encoder {
                axis: 0,
                error: EncoderConfigError::ZeroCountsPerRev
            })
        );
    }

    #[test]
    fn builtin_uses_the_settings_tour() {
        let settings = Settings {
            builtin_tour_mm: &crate::waypoint_moves::WORKSPACE_TOUR_MM,
            ..Settings::default()
        };
        assert_eq!(
            settings.builtin_trajectory([212.132, 0.0]).total_samples(),
            Trajectory::new(
                [212.132, 0.0],
                &crate::waypoint_moves::WORKSPACE_TOUR_MM,
                2.0 * 9_806.65,
                1500.0,
                0.1,
                crate::SAMPLE_PERIOD_S
            )
            .total_samples()
        );
        assert!(Settings::default()
            .builtin_trajectory([212.132, 0.0])
            .finished());
    }
}
