//! One co-simulation sample on the host's side: the firmware's drive registers become torques
//! on the plant, the plant moves one period, its encoders become the counters and index
//! captures the firmware reads, and the host link's bytes cross in both directions.
//!
//! What the simulated hardware presents, as the QEMU board's in-firmware plant does
//! (`firmware/src/board/qemu/{plant,hardware}.rs`):
//! * **Drives**: torque `(2·duty/max − 1)·full_scale` per axis while the enable line is high
//!   (the amplifiers' torque limit is the plant's, `torque_limit_nm`); with it low, no torque
//!   and dynamic braking `−c·ω` (the drives' requirement, firmware/README.md), updated every
//!   substep.
//! * **Encoders**: incremental counters at the plant's resolution (counts per motor revolution
//!   × gear ratio; a plant without quantisation gets the firmware's default, 2^22 counts per
//!   joint revolution), counting up for a positive joint angle, reading 0 where the machine
//!   stood when the controller booted.
//! * **Index marks**: one per axis, at the encoder angle the configuration tells the firmware
//!   ([`HomingMarks`]: beyond the joint's range over the workspace in its search direction);
//!   crossing it in a period reports the counter's value at the mark.
//!
//! Checks: every sample must be the next one (its index from the firmware against the host's
//! count), and consecutive samples one servo period apart on the firmware's own clock; a boot
//! (hello) mid-run is a controller reset (the machine moves on, the counters restart).
use std::collections::VecDeque;
use std::f64::consts::TAU;
use std::io::Write;
use std::time::Duration;

use cosim_wire::{
    decode_up, Config, Down, DownSample, Hello, Sign, Up, DOWN_LEN, MAX_LINK_RX_OUTSTANDING,
    MAX_LINK_RX_PER_SAMPLE,
};

use super::qemu::Qemu;
use super::CoSimError;
use crate::machine_spec::MachineSpec;
use crate::plant::Plant;
use crate::sim::closed_loop::SUBSTEPS;

/// Ticks of the firmware's 25 MHz clock per 500 µs sample.
pub const PERIOD_TICKS: u32 = 12_500;
/// A sample more than this many ticks after the previous one is late (the servo missed a
/// tick: half a period).
pub const LATE_TICKS: u32 = PERIOD_TICKS + PERIOD_TICKS / 2;
/// Counts per joint revolution of a plant without encoder quantisation: the firmware's default
/// encoder (`EncoderConfig::DIRECT_DRIVE_2_22`).
pub const DEFAULT_COUNTS_PER_REV: u32 = 1 << 22;

/// 64-bit FNV-1a: the exchange's digest (two runs with the same digest exchanged the same
/// bytes; not a security hash).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Digest(pub u64);

impl Digest {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    pub fn new() -> Self {
        Digest(Self::OFFSET)
    }

    pub fn add(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(Self::PRIME);
        }
    }
}

impl Default for Digest {
    fn default() -> Self {
        Self::new()
    }
}

/// The encoders as the firmware is configured to read them (sent at every boot).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderPlan {
    /// Counts per motor revolution, per axis.
    pub counts_per_rev: [u32; 2],
    /// Motor revolutions per joint revolution, per axis.
    pub gear_ratio: [f64; 2],
    /// Joint radians per count, per axis.
    pub step_rad: [f64; 2],
}

impl EncoderPlan {
    /// The plant's encoders; a plant without quantisation gets [`DEFAULT_COUNTS_PER_REV`] on a
    /// direct drive. A count per revolution that is not a whole number below 2^32 is refused.
    pub fn of(plant: &Plant) -> Result<Self, CoSimError> {
        let mut plan = EncoderPlan {
            counts_per_rev: [DEFAULT_COUNTS_PER_REV; 2],
            gear_ratio: [1.0; 2],
            step_rad: [TAU / f64::from(DEFAULT_COUNTS_PER_REV); 2],
        };
        let configs = [&plant.config.drive_1, &plant.config.drive_2];
        for (k, config) in configs.iter().enumerate() {
            if plant.drives[k].encoder_step_rad() == 0.0 {
                continue;
            }
            let (counts, gear) = (config.encoder_counts_per_motor_rev, config.gear_ratio);
            if !(counts >= 1.0 && counts <= f64::from(u32::MAX) && counts.fract() == 0.0) {
                return Err(CoSimError::Invalid(format!(
                    "drive_{}.encoder_counts_per_motor_rev = {counts}: the firmware's encoder \
                     counts a whole number of counts per revolution (1 to 2^32 - 1)",
                    k + 1
                )));
            }
            plan.counts_per_rev[k] = counts as u32;
            plan.gear_ratio[k] = gear;
            plan.step_rad[k] = plant.drives[k].encoder_step_rad();
        }
        Ok(plan)
    }
}

/// The machine's index marks as the co-simulation builds it, and the search travel the firmware
/// is configured with (its search directions are the production default: joint 1 positive,
/// joint 2 negative).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HomingMarks {
    /// Encoder angle of each axis's mark (rad).
    pub index_rad: [f64; 2],
    /// Longest search per axis (rad).
    pub max_travel_rad: [f64; 2],
}

/// Beyond the joint's range over the workspace: where a mark goes (rad).
pub const MARK_MARGIN_RAD: f64 = 0.03;
/// Search travel beyond the range and the margin (rad).
pub const TRAVEL_MARGIN_RAD: f64 = 0.1;

impl HomingMarks {
    /// The marks of `spec`'s machine: each joint's range of encoder angles over the rectangle
    /// of its correction grid (the nominal model on a 61×61 lattice: the rectangle the
    /// firmware's homing plan check starts from), the mark [`MARK_MARGIN_RAD`] beyond it in the
    /// search direction (above joint 1's, below joint 2's), the travel the whole range, the
    /// margin and [`TRAVEL_MARGIN_RAD`], so that a search from anywhere in the rectangle finds
    /// its mark. On the paper machine: 1.396 and −1.396 rad, beside the firmware's defaults
    /// (1.40, −1.40).
    pub fn of(spec: &MachineSpec) -> Result<Self, CoSimError> {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let g = &spec.grid;
        let far = g.far_corner_mm();
        let n = 60;
        for i in 0..=n {
            for j in 0..=n {
                let p = [
                    g.x0_mm + (far[0] - g.x0_mm) * f64::from(i) / f64::from(n),
                    g.y0_mm + (far[1] - g.y0_mm) * f64::from(j) / f64::from(n),
                ];
                let a = spec.nominal.inverse(p, 0.0).map_err(|e| {
                    CoSimError::Invalid(format!(
                        "machine '{}': ({:.3}, {:.3}) mm of its grid: {e}",
                        spec.name, p[0], p[1]
                    ))
                })?;
                for k in 0..2 {
                    lo[k] = lo[k].min(a[k]);
                    hi[k] = hi[k].max(a[k]);
                }
            }
        }
        let travel = [0, 1].map(|k| hi[k] - lo[k] + MARK_MARGIN_RAD + TRAVEL_MARGIN_RAD);
        Ok(HomingMarks {
            index_rad: [hi[0] + MARK_MARGIN_RAD, lo[1] - MARK_MARGIN_RAD],
            max_travel_rad: travel,
        })
    }
}

/// What the exchange counted.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Counters {
    /// Samples exchanged (all boots).
    pub samples: u64,
    /// Boots of the firmware (1 without a reset).
    pub boots: u32,
    /// Samples more than [`LATE_TICKS`] after the previous one.
    pub late: u64,
    /// Smallest and largest clock step between consecutive samples (ticks).
    pub clock_step_ticks: Option<[u32; 2]>,
    /// The firmware's worst servo step (µs) and overruns, as its status last said.
    pub worst_step_us: f32,
    pub overruns: u32,
    /// Host-link bytes to and from the firmware.
    pub link_bytes_in: u64,
    pub link_bytes_out: u64,
    /// Bytes of the exchange (both directions).
    pub exchange_bytes: u64,
    /// QEMU's CPU time when it was stopped (s).
    pub qemu_cpu_s_at_stop: Option<f64>,
}

/// The host's side of the exchange: QEMU, the plant and the simulated hardware between them.
pub struct Engine {
    pub qemu: Qemu,
    pub plant: Plant,
    pub counters: Counters,
    /// Digest of every byte exchanged, both ways, in order.
    pub exchange_digest: Digest,
    /// Digest of the host link's bytes from the firmware (replies and telemetry).
    pub link_digest: Digest,
    /// Bytes for the firmware's host link, not yet sent.
    pub to_firmware: VecDeque<u8>,
    /// Bytes from the firmware's host link, not yet read.
    pub from_firmware: VecDeque<u8>,
    /// The drive registers of the last sample, and the torque they command.
    pub drive_enable: bool,
    pub torque_nm: [f64; 2],
    encoders: EncoderPlan,
    hello: Hello,
    /// The counters' zero (counts at the controller's boot).
    count_zero: [i64; 2],
    /// The next sample's index.
    sample: u32,
    last_clock: Option<u32>,
    /// Link bytes written into the firmware's receive pipe since its boot (wrapping, as the
    /// firmware's count of those it read).
    rx_sent: u32,
    config: EngineConfig,
    up: Vec<u8>,
    down: Vec<u8>,
    log: Option<std::io::BufWriter<std::fs::File>>,
}

/// The engine's fixed settings.
#[derive(Clone, Copy, Debug)]
pub struct EngineConfig {
    pub period_s: f64,
    pub home_at_boot: bool,
    /// Where the index marks are and how far the firmware searches for them.
    pub marks: HomingMarks,
    /// At most [`MAX_LINK_RX_PER_SAMPLE`].
    pub link_bytes_per_sample: usize,
    pub dynamic_brake_nm_s_per_rad: f64,
    pub frame_timeout: Duration,
}

impl Engine {
    /// Waits for the firmware's first hello and configures it.
    pub fn start(
        qemu: Qemu,
        plant: Plant,
        config: EngineConfig,
        log: Option<std::fs::File>,
    ) -> Result<Self, CoSimError> {
        let encoders = EncoderPlan::of(&plant)?;
        let mut e = Engine {
            qemu,
            plant,
            counters: Counters::default(),
            exchange_digest: Digest::new(),
            link_digest: Digest::new(),
            to_firmware: VecDeque::new(),
            from_firmware: VecDeque::new(),
            drive_enable: false,
            torque_nm: [0.0; 2],
            encoders,
            hello: Hello {
                pwm_max_duty: 0,
                drive_full_scale_nm: 0.0,
            },
            count_zero: [0; 2],
            sample: 0,
            last_clock: None,
            rx_sent: 0,
            config,
            up: Vec::with_capacity(cosim_wire::MAX_UP_LEN),
            down: vec![0; DOWN_LEN],
            log: log.map(std::io::BufWriter::new),
        };
        e.read_up()?;
        match decode_up(&e.up) {
            Ok(Up::Hello(h)) => e.boot(h)?,
            Ok(_) => {
                return Err(CoSimError::Protocol(
                    "the firmware's first frame is not its hello".into(),
                ))
            }
            Err(err) => return Err(CoSimError::Protocol(format!("first frame: {err}"))),
        }
        Ok(e)
    }

    /// The encoders the firmware reads.
    pub fn encoders(&self) -> &EncoderPlan {
        &self.encoders
    }

    /// What the firmware said at its last boot.
    pub fn hello(&self) -> &Hello {
        &self.hello
    }

    fn read_up(&mut self) -> Result<(), CoSimError> {
        let timeout = self.config.frame_timeout;
        let mut up = std::mem::take(&mut self.up);
        let r = self.qemu.read_up(&mut up, timeout);
        if r.is_ok() {
            self.exchange_digest.add(&up);
            self.counters.exchange_bytes += up.len() as u64;
            if let Some(log) = &mut self.log {
                log.write_all(&up)?;
            }
        }
        self.up = up;
        r
    }

    fn write_down(&mut self) -> Result<(), CoSimError> {
        self.exchange_digest.add(&self.down);
        self.counters.exchange_bytes += self.down.len() as u64;
        if let Some(log) = &mut self.log {
            log.write_all(&self.down)?;
        }
        self.qemu.write_down(&self.down)
    }

    /// The count the encoder of `axis` shows now (before the counter's zero).
    fn count(&self, axis: usize) -> i64 {
        let e = self.plant.drives[axis].encoder_continuous_rad();
        (e / self.encoders.step_rad[axis]).round() as i64
    }

    /// A (re)boot: the counters restart where the machine stands; the configuration goes back.
    fn boot(&mut self, hello: Hello) -> Result<(), CoSimError> {
        if !(hello.pwm_max_duty >= 2
            && hello.drive_full_scale_nm.is_finite()
            && hello.drive_full_scale_nm > 0.0)
        {
            return Err(CoSimError::Protocol(format!(
                "the firmware's hello is not a drive configuration: {hello:?}"
            )));
        }
        self.hello = hello;
        self.count_zero = [self.count(0), self.count(1)];
        self.sample = 0;
        self.last_clock = None;
        // Bytes the firmware did not read before it rebooted are lost, as a UART's would be.
        self.qemu.drain_link_rx()?;
        self.rx_sent = 0;
        self.counters.boots += 1;
        let e = &self.encoders;
        Down::Config(Config {
            counts_per_rev: e.counts_per_rev,
            gear_ratio: e.gear_ratio.map(|g| g as f32),
            sign: [Sign::Normal; 2],
            index_rad: self.config.marks.index_rad.map(|v| v as f32),
            max_travel_rad: self.config.marks.max_travel_rad.map(|v| v as f32),
            home_at_boot: self.config.home_at_boot,
        })
        .encode(&mut self.down)
        .map_err(|e| CoSimError::Protocol(format!("configuration: {e}")))?;
        self.write_down()
    }

    /// One sample: waits for the firmware's sample frame (taking the link's bytes and answering
    /// a reboot's hello on the way), moves the plant one period under its drive registers and
    /// answers with the encoders and the link's received bytes.
    pub fn step(&mut self) -> Result<(), CoSimError> {
        let s = loop {
            self.read_up()?;
            match decode_up(&self.up) {
                Ok(Up::Sample(s)) => break s,
                Ok(Up::Link(bytes)) => {
                    self.link_digest.add(bytes);
                    self.from_firmware.extend(bytes);
                    self.counters.link_bytes_out += bytes.len() as u64;
                }
                Ok(Up::Hello(h)) => self.boot(h)?,
                Err(e) => {
                    return Err(CoSimError::Protocol(format!(
                        "frame from the firmware: {e}"
                    )))
                }
            }
        };
        if s.sample != self.sample {
            return Err(CoSimError::Protocol(format!(
                "the firmware sent sample {}, the host expected {}: a sample was lost or \
                 repeated",
                s.sample, self.sample
            )));
        }
        self.check_clock(s.clock_ticks);
        self.counters.worst_step_us = s.worst_step_us;
        self.counters.overruns = s.overruns;

        // The drives, one period.
        let h = &self.hello;
        let half = f64::from(h.pwm_max_duty) / 2.0;
        let full = f64::from(h.drive_full_scale_nm);
        self.drive_enable = s.drive_enable;
        self.torque_nm = if s.drive_enable {
            s.duty.map(|d| (f64::from(d) / half - 1.0) * full)
        } else {
            [0.0; 2]
        };
        let before = [0, 1].map(|k| self.plant.drives[k].encoder_continuous_rad());
        self.advance()?;

        // The encoders.
        let counts = [0, 1].map(|k| (self.count(k) - self.count_zero[k]) as i32);
        let index_counts = [0, 1].map(|k| {
            let mark = self.config.marks.index_rad[k];
            let after = self.plant.drives[k].encoder_continuous_rad();
            let crossed = before[k] != after && (before[k] - mark) * (after - mark) <= 0.0;
            let at_mark = (mark / self.encoders.step_rad[k]).round() as i64;
            crossed.then(|| (at_mark - self.count_zero[k]) as i32)
        });

        // The link's bytes to the firmware: into its pipe first, announced in the answer.
        let unread = self.rx_sent.wrapping_sub(s.rx_consumed) as usize;
        let n = self
            .to_firmware
            .len()
            .min(self.config.link_bytes_per_sample)
            .min(MAX_LINK_RX_PER_SAMPLE)
            .min(MAX_LINK_RX_OUTSTANDING.saturating_sub(unread));
        if n > 0 {
            let rx: Vec<u8> = self.to_firmware.drain(..n).collect();
            self.exchange_digest.add(&rx);
            self.counters.exchange_bytes += n as u64;
            if let Some(log) = &mut self.log {
                log.write_all(&rx)?;
            }
            self.qemu.write_link_rx(&rx)?;
            self.rx_sent = self.rx_sent.wrapping_add(n as u32);
            self.counters.link_bytes_in += n as u64;
        }
        Down::Sample(DownSample {
            sample: s.sample,
            counts,
            index_counts,
            rx_len: n as u16,
        })
        .encode(&mut self.down)
        .map_err(|e| CoSimError::Protocol(format!("sample: {e}")))?;
        self.write_down()?;
        self.sample = self.sample.wrapping_add(1);
        self.counters.samples += 1;
        Ok(())
    }

    fn check_clock(&mut self, clock: u32) {
        if let Some(last) = self.last_clock {
            let step = clock.wrapping_sub(last);
            if step > LATE_TICKS {
                self.counters.late += 1;
            }
            let [lo, hi] = self.counters.clock_step_ticks.unwrap_or([step, step]);
            self.counters.clock_step_ticks = Some([lo.min(step), hi.max(step)]);
        }
        self.last_clock = Some(clock);
    }

    /// One period of the plant under `torque_nm`, or braking dynamically with the drives off.
    fn advance(&mut self) -> Result<(), CoSimError> {
        let dt = self.config.period_s;
        let moving = self.plant.drives.iter().any(|d| d.velocity_rad_s != 0.0);
        if self.drive_enable || !moving {
            self.plant.advance(self.torque_nm, dt, SUBSTEPS)?;
        } else {
            let c = self.config.dynamic_brake_nm_s_per_rad;
            let h = dt / f64::from(SUBSTEPS);
            for _ in 0..SUBSTEPS {
                let brake = [0, 1].map(|k| -c * self.plant.drives[k].velocity_rad_s);
                self.plant.advance(brake, h, 1)?;
            }
        }
        Ok(())
    }

    /// Ends the run: answers the firmware's next frame with a stop and waits for QEMU to exit.
    pub fn stop(&mut self) -> Result<(), CoSimError> {
        self.read_up()?;
        self.counters.qemu_cpu_s_at_stop = self.qemu.cpu_s();
        Down::Stop
            .encode(&mut self.down)
            .map_err(|e| CoSimError::Protocol(format!("stop: {e}")))?;
        self.write_down()?;
        if let Some(log) = &mut self.log {
            log.flush()?;
        }
        let status = self.qemu.wait_exit(Duration::from_secs(10))?;
        if status.success() {
            Ok(())
        } else {
            Err(CoSimError::Exited {
                status: status.to_string(),
                console: self.qemu.console(),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_digest_is_fnv1a() {
        // FNV-1a 64 of "a" (the published test vector).
        let mut d = Digest::new();
        d.add(b"a");
        assert_eq!(d.0, 0xaf63_dc4c_8601_ec8c);
    }

    #[test]
    fn the_paper_machines_marks_are_the_firmwares_defaults_and_every_machine_gets_its_own() {
        let paper = HomingMarks::of(&MachineSpec::paper()).unwrap();
        eprintln!("paper: {paper:?}");
        assert!((paper.index_rad[0] - 1.40).abs() < 0.005, "{paper:?}");
        assert!((paper.index_rad[1] + 1.40).abs() < 0.005, "{paper:?}");
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let second =
            crate::io::machine_file::read_machine(&root.join("machines/second.toml")).unwrap();
        let marks = HomingMarks::of(&second).unwrap();
        eprintln!("second: {marks:?}");
        // Beyond every pose of the workspace in the search direction, within the travel.
        let c = second
            .nominal
            .inverse(second.workspace.centre_mm(), 0.0)
            .unwrap();
        assert!(
            marks.index_rad[0] > c[0] && marks.index_rad[1] < c[1],
            "{marks:?}"
        );
        assert!(marks.index_rad[0] - c[0] < marks.max_travel_rad[0]);
        assert!(c[1] - marks.index_rad[1] < marks.max_travel_rad[1]);
    }

    #[test]
    fn encoders_follow_the_plant_and_default_to_the_firmwares() {
        let paper = Plant::new(&crate::plant::PlantConfig::paper(), 1);
        let plan = EncoderPlan::of(&paper).unwrap();
        assert_eq!(plan.counts_per_rev, [1 << 20; 2]);
        assert_eq!(plan.gear_ratio, [10.0; 2]);
        assert!((plan.step_rad[0] - TAU / (10.0 * f64::from(1u32 << 20))).abs() < 1e-18);
        let ideal = Plant::new(&crate::plant::PlantConfig::ideal(), 1);
        let plan = EncoderPlan::of(&ideal).unwrap();
        assert_eq!(plan.counts_per_rev, [DEFAULT_COUNTS_PER_REV; 2]);
        assert_eq!(plan.gear_ratio, [1.0; 2]);
        let mut odd = crate::plant::PlantConfig::paper();
        odd.drive_2.encoder_counts_per_motor_rev = 1000.5;
        let e = EncoderPlan::of(&Plant::new(&odd, 1))
            .unwrap_err()
            .to_string();
        assert!(e.contains("drive_2.encoder_counts_per_motor_rev"), "{e}");
    }
}
