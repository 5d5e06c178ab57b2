//! `host-sim plan`: the measurement session's target lists (`host_sim::calib::plan`) as CSV
//! files in a directory (`identify.csv`, `grid.csv`, `verify.csv`, `repeat.csv`: the targets
//! file format with the plan's columns, `host_sim::io::targets_csv`) and the plan's report
//! (`plan.json`, also on stdout: the identification design's condition number and
//! observability against random poses of the same count).

use super::MachineArg;
use anyhow::{Context, Result};
use host_sim::calib::plan::{list_rows, plan, PlanOptions, Selection};
use host_sim::io::policy::CommandFiles;
use host_sim::io::targets_csv::format_target_list;
use host_sim::io::{json_text, KeyOrder};
use std::path::PathBuf;

/// How the identification poses are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SelectionArg {
    /// Maximise det(JᵀJ) of the identification Jacobian over the candidates.
    DOptimal,
    /// Uniform random poses (the first candidates).
    Random,
}

/// Arguments of `host-sim plan`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output directory for identify.csv, grid.csv, verify.csv, repeat.csv and plan.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Draws the candidate poses and the verification targets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Identification poses for the `full` fit.
    #[arg(long, default_value_t = host_sim::calib::plan::IDENTIFICATION_POSES)]
    pub identification_poses: usize,
    /// Candidate poses they are chosen from (default: 10 per pose).
    #[arg(long)]
    pub candidates: Option<usize>,
    /// How the identification poses are chosen.
    #[arg(long, value_enum, default_value = "d-optimal")]
    pub selection: SelectionArg,
    /// Verification targets (fresh: disjoint from every other list).
    #[arg(long, default_value_t = host_sim::calib::plan::VERIFY_TARGETS)]
    pub verify_targets: usize,
    #[command(flatten)]
    pub machine: MachineArg,
}

/// `host-sim plan`.
pub fn run(args: &Args) -> Result<()> {
    let names: Vec<String> = host_sim::calib::plan::LIST_NAMES
        .iter()
        .map(|n| format!("{n}.csv"))
        .chain(["plan.json".to_string()])
        .collect();
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .output_dir("--out", &args.out, &names)
        .check()?;
    let spec = args.machine.spec()?;
    let mut opts = PlanOptions::new(spec, args.seed);
    opts.identification_poses = args.identification_poses;
    opts.candidates = args.candidates.unwrap_or(
        host_sim::calib::plan::CANDIDATES_PER_POSE.saturating_mul(args.identification_poses),
    );
    opts.selection = match args.selection {
        SelectionArg::DOptimal => Selection::DOptimal,
        SelectionArg::Random => Selection::Random,
    };
    opts.verify_targets = args.verify_targets;
    let p = plan(&opts).context("planning")?;
    // Every file staged, then renamed together: a file that cannot be written leaves none.
    let mut files: Vec<(PathBuf, String)> = p
        .lists()
        .iter()
        .map(|(name, list)| {
            (
                args.out.join(format!("{name}.csv")),
                format_target_list(&list_rows(list)),
            )
        })
        .collect();
    let report = json_text(&p.report, KeyOrder::Sorted)?;
    files.push((args.out.join("plan.json"), report.clone()));
    for (path, text) in &files {
        outputs.bytes(path, text.as_bytes())?;
    }
    outputs.commit()?;
    let id = &p.report.identification;
    eprintln!(
        "plan: {} identification poses ({:?} of {}): condition number {:.1} (random poses of the same count {:.1}), observability O1 {:.3} ({:.3})",
        id.chosen.poses,
        id.selection,
        id.candidates,
        id.chosen.condition_number,
        id.random_same_count.condition_number,
        id.chosen.observability_o1,
        id.random_same_count.observability_o1
    );
    for (name, n) in &p.report.lists {
        eprintln!(
            "plan: {n} targets in {}",
            args.out.join(format!("{name}.csv")).display()
        );
    }
    print!("{report}");
    Ok(())
}
