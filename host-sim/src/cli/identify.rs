//! `host-sim identify`: the hidden robot's dynamic parameters from the controller's telemetry
//! of the excitation motion (`host_sim::dynamics`), written as `dynamics.json` (what `grid
//! --dynamics` puts into the image's dynamics block and `simulate --dynamics` feeds forward).
//!
//! Where the telemetry comes from, one of:
//! * `--tcp HOST:PORT` / `--serial PATH`: a controller (QEMU, the real board); the excitation is
//!   streamed to it and its telemetry recorded (it must be homed and running);
//! * `--telemetry LOG`: a recorded log (`--knots K.csv` the knots that were streamed; default:
//!   the built-in excitation of `--machine` at `--accel-g`);
//! * `--plant NAME`: a simulated plant in the host loop (the core's servo, the same record).
//!
//! `--grid`/`--model` name the calibration the controller commands with (its model is what the
//! encoders are read with); with a link, `--grid`'s id must be the one the controller reports.

use anyhow::{bail, Context, Result};
use host_sim::dynamics::excitation::ExcitationOptions;
use host_sim::dynamics::identify::{
    dynamics_file, identify_from_telemetry, identify_on_plant, identify_through_link,
    Identification, TelemetryIdentification,
};
use host_sim::dynamics::samples::SampleOptions;
use host_sim::dynamics::session::{LinkRunOptions, PlantRunOptions, LINK_POLL};
use host_sim::dynamics::tuning::{axis_inertia_kg_m2, servo_config_for};
use host_sim::io::dynamics_file::write_dynamics_file;
use host_sim::io::knots_csv::knots_text;
use host_sim::io::policy::CommandFiles;
use host_sim::io::telemetry_csv::telemetry_text;
use host_sim::io::{json_text, KeyOrder};
use host_sim::link::link_protocol::{calibration_image_id, Command, Response};
use host_sim::link::LinkClient;
use host_sim::machine_spec::MachineSpec;
use host_sim::sim::closed_loop::FeedForward;
use kinematics_core::dynamics::PARAMETER_NAMES;
use kinematics_core::ServoConfig;
use serde::Serialize;
use std::io::{Read, Write};
use std::path::PathBuf;

/// Identify the dynamics from the controller's telemetry of the excitation motion.
#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("source").required(true).args(["tcp", "serial", "telemetry", "plant"])))]
pub struct Args {
    #[command(flatten)]
    pub link: super::link_args::LinkArgs,
    /// Seconds to wait for each reply of the controller.
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
    /// A recorded telemetry log (the telemetry CSV) of the excitation.
    #[arg(long)]
    pub telemetry: Option<PathBuf>,
    /// With --telemetry: the knots that were streamed (t_s,x_mm,y_mm,vx_mm_s,vy_mm_s);
    /// default the built-in excitation.
    #[arg(long, requires = "telemetry")]
    pub knots: Option<PathBuf>,
    /// A simulated plant (`ideal`, `paper` or a plant TOML) run by the host loop.
    #[arg(long)]
    pub plant: Option<String>,
    /// With --plant: seeds the plant.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The calibration image the controller runs (its model reads the encoders).
    #[arg(long)]
    pub grid: Option<PathBuf>,
    /// The model the controller commands with, without an image.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// The identified parameters (dynamics.json).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the telemetry recorded (link, plant).
    #[arg(long)]
    pub telemetry_csv: Option<PathBuf>,
    /// Also write the knots streamed (link, plant): what --knots reads.
    #[arg(long)]
    pub knots_out: Option<PathBuf>,
    /// The excitation's peak acceleration (g; the controller accepts knots up to 5 g as shipped).
    #[arg(long, default_value_t = 2.0)]
    pub accel_g: f64,
    /// The length of each of the excitation's two sections (s; default 8): shorter is quicker
    /// and identifies less precisely.
    #[arg(long, default_value_t = 8.0)]
    pub section_s: f64,
    /// The excitation's knot spacing (ms; 5 to 200, the excitation's limits still met).
    /// Longer knots ask less of the link: under QEMU, whose clock outruns its UART, give 80.
    #[arg(long, default_value_t = 50.0)]
    pub knot_ms: f64,
    /// Telemetry decimation: servo samples per telemetry sample (20 = 100 Hz, the fastest).
    #[arg(long, default_value_t = 20)]
    pub decimation: u16,
    #[command(flatten)]
    pub machine: super::MachineArg,
}

#[derive(Serialize)]
struct Output<'a> {
    source: String,
    #[serde(flatten)]
    result: &'a TelemetryIdentification,
    /// The servo gains designed for the identified inertia (`dynamics::tuning`).
    servo_gains: Vec<AxisGainsOut>,
    outputs: Vec<String>,
}

#[derive(Serialize)]
struct AxisGainsOut {
    axis: usize,
    inertia_kg_m2: f64,
    kp_nm_per_rad: f32,
    ki_nm_per_rad_s: f32,
    kd_nm_s_per_rad: f32,
    observer_inertia_kg_m2: f32,
}

/// `host-sim identify`.
pub fn run(args: &Args) -> Result<()> {
    // Every file declared before anything runs: no output onto an input or another output.
    let mut outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--telemetry", &args.telemetry)
        .input("--knots", &args.knots)
        .input("--plant", args.plant.as_deref().and_then(super::plant_file))
        .input("--grid", &args.grid)
        .input("--model", &args.model)
        .output("--out", &args.out)
        .output("--telemetry-csv", &args.telemetry_csv)
        .output("--knots-out", &args.knots_out)
        .check()?;
    let spec = args.machine.spec()?;
    let accel_mm_s2 = super::common_args::excitation_accel_mm_s2(args.accel_g)?;
    let timeout = super::link_args::reply_timeout(args.timeout_s)?;
    if !(20..=2000).contains(&args.decimation) {
        bail!(
            "--decimation {}: give 20 (100 Hz, the link's fastest) to 2000 servo samples per \
             telemetry sample",
            args.decimation
        );
    }
    args.link.transport()?;
    if args.telemetry.is_some() && (args.telemetry_csv.is_some() || args.knots_out.is_some()) {
        bail!("--telemetry-csv and --knots-out record a run: not with --telemetry");
    }
    let loaded = super::load_calibration(
        args.model.as_deref(),
        args.grid.as_deref(),
        &spec,
        &args.machine,
    )?;
    let cal = loaded.calibration()?;
    let servo = ServoConfig::default();
    let samples = SampleOptions {
        model: cal.model.cast::<f64>(),
        min_transmission: spec.min_transmission,
        torque_limit_nm: servo.axes.map(|a| f64::from(a.torque_limit_nm)),
    };
    let excitation = ExcitationOptions {
        accel_mm_s2,
        section_s: args.section_s,
        knot_s: args.knot_ms * 1e-3,
        ..ExcitationOptions::default()
    };
    // The excitation designed once up front: bad --accel-g/--section-s are refused before a
    // controller is touched.
    let designed =
        host_sim::dynamics::excitation::excitation(&spec, &excitation).with_context(|| {
            format!(
                "the excitation of machine '{}' (--accel-g {}, --section-s {}, --knot-ms {})",
                spec.name, args.accel_g, args.section_s, args.knot_ms
            )
        })?;
    let (source, result, run) = if let Some(log_path) = &args.telemetry {
        let (log, path) = super::common_args::telemetry_run(
            &args.machine,
            &spec,
            log_path,
            args.knots.as_deref(),
            || Ok(designed.knots.clone()),
        )?;
        let result = identify_from_telemetry(&log, &path, &spec, &samples)
            .with_context(|| format!("identifying from {}", log_path.display()))?;
        (format!("telemetry {}", log_path.display()), result, None)
    } else if let Some(name) = &args.plant {
        let plant = super::common_args::plant_for(name, &spec)?;
        let opts = PlantRunOptions {
            spec: spec.clone(),
            excitation,
            decimation: u32::from(args.decimation),
            feedforward: FeedForward::Constant,
            servo: None,
            seed: args.seed,
        };
        let Identification { run, result } = identify_on_plant(&plant, &cal, &opts, &samples)?;
        (format!("plant {name} (host loop)"), result, Some(run))
    } else {
        let opts = LinkRunOptions {
            spec: spec.clone(),
            excitation,
            decimation: args.decimation,
            slack: 10 * timeout,
            poll: LINK_POLL,
        };
        let (transport, mut client) = args.link.open(timeout)?;
        let id = through(&mut client, &loaded.image, &opts, &samples)?;
        let source = transport.to_string();
        (source, id.result, Some(id.run))
    };
    // Everything computed before anything is written.
    let file = dynamics_file(&result, &spec, &source);
    let d = result.identified.dynamics;
    let inertia = axis_inertia_kg_m2(&d, &samples.model, &spec)?;
    let tuned = servo_config_for(&d, &samples.model, &spec, servo)?;
    outputs.with(&args.out, |tmp| write_dynamics_file(tmp, &file))?;
    if let Some(run) = &run {
        if let Some(p) = &args.telemetry_csv {
            outputs.bytes(p, telemetry_text(&run.log).as_bytes())?;
        }
        if let Some(p) = &args.knots_out {
            outputs.bytes(p, knots_text(run.path.knots()).as_bytes())?;
        }
    }
    let written = outputs.commit()?;
    summary(&source, &result, &inertia, &spec);
    let out = Output {
        source,
        result: &result,
        servo_gains: (0..2)
            .map(|k| AxisGainsOut {
                axis: k + 1,
                inertia_kg_m2: inertia[k],
                kp_nm_per_rad: tuned.axes[k].kp_nm_per_rad,
                ki_nm_per_rad_s: tuned.axes[k].ki_nm_per_rad_s,
                kd_nm_s_per_rad: tuned.axes[k].kd_nm_s_per_rad,
                observer_inertia_kg_m2: tuned.axes[k].observer_inertia_kg_m2,
            })
            .collect(),
        outputs: written.iter().map(|p| p.display().to_string()).collect(),
    };
    print!("{}", json_text(&out, KeyOrder::Sorted)?);
    Ok(())
}

/// The excitation through an open link, after checking that the controller runs the image
/// `--grid` names (when given).
fn through<S: Read + Write>(
    client: &mut LinkClient<S>,
    image: &Option<Vec<u8>>,
    opts: &LinkRunOptions,
    samples: &SampleOptions,
) -> Result<Identification> {
    if let Some(bytes) = image {
        let file = calibration_image_id(bytes);
        match client.request(Command::Identify)? {
            Response::Identity(id) if id.calibration_id == Some(file) => {}
            Response::Identity(id) => bail!(
                "the controller runs calibration {:?}, --grid is {file:#010x}: give the image in \
                 force (its model reads the encoders)",
                id.calibration_id
            ),
            other => bail!("unexpected reply to identify: {other:?}"),
        }
    } else {
        eprintln!("identify: no --grid: the controller's encoders are read with the machine's nominal model");
    }
    let id = identify_through_link(client, opts, samples, &mut |done, total| {
        eprint!("\ridentify: excitation {done}/{total} knots");
    });
    eprintln!();
    Ok(id?)
}

/// The human summary (stderr).
fn summary(source: &str, r: &TelemetryIdentification, inertia: &[f64; 2], spec: &MachineSpec) {
    let id = &r.identified;
    eprintln!(
        "identify: machine '{}' (digest {}), {}: {} telemetry samples (decimation {}), {} used, \
         residual {:.4} N·m RMS",
        spec.name,
        spec.identity().digest,
        source,
        r.telemetry_samples,
        r.decimation,
        id.samples_used,
        id.residual_rms_nm
    );
    for (k, name) in PARAMETER_NAMES.iter().enumerate() {
        eprintln!(
            "  {name:<26} {:>12.5e} ± {:.1e}",
            id.parameters[k].1, id.std_dev[k].1
        );
    }
    for a in &id.absorbed {
        eprintln!("  (not separable on this machine: {a})");
    }
    eprintln!(
        "  axis inertia (workspace mean) {:.4e} / {:.4e} kg·m²: servo gains in the JSON (servo_gains)",
        inertia[0], inertia[1]
    );
}
