//! Physical plausibility of a fitted effect: the values must be something a machine can have
//! (the selection's third test, `selection.rs`). Limits: backlash not significantly negative,
//! link changes within 5 % of the link, stretch within 0.1 % strain and c's compliance not
//! significantly (3σ) beyond a factor 3 of b's, the mismatch's effective part errors within 1 %
//! of a link, encoder offsets and frame rotation within 0.1 rad, gear ratio within 1 %, scale
//! within 2000 ppm, B0 within 10 % of a link. Cost: negligible (the mismatch: one product with
//! its effective errors).

use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{idx, Effect};
use crate::effect::PhysicalEffect;

/// Whether an effect's fitted values are something a machine can have (module doc); the error
/// says which value is not. `s2` scales the standard deviations (µm²).
pub fn plausible(problem: &Problem, e: &Effect, f: &Fit, s2: f64) -> Result<(), String> {
    let m = &problem.base;
    let links = [m.a_mm, m.b_mm, m.c_mm, m.d_mm];
    let mean_link_um = 250.0 * (m.a_mm + m.b_mm + m.c_mm + m.d_mm);
    let x = &f.p;
    let sd = |k: usize| {
        f.free
            .iter()
            .position(|&c| c == k)
            .map(|c| (f.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
            .unwrap_or(0.0)
    };
    let within = |k: usize, limit: f64, what: &str| -> Result<(), String> {
        if x[k].abs() <= limit {
            Ok(())
        } else {
            Err(format!(
                "{} = {:.1} is beyond a plausible {what} ({limit:.0})",
                super::library::PARAM_NAMES[k],
                x[k]
            ))
        }
    };
    match e.kind {
        PhysicalEffect::LinkLengths => (0..4).try_for_each(|k| within(idx::LINKS + k, 0.05 * links[k] * 1e3, "5 % of the link")),
        PhysicalEffect::EncoderOffset => (0..2).try_for_each(|k| within(idx::OFFSETS + k, 1e5, "0.1 rad")),
        PhysicalEffect::BaseOffset => (0..2).try_for_each(|k| within(idx::BASE + k, 0.1 * mean_link_um, "10 % of a link")),
        PhysicalEffect::Backlash => (0..2).try_for_each(|k| {
            let (v, s) = (x[idx::BACKLASH + k], sd(idx::BACKLASH + k));
            if v < -3.0 * s - 1e-9 {
                Err(format!(
                    "{} = {v:.1} ± {s:.1}: negative lost motion (the link ahead of its motor) is not backlash",
                    super::library::PARAM_NAMES[idx::BACKLASH + k]
                ))
            } else {
                within(idx::BACKLASH + k, 1e4, "0.01 rad of lost motion")
            }
        }),
        PhysicalEffect::LinkStretch => {
            let n = super::sixbar_modes::N_STRETCH;
            (0..n).try_for_each(|k| within(idx::STRETCH + k, 1e-3 * links[1].min(links[2]) * 1e3, "0.1 % strain of a distal bar"))?;
            // c's compliance within a factor of 3 of the design's (the two bars are alike), or
            // not significantly outside (3σ, as the backlash's sign): on a small stretch the
            // ratio is poorly determined (the sweep: −73 ± 28 % at half magnitude beside a base
            // offset and a frame, the truth's ratio being −40 to +60 %), and a hard bound on an
            // uncertain value rejected the true effect for link lengths. Never a negative
            // compliance nor more than 5×, whatever the uncertainty: a fit that runs the ratio
            // off (ks → 0, kc → 10⁶ ± 10⁹: c stretching alone) is degenerate, not uncertain.
            let (r, s) = (x[idx::STRETCH_RATIO], sd(idx::STRETCH_RATIO));
            if (-100.0..=400.0).contains(&r) && r + 3.0 * s >= -67.0 && r - 3.0 * s <= 200.0 {
                Ok(())
            } else {
                Err(format!("kc_compliance_pct = {r:.0} ± {s:.0}: c would be {:.2}× as compliant as designed", 1.0 + r / 100.0))
            }
        }
        PhysicalEffect::Frame => within(idx::FRAME + 2, 1e5, "0.1 rad"),
        PhysicalEffect::Scale => within(idx::SCALE, 2000.0, "instrument scale error (ppm)"),
        PhysicalEffect::GearRatio => (0..2).try_for_each(|k| within(idx::GEAR + k, 1e4, "1 % ratio error (ppm)")),
        PhysicalEffect::ParallelogramMismatch => {
            let worst = problem
                .effective_sixbar(x)
                .map(|eff| eff.mismatch_raw_um.iter().fold(0.0f64, |a, v| a.max(v.abs())))
                .unwrap_or(f64::INFINITY);
            let limit = 0.01 * mean_link_um;
            if worst <= limit {
                Ok(())
            } else {
                Err(format!("the mismatch needs part errors of {worst:.0} µm, beyond a plausible 1 % of a link ({limit:.0} µm)"))
            }
        }
        _ => Ok(()),
    }
}
