//! The excitation run: the excitation's knots streamed to a controller over its link with the
//! telemetry recorded ([`run_on_link`]: a real machine, the QEMU firmware, a co-simulated
//! controller), or run by the host loop on a simulated plant with the same record made
//! ([`run_on_plant`]: the core's servo on the six-bar plant, telemetry as the controller sends
//! it). Either way the result is the knots as played and a telemetry log.
//!
//! On the link: the controller must be running (homed, no fault); the machine moves to the
//! excitation's start with a planned move (`MoveTo`) unless it is there, the telemetry is
//! subscribed at `decimation`, the knots are streamed with flow control
//! (`link::stream_knots`) after a lead at rest (two rest knots 1 s apart: the host fills the
//! controller's buffer meanwhile), and the run waits until the controller's motion has ended,
//! reading the link meanwhile (a co-simulated controller advances while it is read). A fault
//! during the run is an error naming it; the machine is then stopped by the controller itself.

use super::excitation::{excitation, Excitation, ExcitationOptions};
use super::telemetry::{from_link, from_loop, meta_for};
use super::DynError;
use crate::io::telemetry_csv::TelemetryLog;
use crate::link::link_protocol::{self, Command, HomingState, Knot, ModeCode, StatusReport};
use crate::link::{stream_knots, LinkClient, Progress};
use crate::machine_spec::MachineSpec;
use crate::plant::{Plant, PlantConfig};
use crate::sim::closed_loop::{loop_config, run_loop_configured, FeedForward};
use crate::sim::knots::KnotPath;
use kinematics_core::{Calibration, ServoConfig};
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// An excitation run's record.
#[derive(Clone, Debug)]
pub struct ExcitationRun {
    /// The excitation as designed.
    pub excitation: Excitation,
    /// The knots as played (from where the machine rested when the stream began).
    pub path: KnotPath,
    /// The telemetry.
    pub log: TelemetryLog,
}

/// A run on a simulated plant.
#[derive(Clone, Debug)]
pub struct PlantRunOptions {
    pub spec: MachineSpec,
    pub excitation: ExcitationOptions,
    /// Servo samples per telemetry sample (the link's: at least 20).
    pub decimation: u32,
    /// What the servo feeds forward during the run (a controller feeds forward its image's
    /// dynamics, or the gains' constant inertia without them).
    pub feedforward: FeedForward,
    /// The servo's settings (`None`: the host loop's, `sim::closed_loop::loop_config`).
    pub servo: Option<ServoConfig>,
    /// Seeds the plant.
    pub seed: u64,
}

/// Runs the excitation on `plant` in the host loop (the servo commanding through `cal`).
pub fn run_on_plant(
    plant: &PlantConfig,
    cal: &Calibration<'_>,
    opts: &PlantRunOptions,
) -> Result<ExcitationRun, DynError> {
    check_decimation(opts.decimation)?;
    let ex = excitation(&opts.spec, &opts.excitation)?;
    let trajectory = ex.trajectory();
    let mut p = Plant::new(plant, opts.seed);
    let config = opts.servo.unwrap_or_else(|| loop_config(&p, &opts.spec));
    let mut rows = Vec::new();
    let run = run_loop_configured(
        &mut p,
        cal,
        &trajectory,
        trajectory.natural_duration_s(),
        &opts.spec,
        &opts.feedforward,
        config,
        Some(&mut rows),
    )?;
    if let Some(f) = run.fault {
        return Err(DynError::Telemetry(format!(
            "the excitation run faulted: {f}"
        )));
    }
    let log = from_loop(&rows, meta_for(&opts.spec, opts.decimation));
    Ok(ExcitationRun {
        path: ex.path.clone(),
        excitation: ex,
        log,
    })
}

fn check_decimation(d: u32) -> Result<(), DynError> {
    if !(20..=2000).contains(&d) {
        return Err(DynError::Invalid(format!(
            "telemetry decimation {d}: must be 20 (100 Hz, the link's fastest) to 2000"
        )));
    }
    Ok(())
}

/// A run through a controller's link.
#[derive(Clone, Debug)]
pub struct LinkRunOptions {
    pub spec: MachineSpec,
    pub excitation: ExcitationOptions,
    /// Servo samples per telemetry sample (at least 20).
    pub decimation: u16,
    /// How long the controller may take beyond the motion's own length before the run is given
    /// up (wall time; the controller's replies are bounded by the client's own timeout).
    pub slack: Duration,
    /// The host's wait between two status polls while the controller's knot buffer is full
    /// ([`LINK_POLL`] on a real link or QEMU's UART; zero on a co-simulated link, whose reads
    /// advance the simulation: a wall-clock wait there only stalls it).
    pub poll: Duration,
}

/// The wait between status polls on a link that runs by itself (a board, QEMU's UART): the
/// controller's buffer empties at a knot per 50 ms, so a few polls per knot are plenty.
pub const LINK_POLL: Duration = Duration::from_millis(20);

/// How far from the excitation's start the machine may rest for the stream to begin there (mm).
const AT_START_MM: f64 = 1e-3;

/// The stream begins with the machine held where it rests for `LEAD_KNOTS` segments of the
/// longest the link allows (`link_protocol::MAX_SEGMENT_US`, 1 s): the host fills the
/// controller's knot buffer ahead of the motion meanwhile. A link slower than the controller's
/// clock (QEMU's UART) otherwise starves the stream's first seconds (an underrun).
const LEAD_KNOTS: u32 = 2;

/// `knots` after the lead at `rest_mm` (their times shifted by the lead).
fn with_lead(rest_mm: [f32; 2], knots: &[Knot]) -> Vec<Knot> {
    let segment_us = link_protocol::MAX_SEGMENT_US;
    let lead_us = LEAD_KNOTS * segment_us;
    (1..=LEAD_KNOTS)
        .map(|i| Knot {
            t_us: i * segment_us,
            position_mm: rest_mm,
            velocity_mm_s: [0.0; 2],
        })
        .chain(knots.iter().map(|k| Knot {
            t_us: k.t_us + lead_us,
            position_mm: k.position_mm,
            velocity_mm_s: k.velocity_mm_s,
        }))
        .collect()
}

fn ready(s: &StatusReport) -> Result<(), DynError> {
    if s.mode != ModeCode::Running || s.fault.is_some() || s.homing != HomingState::Homed {
        return Err(DynError::Invalid(format!(
            "the controller is not ready to move: mode {:?}, fault {:?}, homing {:?} (home it \
             with host-sim link home, clear a fault with host-sim link reset)",
            s.mode, s.fault, s.homing
        )));
    }
    Ok(())
}

/// Waits until the controller's motion has ended (reading the link meanwhile: for `poll`
/// between status requests on a link that runs by itself; on a co-simulated one, `poll` zero,
/// the status requests alone run the simulation, so that the run takes the same simulated time
/// whatever the host's speed); its status.
fn wait_until_still<S: Read + Write>(
    client: &mut LinkClient<S>,
    limit: Duration,
    poll: Duration,
) -> Result<StatusReport, DynError> {
    let start = Instant::now();
    loop {
        let s = client.status()?;
        if (!s.moving || s.mode != ModeCode::Running) && s.mode != ModeCode::Stopping {
            return Ok(s);
        }
        if start.elapsed() > limit {
            return Err(DynError::Telemetry(format!(
                "the controller is still moving after {limit:?}: {s:?}"
            )));
        }
        if !poll.is_zero() {
            client.listen(poll)?;
        }
    }
}

/// Streams the excitation to the controller behind `client` and records its telemetry (see the
/// module doc). `progress` gets (knots queued, knots).
pub fn run_on_link<S: Read + Write>(
    client: &mut LinkClient<S>,
    opts: &LinkRunOptions,
    progress: Progress<'_>,
) -> Result<ExcitationRun, DynError> {
    let ex = excitation(&opts.spec, &opts.excitation)?;
    run_motion_on_link(client, ex, opts, progress)
}

/// Streams the motion `ex` (designed for the controller's limits: the excitation, or another
/// motion built as it is, `excitation::figure_eight`) as [`run_on_link`] streams the excitation,
/// and records its telemetry; `opts.excitation` is not used.
pub fn run_motion_on_link<S: Read + Write>(
    client: &mut LinkClient<S>,
    ex: Excitation,
    opts: &LinkRunOptions,
    progress: Progress<'_>,
) -> Result<ExcitationRun, DynError> {
    check_decimation(u32::from(opts.decimation))?;
    let s = client.status()?;
    ready(&s)?;
    let c = ex.start_mm;
    let at = |s: &StatusReport| {
        (f64::from(s.setpoint_mm[0]) - c[0]).hypot(f64::from(s.setpoint_mm[1]) - c[1])
    };
    let mut rest = s;
    if at(&rest) > AT_START_MM {
        client.request(Command::MoveTo {
            target_mm: [c[0] as f32, c[1] as f32],
        })?;
        rest = wait_until_still(client, opts.slack + Duration::from_secs(5), opts.poll)?;
        ready(&rest)?;
    }
    let start = rest.setpoint_mm.map(f64::from);
    let knots = with_lead(rest.setpoint_mm, &ex.knots);
    let path = KnotPath::new(start, &knots)?;
    client.request(Command::Telemetry {
        decimation: opts.decimation,
    })?;
    client.take_telemetry();
    let streamed = stream_knots(client, &knots, opts.poll, progress);
    // Whatever happened, the telemetry is switched off again before reporting.
    let ended = streamed.map_err(DynError::from).and_then(|()| {
        wait_until_still(
            client,
            opts.slack + Duration::from_secs_f64(2.0 * path.end_s()),
            opts.poll,
        )
    });
    let off = client.request(Command::Telemetry { decimation: 0 });
    let end = ended?;
    off?;
    // The telemetry still in flight (on a co-simulated link it came with the answers).
    if !opts.poll.is_zero() {
        client.listen(Duration::from_millis(100))?;
    }
    if let Some(f) = end.fault {
        return Err(DynError::Telemetry(format!(
            "the controller stopped the excitation with fault {f:?} (mode {:?}): reset it \
             (host-sim link reset) and run again",
            end.mode
        )));
    }
    let log = from_link(
        &client.take_telemetry(),
        Some(meta_for(&opts.spec, u32::from(opts.decimation))),
    );
    Ok(ExcitationRun {
        excitation: ex,
        path,
        log,
    })
}
