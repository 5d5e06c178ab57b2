//! The simulated machine: two joint inertias driven by the torques the PWM registers command
//! while the drive-enable line is on, with viscous and Coulomb friction, read back through the
//! encoder counters (2^22 counts per revolution, quantised). With the enable line low the
//! drives brake dynamically (see [`MotorConstants`]).
//!
//! The plant's parameters are deliberately not the servo's: inertias 10 % off the
//! feed-forward, and friction the feed-forward does not know about. It is advanced at the start
//! of every servo sample (the torque written in sample k acts during period k..k+1, as on
//! hardware).
use controller::scenario::stop_check::{CoastModel, PlantState};

use super::hardware;
use super::COUNTS_PER_REV;

/// Parameters of the simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct PlantParams {
    /// Joint inertias (kg·m²): the servo's feed-forward assumes 2e-3.
    pub inertia_kg_m2: [f32; 2],
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_per_rad: f32,
    /// Coulomb friction (N·m), smoothed over [`PlantParams::coulomb_smoothing_rad_s`].
    pub coulomb_nm: f32,
    /// Speed (rad/s) over which the Coulomb friction turns over.
    pub coulomb_smoothing_rad_s: f32,
    /// Integration sub-steps per servo period (semi-implicit Euler).
    pub substeps: u32,
    /// The drives' dynamic braking with the enable line low (N·m·s/rad): a braking torque
    /// `-c·ω` on each joint. [`MOTOR`]'s, 0.225.
    pub dynamic_brake_nm_s_per_rad: f32,
}

/// A drive's motor, for its dynamic braking.
///
/// **Dynamic braking is a hardware requirement of the drives** (firmware/README.md, "Faults and
/// stop categories"): on disable, safe torque off or a break, the amplifier shorts the motor's
/// windings. The back-EMF `k_e·N·ω` then drives a current `k_e·N·ω/R` through the winding
/// resistance, whose torque `k_t·N·k_e·N·ω/R` at the joint brakes the joint, in proportion to
/// its speed, with no energy from the supply and with the controller dead:
/// `c = N²·k_t·k_e/R` (N·m·s/rad at the joint). The simple resistive model holds while the
/// winding's electrical time constant is short against the electrical period (`ω_e·L/R ≪ 1`:
/// 10 pole pairs, 3 mH, 3.6 Ω at 9 rad/s give 0.075, 0.6 % less torque); at higher speeds the
/// inductance lowers the braking torque.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorConstants {
    /// Torque constant (N·m/A).
    pub torque_constant_nm_per_a: f32,
    /// Back-EMF constant (V·s/rad; equal to the torque constant in SI units for an ideal motor).
    pub back_emf_v_s_per_rad: f32,
    /// Winding resistance the short closes the circuit through (Ω: terminal resistance plus the
    /// short's).
    pub winding_resistance_ohm: f32,
    /// Motor turns per joint turn (1: direct drive).
    pub gear_ratio: f32,
}

impl MotorConstants {
    /// The dynamic braking at the joint (N·m·s/rad): `N²·k_t·k_e/R`.
    pub const fn dynamic_brake_nm_s_per_rad(&self) -> f32 {
        self.gear_ratio * self.gear_ratio * self.torque_constant_nm_per_a * self.back_emf_v_s_per_rad
            / self.winding_resistance_ohm
    }
}

/// The simulated drives' motors: a small brushless direct-drive torque motor of the 10 N·m
/// peak class (the drives' full scale), representative values, not a particular part:
/// `k_t` = 0.9 N·m/A (11 A for 10 N·m), `k_e` = 0.9 V·s/rad, `R` = 3.6 Ω, direct drive
/// (`N` = 1, as the QEMU board's encoders are). Dynamic braking `c` = 0.81/3.6 =
/// **0.225 N·m·s/rad** (the motor constant `k_m = k_t/√R` = 0.47 N·m/√W squared). From the
/// built-in tour's top speed (joint 1 at 9.0 rad/s, 2.2·10⁻³ kg·m²) a category-0 coast is at
/// most `J·ω₀/c` = 88 mrad (with the viscous friction, `J·ω₀/(c + b)` = 84 mrad), about 12 mm
/// at the tool; free-wheeling drives coasted 1.06 rad and 145 mm.
pub const MOTOR: MotorConstants =
    MotorConstants { torque_constant_nm_per_a: 0.9, back_emf_v_s_per_rad: 0.9, winding_resistance_ohm: 3.6, gear_ratio: 1.0 };

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            inertia_kg_m2: [2.2e-3, 1.8e-3],
            viscous_nm_s_per_rad: 0.01,
            coulomb_nm: 0.03,
            coulomb_smoothing_rad_s: 1.0e-3,
            substeps: 10,
            dynamic_brake_nm_s_per_rad: MOTOR.dynamic_brake_nm_s_per_rad(),
        }
    }
}

/// Joint angles the simulated machine powers up at (rad): tool near (214, 3) mm.
pub const POWER_ON_ANGLES_RAD: [f32; 2] = [0.80, -0.75];

/// The simulated joints.
#[derive(Clone, Copy, Debug)]
pub struct Plant {
    /// Friction, inertia, integration.
    pub params: PlantParams,
    /// Joint angles (rad), as the encoders count them.
    pub angle_rad: [f32; 2],
    /// Joint velocities (rad/s).
    pub velocity_rad_s: [f32; 2],
    /// The drives' full scale (N·m at 0 % / 100 % duty).
    pub full_scale_nm: f32,
}

impl Plant {
    /// The machine at power-on, at rest, its encoders published.
    pub fn power_on(full_scale_nm: f32) -> Self {
        let plant = Plant {
            params: PlantParams::default(),
            angle_rad: POWER_ON_ANGLES_RAD,
            velocity_rad_s: [0.0; 2],
            full_scale_nm,
        };
        plant.publish_encoders();
        plant
    }

    /// The true joint state (the harness checks it, not the encoders).
    pub fn state(&self) -> PlantState {
        PlantState { joint_rad: self.angle_rad, joint_rad_s: self.velocity_rad_s }
    }

    /// What bounds a coast with the drives off: inertia, viscous friction and the drives'
    /// dynamic braking.
    pub fn coast_model(&self) -> CoastModel {
        CoastModel {
            inertia_kg_m2: self.params.inertia_kg_m2,
            viscous_nm_s_per_rad: self.params.viscous_nm_s_per_rad,
            dynamic_brake_nm_s_per_rad: self.params.dynamic_brake_nm_s_per_rad,
        }
    }

    /// The machine as it was when its controller reset (it does not stop with it).
    pub fn resume(&mut self, state: PlantState) {
        self.angle_rad = state.joint_rad;
        self.velocity_rad_s = state.joint_rad_s;
        self.publish_encoders();
    }

    fn publish_encoders(&self) {
        for k in 0..2 {
            let counts = libm::roundf(self.angle_rad[k] * (COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI)));
            hardware::set_encoder_counts(k, counts as i32);
        }
    }

    /// Advances the joints by `period_s` under the torques the PWM commands now, or, with the
    /// enable line low, under the drives' dynamic braking.
    pub fn advance(&mut self, period_s: f32) {
        let p = self.params;
        let (torque_nm, brake_nm_s_per_rad) = if hardware::drive_enable() {
            (hardware::commanded_torque_nm(self.full_scale_nm), 0.0)
        } else {
            ([0.0; 2], p.dynamic_brake_nm_s_per_rad)
        };
        let h = period_s / p.substeps as f32;
        for (k, torque_nm) in torque_nm.into_iter().enumerate() {
            let (mut angle, mut velocity) = (self.angle_rad[k], self.velocity_rad_s[k]);
            for _ in 0..p.substeps {
                let friction = p.viscous_nm_s_per_rad * velocity
                    + p.coulomb_nm * velocity / (velocity.abs() + p.coulomb_smoothing_rad_s);
                let brake = brake_nm_s_per_rad * velocity;
                velocity += (torque_nm - friction - brake) / p.inertia_kg_m2[k] * h;
                angle += velocity * h;
            }
            self.angle_rad[k] = angle;
            self.velocity_rad_s[k] = velocity;
        }
        self.publish_encoders();
    }
}
