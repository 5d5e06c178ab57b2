//! Telemetry logs: built from what the controller sent over its link or from the host loop's
//! samples (the same record either way, `io::telemetry_csv`), and the checks a log must pass
//! before anything is fitted to it: of this machine, without gaps.
//!
//! **The machine.** The metadata line names the machine and its digest
//! (`MachineSpec::identity`, the machine record's digest, as every file the tools write
//! carries it). A log whose digest differs from the machine's is refused. Independently of the metadata, the
//! samples themselves are checked against the machine: the commanded encoder angles must be
//! the model's inverse kinematics of the setpoints (`samples`), which a log of another design
//! is not.
//!
//! **Gaps.** A controller sends a telemetry sample when its link task finds one due, at least
//! `decimation` servo samples after the last (the ticks are not evenly spaced: 20 to 30 apart
//! at decimation 20 under QEMU). Every fit here treats each sample on its own, but a log with
//! an interval longer than [`GAP_FACTOR`] decimations lost samples on the way: refused, naming
//! where (a slower telemetry, `--decimation 40`, fits a slow link's bandwidth).

use super::DynError;
use crate::io::telemetry_csv::{TelemetryLog, TelemetryMeta, TelemetryRow};
use crate::machine_spec::MachineSpec;
use crate::sim::closed_loop::LogRow;
use link_protocol::TelemetrySample;

/// Samples further apart than this many decimation intervals are a gap.
pub const GAP_FACTOR: u64 = 3;

/// The metadata line of a log of `spec` at `decimation`.
pub fn meta_for(spec: &MachineSpec, decimation: u32) -> TelemetryMeta {
    TelemetryMeta {
        machine: spec.identity(),
        sample_period_s: spec.sample_period_s,
        decimation,
    }
}

/// A log of the samples the controller sent.
pub fn from_link(samples: &[TelemetrySample], meta: Option<TelemetryMeta>) -> TelemetryLog {
    let f = |v: [f32; 2]| v.map(f64::from);
    TelemetryLog {
        meta,
        rows: samples
            .iter()
            .map(|t| TelemetryRow {
                tick: u64::from(t.tick),
                setpoint_mm: f(t.setpoint_mm),
                reference_rad: f(t.reference_rad),
                encoder_rad: f(t.encoder_rad),
                torque_nm: f(t.torque_nm),
                following_error_rad: f64::from(t.following_error_rad),
                mode: format!("{:?}", t.mode),
                fault: t.fault.map(|f| format!("{f:?}")),
            })
            .collect(),
    }
}

/// A log of the host loop's samples as a controller would send them: every `decimation`-th
/// sample from the first, in the controller's f32, the loop running (`Running`, no fault).
pub fn from_loop(rows: &[LogRow], meta: TelemetryMeta) -> TelemetryLog {
    let f = |v: [f64; 2]| v.map(|x| f64::from(x as f32));
    let step = meta.decimation.max(1) as usize;
    TelemetryLog {
        rows: rows
            .iter()
            .enumerate()
            .step_by(step)
            .map(|(k, r)| TelemetryRow {
                tick: k as u64,
                setpoint_mm: f(r.setpoint_mm),
                reference_rad: f(r.reference_rad),
                encoder_rad: f(r.encoder_rad),
                torque_nm: f(r.torque_nm),
                following_error_rad: f64::from(
                    (r.reference_rad[0] - r.encoder_rad[0])
                        .abs()
                        .max((r.reference_rad[1] - r.encoder_rad[1]).abs())
                        as f32,
                ),
                mode: "Running".into(),
                fault: None,
            })
            .collect(),
        meta: Some(meta),
    }
}

/// What [`check`] found about a log that passed.
#[derive(Clone, Debug, PartialEq)]
pub struct LogFacts {
    /// Servo samples per telemetry sample.
    pub decimation: u64,
    /// The servo's sample period (s).
    pub sample_period_s: f64,
    /// Whether the log named its machine (`false`: a log without the metadata line, checked by
    /// its samples only).
    pub machine_named: bool,
}

/// Checks that `log` is one of `spec`'s machine, at its sample period, without gaps, and long
/// enough to fit anything to (`min_rows`); the refusal says what is missing.
pub fn check(
    log: &TelemetryLog,
    spec: &MachineSpec,
    min_rows: usize,
) -> Result<LogFacts, DynError> {
    let refuse = |m: String| Err(DynError::Telemetry(m));
    if log.rows.len() < min_rows.max(2) {
        return refuse(format!(
            "the log has {} samples; at least {} are needed (record the whole excitation: \
             host-sim identify streams it and records its telemetry)",
            log.rows.len(),
            min_rows.max(2)
        ));
    }
    let step = match &log.meta {
        Some(m) => {
            let own = spec.identity();
            if m.machine.digest != own.digest {
                return refuse(format!(
                    "the log is of {}, not of {own}: give the machine file it was recorded on \
                     (--machine)",
                    m.machine
                ));
            }
            if (m.sample_period_s - spec.sample_period_s).abs() > 1e-9 * spec.sample_period_s {
                return refuse(format!(
                    "the log's sample period is {} s, the machine's {} s",
                    m.sample_period_s, spec.sample_period_s
                ));
            }
            u64::from(m.decimation)
        }
        // Without metadata: the smallest interval between samples.
        None => log
            .rows
            .windows(2)
            .map(|w| w[1].tick - w[0].tick)
            .min()
            .unwrap_or(1),
    };
    // A controller sends a sample when its link task finds one due: at least `step` samples
    // after the last, often a few more. A longer interval is samples lost on the way.
    let mut gaps = Vec::new();
    for w in log.rows.windows(2) {
        let d = w[1].tick - w[0].tick;
        if d < step {
            return refuse(format!(
                "ticks {} and {} are {d} samples apart, closer than the decimation {step}: not \
                 one telemetry stream of this decimation",
                w[0].tick, w[1].tick
            ));
        }
        if d > GAP_FACTOR * step {
            gaps.push((w[0].tick, w[1].tick));
        }
    }
    if !gaps.is_empty() {
        let shown: Vec<String> = gaps
            .iter()
            .take(5)
            .map(|(a, b)| {
                format!(
                    "{a} to {b} ({} ms)",
                    (b - a) as f64 * spec.sample_period_s * 1e3
                )
            })
            .collect();
        return refuse(format!(
            "the log has {} gaps longer than {GAP_FACTOR} decimation intervals (between ticks \
             {}{}): the link dropped telemetry; record again with a larger decimation (e.g. \
             --decimation 40)",
            gaps.len(),
            shown.join(", "),
            if gaps.len() > 5 { ", ..." } else { "" }
        ));
    }
    Ok(LogFacts {
        decimation: step,
        sample_period_s: spec.sample_period_s,
        machine_named: log.meta.is_some(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::telemetry_csv::{parse_telemetry, telemetry_text};

    fn log(ticks: &[u64]) -> TelemetryLog {
        let spec = MachineSpec::paper();
        TelemetryLog {
            meta: Some(meta_for(&spec, 20)),
            rows: ticks
                .iter()
                .map(|&tick| TelemetryRow {
                    tick,
                    setpoint_mm: [212.0, 0.0],
                    reference_rad: [0.8, -0.8],
                    encoder_rad: [0.8, -0.8],
                    torque_nm: [0.0; 2],
                    following_error_rad: 0.0,
                    mode: "Running".into(),
                    fault: None,
                })
                .collect(),
        }
    }

    #[test]
    fn a_log_of_this_machine_without_gaps_passes() {
        let spec = MachineSpec::paper();
        let l = log(&[100, 120, 140, 160]);
        let back = parse_telemetry(&telemetry_text(&l)).unwrap();
        let facts = check(&back, &spec, 3).unwrap();
        assert_eq!((facts.decimation, facts.machine_named), (20, true));
        // Too short.
        let e = check(&back, &spec, 10).unwrap_err().to_string();
        assert!(e.contains("4 samples") && e.contains("at least 10"), "{e}");
    }

    #[test]
    fn gaps_and_other_machines_are_refused_saying_what() {
        let spec = MachineSpec::paper();
        // Irregular intervals are a controller's; a hole is not.
        assert!(check(&log(&[100, 120, 145, 165, 190, 240]), &spec, 2).is_ok());
        let e = check(&log(&[100, 120, 181, 201, 300]), &spec, 2)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("2 gaps") && e.contains("120 to 181 (30.5 ms)") && e.contains("201 to 300"),
            "{e}"
        );
        let e = check(&log(&[100, 120, 130]), &spec, 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("closer than the decimation"), "{e}");
        let mut other = log(&[100, 120, 140]);
        other.meta.as_mut().unwrap().machine =
            crate::io::machine_file::parse_machine(include_str!("../../machines/second.toml"))
                .unwrap()
                .identity();
        let e = check(&other, &spec, 2).unwrap_err().to_string();
        assert!(
            e.contains("machine 'second'") && e.contains("--machine"),
            "{e}"
        );
        let mut moved = spec.clone();
        moved.nominal.a_mm += 0.5;
        let e = check(&log(&[100, 120, 140]), &moved, 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("digest"), "{e}");
    }
}
