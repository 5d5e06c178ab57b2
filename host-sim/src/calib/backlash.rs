//! The direction-dependent correction of backlash ("close the loop").
//!
//! Backlash is lost motion β_j between motor j's encoder and its link: a motor that last moved
//! in +θ (dir = +1) drags the link behind it, so the link sits β/2 short of the encoder angle,
//! `link = encoder − dir·β/2` (the diagnosis' convention, `diagnose/forward_model.rs`). No grid can
//! correct it (a grid node is one correction per place, the error flips with the direction);
//! but the servo knows the direction each motor approaches from, so the command can:
//! `encoder command = link angle wanted + dir·β/2`.
//!
//! Three uses, one rule:
//! * [`Backlash::command_rad`]: the commanded encoder angles for a motion whose motors arrive in
//!   directions `dir` (the measurement path [`super::measure::measure_visits_compensated`], and
//!   `host-sim command` with a model that carries `backlash_urad`);
//! * [`Backlash::link_angles`]: measurement rows with the encoder angles turned back into link
//!   angles, so that a grid built from them is free of backlash whatever the directions were
//!   (`host-sim grid`, the demo's pipeline);
//! * [`estimate`]: β from measurements with both approach directions, by the diagnosis' one
//!   LM fit of the model's effects (the hidden robot's parameters, the six-bar's own effects
//!   and backlash, jointly: the configuration-dependent part cannot then leak into β).
//!
//! Where it runs: on the host (the measurement path, `command`); the firmware's servo applies
//! the same convention from the image's backlash block (`kinematics_core::backlash`, written by
//! `calib::image::append_backlash_block`). Cost: two additions per command.

use super::{invalid, CalibError};
use crate::diagnose::fit::fit;
use crate::diagnose::forward_model::Problem;
use crate::diagnose::library::{effect, idx, N_PARAMS};
use crate::io::measurement_csv::Measurement;
use crate::loop_closure::SixBarDesign;
use kinematics_core::FiveBar;

/// Largest lost motion accepted (µrad): 0.01 rad; more is not a backlash but a broken drive.
pub const MAX_BACKLASH_URAD: f64 = 1e4;

/// Lost motion per motor (µrad, ≥ 0).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Backlash {
    pub lost_motion_urad: [f64; 2],
}

impl Backlash {
    /// A validated backlash: finite, not negative, at most [`MAX_BACKLASH_URAD`].
    pub fn new(lost_motion_urad: [f64; 2]) -> Result<Self, CalibError> {
        for (j, b) in lost_motion_urad.iter().enumerate() {
            if !(b.is_finite() && (0.0..=MAX_BACKLASH_URAD).contains(b)) {
                return Err(invalid!("backlash of motor {}: {b} µrad is not a lost motion in [0, {MAX_BACKLASH_URAD}]", j + 1));
            }
        }
        Ok(Backlash { lost_motion_urad })
    }

    /// The encoder angles to command so that the links land at `link_rad` when the motors
    /// arrive in directions `dir` (±1).
    pub fn command_rad(&self, link_rad: [f64; 2], dir: [i8; 2]) -> [f64; 2] {
        [0, 1].map(|j| link_rad[j] + f64::from(dir[j]) * self.lost_motion_urad[j] * 0.5e-6)
    }

    /// The rows with their encoder angles turned into link angles (`θ − dir·β/2`); every row
    /// needs its approach directions.
    pub fn link_angles(&self, rows: &[Measurement]) -> Result<Vec<Measurement>, CalibError> {
        rows.iter()
            .map(|m| {
                let dir = m.dir.ok_or_else(|| {
                    invalid!(
                        "line {}: a backlash correction needs the dir1,dir2 columns",
                        m.line
                    )
                })?;
                let mut out = m.clone();
                for ((t, d), b) in out.theta_deg.iter_mut().zip(dir).zip(self.lost_motion_urad) {
                    *t -= (f64::from(d) * b * 0.5e-6).to_degrees();
                }
                Ok(out)
            })
            .collect()
    }
}

/// The approach direction of each motor for a move from `from_rad` to `to_rad` (+1 when the
/// change, wrapped, is ≥ 0): the rule of the measurement path.
pub fn approach_dir(from_rad: [f64; 2], to_rad: [f64; 2]) -> [i8; 2] {
    [0, 1].map(|j| {
        if kinematics_core::wrap_angle_rad(to_rad[j] - from_rad[j]) >= 0.0 {
            1
        } else {
            -1
        }
    })
}

/// β (µrad) and its standard deviation from measurements with approach directions, against
/// `base` (the fitted model they were commanded with): one LM fit of link lengths, encoder
/// offsets, base offset, the six-bar's link stretch and parallelogram mismatch and backlash
/// together (module doc). A negative fitted β (within the noise of zero) is returned as 0.
pub fn estimate(
    data: &[Measurement],
    base: &FiveBar<f64>,
    design: &SixBarDesign,
) -> Result<(Backlash, [f64; 2]), CalibError> {
    let problem = Problem::new(*base, design, data);
    if !problem.has_dir {
        return Err(invalid!(
            "estimating backlash needs the dir1,dir2 columns on every row"
        ));
    }
    for d in 0..2 {
        let both = problem.points.iter().any(|p| p.dir[d] > 0.0)
            && problem.points.iter().any(|p| p.dir[d] < 0.0);
        if !both {
            return Err(invalid!(
                "motor {} approaches from one side only: its backlash cannot be measured",
                d + 1
            ));
        }
    }
    let names = [
        "link_lengths",
        "encoder_offset",
        "base_offset",
        "backlash",
        "link_stretch",
        "parallelogram_mismatch",
    ];
    let mut free = Vec::new();
    for name in names {
        let e = effect(name).ok_or_else(|| invalid!("internal: no effect {name}"))?;
        if problem.available(e).is_ok() {
            free.extend_from_slice(e.params);
        }
    }
    let f = fit(&problem, &[0.0; N_PARAMS], &free)
        .ok_or_else(|| invalid!("the backlash fit failed (a point left the workspace)"))?;
    let n = f.residuals.len() as f64;
    let s2 = f.cost / (n - f.free.len() as f64).max(1.0);
    let sd = [0, 1].map(|j| {
        let k = idx::BACKLASH + j;
        f.free
            .iter()
            .position(|&c| c == k)
            .map_or(f64::NAN, |c| (f.normal_pinv[(c, c)] * s2).max(0.0).sqrt())
    });
    let beta = [0, 1].map(|j| f.p[idx::BACKLASH + j].max(0.0));
    Ok((Backlash::new(beta)?, sd))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_and_link_angles_are_inverse() {
        let b = Backlash::new([40.0, 100.0]).unwrap();
        let cmd = b.command_rad([0.5, -0.3], [1, -1]);
        assert!((cmd[0] - (0.5 + 20e-6)).abs() < 1e-15 && (cmd[1] - (-0.3 - 50e-6)).abs() < 1e-15);
        let row = Measurement {
            theta_deg: [cmd[0].to_degrees(), cmd[1].to_degrees()],
            measured_mm: [0.0; 2],
            target_mm: None,
            dir: Some([1, -1]),
            run: None,
            t_s: None,
            line: 2,
        };
        let back = b.link_angles(std::slice::from_ref(&row)).unwrap();
        assert!((back[0].theta_deg[0].to_radians() - 0.5).abs() < 1e-12);
        assert!((back[0].theta_deg[1].to_radians() + 0.3).abs() < 1e-12);
        let mut no_dir = row;
        no_dir.dir = None;
        assert!(b
            .link_angles(&[no_dir])
            .unwrap_err()
            .to_string()
            .contains("line 2"));
    }

    #[test]
    fn refuses_what_is_not_a_backlash() {
        for bad in [
            [-1.0, 0.0],
            [f64::NAN, 0.0],
            [0.0, 2e4],
            [0.0, f64::INFINITY],
        ] {
            assert!(Backlash::new(bad).is_err(), "{bad:?}");
        }
    }
}
