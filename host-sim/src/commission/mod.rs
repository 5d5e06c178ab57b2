//! The machine builder's journey through the controller, in one call: identify → home → plan →
//! measure → fit (the instrument's frame registered) → diagnose → dynamics (the excitation's
//! telemetry identified and diagnosed, the check motion run without the dynamics) → grid, two
//! rounds (each measured through the calibration uploaded before it, the identified dynamics
//! fed forward) → upload (the grid with the dynamics block) → verify at fresh targets → moving
//! (the check motion again: the following error the uploaded dynamics give) → the report.
//!
//! Everything goes over the controller's link (`link::LinkClient`: the co-simulation, QEMU on
//! TCP, a serial port) with an instrument beside it (`session::instrument`); every measurement
//! is a [`session`](crate::session) through the controller's own servo and calibration in
//! force, every fit and grid is the library's (`calib::fit`, `calib::grid`), every image is
//! judged as the controller will judge it before it is uploaded (`calib::image::seal_image`),
//! and the controller must report the uploaded image's id (CRC-32C of its bytes) in force
//! before the next step runs on it.
//!
//! | step | what | library |
//! |---|---|---|
//! | identify | firmware, board, the calibration in force | `Command::Identify` |
//! | home | the index search, when not homed | `Command::Home` |
//! | plan | identification poses, grid nodes, fresh verification targets | [`calib::plan`](crate::calib::plan) |
//! | measure | the identification poses, commanded with the calibration in force | [`session::run`] |
//! | fit | `full`, the instrument's frame registered | [`calib::fit`](crate::calib::fit) |
//! | diagnose | the static diagnosis on the same readings; a named backlash goes into the image, the six-bar's effects to the grid | [`diagnose`](crate::diagnose) |
//! | dynamics | the fitted model's image uploaded (no dynamics block); the excitation streamed, its telemetry identified and diagnosed; the check motion | [`dynamics`] |
//! | grid 1, grid 2 | the nodes inside the workspace measured through the fitted model, then through grid 1; the grid from both rounds (nodes outside the workspace estimated: `calib::grid::unmeasured`) | [`calib::grid`](crate::calib::grid) |
//! | upload | the final image (the last grid, the dynamics block); its id read back | [`link::upload_calibration`] |
//! | verify | fresh targets through the controller, the final image in force | [`session::run`] |
//! | moving | the check motion with the final image: its following error at the tool | [`dynamics`] |
//!
//! The accuracy (`final`): with a simulated machine, where the tool really landed (the plant's
//! tool point as a noiseless instrument reads it, mapped into the registered machine frame)
//! against the point commanded, as the demo's; on a real machine, what the instrument read
//! (its noise included). Nothing is written here: [`Commissioned::files`] holds every output,
//! for the caller to write together once the journey is complete.

pub mod cosim_instrument;
pub mod dynamics;
pub mod images;
pub mod motion;

use crate::calib::backlash::Backlash;
use crate::calib::fit::evaluate::Criterion;
use crate::calib::fit::{fit, FitOptions, FrameMode, Method, ModelFigures, Points};
use crate::calib::frame::{machine_frame_gauge, FrameSummary, InstrumentFrame};
use crate::calib::grid::{self, NoiseReport};
use crate::calib::plan::{list_rows, plan, Plan, PlanOptions};
use crate::calib::protocol::Visit;
use crate::diagnose::model_out::extended_model;
use crate::diagnose::{diagnose, DiagnoseOptions};
use crate::io::commanded_csv::format_commanded;
use crate::io::knots_csv::knots_text;
use crate::io::measurement_csv::{format_measurements, Measurement};
use crate::io::model_file::{model_file_text, ModelFile};
use crate::io::targets_csv::format_target_list;
use crate::io::telemetry_csv::telemetry_text;
use crate::link::link_protocol::{calibration_image_id, Command, HomingState, Response};
use crate::link::{upload_calibration, ClientError, LinkClient};
use crate::loop_closure::SixBarDesign;
use crate::machine_spec::MachineSpec;
use crate::numeric::{max_rms, round3, round6};
use crate::session::instrument::Instrument;
use crate::session::link_rig::LinkRig;
use crate::session::{self, SessionOptions, SessionResult};
use serde::Serialize;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// The accuracy the journey aims at with a 1 µm instrument (µm, max and RMS at fresh targets),
/// scaled with the instrument's σ above that.
pub const GOAL_UM: [f64; 2] = [1.0, 0.3];

/// Why the journey stopped: the step and what went wrong (complete, with what to do).
#[derive(Debug, thiserror::Error)]
#[error("{step}: {reason}")]
pub struct CommissionError {
    pub step: &'static str,
    pub reason: String,
}

fn at(step: &'static str) -> impl Fn(&dyn std::fmt::Display) -> CommissionError {
    move |e| CommissionError {
        step,
        reason: e.to_string(),
    }
}

/// How to run the journey.
#[derive(Clone, Debug)]
pub struct CommissionOptions {
    pub spec: MachineSpec,
    /// Draws the plan (identification candidates, verification targets).
    pub seed: u64,
    /// Identification poses (the plan's; 40 by default).
    pub identification_poses: usize,
    /// Fresh verification targets (400 by default).
    pub verify_targets: usize,
    /// Grid rounds: 1 or 2.
    pub grid_rounds: usize,
    pub session: SessionOptions,
    /// The dynamics and moving steps.
    pub moving: dynamics::MovingOptions,
}

impl CommissionOptions {
    /// The full journey on `spec`'s machine.
    pub fn for_machine(spec: &MachineSpec) -> Self {
        CommissionOptions {
            spec: spec.clone(),
            seed: 1,
            identification_poses: crate::calib::plan::IDENTIFICATION_POSES,
            verify_targets: crate::calib::plan::VERIFY_TARGETS,
            grid_rounds: 2,
            session: SessionOptions::for_machine(spec),
            moving: dynamics::MovingOptions::default(),
        }
    }
}

/// One step as the report lists it.
#[derive(Clone, Debug, Serialize)]
pub struct StepReport {
    pub step: &'static str,
    /// Wall time of the step (s).
    pub wall_s: f64,
    /// One line: what it did and found.
    pub what: String,
}

/// The fit in the report.
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    #[serde(flatten)]
    pub model: ModelFigures,
    pub residual_max_um: f64,
    pub residual_rms_um: f64,
    pub instrument_frame: FrameSummary,
}

/// A grid round in the report.
#[derive(Clone, Debug, Serialize)]
pub struct GridRound {
    pub round: usize,
    /// The lattice's nodes, and of them those estimated (outside the workspace, not measured).
    pub nodes: usize,
    pub nodes_estimated: usize,
    pub node_err_max_um: f64,
    pub node_err_rms_um: f64,
    pub noise: NoiseReport,
    pub calibration_id: String,
}

/// The verification at fresh targets (`final`).
#[derive(Clone, Debug, Serialize)]
pub struct FinalReport {
    /// Where the tool landed against the point commanded (µm): the truth with a simulated
    /// machine, the instrument's readings on a real one (`judged_on`).
    pub max_um: f64,
    pub rms_um: f64,
    /// What the instrument read, against the point commanded (µm).
    pub measured_max_um: f64,
    pub measured_rms_um: f64,
    pub n_targets: usize,
    pub judged_on: &'static str,
    pub target_max_um: f64,
    pub target_rms_um: f64,
    pub met: bool,
}

/// The static diagnosis in the report.
#[derive(Clone, Debug, Serialize)]
pub struct DiagnosisSummary {
    /// The effects named, in order.
    pub named: Vec<String>,
    pub rms_before_um: f64,
    pub rms_after_um: f64,
    /// What went into the controller's model: the backlash block (µrad), and the effects the
    /// grid takes.
    pub backlash_urad: Option<[f64; 2]>,
    pub for_the_grid: Vec<String>,
}

/// The journey's report (the command's JSON).
#[derive(Clone, Debug, Serialize)]
pub struct CommissionReport {
    pub machine: String,
    pub controller: String,
    /// The calibration id in force before the journey (hex), if any.
    pub calibration_id_before: Option<String>,
    pub steps: Vec<StepReport>,
    pub fit: FitReport,
    pub diagnosis: DiagnosisSummary,
    pub grid: Vec<GridRound>,
    /// The dynamics identified through the controller (the image's block) and diagnosed.
    pub dynamics: dynamics::DynamicsReport,
    /// The id the controller reports after the final upload: the CRC-32C of `grid.bin`
    /// (hex and number).
    pub calibration_id: String,
    pub calibration_id_u32: u32,
    #[serde(rename = "final")]
    pub final_: FinalReport,
    /// The check motion's following error with the final image, and before its upload.
    pub moving: dynamics::MovingReport,
    pub session_points: usize,
    pub wall_s: f64,
}

/// A finished journey: the report and every file to write (name, bytes).
pub struct Commissioned {
    pub report: CommissionReport,
    pub files: Vec<(String, Vec<u8>)>,
}

/// The names of the files a journey writes.
pub const FILES: [&str; 17] = [
    "plan_identify.csv",
    "plan_grid.csv",
    "plan_verify.csv",
    "fit_measurements.csv",
    "grid_measurements.csv",
    "grid_measurements_round2.csv",
    "verify_measurements.csv",
    "verify_angles.csv",
    "model.json",
    "grid.bin",
    "grid.csv",
    "dynamics.json",
    "excitation_telemetry.csv",
    "excitation_knots.csv",
    "moving_telemetry_before.csv",
    "moving_telemetry.csv",
    "commission.json",
];

/// The journey's state across steps.
struct Journey<'c, 'i, S: Read + Write> {
    client: &'c mut LinkClient<S>,
    instrument: &'i mut dyn Instrument,
    o: &'c CommissionOptions,
    steps: Vec<StepReport>,
    events: &'c mut dyn FnMut(&StepReport),
    points: usize,
}

impl<S: Read + Write> Journey<'_, '_, S> {
    fn done(&mut self, step: &'static str, started: Instant, what: String) {
        let r = StepReport {
            step,
            wall_s: round3(started.elapsed().as_secs_f64()),
            what,
        };
        (self.events)(&r);
        self.steps.push(r);
    }

    fn measure(
        &mut self,
        step: &'static str,
        list: &[Visit],
    ) -> Result<SessionResult, CommissionError> {
        let mut rig = LinkRig::new(self.client, self.instrument, self.o.spec.sample_period_s);
        let r = session::run(&mut rig, list, &self.o.session, &mut |_, _| {});
        if r.is_err() {
            let _ = crate::session::Rig::finish(&mut rig);
        }
        let r = r.map_err(|e| at(step)(&e))?;
        self.points += r.points.len();
        Ok(r)
    }

    /// Uploads `image` and waits until the controller has it in force; returns its id. The
    /// machine waits at the workspace's centre, where any calibration of it engages (the
    /// controller switches at rest, re-engaging where the new calibration puts the tool: near
    /// an edge that can be outside the new calibration's workspace).
    fn upload(&mut self, step: &'static str, image: &[u8]) -> Result<u32, CommissionError> {
        let centre = self.o.spec.workspace.centre_mm();
        self.client
            .request(Command::MoveTo {
                target_mm: centre.map(|v| v as f32),
            })
            .map_err(|e| at(step)(&e))?;
        motion::wait_still(self.client, 120.0).map_err(|e| at(step)(&e))?;
        let id = upload_calibration(self.client, image, &mut |_, _| {}).map_err(|e| {
            let next = match &e {
                ClientError::Refused { .. } => {
                    "the controller judged the image and kept the calibration it had (its \
                     refusal names what it found against the machine it holds)"
                }
                _ => "the controller keeps the calibration it had (check the link, then run again)",
            };
            at(step)(&format!("{e}; {next}"))
        })?;
        let start = Instant::now();
        loop {
            match self.client.request(Command::Identify).map_err(|e| at(step)(&e))? {
                Response::Identity(i) if i.calibration_id == Some(id) => return Ok(id),
                _ if start.elapsed() > Duration::from_secs(60) => {
                    return Err(at(step)(&format!(
                        "the controller accepted image {id:#010x} but did not put it in force within 60 s"
                    )))
                }
                // The next request is the wait (in co-simulation it advances the simulation).
                _ => {}
            }
        }
    }
}

/// The node readings' errors (µm) referred to the command the calibration in `image` gives
/// the node itself: `e − J·(θ − θ_node)`, the error the machine shows through that calibration
/// at the node (a reading taken just inside the soft limit counts at its node).
fn node_errors_um(
    model: &kinematics_core::FiveBar<f64>,
    image: &[u8],
    rows: &[Measurement],
    spec: &MachineSpec,
) -> Vec<f64> {
    let Ok(grid) = kinematics_core::CorrectionGrid::parse(image) else {
        return Vec::new();
    };
    let cal = kinematics_core::Calibration::from_grid(grid);
    rows.iter()
        .filter_map(|m| {
            let t = m.target_mm?;
            let c = cal
                .command_rad([t[0] as f32, t[1] as f32], spec.min_transmission as f32)
                .ok()?
                .map(f64::from);
            let jac = model.forward_pose(c, 0.0).ok()?.jacobian().ok()?;
            let th = m.theta_rad();
            let d = [
                kinematics_core::wrap_angle_rad(th[0] - c[0]),
                kinematics_core::wrap_angle_rad(th[1] - c[1]),
            ];
            let e = [
                m.measured_mm[0] - t[0] - (jac[0][0] * d[0] + jac[0][1] * d[1]),
                m.measured_mm[1] - t[1] - (jac[1][0] * d[0] + jac[1][1] * d[1]),
            ];
            Some(e[0].hypot(e[1]) * 1e3)
        })
        .collect()
}

/// Readings in the machine frame, their targets as recorded (nodes for a grid list).
fn registered(r: &SessionResult, frame: &InstrumentFrame) -> Vec<Measurement> {
    frame.register(&r.measurements)
}

/// Homes the controller if it is not homed; waits until it runs with the drives on.
fn home<S: Read + Write>(client: &mut LinkClient<S>) -> Result<String, ClientError> {
    let s = client.status()?;
    if s.homing == HomingState::Homed && s.fault.is_none() && s.drives_enabled {
        return Ok("already homed and running".into());
    }
    client.request(Command::Home)?;
    let start = Instant::now();
    loop {
        let s = client.status()?;
        if let Some(f) = s.fault {
            return Err(ClientError::Trajectory(format!("homing faulted: {f:?}")));
        }
        if s.homing == HomingState::Failed {
            return Err(ClientError::Trajectory(
                "homing failed (index marks not found): check the encoders' index lines".into(),
            ));
        }
        if s.homing == HomingState::Homed && s.drives_enabled && !s.moving {
            return Ok(format!(
                "homed on the index marks; at ({:.3}, {:.3}) mm",
                s.setpoint_mm[0], s.setpoint_mm[1]
            ));
        }
        if start.elapsed() > Duration::from_secs(120) {
            return Err(ClientError::Timeout(Duration::from_secs(120)));
        }
    }
}

/// Runs the journey (module doc) over `client` with `instrument`; `events` hears every step
/// as it ends.
pub fn commission<S: Read + Write>(
    client: &mut LinkClient<S>,
    instrument: &mut dyn Instrument,
    o: &CommissionOptions,
    events: &mut dyn FnMut(&StepReport),
) -> Result<Commissioned, CommissionError> {
    if !(1..=2).contains(&o.grid_rounds) {
        return Err(at("options")(&"grid rounds must be 1 or 2"));
    }
    let spec = &o.spec;
    let begun = Instant::now();
    let mut j = Journey {
        client,
        instrument,
        o,
        steps: Vec::new(),
        events,
        points: 0,
    };

    let t = Instant::now();
    let identity = match j
        .client
        .request(Command::Identify)
        .map_err(|e| at("identify")(&e))?
    {
        Response::Identity(i) => i,
        other => return Err(at("identify")(&format!("unexpected reply {other:?}"))),
    };
    // Without a calibration in force the controller neither homes nor moves: say why here.
    let Some(before_id) = identity.calibration_id else {
        return Err(at("identify")(
            &"the controller holds no calibration it accepts (none in force): it refused the \
              image in its calibration region, or the region is empty. Give it this machine's \
              commissioning image (host-sim grid --nominal --machine FILE --out FILE, flashed as \
              docs/guides/g474-bring-up.md says); a controller that refuses that too holds another machine",
        ));
    };
    let before = Some(format!("{before_id:#010x}"));
    let v = identity.firmware_version;
    let controller = format!("{:?} firmware {}.{}.{}", identity.board, v[0], v[1], v[2]);
    j.done(
        "identify",
        t,
        format!(
            "{controller}; calibration in force {}",
            before.as_deref().unwrap_or("none")
        ),
    );

    let t = Instant::now();
    let what = home(j.client).map_err(|e| at("home")(&e))?;
    j.done("home", t, what);

    let t = Instant::now();
    let mut po = PlanOptions::new(spec.clone(), o.seed);
    po.identification_poses = o.identification_poses;
    po.verify_targets = o.verify_targets;
    let p: Plan = plan(&po).map_err(|e| at("plan")(&e))?;
    j.done(
        "plan",
        t,
        format!(
            "{} identification poses (condition number {:.1}), {} grid nodes, {} fresh verification targets",
            p.identify.len(),
            p.report.identification.chosen.condition_number,
            p.grid.len(),
            p.verify.len()
        ),
    );

    let t = Instant::now();
    let ident = j.measure("measure", &p.identify)?;
    j.done(
        "measure",
        t,
        format!(
            "{} poses through the controller; settled within {:.3} s",
            ident.report.read, ident.report.settle_s_max
        ),
    );

    let t = Instant::now();
    let fitted = fit(
        &ident.measurements,
        &FitOptions {
            method: Method::Full,
            criterion: Criterion::Measured,
            points: Points::All,
            fixed: Vec::new(),
            leave_one_out: false,
            reject_sigma: crate::calib::fit::blunders::DEFAULT_REJECT_SIGMA,
            frame: FrameMode::Register,
            spec: spec.clone(),
        },
        &mut |_| {},
    )
    .map_err(|e| at("fit")(&e))?;
    // The frame and model as model.json stores them.
    let frame = fitted
        .frame
        .map(|f| InstrumentFrame::from_record(&f.record()))
        .unwrap_or(InstrumentFrame::IDENTITY);
    let fit_rows = registered(&ident, &frame);
    let fit_report = FitReport {
        model: ModelFigures::of(&fitted.model),
        residual_max_um: round3(fitted.summary.max_err_um),
        residual_rms_um: round3(fitted.summary.rms_err_um),
        instrument_frame: frame.summary(),
    };
    j.done(
        "fit",
        t,
        format!(
            "full fit: residual {:.2} / {:.2} µm; the instrument stood at ({:.3}, {:.3}) mm, {:.4}°",
            fit_report.residual_max_um,
            fit_report.residual_rms_um,
            frame.to_instrument.offset_mm[0],
            frame.to_instrument.offset_mm[1],
            frame.to_instrument.rotation_rad.to_degrees()
        ),
    );

    // The static diagnosis on the same readings: a backlash it names goes into the image (the
    // servo compensates it); the six-bar's own effects are left to the grid.
    let t = Instant::now();
    let sixbar = SixBarDesign::for_model(&spec.nominal, spec.workspace.centre_mm())
        .map_err(|e| at("diagnose")(&e))?;
    let report = diagnose(
        &fit_rows,
        &DiagnoseOptions {
            base: fitted.model,
            noise_um: Some(spec.instrument_sigma_um),
            sixbar,
        },
    )
    .map_err(|e| at("diagnose")(&e))?;
    let extended = extended_model(&fitted.model, &report).map_err(|e| at("diagnose")(&e))?;
    // Back in the machine frame's convention (a frame the diagnosis folded into A0 goes into
    // the registration).
    let (model, g) = machine_frame_gauge(&extended.model, &spec.nominal);
    let frame = InstrumentFrame::from_record(
        &InstrumentFrame {
            to_instrument: frame.to_instrument.after(&g),
            std_dev: frame.std_dev,
        }
        .record(),
    );
    let model = ModelFile::from_model(&model)
        .model()
        .map_err(|e| at("diagnose")(&e))?;
    let backlash = match extended.backlash_urad {
        Some(b) => Some(Backlash::new(b).map_err(|e| at("diagnose")(&e))?),
        None => None,
    };
    let diagnosis = DiagnosisSummary {
        named: report.steps.iter().map(|s| s.effect.clone()).collect(),
        rms_before_um: round3(report.initial_rms_um),
        rms_after_um: round3(
            report
                .steps
                .last()
                .map_or(report.initial_rms_um, |s| s.rms_after_um),
        ),
        backlash_urad: extended.backlash_urad.map(|b| b.map(round3)),
        for_the_grid: extended.for_the_grid.keys().cloned().collect(),
    };
    j.done(
        "diagnose",
        t,
        if diagnosis.named.is_empty() {
            "nothing named beyond the five-bar: the grid takes what is left".into()
        } else {
            format!(
                "named {} (RMS {:.2} → {:.2} µm){}",
                diagnosis.named.join(", "),
                diagnosis.rms_before_um,
                diagnosis.rms_after_um,
                diagnosis.backlash_urad.map_or(String::new(), |b| format!(
                    "; backlash {:.1}, {:.1} µrad into the image",
                    b[0], b[1]
                ))
            )
        },
    );
    // The moving machine, through the fitted model's image without dynamics (what the
    // commissioning image feeds forward: nothing): the dynamics identified and diagnosed, the
    // check motion as this image runs it. The grid rounds then run with the identified
    // dynamics fed forward, as the final image will: the static positions the grid learns
    // depend on how the servo approaches them.
    let t = Instant::now();
    let image0 = images::model_image(
        &model,
        spec,
        images::Extras {
            dynamics: None,
            backlash: backlash.as_ref(),
        },
    )
    .map_err(|e| at("dynamics")(&e))?;
    j.upload("dynamics", &image0)?;
    let mo = &o.moving;
    let dy = dynamics::identify(j.client, spec, &model, mo).map_err(|e| at("dynamics")(&e))?;
    let (moving_before, shape, before_run) =
        dynamics::check_run(j.client, spec, &model, mo).map_err(|e| at("dynamics")(&e))?;
    j.done("dynamics", t, dy.report.line(&shape, &moving_before));
    let extras = images::Extras {
        dynamics: Some(&dy.block),
        backlash: backlash.as_ref(),
    };

    // Grid round 1: the nodes commanded through the fitted model alone.
    let t = Instant::now();
    let image = images::model_image(&model, spec, extras).map_err(|e| at("grid 1")(&e))?;
    let id0 = j.upload("grid 1", &image)?;
    // The nodes the controller can be driven to; the others (outside a workspace smaller than
    // the grid's rectangle) are estimated by the grid from these.
    let grid_list: Vec<Visit> = p
        .grid
        .iter()
        .filter(|v| images::node_reachable(spec, v.target_mm))
        .copied()
        .collect();
    let nodes1 = j.measure("grid 1", &grid_list)?;
    let link = |r: &SessionResult| -> Result<Vec<Measurement>, CommissionError> {
        let rows = registered(r, &frame);
        match &backlash {
            Some(b) => b.link_angles(&rows).map_err(|e| at("grid")(&e)),
            None => Ok(rows),
        }
    };
    let rows1 = link(&nodes1)?;
    let (g1, image1) =
        images::grid_image(&model, &rows1, spec, extras).map_err(|e| at("grid 1")(&e))?;
    let e1 = max_rms(&node_errors_um(
        &model,
        &image,
        &registered(&nodes1, &frame),
        spec,
    ));
    let mut rounds = vec![GridRound {
        round: 1,
        nodes: g1.built.nodes.len(),
        nodes_estimated: g1.estimated.len(),
        node_err_max_um: round3(e1.max),
        node_err_rms_um: round3(e1.rms),
        noise: g1.built.noise.clone(),
        calibration_id: format!("{id0:#010x}"),
    }];
    j.done(
        "grid 1",
        t,
        format!(
            "{} nodes through the fitted model (image {id0:#010x}); node error {:.2} / {:.2} µm",
            g1.built.nodes.len() - g1.estimated.len(),
            rounds[0].node_err_max_um,
            rounds[0].node_err_rms_um
        ),
    );
    let mut final_grid = (g1, image1);
    let mut nodes2 = None;
    if o.grid_rounds == 2 {
        let t = Instant::now();
        let id1 = j.upload("grid 2", &final_grid.1)?;
        let n2 = j.measure("grid 2", &grid_list)?;
        let both: Vec<Measurement> = rows1.iter().cloned().chain(link(&n2)?).collect();
        let (g2, image2) =
            images::grid_image(&model, &both, spec, extras).map_err(|e| at("grid 2")(&e))?;
        let e2 = max_rms(&node_errors_um(
            &model,
            &final_grid.1,
            &registered(&n2, &frame),
            spec,
        ));
        rounds.push(GridRound {
            round: 2,
            nodes: g2.built.nodes.len(),
            nodes_estimated: g2.estimated.len(),
            node_err_max_um: round3(e2.max),
            node_err_rms_um: round3(e2.rms),
            noise: g2.built.noise.clone(),
            calibration_id: format!("{id1:#010x}"),
        });
        j.done(
            "grid 2",
            t,
            format!(
                "{} nodes through grid 1 (image {id1:#010x}); their error {:.2} / {:.2} µm; the grid from both rounds",
                g2.built.nodes.len() - g2.estimated.len(),
                round3(e2.max),
                round3(e2.rms)
            ),
        );
        final_grid = (g2, image2);
        nodes2 = Some(n2);
    }

    let t = Instant::now();
    let grid_bin = final_grid.1.clone();
    let id = j.upload("upload", &grid_bin)?;
    if id != calibration_image_id(&grid_bin) {
        return Err(at("upload")(&format!(
            "the controller reports {id:#010x}, the file's id is {:#010x}",
            calibration_image_id(&grid_bin)
        )));
    }
    j.done(
        "upload",
        t,
        format!(
            "grid.bin ({} bytes, the dynamics block included) in force: calibration id {id:#010x}",
            grid_bin.len()
        ),
    );

    let t = Instant::now();
    let verify = j.measure("verify", &p.verify)?;
    let final_ = final_report(&verify, &frame, spec);
    j.done(
        "verify",
        t,
        format!(
            "{} fresh targets through the controller: {:.3} / {:.3} µm max / RMS ({}; measured {:.2} / {:.2})",
            final_.n_targets,
            final_.max_um,
            final_.rms_um,
            final_.judged_on,
            final_.measured_max_um,
            final_.measured_rms_um
        ),
    );

    let t = Instant::now();
    let (after, _, after_run) =
        dynamics::check_run(j.client, spec, &model, mo).map_err(|e| at("moving")(&e))?;
    let moving = dynamics::MovingReport {
        motion: format!(
            "figure-eight at the stream limits, {:.1} g",
            shape.peak_accel_g
        ),
        peak_accel_g: shape.peak_accel_g,
        peak_speed_mm_s: shape.peak_speed_mm_s,
        duration_s: shape.duration_s,
        max_following_um: after.max_following_um,
        rms_following_um: after.rms_following_um,
        before: moving_before,
    };
    j.done("moving", t, moving.line());

    // The files.
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    for (name, list) in [
        ("identify", &p.identify),
        ("grid", &p.grid),
        ("verify", &p.verify),
    ] {
        files.push((
            format!("plan_{name}.csv"),
            format_target_list(&list_rows(list)).into_bytes(),
        ));
    }
    files.push((
        "fit_measurements.csv".into(),
        format_measurements(&ident.measurements).into_bytes(),
    ));
    files.push((
        "grid_measurements.csv".into(),
        format_measurements(&nodes1.measurements).into_bytes(),
    ));
    if let Some(n2) = &nodes2 {
        files.push((
            "grid_measurements_round2.csv".into(),
            format_measurements(&n2.measurements).into_bytes(),
        ));
    }
    files.push((
        "verify_measurements.csv".into(),
        format_measurements(&verify.measurements).into_bytes(),
    ));
    files.push((
        "verify_angles.csv".into(),
        format_commanded(&verify.commanded).into_bytes(),
    ));
    let mut mf = ModelFile::from_model(&model);
    mf.std_dev = fitted.std_dev.clone();
    mf.fit = Some(
        serde_json::json!({ "method": "full", "source": "host-sim commission", "n_points": ident.measurements.len() }),
    );
    mf.backlash_urad = extended.backlash_urad;
    mf.instrument_frame = Some(frame.record());
    files.push((
        "model.json".into(),
        model_file_text(&mf)
            .map_err(|e| at("files")(&e))?
            .into_bytes(),
    ));
    files.push(("grid.bin".into(), grid_bin));
    files.push((
        "grid.csv".into(),
        grid::format_csv(&final_grid.0.built.nodes).into_bytes(),
    ));
    let dynamics_json = crate::io::json_text(&dy.file, crate::io::KeyOrder::Declared)
        .map_err(|e| at("files")(&e))?;
    files.push(("dynamics.json".into(), dynamics_json.into_bytes()));
    for (name, text) in [
        ("excitation_telemetry.csv", telemetry_text(&dy.run.log)),
        ("excitation_knots.csv", knots_text(dy.run.path.knots())),
        (
            "moving_telemetry_before.csv",
            telemetry_text(&before_run.log),
        ),
        ("moving_telemetry.csv", telemetry_text(&after_run.log)),
    ] {
        files.push((name.into(), text.into_bytes()));
    }
    let report = CommissionReport {
        machine: spec.name.clone(),
        controller,
        calibration_id_before: before,
        steps: j.steps,
        fit: fit_report,
        diagnosis,
        grid: rounds,
        dynamics: dy.report,
        calibration_id: format!("{id:#010x}"),
        calibration_id_u32: id,
        final_,
        moving,
        session_points: j.points,
        wall_s: round3(begun.elapsed().as_secs_f64()),
    };
    Ok(Commissioned { report, files })
}

/// The verification's figures: truth where the rig knows it, else the readings.
fn final_report(v: &SessionResult, frame: &InstrumentFrame, spec: &MachineSpec) -> FinalReport {
    let err = |p: [f64; 2], t: [f64; 2]| {
        let q = frame.to_machine_mm(p);
        (q[0] - t[0]).hypot(q[1] - t[1]) * 1e3
    };
    let measured: Vec<f64> = v
        .points
        .iter()
        .filter_map(|p| Some(err(p.reading_mm?, p.commanded_mm)))
        .collect();
    let truth: Vec<f64> = v
        .points
        .iter()
        .filter_map(|p| Some(err(p.true_mm?, p.commanded_mm)))
        .collect();
    let (judged, judged_on) = if truth.len() == v.points.len() && !truth.is_empty() {
        (
            max_rms(&truth),
            "where the tool landed (simulation's truth)",
        )
    } else {
        (max_rms(&measured), "the instrument's readings")
    };
    let m = max_rms(&measured);
    let k = spec.instrument_sigma_um.max(1.0);
    let target = [GOAL_UM[0] * k, GOAL_UM[1] * k];
    FinalReport {
        max_um: round6(judged.max),
        rms_um: round6(judged.rms),
        measured_max_um: round6(m.max),
        measured_rms_um: round6(m.rms),
        n_targets: measured.len(),
        judged_on,
        target_max_um: target[0],
        target_rms_um: target[1],
        met: judged.max <= target[0] && judged.rms <= target[1],
    }
}
