//! `host-sim cut`: a part program cut by the redundant machine (`host_sim::cut`): a table on
//! stderr, the report as JSON on stdout, and with `--out DIR` the plots (`part.png`,
//! `motion.png`), the executed trajectories (`executed.csv`) and the report (`report.json`),
//! staged and written together only once all are ready. A program that cannot be cut (bad
//! G-code, outside the travel, ...) writes nothing; a run that exceeded a limit writes its
//! files (to see why) and exits non-zero.

use anyhow::{bail, Context, Result};
use host_sim::cut::{plots, report, run, CutOptions};
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use host_sim::plant::PlantConfig;
use std::path::{Path, PathBuf};

/// Arguments of `host-sim cut`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The part program (RS274 G-code as laser cutters write it).
    #[arg(long, value_name = "PART.nc")]
    pub program: PathBuf,
    #[command(flatten)]
    pub machine: super::MachineArg,
    /// Where the plots, the executed trajectories and the report go (created).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// The micro's plant: `ideal` (the calibrated machine's stand-in, built around the machine
    /// file's five-bar), `paper` or a plant TOML (with `--model`/`--grid` of its calibration).
    #[arg(long, default_value = "ideal")]
    pub plant: String,
    /// Overrides the plant's linkage model: `sixbar` or `fivebar` (fast).
    #[arg(long)]
    pub plant_model: Option<String>,
    /// Hidden-robot model the micro's servo uses (default: nominal).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correction grid image the micro's servo uses.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Identified dynamics the micro's servo feeds forward (default: the plant's own).
    #[arg(long)]
    pub dynamics: Option<PathBuf>,
    /// Every how many samples a row of executed.csv is written (1: every 0.5 ms).
    #[arg(long, default_value_t = 1)]
    pub csv_every: usize,
}

/// The files `--out DIR` receives.
const OUTPUT_FILES: [&str; 4] = ["part.png", "motion.png", "executed.csv", "report.json"];

fn read_program(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("cannot read the program {}", path.display()))?;
    String::from_utf8(bytes).map_err(|_| {
        anyhow::anyhow!(
            "{} is not a G-code program: not text (UTF-8); give the part program a laser cutter's CAM wrote",
            path.display()
        )
    })
}

pub fn run_cut(args: &Args) -> Result<()> {
    if args.csv_every == 0 || args.csv_every > 1_000_000 {
        bail!("--csv-every must be 1 to 1000000, not {}", args.csv_every);
    }
    // Every file declared before anything is read heavily; written together at the end.
    let mut out = CommandFiles::new()
        .input("--program", &args.program)
        .input("--machine", &args.machine.machine)
        .input("--plant", super::plant_file(&args.plant))
        .input("--model", &args.model)
        .input("--grid", &args.grid)
        .input("--dynamics", &args.dynamics)
        .output_dir("--out", &args.out, &OUTPUT_FILES)
        .check()?;
    let spec = args.machine.spec()?;
    let mut plant = PlantConfig::by_name(&args.plant)?;
    // `ideal` on another machine than the paper's: the ideal plant built around its five-bar.
    if args.plant == "ideal" && host_sim::calib::machine::check_plant_fits(&plant, &spec).is_err() {
        plant = PlantConfig::ideal_for(&spec.nominal, &spec.grid_nodes_mm()).ok_or_else(|| {
            anyhow::anyhow!(
                "no ideal plant can be built around machine '{}' (its nominal model does not reach its grid)",
                spec.name
            )
        })?;
    }
    super::common_args::override_plant_model(&mut plant, args.plant_model.as_deref())?;
    let text = read_program(&args.program)?;
    let loaded = super::load_calibration(
        args.model.as_deref(),
        args.grid.as_deref(),
        &spec,
        &args.machine,
    )?;
    let calibration = loaded.calibration()?;
    let dynamics = match &args.dynamics {
        Some(p) => Some(super::common_args::read_dynamics(
            &args.machine,
            &spec,
            "--dynamics",
            p,
        )?),
        None => None,
    };
    let name = args.program.file_name().map_or_else(
        || args.program.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let opts = CutOptions {
        spec: spec.clone(),
        plant,
        calibration,
        dynamics,
        program_name: name.clone(),
    };
    let cut = run(&text, &opts).with_context(|| format!("{}", args.program.display()))?;
    let r = &cut.report;
    if let Some(dir) = &args.out {
        let micro = &cut.limits.split.micro;
        let g = &spec.gantry;
        out.bytes(
            &dir.join("part.png"),
            &plots::part_png(&spec, &cut.planned, &cut.executed, micro)?,
        )?;
        out.bytes(
            &dir.join("motion.png"),
            &plots::motion_png(
                &cut.executed,
                cut.planned.plan.dt_s,
                [
                    g.speed_mm_s,
                    g.accel_g * host_sim::machine_spec::STANDARD_GRAVITY_MM_S2,
                ],
                micro,
            )?,
        )?;
        out.bytes(
            &dir.join("executed.csv"),
            report::executed_csv(&spec, &name, &cut.planned, &cut.executed, args.csv_every)
                .as_bytes(),
        )?;
        out.bytes(
            &dir.join("report.json"),
            json_text(r, KeyOrder::Declared)?.as_bytes(),
        )?;
    }
    out.commit()?;
    eprintln!(
        "cut {} on {} ({}):",
        r.program, r.machine.name, r.micro_stage
    );
    eprintln!(
        "  plan {:?}{}: {} moves in {} spans, {} pierces, {:.0} mm cut, {:.0} mm rapid",
        r.plan,
        r.fallback
            .as_deref()
            .map_or(String::new(), |f| format!(" ({f})")),
        r.moves,
        r.spans,
        r.pierces,
        r.cut_length_mm,
        r.rapid_length_mm
    );
    eprintln!("  | time | s |");
    eprintln!("  |---|---|");
    eprintln!("  | split machine (as executed) | {:.3} |", r.completion_s);
    eprintln!(
        "  | gantry alone | {:.3} ({:.2}x) |",
        r.gantry_only_s, r.speedup
    );
    eprintln!(
        "  | lower bound | {:.3} (split / bound {:.3}) |",
        r.bound_s, r.bound_ratio
    );
    eprintln!(
        "  contour error while cutting: {:.2} um max, {:.2} um RMS; micro inside its workspace: {} (clearance {:.2} mm); within limits: {}",
        r.contour_max_um, r.contour_rms_um, r.micro_inside_workspace, r.micro.min_clearance_mm, r.within_limits
    );
    eprintln!(
        "  planner {:.3} s, execution {:.2} s wall{}",
        r.planner_s,
        r.execution_s,
        args.out
            .as_ref()
            .map_or(String::new(), |d| format!("; files in {}", d.display()))
    );
    super::print_json(r, KeyOrder::Declared)?;
    if !r.within_limits {
        bail!(
            "the executed motion exceeded a limit: {}",
            r.violations.join("; ")
        );
    }
    Ok(())
}
