//! `host-sim session`: a measurement session through a controller you started (QEMU on a TCP
//! socket, the real board on a serial port): a plan's list visited with its approach, each
//! point settled and read (`host_sim::session`). Writes the measurement CSV (`--out`) and, with
//! `--angles-out`, the angles the machine held per point, which `import --commanded` joins with
//! a tracker's export (`--instrument export`: the readings come from the tracker afterwards).
//! The files are written only once the whole list is done.

use super::MachineArg;
use anyhow::{bail, Context, Result};
use host_sim::calib::plan::visits_from_rows;
use host_sim::io::commanded_csv::format_commanded;
use host_sim::io::measurement_csv::format_measurements;
use host_sim::io::policy::CommandFiles;
use host_sim::io::targets_csv::read_target_list;
use host_sim::io::KeyOrder;
use host_sim::link::LinkClient;
use host_sim::session::instrument::{Deferred, Instrument, TypedIn};
use host_sim::session::link_rig::LinkRig;
use host_sim::session::{run as run_session, Rig, SessionOptions, SessionResult};
use std::io::{Read, Write};
use std::path::PathBuf;
use std::time::Duration;

/// Where the instrument's readings come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum InstrumentArg {
    /// Typed in at each point (stdin): `x y` in mm, an empty line when not seen.
    Typed,
    /// From the tracker's export afterwards: the session writes the angles (--angles-out), and
    /// `host-sim import --commanded ANGLES` joins them with the export.
    Export,
}

/// A measurement session through the controller.
#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("transport").required(true).args(["tcp", "serial"])))]
pub struct Args {
    #[command(flatten)]
    pub link: super::link_args::LinkArgs,
    /// Seconds to wait for each reply.
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
    /// The plan's list to visit (`host-sim plan`: identify.csv, grid.csv, verify.csv, ...).
    #[arg(long, value_name = "FILE")]
    pub targets: PathBuf,
    /// Where the readings come from.
    #[arg(long, value_enum, default_value = "typed")]
    pub instrument: InstrumentArg,
    /// The measurement CSV (with --instrument typed).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// The angles the machine held at each point (encoder, degrees), with the target, the
    /// directions and the run: the commanded list `import --commanded` reads.
    #[arg(long, value_name = "FILE")]
    pub angles_out: Option<PathBuf>,
    /// The settle criterion: largest following error (µrad).
    #[arg(long, default_value_t = 2.0)]
    pub settle_following_error_urad: f64,
    /// The settle criterion: how long it must hold (s).
    #[arg(long, default_value_t = 0.1)]
    pub settle_dwell_s: f64,
    #[command(flatten)]
    pub machine: MachineArg,
}

/// The files and the report of a session.
fn write(
    args: &Args,
    result: &SessionResult,
    mut outputs: host_sim::io::atomic::Outputs,
) -> Result<()> {
    if let Some(out) = &args.out {
        if result.measurements.is_empty() {
            bail!("no point was read: nothing to write to {}", out.display());
        }
        outputs.bytes(out, format_measurements(&result.measurements).as_bytes())?;
    }
    if let Some(a) = &args.angles_out {
        outputs.bytes(a, format_commanded(&result.commanded).as_bytes())?;
    }
    outputs.commit()?;
    Ok(())
}

fn session<S: Read + Write>(
    client: &mut LinkClient<S>,
    args: &Args,
    opts: &SessionOptions,
    visits: &[host_sim::calib::protocol::Visit],
) -> Result<SessionResult> {
    let mut typed;
    let mut deferred = Deferred;
    let instrument: &mut dyn Instrument = match args.instrument {
        InstrumentArg::Typed => {
            typed = TypedIn::new(std::io::stdin().lock(), std::io::stderr());
            &mut typed
        }
        InstrumentArg::Export => &mut deferred,
    };
    let mut rig = LinkRig::new(client, instrument, opts.spec.sample_period_s);
    let mut last = std::time::Instant::now();
    let result = run_session(&mut rig, visits, opts, &mut |done, total| {
        if last.elapsed() > Duration::from_secs(1) || done == total {
            last = std::time::Instant::now();
            eprintln!("session: {done}/{total} points");
        }
    });
    if result.is_err() {
        // Leave the controller quiet: telemetry off (the error is the session's).
        let _ = rig.finish();
    }
    Ok(result?)
}

/// `host-sim session`.
pub fn run(args: &Args) -> Result<()> {
    let timeout = super::link_args::reply_timeout(args.timeout_s)?;
    match (args.instrument, &args.out, &args.angles_out) {
        (InstrumentArg::Typed, None, _) => bail!("give --out FILE for the measurement CSV"),
        (InstrumentArg::Export, _, None) => bail!(
            "--instrument export needs --angles-out FILE: the angles import joins with the tracker's export"
        ),
        (InstrumentArg::Export, Some(_), _) => {
            bail!("--instrument export reads nothing now: give --angles-out, not --out")
        }
        _ => {}
    }
    let outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--targets", &args.targets)
        .output("--out", &args.out)
        .output("--angles-out", &args.angles_out)
        .check()?;
    let spec = args.machine.spec()?;
    let visits = visits_from_rows(&read_target_list(&args.targets)?, &spec);
    let mut opts = SessionOptions::for_machine(&spec);
    opts.settle.following_error_rad = args.settle_following_error_urad * 1e-6;
    opts.settle.dwell_s = args.settle_dwell_s;
    let result = args
        .link
        .open(timeout)
        .and_then(|(_, mut client)| session(&mut client, args, &opts, &visits))
        .with_context(|| format!("measuring {} (nothing written)", args.targets.display()))?;
    write(args, &result, outputs)?;
    let r = &result.report;
    eprintln!(
        "session: {} points, {} read{}; settled in {:.3} s at most ({:.3} s mean), following error ≤ {:.2} µrad",
        r.points,
        r.read,
        if r.missing.is_empty() {
            String::new()
        } else {
            format!(", not seen: {}", r.missing.join(" "))
        },
        r.settle_s_max,
        r.settle_s_mean,
        r.following_error_urad_max
    );
    if r.deferred {
        eprintln!(
            "session: join the tracker's export with the angles: host-sim import --export FILE --map ... --commanded {} --plan {} --out M.csv",
            args.angles_out.as_ref().map_or(String::new(), |p| p.display().to_string()),
            args.targets.display()
        );
    }
    super::print_json(r, KeyOrder::Declared)
}
