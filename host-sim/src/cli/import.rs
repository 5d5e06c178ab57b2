//! `host-sim import`: a laser tracker's (or interferometer's) point export joined by point id
//! with the session's commanded list, written as the measurement CSV (`host_sim::calib::import`;
//! the export's reader `host_sim::io::tracker_export`). Notes and warnings on stderr, the report
//! as JSON on stdout (and `--report FILE`).

use anyhow::{bail, Context, Result};
use host_sim::calib::import::{import, ImportOptions, Missing, Unlisted};
use host_sim::io::commanded_csv::read_commanded;
use host_sim::io::measurement_csv::format_measurements_of;
use host_sim::io::policy::CommandFiles;
use host_sim::io::targets_csv::read_target_list;
use host_sim::io::tracker_export::{read_export, ColumnMap, ExportFormat, LengthUnit};
use host_sim::io::{json_text, KeyOrder};
use std::path::PathBuf;

/// The export's coordinate unit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum UnitArg {
    Mm,
    M,
    /// Micrometres.
    Um,
}

/// Arguments of `host-sim import`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The instrument's export: one row per measured point, the vendor's columns, `,` `;` or
    /// tab separated, metadata lines before the header allowed.
    #[arg(long, value_name = "FILE")]
    pub export: PathBuf,
    /// Which export column is what: `id=COLUMN,x=COLUMN,y=COLUMN[,z=COLUMN]`, names exactly as
    /// in the header (e.g. `id=Point,x=X [mm],y=Y [mm],z=Z [mm]`).
    #[arg(long, value_name = "MAP")]
    pub map: String,
    /// The commanded list of the session, in the order it was measured: `command`'s output
    /// (x_mm,y_mm,theta1_deg,theta2_deg[,dir1,dir2]) or a log in those columns. Row k is point
    /// number k (see --first-id).
    #[arg(long, value_name = "FILE")]
    pub commanded: PathBuf,
    /// The plan's list the angles were commanded for (`plan`'s identify/grid/verify/repeat.csv):
    /// its run and dir columns are carried into the output (`command` does not write them).
    #[arg(long, value_name = "FILE")]
    pub plan: Option<PathBuf>,
    /// The export's unit (default: from the mapped columns' headers, e.g. `X [m]`, `X [µm]`;
    /// when they say none, mm if the points' spread fits --machine's workspace, else refused
    /// with the evidence).
    #[arg(long, value_enum)]
    pub units: Option<UnitArg>,
    /// The export writes numbers with a decimal comma (`212,132`; its delimiter `;` or tab).
    #[arg(long)]
    pub decimal_comma: bool,
    /// The prefix of the session's point ids (e.g. `P`); other points (reference nests) are
    /// skipped with a note. Default: every id's, which must be one.
    #[arg(long, value_name = "TEXT")]
    pub id_prefix: Option<String>,
    /// The point number of the commanded list's first row.
    #[arg(long, default_value_t = 1)]
    pub first_id: u64,
    /// Skip export points whose number is no row of the list (default: an error).
    #[arg(long)]
    pub skip_unlisted: bool,
    /// Refuse an export that misses a row of the list (default: a note, the row not written).
    #[arg(long)]
    pub require_all: bool,
    /// Refuse a point whose Z is further than this from the points' best-fit plane (mm; needs
    /// z= in --map). Default: Z reported only.
    #[arg(long, value_name = "MM")]
    pub z_tolerance_mm: Option<f64>,
    /// Output measurement CSV (`fit`, `grid`, `accuracy`, `verify` read it).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the report (JSON) to this file.
    #[arg(long, value_name = "FILE")]
    pub report: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// `host-sim import`.
pub fn run(args: &Args) -> Result<()> {
    // The measurement CSV and the report together, or neither; never over an input.
    let mut out = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--export", &args.export)
        .input("--commanded", &args.commanded)
        .input("--plan", &args.plan)
        .output("--out", &args.out)
        .output("--report", &args.report)
        .check()?;
    let map = ColumnMap::parse(&args.map).context("--map")?;
    if let Some(t) = args.z_tolerance_mm {
        if !(t > 0.0 && t.is_finite()) {
            bail!("--z-tolerance-mm must be a positive number of mm, not {t}");
        }
        if map.z.is_none() {
            bail!("--z-tolerance-mm needs a z column in --map (z=COLUMN)");
        }
    }
    let unit = args.units.map(|u| match u {
        UnitArg::Mm => LengthUnit::Mm,
        UnitArg::M => LengthUnit::M,
        UnitArg::Um => LengthUnit::Um,
    });
    let spec = args.machine.spec()?;
    let (wx, wy) = (spec.workspace.x_mm, spec.workspace.y_mm);
    let format = ExportFormat {
        unit,
        decimal_comma: args.decimal_comma,
        workspace_extent_mm: Some((wx[1] - wx[0]).hypot(wy[1] - wy[0])),
    };
    let export = read_export(&args.export, &map, format)?;
    let commanded = read_commanded(&args.commanded)?;
    let plan = args.plan.as_deref().map(read_target_list).transpose()?;
    let opts = ImportOptions {
        id_prefix: args.id_prefix.clone(),
        first_id: args.first_id,
        unlisted: if args.skip_unlisted {
            Unlisted::Skip
        } else {
            Unlisted::Refuse
        },
        missing: if args.require_all {
            Missing::Refuse
        } else {
            Missing::Note
        },
        z_tolerance_mm: args.z_tolerance_mm,
    };
    let imported = import(&export, &commanded, plan.as_deref(), &opts).with_context(|| {
        format!(
            "importing {} with {}",
            args.export.display(),
            args.commanded.display()
        )
    })?;
    let report = &imported.report;
    let text = json_text(report, KeyOrder::Sorted)?;
    out.bytes(
        &args.out,
        format_measurements_of(&imported.rows, &spec.identity()).as_bytes(),
    )?;
    if let Some(p) = &args.report {
        out.bytes(p, text.as_bytes())?;
    }
    out.commit()?;
    for n in &report.notes {
        eprintln!("import: note: {n}");
    }
    for w in &report.warnings {
        eprintln!("import: warning: {w}");
    }
    eprintln!(
        "import: {} measurements ({} of {} list rows) -> {}",
        report.imported,
        report.rows_measured,
        report.list_rows,
        args.out.display()
    );
    super::print_json(report, KeyOrder::Sorted)
}
