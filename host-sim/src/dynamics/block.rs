//! How the effects a diagnosis names go into the image's dynamics block (`HRDY`,
//! `kinematics_core::FiveBarDynamics`): Coulomb and viscous friction, a tool mass and a motor
//! inertia are the block's own parameters (added exactly; friction and mass estimated below
//! zero are clamped at zero); a torque constant's error scales a motor's whole torque, which
//! the block has no factor for, so the commanded torque it implies (the machine's need divided
//! by `1 + k`) is fitted onto the block's parameters by least squares over the excitation's
//! samples (`calib::dynamics::fit_rows`, base parameters on a rhombus), what is left reported;
//! cogging has no place in the block (reported as not carried, with the torque it leaves).

use super::report::Carried;
use super::samples::MotionSample;
use super::torque_fit::{with_effects, Fit};
use crate::calib::dynamics::fit_rows;
use crate::effect::PhysicalEffect;
use kinematics_core::dynamics::{regressor, PARAMETERS};
use kinematics_core::FiveBarDynamics;

/// The dynamics block with the named effects added (see the module doc), and how each is
/// carried.
pub(super) fn block_update(
    d0: &FiveBarDynamics<f64>,
    fit: &Fit,
    samples: &[MotionSample],
) -> (Option<FiveBarDynamics<f64>>, Vec<Carried>) {
    let (mut d, x) = with_effects(d0, fit);
    let mut carried = Vec::new();
    let mut ok = true;
    let cogging_rms = |s: &MotionSample| -> [f64; 2] {
        [0, 1].map(|k| {
            let (sn, cs) = (x.cogging_cycles * s.motion.angle_rad[k]).sin_cos();
            x.cogging_nm[k][0] * sn + x.cogging_nm[k][1] * cs
        })
    };
    for c in &fit.cands {
        match c.e.effect {
            PhysicalEffect::Cogging => {
                let sq: f64 = samples
                    .iter()
                    .map(|s| {
                        let v = cogging_rms(s);
                        v[0] * v[0] + v[1] * v[1]
                    })
                    .sum();
                carried.push(Carried {
                    effect: c.name().into(),
                    how: "not_carried".into(),
                    residual_nm: (sq / (2 * samples.len().max(1)) as f64).sqrt(),
                });
            }
            PhysicalEffect::TorqueConstant => {}
            _ => carried.push(Carried {
                effect: c.name().into(),
                how: "exact".into(),
                residual_nm: 0.0,
            }),
        }
    }
    if x.torque_error != [0.0; 2] {
        // τ commanded = (what the machine needs) / (1 + k), fitted onto the block's parameters.
        let (mut rows, mut rhs) = (Vec::new(), Vec::new());
        for s in samples {
            let (Ok(y), Ok(tau)) = (
                regressor(&s.motion, d.coulomb_speed_rad_s),
                d.torque_nm(&s.motion),
            ) else {
                continue;
            };
            for k in 0..2 {
                rows.extend_from_slice(&y[k]);
                rhs.push(tau[k] / (1.0 + x.torque_error[k]));
            }
        }
        let target = rhs.clone();
        match fit_rows(&rows, rhs, 0) {
            Ok(id) => {
                let p = id.dynamics.to_array();
                let sq: f64 = rows
                    .chunks(PARAMETERS)
                    .zip(&target)
                    .map(|(row, t)| {
                        let v: f64 = row.iter().zip(&p).map(|(a, b)| a * b).sum();
                        (v - t).powi(2)
                    })
                    .sum();
                carried.push(Carried {
                    effect: PhysicalEffect::TorqueConstant.name().into(),
                    how: "projected".into(),
                    residual_nm: (sq / target.len().max(1) as f64).sqrt(),
                });
                d = id.dynamics;
            }
            Err(_) => ok = false,
        }
    }
    for k in 0..2 {
        d.coulomb_nm[k] = d.coulomb_nm[k].max(0.0);
        d.viscous_nm_s_per_rad[k] = d.viscous_nm_s_per_rad[k].max(0.0);
    }
    d.tool_mass_kg = d.tool_mass_kg.max(0.0);
    let valid = ok && d.validate().is_ok();
    (valid.then_some(d), carried)
}
