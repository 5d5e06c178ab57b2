//! `host-sim grid`: the correction-grid flash image and its node table from measurements at the
//! nodes (`host_sim::calib::grid`), with a JSON summary; or, with `--nominal`, the machine's
//! commissioning image. Either image ends with the machine record and is judged as the
//! controller will judge it before anything is written.

use anyhow::{bail, Context, Result};
use host_sim::calib::grid::{build_with, format_csv, GridOptions, NoiseReport, Smoothing};
use host_sim::calib::image::{
    append_backlash_block, append_dynamics_block, commissioning_image, finish_image, seal_image,
    CheckedImage, WorkspaceBlock,
};
use host_sim::io::dynamics_file::read_dynamics_file;
use host_sim::io::model_file::read_model_file;
use host_sim::io::plot::{vector_plot_png, VectorField};
use host_sim::io::policy::CommandFiles;
use host_sim::io::KeyOrder;
use kinematics_core::machine::Verdict;
use serde::Serialize;
use std::path::PathBuf;

/// Build the correction-grid image from measurements at the grid nodes.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The fitted model (model.json) the nodes were commanded with; the readings are mapped
    /// into the machine frame by its registered instrument frame. If it carries
    /// `backlash_urad`, the grid is built from link angles (the data need dir1,dir2) and the
    /// image carries the backlash block (the firmware's servo compensates it).
    #[arg(long, required_unless_present = "nominal")]
    pub model: Option<PathBuf>,
    /// Measurements at the nodes; x_target_mm,y_target_mm are the nodes. Several files
    /// (`--data grid1.csv grid2.csv`, e.g. both measurement rounds) are pooled: the readings of
    /// a node are averaged, each referred to the node's own command first, so rounds measured
    /// through different grids pool correctly.
    #[arg(long, required_unless_present = "nominal", num_args = 1..)]
    pub data: Vec<PathBuf>,
    /// Node spacing (mm), the same along x and y (default: the machine's grid step).
    #[arg(long)]
    pub step_mm: Option<f64>,
    /// Output flash image.
    #[arg(long)]
    pub out: PathBuf,
    /// Readable node table (default: the image path with extension .csv).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Optional PNG of the measured node errors.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Identified dynamic parameters (dynamics.json) the image carries for the servo's
    /// feed-forward (the `HRDY` block); without it the image has no dynamics block.
    #[arg(long)]
    pub dynamics: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
    /// How the nodes' errors are smoothed before they become corrections: `gcv` (the default:
    /// the smoothing chosen from the data, with the six-bar's loop closure as a prior by
    /// restricted maximum likelihood, with the generic bases by generalised cross-validation;
    /// repeated readings of a node are averaged), `none` (each node's own error, the paper's
    /// grid), or a number (a fixed smoothing λ in lattice-step units, generic bases).
    #[arg(long, default_value = "gcv")]
    pub smoothing: String,
    /// Smooth with the generic bases only, without the six-bar's loop-closure responses (for a
    /// machine that is not an overconstrained six-bar of the paper's kind, or to compare).
    #[arg(long)]
    pub no_six_bar_prior: bool,
    /// Write the machine's commissioning image instead: the nominal model of --machine, zero
    /// corrections on its grid lattice, its workspace block and its machine record (what a
    /// machine starts with before any calibration). Takes only --machine and --out.
    #[arg(long, conflicts_with_all = ["model", "data", "dynamics", "step_mm", "plot", "csv"])]
    pub nominal: bool,
}

/// The judgement of the image written, in the JSON summaries.
#[derive(Serialize)]
struct Judgement {
    /// The machine it was judged for (its record is the image's last block).
    machine: String,
    /// The machine's digest (CRC-32C of its geometry), 8 hex digits.
    digest: String,
    /// The largest tool-position difference of the image's model from the nominal over the
    /// workspace, in the best-fitting rigid frame (mm).
    same_machine_worst_mm: f64,
    /// That frame: rotation (°) and translation (mm), the instrument's frame as the
    /// calibration saw it.
    frame_rotation_deg: f64,
    frame_translation_mm: [f64; 2],
    /// The largest tool displacement of a node's correction (mm; limit
    /// `controller.max_node_correction_mm`).
    max_correction_mm: f64,
    /// The largest change of it between neighbouring nodes per mm (limit
    /// `controller.max_correction_slope`).
    max_correction_slope: f64,
    /// With dynamics: the smallest and largest kinetic-energy ratio against the nominal
    /// dynamics over the workspace (limit: `controller.dynamics_factor` either way).
    inertia_ratio: Option<[f64; 2]>,
}

impl From<&Verdict> for Judgement {
    fn from(v: &Verdict) -> Self {
        Judgement {
            machine: v.record.name.to_string(),
            digest: format!("{:08x}", v.record.digest()),
            same_machine_worst_mm: f64::from(v.same.worst_mm),
            frame_rotation_deg: f64::from(v.same.frame.rotation_rad()).to_degrees(),
            frame_translation_mm: v.same.frame.translation_mm.map(f64::from),
            max_correction_mm: f64::from(v.margins.correction_mm),
            max_correction_slope: f64::from(v.margins.correction_slope),
            inertia_ratio: v.margins.inertia_ratio.map(|r| r.map(f64::from)),
        }
    }
}

/// `--smoothing` as the library's option.
fn smoothing(s: &str) -> Result<Smoothing> {
    Ok(match s {
        "gcv" => Smoothing::Gcv,
        "none" => Smoothing::None,
        other => match other.parse::<f64>() {
            Ok(l) if l >= 0.0 && l.is_finite() => Smoothing::Fixed(l),
            _ => bail!("--smoothing must be gcv, none or a non-negative number, not '{other}'"),
        },
    })
}

/// What `grid` prints.
#[derive(Serialize)]
struct Summary {
    nx: usize,
    ny: usize,
    x0_mm: f64,
    y0_mm: f64,
    step_mm: f64,
    node_err_max_um: f64,
    node_err_rms_um: f64,
    max_abs_dtheta_urad: f64,
    image: String,
    image_bytes: usize,
    csv: String,
    /// Whether the image carries the machine's workspace block (`written`) or not (a grid
    /// that does not cover the workspace: the firmware then keeps to the grid's rectangle).
    workspace_block: WorkspaceBlock,
    /// Whether the image carries the dynamics block (`--dynamics`).
    dynamics_block: bool,
    /// The noise estimate, the smoothing chosen and the residual expected (grid.rs).
    noise: NoiseReport,
    /// The machine the image is for and how its model compares with the nominal.
    judgement: Judgement,
}

/// What `grid --nominal` prints.
#[derive(Serialize)]
struct CommissioningSummary {
    commissioning: bool,
    image: String,
    image_bytes: usize,
    nx: usize,
    ny: usize,
    judgement: Judgement,
}

/// `host-sim grid --nominal`.
fn run_nominal(
    args: &Args,
    spec: &host_sim::machine_spec::MachineSpec,
    mut outputs: host_sim::io::atomic::Outputs,
) -> Result<()> {
    let CheckedImage {
        bytes: image,
        verdict,
    } = commissioning_image(spec)
        .with_context(|| format!("the commissioning image of machine '{}'", spec.name))?;
    outputs.bytes(&args.out, &image)?;
    outputs.commit()?;
    eprintln!(
        "grid: commissioning image of machine '{}' ({} bytes: nominal model, zero corrections, workspace, machine record {:08x}) written to {}",
        spec.name,
        image.len(),
        verdict.record.digest(),
        args.out.display()
    );
    super::print_json(
        &CommissioningSummary {
            commissioning: true,
            image: args.out.display().to_string(),
            image_bytes: image.len(),
            nx: spec.grid.nx,
            ny: spec.grid.ny,
            judgement: Judgement::from(&verdict),
        },
        KeyOrder::Sorted,
    )
}

/// `host-sim grid`.
pub fn run(args: &Args) -> Result<()> {
    let csv = args
        .csv
        .clone()
        .unwrap_or_else(|| args.out.with_extension("csv"));
    let csv_flag = if args.csv.is_some() {
        "--csv"
    } else {
        "--csv (by default --out with .csv)"
    };
    // Every output staged, then renamed together: a bad --out leaves no node table or plot.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--model", &args.model)
        .repeats("--data", &args.data)
        .input("--dynamics", &args.dynamics)
        .output("--out", &args.out)
        .output(csv_flag, &csv)
        .output("--plot", &args.plot)
        .check()?;
    let spec = args.machine.spec()?;
    if args.nominal {
        return run_nominal(args, &spec, outputs);
    }
    let model_path = args
        .model
        .as_deref()
        .context("--model is required (or --nominal)")?;
    let step_mm = args.step_mm.unwrap_or(spec.grid.step_mm);
    if !(step_mm > 0.0 && step_mm.is_finite()) {
        bail!("--step-mm must be positive, got {step_mm}");
    }
    let smoothing = smoothing(&args.smoothing)?;
    let file = read_model_file(model_path)?;
    args.machine
        .check_model(&spec, "--model", model_path, &file)?;
    let model = file
        .model()
        .map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    // A model with a backlash correction: the grid is built from link angles (calib::backlash),
    // free of the lost motion whatever direction each node was approached from.
    let backlash = file
        .backlash()
        .map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    // The readings into the machine frame, where the model is (the instrument frame the fit
    // registered; none in an older model file).
    let frame = host_sim::calib::frame::InstrumentFrame::of_model_file(&file)
        .map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    let mut data = Vec::new();
    for path in &args.data {
        let rows = frame.register(&super::common_args::read_measurements(
            &args.machine,
            &spec,
            "--data",
            path,
        )?);
        data.extend(match &backlash {
            Some(b) => b
                .link_angles(&rows)
                .with_context(|| format!("{} with the model's backlash", path.display()))?,
            None => rows,
        });
    }
    let sources = args
        .data
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(" + ");
    let built = build_with(
        &model,
        &data,
        &GridOptions {
            step_mm,
            smoothing,
            instrument_sigma_um: Some(spec.instrument_sigma_um),
            six_bar_prior: !args.no_six_bar_prior,
        },
    )
    .with_context(|| format!("in {sources}"))?;
    eprintln!("grid: {}", built.noise.describe());
    let (image, workspace_block) = finish_image(&built.image, &spec)?;
    let image = match &args.dynamics {
        Some(p) => {
            let file = read_dynamics_file(p)?;
            args.machine.check_files(
                &spec,
                &[super::file_machine("--dynamics", p, file.machine.clone())],
            )?;
            let d = file
                .dynamics()
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?;
            append_dynamics_block(&image, &d).with_context(|| format!("with {}", p.display()))?
        }
        None => image,
    };
    // The model's backlash goes into the image too (last in its chain): the firmware's servo
    // compensates it on its reference (kinematics-core/src/backlash.rs).
    let image = match &backlash {
        Some(b) => append_backlash_block(&image, b)
            .with_context(|| format!("with the backlash of {}", model_path.display()))?,
        None => image,
    };
    // Last, the machine record; the finished image judged as the controller will judge it:
    // one it would refuse is not written.
    let CheckedImage {
        bytes: image,
        verdict,
    } = seal_image(&image, &spec)
        .with_context(|| format!("nothing written to {}", args.out.display()))?;
    if workspace_block == WorkspaceBlock::GridDoesNotCoverTheWorkspace {
        eprintln!(
            "grid: the grid does not cover machine '{}''s workspace: the image carries no workspace block (the firmware keeps its stops inside the grid's rectangle)",
            spec.name
        );
    }
    outputs.bytes(&args.out, &image)?;
    outputs.bytes(&csv, format_csv(&built.nodes).as_bytes())?;
    if let Some(plot) = &args.plot {
        let base: Vec<[f64; 2]> = built.nodes.iter().map(|n| n.target_mm).collect();
        let err: Vec<[f64; 2]> = built
            .nodes
            .iter()
            .map(|n| [n.error_mm[0] * 1e3, n.error_mm[1] * 1e3])
            .collect();
        let png = vector_plot_png(
            "grid nodes: measured − target",
            &[VectorField::new("before grid", &base, &err)],
            &[],
        )?;
        outputs.bytes(plot, &png)?;
    }
    outputs.commit()?;
    let stats = built.stats();
    let l = &built.lattice;
    let p = super::um_decimals(spec.instrument_sigma_um);
    eprintln!(
        "grid: {} x {} nodes every {} mm; measured node errors max {:.p$} µm, RMS {:.p$} µm; largest correction {:.1} µrad",
        l.nx, l.ny, l.step_mm, stats.node_err.max, stats.node_err.rms, stats.max_abs_dtheta_urad
    );
    eprintln!(
        "grid: image ({} bytes) -> {}, node table -> {}",
        image.len(),
        args.out.display(),
        csv.display()
    );
    super::print_json(
        &Summary {
            nx: l.nx,
            ny: l.ny,
            x0_mm: l.x0_mm,
            y0_mm: l.y0_mm,
            step_mm: l.step_mm,
            node_err_max_um: stats.node_err.max,
            node_err_rms_um: stats.node_err.rms,
            max_abs_dtheta_urad: stats.max_abs_dtheta_urad,
            image: args.out.display().to_string(),
            image_bytes: image.len(),
            csv: csv.display().to_string(),
            workspace_block,
            dynamics_block: args.dynamics.is_some(),
            noise: built.noise.clone(),
            judgement: Judgement::from(&verdict),
        },
        KeyOrder::Sorted,
    )
}
