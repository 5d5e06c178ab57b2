//! `host-sim command`: motor angles for a targets file, through the firmware's own command path
//! (`host_sim::calib::command`).

use anyhow::{anyhow, Context, Result};
use host_sim::calib::command::{
    check_grid_model, check_in_workspace, command_all, command_all_compensated, format_commands,
    format_commands_with_dirs,
};
use host_sim::calib::image::read_image;
use host_sim::io::model_file::read_model_file;
use host_sim::io::policy::CommandFiles;
use host_sim::io::targets_csv::read_targets;
use kinematics_core::{Calibration, CorrectionGrid};
use std::path::PathBuf;

/// Motor angles for targets, via the firmware's command path (model IK + grid, f32).
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model (model.json; default: the machine file's nominal five-bar, what a first
    /// session on an uncalibrated machine commands with). If it carries `backlash_urad`
    /// (diagnose --out-model, the demo), the targets are a motion in file order and each command
    /// is corrected by its motors' approach directions (written as dir1,dir2 columns).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Optional correction-grid image; its embedded model must be --model's (without --model,
    /// the image's model is used).
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Targets CSV with columns x_mm,y_mm.
    #[arg(long)]
    pub targets: PathBuf,
    /// Output CSV: x_mm,y_mm,theta1_deg,theta2_deg.
    #[arg(long)]
    pub out: PathBuf,
    /// Smallest |sin| of a transmission angle accepted (default: the machine's, the servo's
    /// 0.05 on the paper machine).
    #[arg(long)]
    pub min_transmission: Option<f32>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// `host-sim command`.
pub fn run(args: &Args) -> Result<()> {
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--model", &args.model)
        .input("--grid", &args.grid)
        .input("--targets", &args.targets)
        .output("--out", &args.out)
        .check()?;
    let spec = args.machine.spec()?;
    let image = match &args.grid {
        Some(path) => Some(read_image(path, &spec)?.bytes),
        None => None,
    };
    let grid = match (&image, &args.grid) {
        (Some(bytes), Some(path)) => {
            let g = CorrectionGrid::parse(bytes).map_err(|e| anyhow!("{}: {e}", path.display()))?;
            Some(g)
        }
        _ => None,
    };
    // The model: --model's (the grid's embedded model must be it), else the grid's own, else
    // the machine's nominal five-bar.
    let (model, backlash) = match (&args.model, &grid) {
        (Some(path), _) => {
            let file = read_model_file(path)?;
            args.machine.check_model(&spec, "--model", path, &file)?;
            let model = file
                .model()
                .map_err(|e| anyhow!("{}: {e}", path.display()))?;
            if let Some(g) = &grid {
                check_grid_model(g, &model)?;
            }
            (
                model.cast::<f32>(),
                file.backlash()
                    .map_err(|e| anyhow!("{}: {e}", path.display()))?,
            )
        }
        (None, Some(g)) => (*g.model(), None),
        (None, None) => (spec.nominal.cast::<f32>(), None),
    };
    let cal = Calibration { model, grid };
    let targets = read_targets(&args.targets)?;
    let in_file = || format!("in {}", args.targets.display());
    // The workspace the firmware keeps to: the image's when it carries one, else the machine's.
    let image_region = match cal.grid.as_ref().and_then(|g| g.workspace()) {
        Some(w) => Some(
            w.region
                .cast::<f64>()
                .map_err(|e| anyhow!("the grid's workspace block: {e}"))?,
        ),
        None => None,
    };
    let region = image_region.as_ref().unwrap_or(&spec.workspace.region);
    check_in_workspace(&targets, region, &spec.name, image_region.is_some())
        .with_context(in_file)?;
    let min_transmission = args
        .min_transmission
        .unwrap_or(spec.min_transmission as f32);
    let text = match backlash {
        None => {
            let angles = command_all(&cal, &targets, min_transmission).with_context(in_file)?;
            format_commands(&targets, &angles)
        }
        Some(b) => {
            let (angles, dirs) = command_all_compensated(&cal, &targets, min_transmission, &b)
                .with_context(in_file)?;
            format_commands_with_dirs(&targets, &angles, &dirs)
        }
    };
    outputs.bytes(&args.out, text.as_bytes())?;
    outputs.commit()?;
    eprintln!(
        "command: {} targets -> {}",
        targets.len(),
        args.out.display()
    );
    Ok(())
}
