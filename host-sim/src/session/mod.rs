//! A measurement session through the controller: the machine visits a plan's list on its own
//! servo, approached as the plan says, settled, and read by the instrument; the result is the
//! same measurement CSV `measure` writes for a simulated plant (`io::measurement_csv`).
//!
//! What is talked to is behind one trait, [`Rig`]: a controller (moved by tool targets through
//! the calibration in force, read back by its servo samples) and an instrument. [`link_rig`]
//! drives a real controller over the link (`link::LinkClient`: TCP to QEMU, a serial port, the
//! co-simulation) with any [`instrument::Instrument`] (readings typed in, or none now: the
//! tracker's export joined later by `import`); [`fake`] is an in-process rig around the
//! simulated plant, for tests.
//!
//! Per row of the list, [`run`]:
//! 1. **before anything moves**, every target is checked: inside the machine's workspace and
//!    reachable by the nominal model; a target closer than [`SessionOptions::edge_inset_mm`] to
//!    the workspace's edge (the controller's soft limit refuses it) is moved that far in, along
//!    the way to the workspace's centre. A list the machine cannot visit is refused whole;
//! 2. **approach**: a move to the approach point, then to the target, so that each motor
//!    arrives moving in the row's direction (`dir1,dir2`: the point is the target's nominal
//!    joint angles less `dir · approach_rad`, [`SessionOptions::approach_rad`]); a row
//!    without a direction comes from its `from_mm`. Where the approach point would leave the
//!    workspace, the target is moved in further, 10 µm at a time (at most 1 mm);
//! 3. **settle**: the servo's samples until the criterion of [`settle`] holds;
//! 4. **record** the commanded and the encoder angles (the CSV's angles are the encoder's: where
//!    the machine is), the direction each motor really arrived from (the sign of its last
//!    move), and **read** the instrument. A reading is checked against the others: from the
//!    fourth on, the best rigid motion of the nominal model's tool points onto the readings
//!    (any instrument frame) must leave it within [`SessionOptions::plausible_mm`]; a reading
//!    beyond (a wrong point sighted, a unit mistake) or not finite is an error naming the
//!    point.
//!
//! The CSV's target is the point commanded, except for a grid list (every target a node of the
//! machine's lattice): there the node, and the angles of the point commanded, which the grid
//! refers to the node through the model's Jacobian (`calib::grid`, second order in the inset:
//! 0.07 µm for 0.1 mm). Nothing is written here: the caller writes the result once the whole
//! list is done (a session that fails leaves no half file).

pub mod fake;
pub mod instrument;
pub mod link_rig;
pub mod settle;

use crate::calib::protocol::Visit;
use crate::io::commanded_csv::CommandedRow;
use crate::io::measurement_csv::Measurement;
use crate::link::ClientError;
use crate::machine_spec::MachineSpec;
use crate::numeric::procrustes;
use kinematics_core::wrap_angle_rad;
use serde::Serialize;
pub use settle::{settled_at, ServoSample, SettleCriterion};

/// Why a session stopped. Every message names the row (1-based, the list's order) or point.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The link failed (no answer, a dropped connection, a refusal).
    #[error("the controller: {0}")]
    Link(#[from] ClientError),
    /// A row the machine cannot visit (nothing moved).
    #[error("row {row}: target ({:.3}, {:.3}) mm: {reason}", target_mm[0], target_mm[1])]
    Plan {
        row: usize,
        target_mm: [f64; 2],
        reason: String,
    },
    /// The controller is not ready to move (not homed, a fault, drives off).
    #[error("the controller is not ready: {0}")]
    NotReady(String),
    /// At a point: the move failed, the machine did not settle, the controller faulted.
    #[error("point {point} (row {row}): {reason}")]
    Point {
        point: String,
        row: usize,
        reason: String,
    },
    /// The machine did not settle by the criterion in its timeout.
    #[error("the machine did not settle within {} s (following error ≤ {} µrad and mean speed ≤ {} µrad/s for {} s): a servo that hunts or a drive that creeps", .0.timeout_s, .0.following_error_rad * 1e6, .0.speed_rad_s * 1e6, .0.dwell_s)]
    NotSettled(SettleCriterion),
    /// An instrument reading that cannot be used.
    #[error("point {point}: the instrument's reading {reason}")]
    Reading { point: String, reason: String },
    /// Options that make no session.
    #[error("{0}")]
    Options(String),
}

/// What the session asks of the instrument at one point.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PointRequest {
    /// 0-based row of the list.
    pub index: usize,
    /// The point's id (`P001` for the first row): what a tracker's export names it by.
    pub id: String,
    /// The point commanded (mm, machine frame).
    pub target_mm: [f64; 2],
    /// Where the machine is (encoder, rad).
    pub encoder_rad: [f64; 2],
}

/// One reading of the instrument.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reading {
    /// The point read (mm, the instrument's frame).
    Point([f64; 2]),
    /// No reading (the beam was lost): noted, the row left out of the CSV.
    Missing,
    /// The reading comes later (a tracker's export joined by `import`).
    Deferred,
}

/// The machine at rest at a point.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Settled {
    /// Machine time when settled (s).
    pub t_s: f64,
    /// How long after the move ended (s).
    pub settle_s: f64,
    /// The servo's commanded encoder angles (rad).
    pub reference_rad: [f64; 2],
    /// The encoder angles (rad).
    pub encoder_rad: [f64; 2],
    /// The largest following error in the settled window (rad).
    pub following_error_rad: f64,
}

/// The end of a move.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Moved {
    /// Machine time when the motion ended (s).
    pub t_s: f64,
    /// The encoder angles then (rad).
    pub encoder_rad: [f64; 2],
}

/// A controller with an instrument (module doc).
pub trait Rig {
    /// One line for reports.
    fn describe(&self) -> String;
    /// Checks that the controller can move (homed, running, no fault, drives on).
    fn check_ready(&mut self) -> Result<(), SessionError>;
    /// Moves the tool to `target_mm` (the controller plans the move, through its calibration)
    /// and returns when the motion has ended (the setpoint is there).
    fn move_to(&mut self, target_mm: [f64; 2]) -> Result<Moved, SessionError>;
    /// Waits from `from_s` (machine time) until the machine is settled by `c`.
    fn settle(&mut self, from_s: f64, c: &SettleCriterion) -> Result<Settled, SessionError>;
    /// The instrument's reading at a settled point.
    fn read(&mut self, point: &PointRequest) -> Result<Reading, SessionError>;
    /// Where the tool really was at the last reading, as a noiseless instrument would read it
    /// (the instrument's frame): known in simulation only.
    fn truth_mm(&self) -> Option<[f64; 2]> {
        None
    }
    /// The session is over (telemetry off).
    fn finish(&mut self) -> Result<(), SessionError> {
        Ok(())
    }
}

/// How to run a session.
#[derive(Clone, Debug)]
pub struct SessionOptions {
    /// The machine (workspace, nominal model for the approach points and the checks).
    pub spec: MachineSpec,
    pub settle: SettleCriterion,
    /// Joint distance of the approach point before each target (rad); larger than any backlash
    /// (the paper plant's is 20 µrad): 0.5 mrad is 75-100 µm at the tool.
    pub approach_rad: f64,
    /// Targets nearer the workspace's edge than this are moved in (mm): the controller's soft
    /// limit (the machine file's stop margin, at least the firmware's 0.1 mm) and 1 µm.
    pub edge_inset_mm: f64,
    /// A reading further than this from where the others put it is refused (mm).
    pub plausible_mm: f64,
    /// The first point's number in the ids (`P001`): 1.
    pub first_id: usize,
}

impl SessionOptions {
    /// The defaults for `spec`'s machine.
    pub fn for_machine(spec: &MachineSpec) -> Self {
        SessionOptions {
            spec: spec.clone(),
            settle: SettleCriterion::default(),
            approach_rad: 5e-4,
            edge_inset_mm: spec.workspace.stop_margin_mm.max(0.1) + 0.001,
            plausible_mm: 5.0,
            first_id: 1,
        }
    }
}

/// One visited point.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SessionPoint {
    pub id: String,
    /// The list's target (mm).
    pub listed_mm: [f64; 2],
    /// The point commanded (mm): the target, or moved inside the soft limit.
    pub commanded_mm: [f64; 2],
    pub settled: Settled,
    /// Each motor's direction on arrival (the sign of its last move).
    pub dir: [i8; 2],
    /// The instrument's reading (mm, its frame); `None`: missing or deferred.
    pub reading_mm: Option<[f64; 2]>,
    /// Where the tool really was, as a noiseless instrument would read it (simulation only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_mm: Option<[f64; 2]>,
}

/// What a session did.
#[derive(Clone, Debug, Serialize)]
pub struct SessionReport {
    pub rig: String,
    pub points: usize,
    pub read: usize,
    /// Ids of the points without a reading (the beam lost).
    pub missing: Vec<String>,
    /// The readings come later (`import`).
    pub deferred: bool,
    /// Ids of the points moved inside the soft limit, and by how much (mm).
    pub moved_in: Vec<(String, f64)>,
    /// Whether the CSV's targets are the list's grid nodes (module doc).
    pub grid_list: bool,
    pub settle: SettleCriterion,
    pub settle_s_max: f64,
    pub settle_s_mean: f64,
    pub following_error_urad_max: f64,
    pub machine_time_s: f64,
}

/// A session's result: nothing written yet.
#[derive(Clone, Debug)]
pub struct SessionResult {
    pub points: Vec<SessionPoint>,
    /// The rows with a reading, as the measurement CSV holds them.
    pub measurements: Vec<Measurement>,
    /// Every row with the angles the machine held, as `import --commanded` reads them.
    pub commanded: Vec<CommandedRow>,
    pub report: SessionReport,
}

/// Whether every target of `visits` is a node of the machine's grid lattice.
fn is_grid_list(visits: &[Visit], spec: &MachineSpec) -> bool {
    let g = &spec.grid;
    !visits.is_empty()
        && visits.iter().all(|v| {
            let u = (v.target_mm[0] - g.x0_mm) / g.step_mm;
            let w = (v.target_mm[1] - g.y0_mm) / g.step_mm;
            (u - u.round()).abs() < 1e-6
                && (w - w.round()).abs() < 1e-6
                && (0.0..g.nx as f64).contains(&u.round())
                && (0.0..g.ny as f64).contains(&w.round())
        })
}

/// The point to move to before `target` so that each motor arrives moving in `dir`.
fn approach_point(
    spec: &MachineSpec,
    target_mm: [f64; 2],
    dir: [i8; 2],
    rad: f64,
) -> Option<[f64; 2]> {
    let m = &spec.nominal;
    let th = m.inverse(target_mm, spec.min_transmission).ok()?;
    let back = [
        th[0] - f64::from(dir[0]) * rad,
        th[1] - f64::from(dir[1]) * rad,
    ];
    m.forward(back, spec.min_transmission).ok()
}

/// Where the machine goes for one row: (the point commanded, the approach point).
fn plan_row(
    spec: &MachineSpec,
    v: &Visit,
    o: &SessionOptions,
    row: usize,
) -> Result<([f64; 2], [f64; 2]), SessionError> {
    let refuse = |reason: String| SessionError::Plan {
        row,
        target_mm: v.target_mm,
        reason,
    };
    let ws = &spec.workspace;
    let t = v.target_mm;
    if !(t[0].is_finite() && t[1].is_finite() && ws.contains(t, 1e-9)) {
        return Err(refuse(format!(
            "outside machine '{}''s workspace: the controller refuses it (use a plan of this machine: host-sim plan --machine FILE)",
            spec.name
        )));
    }
    let centre = ws.centre_mm();
    let to_centre = [centre[0] - t[0], centre[1] - t[1]];
    let len = to_centre[0].hypot(to_centre[1]).max(1e-12);
    let inside = |p: [f64; 2]| ws.region.contains(p, o.edge_inset_mm);
    for k in 0..=100 {
        let s = if k == 0 {
            0.0
        } else {
            o.edge_inset_mm + 0.01 * (k - 1) as f64
        };
        let p = if inside(t) && k == 0 {
            t
        } else if k == 0 {
            continue;
        } else {
            [t[0] + s * to_centre[0] / len, t[1] + s * to_centre[1] / len]
        };
        if !inside(p) || spec.nominal.inverse(p, spec.min_transmission).is_err() {
            continue;
        }
        let from = match v.dir {
            Some(d) => match approach_point(spec, p, d, o.approach_rad) {
                Some(a) => a,
                None => continue,
            },
            None => v.from_mm,
        };
        if inside(from) {
            return Ok((p, from));
        }
        if v.dir.is_none() {
            // No direction to keep: come straight from the previous point.
            return Ok((p, p));
        }
    }
    Err(refuse(format!(
        "no point within 1 mm of it inside the controller's soft limit ({} mm from the edge) can be approached as the list says (dir {:?})",
        o.edge_inset_mm, v.dir
    )))
}

/// Largest distance (mm) of a reading from where the nominal model's tool points, moved by the
/// best rigid motion onto all readings, put it; with the index of that reading.
fn worst_misfit(points: &[SessionPoint], spec: &MachineSpec) -> Option<(usize, f64)> {
    type Pair = ([f64; 2], [f64; 2]);
    let (idx, pairs): (Vec<usize>, Vec<Pair>) = points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let r = p.reading_mm?;
            let f = spec.nominal.forward(p.settled.encoder_rad, 0.0).ok()?;
            Some((i, (f, r)))
        })
        .unzip();
    if pairs.len() < 4 {
        return None;
    }
    let (from, to): (Vec<[f64; 2]>, Vec<[f64; 2]>) = pairs.iter().copied().unzip();
    let t = procrustes(&from, &to, None)?;
    pairs
        .iter()
        .zip(idx)
        .map(|((f, r), i)| {
            let q = t.apply(*f);
            (i, (q[0] - r[0]).hypot(q[1] - r[1]))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// Runs the session (module doc); `progress` hears `(done, total)` after every point.
pub fn run(
    rig: &mut dyn Rig,
    visits: &[Visit],
    o: &SessionOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SessionResult, SessionError> {
    o.settle.check().map_err(SessionError::Options)?;
    for (name, v) in [
        ("approach", o.approach_rad),
        ("edge inset", o.edge_inset_mm),
        ("plausible reading distance", o.plausible_mm),
    ] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(SessionError::Options(format!(
                "the session's {name} must be a positive number, not {v}"
            )));
        }
    }
    if visits.is_empty() {
        return Err(SessionError::Options("the list has no targets".into()));
    }
    let spec = &o.spec;
    // 1. Every row checked before anything moves.
    let planned = visits
        .iter()
        .enumerate()
        .map(|(i, v)| plan_row(spec, v, o, i + 1))
        .collect::<Result<Vec<_>, _>>()?;
    let grid_list = is_grid_list(visits, spec);
    rig.check_ready()?;
    let mut points: Vec<SessionPoint> = Vec::with_capacity(visits.len());
    let mut deferred = false;
    let mut t_end = 0.0;
    for (i, (v, &(commanded, from))) in visits.iter().zip(&planned).enumerate() {
        let id = format!("P{:03}", i + o.first_id);
        let at_point = |e: SessionError| match e {
            SessionError::Link(_) | SessionError::NotSettled(_) | SessionError::NotReady(_) => {
                SessionError::Point {
                    point: id.clone(),
                    row: i + 1,
                    reason: e.to_string(),
                }
            }
            other => other,
        };
        // 2. Approach, then the target.
        let before = if from != commanded {
            Some(rig.move_to(from).map_err(at_point)?.encoder_rad)
        } else {
            None
        };
        let ended = rig.move_to(commanded).map_err(at_point)?;
        // 3. Settle.
        let settled = rig.settle(ended.t_s, &o.settle).map_err(at_point)?;
        let dir = [0, 1].map(|j| {
            let last = before.map_or(points.last().map(|p| p.settled.encoder_rad[j]), |b| {
                Some(b[j])
            });
            match last {
                Some(b) if wrap_angle_rad(settled.encoder_rad[j] - b) < 0.0 => -1,
                Some(_) => 1,
                None => v.dir.map_or(1, |d| d[j]),
            }
        });
        // 4. Read.
        let request = PointRequest {
            index: i,
            id: id.clone(),
            target_mm: commanded,
            encoder_rad: settled.encoder_rad,
        };
        let reading_mm = match rig.read(&request)? {
            Reading::Point(p) => {
                if !(p[0].is_finite() && p[1].is_finite()) {
                    return Err(SessionError::Reading {
                        point: id,
                        reason: format!("{p:?} is not a position"),
                    });
                }
                Some(p)
            }
            Reading::Missing => None,
            Reading::Deferred => {
                deferred = true;
                None
            }
        };
        let true_mm = reading_mm.and(rig.truth_mm());
        points.push(SessionPoint {
            id: id.clone(),
            listed_mm: v.target_mm,
            commanded_mm: commanded,
            settled,
            dir,
            reading_mm,
            true_mm,
        });
        if let Some((k, d)) = worst_misfit(&points, spec) {
            if d > o.plausible_mm {
                return Err(SessionError::Reading {
                    point: points[k].id.clone(),
                    reason: format!(
                        "is {d:.3} mm from where the other readings put it (more than {} mm): a wrong point sighted, a unit mistake or a reflector knocked; measure it again",
                        o.plausible_mm
                    ),
                });
            }
        }
        t_end = settled.t_s;
        progress(i + 1, visits.len());
    }
    rig.finish()?;
    Ok(result(
        rig.describe(),
        points,
        visits,
        grid_list,
        deferred,
        o,
        t_end,
    ))
}

/// The CSV rows and the report of the visited points.
fn result(
    rig: String,
    points: Vec<SessionPoint>,
    visits: &[Visit],
    grid_list: bool,
    deferred: bool,
    o: &SessionOptions,
    t_end: f64,
) -> SessionResult {
    let target = |p: &SessionPoint| {
        if grid_list {
            p.listed_mm
        } else {
            p.commanded_mm
        }
    };
    let measurements: Vec<Measurement> = points
        .iter()
        .zip(visits)
        .filter_map(|(p, v)| {
            Some(Measurement {
                theta_deg: p.settled.encoder_rad.map(f64::to_degrees),
                measured_mm: p.reading_mm?,
                target_mm: Some(target(p)),
                dir: Some(p.dir),
                run: Some(v.run),
                t_s: Some(p.settled.t_s),
                line: 0,
            })
        })
        .collect();
    let commanded: Vec<CommandedRow> = points
        .iter()
        .zip(visits)
        .enumerate()
        .map(|(i, (p, v))| CommandedRow {
            line: i + 2,
            theta_deg: p.settled.encoder_rad.map(f64::to_degrees),
            target_mm: Some(target(p)),
            dir: Some(p.dir),
            run: Some(v.run),
        })
        .collect();
    let n = points.len().max(1) as f64;
    let report = SessionReport {
        rig,
        points: points.len(),
        read: measurements.len(),
        missing: if deferred {
            Vec::new()
        } else {
            points
                .iter()
                .filter(|p| p.reading_mm.is_none())
                .map(|p| p.id.clone())
                .collect()
        },
        deferred,
        moved_in: points
            .iter()
            .filter(|p| p.commanded_mm != p.listed_mm)
            .map(|p| {
                let d =
                    (p.commanded_mm[0] - p.listed_mm[0]).hypot(p.commanded_mm[1] - p.listed_mm[1]);
                (p.id.clone(), (d * 1e6).round() / 1e6)
            })
            .collect(),
        grid_list,
        settle: o.settle,
        settle_s_max: points
            .iter()
            .map(|p| p.settled.settle_s)
            .fold(0.0, f64::max),
        settle_s_mean: points.iter().map(|p| p.settled.settle_s).sum::<f64>() / n,
        following_error_urad_max: points
            .iter()
            .map(|p| p.settled.following_error_rad * 1e6)
            .fold(0.0, f64::max),
        machine_time_s: t_end,
    };
    SessionResult {
        points,
        measurements,
        commanded,
        report,
    }
}
