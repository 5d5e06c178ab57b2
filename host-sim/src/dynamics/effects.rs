//! The library of dynamic effects a controller's dynamics model can miss, each a set of torque
//! columns: what the effect adds to the torque the machine needs at each sample, per unit of
//! each of its parameters.
//!
//! | effect | parameters (what the model lacks) | column at motor i |
//! |---|---|---|
//! | `coulomb_friction` | `coulomb_1_nm`, `coulomb_2_nm` | `s(θ̇ᵢ) = θ̇ᵢ/(\|θ̇ᵢ\| + ω_c)` (the model's smoothed sign) |
//! | `viscous_friction` | `viscous_1_nm_s_per_rad`, `viscous_2_nm_s_per_rad` | `θ̇ᵢ` |
//! | `tool_mass` | `tool_mass_kg` | `Jᵢᵀ·C̈` (both motors: the regressor's tool column) |
//! | `motor_inertia` | `motor_1_inertia_kg_m2`, `motor_2_inertia_kg_m2` | `θ̈ᵢ` |
//! | `torque_constant` | `torque_constant_1_pct`, `torque_constant_2_pct` | `−τᵢ/100`, `τ` the model's torque: a motor that delivers `(1 + k/100)` times the command needs `τ/(1 + k/100) ≈ τ·(1 − k/100)` commanded (the model's torque, not the one measured: a column made of the measurement would fit the measurement with itself) |
//! | `cogging` | `cogging_1_nm`, `cogging_1_phase_deg`, (motor 2 alike), `cogging_cycles_per_rev` | `sin(n·θᵢ)`, `cos(n·θᵢ)`: a ripple periodic in the motor angle, `n` cycles per joint revolution found by a scan |
//!
//! Every column is linear in its parameters (cogging's amplitude and phase are its sine and
//! cosine coefficients), so an effect is fitted with the others by linear least squares, and
//! the four first are the dynamics block's own parameters: adding them to the model is adding
//! numbers. A torque constant scales a motor's whole torque, which the block has no factor
//! for; cogging has no place in it at all (see `diagnose`: how the named effects go into the
//! block, and what it cannot carry).
//!
//! Cogging's period: the scan tries every whole number of cycles per joint revolution in
//! [`COGGING_CYCLES`] (a motor's slots times its gear ratio) and keeps the one that explains
//! the most; the selection's threshold pays for the scan (`diagnose`). It starts at 20 cycles
//! per revolution, three periods over the joints' third of a radian-and-more of travel: slower
//! ripples are a smooth dependence on the configuration, which the structure test reports.

use super::samples::MotionSample;
use crate::effect::PhysicalEffect;
use kinematics_core::dynamics::regressor;

/// Cycles per joint revolution the cogging scan tries (inclusive).
pub const COGGING_CYCLES: (u32, u32) = (20, 400);

/// A library effect.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynamicEffect {
    pub effect: PhysicalEffect,
    /// Parameter names (units in the names), in column order.
    pub params: &'static [&'static str],
}

/// The library, in the order candidates are listed.
pub const LIBRARY: [DynamicEffect; 6] = [
    DynamicEffect {
        effect: PhysicalEffect::CoulombFriction,
        params: &["coulomb_1_nm", "coulomb_2_nm"],
    },
    DynamicEffect {
        effect: PhysicalEffect::ViscousFriction,
        params: &["viscous_1_nm_s_per_rad", "viscous_2_nm_s_per_rad"],
    },
    DynamicEffect {
        effect: PhysicalEffect::ToolMass,
        params: &["tool_mass_kg"],
    },
    DynamicEffect {
        effect: PhysicalEffect::MotorInertia,
        params: &["motor_1_inertia_kg_m2", "motor_2_inertia_kg_m2"],
    },
    DynamicEffect {
        effect: PhysicalEffect::TorqueConstant,
        params: &["torque_constant_1_pct", "torque_constant_2_pct"],
    },
    DynamicEffect {
        effect: PhysicalEffect::Cogging,
        params: &[
            "cogging_1_sin_nm",
            "cogging_1_cos_nm",
            "cogging_2_sin_nm",
            "cogging_2_cos_nm",
        ],
    },
];

/// The library entry of `effect`.
pub fn entry(effect: PhysicalEffect) -> Option<&'static DynamicEffect> {
    LIBRARY.iter().find(|e| e.effect == effect)
}

/// The columns of one effect at one sample: `cols[p][i]` is parameter p's torque at motor i.
/// `model_torque_nm` is the model's torque at the sample, `coulomb_speed_rad_s` its Coulomb
/// speed; `cogging_cycles` the cogging's cycles per joint revolution. `None` where the
/// regressor fails (a singular pose).
pub fn columns(
    e: &DynamicEffect,
    s: &MotionSample,
    model_torque_nm: [f64; 2],
    coulomb_speed_rad_s: f64,
    cogging_cycles: f64,
) -> Option<Vec<[f64; 2]>> {
    let m = &s.motion;
    let w = m.velocity_rad_s;
    let sign = |v: f64| v / (v.abs() + coulomb_speed_rad_s);
    Some(match e.effect {
        PhysicalEffect::CoulombFriction => vec![[sign(w[0]), 0.0], [0.0, sign(w[1])]],
        PhysicalEffect::ViscousFriction => vec![[w[0], 0.0], [0.0, w[1]]],
        PhysicalEffect::ToolMass => {
            let y = regressor(m, coulomb_speed_rad_s).ok()?;
            vec![[y[0][2], y[1][2]]]
        }
        PhysicalEffect::MotorInertia => {
            let a = m.acceleration_rad_s2;
            vec![[a[0], 0.0], [0.0, a[1]]]
        }
        PhysicalEffect::TorqueConstant => {
            let t = model_torque_nm;
            vec![[-t[0] / 100.0, 0.0], [0.0, -t[1] / 100.0]]
        }
        PhysicalEffect::Cogging => {
            let th = m.angle_rad;
            let (s1, c1) = (cogging_cycles * th[0]).sin_cos();
            let (s2, c2) = (cogging_cycles * th[1]).sin_cos();
            vec![[s1, 0.0], [c1, 0.0], [0.0, s2], [0.0, c2]]
        }
        _ => return None,
    })
}
