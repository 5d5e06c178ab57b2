//! Run-time settings of the firmware, in one place.
//!
//! On the real board these are compiled in today ([`Settings::default`]); a host link would
//! replace them before the drives are enabled. Nothing here is read from the calibration image:
//! the image carries the geometry only. The app keeps one `&'static Settings` (set up in
//! `init`) that every task borrows.
use kinematics_core::ServoConfig;

use crate::encoder::EncoderConfig;

/// Every run-time setting, with the defaults documented on each field.
#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Servo gains and limits. Default: `ServoConfig::default()` (2e-3 kg·m² per joint,
    /// torque limit 8 N·m, setpoint acceleration limit 5 g·1.05, following error limit
    /// 0.02 rad) with the sample period pinned to the timer's, [`crate::SAMPLE_PERIOD_S`]
    /// (the servo timer runs at [`crate::SAMPLE_RATE_HZ`]; the two must agree).
    pub servo: ServoConfig,
    /// Run without correction grid when the image is bad or missing. Default `false`: the
    /// machine exists for micrometre work and the uncorrected model is off by tens of
    /// micrometres, so a bad image keeps the drives disabled (see README, "Calibration").
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
    /// [`WORKSPACE_TOUR_MM`](crate::trajectory::WORKSPACE_TOUR_MM).
    pub builtin_tour_mm: &'static [[f32; 2]],
    /// Each axis's encoder as fitted: counts per motor revolution, counting direction, gear
    /// ratio from motor to joint ([`EncoderConfig`]; the zero comes from homing, not from
    /// here). Default: [`EncoderConfig::DIRECT_DRIVE_2_22`] on both axes, the QEMU board's
    /// simulated encoders; set them for the motors fitted before the first power-up (see the
    /// bring-up guide in firmware/README.md). A configuration `EncoderScale::new` refuses
    /// reads NaN, so the servo refuses to engage.
    pub encoders: [EncoderConfig; 2],
    /// Peak tool acceleration of the built-in trajectory (mm/s²). Default 2 g.
    pub trajectory_accel_mm_s2: f32,
    /// Peak tool speed of the built-in trajectory (mm/s). Default 1500 mm/s.
    pub trajectory_speed_mm_s: f32,
    /// Rest at every waypoint (s). Default 0.1 s.
    pub trajectory_dwell_s: f32,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            servo: ServoConfig { sample_period_s: crate::SAMPLE_PERIOD_S, ..ServoConfig::default() },
            allow_uncorrected: false,
            overrun_streak_limit: 3,
            drive_full_scale_nm: 10.0,
            telemetry_period_ticks: 500,
            builtin_tour_mm: &[],
            encoders: [EncoderConfig::DIRECT_DRIVE_2_22; 2],
            trajectory_accel_mm_s2: 2.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2,
            trajectory_speed_mm_s: 1_500.0,
            trajectory_dwell_s: 0.1,
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
        assert!(s.servo.axes.iter().all(|a| a.torque_limit_nm < s.drive_full_scale_nm));
        // The default encoders are valid (a refused one would keep the drives off).
        for e in &s.encoders {
            assert!(crate::encoder::EncoderScale::new(e).is_ok(), "{e:?}");
        }
    }
}
