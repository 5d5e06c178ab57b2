//! Motor angles for a list of targets, computed exactly as the firmware does (`host-sim command`).
//!
//! Why: a calibration (model + grid) must be verifiable off-line. Each target goes through
//! `kinematics_core::Calibration::command_rad` in f32 — the same function, the same scalar type
//! and the same grid image the MCU runs — so the angles written here are bit-identical to what the
//! servo would command for that setpoint (before unwrapping next to the motor position).
//! Cost: one IK and one bilinear lookup per target. Error: f32, ~0.01 µm at the tool.
//!
//! Input: the targets CSV (`crate::io::targets_csv`). Output ([`format_commands`]):
//! `x_mm,y_mm,theta1_deg,theta2_deg` (degrees with 9 decimals: f32 radians round-trip exactly).
//! Any unreachable target, any target outside the machine's workspace ([`check_in_workspace`]:
//! the image's workspace block when the grid has one, else the machine file's), any target
//! outside the grid, or a grid built for another model is an error naming the line; nothing is
//! written then.
//!
//! With a backlash correction (a model file with `backlash_urad`, `calib::backlash`) the targets
//! are a motion in file order: each motor's approach direction is the sign of its (unwrapped)
//! command change from the previous target (the first target: +1, the machine's position
//! before it being unknown), each command is moved by dir·β/2 and the output gets `dir1,dir2`
//! columns ([`command_all_compensated`], [`format_commands_with_dirs`]).

use super::{invalid, CalibError};
use crate::io::targets_csv::Target;
use kinematics_core::{Calibration, ConvexWorkspace, CorrectionGrid, FiveBar};

/// How far outside the workspace's edge a target may lie (mm): f32 rounding of an image's
/// vertices (0.004 µm at 162 mm) and of targets written with fewer digits.
pub const WORKSPACE_TOLERANCE_MM: f64 = 1e-3;

/// Refuses the first target outside `region` (the machine `machine`'s workspace, as its file
/// or, `from_image`, its grid image's workspace block states it), naming its line.
pub fn check_in_workspace(
    targets: &[Target],
    region: &ConvexWorkspace<f64>,
    machine: &str,
    from_image: bool,
) -> Result<(), CalibError> {
    for &Target { line, target_mm: t } in targets {
        if !region.contains(t, -WORKSPACE_TOLERANCE_MM) {
            // Vertices to the µm: an image's f32 polygon printed in full reads 162.1320037841797.
            let vertices = region
                .vertices_mm()
                .iter()
                .map(|v| format!("({:.3}, {:.3})", v[0], v[1]))
                .collect::<Vec<_>>()
                .join(", ");
            return Err(invalid!(
                "line {line}: target ({}, {}) is outside the workspace of machine '{machine}' ({:.3} mm beyond its edge{}; vertices {vertices} mm): nothing was written; move or remove that target and run again",
                t[0],
                t[1],
                -region.clearance_mm(t),
                if from_image { ", as the grid image's workspace block states it" } else { "" },
            ));
        }
    }
    Ok(())
}

/// Checks that the grid was built for `model` (every parameter equal after rounding to f32).
pub fn check_grid_model(grid: &CorrectionGrid<'_>, model: &FiveBar<f64>) -> Result<(), CalibError> {
    let want = model.cast::<f32>();
    let got = grid.model();
    let pairs = [
        ("a_mm", got.a_mm, want.a_mm),
        ("b_mm", got.b_mm, want.b_mm),
        ("c_mm", got.c_mm, want.c_mm),
        ("d_mm", got.d_mm, want.d_mm),
        ("base_a0_x_mm", got.base_a0_mm[0], want.base_a0_mm[0]),
        ("base_a0_y_mm", got.base_a0_mm[1], want.base_a0_mm[1]),
        ("base_b0_x_mm", got.base_b0_mm[0], want.base_b0_mm[0]),
        ("base_b0_y_mm", got.base_b0_mm[1], want.base_b0_mm[1]),
        (
            "encoder_offset_1_rad",
            got.encoder_offset_rad[0],
            want.encoder_offset_rad[0],
        ),
        (
            "encoder_offset_2_rad",
            got.encoder_offset_rad[1],
            want.encoder_offset_rad[1],
        ),
    ];
    for (name, g, w) in pairs {
        if g != w {
            return Err(invalid!("the grid was built for another model: {name} is {g} in the grid, {w} in the model file"));
        }
    }
    if got.mode != want.mode {
        return Err(invalid!(
            "the grid was built for another working mode: {:?} vs {:?}",
            got.mode,
            want.mode
        ));
    }
    Ok(())
}

/// Commands every target; the first failure names its line.
pub fn command_all(
    cal: &Calibration<'_>,
    targets: &[Target],
    min_transmission: f32,
) -> Result<Vec<[f32; 2]>, CalibError> {
    targets
        .iter()
        .map(|&Target { line, target_mm: t }| {
            cal.command_rad([t[0] as f32, t[1] as f32], min_transmission)
                .map_err(|e| invalid!("line {line}: target ({}, {}): {e}", t[0], t[1]))
        })
        .collect()
}

/// The output file: `x_mm,y_mm,theta1_deg,theta2_deg` per target.
pub fn format_commands(targets: &[Target], angles: &[[f32; 2]]) -> String {
    let mut s = String::from("x_mm,y_mm,theta1_deg,theta2_deg\n");
    for (Target { target_mm: t, .. }, a) in targets.iter().zip(angles) {
        s.push_str(&format!(
            "{},{},{:.9},{:.9}\n",
            t[0],
            t[1],
            (a[0] as f64).to_degrees(),
            (a[1] as f64).to_degrees()
        ));
    }
    s
}

/// Corrected motor angles (rad) and each target's approach directions.
pub type CommandsWithDirs = (Vec<[f64; 2]>, Vec<[i8; 2]>);

/// [`command_all`] for a motion through the targets in file order, with the direction-dependent
/// backlash correction (module doc). Returns the corrected angles (rad, unwrapped next to the
/// previous command) and each target's approach directions.
pub fn command_all_compensated(
    cal: &Calibration<'_>,
    targets: &[Target],
    min_transmission: f32,
    backlash: &super::backlash::Backlash,
) -> Result<CommandsWithDirs, CalibError> {
    let raw = command_all(cal, targets, min_transmission)?;
    let mut previous: Option<[f64; 2]> = None;
    let mut angles = Vec::with_capacity(raw.len());
    let mut dirs = Vec::with_capacity(raw.len());
    for a in raw {
        let a = [f64::from(a[0]), f64::from(a[1])];
        let (cmd, dir) = match previous {
            None => (a, [1, 1]),
            Some(p) => {
                let cmd = [0, 1].map(|i| p[i] + kinematics_core::wrap_angle_rad(a[i] - p[i]));
                (cmd, super::backlash::approach_dir(p, cmd))
            }
        };
        previous = Some(cmd);
        angles.push(backlash.command_rad(cmd, dir));
        dirs.push(dir);
    }
    Ok((angles, dirs))
}

/// The output file with directions: `x_mm,y_mm,theta1_deg,theta2_deg,dir1,dir2` per target.
pub fn format_commands_with_dirs(
    targets: &[Target],
    angles_rad: &[[f64; 2]],
    dirs: &[[i8; 2]],
) -> String {
    let mut s = String::from("x_mm,y_mm,theta1_deg,theta2_deg,dir1,dir2\n");
    for ((Target { target_mm: t, .. }, a), d) in targets.iter().zip(angles_rad).zip(dirs) {
        s.push_str(&format!(
            "{},{},{:.9},{:.9},{},{}\n",
            t[0],
            t[1],
            a[0].to_degrees(),
            a[1].to_degrees(),
            d[0],
            d[1]
        ));
    }
    s
}
