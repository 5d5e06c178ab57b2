//! `host-sim diagnose`: measurements and a model in, the gap-shrink table on stdout, the report
//! JSON and plots out (`host_sim::diagnose`, `docs/design/diagnosis.md`). With `--telemetry` the
//! moving machine's diagnosis instead (`diagnose_moving`, `host_sim::dynamics::diagnose`).

use anyhow::{bail, Context, Result};
use host_sim::calib::fit::params::N_PARAMS;
use host_sim::calib::fit::plausibility;
use host_sim::calib::frame::{machine_frame_gauge, InstrumentFrame};
use host_sim::diagnose::model_out::extended_model;
use host_sim::diagnose::plots::write_plots;
use host_sim::diagnose::{diagnose_with_plot_data, report, DiagnoseOptions};
use host_sim::io::measurement_csv::read_measurement_file;
use host_sim::io::model_file::{model_file_text, read_model_file};
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use host_sim::loop_closure::SixBarDesign;
use std::path::PathBuf;

/// Command-line arguments of `host-sim diagnose`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Measurement CSV (see measurement_csv).
    #[arg(
        long,
        required_unless_present = "telemetry",
        conflicts_with = "telemetry"
    )]
    pub data: Option<PathBuf>,
    #[command(flatten)]
    pub moving: super::diagnose_moving::MovingArgs,
    /// The current model (model.json); default: the machine's nominal five-bar.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Measurement noise, one standard deviation per axis (µm). Default: from repeats, if any.
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// Report JSON.
    #[arg(long)]
    pub out: PathBuf,
    /// Directory for residual plots (PNG).
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Write the extended model (model.json with the named effects added: five-bar parameters
    /// folded in, backlash as a direction-dependent correction, the rest recorded for the
    /// grid; `diagnose::model_out`).
    #[arg(long)]
    pub out_model: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// `host-sim diagnose`.
pub fn run(args: &Args) -> Result<()> {
    let Some(data_path) = &args.data else {
        if args.plots.is_some() || args.out_model.is_some() || args.noise_um.is_some() {
            bail!("--plots, --out-model and --noise-um are the static diagnosis' (--data); with --telemetry, --out-dynamics writes the updated dynamics");
        }
        let shared = super::diagnose_moving::Shared {
            model: args.model.as_deref(),
            out: &args.out,
            machine: &args.machine,
        };
        return super::diagnose_moving::run(&args.moving, shared);
    };
    // The report, the extended model and the plots staged, then renamed together; none may
    // be an input or another's file.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--data", &args.data)
        .input("--model", &args.model)
        .output("--out", &args.out)
        .output("--out-model", &args.out_model)
        // The plot every diagnosis writes, checked now; the others when staged.
        .output_dir("--plots", &args.plots, &["residual_start.png"])
        .check()?;
    let spec = args.machine.spec()?;
    let read = read_measurement_file(data_path)?;
    args.machine.check_files(
        &spec,
        &[super::file_machine("--data", data_path, read.machine)],
    )?;
    let base = match &args.model {
        Some(p) => {
            let file = read_model_file(p)?;
            args.machine.check_model(&spec, "--model", p, &file)?;
            file.model()?
        }
        None => spec.nominal,
    };
    // The readings into the machine frame by the model's registered instrument frame (none in
    // an older model file): the diagnosis looks at what the model does not explain, not at
    // where the tracker stood.
    let frame = super::frame_of(args.model.as_deref())?;
    let registered_model = match &args.model {
        Some(p) => read_model_file(p)?.instrument_frame.is_some(),
        None => false,
    };
    let data = frame.register(&read.rows);
    // The model written must pass what a fit's must (`calib::fit::plausibility`): data in
    // metres or radians are refused before the diagnosis, not folded into a model.
    if args.out_model.is_some() {
        plausibility::check_units(&spec.nominal, &data)
            .with_context(|| format!("--data {}", data_path.display()))?;
    }
    // The six-bar's own effects are derived from the machine's nominal design, not the current
    // model (which may carry an instrument offset as its A0).
    let sixbar = SixBarDesign::for_model(&spec.nominal, spec.workspace.centre_mm())
        .map_err(|e| anyhow::anyhow!("the machine's six-bar design: {e}"))?;
    if let Some(s) = args.noise_um {
        if !(s.is_finite() && s > 0.0) {
            bail!("--noise-um {s}: must be a positive number of micrometres");
        }
    }
    let (report, plot_data) = diagnose_with_plot_data(
        &data,
        &DiagnoseOptions {
            base,
            noise_um: args.noise_um,
            sixbar,
        },
    )
    .with_context(|| format!("diagnosing {}", data_path.display()))?;
    print!("{}", report::table(&report));
    // Everything computed before anything is written: a model that cannot be made leaves no
    // report behind either.
    let extended = match &args.out_model {
        Some(_) => {
            let e =
                extended_model(&base, &report).context("adding the named effects to the model")?;
            plausibility::check_model(
                &e.model,
                &spec.nominal,
                &[None; N_PARAMS],
                &data,
                &plausibility::FitEvidence::default(),
            )
            .context("the extended model (--out-model)")?;
            Some(e)
        }
        None => None,
    };
    // The extended model back in the machine frame's convention (a frame effect the diagnosis
    // folded into A0 and the offsets goes into the instrument's frame; an exact change of
    // frame), with the frame it now implies.
    let registered_file = |e: &host_sim::diagnose::model_out::ExtendedModel| {
        let mut file = e.file(&data_path.display().to_string());
        if registered_model {
            let fitted = file.model()?;
            let (machine, g) = machine_frame_gauge(&fitted, &spec.nominal);
            let moved = host_sim::io::model_file::ModelFile::from_model(&machine);
            file.base_a0_mm = moved.base_a0_mm;
            file.base_b0_mm = moved.base_b0_mm;
            file.encoder_offset_deg = moved.encoder_offset_deg;
            file.instrument_frame = Some(
                InstrumentFrame {
                    to_instrument: frame.to_instrument.after(&g),
                    std_dev: None,
                }
                .record(),
            );
        }
        Ok::<_, host_sim::io::IoError>(file)
    };
    outputs.bytes(
        &args.out,
        json_text(&report, KeyOrder::Declared)?.as_bytes(),
    )?;
    if let (Some(path), Some(e)) = (&args.out_model, &extended) {
        outputs.bytes(
            path,
            model_file_text(&{
                let mut f = registered_file(e)?;
                f.machine = Some(spec.identity());
                f
            })?
            .as_bytes(),
        )?;
    }
    if let Some(dir) = &args.plots {
        write_plots(&mut outputs, dir, &data, &report, &plot_data)?;
    }
    outputs.commit()?;
    if let Some(path) = &args.out_model {
        eprintln!("diagnose: extended model -> {}", path.display());
    }
    Ok(())
}
