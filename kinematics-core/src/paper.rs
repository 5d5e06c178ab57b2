//! The paper's machine (Kiper et al., Table I): the numbers the host tools and the firmware's
//! build share, in one place.
//!
//! * the nominal hidden robot: [`nominal`] (a = b = c = d = 150 mm, coincident bases, no
//!   offsets: [`FiveBar::paper_nominal`]);
//! * the workspace: the rectangle of Table I's corners, x ∈ [162.132, 262.132] mm (its centre,
//!   212.132 = 150·√2, is where the nominal five-bar is a square), y ∈ [−75, 75] mm;
//! * the correction grid's lattice: 5 mm nodes over that rectangle, 21 × 31 ([`grid_geometry`]);
//! * the servo's sample period, 0.5 ms (2 kHz);
//! * the soft limit: controlled stops end at least [`STOP_MARGIN_MM`] inside the workspace;
//! * the home position [`HOME_MM`] and the design's dynamics [`nominal_dynamics`].
//!
//! Why here: the firmware's build script bakes a grid for this lattice and the host's machine
//! description (`host_sim::machine_spec::MachineSpec::paper`) and the controller's default
//! machine record (`crate::machine::MachineRecord::paper`) start from the same numbers: one
//! copy of each. Another machine is another description (the host's machine file), not an
//! edit here. Cost: constants only.

use crate::{FiveBar, FiveBarDynamics, GridGeometry, Real};

/// Workspace x range (mm): Table I's left and right columns.
pub const WORKSPACE_X_MM: [f64; 2] = [162.132, 262.132];
/// Workspace y range (mm): Table I's bottom and top rows.
pub const WORKSPACE_Y_MM: [f64; 2] = [-75.0, 75.0];
/// Correction-grid node spacing (mm), the same along x and y.
pub const GRID_STEP_MM: f64 = 5.0;
/// Correction-grid nodes along x and y: the workspace at [`GRID_STEP_MM`], edges included.
pub const GRID_NODES: [u16; 2] = [21, 31];
/// Servo sample period (s): 2 kHz.
pub const SAMPLE_PERIOD_S: f64 = 5e-4;
/// The soft limit: how far inside the workspace a controlled stop must end (mm); the firmware's
/// own default (`StopSettings::workspace_margin_mm`) is the same 0.1 mm.
pub const STOP_MARGIN_MM: f64 = 0.1;

/// The home position (mm): the workspace's centre, where the nominal five-bar is a square.
pub const HOME_MM: [f64; 2] = [212.132, 0.0];

/// The nominal hidden robot.
pub fn nominal<T: Real>() -> FiveBar<T> {
    FiveBar::paper_nominal()
}

/// The design's dynamics: the drives' 2e-3 kg·m² at each joint with the linkage lumped into
/// the hidden robot (1.89e-3 kg·m² per lever side, 0.165 kg at the tool, −2.43e-4 kg·m² per
/// distal body: aluminium bars of 120 and 40 mm², 30 g elbow pieces, 100 g platform with its
/// tool; host-sim's `paper` plant computes the same numbers from its bodies), 0.02 N·m·s/rad
/// viscous and 0.05 N·m Coulomb friction per drive. What an identification of this machine
/// should find, and what the plausibility of an image's dynamics is judged against.
pub fn nominal_dynamics<T: Real>() -> FiveBarDynamics<T> {
    let f = T::from_f64;
    FiveBarDynamics {
        motor_inertia_kg_m2: [f(3.89e-3); 2],
        tool_mass_kg: f(0.165),
        distal_inertia_kg_m2: [f(-2.43e-4); 2],
        viscous_nm_s_per_rad: [f(0.02); 2],
        coulomb_nm: [f(0.05); 2],
        coulomb_speed_rad_s: f(0.01),
    }
}

/// The correction grid's lattice (f32, as stored in the flash image).
pub fn grid_geometry() -> GridGeometry {
    GridGeometry {
        nx: GRID_NODES[0],
        ny: GRID_NODES[1],
        x0_mm: WORKSPACE_X_MM[0] as f32,
        y0_mm: WORKSPACE_Y_MM[0] as f32,
        step_x_mm: GRID_STEP_MM as f32,
        step_y_mm: GRID_STEP_MM as f32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lattice_spans_the_workspace_exactly() {
        let g = grid_geometry();
        assert_eq!([g.nx, g.ny], GRID_NODES);
        // The f32 origin is the one a literal 162.132f32 gives (what the firmware's build used).
        assert_eq!(g.x0_mm, 162.132f32);
        for (k, n) in GRID_NODES.iter().enumerate() {
            let span = [WORKSPACE_X_MM, WORKSPACE_Y_MM][k];
            assert_eq!(span[0] + GRID_STEP_MM * f64::from(n - 1), span[1]);
        }
        // The centre is the square pose of the nominal five-bar: C at 150·√2 on the x axis.
        let c = nominal::<f64>()
            .forward(
                [core::f64::consts::FRAC_PI_4, -core::f64::consts::FRAC_PI_4],
                0.0,
            )
            .unwrap();
        assert!(
            (c[0] - 0.5 * (WORKSPACE_X_MM[0] + WORKSPACE_X_MM[1])).abs() < 1e-3
                && c[1].abs() < 1e-9
        );
    }
}
