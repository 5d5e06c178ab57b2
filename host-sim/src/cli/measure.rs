//! `host-sim measure`: a protocol or a plan's list on a simulated plant, written as a
//! measurement CSV (`host_sim::calib::measure`), with the accuracy of the measured visits
//! against their targets as JSON on stdout (true and measured: the demo's verification
//! figures).

use super::MachineArg;
use anyhow::{bail, Result};
use host_sim::calib::machine::PlantMachine;
use host_sim::calib::measure::{
    accuracy, measure_list_compensated, registered, rows, Accuracy, Approach,
};
use host_sim::calib::plan::visits_from_rows;
use host_sim::calib::protocol::{visits, Protocol};
use host_sim::io::measurement_csv::format_measurements_of;
use host_sim::io::model_file::read_model_file;
use host_sim::io::policy::CommandFiles;
use host_sim::io::targets_csv::read_target_list;
use host_sim::io::KeyOrder;
use serde::Serialize;
use std::path::PathBuf;

/// How every motor arrives at its command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ApproachArg {
    /// From `approach_mm` away along a random direction (a protocol's start of each move).
    Random,
    /// Every motor moving forward (unidirectional positioning, as after an overshoot-and-return).
    Positive,
}

impl From<ApproachArg> for Approach {
    fn from(a: ApproachArg) -> Approach {
        match a {
            ApproachArg::Random => Approach::FromVisit,
            ApproachArg::Positive => Approach::Positive,
        }
    }
}

/// Arguments of `host-sim measure`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// `ideal`, `paper` or a plant TOML file.
    #[arg(long)]
    pub plant: String,
    /// `table1`, `grid`, `random:N` or `repeat` (or give --targets).
    #[arg(long)]
    pub protocol: Option<String>,
    /// A targets file to measure in its order: a plan's list (`host-sim plan`; its rows'
    /// approach is used unless --approach is given) or any `x_mm,y_mm` list.
    #[arg(long, value_name = "FILE", conflicts_with = "protocol")]
    pub targets: Option<PathBuf>,
    /// How every motor arrives: `random` (from the move's start) or `positive`. Default: a
    /// plan list's own directions; for a protocol, `random`.
    #[arg(long, value_enum)]
    pub approach: Option<ApproachArg>,
    /// Seeds the random targets and the instrument noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output measurement CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// Hidden-robot model to command with (default: the machine's nominal five-bar); its
    /// backlash_urad, if any, is corrected by direction in every command.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correction grid image to add to the commands.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Overrides the instrument's noise σ (µm).
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// A model.json whose registered instrument frame the printed accuracy is judged in
    /// (default: --model's; without either, the instrument's own frame). The CSV keeps the
    /// instrument's readings as they are.
    #[arg(long, value_name = "MODEL")]
    pub instrument_frame: Option<PathBuf>,
    #[command(flatten)]
    pub machine: MachineArg,
}

/// What `measure` prints.
#[derive(Serialize)]
struct Summary {
    machine: String,
    plant: String,
    targets: String,
    approach: String,
    seed: u64,
    out: String,
    /// Where the tool landed (simulation: the truth) and what the instrument read, against the
    /// targets (µm).
    #[serde(flatten)]
    accuracy: Accuracy,
}

pub fn run(args: &Args) -> Result<()> {
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--plant", super::plant_file(&args.plant))
        .input("--targets", &args.targets)
        .input("--model", &args.model)
        .input("--grid", &args.grid)
        .input("--instrument-frame", &args.instrument_frame)
        .output("--out", &args.out)
        .check()?;
    let spec = args.machine.spec()?;
    let plant = super::common_args::plant_for(&args.plant, &spec)?;
    let (list, what) = match (&args.protocol, &args.targets) {
        (Some(p), None) => (visits(Protocol::parse(p)?, args.seed, &spec), p.clone()),
        (None, Some(path)) => {
            let mut v = visits_from_rows(&read_target_list(path)?, &spec);
            if args.approach.is_some() {
                // The flag wins over the list's directions.
                v.iter_mut().for_each(|v| v.dir = None);
            }
            (v, path.display().to_string())
        }
        _ => bail!("give --protocol (table1, grid, random:N, repeat) or --targets FILE"),
    };
    let approach: Approach = args.approach.map_or(Approach::FromVisit, Approach::from);
    let loaded = super::load_calibration(
        args.model.as_deref(),
        args.grid.as_deref(),
        &spec,
        &args.machine,
    )?;
    let cal = loaded.calibration()?;
    super::check_noise_um(args.noise_um)?;
    // A model with a backlash correction (diagnose --out-model, the demo with random
    // approach): every command corrected by its motors' approach directions, as the servo would.
    let backlash = match &args.model {
        Some(p) => read_model_file(p)?
            .backlash()
            .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
        None => None,
    };
    let frame = super::frame_of(args.instrument_frame.as_deref().or(args.model.as_deref()))?;
    let mut machine = PlantMachine::from_config(plant, &args.plant, args.noise_um, args.seed)?;
    let landed = measure_list_compensated(
        &mut machine,
        &cal,
        backlash.as_ref(),
        &list,
        approach,
        args.seed,
        &spec,
    )?;
    outputs.bytes(
        &args.out,
        format_measurements_of(&rows(&landed), &spec.identity()).as_bytes(),
    )?;
    outputs.commit()?;
    let a = accuracy(&landed);
    let p = super::um_decimals(args.noise_um.unwrap_or(spec.instrument_sigma_um));
    eprintln!(
        "measure: {} measurements of machine '{}' written to {}",
        landed.len(),
        spec.name,
        args.out.display()
    );
    eprintln!(
        "measure: against the targets (µm)   max {:>9.p$}   RMS {:>9.p$}   (where the tool landed)\n\
         measure:                             max {:>9.p$}   RMS {:>9.p$}   (what the instrument read)",
        a.max_um, a.rms_um, a.measured_max_um, a.measured_rms_um
    );
    let approach = match (args.approach, args.targets.is_some()) {
        (Some(a), _) => Approach::from(a).name().to_string(),
        (None, true) => "as the list says (random where it says nothing)".into(),
        (None, false) => Approach::FromVisit.name().to_string(),
    };
    super::print_json(
        &Summary {
            machine: spec.name.clone(),
            plant: args.plant.clone(),
            targets: what,
            approach,
            seed: args.seed,
            out: args.out.display().to_string(),
            accuracy: accuracy(&registered(&landed, &frame)),
        },
        KeyOrder::Sorted,
    )
}
