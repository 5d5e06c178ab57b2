//! The paper's measurement protocols, as the visits a measurement run makes: where each pose is
//! and where the motion towards it comes from (which sets the motors' approach directions, and
//! so which side backlash sits on).
//!
//! * `table1`: Table I's 9 targets, in its order (the centre, then round the workspace's edge:
//!   the 4 corners and 4 mid-sides; on a polygon workspace, where the rays from the centre to
//!   the bounding rectangle's corners and mid-sides leave the polygon);
//! * `grid`: the machine's grid nodes (5 mm over the 100 mm × 150 mm workspace on the paper
//!   machine, 21 × 31), x fastest, rows visited in order (a raster scan: each node approached
//!   from the previous one, the first from `approach_mm` before it);
//! * `random:N`: N uniform random targets in the workspace, each approached along a random
//!   direction from `approach_mm` away (so the two motors' directions take all four
//!   combinations);
//! * `repeat`: ISO 230-2 style bidirectional runs: 5 runs, each an ascending then a descending
//!   pass along the x line (y = centre, 11 targets over the workspace's chord: every 10 mm on
//!   the paper machine) and then along the y line (x = centre, every 15 mm there), every pass
//!   starting with an `approach_mm` overtravel so its first point is approached in the pass
//!   direction too. `run` is the run index. The spacing is the chord's tenth rounded down to
//!   1 µm (so a chord of 100 mm gives exactly 10 mm).
//!
//! Random draws: a seed always gives the same targets (recorded runs stay reproducible).
//! `random:N` samples the closed bounding rectangle (its edges included) from a stream of the
//! seed **and N** (`random:40` for a fit and a "fresh" `random:400` with the same
//! seed used to share their first 40 targets; now lists of different lengths share none), the
//! demo's and the plan's lists the half-open one ([`Range`]) from their own streams. A draw
//! outside a polygon workspace is drawn again (a rectangle never rejects, so its draws are the
//! plain uniform ones). Cost: negligible (rejection: the polygon's share of its bounding
//! rectangle).

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
                    return Err(invalid!(
                        "unknown protocol '{s}' (known: table1, grid, random:N, repeat)"
                    ));
                };
                let n: usize = n.parse().map_err(|_| {
                    invalid!("protocol '{s}': N in random:N must be a positive integer")
                })?;
                if n == 0 || n > MAX_RANDOM_TARGETS {
                    return Err(invalid!(
                        "protocol '{s}': N must be in 1..={MAX_RANDOM_TARGETS}"
                    ));
                }
                Ok(Protocol::Random(n))
            }
        }
    }
}

/// One visit: where to go, where the motion comes from, which run, and (when a list prescribes
/// it, as a plan's lists do) how each motor must arrive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Visit {
    pub target_mm: [f64; 2],
    pub from_mm: [f64; 2],
    pub run: u32,
    /// The approach direction of each motor (+1/−1) the machine must use; `None`: from the
    /// measurement's approach policy.
    pub dir: Option<[i8; 2]>,
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
/// machine). On a polygon, each edge point is where the ray from the centre towards the
/// bounding rectangle's point leaves the polygon.
pub fn table1_targets(ws: &Workspace) -> [[f64; 2]; 9] {
    let ([x0, x1], [y0, y1], [cx, cy]) = (ws.x_mm, ws.y_mm, ws.centre_mm());
    [
        [cx, cy],
        [cx, y1],
        [x1, y1],
        [x1, cy],
        [x1, y0],
        [cx, y0],
        [x0, y0],
        [x0, cy],
        [x0, y1],
    ]
    .map(|p| ws.pulled_inside(p, 0.0))
}

/// Visits of `targets` in order, each approached from the previous one (the first from
/// `first_from`).
fn in_sequence(targets: &[[f64; 2]], first_from: [f64; 2], run: u32, out: &mut Vec<Visit>) {
    let mut from = first_from;
    for &t in targets {
        out.push(Visit {
            target_mm: t,
            from_mm: from,
            run,
            dir: None,
        });
        from = t;
    }
}

/// `n` uniform random targets in the workspace, each approached from `approach_mm` away along
/// a random direction (run 0).
pub fn random_visits(
    n: usize,
    rng: &mut ChaCha8Rng,
    spec: &MachineSpec,
    range: Range,
) -> Vec<Visit> {
    (0..n).map(|_| random_visit(rng, spec, range)).collect()
}

/// One uniform random target in the workspace (drawn in its bounding rectangle, drawn again
/// while outside the polygon), approached from `approach_mm` away along a random direction.
pub fn random_visit(rng: &mut ChaCha8Rng, spec: &MachineSpec, range: Range) -> Visit {
    let ws = &spec.workspace;
    let (x, y, d) = (ws.x_mm, ws.y_mm, spec.approach_mm);
    loop {
        let t = match range {
            Range::Closed => [rng.random_range(x[0]..=x[1]), rng.random_range(y[0]..=y[1])],
            Range::HalfOpen => [rng.random_range(x[0]..x[1]), rng.random_range(y[0]..y[1])],
        };
        let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        if ws.is_rectangle || ws.contains(t, 0.0) {
            return Visit {
                target_mm: t,
                from_mm: [t[0] - d * a.cos(), t[1] - d * a.sin()],
                run: 0,
                dir: None,
            };
        }
    }
}

/// The seed of `random:N`'s stream: the seed and N (module doc).
fn random_stream_seed(seed: u64, n: usize) -> u64 {
    (seed ^ 0x5eed_7a26_0e75) ^ (n as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

/// `n` targets along `axis` over the workspace's chord through its centre (the repeat
/// protocol's lines; module doc).
fn line_targets(ws: &Workspace, axis: usize) -> Vec<[f64; 2]> {
    let centre = ws.centre_mm();
    let at = centre[1 - axis];
    let [lo, hi] = ws
        .chord_mm(axis, at)
        .unwrap_or([centre[axis], centre[axis]]);
    let step = ((hi - lo) / 10.0 * 1000.0).floor() / 1000.0;
    (0..=10)
        .map(|k| {
            let mut p = [0.0; 2];
            p[axis] = lo + step * k as f64;
            p[1 - axis] = at;
            p
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
            let mut rng = ChaCha8Rng::seed_from_u64(random_stream_seed(seed, n));
            v = random_visits(n, &mut rng, spec, Range::Closed);
        }
        Protocol::Repeat => {
            let (xs, ys) = (line_targets(ws, 0), line_targets(ws, 1));
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
        let t1: Vec<[f64; 2]> = visits(Protocol::Table1, 0, &spec)
            .iter()
            .map(|v| v.target_mm)
            .collect();
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
        assert_eq!(
            (g.len(), g[0].from_mm, g[1].from_mm),
            (651, [157.132, -75.0], g[0].target_mm)
        );
        // The repeat lines: every 10 mm along x at y = 0, every 15 mm along y at x = 212.132.
        let r = visits(Protocol::Repeat, 0, &spec);
        assert_eq!(r[1].target_mm, [172.132, 0.0]);
        assert_eq!(r[10].target_mm, [262.132, 0.0]);
        assert_eq!(r[22].target_mm, [212.132, -75.0]);
        assert_eq!(r[32].target_mm, [212.132, 75.0]);
    }

    /// A "fresh" random:400 with the seed of a random:40 fit shares none of its
    /// targets; the same N and seed give the same targets.
    #[test]
    fn random_lists_of_different_lengths_share_no_target() {
        let spec = MachineSpec::paper();
        let fit = visits(Protocol::Random(40), 1, &spec);
        let fresh = visits(Protocol::Random(400), 1, &spec);
        assert_eq!(fit, visits(Protocol::Random(40), 1, &spec));
        for v in &fit {
            let nearest = fresh
                .iter()
                .map(|f| (f.target_mm[0] - v.target_mm[0]).hypot(f.target_mm[1] - v.target_mm[1]))
                .fold(f64::INFINITY, f64::min);
            assert!(nearest > 1e-3, "{:?} reused ({nearest} mm)", v.target_mm);
        }
    }

    #[test]
    fn a_polygon_workspace_keeps_every_target_inside() {
        let mut spec = MachineSpec::paper();
        let cut = [
            [162.132, -75.0],
            [262.132, -75.0],
            [262.132, 35.0],
            [222.132, 75.0],
            [162.132, 75.0],
        ];
        spec.workspace = Workspace::polygon(&cut, 0.1).unwrap();
        for p in [Protocol::Random(300), Protocol::Table1, Protocol::Repeat] {
            for v in visits(p, 3, &spec) {
                assert!(
                    spec.workspace.contains(v.target_mm, 1e-9),
                    "{p:?}: {:?}",
                    v.target_mm
                );
            }
        }
        // Table I's upper right corner is where the diagonal from the centre meets the cut.
        let t1 = table1_targets(&spec.workspace);
        assert!((t1[2][0] + t1[2][1] - 297.132).abs() < 1e-9, "{:?}", t1[2]);
        assert_eq!(t1[3], [262.132, spec.workspace.centre_mm()[1]]);
    }
}
