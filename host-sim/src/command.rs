//! `host-sim command`: motor angles for a list of targets, computed exactly as the firmware does.
//!
//! Why: a calibration (model + grid) must be verifiable off-line. Each target goes through
//! `kinematics_core::Calibration::command_rad` in f32 — the same function, the same scalar type
//! and the same grid image the MCU runs — so the angles written here are bit-identical to what the
//! servo would command for that setpoint (before unwrapping next to the motor position).
//! Cost: one IK and one bilinear lookup per target. Error: f32, ~0.01 µm at the tool.
//!
//! Input: CSV with columns `x_mm,y_mm` (any order, `#` comments). Output:
//! `x_mm,y_mm,theta1_deg,theta2_deg` (degrees with 9 decimals: f32 radians round-trip exactly).
//! Any unreachable target, any target outside the grid, or a grid built for another model is an
//! error naming the line; nothing is written then.

use crate::grid_build::read_image;
use crate::io::model_file::read_model;
use crate::io::atomic::write_atomic;
use anyhow::{anyhow, bail, Context, Result};
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use std::path::{Path, PathBuf};

/// Motor angles for targets, via the firmware's command path (model IK + grid, f32).
#[derive(clap::Args, Debug)]
pub struct CommandArgs {
    /// The model (model.json).
    #[arg(long)]
    pub model: PathBuf,
    /// Optional correction-grid image; its embedded model must be --model's.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Targets CSV with columns x_mm,y_mm.
    #[arg(long)]
    pub targets: PathBuf,
    /// Output CSV: x_mm,y_mm,theta1_deg,theta2_deg.
    #[arg(long)]
    pub out: PathBuf,
    /// Smallest |sin| of a transmission angle accepted (the servo's default).
    #[arg(long, default_value_t = kinematics_core::DEFAULT_MIN_TRANSMISSION as f32)]
    pub min_transmission: f32,
}

/// Reads a targets CSV: `(line, [x, y])`.
pub fn parse_targets(text: &str) -> Result<Vec<(usize, [f64; 2])>> {
    let mut reader = csv::ReaderBuilder::new().trim(csv::Trim::All).flexible(true).comment(Some(b'#')).from_reader(text.as_bytes());
    let headers = reader.headers().context("line 1: cannot read the header")?.clone();
    let col = |name: &str| headers.iter().position(|h| h == name).ok_or_else(|| anyhow!("line 1: required column '{name}' is missing"));
    let (ix, iy) = (col("x_mm")?, col("y_mm")?);
    if let Some(h) = headers.iter().find(|h| *h != "x_mm" && *h != "y_mm") {
        bail!("line 1: unknown column '{h}' (a targets file has x_mm,y_mm)");
    }
    let mut out = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| anyhow!("malformed CSV: {e}"))?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        if record.len() != headers.len() {
            bail!("line {line}: {} fields, the header has {}", record.len(), headers.len());
        }
        let num = |i: usize, name: &str| -> Result<f64> {
            let v: f64 = record[i].parse().map_err(|_| anyhow!("line {line}: '{name}' = '{}' is not a number", &record[i]))?;
            if !v.is_finite() {
                bail!("line {line}: '{name}' = '{}' is not finite", &record[i]);
            }
            Ok(v)
        };
        out.push((line, [num(ix, "x_mm")?, num(iy, "y_mm")?]));
    }
    if out.is_empty() {
        bail!("no targets after the header");
    }
    Ok(out)
}

/// Checks that the grid was built for `model` (every parameter equal after rounding to f32).
pub fn check_grid_model(grid: &CorrectionGrid<'_>, model: &FiveBar<f64>) -> Result<()> {
    let want = model.cast::<f32>();
    let got = grid.model();
    let pairs = [
        ("a_mm", got.a_mm, want.a_mm),
        ("b_mm", got.b_mm, want.b_mm),
        ("c_mm", got.c_mm, want.c_mm),
        ("d_mm", got.d_mm, want.d_mm),
        ("base_a0_x_mm", got.base_a0_mm[0], want.base_a0_mm[0]),
        ("base_a0_y_mm", got.base_a0_mm[1], want.base_a0_mm[1]),
        ("base_b0_x_mm", got.base_b0_mm[0], want.base_b0_mm[0]),
        ("base_b0_y_mm", got.base_b0_mm[1], want.base_b0_mm[1]),
        ("encoder_offset_1_rad", got.encoder_offset_rad[0], want.encoder_offset_rad[0]),
        ("encoder_offset_2_rad", got.encoder_offset_rad[1], want.encoder_offset_rad[1]),
    ];
    for (name, g, w) in pairs {
        if g != w {
            bail!("the grid was built for another model: {name} is {g} in the grid, {w} in the model file");
        }
    }
    if got.mode != want.mode {
        bail!("the grid was built for another working mode: {:?} vs {:?}", got.mode, want.mode);
    }
    Ok(())
}

/// Commands every target; the first failure names its line.
pub fn command_all(cal: &Calibration<'_>, targets: &[(usize, [f64; 2])], min_transmission: f32) -> Result<Vec<[f32; 2]>> {
    targets
        .iter()
        .map(|&(line, t)| {
            cal.command_rad([t[0] as f32, t[1] as f32], min_transmission)
                .map_err(|e| anyhow!("line {line}: target ({}, {}): {e}", t[0], t[1]))
        })
        .collect()
}

fn format_output(targets: &[(usize, [f64; 2])], angles: &[[f32; 2]]) -> String {
    let mut s = String::from("x_mm,y_mm,theta1_deg,theta2_deg\n");
    for ((_, t), a) in targets.iter().zip(angles) {
        s.push_str(&format!("{},{},{:.9},{:.9}\n", t[0], t[1], (a[0] as f64).to_degrees(), (a[1] as f64).to_degrees()));
    }
    s
}

/// `host-sim command`.
pub fn run(args: &CommandArgs) -> Result<()> {
    let model = read_model(&args.model)?;
    let image = match &args.grid {
        Some(p) => Some(read_image(p)?),
        None => None,
    };
    let grid = match &image {
        Some(bytes) => {
            let g = CorrectionGrid::parse(bytes).map_err(|e| anyhow!("{}: {e}", args.grid.as_ref().expect("set").display()))?;
            check_grid_model(&g, &model)?;
            Some(g)
        }
        None => None,
    };
    let cal = Calibration { model: model.cast::<f32>(), grid };
    let text = std::fs::read_to_string(&args.targets).with_context(|| format!("cannot read {}", args.targets.display()))?;
    let targets = parse_targets(&text).with_context(|| format!("in {}", args.targets.display()))?;
    let angles = command_all(&cal, &targets, args.min_transmission).with_context(|| format!("in {}", args.targets.display()))?;
    write_atomic(&args.out, format_output(&targets, &angles).as_bytes())?;
    eprintln!("command: {} targets -> {}", targets.len(), Path::new(&args.out).display());
    Ok(())
}
