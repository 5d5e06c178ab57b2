//! The machine the tools work on, described once: nominal hidden robot, workspace, correction
//! grid lattice, instrument, servo rate and limits, and what the controller judges calibration
//! images against ([`ControllerSpec`]).
//!
//! Why one struct: every library function that needs one of these numbers takes a
//! [`MachineSpec`] (in its options struct), so describing another machine is filling this
//! struct (the machine file loads it, `crate::io::machine_file`) and nothing else, and no
//! number is typed twice. [`MachineSpec::paper`] is the paper's machine, from
//! `kinematics_core::paper` (the numbers the firmware's build shares). [`MachineSpec::record`]
//! is the same machine as the controller holds it (`kinematics_core::machine::MachineRecord`):
//! every calibration image carries it.
//!
//! What is *not* here: the simulated plant's physics (`plant::PlantConfig`, the plant TOML:
//! the "real machine" a calibration is tested against, whose errors the tools must not know) and
//! each tool's own settings (options structs).

pub use crate::gantry_spec::GantrySpec;
use kinematics_core::grid::{GridGeometry, WorkspaceLimits};
use kinematics_core::machine::record::{
    DEFAULT_DYNAMICS_FACTOR, DEFAULT_MAX_BACKLASH_RAD, DEFAULT_MAX_CORRECTION_SLOPE,
    DEFAULT_MAX_NODE_CORRECTION_MM, DEFAULT_SAME_MACHINE_TOLERANCE_MM,
};
use kinematics_core::machine::{MachineName, MachineRecord, PlausibilityLimits, RecordError};
use kinematics_core::{
    paper, Branch, ConvexWorkspace, FiveBar, FiveBarDynamics, DEFAULT_MIN_TRANSMISSION,
};
use serde::{Deserialize, Serialize};

pub mod ranges;

/// Standard gravity (mm/s²), for accelerations stated in g.
pub const STANDARD_GRAVITY_MM_S2: f64 = 9_806.65;

/// Which solution a five-bar's arm or assembly is in (`kinematics_core::Branch`), as the
/// machine file and the plant TOML have it: `positive`, `negative`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum BranchKey {
    Positive,
    Negative,
}

impl From<BranchKey> for Branch {
    fn from(b: BranchKey) -> Branch {
        match b {
            BranchKey::Positive => Branch::Positive,
            BranchKey::Negative => Branch::Negative,
        }
    }
}

impl From<Branch> for BranchKey {
    fn from(b: Branch) -> BranchKey {
        match b {
            Branch::Positive => BranchKey::Positive,
            Branch::Negative => BranchKey::Negative,
        }
    }
}

/// How every motor arrives at a measured or commanded pose (the machine's approach policy).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Approach {
    /// From the visit's start (`from_mm`, `approach_mm` away along a random direction for
    /// random targets): the directions a real motion gives (`random` in files and reports).
    #[serde(rename = "random")]
    FromVisit,
    /// Every motor moving in the positive direction, as after an overshoot-and-return move:
    /// backlash always sits on the same side (unidirectional positioning).
    Positive,
}

impl Approach {
    /// The name in files, flags and reports: `random` or `positive`.
    pub fn name(self) -> &'static str {
        match self {
            Approach::FromVisit => "random",
            Approach::Positive => "positive",
        }
    }
}

/// Where the machine works (mm, machine frame): a convex polygon (a rectangle is one), its
/// bounding rectangle, and the soft limit of the controlled stop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workspace {
    /// The bounding rectangle's x range.
    pub x_mm: [f64; 2],
    /// The bounding rectangle's y range.
    pub y_mm: [f64; 2],
    /// The polygon, counter-clockwise (a rectangle's 4 corners when given as a rectangle).
    pub region: ConvexWorkspace<f64>,
    /// Given as a rectangle: then the polygon is exactly the bounding rectangle.
    pub is_rectangle: bool,
    /// How far inside the polygon a controlled stop must end (mm): the soft limit the firmware
    /// reads from the image's workspace block.
    pub stop_margin_mm: f64,
}

impl Workspace {
    /// The rectangle `[x0, x1] × [y0, y1]`.
    pub fn rectangle(x_mm: [f64; 2], y_mm: [f64; 2], stop_margin_mm: f64) -> Result<Self, String> {
        let region = ConvexWorkspace::rectangle(x_mm, y_mm)
            .map_err(|e| format!("workspace rectangle: {e}"))?;
        Ok(Workspace {
            x_mm,
            y_mm,
            region,
            is_rectangle: true,
            stop_margin_mm,
        })
    }

    /// A convex polygon, vertices counter-clockwise.
    pub fn polygon(vertices_mm: &[[f64; 2]], stop_margin_mm: f64) -> Result<Self, String> {
        let region =
            ConvexWorkspace::new(vertices_mm).map_err(|e| format!("workspace polygon: {e}"))?;
        let (x_mm, y_mm) = region.bounds_mm();
        Ok(Workspace {
            x_mm,
            y_mm,
            region,
            is_rectangle: false,
            stop_margin_mm,
        })
    }

    /// The centre (mm): the rectangle's centre, or the polygon's centroid (area-weighted).
    pub fn centre_mm(&self) -> [f64; 2] {
        if self.is_rectangle {
            return [
                0.5 * (self.x_mm[0] + self.x_mm[1]),
                0.5 * (self.y_mm[0] + self.y_mm[1]),
            ];
        }
        let v = self.region.vertices_mm();
        let (mut a, mut cx, mut cy) = (0.0, 0.0, 0.0);
        for (k, p) in v.iter().enumerate() {
            let q = v[(k + 1) % v.len()];
            let cross = p[0] * q[1] - q[0] * p[1];
            a += cross;
            cx += (p[0] + q[0]) * cross;
            cy += (p[1] + q[1]) * cross;
        }
        [cx / (3.0 * a), cy / (3.0 * a)]
    }

    /// Half the bounding rectangle's extent along x and y (mm).
    pub fn half_mm(&self) -> [f64; 2] {
        [
            0.5 * (self.x_mm[1] - self.x_mm[0]),
            0.5 * (self.y_mm[1] - self.y_mm[0]),
        ]
    }

    /// Whether `p_mm` is inside (edges included, to `tolerance_mm`).
    pub fn contains(&self, p_mm: [f64; 2], tolerance_mm: f64) -> bool {
        self.region.contains(p_mm, -tolerance_mm)
    }

    /// The chord of the polygon along `axis` (0: x, 1: y) at the other coordinate `at_mm`:
    /// `[lo, hi]`, or `None` if the line misses the polygon. A rectangle's chord is its edges,
    /// exactly.
    pub fn chord_mm(&self, axis: usize, at_mm: f64) -> Option<[f64; 2]> {
        let other = 1 - axis;
        let span = [self.x_mm, self.y_mm];
        if !(at_mm >= span[other][0] && at_mm <= span[other][1]) {
            return None;
        }
        if self.is_rectangle {
            return Some(span[axis]);
        }
        let v = self.region.vertices_mm();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (k, p) in v.iter().enumerate() {
            let q = v[(k + 1) % v.len()];
            let (a, b) = (p[other] - at_mm, q[other] - at_mm);
            if a == 0.0 {
                lo = lo.min(p[axis]);
                hi = hi.max(p[axis]);
            }
            if a * b < 0.0 {
                let t = a / (a - b);
                let x = p[axis] + t * (q[axis] - p[axis]);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
        (lo <= hi).then_some([lo, hi])
    }

    /// `p_mm` if it lies inside with `margin_mm` to spare, else the point nearest to it on the
    /// segment from the centre where it does (bisection, to 1e-12 of the segment): how a
    /// protocol or a test motion defined on the bounding rectangle is brought into a polygon.
    pub fn pulled_inside(&self, p_mm: [f64; 2], margin_mm: f64) -> [f64; 2] {
        if self.region.contains(p_mm, margin_mm) {
            return p_mm;
        }
        let c = self.centre_mm();
        let at = |s: f64| [c[0] + s * (p_mm[0] - c[0]), c[1] + s * (p_mm[1] - c[1])];
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if self.region.contains(at(mid), margin_mm) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        at(lo)
    }

    /// What the firmware reads: the polygon in f32 and the stop margin.
    pub fn limits(&self) -> Result<WorkspaceLimits, String> {
        let region = self
            .region
            .cast::<f32>()
            .map_err(|e| format!("the workspace in f32: {e}"))?;
        Ok(WorkspaceLimits {
            region,
            stop_margin_mm: self.stop_margin_mm as f32,
        })
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
        [
            self.x0_mm + i as f64 * self.step_mm,
            self.y0_mm + j as f64 * self.step_mm,
        ]
    }

    /// The far corner, node (nx − 1, ny − 1).
    pub fn far_corner_mm(&self) -> [f64; 2] {
        self.node_mm(self.nx.saturating_sub(1), self.ny.saturating_sub(1))
    }

    /// As the flash image stores it (f32).
    pub fn geometry(&self) -> GridGeometry {
        GridGeometry {
            nx: self.nx.min(usize::from(u16::MAX)) as u16,
            ny: self.ny.min(usize::from(u16::MAX)) as u16,
            x0_mm: self.x0_mm as f32,
            y0_mm: self.y0_mm as f32,
            step_x_mm: self.step_mm as f32,
            step_y_mm: self.step_mm as f32,
        }
    }
}

/// What the controller knows of the machine beyond its geometry (the machine file's
/// `[controller]` and `[nominal_dynamics]`, both optional): where homing ends, and what a
/// calibration image is judged against (`kinematics_core::machine::PlausibilityLimits`, whose
/// doc derives each default).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerSpec {
    /// Where homing ends (mm), inside the workspace. Default: the workspace's centre.
    pub home_mm: [f64; 2],
    /// Largest tool-position difference of an image's model from the nominal over the
    /// workspace, in the best-fitting rigid frame (mm).
    pub same_machine_tolerance_mm: f64,
    /// Largest tool displacement of a grid node's correction (mm).
    pub max_node_correction_mm: f64,
    /// Largest change of that displacement between neighbouring nodes, per mm between them.
    pub max_correction_slope: f64,
    /// Largest lost motion per drive (µrad).
    pub max_backlash_urad: f64,
    /// How far (a factor either way) an image's dynamics may be from `nominal_dynamics`.
    pub dynamics_factor: f64,
    /// The design's dynamics.
    pub nominal_dynamics: FiveBarDynamics<f64>,
}

impl ControllerSpec {
    /// The defaults for a machine whose workspace centre is `home_mm` and whose design's
    /// dynamics are `nominal_dynamics`.
    pub fn defaults(home_mm: [f64; 2], nominal_dynamics: FiveBarDynamics<f64>) -> Self {
        ControllerSpec {
            home_mm,
            same_machine_tolerance_mm: f64::from(DEFAULT_SAME_MACHINE_TOLERANCE_MM),
            max_node_correction_mm: f64::from(DEFAULT_MAX_NODE_CORRECTION_MM),
            max_correction_slope: f64::from(DEFAULT_MAX_CORRECTION_SLOPE),
            max_backlash_urad: (f64::from(DEFAULT_MAX_BACKLASH_RAD) * 1e6).round(),
            dynamics_factor: f64::from(DEFAULT_DYNAMICS_FACTOR),
            nominal_dynamics,
        }
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
    /// How the machine approaches a pose it positions to (plan lists, the demo's default).
    pub approach: Approach,
    /// Distance (mm) from which a measured pose is approached (and the overtravel of a pass).
    pub approach_mm: f64,
    /// The acceleration the machine is built for (g): the point-to-point test motion's, and the
    /// threshold of the closed loop's "at full acceleration" statistics.
    pub max_acceleration_g: f64,
    /// Home position and the limits a calibration image is judged against.
    pub controller: ControllerSpec,
    /// The gantry that carries the micro on a redundant machine (`[gantry]`, optional in the
    /// machine file; `host-sim cut`).
    pub gantry: GantrySpec,
}

impl MachineSpec {
    /// The paper's machine (`kinematics_core::paper`), with a 1 µm calibration instrument;
    /// `host-sim/machines/paper.toml` describes the same machine (a test checks).
    pub fn paper() -> Self {
        MachineSpec {
            name: "paper".into(),
            nominal: paper::nominal(),
            workspace: Workspace::rectangle(
                paper::WORKSPACE_X_MM,
                paper::WORKSPACE_Y_MM,
                paper::STOP_MARGIN_MM,
            )
            .expect("the paper workspace is a rectangle"),
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
            approach: Approach::Positive,
            approach_mm: 5.0,
            max_acceleration_g: 5.0,
            controller: ControllerSpec::defaults(paper::HOME_MM, paper::nominal_dynamics()),
            gantry: GantrySpec::paper(),
        }
    }

    /// The machine record the controller holds and every image carries (`HRMC`): this
    /// description in f32. Refused, naming the machine file's key: a name that is not 1..=16
    /// printable ASCII characters, a limit out of its range, a home outside the workspace.
    pub fn record(&self) -> Result<MachineRecord, String> {
        let c = &self.controller;
        let name = MachineName::new(&self.name).map_err(|_| {
            format!(
                "'name' = {:?}: the controller stores 1..=16 printable ASCII characters",
                self.name
            )
        })?;
        let d = c.nominal_dynamics.cast::<f32>();
        let record = MachineRecord {
            name,
            nominal: self.nominal.cast::<f32>(),
            encoder_sign: [1, 1],
            workspace: self.workspace.limits()?,
            home_mm: c.home_mm.map(|v| v as f32),
            limits: PlausibilityLimits {
                same_machine_tolerance_mm: c.same_machine_tolerance_mm as f32,
                max_node_correction_mm: c.max_node_correction_mm as f32,
                max_correction_slope: c.max_correction_slope as f32,
                max_backlash_rad: (c.max_backlash_urad * 1e-6) as f32,
                dynamics_factor: c.dynamics_factor as f32,
                nominal_dynamics: d,
            },
        };
        record.validate().map_err(|e| match e {
            RecordError::Home => format!(
                "'controller.home_mm' = {:?} lies outside the workspace",
                c.home_mm
            ),
            RecordError::Limit(name) => {
                let (lo, hi) = kinematics_core::machine::record::LIMIT_RANGES
                    .iter()
                    .find(|r| r.0 == name)
                    .map_or((0.0, 0.0), |r| (f64::from(r.1), f64::from(r.2)));
                match name {
                    "max_backlash_rad" => format!(
                        "'controller.max_backlash_urad' = {} must be in ({}, {}] µrad",
                        c.max_backlash_urad,
                        lo * 1e6,
                        (hi * 1e6).round()
                    ),
                    _ => format!("'controller.{name}' must be in ({lo}, {hi}]"),
                }
            }
            RecordError::Dynamics => "'nominal_dynamics': the motor inertias, the friction and the Coulomb speed must be positive, the tool mass non-negative, every value finite (in f32)".into(),
            other => format!("machine '{}': {other}", self.name),
        })?;
        Ok(record)
    }

    /// The grid nodes, x fastest (the order of the `grid` protocol and of the flash image).
    pub fn grid_nodes_mm(&self) -> Vec<[f64; 2]> {
        let g = &self.grid;
        (0..g.ny)
            .flat_map(|j| (0..g.nx).map(move |i| g.node_mm(i, j)))
            .collect()
    }

    /// Checks that the description is a machine the tools can work on; the message names the
    /// quantity (the machine file's key where there is one). Every number finite and in range;
    /// the nominal model valid; the grid (2..=1024 nodes per axis) covers the workspace; every
    /// grid node, and every point of the workspace on a lattice twice as fine, is reachable by
    /// the nominal model in its working mode with the singularity margin (the `grid` protocol
    /// measures every node; targets anywhere in the workspace are commanded).
    pub fn validate(&self) -> Result<(), String> {
        let m = &self.nominal;
        m.validate().map_err(|e| format!("nominal model: {e}"))?;
        let positive = [
            ("instrument.sigma_um", self.instrument_sigma_um, true),
            ("servo.sample_period_s", self.sample_period_s, false),
            ("approach.distance_mm", self.approach_mm, false),
            ("servo.max_acceleration_g", self.max_acceleration_g, false),
            ("grid.step_mm", self.grid.step_mm, false),
            (
                "workspace.stop_margin_mm",
                self.workspace.stop_margin_mm,
                true,
            ),
        ];
        for (key, v, zero_ok) in positive {
            let ok = v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0));
            if !ok {
                return Err(format!(
                    "'{key}' must be {}, not {v}",
                    if zero_ok {
                        "a non-negative number"
                    } else {
                        "positive"
                    }
                ));
            }
        }
        if !(self.min_transmission > 0.0 && self.min_transmission < 1.0) {
            return Err(format!(
                "'servo.min_transmission' must be in (0, 1), not {}",
                self.min_transmission
            ));
        }
        // Every number against its physical meaning (approach against the workspace, a stop
        // margin that leaves a workspace, an instrument's σ, ...).
        ranges::check(self)?;
        let g = &self.grid;
        let max = usize::from(kinematics_core::grid::MAX_NODES_PER_AXIS);
        if !(2..=max).contains(&g.nx) || !(2..=max).contains(&g.ny) {
            return Err(format!(
                "the grid has {} x {} nodes; 2..={max} per axis",
                g.nx, g.ny
            ));
        }
        if !(g.x0_mm.is_finite() && g.y0_mm.is_finite()) {
            return Err("the grid's origin is not finite".into());
        }
        let far = g.far_corner_mm();
        let tol = 1e-9 * (1.0 + far[0].abs().max(far[1].abs()));
        let ws = &self.workspace;
        for v in ws.region.vertices_mm() {
            if v[0] < g.x0_mm - tol
                || v[0] > far[0] + tol
                || v[1] < g.y0_mm - tol
                || v[1] > far[1] + tol
            {
                return Err(format!(
                    "workspace vertex ({}, {}) mm lies outside the grid's rectangle x [{}, {}], y [{}, {}] mm: the grid must cover the workspace",
                    v[0], v[1], g.x0_mm, far[0], g.y0_mm, far[1]
                ));
            }
        }
        let reach = |p: [f64; 2], what: &str| {
            m.inverse(p, self.min_transmission)
                .map(|_| ())
                .map_err(|e| format!("{what} ({:.3}, {:.3}) mm is not reachable by the nominal model with the singularity margin {}: {e}", p[0], p[1], self.min_transmission))
        };
        for p in self.grid_nodes_mm() {
            reach(p, "grid node")?;
        }
        let half = g.step_mm / 2.0;
        for j in 0..2 * g.ny - 1 {
            for i in 0..2 * g.nx - 1 {
                let p = [g.x0_mm + i as f64 * half, g.y0_mm + j as f64 * half];
                if ws.contains(p, 0.0) {
                    reach(p, "workspace point")?;
                }
            }
        }
        ws.limits()?;
        self.record()?;
        self.gantry.validate()?;
        Ok(())
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
        assert_eq!(
            s.grid.node_mm(s.grid.nx - 1, s.grid.ny - 1),
            [s.workspace.x_mm[1], s.workspace.y_mm[1]]
        );
        let nodes = s.grid_nodes_mm();
        assert_eq!(
            (nodes.len(), nodes[1], nodes[21]),
            (651, [167.132, -75.0], [162.132, -70.0])
        );
        assert_eq!(s.validate(), Ok(()));
        assert_eq!(s.workspace.chord_mm(0, 0.0), Some([162.132, 262.132]));
        assert!(
            s.workspace.contains([162.132, 75.0], 0.0)
                && !s.workspace.contains([212.132, -200.0], 0.0)
        );
        assert!(!s.workspace.contains([50.0, 0.0], 0.0));
    }

    #[test]
    fn a_polygon_workspace_centroid_and_chords() {
        // A triangle: centroid at the vertices' mean; chords by intersection.
        let w = Workspace::polygon(&[[0.0, 0.0], [30.0, 0.0], [0.0, 30.0]], 0.0).unwrap();
        let c = w.centre_mm();
        assert!(
            (c[0] - 10.0).abs() < 1e-12 && (c[1] - 10.0).abs() < 1e-12,
            "{c:?}"
        );
        assert_eq!(w.chord_mm(0, 10.0), Some([0.0, 20.0]));
        assert_eq!(w.chord_mm(1, 0.0), Some([0.0, 30.0]));
        assert_eq!(w.chord_mm(0, 31.0), None);
        assert_eq!((w.x_mm, w.y_mm), ([0.0, 30.0], [0.0, 30.0]));
        assert!(
            Workspace::polygon(&[[0.0, 0.0], [0.0, 30.0], [30.0, 0.0]], 0.0).is_err(),
            "clockwise"
        );
    }

    #[test]
    fn validation_names_what_is_wrong() {
        let mut s = MachineSpec::paper();
        s.grid.nx = 20;
        assert!(
            s.validate()
                .unwrap_err()
                .contains("outside the grid's rectangle"),
            "{:?}",
            s.validate()
        );
        let mut s = MachineSpec::paper();
        s.nominal.a_mm = 50.0;
        assert!(
            s.validate().unwrap_err().contains("not reachable"),
            "{:?}",
            s.validate()
        );
        let mut s = MachineSpec::paper();
        s.instrument_sigma_um = f64::NAN;
        assert!(s.validate().unwrap_err().contains("instrument.sigma_um"));
        let mut s = MachineSpec::paper();
        s.min_transmission = 1.5;
        assert!(s.validate().unwrap_err().contains("min_transmission"));
    }
}
