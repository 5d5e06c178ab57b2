//! `host-sim measure`: the paper's measurement protocols, run on a simulated plant.
//!
//! Quasi-static: for each target the commanded encoder angles come from the hidden robot
//! (nominal, or `--model`) plus the correction grid (`--grid`) through
//! `Calibration::command_rad`, in f32 exactly as the firmware computes them; the servo is taken
//! to hold each encoder at the nearest count (no dynamic loop is needed for a static pose),
//! having approached it in the direction the motor last moved; the plant's linkage is solved for
//! equilibrium and the instrument reads the tool point. One measurement costs one six-bar solve
//! (a few µs).
//!
//! Protocols:
//! * `table1`: Table I's 9 targets, in its order (the 4 corners, 4 mid-sides and the centre);
//! * `grid`: the 5 mm grid over the 100 mm × 150 mm workspace, 21 × 31 nodes, x fastest, rows
//!   visited in order (so the approach directions are those of a raster scan);
//! * `random:N`: N uniform random targets, each approached along a random direction from 5 mm
//!   away (so dir1/dir2 take all four combinations);
//! * `repeat`: ISO 230-2 style bidirectional runs: 5 runs, each an ascending then a descending
//!   pass along the x line (y = 0, x = 162.132..262.132 every 10 mm) and then along the y line
//!   (x = 212.132, y = -75..75 every 15 mm). Every pass starts with a 5 mm overtravel, so its
//!   first point is approached in the pass direction too. `run` is the run index. Rows are in
//!   time order (`t_s`): the accuracy tool tells the line by which target coordinate varies
//!   (y_target = 0 and x varying: the x line; x_target = 212.132 and y varying: the y line)
//!   and the approach direction along the line by the sign of the change of that coordinate
//!   from the previous row of the same line and run (a pass's first row has the direction of
//!   the pass that follows it: ascending passes start at the low end). `dir1`, `dir2` give the
//!   motors' own directions.
//!
//! Each measurement takes 1 s of machine time (`t_s` = index).

use crate::io::measurement_csv::{write_measurements, Measurement};
use crate::io::model_file::read_model;
use crate::plant::{Plant, PlantConfig};
use anyhow::{anyhow, bail, Context, Result};
use kinematics_core::{wrap_angle_rad, Calibration, CorrectionGrid, FiveBar, ServoConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};

/// Arguments of `host-sim measure`.
#[derive(clap::Args, Debug)]
pub struct MeasureArgs {
    /// `ideal`, `paper` or a plant TOML file.
    #[arg(long)]
    pub plant: String,
    /// `table1`, `grid`, `random:N` or `repeat`.
    #[arg(long)]
    pub protocol: String,
    /// Seeds the random targets and the instrument noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output measurement CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// Hidden-robot model to command with (default: the nominal five-bar).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Correction grid image to add to the commands.
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// Overrides the instrument's noise σ (µm).
    #[arg(long)]
    pub noise_um: Option<f64>,
}

/// A measurement protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    Table1,
    Grid,
    Random(usize),
    Repeat,
}

impl Protocol {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "table1" => Ok(Protocol::Table1),
            "grid" => Ok(Protocol::Grid),
            "repeat" => Ok(Protocol::Repeat),
            _ => {
                if let Some(n) = s.strip_prefix("random:") {
                    let n: usize = n.parse().map_err(|_| anyhow!("protocol '{s}': N in random:N must be a positive integer"))?;
                    if n == 0 || n > 1_000_000 {
                        bail!("protocol '{s}': N must be in 1..=1000000");
                    }
                    Ok(Protocol::Random(n))
                } else {
                    bail!("unknown protocol '{s}' (known: table1, grid, random:N, repeat)")
                }
            }
        }
    }
}

/// Table I's desired positions (mm), in the paper's order.
pub const TABLE1_TARGETS_MM: [[f64; 2]; 9] = [
    [212.132, 0.0],
    [212.132, 75.0],
    [262.132, 75.0],
    [262.132, 0.0],
    [262.132, -75.0],
    [212.132, -75.0],
    [162.132, -75.0],
    [162.132, 0.0],
    [162.132, 75.0],
];

/// Workspace of the paper's machine (mm).
pub const WORKSPACE_X_MM: [f64; 2] = [162.132, 262.132];
pub const WORKSPACE_Y_MM: [f64; 2] = [-75.0, 75.0];

/// One visit: where to go, where the motion comes from, which run.
#[derive(Clone, Copy, Debug)]
pub struct Visit {
    pub target_mm: [f64; 2],
    pub from_mm: [f64; 2],
    pub run: u32,
}

/// The visits of a protocol, in order.
pub fn visits(protocol: Protocol, seed: u64) -> Vec<Visit> {
    let mut v: Vec<Visit> = Vec::new();
    let seq = |targets: &[[f64; 2]], first_from: [f64; 2], run: u32, v: &mut Vec<Visit>| {
        let mut from = first_from;
        for &t in targets {
            v.push(Visit { target_mm: t, from_mm: from, run });
            from = t;
        }
    };
    match protocol {
        Protocol::Table1 => seq(&TABLE1_TARGETS_MM, [207.132, -5.0], 0, &mut v),
        Protocol::Grid => {
            let mut t = Vec::new();
            for j in 0..31 {
                for i in 0..21 {
                    t.push([WORKSPACE_X_MM[0] + 5.0 * i as f64, WORKSPACE_Y_MM[0] + 5.0 * j as f64]);
                }
            }
            seq(&t, [WORKSPACE_X_MM[0] - 5.0, WORKSPACE_Y_MM[0]], 0, &mut v);
        }
        Protocol::Random(n) => {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_7a26_0e75);
            for _ in 0..n {
                let t = [rng.random_range(WORKSPACE_X_MM[0]..=WORKSPACE_X_MM[1]), rng.random_range(WORKSPACE_Y_MM[0]..=WORKSPACE_Y_MM[1])];
                let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                v.push(Visit { target_mm: t, from_mm: [t[0] - 5.0 * a.cos(), t[1] - 5.0 * a.sin()], run: 0 });
            }
        }
        Protocol::Repeat => {
            let xs: Vec<[f64; 2]> = (0..=10).map(|k| [WORKSPACE_X_MM[0] + 10.0 * k as f64, 0.0]).collect();
            let ys: Vec<[f64; 2]> = (0..=10).map(|k| [212.132, WORKSPACE_Y_MM[0] + 15.0 * k as f64]).collect();
            for run in 0..5 {
                for (line, axis) in [(&xs, 0usize), (&ys, 1usize)] {
                    let up: Vec<[f64; 2]> = line.clone();
                    let down: Vec<[f64; 2]> = line.iter().rev().cloned().collect();
                    for (pass, sign) in [(up, 1.0), (down, -1.0)] {
                        let mut over = pass[0];
                        over[axis] -= 5.0 * sign;
                        seq(&pass, over, run, &mut v);
                    }
                }
            }
        }
    }
    v
}

/// Reads `--model` and `--grid`: the model to command with and the grid image bytes (checked).
pub fn load_calibration(model: Option<&Path>, grid: Option<&Path>) -> Result<(FiveBar<f32>, Option<Vec<u8>>)> {
    let from_model = match model {
        Some(p) => Some(read_model(p)?.cast::<f32>()),
        None => None,
    };
    let bytes = match grid {
        None => None,
        Some(p) => Some(std::fs::read(p).with_context(|| format!("cannot read grid {}", p.display()))?),
    };
    let model = match (&bytes, from_model) {
        (Some(b), m) => {
            let g = CorrectionGrid::parse(b).map_err(|e| anyhow!("grid {}: {e}", grid.map(|p| p.display().to_string()).unwrap_or_default()))?;
            if let Some(m) = m {
                if m != *g.model() {
                    bail!("the model in --model differs from the model stored in --grid");
                }
            }
            *g.model()
        }
        (None, Some(m)) => m,
        (None, None) => FiveBar::<f32>::paper_nominal(),
    };
    Ok((model, bytes))
}

/// Runs a protocol on a plant and returns the measurements.
pub fn measure(plant_cfg: &PlantConfig, protocol: Protocol, seed: u64, cal: &Calibration<'_>, noise_um: Option<f64>) -> Result<Vec<Measurement>> {
    let mut plant = Plant::new(plant_cfg, seed);
    if let Some(n) = noise_um {
        if !(n >= 0.0 && n.is_finite()) {
            bail!("--noise-um must be a non-negative number, not {n}");
        }
        plant.instrument.noise_sigma_mm = n * 1e-3;
    }
    let min_t = ServoConfig::default().min_transmission;
    let mut previous = [0.0f64; 2];
    let mut rows = Vec::new();
    for (k, v) in visits(protocol, seed).into_iter().enumerate() {
        let t32 = [v.target_mm[0] as f32, v.target_mm[1] as f32];
        let cmd = cal
            .command_rad(t32, min_t)
            .map_err(|e| anyhow!("target ({:.3}, {:.3}) mm: {e}", v.target_mm[0], v.target_mm[1]))?;
        // The motors turn continuously: unwrap next to the previous command.
        let cmd = [0, 1].map(|i| previous[i] + wrap_angle_rad(f64::from(cmd[i]) - previous[i]));
        previous = cmd;
        let dir = match cal.model.cast::<f64>().inverse(v.from_mm, 0.0) {
            Ok(f) => [0, 1].map(|i| if wrap_angle_rad(cmd[i] - f[i]) >= 0.0 { 1i8 } else { -1 }),
            Err(_) => [1, 1],
        };
        let (enc, sol) = plant
            .settle(cmd, dir)
            .with_context(|| format!("target ({:.3}, {:.3}) mm", v.target_mm[0], v.target_mm[1]))?;
        let measured = plant.instrument.read_mm(sol.tool_mm);
        rows.push(Measurement {
            theta_deg: [enc[0].to_degrees(), enc[1].to_degrees()],
            measured_mm: measured,
            target_mm: Some(v.target_mm),
            dir: Some(dir),
            run: Some(v.run),
            t_s: Some(k as f64),
            line: 0,
        });
    }
    Ok(rows)
}

pub fn run(args: MeasureArgs) -> Result<()> {
    let plant = PlantConfig::by_name(&args.plant)?;
    let protocol = Protocol::parse(&args.protocol)?;
    let (model, bytes) = load_calibration(args.model.as_deref(), args.grid.as_deref())?;
    let grid = match &bytes {
        Some(b) => Some(CorrectionGrid::parse(b).map_err(|e| anyhow!("grid: {e}"))?),
        None => None,
    };
    let cal = Calibration { model, grid };
    let rows = measure(&plant, protocol, args.seed, &cal, args.noise_um)?;
    write_measurements(&args.out, &rows)?;
    eprintln!("measure: {} measurements written to {}", rows.len(), args.out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nominal() -> Calibration<'static> {
        Calibration { model: FiveBar::<f32>::paper_nominal(), grid: None }
    }

    fn worst_error_mm(rows: &[Measurement]) -> f64 {
        rows.iter()
            .map(|m| {
                let t = m.target_mm.unwrap();
                (m.measured_mm[0] - t[0]).hypot(m.measured_mm[1] - t[1])
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn ideal_plant_measures_the_targets() {
        let rows = measure(&PlantConfig::ideal(), Protocol::Table1, 1, &nominal(), None).unwrap();
        assert_eq!(rows.len(), 9);
        // f32 commands: 0.1 µm class.
        assert!(worst_error_mm(&rows) < 2e-4, "{}", worst_error_mm(&rows));
    }

    #[test]
    fn paper_plant_resembles_table1() {
        let rows = measure(&PlantConfig::paper(), Protocol::Grid, 1, &nominal(), Some(0.0)).unwrap();
        assert_eq!(rows.len(), 21 * 31);
        let worst = worst_error_mm(&rows);
        let t1 = measure(&PlantConfig::paper(), Protocol::Table1, 1, &nominal(), Some(0.0)).unwrap();
        for m in &t1 {
            let t = m.target_mm.unwrap();
            eprintln!("{:?} err {:.3} {:.3}", t, m.measured_mm[0] - t[0], m.measured_mm[1] - t[1]);
        }
        eprintln!("worst over grid {worst}");
        assert!((1.3..1.8).contains(&worst), "worst error {worst} mm");
        // The reference point reads (nearly) its target, as in the paper.
        let p1 = &t1[0];
        assert!((p1.measured_mm[0] - 212.132).hypot(p1.measured_mm[1]) < 0.02);
    }

    #[test]
    fn protocols_and_directions() {
        assert!(Protocol::parse("random:0").is_err());
        assert!(Protocol::parse("spiral").is_err());
        assert_eq!(Protocol::parse("random:12").unwrap(), Protocol::Random(12));
        let rows = measure(&PlantConfig::paper(), Protocol::Random(40), 3, &nominal(), None).unwrap();
        let mut seen = std::collections::HashSet::new();
        for m in &rows {
            seen.insert(m.dir.unwrap());
        }
        assert_eq!(seen.len(), 4, "{seen:?}");
        let rep = visits(Protocol::Repeat, 0);
        assert_eq!(rep.len(), 5 * 2 * 2 * 11);
    }

    #[test]
    fn unreachable_target_is_an_error() {
        let mut cal = nominal();
        cal.model.a_mm = 50.0;
        let err = measure(&PlantConfig::ideal(), Protocol::Table1, 1, &cal, None).unwrap_err();
        assert!(format!("{err:#}").contains("target (212.132, 0.000)"), "{err:#}");
    }

    #[test]
    fn backlash_alone_shows_as_a_direction_dependent_error() {
        use crate::plant::Effect;
        let cfg = PlantConfig::paper().with_only(Effect::Backlash);
        let rows = measure(&cfg, Protocol::Repeat, 1, &nominal(), None).unwrap();
        // On the x line (y = 0) motor 1 and 2 move in opposite directions; ascending and
        // descending passes must be displaced in opposite directions by about J·β/2.
        let mut shift = [0.0f64; 2];
        let mut n = [0usize; 2];
        for m in rows.iter().filter(|m| m.run == Some(0) && m.target_mm.unwrap()[1] == 0.0) {
            let k = usize::from(m.dir.unwrap()[0] < 0);
            shift[k] += m.measured_mm[0] - m.target_mm.unwrap()[0];
            n[k] += 1;
        }
        let (a, b) = (shift[0] / n[0] as f64 * 1e3, shift[1] / n[1] as f64 * 1e3);
        assert!(a * b < 0.0 && a.abs() > 0.5 && b.abs() > 0.5, "mean x error by direction: {a} um, {b} um");
    }
}

