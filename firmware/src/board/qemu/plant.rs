//! The simulated machine: two joint inertias driven by the torques the PWM registers command
//! while the drive-enable line is on, with viscous and Coulomb friction, read back through the
//! encoder counters (2^22 counts per revolution, quantised).
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
}

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            inertia_kg_m2: [2.2e-3, 1.8e-3],
            viscous_nm_s_per_rad: 0.01,
            coulomb_nm: 0.03,
            coulomb_smoothing_rad_s: 1.0e-3,
            substeps: 10,
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

    /// What bounds a coast with the drives off: inertia and viscous friction.
    pub fn coast_model(&self) -> CoastModel {
        CoastModel { inertia_kg_m2: self.params.inertia_kg_m2, viscous_nm_s_per_rad: self.params.viscous_nm_s_per_rad }
    }

    fn publish_encoders(&self) {
        for k in 0..2 {
            let counts = libm::roundf(self.angle_rad[k] * (COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI)));
            hardware::set_encoder_counts(k, counts as i32);
        }
    }

    /// Advances the joints by `period_s` under the torques the PWM commands now.
    pub fn advance(&mut self, period_s: f32) {
        let torque_nm =
            if hardware::drive_enable() { hardware::commanded_torque_nm(self.full_scale_nm) } else { [0.0; 2] };
        let p = self.params;
        let h = period_s / p.substeps as f32;
        for (k, torque_nm) in torque_nm.into_iter().enumerate() {
            let (mut angle, mut velocity) = (self.angle_rad[k], self.velocity_rad_s[k]);
            for _ in 0..p.substeps {
                let friction = p.viscous_nm_s_per_rad * velocity
                    + p.coulomb_nm * velocity / (velocity.abs() + p.coulomb_smoothing_rad_s);
                velocity += (torque_nm - friction) / p.inertia_kg_m2[k] * h;
                angle += velocity * h;
            }
            self.angle_rad[k] = angle;
            self.velocity_rad_s[k] = velocity;
        }
        self.publish_encoders();
    }
}
