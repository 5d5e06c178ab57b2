//! `host-sim diagnose`: find where the model and the measurements disagree, name the missing
//! effect, add it to the model and show the gap shrink (issue 7).
//!
//! ```text
//! host-sim diagnose --data M.csv [--model model.json] [--noise-um N] --out report.json [--plots DIR]
//! ```
//!
//! Pipeline: residuals of the current model ([`effects`]) → stepwise selection over the effect
//! library with a BIC score ([`selection`], fits by [`lm`]) → confounding of the chosen effects
//! with the other candidates ([`confounding`]) → structure of what is left ([`structure`]) →
//! report and table ([`report`]) and plots. [`diagnose`] is the whole analysis on in-memory
//! measurements, so the tests (and later `host-sim measure` plants) call it directly.
//!
//! Noise σ: `--noise-um` if given, else estimated from repeated poses (same angles and
//! directions, e.g. several `run`s), else unknown — then scores compare against the residual
//! variance only and "unexplained" rests on the structure tests.
//!
//! Cost: a few dozen LM fits of ≤ 18 parameters; about a second for 650 points (dev profile).

pub mod confounding;
pub mod effects;
pub mod lm;
pub mod report;
pub mod selection;
pub mod structure;
pub mod synth;

use crate::io::measurement_csv::{read_measurements, Measurement};
use crate::io::model_file::read_model;
use crate::io::atomic::write_atomic;
use crate::io::plot::{vector_plot, xy_plot, Mark, Series, VectorField};
use anyhow::{bail, Context, Result};
use effects::{rms_max_um, Effect, Problem, LIBRARY, N_PARAMS, PARAM_NAMES};
use kinematics_core::FiveBar;
use lm::Fit;
use report::{Param, Report, Step};
use selection::Fitter;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

/// Command-line arguments of `host-sim diagnose`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Measurement CSV (see measurement_csv).
    #[arg(long)]
    pub data: PathBuf,
    /// The current model (model.json); default: the paper's nominal machine.
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
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let data = read_measurements(&args.data)?;
    let base = match &args.model {
        Some(p) => read_model(p)?,
        None => FiveBar::paper_nominal(),
    };
    if let Some(s) = args.noise_um {
        if !(s.is_finite() && s > 0.0) {
            bail!("--noise-um {s}: must be a positive number of micrometres");
        }
    }
    let (report, history) = diagnose_with_history(&data, &base, args.noise_um)
        .with_context(|| format!("diagnosing {}", args.data.display()))?;
    print!("{}", report::table(&report));
    let mut text = serde_json::to_string_pretty(&report)?;
    text.push('\n');
    write_atomic(&args.out, text.as_bytes())?;
    if let Some(dir) = &args.plots {
        plots(dir, &data, &base, &report, &history)?;
    }
    Ok(())
}

/// Residual fields of the start and after each step, for the plots.
pub struct History {
    pub base_mm: Vec<[f64; 2]>,
    /// (label, residual µm per point): "start", then one per step.
    pub fields: Vec<(String, Vec<[f64; 2]>)>,
    pub problem: Problem,
}

/// The whole analysis on in-memory measurements with the given base model.
pub fn diagnose(data: &[Measurement], base: &FiveBar<f64>, noise_um: Option<f64>) -> Result<Report> {
    diagnose_with_history(data, base, noise_um).map(|(r, _)| r)
}

/// Pooled standard deviation per axis over groups of repeated poses (same angles to 1e-6° and
/// same directions); `None` without at least 3 degrees of freedom.
pub fn noise_from_repeats_um(data: &[Measurement]) -> Option<(f64, usize)> {
    let mut groups: HashMap<(i64, i64, i8, i8), Vec<[f64; 2]>> = HashMap::new();
    for m in data {
        let key = (
            (m.theta_deg[0] * 1e6).round() as i64,
            (m.theta_deg[1] * 1e6).round() as i64,
            m.dir.map(|d| d[0]).unwrap_or(0),
            m.dir.map(|d| d[1]).unwrap_or(0),
        );
        groups.entry(key).or_default().push(m.measured_mm);
    }
    let (mut ss, mut dof) = (0.0, 0usize);
    for g in groups.values().filter(|g| g.len() >= 2) {
        for axis in 0..2 {
            let mean = g.iter().map(|p| p[axis]).sum::<f64>() / g.len() as f64;
            ss += g.iter().map(|p| (p[axis] - mean).powi(2)).sum::<f64>();
        }
        dof += 2 * (g.len() - 1);
    }
    (dof >= 3).then(|| ((ss / dof as f64).sqrt() * 1e3, dof))
}

fn params_of(fit: &Fit, effects: &[&'static Effect], s2: f64) -> BTreeMap<String, Param> {
    let mut out = BTreeMap::new();
    for e in effects {
        for &k in e.params {
            let col = fit.free.iter().position(|&f| f == k);
            let sd = col.map(|c| (fit.normal_pinv[(c, c)] * s2).max(0.0).sqrt()).unwrap_or(f64::NAN);
            out.insert(PARAM_NAMES[k].to_string(), Param { value: fit.p[k], std_dev: sd });
        }
    }
    out
}

fn pairs(r: &[f64]) -> Vec<[f64; 2]> {
    r.chunks(2).map(|c| [c[0], c[1]]).collect()
}

/// [`diagnose`], also returning the residual fields for plotting.
pub fn diagnose_with_history(
    data: &[Measurement],
    base: &FiveBar<f64>,
    noise_um_arg: Option<f64>,
) -> Result<(Report, History)> {
    let problem = Problem::new(*base, data);
    let mut notes = Vec::new();
    if !problem.dropped_lines.is_empty() {
        notes.push(format!(
            "{} point(s) have no forward solution with the base model, or are at a singularity, and are excluded: lines {:?}",
            problem.dropped_lines.len(),
            problem.dropped_lines
        ));
    }
    if problem.points.len() < 3 {
        bail!("only {} usable point(s): the diagnosis needs at least 3", problem.points.len());
    }
    let (noise_um, noise_source) = match noise_um_arg {
        Some(s) => (Some(s), "given (--noise-um)".to_string()),
        None => match noise_from_repeats_um(data) {
            Some((s, dof)) => (Some(s), format!("estimated from repeated poses ({dof} degrees of freedom)")),
            None => (None, "unknown: no --noise-um and no repeated poses".to_string()),
        },
    };
    let n = (2 * problem.points.len()) as f64;
    let sel = selection::select(&problem, noise_um);
    notes.extend(sel.skipped.iter().cloned());
    // Cumulative fits in the order the final effects were added: the gap-shrink table.
    let mut fitter = Fitter::new(&problem);
    let zero = [0.0; N_PARAMS];
    let start = fitter.fit(&[], &zero).context("the base model has no forward solution")?;
    let (initial_rms_um, initial_max_um) = rms_max_um(&start.residuals.as_slice());
    let base_mm: Vec<[f64; 2]> = problem.points.iter().map(|p| p.measured_mm).collect();
    let mut fields = vec![("start".to_string(), pairs(&start.residuals.as_slice()))];
    let mut steps = Vec::new();
    let mut prev = start.clone();
    let mut last = start.clone();
    for k in 0..sel.effects.len() {
        let set = &sel.effects[..=k];
        let f = fitter.fit(set, &sel.fit.p).with_context(|| format!("refitting step {}", k + 1))?;
        let s2 = (f.cost / (n - f.free.len() as f64).max(1.0)).max(noise_um.map(|s| s * s).unwrap_or(0.0));
        let (rb, mb) = rms_max_um(&prev.residuals.as_slice());
        let (ra, ma) = rms_max_um(&f.residuals.as_slice());
        steps.push(Step {
            effect: set[k].name.to_string(),
            params: params_of(&f, &set[k..=k], s2),
            rms_before_um: rb,
            rms_after_um: ra,
            max_before_um: mb,
            max_after_um: ma,
        });
        fields.push((format!("after {}", set[k].name), pairs(&f.residuals.as_slice())));
        prev = f.clone();
        last = f;
    }
    let k_final = last.free.len() as f64;
    let dof = (n - k_final).max(1.0);
    let s2_final = (last.cost / dof).max(noise_um.map(|s| s * s).unwrap_or(0.0));
    let final_params = params_of(&last, &sel.effects, s2_final);
    let (final_rms_um, final_max_um) = rms_max_um(&last.residuals.as_slice());
    // Confounding with every available candidate.
    let candidates: Vec<&'static Effect> = LIBRARY.iter().filter(|e| problem.available(e).is_ok()).collect();
    let overlaps = confounding::overlaps(&problem, &last, &sel.effects, &candidates, s2_final);
    let confounded = confounding::confounded(&overlaps);
    let pose_overlaps = confounding::pose_set_overlaps(&problem, &last.p, &candidates, 0.99);
    // What the data cannot rule out: every candidate left out, fitted on top of the final model.
    let mut not_detected = Vec::new();
    for &c in candidates.iter().filter(|c| !sel.effects.contains(c)) {
        let mut set = sel.effects.clone();
        set.push(c);
        if set.iter().map(|e| e.params.len()).sum::<usize>() as f64 >= n {
            continue;
        }
        if let Some(f) = fitter.fit(&set, &last.p) {
            let s2 = (f.cost / (n - f.free.len() as f64).max(1.0)).max(noise_um.map(|s| s * s).unwrap_or(0.0));
            // Column-normalised Jacobian singular below 1e-6: some direction of the candidate is
            // exactly what the final model already does (no bound exists).
            let identifiable = f.svd.min() > 1e-6;
            let mut params = params_of(&f, &[c], s2);
            if !identifiable {
                params.values_mut().for_each(|p| p.std_dev = f64::INFINITY);
            }
            not_detected.push(report::NotDetected {
                effect: c.name.to_string(),
                identifiable,
                params,
                delta_bic: selection::delta_bic(&problem, noise_um, &last, &f),
            });
        }
    }
    // Is anything left above the noise, and what does it look like?
    let initial_structure = structure::analyse(&problem, data, &start.residuals.as_slice());
    let final_structure = structure::analyse(&problem, data, &last.residuals.as_slice());
    let significant: Vec<&structure::Finding> = final_structure.iter().filter(|f| f.significant).collect();
    let chi2_per_dof = noise_um.map(|s| last.cost / dof / (s * s));
    let (unexplained, mut unexplained_description) = match chi2_per_dof {
        Some(c) => {
            // χ² test at ~4σ of the χ² distribution, and a practical floor of 10 % over the noise
            // (a slightly misjudged noise figure must not read as a missing effect).
            let limit = (1.0 + 4.0 * (2.0 / dof).sqrt()).max(1.21);
            if c > limit {
                (true, format!("residual is {:.2}× the noise variance (limit {:.2}) and no further library effect is significant", c, limit))
            } else {
                (false, format!("residual at the noise level (χ²/dof {:.2} ≤ {:.2})", c, limit))
            }
        }
        None if final_structure.iter().any(|f| f.kind == "too_few_points") => (
            false,
            "UNDECIDED: noise unknown (no --noise-um, no repeats) and too few points to test the residual's structure; \
             give --noise-um to decide"
                .to_string(),
        ),
        None => {
            if significant.is_empty() {
                (false, "noise unknown; no significant structure left in the residual".to_string())
            } else {
                (true, "noise unknown; the residual has significant structure no library effect explains".to_string())
            }
        }
    };
    if !significant.is_empty() {
        let d: Vec<String> = significant.iter().map(|f| format!("[{}] {}", f.kind, f.description)).collect();
        unexplained_description.push_str(&format!(". Structure of the residual: {}", d.join("; ")));
    } else if unexplained && final_structure.iter().any(|f| f.kind == "too_few_points") {
        unexplained_description.push_str(&format!(
            ". Too few points ({}) to describe its structure; largest radial residuals: {}",
            problem.points.len(),
            largest_points(data, &problem, &last.residuals.as_slice())
        ));
    } else if unexplained {
        unexplained_description.push_str(&format!(
            ". No test found a structure (not periodic in a motor angle, not direction-dependent, no drift, not smooth over \
             the workspace): looks like extra noise or isolated outliers; largest radial residuals: {}",
            largest_points(data, &problem, &last.residuals.as_slice())
        ));
    }
    let score = format!(
        "BIC = RSS/σ² + k·ln n (n = {} residuals), σ² = max(noise², smaller residual variance of the two models compared); \
         add if ΔBIC < −{}, remove if ΔBIC < 0, swap if ΔBIC < −{}",
        n,
        selection::ADD_MARGIN,
        selection::SWAP_MARGIN
    );
    let report = Report {
        points: problem.points.len(),
        dropped_lines: problem.dropped_lines.clone(),
        noise_um,
        noise_source,
        score,
        initial_rms_um,
        initial_max_um,
        steps,
        final_params,
        confounded,
        overlaps,
        not_detected,
        pose_overlaps,
        unexplained,
        unexplained_description,
        final_structure,
        initial_structure,
        final_rms_um,
        final_max_um,
        chi2_per_dof,
        selection_log: sel.log,
        notes,
    };
    Ok((report, History { base_mm, fields, problem }))
}

/// The three largest radial residuals, with their file line (or index) and position.
fn largest_points(data: &[Measurement], problem: &Problem, residual_um: &[f64]) -> String {
    let kept: Vec<&Measurement> = problem.points.iter().filter_map(|p| data.get(p.index)).collect();
    let mut idx: Vec<usize> = (0..problem.points.len()).collect();
    let mag = |i: usize| residual_um[2 * i].hypot(residual_um[2 * i + 1]);
    idx.sort_by(|&a, &b| mag(b).total_cmp(&mag(a)));
    idx.iter()
        .take(3)
        .map(|&i| {
            let p = problem.points[i].measured_mm;
            let line = kept.get(i).map(|m| m.line).unwrap_or(0);
            format!("{:.0} µm at line {line} ({:.1}, {:.1}) mm", mag(i), p[0], p[1])
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Residual plots: the field before/after each step (one scale per step), and the final
/// residual against configuration and time.
fn plots(dir: &Path, data: &[Measurement], _base: &FiveBar<f64>, report: &Report, h: &History) -> Result<()> {
    vector_plot(
        &dir.join("residual_start.png"),
        "residual of the starting model",
        &[VectorField { label: "start", base_mm: &h.base_mm, error_um: &h.fields[0].1 }],
    )?;
    for k in 1..h.fields.len() {
        let name = &report.steps[k - 1].effect;
        vector_plot(
            &dir.join(format!("residual_step{k}_{name}.png")),
            &format!("step {k}: {name}"),
            &[
                VectorField { label: "before", base_mm: &h.base_mm, error_um: &h.fields[k - 1].1 },
                VectorField { label: "after", base_mm: &h.base_mm, error_um: &h.fields[k].1 },
            ],
        )?;
    }
    let Some((_, last)) = h.fields.last() else { return Ok(()) };
    let first = &h.fields[0].1;
    let pts = &h.problem.points;
    let radial = |r: &[[f64; 2]], f: &dyn Fn(usize) -> f64| -> Vec<[f64; 2]> {
        r.iter().enumerate().map(|(i, e)| [f(i), e[0].hypot(e[1])]).collect()
    };
    let configs: [(&str, &str, Box<dyn Fn(usize) -> f64>); 3] = [
        ("theta1", "θ1 (deg)", Box::new(|i| pts[i].theta_rad[0].to_degrees())),
        ("theta2", "θ2 (deg)", Box::new(|i| pts[i].theta_rad[1].to_degrees())),
        ("theta_diff", "θ1 − θ2 (deg)", Box::new(|i| (pts[i].theta_rad[0] - pts[i].theta_rad[1]).to_degrees())),
    ];
    for (file, label, f) in configs.iter() {
        let a = radial(first, f.as_ref());
        let b = radial(last, f.as_ref());
        xy_plot(
            &dir.join(format!("residual_vs_{file}.png")),
            &format!("radial residual vs {label}"),
            label,
            "radial residual (µm)",
            &[
                Series { label: "start", points: &a, mark: Mark::Dots },
                Series { label: "final", points: &b, mark: Mark::Dots },
            ],
        )?;
    }
    // Joint-space residual against each motor's own angle: where a gear or encoder error shows.
    let flat: Vec<f64> = last.iter().flat_map(|e| [e[0], e[1]]).collect();
    let joint = structure::joint_residual_urad(&h.problem, &flat);
    for j in 0..2 {
        let pts_j: Vec<[f64; 2]> =
            joint.iter().enumerate().map(|(i, d)| [pts[i].theta_rad[j].to_degrees(), d[j]]).collect();
        xy_plot(
            &dir.join(format!("final_joint_residual_motor{}.png", j + 1)),
            &format!("final residual in joint space, motor {} vs its angle", j + 1),
            &format!("θ{} (deg)", j + 1),
            &format!("δθ{} (µrad)", j + 1),
            &[Series { label: "final", points: &pts_j, mark: Mark::Dots }],
        )?;
    }
    if h.problem.has_dir {
        // Final residual along θ1 split by approach direction of motor 1.
        let plus: Vec<[f64; 2]> = last
            .iter()
            .enumerate()
            .filter(|(i, _)| pts[*i].dir[0] > 0.0)
            .map(|(i, e)| [pts[i].theta_rad[0].to_degrees(), e[0].hypot(e[1])])
            .collect();
        let minus: Vec<[f64; 2]> = last
            .iter()
            .enumerate()
            .filter(|(i, _)| pts[*i].dir[0] < 0.0)
            .map(|(i, e)| [pts[i].theta_rad[0].to_degrees(), e[0].hypot(e[1])])
            .collect();
        xy_plot(
            &dir.join("final_residual_by_direction.png"),
            "final radial residual by approach direction of motor 1",
            "θ1 (deg)",
            "radial residual (µm)",
            &[
                Series { label: "dir1 = +1", points: &plus, mark: Mark::Dots },
                Series { label: "dir1 = −1", points: &minus, mark: Mark::Dots },
            ],
        )?;
    }
    let times: Option<Vec<f64>> = h.problem.points.iter().map(|p| data.get(p.index).and_then(|m| m.t_s)).collect();
    if let Some(t) = times {
        if t.len() == last.len() {
            let a: Vec<[f64; 2]> = last.iter().zip(&t).map(|(e, t)| [*t, e[0].hypot(e[1])]).collect();
            xy_plot(
                &dir.join("final_residual_vs_time.png"),
                "final radial residual vs time",
                "t (s)",
                "radial residual (µm)",
                &[Series { label: "final", points: &a, mark: Mark::Dots }],
            )?;
        }
    }
    Ok(())
}
