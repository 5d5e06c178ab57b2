//! The whole calibration story on one machine (`host-sim demo`): plan, measure, fit, grid,
//! verify, in one process, on a machine whose truth is known, stating the accuracy after every
//! step.
//!
//! Why: this is what docs/getting-started.md shows first. It runs exactly what a machine builder
//! runs with the separate commands, through the same library functions, so the commands reproduce
//! it (the step-by-step guide's command-by-command workflow, checked by `tests/workflow.rs`):
//!
//! | step | library function | command | noise seed |
//! |---|---|---|---|
//! | 0. the lists (identification poses chosen for identifiability, grid nodes, verification targets, repeat runs) | [`super::plan::plan`] | `plan --seed S` | — |
//! | 1. measure the identification poses, nominal model | [`super::measure::measure_list`] | `measure --targets identify.csv` | 10·S + 1 |
//! | 2. fit: the paper's `ls` (links only, for comparison) and `full` (LM: links, A0, B0, encoder offsets) | [`super::fit::fit`] | `fit --method ls`, `fit --method full` | — |
//! | 3. measure the grid nodes commanded with the `full` model; build the grid (+ the workspace block; the machine record last, judged as the controller judges it) | `measure_list`, [`super::grid::build`], [`super::image::finish_image`], [`super::image::seal_image`] | `measure --targets grid.csv --model`, `grid` | 10·S + 5 |
//! | 4. measure the nodes again through that grid; rebuild it from both rounds' readings (round 2, the image to flash) | the same | `measure --grid`, `grid --data grid1.csv --data grid2.csv` | 10·S + 7 |
//! | 5. verify every stage on the verification targets: nominal, `ls`, `full`, `full` + grid, `full` + refined grid | `measure_list`, [`super::measure::accuracy`] | `measure --targets verify.csv [--model M] [--grid G]` | 10·S + 2, 3, 4, 6, 8 |
//!
//! Each list is measured as `measure --seed` measures it (the instrument's noise restarted from
//! the step's seed, the clock from 0), and the fits and the grid read the measurements as the
//! CSV files hold them (rounded to 1 nm and 1e-9°, [`round_trip`]), so the files give the same
//! models, images and figures bit for bit.
//!
//! The grid is first order in the error it corrects, so where the fit leaves a large error one
//! round leaves ~1 % of it and the second removes that (the six-bar plant with A0 held at the
//! origin: fit ~1 mm, one round 16 µm, two 6 µm); after a good fit both sit at the floor.
//! Round 2 is built from both rounds' readings (two per node, each referred to the node's IK
//! command, so the instrument's noise in the grid drops by √2; the grid smooths the node errors
//! and applies no correction the noise would swamp, see [`super::grid`]): with a 10 µm
//! instrument this is what brings fit + grid under 6 µm; with 1 µm both rounds sit at the floor.
//! Accuracy = distance from the target to where the tool really is (the machine's noiseless
//! truth as a perfect instrument would read it, mapped into the machine frame the `full` fit
//! registered, [`super::frame`]: the nominal stage too; the `ls` stage in its own registered
//! frame); the noisy readings are reported too. The paper's `ls` fit failing is its own
//! result: the run goes on without its row. Every target is commanded exactly as the firmware
//! does (`Calibration::command_rad`, f32).
//!
//! Approach: the lists carry the machine's policy ([`PipelineOptions::approach`]). With
//! [`Approach::Positive`] every motor arrives moving forward (as after an overshoot-and-return
//! move): unidirectional positioning, so backlash always sits on one side and is calibrated
//! away; with [`Approach::FromVisit`] each motor arrives as the motion from `approach_mm` away
//! along a random direction (grid nodes in raster order) makes it. Then, after step 3's
//! measurement, the backlash is measured on [`BACKLASH_POSES`] random poses of its own (noise
//! seed 10·S + 9; [`super::backlash::estimate`]; kept where > 3σ) and corrected from there on
//! by direction (each motor's command moved by dir·β/2, [`measure_list_compensated`]; the grids
//! built from link angles): on the paper plant its 20 µrad, which left 5.14 µm max / 2.81 µm RMS
//! uncorrected, are taken out (figures in docs/reference/calibration-tools.md). The separate
//! commands do this step with `diagnose --out-model` (docs/design/diagnosis.md, "Closing the
//! loop").
//!
//! Output: [`calibrate`] keeps everything in memory ([`Calibrated`]); [`write_outputs`] writes the
//! plan's lists, the measurement CSVs, `model.json` (`full`), `model_ls.json`, `grid.bin` +
//! `grid.csv` (the refined grid) and PNG error-vector plots ([`FILES`], each atomically);
//! [`summary`] is the JSON report. The machine is behind [`super::machine::Machine`]. Cost:
//! ~2.2 k measurements, the plan's selection and two fits: about a second.

use super::backlash::{self, Backlash};
use super::fit::evaluate::Criterion;
use super::fit::full::FullFit;
use super::fit::params::NAMES;
use super::fit::{fit, FitOptions, Method, Points};
use super::frame::InstrumentFrame;
use super::grid::{self, BuiltGrid};
use super::image::{finish_image, seal_image};
use super::machine::Machine;
use super::measure::{measure_list_compensated, registered, rows, Landed};
use super::plan::{plan, with_approach, Plan, PlanOptions};
use super::protocol::{random_visits, Range, Visit};
use super::{invalid, CalibError};
use crate::io::measurement_csv::{format_measurements, parse_measurements, Measurement};
use crate::io::model_file::ModelFile;
use crate::loop_closure::SixBarDesign;
use crate::machine_identity::MachineIdentity;
use crate::machine_spec::MachineSpec;
use kinematics_core::{Calibration, CorrectionGrid, FiveBar};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

mod files;
mod summary;

pub use files::{write_outputs, FILES};
pub use summary::{
    summary, FinalSummary, FullFitSummary, GridSummary, LsFitSummary, StageSummary, Summary,
};

pub use super::measure::{
    accuracy, measured_error_vectors_um, true_error_vectors_um, Accuracy, Approach,
};

/// Poses measured for the fits (the plan's identification poses).
pub const FIT_POSES: usize = super::plan::IDENTIFICATION_POSES;
/// Random poses measured for the backlash (random approach only).
pub const BACKLASH_POSES: usize = 200;
/// Fresh random targets per verification (the plan's verification list).
pub const VERIFY_TARGETS: usize = super::plan::VERIFY_TARGETS;
/// The accuracy to reach: the 1 µm instrument's noise floor.
pub const TARGET_MAX_UM: f64 = 5.0;
pub const TARGET_RMS_UM: f64 = 2.0;

/// The accuracy goal `[max, RMS]` (µm) of a run on `spec`'s machine: the noise floor,
/// [`TARGET_MAX_UM`] / [`TARGET_RMS_UM`] with a 1 µm instrument, scaled with the instrument's σ
/// above that (the grid and the fit carry the measurement noise into the result).
pub fn goal_um(spec: &MachineSpec) -> [f64; 2] {
    let k = spec.instrument_sigma_um.max(1.0);
    [TARGET_MAX_UM * k, TARGET_RMS_UM * k]
}

/// How to run the story.
#[derive(Clone, Debug)]
pub struct PipelineOptions {
    /// Draws the fit poses and the verification targets.
    pub seed: u64,
    pub approach: Approach,
    pub spec: MachineSpec,
}

/// What the pipeline reports while it runs.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A step starts (a line of progress).
    Step(String),
    /// The `full` fit held a parameter at nominal: the data confound it.
    Held { param: &'static str, why: String },
}

/// One verified calibration state.
#[derive(Clone, Debug)]
pub struct Stage {
    /// Short key: `nominal`, `ls`, `full`, `full+grid`, `full+grid2`; also names the
    /// verification CSV (`verify_<key>.csv`, `+` written as `_`).
    pub key: &'static str,
    pub description: String,
    /// What the paper reports for the comparable step.
    pub paper: &'static str,
    pub accuracy: Accuracy,
    /// As measured (instrument frame: what the verification CSV holds).
    pub landed: Vec<Landed>,
    /// The registration the stage is judged in: its calibration's (the nominal stage: the
    /// `full` fit's, the frame the calibration defines).
    pub frame: InstrumentFrame,
}

impl Stage {
    /// The visits with readings and truth in the machine frame.
    pub fn landed_in_machine_frame(&self) -> Vec<Landed> {
        registered(&self.landed, &self.frame)
    }
}

/// Everything a calibration run produced (in memory; [`write_outputs`] writes it).
pub struct Calibrated {
    pub machine: String,
    /// The machine's identity, which every file written carries (`crate::machine_identity`).
    pub identity: MachineIdentity,
    /// The lists measured (the plan's identification, grid and verification lists, and its
    /// repeat runs, which the demo does not measure).
    pub plan: Plan,
    pub fit_data: Vec<Landed>,
    /// The paper's `ls` fit and its registration, or why it failed (the run goes on without it).
    pub ls: Result<(FiveBar<f64>, InstrumentFrame), String>,
    pub full: FullFit,
    /// The instrument's frame the `full` fit registered (`super::frame`): the grids are built
    /// and the calibrated stages judged in the machine frame it defines.
    pub frame: InstrumentFrame,
    /// Grid nodes commanded with the `full` model (round 1) and the grid built from them.
    pub grid_data: Vec<Landed>,
    pub grid: BuiltGrid,
    /// Grid nodes re-measured through the round-1 grid (round 2) and the refined grid: the one
    /// to flash.
    pub grid2_data: Vec<Landed>,
    pub grid2: BuiltGrid,
    pub approach: Approach,
    /// The backlash measured and corrected by direction (random approach only).
    pub backlash: Option<Backlash>,
    pub stages: Vec<Stage>,
    /// The accuracy goal `[max, RMS]` (µm), [`goal_um`].
    pub goal_um: [f64; 2],
}

impl Calibrated {
    /// Measured visits (as measured: instrument frame) with readings and truth in the machine
    /// frame the `full` fit registered: what the grids were built from and accuracy is judged
    /// on.
    pub fn in_machine_frame(&self, landed: &[Landed]) -> Vec<Landed> {
        registered(landed, &self.frame)
    }

    /// The last stage (fit + refined grid).
    pub fn final_accuracy(&self) -> Option<Accuracy> {
        self.stages.last().map(|s| s.accuracy)
    }

    /// The accuracy target (noise floor) met by the last stage.
    pub fn target_met(&self) -> bool {
        self.final_accuracy()
            .is_some_and(|a| a.max_um <= self.goal_um[0] && a.rms_um <= self.goal_um[1])
    }
}

/// A grid image as the firmware reads it.
fn grid_calibration<'g>(g: &'g BuiltGrid, what: &str) -> Result<Calibration<'g>, CalibError> {
    let parsed = CorrectionGrid::parse(&g.image)
        .map_err(|e| invalid!("the {what} image does not parse: {e}"))?;
    Ok(Calibration::from_grid(parsed))
}

/// A fit's registered frame as `model.json` stores and reads it back (the identity when the
/// fit registered none).
fn as_stored(frame: Option<InstrumentFrame>) -> InstrumentFrame {
    frame.map_or(InstrumentFrame::IDENTITY, |f| {
        InstrumentFrame::from_record(&f.record())
    })
}

/// The instrument noise seed of the demo's measurement `step` (1..=8, the module doc's table):
/// `10·seed + step`, what `measure --seed` is given in the command-by-command workflow.
pub fn noise_seed(seed: u64, step: u64) -> u64 {
    seed.wrapping_mul(10).wrapping_add(step)
}

/// Measurement rows as a CSV file holds them (what `fit` and `grid` read back).
pub fn round_trip(rows: &[Measurement]) -> Result<Vec<Measurement>, CalibError> {
    Ok(parse_measurements(&format_measurements(rows))?)
}

/// The `full` fit as `fit --method full --no-loo` runs it.
fn fit_with(
    method: Method,
    data: &[Measurement],
    spec: &MachineSpec,
) -> Result<super::fit::FitOutcome, CalibError> {
    let opts = FitOptions {
        method,
        criterion: Criterion::Measured,
        points: Points::All,
        fixed: Vec::new(),
        leave_one_out: false,
        reject_sigma: super::fit::blunders::DEFAULT_REJECT_SIGMA,
        frame: super::fit::FrameMode::Register,
        spec: spec.clone(),
    };
    fit(data, &opts, &mut |_| {})
}

/// The grid from node measurements, as `grid` builds and finishes it.
fn build_grid(
    model: &FiveBar<f64>,
    data: &[Measurement],
    spec: &MachineSpec,
) -> Result<BuiltGrid, CalibError> {
    let mut built = grid::build_with(model, data, &grid::GridOptions::for_machine(spec))?;
    built.image = finish_image(&built.image, spec)?.0;
    Ok(built)
}

/// Runs the calibration on `machine` (the steps of the module doc); `events` hears progress.
pub fn calibrate(
    machine: &mut dyn Machine,
    opts: &PipelineOptions,
    events: &mut dyn FnMut(Event),
) -> Result<Calibrated, CalibError> {
    let approach = opts.approach;
    // The plan under the run's approach policy: its rows carry the directions.
    let spec = &MachineSpec {
        approach,
        ..opts.spec.clone()
    };
    let step = |events: &mut dyn FnMut(Event), s: String| events(Event::Step(s));
    let description = machine.describe();
    step(events, "step 0: planning the lists (identification poses chosen for identifiability, grid, verification targets)".into());
    let plan =
        plan(&PlanOptions::new(spec.clone(), opts.seed)).map_err(|e| e.context("planning"))?;
    let seed = |k: u64| noise_seed(opts.seed, k);
    let measure_with = |machine: &mut dyn Machine,
                        cal: &Calibration<'_>,
                        b: Option<&Backlash>,
                        v: &[Visit],
                        k: u64,
                        what: &str| {
        measure_list_compensated(machine, cal, b, v, approach, seed(k), spec)
            .map_err(|e| e.context(what))
    };
    let measure =
        |machine: &mut dyn Machine, cal: &Calibration<'_>, v: &[Visit], k: u64, what: &str| {
            measure_with(machine, cal, None, v, k, what)
        };
    let read_back =
        |landed: &[Landed], what: &str| round_trip(&rows(landed)).map_err(|e| e.context(what));
    let nominal = spec.nominal;
    let nominal_cal = Calibration {
        model: nominal.cast(),
        grid: None,
    };
    let (n_fit, n_verify) = (plan.identify.len(), plan.verify.len());

    step(
        events,
        format!("step 1: measuring {n_fit} identification poses commanded with the nominal model"),
    );
    let fit_data = measure(
        machine,
        &nominal_cal,
        &plan.identify,
        1,
        "measuring the fit poses",
    )?;
    let fit_rows = read_back(&fit_data, "the fit poses")?;
    let mut stages = Vec::new();
    step(
        events,
        format!("verifying the nominal model on {n_verify} fresh targets"),
    );
    let nominal_landed = measure(
        machine,
        &nominal_cal,
        &plan.verify,
        2,
        "verifying the nominal model",
    )?;
    let stage =
        |key, description: &str, paper, landed: Vec<Landed>, frame: InstrumentFrame| Stage {
            key,
            description: description.to_string(),
            paper,
            accuracy: accuracy(&registered(&landed, &frame)),
            landed,
            frame,
        };

    step(events, "step 2: fitting the hidden robot: full (LM: links, A0, B0, offsets) and the paper's ls (links only), each registering the instrument's frame".into());
    let full_fit = fit_with(Method::Full, &fit_rows, spec).map_err(|e| e.context("full fit"))?;
    // The frame as model.json stores it, so that `grid --model` and `measure --model` read
    // the same one.
    let frame = as_stored(full_fit.frame);
    let mut full = full_fit
        .full
        .ok_or_else(|| invalid!("internal: the full fit reported no full fit"))?;
    // The model as model.json stores it (offsets in degrees), for the same reason.
    full.model = ModelFile::from_model(&full.model).model()?;
    for (k, why) in &full.identifiability.fixed {
        events(Event::Held {
            param: NAMES[*k],
            why: why.clone(),
        });
    }
    let t = frame.to_instrument;
    step(
        events,
        format!(
            "instrument frame registered: rotation {:.6}°, offset ({:.4}, {:.4}) mm; the model is in the machine frame",
            t.rotation_rad.to_degrees(),
            t.offset_mm[0],
            t.offset_mm[1]
        ),
    );
    stages.push(stage(
        "nominal",
        "before calibration (nominal model)",
        "~1500",
        nominal_landed,
        frame,
    ));
    // The paper's ls: links only; a failure is its own result, not the run's.
    let ls = fit_with(Method::Ls, &fit_rows, spec)
        .map(|o| (o.model, as_stored(o.frame)))
        .map_err(|e| e.to_string());
    match &ls {
        Ok((ls_model, ls_frame)) => {
            let ls_cal = Calibration {
                model: ls_model.cast(),
                grid: None,
            };
            let landed = measure(machine, &ls_cal, &plan.verify, 3, "verifying the ls model")?;
            stages.push(stage(
                "ls",
                "paper's ls fit (4 links)",
                "~700",
                landed,
                *ls_frame,
            ));
        }
        Err(e) => step(
            events,
            format!("the paper's ls fit failed ({e}); going on without its row"),
        ),
    }
    let full_cal = Calibration {
        model: full.model.cast(),
        grid: None,
    };
    let landed = measure(
        machine,
        &full_cal,
        &plan.verify,
        4,
        "verifying the full model",
    )?;
    stages.push(stage(
        "full",
        "full fit (LM: links, A0, B0, offsets)",
        "-",
        landed,
        frame,
    ));

    let g = &spec.grid;
    step(
        events,
        format!(
            "step 3: measuring the {} mm grid ({} x {} nodes) commanded with the full model",
            g.step_mm, g.nx, g.ny
        ),
    );
    let grid_data = measure(machine, &full_cal, &plan.grid, 5, "measuring the grid")?;
    // Random approach directions: the backlash is measured on poses of its own (random places,
    // random directions: on the grid's raster the direction follows the configuration, and
    // configuration structure no model has would pass for backlash) and corrected from here on
    // by the direction-dependent command (backlash.rs); the grids are built from link angles.
    // A motor whose β is not significant (≤ 3σ) gets no correction.
    let backlash = match approach {
        Approach::Positive => None,
        Approach::FromVisit => {
            let design = SixBarDesign::for_model(&spec.nominal, spec.workspace.centre_mm())
                .map_err(|e| invalid!("the six-bar design: {e}"))?;
            let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0xbac_c1a5);
            let mut poses = random_visits(BACKLASH_POSES, &mut rng, spec, Range::HalfOpen);
            with_approach(&mut poses, spec)?;
            let data = measure(
                machine,
                &full_cal,
                &poses,
                9,
                "measuring the backlash poses",
            )?;
            let (b, sd) = backlash::estimate(
                &frame.register(&read_back(&data, "the backlash poses")?),
                &full.model,
                &design,
            )
            .map_err(|e| e.context("estimating the backlash"))?;
            let kept = [0, 1].map(|j| {
                if b.lost_motion_urad[j] > 3.0 * sd[j] {
                    b.lost_motion_urad[j]
                } else {
                    0.0
                }
            });
            step(
                events,
                format!(
                    "backlash from {BACKLASH_POSES} random poses: {:.1} ± {:.1} and {:.1} ± {:.1} µrad; corrected by direction from here on: {:.1}, {:.1} µrad",
                    b.lost_motion_urad[0], sd[0], b.lost_motion_urad[1], sd[1], kept[0], kept[1]
                ),
            );
            Some(Backlash::new(kept)?)
        }
    };
    // The grids are built from link angles when the backlash is corrected (backlash.rs).
    // And from readings in the machine frame.
    let link_rows = |landed: &[Landed], what: &str| -> Result<Vec<Measurement>, CalibError> {
        let rows = frame.register(&read_back(landed, what)?);
        match &backlash {
            Some(b) => b.link_angles(&rows),
            None => Ok(rows),
        }
    };
    let grid1_rows = link_rows(&grid_data, "the grid, round 1")?;
    let grid =
        build_grid(&full.model, &grid1_rows, spec).map_err(|e| e.context("building the grid"))?;
    let grid_cal = grid_calibration(&grid, "built grid")?;
    let landed = measure_with(
        machine,
        &grid_cal,
        backlash.as_ref(),
        &plan.verify,
        6,
        "verifying full fit + grid",
    )?;
    stages.push(stage(
        "full+grid",
        &format!("full fit + {} mm grid (1 round)", g.step_mm),
        "~37 (40x)",
        landed,
        frame,
    ));
    // Round 2: the grid is first order in the error it corrects (grid/mod.rs's doc), so the nodes
    // are measured again through it and the grid rebuilt from what is left.
    step(
        events,
        "step 4: measuring the grid nodes again through the grid (round 2) and refining it".into(),
    );
    let grid2_data = measure_with(
        machine,
        &grid_cal,
        backlash.as_ref(),
        &plan.grid,
        7,
        "measuring the grid, round 2",
    )?;
    // Both rounds' readings: the grid refers each to the node's IK command (grid/mod.rs), so the
    // refined grid averages two readings per node and the instrument's noise in it drops by √2.
    // With a backlash correction both rounds are in link angles (backlash.rs).
    let both: Vec<Measurement> = grid1_rows
        .into_iter()
        .chain(link_rows(&grid2_data, "the grid, round 2")?)
        .collect();
    let grid2 = build_grid(&full.model, &both, spec)
        .map_err(|e| e.context("building the grid, round 2"))?;
    let grid2_cal = grid_calibration(&grid2, "refined grid")?;
    step(
        events,
        format!("step 5: verifying full fit + refined grid on the same {n_verify} fresh targets"),
    );
    let landed = measure_with(
        machine,
        &grid2_cal,
        backlash.as_ref(),
        &plan.verify,
        8,
        "verifying full fit + refined grid",
    )?;
    stages.push(stage(
        "full+grid2",
        &format!("full fit + {} mm grid (2 rounds)", g.step_mm),
        "-",
        landed,
        frame,
    ));
    // The image to flash carries the estimated backlash (last block, as `host-sim grid` writes
    // it from the model's `backlash_urad`): the firmware's servo compensates it. Added after
    // the stages above, which command through the host's compensation (measure_with).
    let mut grid2 = grid2;
    if let Some(b) = &backlash {
        grid2.image = super::image::append_backlash_block(&grid2.image, b)?;
    }
    // Both images end with the machine record, judged as the controller will judge them (what
    // `host-sim grid` writes).
    let mut grid = grid;
    grid.image = seal_image(&grid.image, spec)
        .map_err(|e| e.context("the grid, round 1"))?
        .bytes;
    grid2.image = seal_image(&grid2.image, spec)
        .map_err(|e| e.context("the refined grid"))?
        .bytes;
    step(events, "calibration done".into());
    let goal_um = goal_um(spec);
    Ok(Calibrated {
        identity: spec.identity(),
        machine: description,
        plan,
        fit_data,
        ls,
        full,
        frame,
        grid_data,
        grid,
        grid2_data,
        grid2,
        approach,
        backlash,
        stages,
        goal_um,
    })
}
