//! The controller's dynamics model as a plant: the rigid hidden robot with the model's inertias
//! and friction, plus the library's effects (a torque constant, cogging), driven by the
//! servo's torques. What the closed loop would do if the machine were its model
//! (`predict`); the diagnosis compares that with the machine's telemetry.
//!
//! ```text
//! M(θ)·θ̈ + h(θ, θ̇) + fv·θ̇ + fc·θ̇/(|θ̇| + ω_c) + cog(θ) = k·τ
//! ```
//! `M` and `h` from `FiveBarDynamics::mass_matrix_and_bias` (friction left out), the friction
//! the model's own (Coulomb smoothed as the model's is), `k` the motors' torque per command,
//! `cog` a ripple `a·sin(nθ) + b·cos(nθ)` per motor. Angles are encoder angles: the model's
//! kinematics read them.
//!
//! Integration over each servo sample (torque held): `M` and the velocity products'
//! coefficients at the configuration predicted for the sample's middle (as the six-bar plant
//! does, `plant::motion`), then classical Runge–Kutta in [`SUBSTEPS`] steps with the friction
//! at every stage. Cost: four evaluations of the inverse dynamics and one forward kinematics
//! per sample, a few dozen flops per stage.

use kinematics_core::{FiveBar, FiveBarDynamics, KinematicsError};

/// Runge–Kutta steps per servo sample.
pub const SUBSTEPS: u32 = 4;

/// What the model lacks beyond its own parameters.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Extras {
    /// Torque delivered per torque commanded, minus one, per motor (a torque constant's error).
    pub torque_error: [f64; 2],
    /// Cogging: sine and cosine amplitudes per motor (N·m) and cycles per joint revolution.
    pub cogging_nm: [[f64; 2]; 2],
    pub cogging_cycles: f64,
}

/// The model as a plant, with its state.
#[derive(Clone, Debug)]
pub struct ModelPlant {
    model: FiveBar<f64>,
    dynamics: FiveBarDynamics<f64>,
    extras: Extras,
    /// Encoder angles (rad) and their rates (rad/s).
    pub angle_rad: [f64; 2],
    pub velocity_rad_s: [f64; 2],
}

impl ModelPlant {
    /// At rest at `angle_rad`.
    pub fn new(
        model: FiveBar<f64>,
        dynamics: FiveBarDynamics<f64>,
        extras: Extras,
        angle_rad: [f64; 2],
    ) -> Self {
        ModelPlant {
            model,
            dynamics,
            extras,
            angle_rad,
            velocity_rad_s: [0.0; 2],
        }
    }

    /// Advances by `dt_s` under the commanded torques `torque_nm` (held).
    pub fn advance(&mut self, torque_nm: [f64; 2], dt_s: f64) -> Result<(), KinematicsError> {
        let d = &self.dynamics;
        let mid = [0, 1].map(|k| self.angle_rad[k] + 0.5 * dt_s * self.velocity_rad_s[k]);
        let pose = self.model.forward_pose(mid, 0.0)?;
        // M, and h(w) = Σ wᵢwⱼ·cᵢⱼ from three evaluations (h is a quadratic form in w).
        let (m, h1) = d.mass_matrix_and_bias(&pose, [1.0, 0.0])?;
        let (_, h2) = d.mass_matrix_and_bias(&pose, [0.0, 1.0])?;
        let (_, h12) = d.mass_matrix_and_bias(&pose, [1.0, 1.0])?;
        let cross = [0, 1].map(|k| 0.5 * (h12[k] - h1[k] - h2[k]));
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        if !(det > 0.0 && m[0][0] > 0.0) {
            return Err(KinematicsError::NonFinite);
        }
        let inv = [
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ];
        let e = &self.extras;
        let tau = [0, 1].map(|k| (1.0 + e.torque_error[k]) * torque_nm[k]);
        let accel = |th: [f64; 2], w: [f64; 2]| {
            let mut r = [0.0; 2];
            for k in 0..2 {
                let h = w[0] * w[0] * h1[k] + w[1] * w[1] * h2[k] + 2.0 * w[0] * w[1] * cross[k];
                let friction = d.viscous_nm_s_per_rad[k] * w[k]
                    + d.coulomb_nm[k] * w[k] / (w[k].abs() + d.coulomb_speed_rad_s);
                let (s, c) = (e.cogging_cycles * th[k]).sin_cos();
                let cog = e.cogging_nm[k][0] * s + e.cogging_nm[k][1] * c;
                r[k] = tau[k] - h - friction - cog;
            }
            [
                inv[0][0] * r[0] + inv[0][1] * r[1],
                inv[1][0] * r[0] + inv[1][1] * r[1],
            ]
        };
        let h = dt_s / f64::from(SUBSTEPS);
        let add = |x: [f64; 2], d: [f64; 2], s: f64| [x[0] + d[0] * s, x[1] + d[1] * s];
        for _ in 0..SUBSTEPS {
            let (th, w) = (self.angle_rad, self.velocity_rad_s);
            let a1 = accel(th, w);
            let (t2, w2) = (add(th, w, h / 2.0), add(w, a1, h / 2.0));
            let a2 = accel(t2, w2);
            let (t3, w3) = (add(th, w2, h / 2.0), add(w, a2, h / 2.0));
            let a3 = accel(t3, w3);
            let (t4, w4) = (add(th, w3, h), add(w, a3, h));
            let a4 = accel(t4, w4);
            for k in 0..2 {
                self.angle_rad[k] += h / 6.0 * (w[k] + 2.0 * w2[k] + 2.0 * w3[k] + w4[k]);
                self.velocity_rad_s[k] += h / 6.0 * (a1[k] + 2.0 * a2[k] + 2.0 * a3[k] + a4[k]);
            }
        }
        if !(self
            .angle_rad
            .iter()
            .chain(&self.velocity_rad_s)
            .all(|v| v.is_finite()))
        {
            return Err(KinematicsError::NonFinite);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics_core::joint_motion::motion_from_pose;

    /// Under the model's own torque for a motion, the plant accelerates as that motion does;
    /// a torque constant's error scales the acceleration the torque produces.
    #[test]
    fn the_models_torque_gives_the_models_acceleration() {
        let model = FiveBar::<f64>::paper_nominal();
        let d = FiveBarDynamics {
            motor_inertia_kg_m2: [3.6e-3, 3.7e-3],
            tool_mass_kg: 0.165,
            distal_inertia_kg_m2: [0.0; 2],
            viscous_nm_s_per_rad: [0.02, 0.02],
            coulomb_nm: [0.05, 0.05],
            coulomb_speed_rad_s: 0.01,
        };
        let th = model.inverse([215.0, 20.0], 0.05).unwrap();
        let (w, a) = ([1.5, -2.0], [80.0, 40.0]);
        let pose = model.forward_pose(th, 0.0).unwrap();
        let tau = d
            .torque_nm(&motion_from_pose(&pose, w, a).unwrap())
            .unwrap();
        let dt = 1e-6;
        let mut p = ModelPlant::new(model, d, Extras::default(), th);
        p.velocity_rad_s = w;
        p.advance(tau, dt).unwrap();
        for k in 0..2 {
            let got = (p.velocity_rad_s[k] - w[k]) / dt;
            assert!(
                (got - a[k]).abs() < 1e-3 * a[k].abs(),
                "{k}: {got} vs {}",
                a[k]
            );
        }
        let extras = Extras {
            torque_error: [0.1, 0.0],
            ..Extras::default()
        };
        let mut q = ModelPlant::new(model, d, extras, th);
        q.velocity_rad_s = w;
        q.advance(tau, dt).unwrap();
        assert!(((q.velocity_rad_s[0] - w[0]) / dt - a[0]).abs() > 0.05 * a[0].abs());
    }
}
