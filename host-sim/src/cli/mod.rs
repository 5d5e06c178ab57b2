//! The command line's edge: one file per subcommand, each with its clap arguments, the checks
//! of its flags (messages name the flag), the call into the library and the printing of tables
//! (stderr) and JSON (stdout). `anyhow` lives only here and in `main.rs`.
//!
//! Where a change goes: a new flag in its subcommand's file (and the option it sets in the
//! library's options struct); a new subcommand is a file here and a variant of [`Tool`].

mod accuracy;
mod command;
mod commission;
mod common_args;
mod cut;
mod demo;
mod diagnose;
mod diagnose_moving;
mod fit;
mod grid;
mod identify;
mod import;
mod link;
mod link_args;
mod measure;
mod plan;
mod session;
mod simulate;
mod verify;

use anyhow::{anyhow, bail, Result};
use clap::{Parser, Subcommand};
use host_sim::calib::image::read_image;
use host_sim::io::machine_file::{self, read_machine};
use host_sim::io::model_file::{read_model_file, ModelFile};
use host_sim::io::{json_text, KeyOrder};
use host_sim::machine_identity::{check_files, check_model_geometry, FileMachine, MachineIdentity};
use host_sim::machine_spec::MachineSpec;
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use std::path::{Path, PathBuf};

/// Plant simulation and calibration tools of the hidden-robot micro-mechanism.
#[derive(Parser)]
#[command(name = "host-sim", version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Tool,
}

/// The subcommands.
#[derive(Subcommand)]
enum Tool {
    /// Plan the measurement session: the target lists, each row with its approach (CSV files).
    Plan(plan::Args),
    /// Measure a simulated plant with one of the paper's protocols or a plan's list (writes a
    /// measurement CSV; accuracy figures as JSON).
    Measure(measure::Args),
    /// Run the closed 2 kHz loop on a simulated plant (JSON summary on stdout).
    Simulate(simulate::Args),
    /// A laser tracker's / interferometer's point export joined by point id with the commanded
    /// list (column map, units, repeats, missing points), written as a measurement CSV.
    Import(import::Args),
    /// Fit the hidden robot to measurements (poly, ls, full).
    Fit(fit::Args),
    /// Build the correction-grid flash image from measurements at the grid nodes.
    Grid(grid::Args),
    /// Motor angles for targets, exactly as the firmware computes them (model + grid, f32).
    #[command(name = "command")]
    MotorCommand(command::Args),
    /// VDI/DGQ 3441 and ISO 230-2 figures per axis line from repeated bidirectional runs.
    Accuracy(accuracy::Args),
    /// The accuracy report for the customer: ISO 230-2 / VDI 3441 per axis and the 2-D
    /// position error, before and after calibration (one HTML page, plots embedded).
    Verify(verify::Args),
    /// Find where model and measurements disagree, name the missing effect, show the gap shrink.
    Diagnose(diagnose::Args),
    /// The whole calibration on a built-in simulated machine: measure, fit, grid, verify.
    Demo(demo::Args),
    /// The hidden robot's dynamic parameters from the controller's telemetry of the excitation
    /// motion (a controller over its link, a recorded log, or a simulated plant): dynamics.json.
    Identify(identify::Args),
    /// Cut a part program (G-code) with the gantry and the micro together: the split plan, the
    /// gantry-alone time, a lower bound, executed in simulation (table on stderr, JSON on stdout,
    /// plots and executed trajectories with --out DIR).
    Cut(cut::Args),
    /// Talk to a controller over its host link (QEMU: --tcp; the real board: --serial): identify, home, move, stream, upload...
    Link(link::Args),
    /// A measurement session through the controller: a plan's list visited with its approach,
    /// each point settled and read (typed in, or the tracker's export joined later by import).
    Session(session::Args),
    /// The machine builder's whole journey through the controller (co-simulated with --qemu,
    /// or one you started: --tcp, --serial): identify, home, plan, measure, fit, diagnose,
    /// dynamics, grid, upload, verify, moving; a table per step on stderr, the report as JSON.
    Commission(commission::Args),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Tool::Plan(a) => plan::run(&a),
        Tool::Measure(a) => measure::run(&a),
        Tool::Simulate(a) => simulate::run(&a),
        Tool::Import(a) => import::run(&a),
        Tool::Fit(a) => fit::run(&a),
        Tool::Grid(a) => grid::run(&a),
        Tool::MotorCommand(a) => command::run(&a),
        Tool::Accuracy(a) => accuracy::run(&a),
        Tool::Verify(a) => verify::run(&a),
        Tool::Diagnose(a) => diagnose::run(&a),
        Tool::Demo(a) => demo::run(&a),
        Tool::Link(a) => link::run(&a),
        Tool::Session(a) => session::run(&a),
        Tool::Commission(a) => commission::run(&a),
        Tool::Identify(a) => identify::run(&a),
        Tool::Cut(a) => cut::run_cut(&a),
    }
}

/// `--machine FILE`, the flag every subcommand has.
#[derive(clap::Args, Debug, Clone)]
pub struct MachineArg {
    /// The machine file (TOML; see docs/reference/machine-file.md). Default: the paper's machine
    /// (host-sim/machines/paper.toml, built in).
    #[arg(long, value_name = "FILE")]
    pub machine: Option<PathBuf>,
}

impl MachineArg {
    /// The machine every subcommand works on: the file's, or the paper's. The ONE place the
    /// machine is chosen.
    fn spec(&self) -> Result<MachineSpec> {
        match &self.machine {
            Some(path) => Ok(read_machine(path)?),
            None => Ok(machine_file::paper()),
        }
    }

    /// The flag as messages name it: `--machine FILE`, or the default.
    fn describe(&self) -> String {
        match &self.machine {
            Some(p) => format!("--machine {}", p.display()),
            None => "the default machine (no --machine given)".into(),
        }
    }

    /// Checks that `files` are of `spec`'s machine (`host_sim::machine_identity`): a file of
    /// another machine is refused naming both; a file naming none gets a note on stderr.
    fn check_files(&self, spec: &MachineSpec, files: &[FileMachine]) -> Result<()> {
        let notes =
            check_files(&spec.identity(), &self.describe(), files).map_err(|e| anyhow!(e))?;
        for n in notes {
            eprintln!("note: {n}");
        }
        Ok(())
    }

    /// Checks a model (read from `--flag path`) against `spec`'s machine: the identity it
    /// carries, and its geometry.
    fn check_model(
        &self,
        spec: &MachineSpec,
        flag: &str,
        path: &Path,
        file: &ModelFile,
    ) -> Result<()> {
        let what = format!("{flag} {}", path.display());
        self.check_files(
            spec,
            &[FileMachine {
                what: what.clone(),
                identity: file.machine.clone(),
            }],
        )?;
        let model = file
            .model()
            .map_err(|e| anyhow!("{}: {e}", path.display()))?;
        check_model_geometry(&model, &spec.nominal, &what, &spec.name).map_err(|e| anyhow!(e))
    }
}

/// A file and the machine it names, for [`MachineArg::check_files`].
fn file_machine(flag: &str, path: &Path, identity: Option<MachineIdentity>) -> FileMachine {
    FileMachine {
        what: format!("{flag} {}", path.display()),
        identity,
    }
}

/// The plant file `--plant NAME` reads, if it names one (`ideal` and `paper` are built in):
/// an input of the command (`host_sim::io::policy`).
fn plant_file(name: &str) -> Option<PathBuf> {
    match name {
        "ideal" | "paper" | "stand-in" => None,
        path => Some(PathBuf::from(path)),
    }
}

/// Decimals of a figure in µm that show what an instrument of σ `sigma_um` resolves (a tenth
/// of σ; at most 3): the human summaries print no more digits than the data hold.
fn um_decimals(sigma_um: f64) -> usize {
    if !(sigma_um > 0.0 && sigma_um.is_finite()) {
        return 3;
    }
    (-(sigma_um / 10.0).log10()).ceil().clamp(0.0, 3.0) as usize
}

/// Prints a JSON document on stdout (one document, pretty, final newline).
fn print_json(value: &impl serde::Serialize, order: KeyOrder) -> Result<()> {
    use std::io::Write as _;
    write!(std::io::stdout(), "{}", json_text(value, order)?)
        .map_err(|e| anyhow!("cannot write to stdout: {e}"))
}

/// Reads `--model` and `--grid`, each checked to be of `spec`'s machine: the model to command
/// with (the grid's own when a grid is given, which `--model` must then equal; the machine's
/// nominal without either) and the grid image bytes, judged for the machine
/// (`calib::image::read_image`: another machine's image or an implausible one is refused).
fn load_calibration(
    model: Option<&Path>,
    grid: Option<&Path>,
    spec: &MachineSpec,
    machine: &MachineArg,
) -> Result<LoadedCalibration> {
    let nominal = &spec.nominal;
    let from_model = match model {
        Some(p) => {
            let file = read_model_file(p)?;
            machine.check_model(spec, "--model", p, &file)?;
            Some(file.model()?.cast::<f32>())
        }
        None => None,
    };
    let bytes = match grid {
        None => None,
        Some(p) => Some(read_image(p, spec)?.bytes),
    };
    let model = match (&bytes, from_model) {
        (Some(b), m) => {
            let g = CorrectionGrid::parse(b).map_err(|e| {
                anyhow!(
                    "grid {}: {e}",
                    grid.map(|p| p.display().to_string()).unwrap_or_default()
                )
            })?;
            if let Some(m) = m {
                if m != *g.model() {
                    bail!("the model in --model differs from the model stored in --grid");
                }
            }
            *g.model()
        }
        (None, Some(m)) => m,
        (None, None) => nominal.cast::<f32>(),
    };
    Ok(LoadedCalibration {
        model,
        image: bytes,
    })
}

/// What [`load_calibration`] read: the model to command with and the grid image's bytes. The
/// servo's [`Calibration`] borrows the image, so the commands keep this and take
/// [`LoadedCalibration::calibration`] from it.
struct LoadedCalibration {
    model: FiveBar<f32>,
    image: Option<Vec<u8>>,
}

impl LoadedCalibration {
    /// The calibration the servo runs: the model and the image's grid.
    fn calibration(&self) -> Result<Calibration<'_>> {
        Ok(Calibration {
            model: self.model,
            grid: parse_grid(&self.image)?,
        })
    }
}

/// The registered instrument frame of a model file (`calib::frame`): the readings of its
/// set-up are mapped into the machine frame by it. No file, or a file without one (an older
/// fit): the instrument's own frame.
fn frame_of(model: Option<&Path>) -> Result<host_sim::calib::frame::InstrumentFrame> {
    match model {
        Some(p) => host_sim::calib::frame::InstrumentFrame::of_model_file(
            &host_sim::io::model_file::read_model_file(p)?,
        )
        .map_err(|e| anyhow!("{}: {e}", p.display())),
        None => Ok(host_sim::calib::frame::InstrumentFrame::IDENTITY),
    }
}

/// A parsed grid image (for `Calibration`), its errors naming the flag.
fn parse_grid(bytes: &Option<Vec<u8>>) -> Result<Option<CorrectionGrid<'_>>> {
    bytes
        .as_deref()
        .map(|b| CorrectionGrid::parse(b).map_err(|e| anyhow!("grid: {e}")))
        .transpose()
}

/// `--noise-um`: a non-negative number.
fn check_noise_um(n: Option<f64>) -> Result<()> {
    match n {
        Some(n) if !(n >= 0.0 && n.is_finite()) => {
            bail!("--noise-um must be a non-negative number, not {n}")
        }
        _ => Ok(()),
    }
}
