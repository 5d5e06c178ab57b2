//! The machine the tools work on, described once: nominal hidden robot, workspace, correction
//! grid lattice, instrument, servo rate and limits.
//!
//! Why: these numbers used to be typed where they were needed (the workspace's x origin
//! `162.132` in ten files, the sample period and the singularity margin twice); a second
//! machine would have meant finding them all. Every library function that needs one of them
//! takes a [`MachineSpec`] (in its options struct), so describing another machine is filling
//! this struct (issue 12: a machine file loads it) and nothing else. [`MachineSpec::paper`] is
//! the paper's machine, from `kinematics_core::paper` (the numbers the firmware's build shares).
//!
//! What is *not* here: the simulated plant's physics (`plant::PlantConfig`, the plant TOML:
//! the "real machine" a calibration is tested against, whose errors the tools must not know) and
//! each tool's own settings (options structs).

use kinematics_core::{paper, FiveBar, DEFAULT_MIN_TRANSMISSION};

/// Standard gravity (mm/s²), for accelerations stated in g.
pub const STANDARD_GRAVITY_MM_S2: f64 = 9_806.65;

/// The rectangle targets are drawn from (mm, machine frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workspace {
    pub x_mm: [f64; 2],
    pub y_mm: [f64; 2],
}

impl Workspace {
    /// The centre (mm).
    pub fn centre_mm(&self) -> [f64; 2] {
        [0.5 * (self.x_mm[0] + self.x_mm[1]), 0.5 * (self.y_mm[0] + self.y_mm[1])]
    }

    /// Half the extent along x and y (mm).
    pub fn half_mm(&self) -> [f64; 2] {
        [0.5 * (self.x_mm[1] - self.x_mm[0]), 0.5 * (self.y_mm[1] - self.y_mm[0])]
    }
}

/// A rectangular lattice of grid nodes (mm): node (i, j) at `(x0 + i·step, y0 + j·step)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridLattice {
    pub x0_mm: f64,
    pub y0_mm: f64,
    pub step_mm: f64,
    pub nx: usize,
    pub ny: usize,
}

impl GridLattice {
    /// Position of node (i, j).
    pub fn node_mm(&self, i: usize, j: usize) -> [f64; 2] {
        [self.x0_mm + i as f64 * self.step_mm, self.y0_mm + j as f64 * self.step_mm]
    }
}

/// One machine's description (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct MachineSpec {
    /// Short name, for reports.
    pub name: String,
    /// The nominal hidden robot: what commands are computed with before any calibration.
    pub nominal: FiveBar<f64>,
    pub workspace: Workspace,
    /// The correction grid's nodes (measured by the `grid` protocol, stored in the flash image).
    pub grid: GridLattice,
    /// The calibration instrument's noise, σ per axis (µm): the demo's premise.
    pub instrument_sigma_um: f64,
    /// Servo sample period (s).
    pub sample_period_s: f64,
    /// Smallest |sin| of a transmission angle a command may have (the singularity margin).
    pub min_transmission: f64,
    /// Distance (mm) from which a measured pose is approached (and the overtravel of a pass).
    pub approach_mm: f64,
    /// The acceleration the machine is built for (g): the point-to-point test motion's, and the
    /// threshold of the closed loop's "at full acceleration" statistics.
    pub max_acceleration_g: f64,
}

impl MachineSpec {
    /// The paper's machine (`kinematics_core::paper`), with a 1 µm calibration instrument.
    pub fn paper() -> Self {
        MachineSpec {
            name: "paper".into(),
            nominal: paper::nominal(),
            workspace: Workspace { x_mm: paper::WORKSPACE_X_MM, y_mm: paper::WORKSPACE_Y_MM },
            grid: GridLattice {
                x0_mm: paper::WORKSPACE_X_MM[0],
                y0_mm: paper::WORKSPACE_Y_MM[0],
                step_mm: paper::GRID_STEP_MM,
                nx: usize::from(paper::GRID_NODES[0]),
                ny: usize::from(paper::GRID_NODES[1]),
            },
            instrument_sigma_um: 1.0,
            sample_period_s: paper::SAMPLE_PERIOD_S,
            min_transmission: DEFAULT_MIN_TRANSMISSION,
            approach_mm: 5.0,
            max_acceleration_g: 5.0,
        }
    }

    /// The grid nodes, x fastest (the order of the `grid` protocol and of the flash image).
    pub fn grid_nodes_mm(&self) -> Vec<[f64; 2]> {
        let g = &self.grid;
        (0..g.ny).flat_map(|j| (0..g.nx).map(move |i| g.node_mm(i, j))).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_machine() {
        let s = MachineSpec::paper();
        // The centre and the lattice's far corner are exactly the paper's printed numbers.
        assert_eq!(s.workspace.centre_mm(), [212.132, 0.0]);
        assert_eq!(s.grid.node_mm(s.grid.nx - 1, s.grid.ny - 1), [s.workspace.x_mm[1], s.workspace.y_mm[1]]);
        let nodes = s.grid_nodes_mm();
        assert_eq!((nodes.len(), nodes[1], nodes[21]), (651, [167.132, -75.0], [162.132, -70.0]));
    }
}
