//! The servo's own check of a calibration image, on top of the machine's judgement
//! (`kinematics_core::machine`: the node corrections, their change between neighbours, the
//! dynamics, the backlash and the workspace against the machine record's limits; see
//! [`crate::calibration`]).
//!
//! The machine's judgement bounds the correction and its slope (first difference); it does not
//! bound how fast the slope changes from one cell to the next (second difference). Between
//! nodes the correction is bilinear, so its slope steps at every cell boundary, and a move
//! across the grid at speed `v` turns a slope change `Δs` into a reference-speed step `v·Δs`
//! that the servo's derivative gain turns into a torque step. The limit:
//!
//! | what | limit | derived from |
//! |---|---|---|
//! | the slope's change from one cell to the next, `|δ(i+1) − 2δ(i) + δ(i−1)| / step`, per axis, along x and y | [`MAX_REFERENCE_SPEED_STEP_RAD_S`] / `servo.max_speed_mm_s` (3.3e-5 rad/mm with the default 3000 mm/s) | a move at the servo's top speed meets a reference-speed step of at most 0.1 rad/s at a cell boundary: at most 1 N·m through the derivative gain (`kd` 10.4 N·m·s/rad) |
//!
//! A limit of the servo (its top speed), not of the machine file: the board's settings give it
//! ([`max_slope_change_rad_per_mm`]). Real grids sit far inside: host-sim's demo grid of the
//! paper's machine changes its slope by 6e-7 rad/mm, the QEMU board's synthetic image by
//! 9.3e-7 rad/mm.
//!
//! Cost: a few operations per node and axis (about 20,000 instructions for the paper's 651
//! nodes); run with the machine's judgement, never in the servo's sample.
use kinematics_core::{CorrectionGrid, ServoConfig};

/// The reference speed step a move across the grid at the servo's top speed may meet at a cell
/// boundary (rad/s): the slope-change limit is this over `ServoConfig::max_speed_mm_s`.
pub const MAX_REFERENCE_SPEED_STEP_RAD_S: f32 = 0.1;

/// The slope-change limit for `servo` (rad/mm): [`MAX_REFERENCE_SPEED_STEP_RAD_S`] over its top
/// speed.
pub fn max_slope_change_rad_per_mm(servo: &ServoConfig) -> f32 {
    MAX_REFERENCE_SPEED_STEP_RAD_S / servo.max_speed_mm_s
}

/// A slope change beyond the limit: at `node` (its neighbours before and after it along x or
/// y), motor `axis`'s correction's slope changes by `value_rad_per_mm`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlopeChange {
    /// The node `(i, j)` in the middle.
    pub node: [u16; 2],
    /// Motor 0 or 1.
    pub axis: u8,
    /// The slope change (rad/mm).
    pub value_rad_per_mm: f32,
    /// The limit (rad/mm).
    pub limit_rad_per_mm: f32,
}

impl core::fmt::Display for SlopeChange {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "implausible calibration image: motor {}'s correction changes its slope by {:e} rad/mm at grid node ({}, {}), the limit is {:e} rad/mm: a move across it at the servo's top speed would step the reference speed",
            self.axis + 1,
            self.value_rad_per_mm,
            self.node[0],
            self.node[1],
            self.limit_rad_per_mm
        )
    }
}

/// The largest slope change of `grid`'s corrections (rad/mm), or the first node beyond
/// `limit_rad_per_mm` (a NaN limit or value refuses).
pub fn slope_change(grid: &CorrectionGrid<'_>, limit_rad_per_mm: f32) -> Result<f32, SlopeChange> {
    let g = *grid.geometry();
    let node = |i: u16, j: u16| grid.node_rad(i, j);
    let mut largest = 0.0f32;
    for j in 0..g.ny {
        for i in 0..g.nx {
            let d = node(i, j);
            // Along x, then y: the node with a neighbour on either side.
            let along = [
                (i > 0 && i + 1 < g.nx).then(|| (node(i - 1, j), node(i + 1, j), g.step_x_mm)),
                (j > 0 && j + 1 < g.ny).then(|| (node(i, j - 1), node(i, j + 1), g.step_y_mm)),
            ];
            for (before, after, step_mm) in along.into_iter().flatten() {
                for axis in 0..2 {
                    let change = (after[axis] - 2.0 * d[axis] + before[axis]).abs() / step_mm;
                    if !(change <= limit_rad_per_mm) {
                        return Err(SlopeChange {
                            node: [i, j],
                            axis: axis as u8,
                            value_rad_per_mm: change,
                            limit_rad_per_mm,
                        });
                    }
                    largest = largest.max(change);
                }
            }
        }
    }
    Ok(largest)
}
