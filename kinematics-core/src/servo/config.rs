//! The servo's run-time settings ([`ServoConfig`]) and which it can run with
//! ([`ServoConfig::validate`], [`ConfigError`]).
use crate::pid::{AxisGains, InvalidGain};

/// Standard gravity (mm/s²), for limits stated in g.
pub const STANDARD_GRAVITY_MM_S2: f32 = 9_806.65;

/// Run-time settings of the servo; [`ServoConfig::default`] suits the paper's machine as
/// simulated by `host-sim`'s default plant. [`ServoConfig::validate`] says which a servo can
/// run with.
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
    /// moves ω within 900..1120 rad/s. The stiffness alone holds the following error at 5 g
    /// to about 10 µm when the feed-forward's masses are 20 % off (δ·a/ω²,
    /// docs/design/servo-and-dynamics.md); the disturbance observer
    /// ([`crate::disturbance_observer`], 2000 rad/s: `g·dt = 1`, α = 0.5, nominal inertia the
    /// identified diagonal) takes that to 5-6.4 µm on the paper plant. Faster observers gain little
    /// (3000 rad/s: 6.1 µm; what remains is the first samples of each jerk ramp, which an estimate
    /// a sample late cannot see) and pass more quantisation.
    fn default() -> Self {
        const INERTIA_KG_M2: f32 = 7.4e-3;
        const OMEGA_RAD_S: f32 = 1000.0;
        const OBSERVER_BANDWIDTH_RAD_S: f32 = 2000.0;
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
            observer_bandwidth_rad_s: OBSERVER_BANDWIDTH_RAD_S,
            observer_inertia_kg_m2: INERTIA_KG_M2,
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

/// A [`ServoConfig`] the servo refuses to run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// `sample_period_s` is not a positive finite number.
    SamplePeriod,
    /// `min_transmission` is not in `[0, 1)` (a `|sin|`: 1 or more refuses every pose).
    MinTransmission,
    /// A limit (`max_speed_mm_s`, `max_accel_mm_s2`, `max_following_error_rad`) is negative,
    /// NaN or infinite.
    Limit(&'static str),
    /// A gain of axis `axis` (0 or 1) is refused by [`AxisGains::validate`].
    Gain {
        /// 0 or 1.
        axis: u8,
        /// What is wrong with it.
        gain: InvalidGain,
    },
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ConfigError::SamplePeriod => {
                f.write_str("sample_period_s must be a positive finite number")
            }
            ConfigError::MinTransmission => f.write_str("min_transmission must be in [0, 1)"),
            ConfigError::Limit(name) => write!(f, "{name} must be a finite non-negative number"),
            ConfigError::Gain { axis, gain } => write!(f, "axis {}: {gain}", axis + 1),
        }
    }
}

impl core::error::Error for ConfigError {}

impl ServoConfig {
    /// Checks every field: a positive finite sample period, a singularity margin in `[0, 1)`,
    /// finite non-negative limits, and gains [`AxisGains::validate`] accepts.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(self.sample_period_s.is_finite() && self.sample_period_s > 0.0) {
            return Err(ConfigError::SamplePeriod);
        }
        if !(self.min_transmission >= 0.0 && self.min_transmission < 1.0) {
            return Err(ConfigError::MinTransmission);
        }
        for (v, name) in [
            (self.max_speed_mm_s, "max_speed_mm_s"),
            (self.max_accel_mm_s2, "max_accel_mm_s2"),
            (self.max_following_error_rad, "max_following_error_rad"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::Limit(name));
            }
        }
        for (axis, gains) in self.axes.iter().enumerate() {
            gains.validate().map_err(|gain| ConfigError::Gain {
                axis: axis as u8,
                gain,
            })?;
        }
        Ok(())
    }
}
