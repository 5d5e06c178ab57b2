//! The telemetry CSV: what the controller reports while it moves (`host-sim link telemetry
//! --csv`, `link stream --telemetry-csv`, `identify --telemetry-csv`) and what the host loop
//! reports of a simulated run (`simulate --telemetry-csv`), in one format, read by `identify
//! --telemetry` and `diagnose --telemetry`.
//!
//! ```text
//! # machine=paper digest=5f0c2a91 sample_period_s=0.0005 decimation=20
//! tick,setpoint_x_mm,setpoint_y_mm,reference_1_rad,reference_2_rad,encoder_1_rad,encoder_2_rad,torque_1_nm,torque_2_nm,following_error_rad,mode,fault
//! 1200,212.13203,0,0.7853982,-0.7853982,0.7853975,-0.78539836,0.0123,-0.0456,7.2e-7,Running,
//! ```
//! * The first line is a comment with the log's metadata: the machine's identity (its name and
//!   digest, as every file the tools write carries it: `crate::machine_identity`, the line a
//!   measurement CSV starts with), the servo's sample period and the telemetry decimation (the
//!   fewest servo samples between two telemetry samples). After the digest, keys are
//!   `key=value` separated by spaces; unknown keys are ignored (a later writer may add some).
//!   Readers skip every other line starting with `#`. A file without the metadata line
//!   (written before it existed) is read, with [`TelemetryLog::meta`] `None`.
//! * Then the column header, exactly these twelve columns in this order (the link's telemetry
//!   sample, `link_protocol::TelemetrySample`), one row per sample: the servo's sample index,
//!   the setpoint (mm), the commanded and read encoder angles (rad), the torques written (N·m),
//!   the larger |reference − encoder| of the two axes (rad), the servo loop's mode and the
//!   latched fault (empty: none).
//! * Numbers are the controller's f32 values, written shortest-exact and read as f32 (a log
//!   read back is the log written); every number must be finite, ticks strictly increasing. Errors name the line (1-based) and the column.

use super::atomic::write_atomic;
use super::{read_text, IoError};
use crate::machine_identity::{csv_line, parse_csv_line, MachineIdentity};
use std::fmt::Write as _;
use std::path::Path;

/// The columns, in order.
pub const COLUMNS: [&str; 12] = [
    "tick",
    "setpoint_x_mm",
    "setpoint_y_mm",
    "reference_1_rad",
    "reference_2_rad",
    "encoder_1_rad",
    "encoder_2_rad",
    "torque_1_nm",
    "torque_2_nm",
    "following_error_rad",
    "mode",
    "fault",
];

/// Most rows a log may have (about 28 hours at 100 Hz): a bound against hostile files.
pub const MAX_ROWS: usize = 10_000_000;

/// A format error: the message names the line and column.
macro_rules! bail {
    ($($t:tt)*) => { return Err(IoError::Parse(format!($($t)*))) };
}

/// The metadata line.
#[derive(Clone, Debug, PartialEq)]
pub struct TelemetryMeta {
    /// The machine's name and digest.
    pub machine: MachineIdentity,
    /// The servo's sample period (s).
    pub sample_period_s: f64,
    /// Servo samples per telemetry sample.
    pub decimation: u32,
}

/// One telemetry sample.
#[derive(Clone, Debug, PartialEq)]
pub struct TelemetryRow {
    /// The servo's sample index.
    pub tick: u64,
    pub setpoint_mm: [f64; 2],
    /// Commanded encoder angles (rad).
    pub reference_rad: [f64; 2],
    /// Encoder angles read (rad).
    pub encoder_rad: [f64; 2],
    /// Torques written (N·m).
    pub torque_nm: [f64; 2],
    /// The larger |reference − encoder| of the two axes (rad).
    pub following_error_rad: f64,
    /// The servo loop's mode (`Running`, `Holding`, ...).
    pub mode: String,
    /// The latched fault, if any.
    pub fault: Option<String>,
}

/// A whole log.
#[derive(Clone, Debug, PartialEq)]
pub struct TelemetryLog {
    /// The metadata line, if the file had one.
    pub meta: Option<TelemetryMeta>,
    pub rows: Vec<TelemetryRow>,
}

/// The file's text.
pub fn telemetry_text(log: &TelemetryLog) -> String {
    let mut s = String::new();
    if let Some(m) = &log.meta {
        let _ = writeln!(
            s,
            "{} sample_period_s={} decimation={}",
            csv_line(&m.machine),
            m.sample_period_s,
            m.decimation
        );
    }
    s.push_str(&COLUMNS.join(","));
    s.push('\n');
    // The controller's values are f32: written as such (shortest exact).
    let f = |v: f64| v as f32;
    for r in &log.rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            r.tick,
            f(r.setpoint_mm[0]),
            f(r.setpoint_mm[1]),
            f(r.reference_rad[0]),
            f(r.reference_rad[1]),
            f(r.encoder_rad[0]),
            f(r.encoder_rad[1]),
            f(r.torque_nm[0]),
            f(r.torque_nm[1]),
            f(r.following_error_rad),
            r.mode,
            r.fault.as_deref().unwrap_or(""),
        );
    }
    s
}

/// Parses the metadata line: the machine's identity, then `key=value` pairs.
fn parse_meta(line: &str, line_no: usize) -> Result<TelemetryMeta, IoError> {
    let machine = parse_csv_line(line).ok_or_else(|| {
        IoError::Parse(format!(
            "line {line_no}: the metadata line must start '# machine=NAME digest=HEX8' (8 hex digits)"
        ))
    })?;
    let rest = line
        .split_once(" digest=")
        .map_or("", |(_, t)| t)
        .split_once(char::is_whitespace)
        .map_or("", |(_, t)| t);
    let (mut period, mut decimation) = (None, None);
    for pair in rest.split_whitespace() {
        let Some((k, v)) = pair.split_once('=') else {
            bail!("line {line_no}: metadata '{pair}' is not key=value");
        };
        match k {
            "sample_period_s" => {
                period = Some(
                    v.parse::<f64>()
                        .ok()
                        .filter(|p| *p > 0.0 && *p < 1.0)
                        .ok_or_else(|| {
                            IoError::Parse(format!(
                                "line {line_no}: sample_period_s '{v}' is not a period in (0, 1) s"
                            ))
                        })?,
                )
            }
            "decimation" => {
                decimation = Some(v.parse::<u32>().ok().filter(|d| *d >= 1).ok_or_else(|| {
                    IoError::Parse(format!(
                        "line {line_no}: decimation '{v}' is not a whole number of samples >= 1"
                    ))
                })?)
            }
            _ => {}
        }
    }
    let missing =
        |k: &str| IoError::Parse(format!("line {line_no}: the metadata line has no {k}="));
    Ok(TelemetryMeta {
        machine,
        sample_period_s: period.ok_or_else(|| missing("sample_period_s"))?,
        decimation: decimation.ok_or_else(|| missing("decimation"))?,
    })
}

/// Parses a log (see the module doc).
pub fn parse_telemetry(text: &str) -> Result<TelemetryLog, IoError> {
    let mut meta = None;
    let mut header_seen = false;
    let mut rows: Vec<TelemetryRow> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        if line.starts_with('#') {
            if !header_seen
                && meta.is_none()
                && line
                    .trim_start_matches('#')
                    .trim_start()
                    .starts_with("machine=")
            {
                meta = Some(parse_meta(line, line_no)?);
            }
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if !header_seen {
            if fields != COLUMNS {
                let which = COLUMNS
                    .iter()
                    .enumerate()
                    .find(|(k, c)| fields.get(*k) != Some(*c))
                    .map_or(String::new(), |(k, c)| {
                        format!(
                            " (column {}: '{}' where '{c}' is expected)",
                            k + 1,
                            fields.get(k).copied().unwrap_or("")
                        )
                    });
                bail!(
                    "line {line_no}: not a telemetry header{which}; expected '{}'",
                    COLUMNS.join(",")
                );
            }
            header_seen = true;
            continue;
        }
        if fields.len() != COLUMNS.len() {
            bail!(
                "line {line_no}: {} fields, expected {} ({})",
                fields.len(),
                COLUMNS.len(),
                COLUMNS.join(",")
            );
        }
        if rows.len() >= MAX_ROWS {
            bail!(
                "line {line_no}: more than {MAX_ROWS} samples: not a telemetry log this tool reads"
            );
        }
        // The values are f32 (the controller's): read as such, so that a log read back is
        // the log written, bit for bit.
        let num = |k: usize| -> Result<f64, IoError> {
            match fields[k].parse::<f32>() {
                Ok(v) if v.is_finite() && v.abs() < 1e9 => Ok(f64::from(v)),
                _ => Err(IoError::Parse(format!(
                    "line {line_no}, column {}: '{}' is not a finite number",
                    COLUMNS[k], fields[k]
                ))),
            }
        };
        let tick = fields[0].parse::<u64>().map_err(|_| {
            IoError::Parse(format!(
                "line {line_no}, column tick: '{}' is not a sample index",
                fields[0]
            ))
        })?;
        if let Some(last) = rows.last() {
            if tick <= last.tick {
                bail!(
                    "line {line_no}: tick {tick} after {}: ticks must increase strictly",
                    last.tick
                );
            }
        }
        if fields[10].is_empty() {
            bail!("line {line_no}, column mode: empty");
        }
        rows.push(TelemetryRow {
            tick,
            setpoint_mm: [num(1)?, num(2)?],
            reference_rad: [num(3)?, num(4)?],
            encoder_rad: [num(5)?, num(6)?],
            torque_nm: [num(7)?, num(8)?],
            following_error_rad: num(9)?,
            mode: fields[10].to_string(),
            fault: (!fields[11].is_empty()).then(|| fields[11].to_string()),
        });
    }
    if !header_seen {
        bail!(
            "no telemetry header: expected a line '{}'",
            COLUMNS.join(",")
        );
    }
    Ok(TelemetryLog { meta, rows })
}

/// Reads a log.
pub fn read_telemetry(path: &Path) -> Result<TelemetryLog, IoError> {
    parse_telemetry(&read_text(path)?).map_err(|e| IoError::content(path, e))
}

/// Writes a log atomically.
pub fn write_telemetry(path: &Path, log: &TelemetryLog) -> Result<(), IoError> {
    write_atomic(path, telemetry_text(log).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log() -> TelemetryLog {
        let row = |tick: u64, x: f64| TelemetryRow {
            tick,
            setpoint_mm: [x, -1.5],
            reference_rad: [0.785, -0.785],
            encoder_rad: [0.785_000_1, -0.785],
            torque_nm: [0.125, -0.5],
            following_error_rad: 6e-8,
            mode: "Running".into(),
            fault: None,
        };
        TelemetryLog {
            meta: Some(TelemetryMeta {
                machine: MachineIdentity {
                    name: "paper".into(),
                    digest: "0123abcd".into(),
                },
                sample_period_s: 0.0005,
                decimation: 20,
            }),
            rows: vec![row(100, 212.25), row(120, 212.5)],
        }
    }

    #[test]
    fn round_trip_and_the_metadata_line() {
        let l = log();
        let text = telemetry_text(&l);
        assert!(text.starts_with(
            "# machine=paper digest=0123abcd sample_period_s=0.0005 decimation=20\ntick,"
        ));
        let back = parse_telemetry(&text).unwrap();
        assert_eq!(back.meta, l.meta);
        assert_eq!(back.rows.len(), 2);
        assert_eq!(back.rows[1].setpoint_mm, [212.5, -1.5]);
        // f32's value, not the decimal's: what the controller holds.
        assert_eq!(back.rows[0].encoder_rad[0], f64::from(0.785_000_1_f32));
        assert_ne!(back.rows[0].encoder_rad[0], 0.785_000_1);
        // Without the metadata line (older files) and with other comments: read.
        let old = text.lines().skip(1).collect::<Vec<_>>().join("\n");
        let back = parse_telemetry(&format!("# a note\n{old}\n# end\n")).unwrap();
        assert_eq!((back.meta, back.rows.len()), (None, 2));
        // Faults and unknown metadata keys.
        let t = text
            .replace("decimation=20", "decimation=20 firmware=1.2")
            .replace("Running,\n", "Holding,Underrun\n");
        let back = parse_telemetry(&t).unwrap();
        assert_eq!(back.rows[1].fault.as_deref(), Some("Underrun"));
    }

    #[test]
    fn refusals_name_the_line_and_column() {
        let text = telemetry_text(&log());
        let e = |t: &str| parse_telemetry(t).unwrap_err().to_string();
        assert!(e("").contains("no telemetry header"));
        let m = e(&text.replace("torque_1_nm", "torque1"));
        assert!(m.contains("column 8") && m.contains("torque_1_nm"), "{m}");
        let m = e(&text.replace("0.125", "nan"));
        assert!(m.contains("line 3") && m.contains("torque_1_nm"), "{m}");
        let m = e(&text.replace("\n120,", "\n90,"));
        assert!(m.contains("line 4") && m.contains("increase"), "{m}");
        let m = e(&text.replace("digest=0123abcd", "digest=xyz"));
        assert!(m.contains("8 hex digits"), "{m}");
        let m = e(&text.replace("sample_period_s=0.0005", "sample_period_s=-1"));
        assert!(m.contains("sample_period_s"), "{m}");
        let m = e(&text.replace(" decimation=20", ""));
        assert!(m.contains("no decimation="), "{m}");
        let m = e(&text.replace(",Running,", ",Running"));
        assert!(m.contains("11 fields"), "{m}");
        let m = e(&text.replace("\n100,", "\n-3,"));
        assert!(m.contains("column tick"), "{m}");
    }
}
