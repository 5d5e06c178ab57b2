//! The redundant machine cuts a part program: the gantry carries the micro across the sheet,
//! the micro takes the fast, small motions (`host-sim cut`, docs/guides/cut-a-part.md; the
//! design and the bound's derivation: docs/design/redundant-planner.md).
//!
//! | file | job |
//! |---|---|
//! | [`gcode`] | RS274 part programs in: moves, dwells, beam switches; errors name line and word |
//! | [`parts`] | example part programs, the 1000-contour nest, random programs (tests, bench) |
//! | [`path`] | the path's geometry: lines and arcs, tangents, curvature, distance to them |
//! | [`profile`] | the jerk-limited time law along a span of segments (rest to rest) |
//! | [`limits`] | a machine's limits along the path: segment caps, junction caps |
//! | [`timeline`] | the program's spans and rests in time, the tool at any instant |
//! | [`micro`] | the micro's limits from its model (workspace less margin, joints, torques) |
//! | [`split`] | the split planner: tool timed, gantry filtered, micro checked; the fallback |
//! | [`bound`] | the lower bound no plan can beat |
//! | [`execute`] | both stages executed on one time base, with dual-stage compensation |
//! | [`report`] | the figures from the executed motion, CSV |
//! | [`plots`] | the part and the stages' motion as PNG |
//!
//! The gantry's axes in simulation (drives, following error) are the plant's:
//! [`crate::plant::gantry`].
//!
//! Layers: `gcode` → `path`/`profile`/`limits` → `timeline` → `split`/`bound` → `execute` →
//! `report`/`plots`; this file wires them ([`run`]).

pub mod bound;
pub mod execute;
pub mod gcode;
pub mod limits;
pub mod micro;
pub mod parts;
pub mod path;
pub mod plots;
pub mod profile;
pub mod report;
pub mod split;
pub mod timeline;

use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use crate::plant::{PlantConfig, PlantError};
use bound::{Bound, BoundLimits};
use execute::{Executed, HostLoop, MicroStage};
use gcode::{parse_program, Program, ProgramError};
use kinematics_core::{Calibration, FiveBarDynamics};
use limits::PathLimits;
use micro::MicroLimits;
use split::{AxisLimits, Plan, SplitOptions};
use std::time::Instant;
use timeline::Layout;

/// Share of the gantry's acceleration limit a plan uses (the executed motion overshoots its
/// reference a little: the check is on the executed motion).
pub const GANTRY_HEADROOM: f64 = 0.9;
/// Share of the gantry's jerk limit a plan uses (its drives' response adds about 12 % at the
/// jerk's corners, as measured over the jerk window).
pub const GANTRY_JERK_HEADROOM: f64 = 0.75;
/// Share of the gantry's speed a plan uses.
pub const SPEED_HEADROOM: f64 = 0.98;
/// Share of the micro's acceleration and speed a plan uses (the compensation and the servo's
/// response come on top).
pub const MICRO_HEADROOM: f64 = 0.85;
/// The tool's tangential jerk in the split (mm/s³): 5 g in 1 ms. The micro has no jerk limit;
/// this keeps its setpoints smooth for the feed-forward.
pub const TOOL_JERK_MM_S3: f64 = 3.0e7;
/// Share of one sample's acceleration a junction's velocity jump may be.
pub const KINK_SHARE: f64 = 0.05;

/// Why a program cannot be cut.
#[derive(Debug, thiserror::Error)]
pub enum CutError {
    #[error(transparent)]
    Program(#[from] ProgramError),
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// Settings that make no machine (the message names them).
    #[error("{0}")]
    Invalid(String),
    /// The execution faulted (the message says when and why).
    #[error("execution: {0}")]
    Execution(String),
}

/// The limits every part of the planning uses, from the machine.
#[derive(Clone, Debug)]
pub struct MachineLimits {
    pub split: SplitOptions,
    pub bound: BoundLimits,
}

impl MachineLimits {
    /// From the machine and the micro's derived limits.
    pub fn new(spec: &MachineSpec, micro: MicroLimits) -> MachineLimits {
        let g = &spec.gantry;
        let dt = spec.sample_period_s;
        let ga = g.accel_g * STANDARD_GRAVITY_MM_S2;
        let gantry = AxisLimits {
            speed_mm_s: g.speed_mm_s * SPEED_HEADROOM,
            accel_mm_s2: ga * GANTRY_HEADROOM,
            jerk_mm_s3: g.jerk_mm_s3 * GANTRY_JERK_HEADROOM,
        };
        let micro_accel = micro.accel_mm_s2 * MICRO_HEADROOM;
        let tool = PathLimits {
            axis_speed_mm_s: gantry.speed_mm_s,
            accel_mm_s2: micro_accel,
            jerk_mm_s3: TOOL_JERK_MM_S3,
            per_axis: false,
            curvature_jerk: false,
            kink_dv_mm_s: KINK_SHARE * micro_accel * dt,
        };
        let gantry_only = PathLimits {
            axis_speed_mm_s: gantry.speed_mm_s,
            accel_mm_s2: gantry.accel_mm_s2,
            jerk_mm_s3: gantry.jerk_mm_s3,
            per_axis: true,
            curvature_jerk: true,
            kink_dv_mm_s: (KINK_SHARE * gantry.accel_mm_s2 * dt)
                .min(gantry.jerk_mm_s3 * limits::JERK_WINDOW_S * dt),
        };
        let bound = BoundLimits {
            axis_speed_mm_s: g.speed_mm_s,
            micro_accel_mm_s2: micro.accel_mm_s2,
            gantry_accel_mm_s2: ga,
            micro_width_mm: micro.width_mm,
            sample_period_s: dt,
        };
        MachineLimits {
            split: SplitOptions {
                dt_s: dt,
                tool,
                gantry_only,
                gantry,
                micro_speed_mm_s: micro.speed_mm_s * MICRO_HEADROOM,
                micro_accel_mm_s2: micro_accel,
                micro,
            },
            bound,
        }
    }
}

/// A program planned: the split (or the fallback), the baseline's time, the bound.
#[derive(Clone, Debug)]
pub struct Planned {
    pub program: Program,
    pub layout: Layout,
    pub plan: Plan,
    pub gantry_only_s: f64,
    pub bound: Bound,
    /// Wall time of the planning (s).
    pub planner_s: f64,
}

/// Reads and plans a program on `spec`'s machine with the micro `plant` builds.
pub fn plan_program(
    text: &str,
    spec: &MachineSpec,
    plant: &PlantConfig,
) -> Result<(Planned, MachineLimits), CutError> {
    let program = parse_program(text, &spec.gantry)?;
    let wall = Instant::now();
    let micro = MicroLimits::derive(spec, plant)?;
    let limits = MachineLimits::new(spec, micro);
    let layout = Layout::new(&program);
    let baseline = timeline::Timeline::new(
        &layout,
        timeline::laws(&layout, &limits.split.gantry_only, None),
    );
    let gantry_only_s = baseline.duration_s();
    let plan = split::plan(&layout, &limits.split, gantry_only_s);
    let bound = limits.bound.bound(&layout);
    Ok((
        Planned {
            program,
            layout,
            plan,
            gantry_only_s,
            bound,
            planner_s: wall.elapsed().as_secs_f64(),
        },
        limits,
    ))
}

/// What [`run`] needs besides the program.
pub struct CutOptions<'a> {
    pub spec: MachineSpec,
    /// The micro's plant.
    pub plant: PlantConfig,
    /// What the micro's servo commands with (model, grid).
    pub calibration: Calibration<'a>,
    /// What it feeds forward (default: the plant's own, as an identification finds them).
    pub dynamics: Option<FiveBarDynamics<f64>>,
    /// A name for the program in reports.
    pub program_name: String,
}

/// A program cut: the plan, the executed motion, the figures.
pub struct CutRun {
    pub planned: Planned,
    pub limits: MachineLimits,
    pub executed: Vec<Executed>,
    pub report: report::CutReport,
}

/// Plans `text` and executes it with the host loop (see the module doc).
pub fn run(text: &str, opts: &CutOptions<'_>) -> Result<CutRun, CutError> {
    crate::calib::machine::check_plant_fits(&opts.plant, &opts.spec)
        .map_err(|e| CutError::Invalid(e.to_string()))?;
    let (planned, limits) = plan_program(text, &opts.spec, &opts.plant)?;
    let dynamics = match opts.dynamics {
        Some(d) => d,
        None => crate::plant::Plant::new(&opts.plant, 1).true_dynamics(),
    };
    let mut stage = HostLoop::new(&opts.plant, opts.calibration, &opts.spec, &dynamics)?;
    let wall = Instant::now();
    let executed = execute::execute(
        &planned.layout,
        &planned.plan,
        &opts.spec.gantry,
        &mut stage,
        limits.split.micro.centre_mm,
    )?;
    let execution_s = wall.elapsed().as_secs_f64();
    let report = report::report(&report::ReportInputs {
        name: &opts.program_name,
        spec: &opts.spec,
        planned: &planned,
        limits: &limits,
        executed: &executed,
        stage: &stage.describe(),
        execution_s,
    });
    Ok(CutRun {
        planned,
        limits,
        executed,
        report,
    })
}
