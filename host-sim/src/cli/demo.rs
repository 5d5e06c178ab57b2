//! `host-sim demo`: the whole calibration story on a built-in simulated machine, no files to
//! bring (`host_sim::calib::pipeline`, `docs/reference/calibration-tools.md`).
//!
//! Output: progress and the human table on stderr, one JSON summary on stdout (scripts parse it)
//! and the same in `summary.json`, written last in `--out` after every other file
//! (`pipeline::FILES`), each atomically, only once every step has succeeded. A run that misses
//! its stated goal (the noise floor) writes everything and exits non-zero.

use anyhow::{bail, Result};
use host_sim::calib::machine::{Machine, PlantMachine, StandInMachine};
use host_sim::calib::pipeline::{
    calibrate, summary, write_outputs, Approach, Calibrated, Event, PipelineOptions,
};
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use std::path::PathBuf;
use std::time::Instant;

/// How poses are approached.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ApproachArg {
    Random,
    Positive,
}

/// Run the whole calibration on a built-in simulated machine.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Directory for the measurement CSVs, models, grid image and plots.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seeds the machine's errors, the instrument noise and the random targets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The simulated machine: a six-bar plant (`paper`, the documented default resembling the
    /// paper's machine; `ideal`; or a plant TOML file, which must be built around --machine's
    /// five-bar) or `stand-in` (rigid five-bar + distortion, see machine.rs).
    #[arg(long, default_value = "paper")]
    pub plant: String,
    /// Instrument noise σ per axis (µm) for a plant (default: the machine file's instrument,
    /// 1 µm on the paper machine: the demo's premise; the `paper` plant's own is FARO-class,
    /// 10 µm).
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// How every pose is approached: `random` (from 5 mm away along a random direction; the
    /// grid in raster order) or `positive` (every motor reaches its command moving in the
    /// positive direction, as after an overshoot-and-return move: backlash then always sits
    /// on the same side and the grid calibrates it away). With `random` the backlash is
    /// measured on 200 random poses of its own and corrected by each motor's approach
    /// direction from then on (host-side, `calib::backlash`; model.json gets backlash_urad).
    /// Default: the machine file's policy (`positive` on the paper machine).
    #[arg(long, value_enum)]
    pub approach: Option<ApproachArg>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// Prints a progress line with the time since `start`.
fn progress(start: &Instant, what: &str) {
    eprintln!("demo: [{:6.2} s] {what}", start.elapsed().as_secs_f64());
}

/// The human-readable table (for stderr).
fn format_table(cal: &Calibrated) -> String {
    let before = cal.stages.first().map_or(f64::NAN, |s| s.accuracy.max_um);
    let mut s = format!(
        "machine: {}\n\naccuracy on {} fresh random targets (µm; true = where the tool landed, measured = what the instrument read)\n",
        cal.machine, cal.plan.verify.len()
    );
    s.push_str(&format!(
        "{:<36} {:>10} {:>10} {:>9} {:>13} {:>13} {:>11}\n",
        "step", "true max", "true RMS", "gain", "measured max", "measured RMS", "paper max"
    ));
    for st in &cal.stages {
        let a = &st.accuracy;
        s.push_str(&format!(
            "{:<36} {:>10.1} {:>10.2} {:>8.0}x {:>13.1} {:>13.2} {:>11}\n",
            st.description,
            a.max_um,
            a.rms_um,
            before / a.max_um,
            a.measured_max_um,
            a.measured_rms_um,
            st.paper
        ));
    }
    if cal.final_accuracy().is_some() {
        s.push_str(&format!(
            "\ntarget (noise floor): max <= {} µm, RMS <= {} µm: {}\n",
            cal.goal_um[0],
            cal.goal_um[1],
            if cal.target_met() { "met" } else { "NOT met" }
        ));
    }
    s
}

/// `host-sim demo`.
pub fn run(args: &Args) -> Result<()> {
    // Every file of the directory staged, then renamed together once all are ready.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--plant", super::plant_file(&args.plant))
        .output_dir("--out", &args.out, &host_sim::calib::pipeline::FILES)
        .check()?;
    let mut spec = args.machine.spec()?;
    let noise_um = args.noise_um.unwrap_or(spec.instrument_sigma_um);
    super::check_noise_um(Some(noise_um))?;
    // The instrument the run measures with (its σ sets the goal).
    if !matches!(args.plant.as_str(), "stand-in") {
        spec.instrument_sigma_um = noise_um;
    }
    let mut machine: Box<dyn Machine> = match args.plant.as_str() {
        "stand-in" => Box::new(StandInMachine::paper_like(&spec, args.seed)?),
        name => {
            let plant = super::common_args::plant_for(name, &spec)?;
            Box::new(PlantMachine::from_config(
                plant,
                name,
                Some(noise_um),
                args.seed,
            )?)
        }
    };
    let approach = match args.approach {
        None => spec.approach,
        Some(ApproachArg::Random) => Approach::FromVisit,
        Some(ApproachArg::Positive) => Approach::Positive,
    };
    let start = Instant::now();
    let mut events = |e: Event| match e {
        Event::Step(what) => progress(&start, &what),
        Event::Held { param, why } => {
            eprintln!("demo: full fit: {param} held at nominal: the data confound {why}")
        }
    };
    let cal = calibrate(
        machine.as_mut(),
        &PipelineOptions {
            seed: args.seed,
            approach,
            spec,
        },
        &mut events,
    )?;
    let start = Instant::now();
    progress(
        &start,
        &format!(
            "writing CSVs, models, grid image and plots into {}",
            args.out.display()
        ),
    );
    let mut files = write_outputs(&cal, &args.out, &mut outputs)?;
    files.push(args.out.join("summary.json"));
    let summary = summary(&cal, args.seed, &args.out, &files);
    let text = json_text(&summary, KeyOrder::Sorted)?;
    outputs.bytes(&args.out.join("summary.json"), text.as_bytes())?;
    outputs.commit()?;
    progress(&start, "files written");
    eprintln!("\n{}", format_table(&cal));
    eprintln!(
        "grid, round 1: {}\ngrid, round 2: {}\n",
        cal.grid.noise.describe(),
        cal.grid2.noise.describe()
    );
    print!("{text}");
    if !summary.final_.met {
        bail!(
            "the accuracy target (max <= {} µm, RMS <= {} µm) was not met on this machine: {:?} / {:?} µm (outputs written to {})",
            summary.final_.target_max_um,
            summary.final_.target_rms_um,
            summary.final_.max_um,
            summary.final_.rms_um,
            args.out.display()
        );
    }
    Ok(())
}
