//! `host-sim fit`: flags → `host_sim::calib::fit::FitOptions`, the fit, the model file and the
//! JSON summary (see `docs/reference/calibration-tools.md`).

use anyhow::{bail, Context, Result};
use host_sim::calib::fit::blunders::{
    check_options, BlunderReport, RejectOptions, DEFAULT_REJECT_SIGMA,
};
use host_sim::calib::fit::evaluate::{self, Criterion};
use host_sim::calib::fit::subset_search::{Progress, Stage};
use host_sim::calib::fit::{check_data, fit, params, FitOptions, FrameMode, Method, Points};
use host_sim::calib::CalibError;
use host_sim::io::measurement_csv::Measurement;
use host_sim::io::model_file::{model_file_text, ModelFile};
use host_sim::io::plot::{vector_plot_png, VectorField};
use host_sim::io::policy::CommandFiles;
use host_sim::io::KeyOrder;
use host_sim::machine_spec::MachineSpec;
use kinematics_core::FiveBar;
use std::path::PathBuf;

/// Which synthesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// Precision points, 2 per dyad (paper Sec. III-A).
    Poly,
    /// Least squares per dyad on the algebraic residual (paper Sec. III-B).
    Ls,
    /// Levenberg–Marquardt on the position residual over all identifiable parameters.
    Full,
}

/// Which position the model's prediction is compared with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CriterionArg {
    /// `FK(measured angles)` vs the measured position: the model's prediction error.
    Measured,
    /// `FK(measured angles)` vs the desired (target) position: the paper's measure.
    Paper,
}

/// Whether the instrument's frame is registered.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FrameArg {
    /// Estimate where the instrument stands (a rigid motion, any distance and angle) with the
    /// model; the model is in the machine frame, model.json keeps the frame for later readings.
    Register,
    /// The readings are in the machine frame already (an instrument referenced to the machine,
    /// as the paper's at Table I's point 1): used as they are.
    Machine,
}

/// Fit the hidden robot (five-bar) to measured motor angles and tool positions.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Measurement CSV (see measurement_csv): theta1_deg,theta2_deg,x_mm,y_mm[,x_target_mm,y_target_mm,...].
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, value_enum)]
    pub method: MethodArg,
    /// Try every subset of the points and keep the one with the smallest maximum error (poly, ls).
    #[arg(long)]
    pub subset_search: bool,
    /// Subset size for --subset-search (poly: 2; ls: default every size from 3 to N).
    #[arg(long)]
    pub subset_size: Option<usize>,
    /// Fit on these points only (1-based, comma separated), e.g. --points 1,8 (poly, ls).
    #[arg(long, value_delimiter = ',')]
    pub points: Vec<usize>,
    /// Error measure for the subset search and the reported max/rms: `measured` = FK(angles) vs
    /// measured position (the model's prediction error), `paper` = FK(angles) vs target.
    #[arg(long, value_enum, default_value = "measured")]
    pub criterion: CriterionArg,
    /// `full`: hold these parameters at nominal (names as in the summary, e.g. base_b0_x_mm).
    #[arg(long, value_delimiter = ',')]
    pub fix: Vec<String>,
    /// `full`: skip the leave-one-out prediction check (N extra fits).
    #[arg(long)]
    pub no_loo: bool,
    /// `full`: the blunder test's threshold k (σ units, default 4): rows whose leave-one-out
    /// residual exceeds max(k, √(2 ln(100 N))) σ are rejected, named, and the rest refitted;
    /// more than 10 % rejected refuses the fit. 0 fits every row. See
    /// docs/reference/calibration-tools.md "Blunders".
    #[arg(long)]
    pub reject_sigma: Option<f64>,
    /// The instrument's frame: `register` (where the tracker stands is estimated with the
    /// model) or `machine` (the readings are in the machine frame already).
    #[arg(long, value_enum, default_value = "register")]
    pub frame: FrameArg,
    /// Output model.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Optional PNG: error vectors (measured − predicted) of the nominal and the fitted model.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

/// The flags as the library's options, refusing combinations that make no fit (the messages
/// name the flags).
fn options(args: &Args, data: &[Measurement], spec: MachineSpec) -> Result<FitOptions> {
    let method = match args.method {
        MethodArg::Poly => Method::Poly,
        MethodArg::Ls => Method::Ls,
        MethodArg::Full => Method::Full,
    };
    let criterion = match args.criterion {
        CriterionArg::Measured => Criterion::Measured,
        CriterionArg::Paper => Criterion::Paper,
    };
    let n = data.len();
    for &p in &args.points {
        if p == 0 || p > n {
            bail!("--points: point {p} does not exist (the data have {n} points, numbered from 1)");
        }
    }
    let mut opts = FitOptions {
        method,
        criterion,
        points: Points::All,
        fixed: Vec::new(),
        leave_one_out: !args.no_loo,
        reject_sigma: 0.0,
        frame: match args.frame {
            FrameArg::Register => FrameMode::Register,
            FrameArg::Machine => FrameMode::Machine,
        },
        spec,
    };
    match method {
        Method::Poly | Method::Ls => {
            if !args.fix.is_empty() {
                bail!("--fix applies to --method full only (poly and ls fit the four links)");
            }
            if args.reject_sigma.is_some() {
                bail!(
                    "--reject-sigma applies to --method full only (poly and ls fit chosen points)"
                );
            }
            opts.points = if args.subset_search {
                let sizes: Vec<usize> = match (method, args.subset_size) {
                    (Method::Poly, None | Some(2)) => vec![2],
                    (Method::Poly, Some(s)) => {
                        bail!("--subset-size {s}: poly uses exactly 2 points")
                    }
                    (_, Some(s)) if s < 2 || s > n => {
                        bail!("--subset-size {s}: must be between 2 and the {n} points")
                    }
                    (_, Some(s)) => vec![s],
                    (_, None) if n < 3 => {
                        bail!("ls subset search needs at least 3 points, the data have {n}")
                    }
                    (_, None) => (3..=n).collect(),
                };
                Points::Search { sizes }
            } else if args.points.is_empty() {
                if method == Method::Poly && n != 2 {
                    bail!("poly uses exactly 2 precision points: give --points i,j or --subset-search (the data have {n} points)");
                }
                Points::All
            } else {
                if method == Method::Poly && args.points.len() != 2 {
                    bail!("poly uses exactly 2 precision points: give --points i,j or --subset-search (the data have {n} points)");
                }
                Points::Chosen(args.points.iter().map(|p| p - 1).collect())
            };
        }
        Method::Full => {
            if args.subset_search || !args.points.is_empty() || args.subset_size.is_some() {
                bail!("--subset-search, --subset-size and --points apply to poly and ls; full fits every point");
            }
            for name in &args.fix {
                let k = params::NAMES
                    .iter()
                    .position(|n| n == name)
                    .with_context(|| {
                        format!(
                            "--fix: unknown parameter '{name}' (known: {})",
                            params::NAMES.join(", ")
                        )
                    })?;
                if opts.fixed.contains(&k) {
                    bail!("--fix: '{name}' is given twice");
                }
                opts.fixed.push(k);
            }
            if opts.fixed.len() == params::NAMES.len() {
                bail!(
                    "--fix holds all {} parameters: nothing is left to fit",
                    params::NAMES.len()
                );
            }
            opts.reject_sigma = args.reject_sigma.unwrap_or(DEFAULT_REJECT_SIGMA);
            let reject = RejectOptions {
                reject_sigma: opts.reject_sigma,
                instrument_sigma_um: opts.spec.instrument_sigma_um,
            };
            check_options(&reject).map_err(|e| anyhow::anyhow!("--{e}"))?;
        }
    }
    Ok(opts)
}

/// The data checks, their messages naming the flag that asked for them.
fn check(data: &[Measurement], criterion: Criterion) -> Result<()> {
    match check_data(data, criterion) {
        Err(CalibError::MissingTargets { line }) => {
            bail!("line {line}: --criterion paper needs x_target_mm,y_target_mm on every row")
        }
        r => Ok(r?),
    }
}

/// The rejected rows as a table on stderr (nothing when none).
fn print_blunders(b: &BlunderReport) {
    if b.rejected.is_empty() {
        return;
    }
    eprintln!(
        "fit: blunder test rejected {} row(s) beyond {:.1} σ (σ = {:.2} µm) and refitted without them:",
        b.rejected.len(),
        b.threshold_sigma,
        b.sigma_um
    );
    eprintln!(
        "  {:>6} {:>6} {:>14} {:>10}",
        "row", "line", "residual_um", "sigma"
    );
    for r in &b.rejected {
        eprintln!(
            "  {:>6} {:>6} {:>14.1} {:>10.1}",
            r.row, r.line, r.residual_um, r.sigma_units
        );
    }
    if !b.settled {
        eprintln!("fit: blunder test: the rejected rows still changed after {} fits; the last fit stands (rows near the threshold)", b.fits);
    }
}

/// `host-sim fit`.
pub fn run(args: &Args) -> Result<()> {
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--data", &args.data)
        .output("--out", &args.out)
        .output("--plot", &args.plot)
        .check()?;
    let spec = args.machine.spec()?;
    let data = super::common_args::read_measurements(&args.machine, &spec, "--data", &args.data)?;
    let identity = spec.identity();
    let criterion = match args.criterion {
        CriterionArg::Measured => Criterion::Measured,
        CriterionArg::Paper => Criterion::Paper,
    };
    check(&data, criterion)?;
    let nominal = spec.nominal;
    let sigma_um = spec.instrument_sigma_um;
    let opts = options(args, &data, spec)?;
    // The search reports about once a second.
    let mut progress = |p: Progress| match p.stage {
        Stage::SubsetSearch => eprintln!(
            "subset search: {}/{} subsets, best max error so far {:.1} µm",
            p.tried, p.total, p.best_max_um
        ),
        Stage::LeaveOneOut => eprintln!("leave-one-out: {}/{} points refitted", p.tried, p.total),
    };
    let outcome = fit(&data, &opts, &mut progress)?;
    if let Some(s) = &outcome.search {
        eprintln!(
            "subset search: {} subsets tried ({} valid) in {:.2} s; best max error {:.1} µm",
            s.tried, s.valid, s.elapsed_s, s.best_max_um
        );
    }
    if let Some(f) = &outcome.full {
        for (k, why) in &f.identifiability.fixed {
            eprintln!(
                "fit: {} held at nominal: the data confound {why}",
                params::NAMES[*k]
            );
        }
    }
    if let Some(b) = &outcome.summary.blunders {
        print_blunders(b);
    }
    if let Some(l) = &outcome.summary.leave_one_out {
        if l.max_um.is_none() {
            eprintln!("fit: leave-one-out: no point could be predicted from the others (every fit on the rest failed: too few points)");
        } else if l.failed > 0 {
            eprintln!(
                "fit: leave-one-out: {} of {} points could not be predicted from the others",
                l.failed,
                l.per_point_um.len()
            );
        }
    }
    // Every output staged, then renamed together: a bad --plot path leaves no model.json.
    let mut file = ModelFile::from_model(&outcome.model);
    file.machine = Some(identity);
    file.std_dev = outcome.std_dev.clone();
    file.fit = Some(serde_json::to_value(&outcome.summary)?);
    file.instrument_frame = outcome.frame.map(|f| f.record());
    if let Some(f) = &outcome.frame {
        let t = f.to_instrument;
        eprintln!(
            "fit: instrument frame registered: rotation {:.6}°, offset ({:.4}, {:.4}) mm (the model is in the machine frame: A0 nominal, mean encoder offset nominal)",
            t.rotation_rad.to_degrees(),
            t.offset_mm[0],
            t.offset_mm[1]
        );
    }
    outputs.bytes(&args.out, model_file_text(&file)?.as_bytes())?;
    if let Some(plot) = &args.plot {
        // In the machine frame, where the model is.
        let data = outcome
            .frame
            .map_or_else(|| data.clone(), |f| f.register(&data));
        let base: Vec<[f64; 2]> = data.iter().map(|m| m.measured_mm).collect();
        let vecs = |m: &FiveBar<f64>| -> Vec<[f64; 2]> {
            evaluate::error_vectors_um(m, &data, Criterion::Measured)
                .into_iter()
                .map(|e| e.unwrap_or([f64::NAN; 2]))
                .collect()
        };
        let (before, after) = (vecs(&nominal), vecs(&outcome.model));
        let png = vector_plot_png(
            "measured − predicted",
            &[
                VectorField::new("nominal model", &base, &before),
                VectorField::new("fitted model", &base, &after),
            ],
            &[],
        )?;
        outputs.bytes(plot, &png)?;
    }
    outputs.commit()?;
    print_summary(&outcome.summary, sigma_um, &args.out);
    super::print_json(&outcome.summary, KeyOrder::Sorted)
}

/// The fit for a person, on stderr: the model and its errors, to what the instrument resolves.
fn print_summary(s: &host_sim::calib::fit::FitSummary, sigma_um: f64, out: &std::path::Path) {
    let p = super::um_decimals(sigma_um);
    let m = &s.model;
    eprintln!(
        "fit: {:?} on {} points: error max {:.p$} µm, RMS {:.p$} µm{}",
        s.method,
        s.n_points,
        s.max_err_um,
        s.rms_err_um,
        match s
            .leave_one_out
            .as_ref()
            .and_then(|l| l.max_um.zip(l.rms_um))
        {
            Some((max, rms)) => format!(
                "; predicting each point from the others max {max:.p$} µm, RMS {rms:.p$} µm"
            ),
            None => String::new(),
        }
    );
    eprintln!(
        "fit: a {:.4}  b {:.4}  c {:.4}  d {:.4} mm; A0 ({:.4}, {:.4}) mm, B0 − A0 ({:.4}, {:.4}) mm; encoder offsets ({:.5}, {:.5})° -> {}",
        m.a_mm,
        m.b_mm,
        m.c_mm,
        m.d_mm,
        m.base_a0_mm[0],
        m.base_a0_mm[1],
        m.base_b0_mm[0],
        m.base_b0_mm[1],
        m.encoder_offset_deg[0],
        m.encoder_offset_deg[1],
        out.display()
    );
}
