//! The journey's moving machine: the dynamics identified through the controller and what its
//! feed-forward gives on a motion the identification never saw.
//!
//! * **dynamics**: the excitation (`dynamics::excitation`) streamed over the link with the
//!   static calibration in force, its telemetry recorded and fitted
//!   (`dynamics::identify::identify_through_link`); the moving machine's diagnosis
//!   (`dynamics::diagnose`) on the same telemetry against the identified dynamics names what
//!   the block's parameters still miss (cogging, a torque constant, ...), and the block that
//!   goes into the image is the identified one with what it names added (`model_out`).
//! * **moving**: the check motion (`dynamics::excitation::figure_eight`, 2 g by default, up to
//!   the machine's rated 5 g, the controller's stream limit for knots) streamed with the telemetry recorded, once before the dynamics are uploaded
//!   (the controller feeds forward what the image in force carries: nothing in a commissioning
//!   image, the gains' constant inertia then) and once after. The following error at the tool:
//!   the telemetry's `reference − encoder` through the model's Jacobian at the setpoint (µm),
//!   its max and RMS over the samples where the setpoint moves.
//!
//! A telemetry that cannot be identified or diagnosed (too short, a fault during the motion,
//! the motion not exciting a parameter) stops the journey at its step with the library's
//! reason; nothing is written.

use crate::dynamics::diagnose::{diagnose_telemetry, DiagnoseOptions};
use crate::dynamics::excitation::{figure_eight, figure_eight_knot_s, ExcitationOptions};
use crate::dynamics::identify::{checked_samples, dynamics_file, identify_through_link};
use crate::dynamics::predict::{at_tool_um, Controller};
use crate::dynamics::report::{Carried, RatedMotion};
use crate::dynamics::samples::SampleOptions;
use crate::dynamics::session::{run_motion_on_link, ExcitationRun, LinkRunOptions};
use crate::dynamics::tuning::axis_inertia_kg_m2;
use crate::dynamics::DynError;
use crate::io::dynamics_file::DynamicsFile;
use crate::link::LinkClient;
use crate::machine_spec::{MachineSpec, STANDARD_GRAVITY_MM_S2};
use crate::numeric::{max_rms, round3, round6};
use crate::sim::closed_loop::servo_config_at;
use kinematics_core::dynamics::PARAMETER_NAMES;
use kinematics_core::{wrap_angle_rad, FiveBar, FiveBarDynamics};
use serde::Serialize;
use std::io::{Read, Write};
use std::time::Duration;

/// How the moving machine's steps run.
#[derive(Clone, Copy, Debug)]
pub struct MovingOptions {
    /// The excitation (its limits are the controller's stream limits; `section_s` sets its
    /// length: two sections).
    pub excitation: ExcitationOptions,
    /// The check motion's length (s).
    pub check_s: f64,
    /// The check motion's peak acceleration (mm/s²). Default 2 g, as the excitation's: a head
    /// heavier than the design's, not identified yet, can trip the controller's stuck-encoder
    /// check at 5 g (its inertia bounds are the design's). Up to 5 g, the machine's rating and
    /// the controller's stream limit for knots.
    pub check_accel_mm_s2: f64,
    /// Servo samples per telemetry sample (20: 100 Hz, the link's fastest).
    pub decimation: u16,
    /// The wait between status polls while the controller's knot buffer is full
    /// (`dynamics::session::LINK_POLL` on a board or QEMU's UART; zero on a co-simulated link).
    pub poll: Duration,
}

impl Default for MovingOptions {
    fn default() -> Self {
        MovingOptions {
            excitation: ExcitationOptions::default(),
            check_s: 4.0,
            check_accel_mm_s2: 2.0 * STANDARD_GRAVITY_MM_S2,
            decimation: 20,
            poll: Duration::ZERO,
        }
    }
}

/// The dynamic diagnosis in the report.
#[derive(Clone, Debug, Serialize)]
pub struct DynamicDiagnosis {
    /// The effects named (in order), and the following-error residual (µm at the tool) before
    /// and after them.
    pub named: Vec<String>,
    pub rms_before_um: f64,
    pub rms_after_um: f64,
    /// Whether the torque still depends on the motion in a way no library effect has.
    pub unexplained: bool,
    /// How each named effect goes into the block.
    pub carried: Vec<Carried>,
    /// The rated motion (5 g) simulated on the machine as diagnosed: fed forward the identified
    /// block, and with the named effects added.
    pub rated_motion: Option<RatedMotion>,
}

/// The dynamics step in the report: what goes into the image's dynamics block.
#[derive(Clone, Debug, Serialize)]
pub struct DynamicsReport {
    pub tool_mass_kg: f64,
    /// One standard deviation of the identified tool mass.
    pub tool_mass_std_dev_kg: f64,
    pub motor_inertia_kg_m2: [f64; 2],
    pub distal_inertia_kg_m2: [f64; 2],
    pub viscous_nm_s_per_rad: [f64; 2],
    pub coulomb_nm: [f64; 2],
    /// Each axis' inertia (the mass matrix's diagonal over the workspace): what the servo's
    /// gains must be designed for.
    pub axis_inertia_kg_m2: [f64; 2],
    pub telemetry_samples: usize,
    pub samples_used: usize,
    pub residual_rms_nm: f64,
    pub diagnosis: DynamicDiagnosis,
}

/// The following error at the tool over a motion (µm).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Following {
    pub max_following_um: f64,
    pub rms_following_um: f64,
}

/// The check motion after the upload, and before it.
#[derive(Clone, Debug, Serialize)]
pub struct MovingReport {
    pub motion: String,
    pub peak_accel_g: f64,
    pub peak_speed_mm_s: f64,
    pub duration_s: f64,
    /// With the final image (its dynamics fed forward).
    pub max_following_um: f64,
    pub rms_following_um: f64,
    /// With the image in force before the dynamics step's upload.
    pub before: Following,
}

impl DynamicsReport {
    /// The step's line in the table, with the check motion run before the upload.
    pub fn line(&self, shape: &MovingShape, before: &Following) -> String {
        format!(
            "tool {:.4} ± {:.4} kg, axis inertia {:.3e} / {:.3e} kg·m²; diagnosis named {} \
             (RMS {:.2} → {:.2} µm); check motion ({:.1} g) before: {:.2} / {:.2} µm max / RMS",
            self.tool_mass_kg,
            self.tool_mass_std_dev_kg,
            self.axis_inertia_kg_m2[0],
            self.axis_inertia_kg_m2[1],
            if self.diagnosis.named.is_empty() {
                "nothing".to_string()
            } else {
                self.diagnosis.named.join(", ")
            },
            self.diagnosis.rms_before_um,
            self.diagnosis.rms_after_um,
            shape.peak_accel_g,
            before.max_following_um,
            before.rms_following_um
        )
    }
}

impl MovingReport {
    /// The moving step's line in the table.
    pub fn line(&self) -> String {
        format!(
            "check motion ({:.1} g) with the dynamics fed forward: {:.2} / {:.2} µm max / RMS \
             following error at the tool (before the upload {:.2} / {:.2})",
            self.peak_accel_g,
            self.max_following_um,
            self.rms_following_um,
            self.before.max_following_um,
            self.before.rms_following_um
        )
    }
}

/// What the dynamics step found and what it gives the image.
pub struct Identified {
    /// The block for the image.
    pub block: FiveBarDynamics<f64>,
    pub report: DynamicsReport,
    /// `dynamics.json`.
    pub file: DynamicsFile,
    /// The excitation's record (knots and telemetry).
    pub run: ExcitationRun,
}

fn link_options(spec: &MachineSpec, o: &MovingOptions) -> LinkRunOptions {
    LinkRunOptions {
        spec: spec.clone(),
        excitation: o.excitation,
        decimation: o.decimation,
        slack: Duration::from_secs(120),
        poll: o.poll,
    }
}

/// How the log is read: the model the controller commands with, the servo's torque limit.
fn sample_options(spec: &MachineSpec, model: &FiveBar<f64>) -> SampleOptions {
    SampleOptions {
        model: *model,
        min_transmission: spec.min_transmission,
        torque_limit_nm: servo_config_at(spec)
            .axes
            .map(|a| f64::from(a.torque_limit_nm)),
    }
}

/// The dynamics step (module doc) through `client`, the controller commanding with `model`.
pub fn identify<S: Read + Write>(
    client: &mut LinkClient<S>,
    spec: &MachineSpec,
    model: &FiveBar<f64>,
    o: &MovingOptions,
) -> Result<Identified, DynError> {
    let samples = sample_options(spec, model);
    let id = identify_through_link(client, &link_options(spec, o), &samples, &mut |_, _| {})?;
    let identified = id.result.identified.dynamics;
    let report = diagnose_telemetry(
        &id.run.log,
        &id.run.path,
        &DiagnoseOptions {
            spec: spec.clone(),
            samples,
            controller: Controller::new(spec, *model, servo_config_at(spec), identified)?,
        },
    )?;
    let block = match (&report.model_out, report.steps.is_empty()) {
        (_, true) => identified,
        (Some(out), false) => FiveBarDynamics::from_array(
            PARAMETER_NAMES.map(|n| out[n]),
            identified.coulomb_speed_rad_s,
        ),
        (None, false) => {
            return Err(DynError::NotIdentifiable(format!(
                "the effects the diagnosis named ({}) do not make a valid dynamics block with \
                 the identified parameters: run the excitation again (a longer one: \
                 --excitation-section-s)",
                report
                    .steps
                    .iter()
                    .map(|s| s.effect.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )))
        }
    };
    let named: Vec<String> = report.steps.iter().map(|s| s.effect.clone()).collect();
    let mut file = dynamics_file(
        &id.result,
        spec,
        "the controller's telemetry of the excitation (host-sim commission)",
    );
    let from_block = DynamicsFile::from_dynamics(&block);
    file.motor_inertia_kg_m2 = from_block.motor_inertia_kg_m2;
    file.tool_mass_kg = from_block.tool_mass_kg;
    file.distal_inertia_kg_m2 = from_block.distal_inertia_kg_m2;
    file.viscous_nm_s_per_rad = from_block.viscous_nm_s_per_rad;
    file.coulomb_nm = from_block.coulomb_nm;
    if let Some(serde_json::Value::Object(m)) = &mut file.identification {
        m.insert("effects_named".into(), serde_json::json!(named));
    }
    let sd = |name: &str| {
        id.result
            .identified
            .std_dev
            .iter()
            .find(|(n, _)| n == name)
            .map_or(f64::NAN, |(_, s)| *s)
    };
    let report = DynamicsReport {
        tool_mass_kg: round6(block.tool_mass_kg),
        tool_mass_std_dev_kg: round6(sd("tool_mass_kg")),
        motor_inertia_kg_m2: block.motor_inertia_kg_m2,
        distal_inertia_kg_m2: block.distal_inertia_kg_m2,
        viscous_nm_s_per_rad: block.viscous_nm_s_per_rad,
        coulomb_nm: block.coulomb_nm,
        axis_inertia_kg_m2: axis_inertia_kg_m2(&block, model, spec)?,
        telemetry_samples: id.result.telemetry_samples,
        samples_used: id.result.identified.samples_used,
        residual_rms_nm: id.result.identified.residual_rms_nm,
        diagnosis: DynamicDiagnosis {
            named,
            rms_before_um: round3(report.initial_rms_um),
            rms_after_um: round3(report.final_rms_um),
            unexplained: report.unexplained,
            carried: report.carried.clone(),
            rated_motion: report.rated_motion.clone(),
        },
    };
    Ok(Identified {
        block,
        report,
        file,
        run: id.run,
    })
}

/// The check motion for `spec`'s machine at `o`'s limits.
fn check_motion(
    spec: &MachineSpec,
    o: &MovingOptions,
) -> Result<crate::dynamics::excitation::Excitation, DynError> {
    let check = ExcitationOptions {
        section_s: o.check_s,
        accel_mm_s2: o.check_accel_mm_s2,
        ..o.excitation
    };
    figure_eight(
        spec,
        &ExcitationOptions {
            knot_s: figure_eight_knot_s(&check),
            ..check
        },
    )
}

/// Designs the excitation and the check motion without running them: options that make no
/// motion are refused before a controller is touched.
pub fn check_options(spec: &MachineSpec, o: &MovingOptions) -> Result<(), DynError> {
    crate::dynamics::excitation::excitation(spec, &o.excitation)?;
    check_motion(spec, o)?;
    Ok(())
}

/// Runs the check motion through `client` (the controller commanding with `model`); its
/// following error at the tool and the run's record.
pub fn check_run<S: Read + Write>(
    client: &mut LinkClient<S>,
    spec: &MachineSpec,
    model: &FiveBar<f64>,
    o: &MovingOptions,
) -> Result<(Following, MovingShape, ExcitationRun), DynError> {
    let ex = check_motion(spec, o)?;
    let shape = MovingShape {
        peak_accel_g: round3(ex.peak_accel_mm_s2 / STANDARD_GRAVITY_MM_S2),
        peak_speed_mm_s: round3(ex.peak_speed_mm_s),
        duration_s: round3(ex.duration_s()),
    };
    let run = run_motion_on_link(client, ex, &link_options(spec, o), &mut |_, _| {})?;
    let f = following_at_tool(&run, spec, model)?;
    Ok((f, shape, run))
}

/// The check motion's size.
#[derive(Clone, Copy, Debug)]
pub struct MovingShape {
    pub peak_accel_g: f64,
    pub peak_speed_mm_s: f64,
    pub duration_s: f64,
}

/// Speed of the setpoint above which a sample counts as moving (mm/s).
const MOVING_MM_S: f64 = 1.0;

/// The following error at the tool over `run`'s motion (module doc).
pub fn following_at_tool(
    run: &ExcitationRun,
    spec: &MachineSpec,
    model: &FiveBar<f64>,
) -> Result<Following, DynError> {
    let samples = sample_options(spec, model);
    let (facts, m) = checked_samples(&run.log, &run.path, spec, &samples)?;
    let end_s = run.path.end_s();
    let mut err_um = Vec::new();
    for r in &run.log.rows {
        let t = (r.tick as i64 - m.start_tick) as f64 * facts.sample_period_s;
        if !(0.0..=end_s).contains(&t) {
            continue;
        }
        let v = run.path.motion_at(t).velocity_mm_s;
        if v[0].hypot(v[1]) < MOVING_MM_S {
            continue;
        }
        let e = [0, 1].map(|i| wrap_angle_rad(r.reference_rad[i] - r.encoder_rad[i]));
        let Some(at) = at_tool_um(model, r.setpoint_mm, e, spec.min_transmission) else {
            return Err(DynError::Telemetry(format!(
                "at tick {} the setpoint ({:.3}, {:.3}) mm has no Jacobian in the model",
                r.tick, r.setpoint_mm[0], r.setpoint_mm[1]
            )));
        };
        err_um.push(at[0].hypot(at[1]));
    }
    if err_um.is_empty() {
        return Err(DynError::Telemetry(
            "the telemetry holds no sample of the motion: record it while the machine moves".into(),
        ));
    }
    let s = max_rms(&err_um);
    Ok(Following {
        max_following_um: round3(s.max),
        rms_following_um: round3(s.rms),
    })
}
