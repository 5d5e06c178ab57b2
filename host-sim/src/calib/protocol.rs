//! The paper's measurement protocols, as the visits a measurement run makes: where each pose is
//! and where the motion towards it comes from (which sets the motors' approach directions, and
//! so which side backlash sits on).
//!
//! * `table1`: Table I's 9 targets, in its order (the centre, then round the workspace's edge:
//!   the 4 corners and 4 mid-sides);
//! * `grid`: the machine's grid nodes (5 mm over the 100 mm × 150 mm workspace on the paper
//!   machine, 21 × 31), x fastest, rows visited in order (a raster scan: each node approached
//!   from the previous one, the first from `approach_mm` before it);
//! * `random:N`: N uniform random targets in the workspace, each approached along a random
//!   direction from `approach_mm` away (so the two motors' directions take all four
//!   combinations);
//! * `repeat`: ISO 230-2 style bidirectional runs: 5 runs, each an ascending then a descending
//!   pass along the x line (y = centre, x every 10 mm) and then along the y line (x = centre,
//!   y every 15 mm), every pass starting with an `approach_mm` overtravel so its first point is
//!   approached in the pass direction too. `run` is the run index.
//!
//! Random draws: a seed always gives the same targets (recorded runs stay reproducible), so the
//! two generators keep their historical draws: `random:N` samples the closed rectangle
//! (its edges included) from its own stream of the seed, the demo's targets the half-open one
//! ([`Range`]). Cost: negligible.

use super::{invalid, CalibError};
use crate::machine_spec::{MachineSpec, Workspace};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A measurement protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Protocol {
    Table1,
    Grid,
    Random(usize),
    Repeat,
}

/// The most targets `random:N` draws.
pub const MAX_RANDOM_TARGETS: usize = 1_000_000;

impl Protocol {
    /// `table1`, `grid`, `random:N` or `repeat`.
    pub fn parse(s: &str) -> Result<Self, CalibError> {
        match s {
            "table1" => Ok(Protocol::Table1),
            "grid" => Ok(Protocol::Grid),
            "repeat" => Ok(Protocol::Repeat),
            _ => {
                let Some(n) = s.strip_prefix("random:") else {
                    return Err(invalid!("unknown protocol '{s}' (known: table1, grid, random:N, repeat)"));
                };
                let n: usize = n.parse().map_err(|_| invalid!("protocol '{s}': N in random:N must be a positive integer"))?;
                if n == 0 || n > MAX_RANDOM_TARGETS {
                    return Err(invalid!("protocol '{s}': N must be in 1..={MAX_RANDOM_TARGETS}"));
                }
                Ok(Protocol::Random(n))
            }
        }
    }
}

/// One visit: where to go, where the motion comes from, which run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Visit {
    pub target_mm: [f64; 2],
    pub from_mm: [f64; 2],
    pub run: u32,
}

/// Which rectangle random targets are drawn from (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Range {
    /// Edges included (`random:N`).
    Closed,
    /// Upper edges excluded (the demo's fit poses and verification targets).
    HalfOpen,
}

/// Table I's targets in the paper's order: the workspace's centre, then its edge from the top
/// middle round through the corners (x = centre, right, left columns; y = 0, ±75 on the paper
/// machine).
pub fn table1_targets(ws: &Workspace) -> [[f64; 2]; 9] {
    let ([x0, x1], [y0, y1], [cx, cy]) = (ws.x_mm, ws.y_mm, ws.centre_mm());
    [[cx, cy], [cx, y1], [x1, y1], [x1, cy], [x1, y0], [cx, y0], [x0, y0], [x0, cy], [x0, y1]]
}

/// Visits of `targets` in order, each approached from the previous one (the first from
/// `first_from`).
fn in_sequence(targets: &[[f64; 2]], first_from: [f64; 2], run: u32, out: &mut Vec<Visit>) {
    let mut from = first_from;
    for &t in targets {
        out.push(Visit { target_mm: t, from_mm: from, run });
        from = t;
    }
}

/// `n` uniform random targets in the workspace, each approached from `approach_mm` away along
/// a random direction (run 0).
pub fn random_visits(n: usize, rng: &mut ChaCha8Rng, spec: &MachineSpec, range: Range) -> Vec<Visit> {
    let (x, y, d) = (spec.workspace.x_mm, spec.workspace.y_mm, spec.approach_mm);
    (0..n)
        .map(|_| {
            let t = match range {
                Range::Closed => [rng.random_range(x[0]..=x[1]), rng.random_range(y[0]..=y[1])],
                Range::HalfOpen => [rng.random_range(x[0]..x[1]), rng.random_range(y[0]..y[1])],
            };
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            Visit { target_mm: t, from_mm: [t[0] - d * a.cos(), t[1] - d * a.sin()], run: 0 }
        })
        .collect()
}

/// The visits of a protocol on `spec`'s machine, in order; `seed` draws `random:N`'s targets.
pub fn visits(protocol: Protocol, seed: u64, spec: &MachineSpec) -> Vec<Visit> {
    let mut v: Vec<Visit> = Vec::new();
    let (ws, d) = (&spec.workspace, spec.approach_mm);
    match protocol {
        Protocol::Table1 => {
            let t = table1_targets(ws);
            in_sequence(&t, [t[0][0] - d, t[0][1] - d], 0, &mut v);
        }
        Protocol::Grid => {
            let g = &spec.grid;
            in_sequence(&spec.grid_nodes_mm(), [g.x0_mm - d, g.y0_mm], 0, &mut v);
        }
        Protocol::Random(n) => {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_7a26_0e75);
            v = random_visits(n, &mut rng, spec, Range::Closed);
        }
        Protocol::Repeat => {
            let [cx, cy] = ws.centre_mm();
            let xs: Vec<[f64; 2]> = (0..=10).map(|k| [ws.x_mm[0] + 10.0 * k as f64, cy]).collect();
            let ys: Vec<[f64; 2]> = (0..=10).map(|k| [cx, ws.y_mm[0] + 15.0 * k as f64]).collect();
            for run in 0..5 {
                for (line, axis) in [(&xs, 0usize), (&ys, 1usize)] {
                    let up: Vec<[f64; 2]> = line.clone();
                    let down: Vec<[f64; 2]> = line.iter().rev().cloned().collect();
                    for (pass, sign) in [(up, 1.0), (down, -1.0)] {
                        let mut over = pass[0];
                        over[axis] -= d * sign;
                        in_sequence(&pass, over, run, &mut v);
                    }
                }
            }
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn protocols() {
        assert!(Protocol::parse("random:0").is_err());
        assert!(Protocol::parse("spiral").is_err());
        assert_eq!(Protocol::parse("random:12").unwrap(), Protocol::Random(12));
        let spec = MachineSpec::paper();
        assert_eq!(visits(Protocol::Repeat, 0, &spec).len(), 5 * 2 * 2 * 11);
        // Table I as the paper prints it.
        let t1: Vec<[f64; 2]> = visits(Protocol::Table1, 0, &spec).iter().map(|v| v.target_mm).collect();
        let printed = [
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
        assert_eq!(t1, printed);
        let g = visits(Protocol::Grid, 0, &spec);
        assert_eq!((g.len(), g[0].from_mm, g[1].from_mm), (651, [157.132, -75.0], g[0].target_mm));
    }
}
