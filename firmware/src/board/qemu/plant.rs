//! The simulated machine: the five-bar linkage driven by the torques the PWM registers command
//! while the drive-enable line is on, read back through the encoder counters (2^22 counts per
//! revolution, quantised).
//!
//! Its dynamics are the hidden robot's rigid-body dynamics with the two motors coupled through
//! the linkage (`kinematics_core::dynamics`: configuration-dependent inertia matrix,
//! centripetal and Coriolis torques), plus viscous and smoothed Coulomb friction at each motor:
//! `M(θ)·θ̈ + h(θ, θ̇) + friction(θ̇) = τ`. The plant's parameters are deliberately not the
//! ones in the calibration image the servo feeds forward (`machine.rs`, written into the image
//! by `firmware/build.rs`): every inertia and the tool mass are 20 % off, alternating in sign,
//! and the friction differs, so the feedback has a real remainder to correct.
//!
//! Integration, once per servo sample (the torque written in sample k acts during period
//! k..k+1, as on hardware): `M` and `h` at the middle of the period (the pose predicted from the
//! current velocity), then `substeps` steps with the friction updated and the position advanced
//! with the mean velocity of each step (second order). Cost: one FK and three inverse-dynamics
//! evaluations per sample (about 1,200 instructions), far inside the 62,500 instructions of a
//! 500 µs period at QEMU's `-icount shift=3`.
use kinematics_core::dynamics::{solve_spd, FiveBarDynamics};
use kinematics_core::FiveBar;

use super::hardware;
use super::machine::TRUE_DYNAMICS;
use super::COUNTS_PER_REV;

/// Parameters of the simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct PlantParams {
    /// The linkage with its rotors (the true dynamics; friction below, not in here).
    pub dynamics: FiveBarDynamics<f32>,
    /// Viscous friction (N·m·s/rad).
    pub viscous_nm_s_per_rad: f32,
    /// Coulomb friction (N·m), smoothed over [`PlantParams::coulomb_smoothing_rad_s`].
    pub coulomb_nm: f32,
    /// Speed (rad/s) over which the Coulomb friction turns over.
    pub coulomb_smoothing_rad_s: f32,
    /// Integration sub-steps per servo period.
    pub substeps: u32,
}

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            dynamics: TRUE_DYNAMICS,
            viscous_nm_s_per_rad: 0.01,
            coulomb_nm: 0.03,
            coulomb_smoothing_rad_s: 1.0e-3,
            substeps: 10,
        }
    }
}

/// Joint angles the simulated machine powers up at (rad): tool near (214, 3) mm.
pub const POWER_ON_ANGLES_RAD: [f32; 2] = [0.80, -0.75];

/// The simulated machine.
#[derive(Clone, Copy, Debug)]
pub struct Plant {
    /// Dynamics, friction, integration.
    pub params: PlantParams,
    /// The linkage's geometry (the paper's nominal five-bar, the one the image's model is).
    pub linkage: FiveBar<f32>,
    /// Joint angles (rad), as the encoders count them.
    pub angle_rad: [f32; 2],
    /// Joint velocities (rad/s).
    pub velocity_rad_s: [f32; 2],
    /// The drives' full scale (N·m at 0 % / 100 % duty).
    pub full_scale_nm: f32,
    /// The linkage left its assembly (a singular or unreachable pose): the plant stopped.
    pub jammed: bool,
}

impl Plant {
    /// The machine at power-on, at rest, its encoders published.
    pub fn power_on(full_scale_nm: f32) -> Self {
        let plant = Plant {
            params: PlantParams::default(),
            linkage: FiveBar::paper_nominal(),
            angle_rad: POWER_ON_ANGLES_RAD,
            velocity_rad_s: [0.0; 2],
            full_scale_nm,
            jammed: false,
        };
        plant.publish_encoders();
        plant
    }

    fn publish_encoders(&self) {
        for k in 0..2 {
            let counts = libm::roundf(self.angle_rad[k] * (COUNTS_PER_REV as f32 / (2.0 * core::f32::consts::PI)));
            hardware::set_encoder_counts(k, counts as i32);
        }
    }

    /// Advances the machine by `period_s` under the torques the PWM commands now. A pose the
    /// linkage cannot take (driven through a singularity) jams it: it stops where it is.
    pub fn advance(&mut self, period_s: f32) {
        let torque_nm =
            if hardware::drive_enable() { hardware::commanded_torque_nm(self.full_scale_nm) } else { [0.0; 2] };
        if !self.jammed && self.integrate(torque_nm, period_s).is_none() {
            self.jammed = true;
            self.velocity_rad_s = [0.0; 2];
        }
        self.publish_encoders();
    }

    fn integrate(&mut self, torque_nm: [f32; 2], period_s: f32) -> Option<()> {
        let p = self.params;
        let (mut angle, mut velocity) = (self.angle_rad, self.velocity_rad_s);
        let half = 0.5 * period_s;
        let mid = [angle[0] + velocity[0] * half, angle[1] + velocity[1] * half];
        let pose = self.linkage.forward_pose(mid, 0.0).ok()?;
        let (m, bias) = p.dynamics.mass_matrix_and_bias(&pose, velocity).ok()?;
        let h = period_s / p.substeps as f32;
        for _ in 0..p.substeps {
            let mut r = [0.0f32; 2];
            for k in 0..2 {
                let w = velocity[k];
                let friction = p.viscous_nm_s_per_rad * w + p.coulomb_nm * w / (w.abs() + p.coulomb_smoothing_rad_s);
                r[k] = torque_nm[k] - bias[k] - friction;
            }
            let acc = solve_spd(&m, r).ok()?;
            for k in 0..2 {
                let before = velocity[k];
                velocity[k] += acc[k] * h;
                angle[k] += 0.5 * (before + velocity[k]) * h;
            }
        }
        if !(angle.iter().chain(velocity.iter()).all(|v| v.is_finite())) {
            return None;
        }
        self.angle_rad = angle;
        self.velocity_rad_s = velocity;
        Some(())
    }
}
