//! Co-simulation: the production firmware under QEMU drives this crate's six-bar plant, in
//! lockstep, every 500 µs servo sample (docs/design/co-simulation.md).
//!
//! ```text
//!  QEMU (-icount: virtual time)                         host-sim (this module)
//!  servo tick ─► begin_sample ── up: duty, enable, link TX ──► drives: torque or braking
//!                  (blocked; virtual time stands still)       plant: one period (six-bar, backlash,
//!                ◄── down: counters, index, link RX ────────   friction, quantisation) ─► encoders
//!  encoders ─► servo step ─► PWM duty ─► ... next tick         link bytes ◄─► LinkClient (CoSimLink)
//! ```
//!
//! * [`CoSim::start`] starts QEMU with the firmware (found or built: [`CoSimOptions::firmware`])
//!   and the calibration region's initial content, places the plant where the machine powers
//!   up and answers the firmware's hello with the machine's encoders.
//! * [`CoSim::link`] is a [`LinkClient`] whose reads advance the simulation until the
//!   controller's answer arrives ([`CoSimLink`]): the link's bytes travel inside the samples,
//!   so when a command takes effect is part of the deterministic run, and the host never waits
//!   on a wall clock.
//! * [`CoSim::run_for_s`], [`CoSim::plant_truth`], [`CoSim::instrument_reading_mm`] (the
//!   tool point through the instrument's frame, scale and noise, as a tracker would read it),
//!   [`CoSim::stats`].
//! * [`CoSim::shutdown`] ends QEMU cleanly (the firmware removes torque and exits); dropping a
//!   `CoSim` kills QEMU (also on a panic).
//!
//! Where a change goes: the bytes of the exchange are `cosim-wire` (shared with the firmware);
//! the simulated hardware (drives, encoders, index marks) is [`exchange`]; starting and stopping
//! QEMU is [`qemu`]; the link transport is [`transport`].

pub mod exchange;
pub mod one_core;
pub mod qemu;
pub mod transport;

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::link::{ClientError, LinkClient};
use crate::machine_spec::MachineSpec;
use crate::plant::{Plant, PlantConfig, PlantError};
use exchange::{Engine, EngineConfig};

pub use transport::CoSimLink;

/// The calibration a machine starts with, for [`CoSimOptions::image`]: `spec`'s commissioning
/// image (`calib::image::commissioning_image`: the nominal model, zero corrections, the
/// workspace block and the machine record; `host-sim grid --nominal`). The controller then
/// commands the nominal model, as a newly built machine's does before its first calibration.
pub fn commissioning_image(spec: &MachineSpec) -> Result<Vec<u8>, CoSimError> {
    crate::calib::image::commissioning_image(spec)
        .map(|checked| checked.bytes)
        .map_err(|e| CoSimError::Invalid(format!("machine '{}': {e}", spec.name)))
}

/// Why a co-simulation cannot start or go on.
#[derive(Debug, thiserror::Error)]
pub enum CoSimError {
    /// The firmware ELF cannot be found, built or read (the message says what to do).
    #[error("firmware: {0}")]
    Firmware(String),
    /// QEMU cannot be started.
    #[error("qemu: {0}")]
    Qemu(String),
    /// QEMU ended while the co-simulation expected a frame.
    #[error("QEMU exited ({status}) in the middle of the co-simulation; its console:\n{console}")]
    Exited { status: String, console: String },
    /// No frame from the firmware in time (a firmware without co-simulation support never
    /// opens the exchange).
    #[error(
        "no frame from the firmware within {waited_s} s (is the ELF a firmware with \
         co-simulation? rebuild it: cargo build --release -p firmware --bin firmware --target \
         thumbv7em-none-eabihf); QEMU's console:\n{console}"
    )]
    Timeout { waited_s: f64, console: String },
    /// The exchange broke its rules (a sample lost, repeated, undecodable).
    #[error("co-simulation exchange: {0}")]
    Protocol(String),
    /// The plant cannot move (driven through a singularity) or be built.
    #[error(transparent)]
    Plant(#[from] PlantError),
    /// Options that make no co-simulation (the message names the option).
    #[error("{0}")]
    Invalid(String),
    #[error("co-simulation i/o: {0}")]
    Io(#[from] std::io::Error),
}

/// What a co-simulation runs.
#[derive(Clone, Debug)]
pub struct CoSimOptions {
    /// The firmware ELF; `None`: `HOST_SIM_FIRMWARE`, else the workspace's release build, built
    /// with cargo if missing ([`qemu::locate_firmware`]).
    pub firmware: Option<PathBuf>,
    /// The QEMU binary. Default `qemu-system-arm` (on the `PATH`).
    pub qemu: PathBuf,
    /// The machine (nominal model, workspace, servo rate).
    pub machine: MachineSpec,
    /// The simulated machine the firmware drives.
    pub plant: PlantConfig,
    /// Seeds the instrument's noise.
    pub seed: u64,
    /// The calibration region's content at power-on (empty: erased, the drives never enable).
    /// [`commissioning_image`] is a new machine's.
    pub image: Vec<u8>,
    /// Where the tool stands at power-on (mm, nominal model; the incremental counters read 0
    /// there). Default: the workspace's centre.
    pub power_on_mm: Option<[f64; 2]>,
    /// Home at boot; otherwise the link's Home command starts homing (the production default).
    pub home_at_boot: bool,
    /// Host-link bytes the controller receives per sample at most (at most
    /// `cosim_wire::MAX_LINK_RX_PER_SAMPLE`, the default; 6 is a 115 200 Bd UART's rate). What
    /// the controller transmits reaches the host in the period it was sent.
    pub link_bytes_per_sample: usize,
    /// The drives' dynamic braking with the enable line low (N·m·s/rad at the joint). Default
    /// 0.225, the QEMU board's motors (docs/reference/faults.md, "Category 0 needs dynamic
    /// braking").
    pub dynamic_brake_nm_s_per_rad: f64,
    /// Longest wall-clock wait for one frame from the firmware (QEMU's boot included).
    pub frame_timeout: Duration,
    /// Simulated time a link read waits for the controller's next byte before it reports a
    /// timeout to the client (which then gives up at its own timeout).
    pub link_read_limit_s: f64,
    /// Writes every byte exchanged, both ways, in order, to this file.
    pub exchange_log: Option<PathBuf>,
    /// Runs QEMU and the thread that calls into the co-simulation on one core no other
    /// co-simulation holds ([`one_core`]: a third to a half less time; the exchange is the
    /// same).
    /// Default on; off, or with every core held, they run wherever the OS puts them.
    pub one_core: bool,
}

impl CoSimOptions {
    /// The defaults around `machine`, `plant` and the calibration region's `image`.
    pub fn new(machine: MachineSpec, plant: PlantConfig, image: Vec<u8>) -> Self {
        CoSimOptions {
            firmware: None,
            qemu: "qemu-system-arm".into(),
            machine,
            plant,
            seed: 1,
            image,
            power_on_mm: None,
            home_at_boot: false,
            link_bytes_per_sample: cosim_wire::MAX_LINK_RX_PER_SAMPLE,
            dynamic_brake_nm_s_per_rad: 0.225,
            frame_timeout: Duration::from_secs(30),
            link_read_limit_s: 2.0,
            exchange_log: None,
            one_core: true,
        }
    }

    fn validate(&self) -> Result<(), CoSimError> {
        let bad = |what: &str| Err(CoSimError::Invalid(format!("co-simulation: {what}")));
        if !(1..=cosim_wire::MAX_LINK_RX_PER_SAMPLE).contains(&self.link_bytes_per_sample) {
            return bad(&format!(
                "link_bytes_per_sample {} is not within 1..={}",
                self.link_bytes_per_sample,
                cosim_wire::MAX_LINK_RX_PER_SAMPLE
            ));
        }
        if !(self.dynamic_brake_nm_s_per_rad.is_finite() && self.dynamic_brake_nm_s_per_rad >= 0.0)
        {
            return bad("dynamic_brake_nm_s_per_rad must be finite and not negative");
        }
        if !(self.link_read_limit_s > 0.0 && self.link_read_limit_s <= 3600.0) {
            return bad("link_read_limit_s must be within (0, 3600] s");
        }
        if let Some(p) = self.power_on_mm {
            if !self.machine.workspace.contains(p, 0.0) {
                return bad(&format!(
                    "power_on_mm ({:.3}, {:.3}) is outside machine '{}''s workspace",
                    p[0], p[1], self.machine.name
                ));
            }
        }
        self.machine
            .validate()
            .map_err(|e| CoSimError::Invalid(format!("machine '{}': {e}", self.machine.name)))
    }
}

/// The plant's true state (what no controller can see: for tests and reports).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PlantTruth {
    /// Simulated time since the start (s).
    pub simulated_s: f64,
    /// The tool point, machine frame (mm): the six-bar's equilibrium at the link angles.
    pub tool_mm: [f64; 2],
    /// The links' geometric angles (rad).
    pub link_rad: [f64; 2],
    /// What the encoders read (rad, quantised; the firmware's angles once homed).
    pub encoder_rad: [f64; 2],
    /// The motors' speeds (rad/s).
    pub velocity_rad_s: [f64; 2],
    /// The drive-enable line and the torque the duty registers command (0 with it low).
    pub drive_enable: bool,
    pub torque_nm: [f64; 2],
}

/// What a co-simulation did and how fast (the benchmark's figures).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CoSimStats {
    /// Samples exchanged and the simulated time they make.
    pub samples: u64,
    pub simulated_s: f64,
    /// Wall time since the start (QEMU's boot included).
    pub wall_s: f64,
    /// Simulated seconds per wall second.
    pub speed: f64,
    /// Firmware boots (1 without a reset).
    pub boots: u32,
    /// The firmware's worst servo step (µs, its own measurement from the tick) and overruns.
    pub worst_step_us: f32,
    pub overruns: u32,
    /// Samples more than 1.5 periods after the previous one on the firmware's clock.
    pub late_samples: u64,
    /// Smallest and largest interval between consecutive samples (µs, firmware's clock).
    pub sample_interval_us: Option<[f64; 2]>,
    /// FNV-1a 64 of every byte exchanged, both ways, in order (hex), and their number.
    pub exchange_digest: String,
    pub exchange_bytes: u64,
    /// FNV-1a 64 of the host link's bytes from the controller (replies, telemetry), and the
    /// link's bytes each way.
    pub link_digest: String,
    pub link_bytes_to_controller: u64,
    pub link_bytes_from_controller: u64,
    /// CPU time of QEMU and of this process since they started (s; Linux only): where the wall
    /// time goes.
    pub qemu_cpu_s: Option<f64>,
    pub host_cpu_s: Option<f64>,
    /// The core QEMU and the driving thread share (`None`: not pinned, [`one_core`]).
    pub core: Option<usize>,
    /// The encoders the firmware was configured with (counts per motor revolution, gear ratio).
    pub encoder_counts_per_rev: [u32; 2],
    pub encoder_gear_ratio: [f64; 2],
}

/// A running co-simulation (see the module doc).
pub struct CoSim {
    engine: Arc<Mutex<Engine>>,
    period_s: f64,
    link_read_limit_samples: u64,
    started: Instant,
    /// Link clients made so far.
    clients: u16,
}

/// Locks the engine; a panic elsewhere does not make the state unusable for a report.
fn lock(engine: &Mutex<Engine>) -> MutexGuard<'_, Engine> {
    engine.lock().unwrap_or_else(|e| e.into_inner())
}

impl CoSim {
    /// Starts QEMU with the firmware and the plant at its power-on pose; returns once the
    /// firmware has booted and taken its configuration.
    pub fn start(opts: &CoSimOptions) -> Result<CoSim, CoSimError> {
        opts.validate()?;
        let mut plant = Plant::new(&opts.plant, opts.seed);
        let spec = &opts.machine;
        let power_on = opts
            .power_on_mm
            .unwrap_or_else(|| spec.workspace.centre_mm());
        let encoder_rad = spec.nominal.inverse(power_on, 0.0).map_err(|e| {
            CoSimError::Invalid(format!(
                "power-on pose ({:.3}, {:.3}) mm: {e}",
                power_on[0], power_on[1]
            ))
        })?;
        plant.settle(encoder_rad, [1, 1])?;
        let elf = qemu::locate_firmware(opts.firmware.as_deref())?;
        // Pinned before the spawn: QEMU inherits the core.
        let core = opts.one_core.then(one_core::OneCore::pin).flatten();
        let process = qemu::Qemu::spawn(&opts.qemu, &elf, &opts.image)?.on_core(core);
        let log = match &opts.exchange_log {
            Some(p) => Some(std::fs::File::create(p)?),
            None => None,
        };
        let config = EngineConfig {
            period_s: spec.sample_period_s,
            home_at_boot: opts.home_at_boot,
            marks: exchange::HomingMarks::of(spec)?,
            link_bytes_per_sample: opts.link_bytes_per_sample,
            dynamic_brake_nm_s_per_rad: opts.dynamic_brake_nm_s_per_rad,
            frame_timeout: opts.frame_timeout,
        };
        let engine = Engine::start(process, plant, config, log)?;
        Ok(CoSim {
            engine: Arc::new(Mutex::new(engine)),
            period_s: spec.sample_period_s,
            link_read_limit_samples: (opts.link_read_limit_s / spec.sample_period_s).ceil() as u64,
            started: Instant::now(),
            clients: 0,
        })
    }

    /// A link client over the exchange; `timeout` bounds each request in wall time (the
    /// simulation advances meanwhile: a silent controller is reported after
    /// [`CoSimOptions::link_read_limit_s`] of simulated time per read, then at `timeout`).
    /// Each client numbers its requests from its own deterministic start (clients made in the
    /// same order get the same numbers in every run). The client shares the co-simulation:
    /// QEMU ends when the `CoSim` and every client made from it are gone.
    pub fn link(&mut self, timeout: Duration) -> Result<LinkClient<CoSimLink>, ClientError> {
        self.clients = self.clients.wrapping_add(1);
        let first = self.clients.wrapping_mul(0x4000).wrapping_add(1);
        Ok(LinkClient::new(
            CoSimLink::new(self.engine.clone(), self.link_read_limit_samples),
            timeout,
        )?
        .with_sequence(first))
    }

    /// Runs `seconds` of simulated time (whole samples, rounded to the nearest).
    pub fn run_for_s(&mut self, seconds: f64) -> Result<(), CoSimError> {
        if !(0.0..=1.0e6).contains(&seconds) {
            return Err(CoSimError::Invalid(format!(
                "run_for_s({seconds}): not within 0..=1e6 s"
            )));
        }
        let n = (seconds / self.period_s).round() as u64;
        let mut e = lock(&self.engine);
        for _ in 0..n {
            e.step()?;
        }
        Ok(())
    }

    /// Simulated time since the start (s).
    pub fn simulated_s(&self) -> f64 {
        lock(&self.engine).counters.samples as f64 * self.period_s
    }

    /// The plant's true state now.
    pub fn plant_truth(&self) -> Result<PlantTruth, CoSimError> {
        let mut e = lock(&self.engine);
        let tool_mm = e.plant.solve()?.tool_mm;
        let p = &e.plant;
        Ok(PlantTruth {
            simulated_s: e.counters.samples as f64 * self.period_s,
            tool_mm,
            link_rad: p.link_rad(),
            encoder_rad: p.encoder_rad(),
            velocity_rad_s: [p.drives[0].velocity_rad_s, p.drives[1].velocity_rad_s],
            drive_enable: e.drive_enable,
            torque_nm: e.torque_nm,
        })
    }

    /// What the instrument reads now: the tool point through its frame, scale error and noise
    /// (the plant's instrument, seeded by [`CoSimOptions::seed`]).
    pub fn instrument_reading_mm(&self) -> Result<[f64; 2], CoSimError> {
        let mut e = lock(&self.engine);
        let tool = e.plant.solve()?.tool_mm;
        Ok(e.plant.instrument.read_mm(tool))
    }

    /// The figures so far.
    pub fn stats(&self) -> CoSimStats {
        let e = lock(&self.engine);
        let c = &e.counters;
        let simulated_s = c.samples as f64 * self.period_s;
        let wall_s = self.started.elapsed().as_secs_f64();
        let us = |ticks: u32| f64::from(ticks) / 25.0;
        CoSimStats {
            samples: c.samples,
            simulated_s,
            wall_s,
            speed: simulated_s / wall_s.max(1e-9),
            boots: c.boots,
            worst_step_us: c.worst_step_us,
            overruns: c.overruns,
            late_samples: c.late,
            sample_interval_us: c.clock_step_ticks.map(|[lo, hi]| [us(lo), us(hi)]),
            exchange_digest: format!("{:016x}", e.exchange_digest.0),
            exchange_bytes: c.exchange_bytes,
            link_digest: format!("{:016x}", e.link_digest.0),
            link_bytes_to_controller: c.link_bytes_in,
            link_bytes_from_controller: c.link_bytes_out,
            qemu_cpu_s: e.qemu.cpu_s().or(c.qemu_cpu_s_at_stop),
            host_cpu_s: qemu::cpu_s_of("/proc/self/stat"),
            core: e.qemu.core(),
            encoder_counts_per_rev: e.encoders().counts_per_rev,
            encoder_gear_ratio: e.encoders().gear_ratio,
        }
    }

    /// QEMU's working directory (the firmware's `defmt.bin` and console are there while the
    /// co-simulation lives).
    pub fn work_dir(&self) -> PathBuf {
        lock(&self.engine).qemu.dir().to_path_buf()
    }

    /// QEMU's process id.
    pub fn qemu_pid(&self) -> u32 {
        lock(&self.engine).qemu.pid()
    }

    /// What QEMU and the firmware printed so far.
    pub fn console(&self) -> String {
        lock(&self.engine).qemu.console()
    }

    /// Ends the run: the firmware removes torque and ends QEMU (exit status 0); returns the
    /// final figures.
    pub fn shutdown(self) -> Result<CoSimStats, CoSimError> {
        lock(&self.engine).stop()?;
        Ok(self.stats())
    }
}
