//! One drive: motor with gearbox, encoder, backlash and gear cyclic error, in joint-side units.
//!
//! Why this shape: the servo (kinematics-core) commands joint-side torque and reads a joint-side
//! encoder angle; the linkage needs the *link* angle. Between them sit the effects the
//! calibration must live with:
//!
//! ```text
//! torque ─► [limit] ─► J·ω' = τ - b·ω - τc·sgn(ω) ─► motor angle ─┬─► encoder: quantize(motor - offset)
//!                                                                 └─► play(β) + cyclic error ─► link angle
//! ```
//! * The encoder sits on the motor (counts per motor rev × gear ratio per joint rev) and reads
//!   `motor - offset`, so the kinematics convention `geometric = encoder + offset` holds.
//! * Backlash is a play operator of total width β: the link stays put until the motor has taken
//!   up the play, then follows it lagging by β/2 on the side of the last motion (it reverses with
//!   the direction of motion: tested). The link side is massless (all inertia is lumped at the
//!   motor), so the play needs no contact model.
//! * Gear cyclic error: `amplitude·sin(cycles·gear_ratio·motor + phase)` on the link, an effect
//!   no hidden-robot model has (for diagnosis tests).
//! * Torque: the amplifier's limit on the command, then the motor's torque constant error (the
//!   torque delivered is `(1 + e)` times the command); cogging, a ripple periodic in the motor
//!   angle, `amplitude·sin(cycles·gear_ratio·motor + phase)`, acts against it (the moving
//!   machine's diagnosis, `dynamics`, names both).
//! * Not modelled: the torque the stressed linkage puts on the levers (it would only load the
//!   servo's integrator) and gear/shaft compliance; a disabled drive (the closed loop ends at a
//!   servo fault instead of removing torque, so the drives' dynamic braking, which the QEMU
//!   plant models for category-0 stops, never acts here).
//! * Dynamics ([`Drive::step`]): semi-implicit Euler on one rigid inertia with viscous and
//!   Coulomb friction (stick when the torque cannot break away), for a drive alone. Cost: a
//!   handful of flops per substep; error O(dt²) per step. In the plant the drives are coupled
//!   through the linkage's inertia: `crate::plant::motion` integrates both together, with the
//!   parameters below ([`Drive::rotor_inertia_kg_m2`], [`Drive::friction`],
//!   [`Drive::limit_torque`]) and [`Drive::set_motion`].

use crate::plant::config::DriveConfig;
use std::f64::consts::TAU;

#[derive(Clone, Debug)]
pub struct Drive {
    inertia_kg_m2: f64,
    viscous_nm_s_per_rad: f64,
    coulomb_nm: f64,
    torque_limit_nm: f64,
    /// Encoder resolution at the joint (rad), 0 = continuous.
    encoder_step_rad: f64,
    encoder_offset_rad: f64,
    backlash_rad: f64,
    cyclic_amplitude_rad: f64,
    cyclic_rad_per_rad: f64,
    cyclic_phase_rad: f64,
    /// Delivered torque per commanded (1 + the torque constant's error).
    torque_gain: f64,
    /// Cogging amplitude (N·m), cycles per joint radian, phase (rad).
    cogging_nm: f64,
    cogging_rad_per_rad: f64,
    cogging_phase_rad: f64,
    /// Motor angle, geometric, joint side.
    pub motor_rad: f64,
    pub velocity_rad_s: f64,
    /// Output of the play operator (link angle without cyclic error).
    play_rad: f64,
}

impl Drive {
    pub fn new(cfg: &DriveConfig) -> Self {
        let counts = cfg.encoder_counts_per_motor_rev * cfg.gear_ratio;
        Drive {
            inertia_kg_m2: cfg.inertia_kg_m2,
            viscous_nm_s_per_rad: cfg.viscous_friction_nm_s_per_rad,
            coulomb_nm: cfg.coulomb_friction_nm,
            torque_limit_nm: cfg.torque_limit_nm,
            encoder_step_rad: if counts > 0.0 { TAU / counts } else { 0.0 },
            encoder_offset_rad: cfg.encoder_offset_deg.to_radians(),
            backlash_rad: cfg.backlash_urad * 1e-6,
            cyclic_amplitude_rad: cfg.cyclic_error_urad * 1e-6,
            cyclic_rad_per_rad: cfg.cyclic_error_cycles_per_motor_rev * cfg.gear_ratio,
            cyclic_phase_rad: cfg.cyclic_error_phase_deg.to_radians(),
            torque_gain: 1.0 + cfg.torque_constant_error_pct / 100.0,
            cogging_nm: cfg.cogging_nm,
            cogging_rad_per_rad: cfg.cogging_cycles_per_motor_rev * cfg.gear_ratio,
            cogging_phase_rad: cfg.cogging_phase_deg.to_radians(),
            motor_rad: 0.0,
            velocity_rad_s: 0.0,
            play_rad: 0.0,
        }
    }

    /// An encoder angle rounded to the encoder's resolution.
    pub fn quantize_rad(&self, encoder_rad: f64) -> f64 {
        if self.encoder_step_rad > 0.0 {
            (encoder_rad / self.encoder_step_rad).round() * self.encoder_step_rad
        } else {
            encoder_rad
        }
    }

    /// The encoder's resolution at the joint (rad per count; 0: not quantised).
    pub fn encoder_step_rad(&self) -> f64 {
        self.encoder_step_rad
    }

    /// The encoder's angle before quantisation (`motor - offset`): where an index mark on the
    /// encoder disc is crossed.
    pub fn encoder_continuous_rad(&self) -> f64 {
        self.motor_rad - self.encoder_offset_rad
    }

    /// What the encoder reads now.
    pub fn encoder_rad(&self) -> f64 {
        self.quantize_rad(self.motor_rad - self.encoder_offset_rad)
    }

    /// The link's geometric angle now.
    pub fn link_rad(&self) -> f64 {
        let cyclic = if self.cyclic_amplitude_rad != 0.0 {
            self.cyclic_amplitude_rad
                * (self.cyclic_rad_per_rad * self.motor_rad + self.cyclic_phase_rad).sin()
        } else {
            0.0
        };
        self.play_rad + cyclic
    }

    /// Puts the drive at rest with the encoder reading `encoder_rad` (quantized), having
    /// arrived there moving in direction `dir` (+1/-1): the state a position servo leaves after
    /// a move. Returns the encoder reading.
    pub fn settle(&mut self, encoder_rad: f64, dir: i8) -> f64 {
        let reading = self.quantize_rad(encoder_rad);
        self.motor_rad = reading + self.encoder_offset_rad;
        self.velocity_rad_s = 0.0;
        self.play_rad = self.motor_rad - f64::from(dir.signum()) * self.backlash_rad / 2.0;
        reading
    }

    /// Play operator: the link follows the motor once the play is taken up.
    fn update_play(&mut self) {
        let half = self.backlash_rad / 2.0;
        if self.motor_rad - self.play_rad > half {
            self.play_rad = self.motor_rad - half;
        } else if self.motor_rad - self.play_rad < -half {
            self.play_rad = self.motor_rad + half;
        }
    }

    /// Motor and gearbox inertia at the joint (kg·m²).
    pub fn rotor_inertia_kg_m2(&self) -> f64 {
        self.inertia_kg_m2
    }

    /// Viscous (N·m·s/rad) and Coulomb (N·m) friction.
    pub fn friction(&self) -> (f64, f64) {
        (self.viscous_nm_s_per_rad, self.coulomb_nm)
    }

    /// The torque the amplifier delivers for the command `torque_nm`: limited, times the
    /// torque constant's error.
    pub fn limit_torque(&self, torque_nm: f64) -> f64 {
        torque_nm.clamp(-self.torque_limit_nm, self.torque_limit_nm) * self.torque_gain
    }

    /// The cogging torque at motor angle `motor_rad` (N·m, acting against the drive's torque).
    pub fn cogging_nm(&self, motor_rad: f64) -> f64 {
        if self.cogging_nm == 0.0 {
            return 0.0;
        }
        self.cogging_nm * (self.cogging_rad_per_rad * motor_rad + self.cogging_phase_rad).sin()
    }

    /// Sets the motor's angle and velocity (from an integration of the coupled drives); the link
    /// follows through the play.
    pub fn set_motion(&mut self, motor_rad: f64, velocity_rad_s: f64) {
        self.motor_rad = motor_rad;
        self.velocity_rad_s = velocity_rad_s;
        self.update_play();
    }

    /// Moves the motor to `motor_rad` kinematically (for tests and quasi-static protocols).
    pub fn move_motor_to(&mut self, motor_rad: f64) {
        self.motor_rad = motor_rad;
        self.update_play();
    }

    /// One dynamics substep of `dt_s` with joint torque command `torque_nm` (limited here).
    pub fn step(&mut self, torque_nm: f64, dt_s: f64) {
        let tau = self.limit_torque(torque_nm) - self.cogging_nm(self.motor_rad);
        let w = self.velocity_rad_s;
        if w == 0.0 && tau.abs() <= self.coulomb_nm {
            // Stuck: static friction balances the torque.
        } else {
            let dir = if w != 0.0 { w.signum() } else { tau.signum() };
            let acc =
                (tau - self.viscous_nm_s_per_rad * w - self.coulomb_nm * dir) / self.inertia_kg_m2;
            let mut w_new = w + acc * dt_s;
            // Coulomb friction stops the motor; it does not reverse it within a step.
            if w != 0.0 && w_new * w < 0.0 && self.coulomb_nm > 0.0 {
                w_new = 0.0;
            }
            self.velocity_rad_s = w_new;
            self.motor_rad += w_new * dt_s;
        }
        self.update_play();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::config::PlantConfig;

    #[test]
    fn backlash_reverses_with_direction() {
        let mut cfg = PlantConfig::ideal().drive_1;
        cfg.backlash_urad = 100.0;
        let mut d = Drive::new(&cfg);
        d.settle(0.0, 1);
        assert!((d.link_rad() - -50e-6).abs() < 1e-12);
        // Reversing: the link does not move until the play is taken up...
        d.move_motor_to(-60e-6);
        assert!((d.link_rad() - -50e-6).abs() < 1e-12, "{}", d.link_rad());
        // ...then it lags on the other side.
        d.move_motor_to(-1e-3);
        assert!((d.link_rad() - (-1e-3 + 50e-6)).abs() < 1e-12);
        // Back to the same motor angle from below: the link is now β below, not above.
        d.move_motor_to(0.0);
        assert!((d.link_rad() - -50e-6).abs() < 1e-12);
        let mut up = d.clone();
        up.settle(0.0, -1);
        assert!((up.link_rad() - 50e-6).abs() < 1e-12);
        // And under dynamics: a torque pulse forward then backward.
        let mut d = Drive::new(&cfg);
        d.settle(0.0, 1);
        for _ in 0..100 {
            d.step(-0.5, 5e-5);
        }
        assert!(
            d.link_rad() > d.motor_rad,
            "moving negative, the link lags above the motor"
        );
    }

    #[test]
    fn encoder_quantization_and_offset() {
        let mut cfg = PlantConfig::ideal().drive_1;
        cfg.encoder_counts_per_motor_rev = 1000.0;
        cfg.gear_ratio = 10.0;
        cfg.encoder_offset_deg = 1.0;
        let mut d = Drive::new(&cfg);
        let r = d.settle(0.123456, 1);
        let step = TAU / 10_000.0;
        assert!((r / step - (r / step).round()).abs() < 1e-9);
        assert!((r - 0.123456).abs() <= step / 2.0);
        assert!((d.link_rad() - (r + 1f64.to_radians())).abs() < 1e-12);
    }

    #[test]
    fn coulomb_friction_holds_below_breakaway() {
        let mut cfg = PlantConfig::ideal().drive_1;
        cfg.coulomb_friction_nm = 0.1;
        let mut d = Drive::new(&cfg);
        d.settle(0.0, 1);
        for _ in 0..1000 {
            d.step(0.09, 5e-5);
        }
        assert_eq!(d.motor_rad, 0.0);
        for _ in 0..1000 {
            d.step(0.2, 5e-5);
        }
        // (0.2 - 0.1) / 2e-3 = 50 rad/s² for 50 ms: 0.0625 rad.
        assert!((d.motor_rad - 0.0625).abs() < 1e-3, "{}", d.motor_rad);
    }

    #[test]
    fn cyclic_error_follows_the_motor_angle() {
        let mut cfg = PlantConfig::ideal().drive_1;
        cfg.cyclic_error_urad = 10.0;
        cfg.cyclic_error_cycles_per_motor_rev = 1.0;
        cfg.gear_ratio = 10.0;
        let mut d = Drive::new(&cfg);
        // A quarter motor revolution = 1/40 joint revolution: sin goes 0 -> 1.
        d.settle(0.0, 1);
        assert!(d.link_rad().abs() < 1e-12);
        d.settle(TAU / 40.0, 1);
        assert!((d.link_rad() - TAU / 40.0 - 10e-6).abs() < 1e-12);
    }
}
