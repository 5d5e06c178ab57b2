//! `host-sim verify`: the accuracy report for the customer (`host_sim::calib::verify`) from the
//! verification and repeat measurements after calibration (and before it, optionally): one
//! self-contained HTML page (`--out`), the figures as JSON on stdout (and in `--json`). Every
//! output is made in memory first and written (atomically) only once all are ready.

use super::MachineArg;
use anyhow::{anyhow, bail, Context, Result};
use host_sim::calib::verify::{html, verify, StageData, VerifyOptions};
use host_sim::io::measurement_csv::Measurement;
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use host_sim::machine_spec::MachineSpec;
use std::path::{Path, PathBuf};

/// The accuracy report: ISO 230-2 / VDI 3441 per axis line and the 2-D position error, before
/// and after calibration.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Verification targets measured after calibration (measurement CSV with targets; the
    /// plan's verify.csv measured with `measure --targets ... --grid grid.bin`).
    #[arg(long, value_name = "FILE")]
    pub after_verify: PathBuf,
    /// Repeat runs measured after calibration (targets and run on every row, in motion order;
    /// the plan's repeat.csv measured with `measure --targets ... --grid grid.bin`).
    #[arg(long, value_name = "FILE")]
    pub after_repeat: PathBuf,
    /// Verification targets measured before calibration (nominal model).
    #[arg(long, value_name = "FILE", requires = "before_repeat")]
    pub before_verify: Option<PathBuf>,
    /// Repeat runs measured before calibration (nominal model).
    #[arg(long, value_name = "FILE", requires = "before_verify")]
    pub before_repeat: Option<PathBuf>,
    /// The report (HTML, plots embedded).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Also write the JSON figures to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// The calibrated model.json whose registered instrument frame maps every input's readings
    /// into the machine frame (one instrument set-up for all of them). Without it the readings
    /// are judged as they are (an instrument aligned to the machine).
    #[arg(long, value_name = "MODEL")]
    pub instrument_frame: Option<PathBuf>,
    #[command(flatten)]
    pub machine: MachineArg,
}

/// Reads `--flag path`, checked to be of the machine, registered into the machine frame.
fn read(
    machine: &MachineArg,
    spec: &MachineSpec,
    flag: &str,
    path: &Path,
    frame: &host_sim::calib::frame::InstrumentFrame,
) -> Result<Vec<Measurement>> {
    let rows = super::common_args::read_measurements(machine, spec, flag, path)?;
    Ok(frame.register(&rows))
}

/// `host-sim verify`.
pub fn run(args: &Args) -> Result<()> {
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--after-verify", &args.after_verify)
        .input("--after-repeat", &args.after_repeat)
        .input("--before-verify", &args.before_verify)
        .input("--before-repeat", &args.before_repeat)
        .input("--instrument-frame", &args.instrument_frame)
        .output("--out", &args.out)
        .output("--json", &args.json)
        .check()?;
    let spec = args.machine.spec()?;
    let frame = super::frame_of(args.instrument_frame.as_deref())?;
    let m = &args.machine;
    let after = StageData {
        verify: read(m, &spec, "--after-verify", &args.after_verify, &frame)?,
        repeat: read(m, &spec, "--after-repeat", &args.after_repeat, &frame)?,
    };
    let before = match (&args.before_verify, &args.before_repeat) {
        (Some(v), Some(r)) => Some(StageData {
            verify: read(m, &spec, "--before-verify", v, &frame)?,
            repeat: read(m, &spec, "--before-repeat", r, &frame)?,
        }),
        (None, None) => None,
        _ => bail!("--before-verify and --before-repeat come together"),
    };
    let report = verify(&VerifyOptions {
        spec: spec.clone(),
        before,
        after,
    })
    .map_err(|e| anyhow!("{e}"))?;
    let mut listed = vec![
        (
            "after calibration, verification".to_string(),
            args.after_verify.display().to_string(),
        ),
        (
            "after calibration, repeat runs".into(),
            args.after_repeat.display().to_string(),
        ),
    ];
    if let (Some(v), Some(r)) = (&args.before_verify, &args.before_repeat) {
        listed.insert(
            0,
            (
                "before calibration, repeat runs".into(),
                r.display().to_string(),
            ),
        );
        listed.insert(
            0,
            (
                "before calibration, verification".into(),
                v.display().to_string(),
            ),
        );
    }
    let page = html::render(&report, &spec, &listed).context("rendering the report")?;
    let json = json_text(&report, KeyOrder::Sorted)?;
    // Both staged, then renamed together: a --json that cannot be written leaves no page.
    outputs.bytes(&args.out, page.as_bytes())?;
    if let Some(j) = &args.json {
        outputs.bytes(j, json.as_bytes())?;
    }
    outputs.commit()?;
    for s in &report.stages {
        let p = &s.position;
        eprintln!(
            "verify: {}: 2-D position error max {:.2} µm, RMS {:.2} µm ({} targets)",
            s.stage, p.max_um, p.rms_um, p.n_points
        );
        for l in &s.lines {
            eprintln!(
                "verify: {}: {}: ISO 230-2 A {:.2} R {:.2} E {:.2} B {:.2} µm; VDI 3441 P {:.2} Ps {:.2} µm",
                s.stage,
                html::line_name(l),
                l.iso_230_2.a_um,
                l.iso_230_2.r_um,
                l.iso_230_2.e_um,
                l.iso_230_2.b_um,
                l.vdi_3441.p_um,
                l.vdi_3441.ps_um
            );
        }
    }
    for n in &report.notes {
        eprintln!("verify: note: {n}");
    }
    eprintln!("verify: report written to {}", args.out.display());
    use std::io::Write as _;
    write!(std::io::stdout(), "{json}").map_err(|e| anyhow!("cannot write to stdout: {e}"))
}
