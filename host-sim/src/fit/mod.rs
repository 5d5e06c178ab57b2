//! `host-sim fit`: the hidden-robot fits of the paper (`poly`, `ls`, with its subset search) and
//! the full nonlinear fit (`full`). See `CALIBRATION.md` for the commands and the Table I story.
//!
//! One algorithm per file: [`poly`] (Eqs. 1–3), [`least_squares`] (Eqs. 4–6), [`subset_search`],
//! [`evaluate`] (the error criteria), [`params`], [`identifiability`], [`levenberg_marquardt`].
//! This file only wires them to the command line and writes the model and the JSON summary.

pub mod evaluate;
pub mod identifiability;
pub mod least_squares;
pub mod levenberg_marquardt;
pub mod params;
pub mod poly;
pub mod subset_search;

use crate::io::measurement_csv::{read_measurements, Measurement};
use crate::io::model_file::{write_model_file, ModelFile};
use crate::io::plot::{vector_plot, VectorField};
use anyhow::{bail, Context, Result};
use evaluate::Criterion;
use kinematics_core::FiveBar;
use poly::DyadPoint;
use serde_json::{json, Value};
use std::path::PathBuf;

/// Which synthesis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Precision points, 2 per dyad (paper Sec. III-A).
    Poly,
    /// Least squares per dyad on the algebraic residual (paper Sec. III-B).
    Ls,
    /// Levenberg–Marquardt on the position residual over all identifiable parameters.
    Full,
}

/// Fit the hidden robot (five-bar) to measured motor angles and tool positions.
#[derive(clap::Args, Debug)]
pub struct FitArgs {
    /// Measurement CSV (see measurement_csv): theta1_deg,theta2_deg,x_mm,y_mm[,x_target_mm,y_target_mm,...].
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long, value_enum)]
    pub method: Method,
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
    pub criterion: Criterion,
    /// `full`: hold these parameters at nominal (names as in the summary, e.g. base_b0_x_mm).
    #[arg(long, value_delimiter = ',')]
    pub fix: Vec<String>,
    /// `full`: skip the leave-one-out prediction check (N extra fits).
    #[arg(long)]
    pub no_loo: bool,
    /// Output model.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Optional PNG: error vectors (measured − predicted) of the nominal and the fitted model.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// The dyad observations of a subset: arm 1 about A0, arm 2 about B0, geometric angles.
fn dyad_points(data: &[Measurement], subset: &[usize], base: &FiveBar<f64>) -> (Vec<DyadPoint>, Vec<DyadPoint>) {
    let mut arm1 = Vec::with_capacity(subset.len());
    let mut arm2 = Vec::with_capacity(subset.len());
    for &i in subset {
        let m = &data[i];
        let th = m.theta_rad();
        let [x, y] = m.measured_mm;
        let a0 = base.base_a0_mm;
        arm1.push(DyadPoint { theta_rad: th[0] + base.encoder_offset_rad[0], x_mm: x - a0[0], y_mm: y - a0[1] });
        arm2.push(DyadPoint {
            theta_rad: th[1] + base.encoder_offset_rad[1],
            x_mm: x - a0[0] - base.base_b0_mm[0],
            y_mm: y - a0[1] - base.base_b0_mm[1],
        });
    }
    (arm1, arm2)
}

/// The paper's synthesis on the points `subset` (0-based): links a, b (arm 1) and d, c (arm 2);
/// base offset, encoder offsets and working mode are kept from `base`.
pub fn synthesize(data: &[Measurement], subset: &[usize], method: Method, base: &FiveBar<f64>) -> Result<FiveBar<f64>> {
    let (arm1, arm2) = dyad_points(data, subset, base);
    let ((a, b), (d, c)) = match method {
        Method::Poly => {
            if subset.len() != 2 {
                bail!("poly uses exactly 2 precision points, got {}", subset.len());
            }
            (
                poly::precision_point_dyad([arm1[0], arm1[1]]).context("arm 1 (a, b)")?,
                poly::precision_point_dyad([arm2[0], arm2[1]]).context("arm 2 (d, c)")?,
            )
        }
        Method::Ls => (
            least_squares::least_squares_dyad(&arm1).context("arm 1 (a, b)")?,
            least_squares::least_squares_dyad(&arm2).context("arm 2 (d, c)")?,
        ),
        Method::Full => bail!("synthesize: full is not a dyad synthesis"),
    };
    let m = FiveBar { a_mm: a, b_mm: b, c_mm: c, d_mm: d, ..*base };
    m.validate().map_err(|e| anyhow::anyhow!("fitted model invalid: {e}"))?;
    Ok(m)
}

/// Refuses two rows with the same motor angles (the same pose measured twice would weigh
/// double and, in a precision-point pair, make the system singular).
pub fn check_duplicates(data: &[Measurement]) -> Result<()> {
    for (i, m) in data.iter().enumerate() {
        for n in &data[..i] {
            if n.theta_deg == m.theta_deg && n.run == m.run {
                bail!("line {}: duplicate point, same motor angles as line {}", m.line, n.line);
            }
        }
    }
    Ok(())
}

fn round6(v: f64) -> f64 {
    (v * 1e6).round() / 1e6
}

fn summary_errors(model: &FiveBar<f64>, data: &[Measurement]) -> Value {
    let e = evaluate::errors_um(model, data, Criterion::Measured);
    let (max, rms) = evaluate::max_rms(&e);
    let mut v = json!({ "vs_measured": { "max_um": round6(max), "rms_um": round6(rms) } });
    if data.iter().all(|m| m.target_mm.is_some()) {
        let e = evaluate::errors_um(model, data, Criterion::Paper);
        let (max, rms) = evaluate::max_rms(&e);
        v["vs_target"] = json!({ "max_um": round6(max), "rms_um": round6(rms) });
    }
    v
}

/// The summary of a fitted model (also stored as the model file's `fit` record).
fn summary(method: Method, criterion: Criterion, model: &FiveBar<f64>, data: &[Measurement], subset: Option<&[usize]>) -> Value {
    let errors = evaluate::errors_um(model, data, criterion);
    let (max, rms) = evaluate::max_rms(&errors);
    json!({
        "method": format!("{method:?}").to_lowercase(),
        "criterion": criterion,
        "n_points": data.len(),
        "a_mm": round6(model.a_mm),
        "b_mm": round6(model.b_mm),
        "c_mm": round6(model.c_mm),
        "d_mm": round6(model.d_mm),
        "base_a0_mm": [round6(model.base_a0_mm[0]), round6(model.base_a0_mm[1])],
        "base_b0_mm": [round6(model.base_b0_mm[0]), round6(model.base_b0_mm[1])],
        "encoder_offset_deg": [round6(model.encoder_offset_rad[0].to_degrees()), round6(model.encoder_offset_rad[1].to_degrees())],
        "subset": subset.map(|s| s.iter().map(|i| i + 1).collect::<Vec<_>>()),
        "max_err_um": round6(max),
        "rms_err_um": round6(rms),
        "point_err_um": errors.iter().map(|&e| (e * 10.0).round() / 10.0).collect::<Vec<_>>(),
        "errors": summary_errors(model, data),
    })
}

/// Runs a fit and returns the fitted model, the JSON summary and the std-dev map for the file.
pub fn fit(args: &FitArgs, data: &[Measurement]) -> Result<(FiveBar<f64>, Value, std::collections::BTreeMap<String, f64>)> {
    evaluate::check_criterion(data, args.criterion)?;
    check_duplicates(data)?;
    let nominal = FiveBar::<f64>::paper_nominal();
    let n = data.len();
    let mut std_map = std::collections::BTreeMap::new();
    for &p in &args.points {
        if p == 0 || p > n {
            bail!("--points: point {p} does not exist (the data have {n} points, numbered from 1)");
        }
    }
    match args.method {
        Method::Poly | Method::Ls => {
            if !args.fix.is_empty() {
                bail!("--fix applies to --method full only (poly and ls fit the four links)");
            }
            let (model, subset) = if args.subset_search {
                let sizes: Vec<usize> = match (args.method, args.subset_size) {
                    (Method::Poly, None | Some(2)) => vec![2],
                    (Method::Poly, Some(s)) => bail!("--subset-size {s}: poly uses exactly 2 points"),
                    (_, Some(s)) if s < 2 || s > n => bail!("--subset-size {s}: must be between 2 and the {n} points"),
                    (_, Some(s)) => vec![s],
                    (_, None) if n < 3 => bail!("ls subset search needs at least 3 points, the data have {n}"),
                    (_, None) => (3..=n).collect(),
                };
                if n < 2 {
                    bail!("the data have {n} point; a fit needs at least 2");
                }
                let best = subset_search::search(
                    n,
                    &sizes,
                    |s| synthesize(data, s, args.method, &nominal),
                    |m| evaluate::errors_um(m, data, args.criterion),
                )?;
                (best.model, Some(best.subset))
            } else {
                let subset: Vec<usize> = if args.points.is_empty() { (0..n).collect() } else { args.points.iter().map(|p| p - 1).collect() };
                if args.method == Method::Poly && subset.len() != 2 {
                    bail!("poly uses exactly 2 precision points: give --points i,j or --subset-search (the data have {n} points)");
                }
                if subset.len() < 2 {
                    bail!("a dyad fit needs at least 2 points, got {}", subset.len());
                }
                let m = synthesize(data, &subset, args.method, &nominal)?;
                (m, (!args.points.is_empty()).then_some(subset))
            };
            let mut s = summary(args.method, args.criterion, &model, data, subset.as_deref());
            if args.method == Method::Ls && subset.is_none() && n >= 3 {
                // Leave-one-out of the all-points least-squares fit.
                let loo: Vec<Option<f64>> = (0..n)
                    .map(|i| {
                        let rest: Vec<usize> = (0..n).filter(|&k| k != i).collect();
                        let m = synthesize(data, &rest, Method::Ls, &nominal).ok()?;
                        Some(evaluate::errors_um(&m, &data[i..=i], Criterion::Measured)[0])
                    })
                    .collect();
                s["leave_one_out"] = loo_json(&loo);
            }
            Ok((model, s, std_map))
        }
        Method::Full => {
            if args.subset_search || !args.points.is_empty() || args.subset_size.is_some() {
                bail!("--subset-search, --subset-size and --points apply to poly and ls; full fits every point");
            }
            let mut fixed = Vec::new();
            for name in &args.fix {
                let k = params::NAMES.iter().position(|n| n == name).with_context(|| {
                    format!("--fix: unknown parameter '{name}' (known: {})", params::NAMES.join(", "))
                })?;
                fixed.push(k);
            }
            let f = levenberg_marquardt::fit_full(data, &nominal, &fixed)?;
            let mut s = summary(args.method, args.criterion, &f.model, data, None);
            let mut sd = serde_json::Map::new();
            for (k, v) in f.std_dev.iter().enumerate() {
                if let Some(v) = v {
                    let (name, val) = file_name_value(k, *v);
                    sd.insert(name.clone(), json!(round6(val)));
                    std_map.insert(name, val);
                }
            }
            s["std_dev"] = Value::Object(sd);
            s["fixed"] = f
                .identifiability
                .fixed
                .iter()
                .map(|(k, why)| json!({ "param": params::NAMES[*k], "held_at": "nominal", "confounded": why }))
                .chain(fixed.iter().map(|&k| json!({ "param": params::NAMES[k], "held_at": "nominal", "confounded": "fixed by --fix" })))
                .collect::<Vec<_>>()
                .into();
            s["identifiability"] = json!({
                "rank_all_params": f.identifiability.rank_all,
                "condition_number_free": f.identifiability.condition_number,
                "singular_values_rel": f.identifiability.singular_values_rel,
                "poorly_conditioned": f.identifiability.condition_number > identifiability::WARN_CONDITION,
            });
            s["sigma_um"] = json!(round6(f.sigma_mm * 1e3));
            s["iterations"] = json!(f.iterations);
            for (k, why) in &f.identifiability.fixed {
                eprintln!("fit: {} held at nominal: the data confound {why}", params::NAMES[*k]);
            }
            if !args.no_loo {
                s["leave_one_out"] = loo_json(&levenberg_marquardt::leave_one_out_um(data, &nominal, &fixed));
            }
            Ok((f.model, s, std_map))
        }
    }
}

/// Std-dev name and value as in model.json (offsets in degrees).
fn file_name_value(k: usize, v: f64) -> (String, f64) {
    match params::NAMES[k].strip_suffix("_rad") {
        Some(stem) => (format!("{stem}_deg"), v.to_degrees()),
        None => (params::NAMES[k].to_string(), v),
    }
}

fn loo_json(loo: &[Option<f64>]) -> Value {
    let ok: Vec<f64> = loo.iter().flatten().copied().collect();
    let (max, rms) = evaluate::max_rms(&ok);
    json!({
        "what": "each point predicted by a fit on the other points: |FK(angles) - measured|",
        "max_um": round6(max),
        "rms_um": round6(rms),
        "per_point_um": loo.iter().map(|e| e.map(|v| (v * 10.0).round() / 10.0)).collect::<Vec<_>>(),
    })
}

/// `host-sim fit`.
pub fn run(args: &FitArgs) -> Result<()> {
    let data = read_measurements(&args.data)?;
    let (model, summary, std_dev) = fit(args, &data)?;
    if let Some(plot) = &args.plot {
        let base: Vec<[f64; 2]> = data.iter().map(|m| m.measured_mm).collect();
        let nominal = FiveBar::<f64>::paper_nominal();
        let vecs = |m: &FiveBar<f64>| -> Vec<[f64; 2]> {
            evaluate::error_vectors_um(m, &data, Criterion::Measured).into_iter().map(|e| e.unwrap_or([f64::NAN; 2])).collect()
        };
        let (before, after) = (vecs(&nominal), vecs(&model));
        vector_plot(
            plot,
            "measured − predicted",
            &[
                VectorField { label: "nominal model", base_mm: &base, error_um: &before },
                VectorField { label: "fitted model", base_mm: &base, error_um: &after },
            ],
        )?;
    }
    let mut file = ModelFile::from_model(&model);
    file.std_dev = std_dev;
    file.fit = Some(summary.clone());
    write_model_file(&args.out, &file)?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}
