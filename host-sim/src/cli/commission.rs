//! `host-sim commission`: the machine builder's whole journey through the controller
//! (`host_sim::commission`): `--qemu` starts the co-simulated controller (the production
//! firmware under QEMU driving the simulated plant, `host_sim::cosim`); `--tcp`/`--serial` run
//! the same journey against a controller you started, the instrument's readings typed in.
//! A table per step on stderr, the report as JSON on stdout, every file into `--out` at the end
//! (`commission::FILES`), written together only when the journey is complete.

use super::MachineArg;
use anyhow::{bail, Context, Result};
use host_sim::calib::image::commissioning_image;
use host_sim::calib::machine::check_plant_fits;
use host_sim::commission::cosim_instrument::CoSimInstrument;
use host_sim::commission::dynamics::check_options;
use host_sim::commission::{commission, CommissionOptions, Commissioned, StepReport, FILES};
use host_sim::cosim::{CoSim, CoSimOptions};
use host_sim::dynamics::session::LINK_POLL;
use host_sim::io::atomic::Outputs;
use host_sim::io::policy::CommandFiles;
use host_sim::io::{json_text, KeyOrder};
use host_sim::plant::PlantConfig;
use host_sim::session::instrument::{Instrument, TypedIn};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The machine builder's journey through the controller.
#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("controller").required(true).args(["qemu", "tcp", "serial"])))]
pub struct Args {
    /// Start the co-simulated controller: the firmware under QEMU driving the simulated plant.
    #[arg(long)]
    pub qemu: bool,
    /// A controller you started (--tcp, --serial): the instrument's readings are typed in.
    #[command(flatten)]
    pub link: super::link_args::LinkArgs,
    /// With --qemu: the simulated machine (`paper` or a plant TOML; default `paper`).
    #[arg(long, default_value = "paper")]
    pub plant: String,
    /// With --qemu: the firmware ELF (default: HOST_SIM_FIRMWARE, else the workspace's build).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// With --qemu: the instrument's noise σ per axis (µm; default: the machine file's).
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// Seeds the plan (and, with --qemu, the instrument's noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Identification poses.
    #[arg(long, default_value_t = host_sim::calib::plan::IDENTIFICATION_POSES)]
    pub identification_poses: usize,
    /// Fresh verification targets.
    #[arg(long, default_value_t = host_sim::calib::plan::VERIFY_TARGETS)]
    pub verify_targets: usize,
    /// Grid rounds (1 or 2).
    #[arg(long, default_value_t = 2)]
    pub grid_rounds: usize,
    /// The dynamics step: the length of each of the excitation's two sections (s; 1.5 to 600).
    /// Shorter is quicker and identifies less precisely.
    #[arg(long, default_value_t = 8.0)]
    pub excitation_section_s: f64,
    /// The moving steps: the check motion's length (s; 1.5 to 600).
    #[arg(long, default_value_t = 4.0)]
    pub check_motion_s: f64,
    /// The excitation's and the check motion's knot spacing (ms; 5 to 200; a check motion
    /// faster than 2 g takes at most 1/16 of its faster period). Under QEMU on TCP, whose
    /// clock outruns its UART, give 80.
    #[arg(long, default_value_t = 50.0)]
    pub knot_ms: f64,
    /// The moving steps: the check motion's peak acceleration (g; 0.05 to 20, at most the
    /// controller's stream limit, 5 g as shipped). A head heavier than the design's can trip
    /// the controller's stuck-encoder check at 5 g before its dynamics are identified.
    #[arg(long, default_value_t = 2.0)]
    pub check_accel_g: f64,
    /// Seconds to wait for each reply (--tcp, --serial).
    #[arg(long, default_value_t = 10.0)]
    pub timeout_s: f64,
    /// The output directory.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub machine: MachineArg,
}

fn table_line(r: &StepReport) {
    eprintln!("commission: {:<9} {:>8.1} s  {}", r.step, r.wall_s, r.what);
}

fn write(done: &Commissioned, args: &Args, mut outputs: Outputs) -> Result<String> {
    for (name, bytes) in &done.files {
        outputs.bytes(&args.out.join(name), bytes)?;
    }
    let text = json_text(&done.report, KeyOrder::Declared)?;
    outputs.bytes(&args.out.join("commission.json"), text.as_bytes())?;
    outputs.commit()?;
    Ok(text)
}

/// `host-sim commission`.
pub fn run(args: &Args) -> Result<()> {
    args.link.transport()?;
    let outputs = CommandFiles::new()
        .input("--machine", &args.machine.machine)
        .input("--plant", super::plant_file(&args.plant))
        .input("--firmware", &args.firmware)
        .output_dir("--out", &args.out, &FILES)
        .check()?;
    let timeout = super::link_args::reply_timeout(args.timeout_s)?;
    if !(1..=2).contains(&args.grid_rounds) {
        bail!(
            "--grid-rounds must be 1 or 2 (grid rounds), not {}",
            args.grid_rounds
        );
    }
    let mut spec = args.machine.spec()?;
    let started = Instant::now();
    let mut events = |r: &StepReport| table_line(r);
    let mut o = CommissionOptions::for_machine(&spec);
    o.seed = args.seed;
    o.identification_poses = args.identification_poses;
    o.verify_targets = args.verify_targets;
    o.grid_rounds = args.grid_rounds;
    o.moving.excitation.section_s = args.excitation_section_s;
    o.moving.excitation.knot_s = args.knot_ms * 1e-3;
    o.moving.check_s = args.check_motion_s;
    o.moving.check_accel_mm_s2 =
        args.check_accel_g * host_sim::machine_spec::STANDARD_GRAVITY_MM_S2;
    // A co-simulated link's reads advance the simulation: no wall-clock wait between polls.
    o.moving.poll = if args.qemu { Duration::ZERO } else { LINK_POLL };
    // The motions designed before a controller is touched: options that make none are refused.
    check_options(&spec, &o.moving).map_err(|e| {
        anyhow::anyhow!(
            "dynamics: {e} (--excitation-section-s {}, --check-motion-s {}, --knot-ms {}, --check-accel-g {})",
            args.excitation_section_s,
            args.check_motion_s,
            args.knot_ms,
            args.check_accel_g
        )
    })?;
    let done = if args.qemu {
        let mut plant = PlantConfig::by_name(&args.plant)?;
        check_plant_fits(&plant, &spec)?;
        let noise_um = args.noise_um.unwrap_or(spec.instrument_sigma_um);
        super::check_noise_um(Some(noise_um))?;
        plant.instrument.noise_sigma_um = noise_um;
        spec.instrument_sigma_um = noise_um;
        o.spec = spec.clone();
        o.session.spec = spec.clone();
        // The machine's commissioning image (nominal model, zero corrections, its record):
        // what a new machine's controller holds.
        let image = commissioning_image(&spec)?.bytes;
        let mut co = CoSimOptions::new(spec.clone(), plant.clone(), image);
        co.firmware = args.firmware.clone();
        co.seed = args.seed;
        eprintln!(
            "commission: starting the co-simulated controller (firmware under QEMU, plant '{}')",
            args.plant
        );
        let mut sim = CoSim::start(&co).context("starting the co-simulation")?;
        let done = {
            let mut client = sim.link(Duration::from_secs(120))?;
            let mut instrument = CoSimInstrument::new(&sim, &plant);
            commission(&mut client, &mut instrument, &o, &mut events)
        };
        let stats = sim.shutdown();
        let done = done?;
        if let Ok(s) = stats {
            eprintln!(
                "commission: co-simulation: {:.1} s simulated in {:.1} s ({:.2} simulated s per wall s); the firmware's worst servo step {:.1} µs, {} overruns",
                s.simulated_s, s.wall_s, s.speed, s.worst_step_us, s.overruns
            );
        }
        done
    } else {
        if args.noise_um.is_some() || args.firmware.is_some() || args.plant != "paper" {
            bail!("--plant, --firmware and --noise-um apply to --qemu only");
        }
        let mut typed = TypedIn::new(std::io::stdin().lock(), std::io::stderr());
        let instrument: &mut dyn Instrument = &mut typed;
        let (_, mut client) = args.link.open(timeout)?;
        commission(&mut client, instrument, &o, &mut events)?
    };
    let text = write(&done, args, outputs)?;
    let r = &done.report;
    eprintln!(
        "commission: done in {:.1} s: {} points measured through the controller; calibration {} in force; at {} fresh targets {:.3} / {:.3} µm max / RMS (goal {} / {}: {}); tool mass {:.4} kg identified, the check motion's following error {:.2} µm max (before the dynamics {:.2})",
        started.elapsed().as_secs_f64(),
        r.session_points,
        r.calibration_id,
        r.final_.n_targets,
        r.final_.max_um,
        r.final_.rms_um,
        r.final_.target_max_um,
        r.final_.target_rms_um,
        if r.final_.met { "met" } else { "NOT met" },
        r.dynamics.tool_mass_kg,
        r.moving.max_following_um,
        r.moving.before.max_following_um
    );
    print!("{text}");
    Ok(())
}
